"""Plant descriptions: load, validate and identify the hybrid automaton of a monitored plant.

A plant file is YAML (see ``config/systems/``). The plant is a hybrid automaton
(Heracleous et al., eq. 1-3): named states, inputs and outputs; modes, each with linear or
affine dynamics (continuous or discrete time) or a named nonlinear model; guards, each
autonomous (on a state) or controlled (on an input); bounds on measurement noise,
disturbances and per-mode modelling uncertainty; fault channels; a sample time; an initial
mode and state.

Schema (``format_version: 1``)::

    format_version: 1
    name: pwa_cascade                 # identifier, [A-Za-z0-9_]+
    description: free text            # not part of the plant's identity
    time: continuous                  # continuous | discrete (default of every mode)
    sample_time: 0.01                 # s, > 0
    states: [x1, x2, b1, b2]
    inputs: []                        # may be empty
    outputs: [y1, y2]
    disturbances: [w1, w2, w3, w4]    # bounded unknown inputs w (may be empty)
    bounds:
      disturbance: [1.0, 1.0, 1.0, 1.0]    # |w_i| <= bound, one per disturbance
      measurement_noise: [0.0, 0.0]        # |v_i| <= bound, one per output
    shared: {B: ..., C: ..., D: ..., E: ...}  # defaults for every mode that omits them
    modes:
      safe:
        dynamics: linear              # linear | nonlinear
        time: continuous              # optional override of the plant's default
        A: [[...]]                    # n x n
        B: [[...]]                    # n x nu (default zeros)
        C: [[...]]                    # ny x n (required, here or in shared)
        D: [[...]]                    # n x nw (default zeros)
        E: [[...]]                    # ny x nw (default zeros)
        offset: [...]                 # n, affine term (default zeros)
        uncertainty: [...]            # n, |eta_i| <= bound added to x_{k+1} (default zeros)
      tank_mode:
        dynamics: nonlinear
        model: three_tank             # a model of fd_monitor.model.nonlinear
        params: {name: value, ...}    # checked against the model's parameter list
        C: ...                        # as above
    guards:
      - name: g_safe_to_x2            # optional; default "<from>-><to>"
        from: safe
        to: x2_high
        kind: autonomous              # autonomous (conditions on states) | controlled (on inputs)
        when: [{var: x2, op: ">", value: 0.4}]   # all conditions must hold
    faults:
      - {name: bias_y1, kind: sensor_bias, output: y1}      # y_i += f
      - {name: act_u1, kind: actuator, input: u1}           # u_j += f (in the plant only)
      - {name: b1_step, kind: state_jump, state: b1}        # x_j jumps by the change of f
      - {name: leak, kind: process, F: [1.0, 0.0, 0.0]}     # dx (or x_{k+1}) += F f
      - {name: gust, kind: process, F: {safe: [...], x2_high: [...]},   # F per mode
         E: [0.0, 1.0]}                                                # optional: y += E f
      - {name: leak1, kind: parameter, parameter: leak_area_1}  # model parameter += f
    initial:
      mode: safe
      state: [0.0, 0.6, 0.0, 0.1]
    switching: guards                 # optional: guards (default) | arbitrary (any mode
                                      # sequence, e.g. the switched designs of Farhat & Koenig)
    lpv:                              # optional: parameter-dependent linear modes
      parameters:
        - {name: rho1, min: -1.0, max: 1.0, measured: true}   # measured: false = uncertain
    # and in a linear mode:  A_rho: [A_1, ..., A_d] (d x n x n), B_rho (d x n x nu)
    # so that A(rho) = A + sum_j rho_j A_j, B(rho) = B + sum_j rho_j B_j (thesis 5.2, 6.5).
    limits:                           # optional: the physical range of what is measured
      outputs: {y1: [-1.0, 1.0]}      # [min, max] per output (any subset), output units
      inputs: {u1: [0.0, 2.0]}        # [min, max] per input (any subset)
    envelope:                         # optional: the declared operating envelope (the
      states: {x1: [0.0, 1.0], ...}   # region a `thresholds` design certifies and the
      inputs: {u1: [-1.0, 1.0], ...}  # runtime checks); every state and input needs a
      modes: {safe: {states: {x2: [0.0, 0.4]}}}   # range; `modes` narrows them per mode

``limits`` say what a sensor or an actuator command can physically read: a sample outside
them is implausible and refused where samples enter the runtime
(:mod:`fd_monitor.core.plausibility`), like a NaN. A channel without limits may read any
value of magnitude <= MAX_MAGNITUDE. Limits describe the instruments, not the dynamics,
so they do not enter the plant's canonical form (its SHA-256).

The optional keys ``switching``, ``lpv``, ``A_rho``, ``B_rho`` and a process fault's ``E`` or
per-mode ``F`` enter the plant's canonical form (its SHA-256) only when they are given, so
the identity of a plant file without them does not depend on their existence.

Semantics: in mode ``q`` a continuous-time linear mode is ``dx/dt = A x + B u + D w + offset``
(discretised exactly with zero-order hold on u and w, see :mod:`fd_monitor.core.plant`); a
discrete-time one is ``x_{k+1} = A x_k + B u_k + D w_k + offset``; a nonlinear one is
``x_{k+1} = model(x_k, u_k, params) + D w_k``. Outputs are ``y_k = C x_k + E w_k + v_k`` plus
sensor faults. The modelling uncertainty ``eta_k`` (``|eta_i| <= uncertainty_i`` of the
current mode) is added to ``x_{k+1}``. Guards are checked at every sample on ``x_{k+1}``
(autonomous) or ``u_k`` (controlled); the first guard of the current mode that holds fires.

Every validation error names the file, the key path and what was expected.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from fd_monitor.model.errors import SystemFileError
from fd_monitor.model.paths import find_config_file

__all__ = [
    "Condition",
    "Envelope",
    "FaultChannel",
    "Guard",
    "LPVParameter",
    "Mode",
    "System",
    "SUPPORTED_FORMAT_VERSIONS",
    "load_system",
    "parse_system",
    "MAX_MAGNITUDE",
    "parse_yaml_text",
    "read_yaml",
    "require_memory",
]

SUPPORTED_FORMAT_VERSIONS = (1,)
_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_OPS = ("<", "<=", ">", ">=", "==")
_FAULT_KINDS = ("sensor_bias", "actuator", "state_jump", "process", "parameter")
_TOP_KEYS = {
    "format_version", "name", "description", "time", "sample_time", "states", "inputs",
    "outputs", "disturbances", "bounds", "shared", "modes", "guards", "faults", "initial",
    "switching", "lpv", "limits", "envelope",
}
_MODE_KEYS = {
    "dynamics", "time", "A", "B", "C", "D", "E", "offset", "uncertainty", "model", "params",
    "description", "A_rho", "B_rho",
}


@dataclass(frozen=True)
class Condition:
    """One enabling condition ``var op value`` of a guard.

    Attributes
    ----------
    var : str
        State name (autonomous guard) or input name (controlled guard).
    index : int
        Index of ``var`` in the state vector or the input vector.
    op : str
        One of ``<``, ``<=``, ``>``, ``>=``, ``==``.
    value : float
        Threshold, in the unit of ``var``.
    """

    var: str
    index: int
    op: str
    value: float

    def holds(self, v: float) -> bool:
        """Return whether the condition holds for the value ``v`` of its variable."""
        if self.op == "<":
            return v < self.value
        if self.op == "<=":
            return v <= self.value
        if self.op == ">":
            return v > self.value
        if self.op == ">=":
            return v >= self.value
        return v == self.value


@dataclass(frozen=True)
class Guard:
    """A transition ``source -> target`` enabled when every condition holds.

    Attributes
    ----------
    name : str
    source, target : int
        Mode indices.
    kind : str
        ``"autonomous"`` (conditions on states) or ``"controlled"`` (conditions on inputs).
    conditions : tuple of Condition
    """

    name: str
    source: int
    target: int
    kind: str
    conditions: tuple[Condition, ...]

    def enabled(self, x: np.ndarray, u: np.ndarray) -> bool:
        """Return whether the guard's conditions hold for state ``x`` (n,) and input ``u`` (nu,)."""
        vec = x if self.kind == "autonomous" else u
        return all(c.holds(float(vec[c.index])) for c in self.conditions)


@dataclass(frozen=True)
class FaultChannel:
    """A place where a fault can enter the plant.

    Attributes
    ----------
    name : str
    kind : str
        ``sensor_bias`` (added to output ``index``), ``actuator`` (added to input ``index``),
        ``state_jump`` (state ``index`` jumps by the change of the fault signal), ``process``
        (``F f`` added to the state derivative or update), ``parameter`` (added to the
        nonlinear model parameter ``parameter``).
    index : int
        Output, input or state index; -1 for ``process`` and ``parameter``.
    F : numpy.ndarray or None
        (n,) direction of a ``process`` fault that enters every mode the same way; None for
        other kinds and for a mode-dependent direction (see ``F_modes``).
    parameter : str or None
        Parameter name of a ``parameter`` fault.
    F_modes : tuple of numpy.ndarray or None
        Per mode (in mode order), the (n,) direction of a mode-dependent ``process`` fault
        (zeros in the modes the file does not list); None otherwise.
    E : numpy.ndarray or None
        (ny,) output direction of a ``process`` fault (``y += E f``), when given.
    """

    name: str
    kind: str
    index: int = -1
    F: np.ndarray | None = None
    parameter: str | None = None
    F_modes: tuple[np.ndarray, ...] | None = None
    E: np.ndarray | None = None

    def direction(self, mode: int, n: int) -> np.ndarray:
        """(n,) state direction of a ``process`` fault in mode index ``mode`` (zeros for the
        other kinds)."""
        if self.F_modes is not None:
            return self.F_modes[mode]
        if self.F is not None:
            return self.F
        return np.zeros(n)


@dataclass(frozen=True)
class LPVParameter:
    """A scheduling (measured) or uncertain (unmeasured) parameter of an LPV plant.

    Attributes
    ----------
    name : str
    min, max : float
        Bounds of the parameter box (thesis 5.4, 6.4), dimensionless.
    measured : bool
        True: available to the residual generators (LPV, ch. 6); False: an uncertainty
        (ch. 5).
    """

    name: str
    min: float
    max: float
    measured: bool


@dataclass(frozen=True)
class Mode:
    """One discrete mode of the plant.

    Attributes
    ----------
    name : str
    dynamics : str
        ``"linear"`` or ``"nonlinear"``.
    time : str
        ``"continuous"`` or ``"discrete"`` (linear modes; nonlinear models are discrete maps).
    A : numpy.ndarray or None
        (n, n) state matrix (linear modes).
    B : numpy.ndarray
        (n, nu) input matrix.
    C : numpy.ndarray
        (ny, n) output matrix.
    D : numpy.ndarray
        (n, nw) disturbance-to-state matrix.
    E : numpy.ndarray
        (ny, nw) disturbance-to-output matrix.
    offset : numpy.ndarray
        (n,) affine term.
    uncertainty : numpy.ndarray
        (n,) bound on the additive modelling uncertainty of ``x_{k+1}``, state units.
    model : str or None
        Name of the nonlinear model.
    params : dict
        Parameters of the nonlinear model.
    A_rho : numpy.ndarray or None
        (d, n, n) affine parts of A of an LPV plant (``lpv`` key), when given.
    B_rho : numpy.ndarray or None
        (d, n, nu) affine parts of B, when given.
    """

    name: str
    dynamics: str
    time: str
    A: np.ndarray | None
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    E: np.ndarray
    offset: np.ndarray
    uncertainty: np.ndarray
    model: str | None = None
    params: Mapping[str, float] = field(default_factory=dict)
    A_rho: np.ndarray | None = None
    B_rho: np.ndarray | None = None

    def A_of(self, rho: np.ndarray | None) -> np.ndarray:
        """(n, n) ``A(rho) = A + sum_j rho_j A_j`` of a linear mode (``A`` when no A_rho)."""
        assert self.A is not None
        if rho is None or self.A_rho is None:
            return self.A
        return self.A + np.tensordot(np.asarray(rho, dtype=float), self.A_rho, axes=1)


@dataclass(frozen=True)
class Envelope:
    """Declared operating envelope: a box of states and inputs per mode (physical limits).

    Attributes
    ----------
    state_lo, state_hi : numpy.ndarray
        (s, n) state ranges per mode, state units.
    input_lo, input_hi : numpy.ndarray
        (s, nu) input ranges per mode, input units.
    """

    state_lo: np.ndarray
    state_hi: np.ndarray
    input_lo: np.ndarray
    input_hi: np.ndarray


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

    @property
    def is_linear(self) -> bool:
        """True when every mode has linear (affine) dynamics."""
        return all(m.dynamics == "linear" for m in self.modes)


# --------------------------------------------------------------------------------------
# reading


#: Limits of the strict YAML reader (:func:`read_yaml`): nesting depth, alias uses, and
#: nodes after alias expansion (a 500x500 plant is 250,000 nodes per matrix). Beyond them a
#: file is refused before it is built (a deep nesting overflows the recursive builder, an
#: alias bomb expands into gigabytes when printed).
MAX_YAML_DEPTH = 64
MAX_YAML_ALIASES = 1000
MAX_YAML_NODES = 20_000_000
#: Largest magnitude of a number in a plant file: beyond, products in the simulation and
#: the designs overflow float64 (1e308) or lose every digit.
MAX_MAGNITUDE = 1.0e15
#: Sample times accepted, s (1 MHz .. 1e6 s).
SAMPLE_TIME_RANGE = (1.0e-6, 1.0e6)


# libyaml's parser when PyYAML has it (5-10x faster on gain files); same events and marks.
_BaseLoader: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _StrictLoader(_BaseLoader):
    """yaml.SafeLoader that refuses duplicate keys (YAML 1.2; PyYAML keeps the last one).

    Merge keys (``<<: *base``) stay allowed: explicit keys override merged ones, as YAML
    defines; only two explicit equal keys in one mapping are refused.
    """

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> Any:
        seen: dict[tuple[str, str], int] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node,
                                                                           yaml.ScalarNode):
                continue
            key = (key_node.tag, key_node.value)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key_node.value!r} (first at line "
                    f"{seen[key]})", key_node.start_mark)
            seen[key] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep)


# YAML 1.2 floats (1e-300, 1.0e12, 5E3): YAML 1.1, which PyYAML implements, reads them as
# strings, and "expected a number, got '1e-300'" puzzles everyone. Integers keep their own
# resolver (it comes first); this one needs a dot or an exponent.
_StrictLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."))


def _check_structure(text: str, origin: str, error: type[Exception]) -> None:
    """Refuse, from the event stream (no recursion, nothing built), a YAML document nested
    deeper than MAX_YAML_DEPTH, using more than MAX_YAML_ALIASES aliases, or expanding to
    more than MAX_YAML_NODES nodes."""
    depth, aliases = 0, 0
    sizes: dict[str, int] = {}            # anchor -> nodes of the anchored node, expanded
    stack: list[list[Any]] = [[0, None]]  # per open collection: [nodes so far, anchor]
    for ev in yaml.parse(text, Loader=_BaseLoader):
        line = ev.start_mark.line + 1 if ev.start_mark is not None else 0
        if isinstance(ev, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            depth += 1
            if depth > MAX_YAML_DEPTH:
                raise error(f"{origin}: line {line}: YAML nested deeper than "
                            f"{MAX_YAML_DEPTH} levels (refused)")
            stack.append([1, ev.anchor])
        elif isinstance(ev, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            depth -= 1
            count, anchor = stack.pop()
            if anchor is not None:
                sizes[anchor] = count
            stack[-1][0] += count
        elif isinstance(ev, yaml.ScalarEvent):
            if ev.anchor is not None:
                sizes[ev.anchor] = 1
            stack[-1][0] += 1
        elif isinstance(ev, yaml.AliasEvent):
            aliases += 1
            if aliases > MAX_YAML_ALIASES:
                raise error(f"{origin}: line {line}: more than {MAX_YAML_ALIASES} YAML "
                            f"aliases (refused)")
            stack[-1][0] += sizes.get(ev.anchor or "", 1)
            total = sum(c for c, _ in stack)
            if total > MAX_YAML_NODES:
                raise error(f"{origin}: line {line}: YAML aliases expand to more than "
                            f"{MAX_YAML_NODES} nodes (an alias bomb? refused)")


def read_yaml(path: Path, error: type[Exception] = SystemFileError) -> Any:
    """Read a YAML file strictly; raise ``error`` with a one-line message on any failure.

    The one YAML reader of every fd_monitor file (plants, scenarios, gain files, design
    files, the bag library): UTF-8 only; duplicate keys, nesting deeper than
    :data:`MAX_YAML_DEPTH`, more than :data:`MAX_YAML_ALIASES` aliases or an alias expansion
    beyond :data:`MAX_YAML_NODES` nodes are refused.
    """
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise error(f"{path}: file not found") from None
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror or exc}") from None
    return parse_yaml_text(raw, str(path), error)


def parse_yaml_text(raw: bytes | str, origin: str, error: type[Exception] = SystemFileError
                    ) -> Any:
    """:func:`read_yaml` on bytes or text already read (``origin`` names it in messages)."""
    if isinstance(raw, bytes):
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise error(f"{origin}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset "
                        f"{exc.start})") from None
    else:
        text = raw
    try:
        _check_structure(text, origin, error)
        return yaml.load(text, Loader=_StrictLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise error(f"{origin}: invalid YAML{where}: {problem}") from None
    except RecursionError:
        raise error(f"{origin}: YAML nested too deeply (refused)") from None


def require_memory(nbytes: float, what: str, error: type[Exception]) -> None:
    """Refuse, before allocating, arrays of ``nbytes`` bytes that would not fit in memory.

    Parameters
    ----------
    nbytes : float
        Bytes the computation would allocate (an estimate from the shapes).
    what : str
        What needs them, with where it comes from (``"scenario x.yaml: 1e12 samples"``).
    error : type of Exception
        Raised with the size needed and the memory available.
    """
    avail = _available_memory()
    if not math.isfinite(nbytes) or nbytes > avail:
        raise error(f"{what}: would need {_human(nbytes)} of memory, "
                    f"{_human(avail)} available (refused before allocating)")


def _available_memory() -> float:
    """Bytes of memory available now (MemAvailable), else physical memory."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return float(line.split()[1]) * 1024.0
    except (OSError, ValueError, IndexError):
        pass
    import os

    try:
        return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError):
        return 8.0e9


def _human(nbytes: float) -> str:
    if not math.isfinite(nbytes):
        return "unbounded bytes"
    for unit, f in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if nbytes >= f:
            return f"{nbytes / f:.3g} {unit}"
    return f"{nbytes:.0f} bytes"


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
    """
    path = find_config_file(source, "systems", SystemFileError, what="plant")
    data = read_yaml(path)
    return parse_system(data, str(path))


class _Ctx:
    """Error context: the file name, prefixed to every message."""

    def __init__(self, origin: str) -> None:
        self.origin = origin

    def fail(self, key: str, expected: str, got: Any = None, *, show_got: bool = True) -> None:
        tail = f", got {_short(got)}" if show_got else ""
        raise SystemFileError(f"{self.origin}: {key}: expected {expected}{tail}")


class _Got(str):
    """A description of what was found, printed as is (not quoted)."""


def _short(v: Any) -> str:
    if isinstance(v, _Got):
        return str(v)
    s = repr(v)
    return s if len(s) <= 60 else s[:57] + "..."


def _names(ctx: _Ctx, data: Mapping[str, Any], key: str, required: bool) -> tuple[str, ...]:
    if key not in data:
        if required:
            ctx.fail(key, "a list of names (missing key)", show_got=False)
        return ()
    v = data[key]
    if v is None:
        v = []
    if not isinstance(v, list) or not all(isinstance(s, str) for s in v):
        ctx.fail(key, "a list of names", v)
    for i, s in enumerate(v):
        if not _NAME_RE.match(s):
            ctx.fail(f"{key}[{i}]", "a name of letters, digits and '_'", s)
    dup = {s for s in v if v.count(s) > 1}
    if dup:
        ctx.fail(key, "unique names", sorted(dup))
    return tuple(v)


def _number(ctx: _Ctx, key: str, v: Any, *, positive: bool = False, nonneg: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        ctx.fail(key, "a number", v)
    x = float(v)
    if not math.isfinite(x):
        ctx.fail(key, "a finite number", v)
    if abs(x) > MAX_MAGNITUDE:
        ctx.fail(key, f"a number of magnitude <= {MAX_MAGNITUDE:g} (larger ones overflow the "
                 f"simulation and the designs)", v)
    if positive and x <= 0:
        ctx.fail(key, "a number > 0", v)
    if nonneg and x < 0:
        ctx.fail(key, "a number >= 0 (a bound cannot be negative)", v)
    return x


def _matrix(ctx: _Ctx, key: str, v: Any, shape: tuple[int, int]) -> np.ndarray:
    rows, cols = shape
    if rows == 0 or cols == 0:
        if v in (None, [], [[]]):
            return np.zeros(shape)
    if not isinstance(v, list) or not all(isinstance(r, list) for r in v):
        ctx.fail(key, f"a {rows}x{cols} matrix (a list of rows)", v)
    got = (len(v), len(v[0]) if v else 0)
    if len(v) != rows or any(len(r) != cols for r in v):
        widths = sorted({len(r) for r in v})
        ctx.fail(key, f"a {rows}x{cols} matrix",
                 _Got(f"{got[0]} rows of length {', '.join(map(str, widths))}"))
    out = np.empty(shape)
    for i, r in enumerate(v):
        for j, e in enumerate(r):
            out[i, j] = _number(ctx, f"{key}[{i}][{j}]", e)
    return out


def _vector(ctx: _Ctx, key: str, v: Any, size: int, *, nonneg: bool = False) -> np.ndarray:
    if size == 0 and v in (None, []):
        return np.zeros(0)
    if not isinstance(v, list):
        ctx.fail(key, f"a list of {size} numbers", v)
    if len(v) != size:
        ctx.fail(key, f"a list of {size} numbers", _Got(f"{len(v)} numbers"))
    return np.array([_number(ctx, f"{key}[{i}]", e, nonneg=nonneg) for i, e in enumerate(v)])


def _mapping(ctx: _Ctx, key: str, v: Any) -> Mapping[str, Any]:
    if not isinstance(v, Mapping):
        ctx.fail(key, "a mapping", v)
    return v


def _check_keys(ctx: _Ctx, key: str, data: Mapping[str, Any], allowed: set[str]) -> None:
    for k in data:
        if k not in allowed:
            where = f"{key}.{k}" if key else str(k)
            ctx.fail(where, f"one of the keys {sorted(allowed)} (unknown key)", show_got=False)


def parse_system(data: Any, origin: str = "<dict>") -> System:
    """Validate parsed YAML ``data`` and build a :class:`System`.

    Parameters
    ----------
    data : Any
        What ``yaml.safe_load`` returned.
    origin : str
        Name of the file, used in error messages.
    """
    from fd_monitor.model.nonlinear import get_model  # late: core imports this module's types

    ctx = _Ctx(origin)
    if not isinstance(data, Mapping):
        ctx.fail("(top level)", "a mapping of plant keys", type(data).__name__)
    _check_keys(ctx, "", data, _TOP_KEYS)
    version = data.get("format_version", 1)
    if isinstance(version, bool) or version not in SUPPORTED_FORMAT_VERSIONS:
        ctx.fail("format_version", f"one of {SUPPORTED_FORMAT_VERSIONS}", version)
    if "name" not in data:
        ctx.fail("name", "the plant's name (missing key)", show_got=False)
    name = data["name"]
    if not isinstance(name, str) or not _NAME_RE.match(name):
        ctx.fail("name", "a name of letters, digits and '_'", name)
    description = data.get("description", "")
    if not isinstance(description, str):
        ctx.fail("description", "a string", _Got(type(description).__name__))
    default_time = data.get("time", "continuous")
    if default_time not in ("continuous", "discrete"):
        ctx.fail("time", "'continuous' or 'discrete'", default_time)
    if "sample_time" not in data:
        ctx.fail("sample_time", "the sample time in s (missing key)", show_got=False)
    ts = _number(ctx, "sample_time", data["sample_time"], positive=True)
    if not SAMPLE_TIME_RANGE[0] <= ts <= SAMPLE_TIME_RANGE[1]:
        ctx.fail("sample_time", f"a sample time in [{SAMPLE_TIME_RANGE[0]:g}, "
                 f"{SAMPLE_TIME_RANGE[1]:g}] s", data["sample_time"])

    states = _names(ctx, data, "states", required=True)
    if not states:
        ctx.fail("states", "at least one state", [])
    inputs = _names(ctx, data, "inputs", required=False)
    outputs = _names(ctx, data, "outputs", required=True)
    if not outputs:
        ctx.fail("outputs", "at least one output", [])
    dists = _names(ctx, data, "disturbances", required=False)
    n, nu, ny, nw = len(states), len(inputs), len(outputs), len(dists)

    bounds = _mapping(ctx, "bounds", data.get("bounds", {}) or {})
    _check_keys(ctx, "bounds", bounds, {"disturbance", "measurement_noise"})
    wbar = (_vector(ctx, "bounds.disturbance", bounds["disturbance"], nw, nonneg=True)
            if "disturbance" in bounds else np.ones(nw))
    if nw and "disturbance" not in bounds:
        ctx.fail("bounds.disturbance", f"a bound for each of the {nw} disturbances (missing key)",
                 show_got=False)
    vbar = (_vector(ctx, "bounds.measurement_noise", bounds["measurement_noise"], ny, nonneg=True)
            if "measurement_noise" in bounds else np.zeros(ny))

    shared = _mapping(ctx, "shared", data.get("shared", {}) or {})
    _check_keys(ctx, "shared", shared, {"B", "C", "D", "E", "uncertainty"})
    lpv = _parse_lpv(ctx, data)
    d = len(lpv)

    if "modes" not in data:
        ctx.fail("modes", "a mapping of mode names to dynamics (missing key)", show_got=False)
    modes_raw = _mapping(ctx, "modes", data["modes"])
    if not modes_raw:
        ctx.fail("modes", "at least one mode", {})
    modes: list[Mode] = []
    for mname, spec in modes_raw.items():
        key = f"modes.{mname}"
        if not isinstance(mname, str) or not _NAME_RE.match(mname):
            ctx.fail(key, "a mode name of letters, digits and '_'", mname)
        spec = _mapping(ctx, key, spec)
        _check_keys(ctx, key, spec, _MODE_KEYS)
        merged = {**shared, **spec}
        dyn = spec.get("dynamics", "linear")
        if dyn not in ("linear", "nonlinear"):
            ctx.fail(f"{key}.dynamics", "'linear' or 'nonlinear'", dyn)
        mtime = spec.get("time", default_time)
        if mtime not in ("continuous", "discrete"):
            ctx.fail(f"{key}.time", "'continuous' or 'discrete'", mtime)

        def mat(k: str, shape: tuple[int, int], required: bool = False,
                _m: Mapping[str, Any] = merged, _key: str = key,
                _spec: Mapping[str, Any] = spec) -> np.ndarray:
            if k not in _m:
                if required:
                    ctx.fail(f"{_key}.{k}", f"a {shape[0]}x{shape[1]} matrix (missing key; "
                             f"give it in the mode or in 'shared')", show_got=False)
                return np.zeros(shape)
            where = f"{_key}.{k}" if k in _spec else f"shared.{k}"
            return _matrix(ctx, where, _m[k], shape)

        C = mat("C", (ny, n), required=True)
        B = mat("B", (n, nu))
        D = mat("D", (n, nw))
        E = mat("E", (ny, nw))
        offset = (_vector(ctx, f"{key}.offset", spec["offset"], n) if "offset" in spec
                  else np.zeros(n))
        unc_key = f"{key}.uncertainty" if "uncertainty" in spec else "shared.uncertainty"
        unc = (_vector(ctx, unc_key, merged["uncertainty"], n, nonneg=True)
               if "uncertainty" in merged else np.zeros(n))
        A: np.ndarray | None = None
        model: str | None = None
        params: dict[str, float] = {}
        A_rho = _stack3(ctx, f"{key}.A_rho", spec, d, (n, n), dyn)
        B_rho = _stack3(ctx, f"{key}.B_rho", spec, d, (n, nu), dyn)
        if dyn == "linear":
            if "model" in spec or "params" in spec:
                ctx.fail(f"{key}.model", "no 'model'/'params' in a linear mode (set "
                         "dynamics: nonlinear)", show_got=False)
            A = mat("A", (n, n), required=True)
        else:
            if "A" in spec:
                ctx.fail(f"{key}.A", "no 'A' in a nonlinear mode (the model gives the "
                         "dynamics)", show_got=False)
            if "model" not in spec:
                ctx.fail(f"{key}.model", "the name of a nonlinear model (missing key)",
                         show_got=False)
            model = spec["model"]
            try:
                mdl = get_model(str(model))
            except KeyError as exc:
                ctx.fail(f"{key}.model", str(exc.args[0]), show_got=False)
                raise AssertionError from exc  # unreachable: fail raises
            if mdl.n_states != n or mdl.n_inputs != nu:
                ctx.fail(f"{key}.model", f"a model with {n} states and {nu} inputs (model "
                         f"{model!r} has {mdl.n_states} and {mdl.n_inputs})", show_got=False)
            praw = _mapping(ctx, f"{key}.params", spec.get("params", {}) or {})
            for p in praw:
                if p not in mdl.param_names:
                    ctx.fail(f"{key}.params.{p}", f"a parameter of model {model!r}: "
                             f"{list(mdl.param_names)}", show_got=False)
            for p in mdl.param_names:
                if p not in praw:
                    if p in mdl.defaults:
                        params[p] = float(mdl.defaults[p])
                        continue
                    ctx.fail(f"{key}.params.{p}", "a number (missing parameter)",
                             show_got=False)
                params[p] = _number(ctx, f"{key}.params.{p}", praw[p])
            for p, (lo, hi, lo_open) in mdl.ranges.items():
                v = params[p]
                if (v <= lo if lo_open else v < lo) or v > hi:
                    ctx.fail(f"{key}.params.{p}", f"a value in {'(' if lo_open else '['}"
                             f"{lo:g}, {hi:g}] (the physical range of model {model!r})",
                             praw.get(p, v))
        modes.append(Mode(mname, dyn, mtime, A, B, C, D, E, offset, unc, model, params,
                          A_rho, B_rho))
    mode_names = [m.name for m in modes]

    def mode_ref(key: str, v: Any) -> int:
        if v not in mode_names:
            ctx.fail(key, f"one of the modes {mode_names} (unknown mode)", v)
        return mode_names.index(v)

    guards: list[Guard] = []
    graw = data.get("guards", []) or []
    if not isinstance(graw, list):
        ctx.fail("guards", "a list of guards", graw)
    for gi, g in enumerate(graw):
        key = f"guards[{gi}]"
        g = _mapping(ctx, key, g)
        _check_keys(ctx, key, g, {"name", "from", "to", "kind", "when"})
        for req in ("from", "to", "kind", "when"):
            if req not in g:
                ctx.fail(f"{key}.{req}", "a value (missing key)", show_got=False)
        src = mode_ref(f"{key}.from", g["from"])
        dst = mode_ref(f"{key}.to", g["to"])
        if src == dst:
            ctx.fail(f"{key}.to", "a mode other than 'from'", g["to"])
        kind = g["kind"]
        if kind not in ("autonomous", "controlled"):
            ctx.fail(f"{key}.kind", "'autonomous' (on states) or 'controlled' (on inputs)", kind)
        names = states if kind == "autonomous" else inputs
        what = "state" if kind == "autonomous" else "input"
        when = g["when"]
        if isinstance(when, Mapping):
            when = [when]
        if not isinstance(when, list) or not when:
            ctx.fail(f"{key}.when", "a non-empty list of {var, op, value}", when)
        conds = []
        for ci, c in enumerate(when):
            ckey = f"{key}.when[{ci}]"
            c = _mapping(ctx, ckey, c)
            _check_keys(ctx, ckey, c, {"var", "op", "value"})
            var = c.get("var")
            if var not in names:
                ctx.fail(f"{ckey}.var", f"a {what} of a {kind} guard: {list(names)}", var)
            op = c.get("op")
            if op not in _OPS:
                ctx.fail(f"{ckey}.op", f"one of {list(_OPS)}", op)
            if "value" not in c:
                ctx.fail(f"{ckey}.value", "a number (missing key)", show_got=False)
            conds.append(Condition(str(var), names.index(var), str(op),
                                   _number(ctx, f"{ckey}.value", c["value"])))
        gname = g.get("name", f"{g['from']}->{g['to']}")
        if not isinstance(gname, str):
            ctx.fail(f"{key}.name", "a string", gname)
        guards.append(Guard(gname, src, dst, kind, tuple(conds)))
    if len({g.name for g in guards}) != len(guards):
        ctx.fail("guards", "unique guard names", [g.name for g in guards])

    faults: list[FaultChannel] = []
    fraw = data.get("faults", []) or []
    if not isinstance(fraw, list):
        ctx.fail("faults", "a list of fault channels", fraw)
    for fi, f in enumerate(fraw):
        key = f"faults[{fi}]"
        f = _mapping(ctx, key, f)
        kind = f.get("kind")
        if kind not in _FAULT_KINDS:
            ctx.fail(f"{key}.kind", f"one of {list(_FAULT_KINDS)}", kind)
        target_key = {"sensor_bias": "output", "actuator": "input", "state_jump": "state",
                      "process": "F", "parameter": "parameter"}[kind]
        _check_keys(ctx, key, f, {"name", "kind", target_key} | (
            {"E"} if kind == "process" else set()))
        if target_key not in f:
            ctx.fail(f"{key}.{target_key}", f"the {target_key} of a {kind} fault (missing key)",
                     show_got=False)
        fname = f.get("name")
        if not isinstance(fname, str) or not _NAME_RE.match(fname):
            ctx.fail(f"{key}.name", "a name of letters, digits and '_'", fname)
        tgt = f[target_key]
        if kind in ("sensor_bias", "actuator", "state_jump"):
            pool = {"sensor_bias": outputs, "actuator": inputs, "state_jump": states}[kind]
            if tgt not in pool:
                ctx.fail(f"{key}.{target_key}", f"one of {list(pool)}", tgt)
            faults.append(FaultChannel(str(fname), kind, pool.index(tgt)))
        elif kind == "process":
            Fe = _vector(ctx, f"{key}.E", f["E"], ny) if "E" in f else None
            if isinstance(tgt, Mapping):
                per = []
                for mk in tgt:
                    if mk not in mode_names:
                        ctx.fail(f"{key}.F.{mk}", f"one of the modes {mode_names} (a mapping "
                                 f"mode -> {n}-vector)", mk)
                for m in modes:
                    per.append(_vector(ctx, f"{key}.F.{m.name}", tgt[m.name], n)
                               if m.name in tgt else np.zeros(n))
                if not tgt:
                    ctx.fail(f"{key}.F", f"a {n}-vector or a non-empty mapping mode -> "
                             f"{n}-vector", tgt)
                faults.append(FaultChannel(str(fname), kind, -1, F_modes=tuple(per), E=Fe))
            else:
                faults.append(FaultChannel(str(fname), kind, -1,
                                           F=_vector(ctx, f"{key}.F", tgt, n), E=Fe))
        else:
            if not isinstance(tgt, str):
                ctx.fail(f"{key}.parameter", "the name of a model parameter", tgt)
            for m in modes:
                if m.dynamics != "nonlinear" or tgt not in m.params:
                    ctx.fail(f"{key}.parameter", f"a parameter of the nonlinear model of every "
                             f"mode (mode {m.name!r} lacks it)", tgt)
            faults.append(FaultChannel(str(fname), kind, -1, parameter=str(tgt)))
    if len({f.name for f in faults}) != len(faults):
        ctx.fail("faults", "unique fault names", [f.name for f in faults])

    if "initial" not in data:
        ctx.fail("initial", "{mode, state} (missing key)", show_got=False)
    init = _mapping(ctx, "initial", data["initial"])
    _check_keys(ctx, "initial", init, {"mode", "state"})
    if "mode" not in init:
        ctx.fail("initial.mode", "a mode name (missing key)", show_got=False)
    q0 = mode_ref("initial.mode", init["mode"])
    if "state" not in init:
        ctx.fail("initial.state", f"a list of {n} numbers (missing key)", show_got=False)
    x0 = _vector(ctx, "initial.state", init["state"], n)
    switching = data.get("switching", "guards")
    if switching not in ("guards", "arbitrary"):
        ctx.fail("switching", "'guards' (mode changes by the guards) or 'arbitrary' (any mode "
                 "sequence)", switching)

    canonical = _canonical(name, ts, states, inputs, outputs, dists, wbar, vbar, modes,
                           guards, faults, q0, x0,
                           switching if "switching" in data else None,
                           lpv if "lpv" in data else None)
    digest = hashlib.sha256(canonical.encode()).hexdigest()
    ylim, ulim = _parse_limits(ctx, data, outputs, inputs)
    env = _parse_envelope(ctx, data["envelope"], states, inputs, modes) \
        if data.get("envelope") is not None else None
    return System(name, description, ts, states, inputs, outputs, dists, tuple(modes),
                  tuple(guards), tuple(faults), wbar, vbar, q0, x0, origin, canonical, digest,
                  str(switching), lpv, ylim, ulim, env)


def _parse_limits(ctx: _Ctx, data: Mapping[str, Any], outputs: Sequence[str],
                  inputs: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """The optional ``limits: {outputs: {name: [min, max]}, inputs: {...}}``."""
    lim = _mapping(ctx, "limits", data.get("limits", {}) or {})
    _check_keys(ctx, "limits", lim, {"outputs", "inputs"})
    out = []
    for group, names in (("outputs", outputs), ("inputs", inputs)):
        arr = np.tile([-MAX_MAGNITUDE, MAX_MAGNITUDE], (len(names), 1))
        spec = _mapping(ctx, f"limits.{group}", lim.get(group, {}) or {})
        for ch, rng in spec.items():
            key = f"limits.{group}.{ch}"
            if ch not in names:
                ctx.fail(key, f"one of the {group} {list(names)}", ch)
            if not isinstance(rng, list) or len(rng) != 2:
                ctx.fail(key, "[min, max]", rng)
            lo = _number(ctx, f"{key}[0]", rng[0])
            hi = _number(ctx, f"{key}[1]", rng[1])
            if hi <= lo:
                ctx.fail(f"{key}[1]", f"max > min ({lo:g})", rng[1])
            arr[list(names).index(ch)] = (lo, hi)
        out.append(arr)
    return out[0], out[1]


def _parse_envelope(ctx: _Ctx, data: Any, states: Sequence[str], inputs: Sequence[str],
                    modes: Sequence[Mode]) -> Envelope:
    """``envelope: {states: {x: [lo, hi]}, inputs: {u: [lo, hi]}, modes: {m: {...}}}``.

    Every state and input needs a range; ``modes`` narrows them per mode (optional).
    """
    env = _mapping(ctx, "envelope", data)
    _check_keys(ctx, "envelope", env, {"states", "inputs", "modes"})

    def ranges(key: str, spec: Any, names: Sequence[str], lo: np.ndarray, hi: np.ndarray,
               complete: bool) -> None:
        spec = _mapping(ctx, key, spec if spec is not None else {})
        _check_keys(ctx, key, spec, set(names))
        for i, nm in enumerate(names):
            if nm not in spec:
                if complete:
                    ctx.fail(f"{key}.{nm}", "a range [lo, hi] (missing key)", show_got=False)
                continue
            v = spec[nm]
            if not isinstance(v, list) or len(v) != 2:
                ctx.fail(f"{key}.{nm}", "a range [lo, hi]", v)
            a = _number(ctx, f"{key}.{nm}[0]", v[0])
            b = _number(ctx, f"{key}.{nm}[1]", v[1])
            if not a <= b:
                ctx.fail(f"{key}.{nm}", "a range [lo, hi] with lo <= hi", v)
            lo[..., i], hi[..., i] = a, b

    s, n, nu = len(modes), len(states), len(inputs)
    x_lo, x_hi = np.zeros((s, n)), np.zeros((s, n))
    u_lo, u_hi = np.zeros((s, nu)), np.zeros((s, nu))
    ranges("envelope.states", env.get("states"), states, x_lo, x_hi, True)
    ranges("envelope.inputs", env.get("inputs"), inputs, u_lo, u_hi, nu > 0)
    per_mode = _mapping(ctx, "envelope.modes", env.get("modes") or {})
    names = [m.name for m in modes]
    _check_keys(ctx, "envelope.modes", per_mode, set(names))
    for mname, spec in per_mode.items():
        q = names.index(mname)
        key = f"envelope.modes.{mname}"
        spec = _mapping(ctx, key, spec)
        _check_keys(ctx, key, spec, {"states", "inputs"})
        ranges(f"{key}.states", spec.get("states"), states, x_lo[q], x_hi[q], False)
        ranges(f"{key}.inputs", spec.get("inputs"), inputs, u_lo[q], u_hi[q], False)
    return Envelope(x_lo, x_hi, u_lo, u_hi)


def _parse_lpv(ctx: _Ctx, data: Mapping[str, Any]) -> tuple[LPVParameter, ...]:
    """The optional top-level ``lpv: {parameters: [{name, min, max, measured}]}``."""
    if "lpv" not in data:
        return ()
    lp = _mapping(ctx, "lpv", data["lpv"])
    _check_keys(ctx, "lpv", lp, {"parameters"})
    raw = lp.get("parameters")
    if not isinstance(raw, list) or not raw:
        ctx.fail("lpv.parameters", "a non-empty list of {name, min, max, measured}", raw)
        raise AssertionError  # unreachable: fail raises
    out = []
    for i, pr in enumerate(raw):
        key = f"lpv.parameters[{i}]"
        pr = _mapping(ctx, key, pr)
        _check_keys(ctx, key, pr, {"name", "min", "max", "measured"})
        for req in ("name", "min", "max", "measured"):
            if req not in pr:
                ctx.fail(f"{key}.{req}", "a value (missing key)", show_got=False)
        nm = pr["name"]
        if not isinstance(nm, str) or not _NAME_RE.match(nm):
            ctx.fail(f"{key}.name", "a name of letters, digits and '_'", nm)
        lo = _number(ctx, f"{key}.min", pr["min"])
        hi = _number(ctx, f"{key}.max", pr["max"])
        if hi < lo:
            ctx.fail(f"{key}.max", f"a number >= min ({lo})", pr["max"])
        if not isinstance(pr["measured"], bool):
            ctx.fail(f"{key}.measured", "true (a scheduling parameter) or false (an "
                     "uncertainty)", pr["measured"])
        out.append(LPVParameter(str(nm), lo, hi, bool(pr["measured"])))
    names = [p.name for p in out]
    if len(set(names)) != len(names):
        ctx.fail("lpv.parameters", "unique parameter names", names)
    return tuple(out)


def _stack3(ctx: _Ctx, key: str, spec: Mapping[str, Any], d: int, shape: tuple[int, int],
            dyn: str) -> np.ndarray | None:
    """A per-mode ``A_rho`` / ``B_rho``: a list of d matrices of ``shape``, or None."""
    k = key.rsplit(".", 1)[1]
    if k not in spec:
        return None
    if d == 0:
        ctx.fail(key, "no affine parts without a top-level 'lpv: {parameters: [...]}'",
                 show_got=False)
    if dyn != "linear":
        ctx.fail(key, "affine parts only in a linear mode", show_got=False)
    v = spec[k]
    if not isinstance(v, list) or len(v) != d:
        ctx.fail(key, f"a list of {d} {shape[0]}x{shape[1]} matrices (one per lpv parameter)",
                 _Got(f"{len(v)} entries") if isinstance(v, list) else v)
    return np.array([_matrix(ctx, f"{key}[{j}]", m, shape) for j, m in enumerate(v)])


def _canonical(name: str, ts: float, states: Sequence[str], inputs: Sequence[str],
               outputs: Sequence[str], dists: Sequence[str], wbar: np.ndarray,
               vbar: np.ndarray, modes: Sequence[Mode], guards: Sequence[Guard],
               faults: Sequence[FaultChannel], q0: int, x0: np.ndarray,
               switching: str | None = None,
               lpv: Sequence[LPVParameter] | None = None) -> str:
    """Canonical JSON of everything that defines the plant (not its description or layout).

    The optional keys (``switching``, ``lpv``, a mode's ``A_rho``/``B_rho``, a process
    fault's ``E``/per-mode ``F``) are included only when given, so older plant files keep
    their SHA-256.
    """

    def arr(a: np.ndarray | None) -> Any:
        return None if a is None else np.asarray(a, dtype=float).tolist()

    def mode_doc(m: Mode) -> dict[str, Any]:
        out = {"name": m.name, "dynamics": m.dynamics, "time": m.time, "A": arr(m.A),
               "B": arr(m.B), "C": arr(m.C), "D": arr(m.D), "E": arr(m.E),
               "offset": arr(m.offset), "uncertainty": arr(m.uncertainty), "model": m.model,
               "params": dict(sorted(m.params.items()))}
        if m.A_rho is not None:
            out["A_rho"] = arr(m.A_rho)
        if m.B_rho is not None:
            out["B_rho"] = arr(m.B_rho)
        return out

    def fault_doc(f: FaultChannel) -> dict[str, Any]:
        out = {"name": f.name, "kind": f.kind, "index": f.index, "F": arr(f.F),
               "parameter": f.parameter}
        if f.F_modes is not None:
            out["F_modes"] = [arr(v) for v in f.F_modes]
        if f.E is not None:
            out["E_out"] = arr(f.E)
        return out

    doc: dict[str, Any] = {
        "format_version": 1,
        "name": name,
        "sample_time": ts,
        "states": list(states),
        "inputs": list(inputs),
        "outputs": list(outputs),
        "disturbances": list(dists),
        "disturbance_bound": arr(wbar),
        "measurement_noise": arr(vbar),
        "modes": [mode_doc(m) for m in modes],
        "guards": [
            {"name": g.name, "from": g.source, "to": g.target, "kind": g.kind,
             "when": [[c.var, c.op, c.value] for c in g.conditions]}
            for g in guards
        ],
        "faults": [fault_doc(f) for f in faults],
        "initial": {"mode": q0, "state": arr(x0)},
    }
    if switching is not None:
        doc["switching"] = switching
    if lpv is not None:
        doc["lpv"] = [{"name": p.name, "min": p.min, "max": p.max, "measured": p.measured}
                      for p in lpv]
    return json.dumps(doc, sort_keys=True, separators=(",", ":"))
