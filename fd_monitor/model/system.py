"""A plant: the :class:`System` type and its entry points :func:`load_system` and
:func:`parse_system`.

A plant file is YAML (see ``config/systems/``; schema and semantics:
:mod:`fd_monitor.model.plant_schema`). :func:`parse_system` checks it section by section
(:mod:`fd_monitor.model.plant_sections`) with the one validation toolkit
(:mod:`fd_monitor.model.validate`): every error names the file, the key path and what was
expected.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.model.errors import SystemFileError
from fd_monitor.model.paths import find_config_file
from fd_monitor.model.plant_parts import Envelope, FaultChannel, Guard, LPVParameter, Mode
from fd_monitor.model.plant_schema import MAX_MAGNITUDE, TOP_KEYS
from fd_monitor.model.plant_sections import (
    canonical_form,
    parse_bounds,
    parse_channels,
    parse_envelope,
    parse_faults,
    parse_guards,
    parse_header,
    parse_initial,
    parse_limits,
    parse_lpv,
    parse_modes,
    parse_shared,
    parse_switching,
    parse_units,
)
from fd_monitor.model.validate import Checker
from fd_monitor.model.yaml_io import read_yaml

__all__ = ["System", "gain_system", "load_system", "parse_system", "plant_checker"]


@dataclass(frozen=True)
class System:
    """A validated plant description (a hybrid automaton).

    Attributes
    ----------
    name : str
    description : str
    sample_time : float
        Sample time Ts, s.
    states, inputs, outputs, disturbances : tuple of str
        Channel names; their lengths are n, nu, ny, nw.
    modes : tuple of Mode
    guards : tuple of Guard
    faults : tuple of FaultChannel
    disturbance_bound : numpy.ndarray
        (nw,) bounds on |w_i|.
    measurement_noise : numpy.ndarray
        (ny,) bounds on |v_i|, output units.
    initial_mode : int
    initial_state : numpy.ndarray
        (n,)
    source : str
        The file it was read from (or ``"<dict>"``).
    sha256 : str
        SHA-256 of the canonical form: the plant's identity.
    switching : str
        ``guards`` (mode changes by the guards only) or ``arbitrary`` (any mode sequence).
    lpv : tuple of LPVParameter
        Parameters of an LPV plant (empty for other plants).
    output_limits, input_limits : numpy.ndarray
        (ny, 2) and (nu, 2) ``[min, max]`` physical range of each output and input (the
        ``limits`` key; +-MAX_MAGNITUDE where the file gives none).
    envelope : Envelope or None
        The declared operating envelope (``envelope`` key), when given. Not part of the
        canonical form: it states where the monitor must work, not how the plant behaves
        (a gain file stores the envelope it certifies).
    state_units, input_units, output_units : tuple of str
        The unit of each state, input and output (the ``units`` key; ``"-"`` where the file
        gives none). Not part of the canonical form.
    """

    name: str
    description: str
    sample_time: float
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    disturbances: tuple[str, ...]
    modes: tuple[Mode, ...]
    guards: tuple[Guard, ...]
    faults: tuple[FaultChannel, ...]
    disturbance_bound: np.ndarray
    measurement_noise: np.ndarray
    initial_mode: int
    initial_state: np.ndarray
    source: str
    canonical: str
    sha256: str
    switching: str = "guards"
    lpv: tuple[LPVParameter, ...] = ()
    output_limits: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    input_limits: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    envelope: Envelope | None = None
    state_units: tuple[str, ...] = ()
    input_units: tuple[str, ...] = ()
    output_units: tuple[str, ...] = ()

    @property
    def n_rho(self) -> int:
        """Number of LPV parameters d."""
        return len(self.lpv)

    @property
    def n(self) -> int:
        """Number of states."""
        return len(self.states)

    @property
    def nu(self) -> int:
        """Number of inputs."""
        return len(self.inputs)

    @property
    def ny(self) -> int:
        """Number of outputs."""
        return len(self.outputs)

    @property
    def nw(self) -> int:
        """Number of disturbance channels."""
        return len(self.disturbances)

    @property
    def mode_names(self) -> tuple[str, ...]:
        """Mode names, in index order."""
        return tuple(m.name for m in self.modes)

    def mode_index(self, name: str) -> int:
        """Return the index of mode ``name``; raise ``KeyError`` naming the known modes."""
        for i, m in enumerate(self.modes):
            if m.name == name:
                return i
        raise KeyError(f"unknown mode {name!r} of plant {self.name!r}; modes: {self.mode_names}")

    def fault(self, name: str) -> FaultChannel:
        """Return the fault channel ``name``; raise ``KeyError`` naming the known channels."""
        for f in self.faults:
            if f.name == name:
                return f
        known = tuple(f.name for f in self.faults)
        raise KeyError(f"unknown fault channel {name!r} of plant {self.name!r}; channels: {known}")

    def guards_from(self, mode: int, kind: str | None = None) -> tuple[Guard, ...]:
        """Guards leaving ``mode`` (optionally only those of ``kind``), in file order."""
        return tuple(
            g for g in self.guards if g.source == mode and (kind is None or g.kind == kind)
        )


def load_system(source: str | Path) -> System:
    """Load and validate a plant description.

    Parameters
    ----------
    source : str or pathlib.Path
        A path to a YAML file, or the name of a shipped plant (``three_tank``), looked up in
        ``config/systems/``.

    Returns
    -------
    System

    Raises
    ------
    SystemFileError
        With a message naming the file, the key path and what was expected.

    Examples
    --------
    >>> plant = load_system("three_tank")
    >>> plant.states, plant.nu, plant.sample_time
    (('h1', 'h2', 'h3'), 3, 0.1)
    >>> len(plant.sha256)
    64
    """
    path = find_config_file(source, "systems", SystemFileError, what="plant")
    data = read_yaml(path)
    return parse_system(data, str(path))


def gain_system(gains: Any, source: str | Path | None = None,
                option: str = "--system") -> System:
    """The plant a gain file was designed for.

    Looked up, in this order: ``source`` when given; the plant file the gain file records
    (``system.file``); the plant's name among the shipped plants. Whether it is the plant
    the gain file was designed for is checked by
    :func:`~fd_monitor.model.gains.load_gains` (its SHA-256).

    Parameters
    ----------
    gains : GainFile
        Loaded (:func:`fd_monitor.model.gains.load_gains`; ``verify=False`` is enough): its
        ``path``, ``system_name`` and ``system_file``.
    source : str or pathlib.Path, optional
        A plant file or a shipped name given by the user.
    option : str
        How the user gives a plant file (named in the error): ``--system``,
        ``-p system:=``.

    Raises
    ------
    SystemFileError
        A bad plant file; or no plant found, the message naming ``option``.
    """
    if source is not None:
        return load_system(source)
    if gains.system_file:
        if not Path(gains.system_file).is_file():
            raise SystemFileError(
                f"{gains.path}: system.file: plant file {gains.system_file} (of plant "
                f"{gains.system_name}) not found: moved? give it with {option} PLANT.yaml")
        return load_system(gains.system_file)
    try:
        path = find_config_file(gains.system_name, "systems", SystemFileError, "plant")
    except SystemFileError:
        raise SystemFileError(
            f"{gains.path}: designed for plant {gains.system_name}, which is not a shipped "
            f"plant and the gain file records no plant file: give it with {option} "
            f"PLANT.yaml") from None
    return load_system(path)


def plant_checker(origin: str) -> Checker:
    """The :class:`~fd_monitor.model.validate.Checker` of a plant file: numbers of magnitude
    at most MAX_MAGNITUDE, and bounds that cannot be negative."""
    return Checker(origin, SystemFileError, max_magnitude=MAX_MAGNITUDE,
                   type_expected="a number",
                   nonneg_expected="a number >= 0 (a bound cannot be negative)")


def parse_system(data: Any, origin: str = "<dict>") -> System:
    """Validate parsed YAML ``data`` and build a :class:`System`.

    Parameters
    ----------
    data : Any
        What ``yaml.safe_load`` returned.
    origin : str
        Name of the file, used in error messages.
    """
    ck = plant_checker(origin)
    if not isinstance(data, Mapping):
        ck.fail("(top level)", "a mapping of plant keys", type(data).__name__)
    ck.keys("", data, TOP_KEYS)
    head = parse_header(ck, data)
    ch = parse_channels(ck, data)
    wbar, vbar = parse_bounds(ck, data, ch)
    shared = parse_shared(ck, data)
    lpv = parse_lpv(ck, data)
    modes = parse_modes(ck, data, ch, head.time, shared, len(lpv))
    guards = parse_guards(ck, data, ch, modes)
    faults = parse_faults(ck, data, ch, modes)
    q0, x0 = parse_initial(ck, data, len(ch.states), modes)
    switching = parse_switching(ck, data)
    canonical = canonical_form(head.name, head.sample_time, ch.states, ch.inputs, ch.outputs,
                               ch.disturbances, wbar, vbar, modes, guards, faults, q0, x0,
                               switching if "switching" in data else None,
                               lpv if "lpv" in data else None)
    digest = hashlib.sha256(canonical.encode()).hexdigest()
    ylim, ulim = parse_limits(ck, data, ch.outputs, ch.inputs)
    env = parse_envelope(ck, data["envelope"], ch.states, ch.inputs, modes) \
        if data.get("envelope") is not None else None
    xunits, uunits, yunits = parse_units(ck, data, ch)
    return System(head.name, head.description, head.sample_time, ch.states, ch.inputs,
                  ch.outputs, ch.disturbances, modes, guards, faults, wbar, vbar, q0, x0,
                  origin, canonical, digest, switching, lpv, ylim, ulim, env, xunits, uunits,
                  yunits)
