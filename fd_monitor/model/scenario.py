"""Scenarios: what a simulation feeds the plant (inputs, faults, noise) and for how long.

A scenario is a small YAML file (``config/scenarios/``)::

    name: three_tank_bias_h1
    description: free text
    system: three_tank            # a shipped plant name or a path (relative to this file)
    duration: 400.0               # s
    seed: 0                       # default seed (the command line may override it)
    initial: {mode: closed_low, state: [0.4, 0.2, 0.3]}   # optional, overrides the plant's
    noise: {scale: 1.0, distribution: uniform}        # w and v; uniform | extreme (vertices)
    uncertainty: {scale: 1.0, distribution: uniform}  # eta
    inputs:                       # one entry per plant input
      q1: {pi: {output: h1, reference: {steps: [[0, 0.4], [200, 0.55]]},
                kp: 2.0e-3, ki: 2.0e-5, min: 0.0, max: 1.5e-4}}
      q2: 3.0e-5                  # a constant
      v13: {steps: [[0, 0.0], [300, 1.0]]}
    faults:
      - {channel: bias_h1, profile: abrupt, time: 150.0, magnitude: 0.01}
      - {channel: bias_h2, profile: incipient, time: 150.0, magnitude: 0.01, rate: 0.05}
      - {channel: pump1, profile: abrupt, time: 80.0, magnitude: 0.3, relative: true}

Input profiles: a number; ``{constant: c}``; ``{steps: [[t, v], ...]}`` (value of the last
step at or before t; 0 before the first); ``{ramp: {start, end, from, to}}``;
``{sine: {amplitude, period, offset, phase}}``; ``{pi: {output, reference, kp, ki, min, max}}``
(a PI level controller on a measured output with conditional-integration anti-windup; the
reference is itself a profile).

LPV / uncertain plants (``A_rho``, ``B_rho``) need the scheduling signal rho(t); any plant may
record one as a side signal (``rho.<name>`` on ``/plant/truth``)::

    scheduling:                   # one profile per lpv parameter of the plant ...
      rho1: {sine: {amplitude: 1.0, period: 1.0}}
      rho2: {steps: [[0, 0.2], [5, -0.4]]}
    scheduling: {map: three_tank_sqrt, names: [rho1, rho2, rho3],   # ... or a function of
                 params: {min_difference: 1.0e-3}}                  # the true state (7.19)

Profiles must stay inside the plant's parameter box (``lpv.parameters`` min/max); a map is
one of :data:`fd_monitor.model.nonlinear.SCHEDULING_MAPS`, evaluated on the true state
(inside each sample, too, for a plant that depends on it); ``names`` default to the plant's
lpv parameters.

Switching signal: by default the plant's guards. ``switching: {schedule: [[t, mode], ...]}``
imposes the mode instead (the mode of the last entry at or before t; the initial mode before
the first), e.g. for a plant with arbitrary switching (Farhat & Koenig)::

    switching: {schedule: [[0, mode1], [4.0, mode2], [9.5, mode1]]}
    switching: {random: {min_dwell: 0.5, max_dwell: 4.0}}   # arbitrary switching, per run

``random`` draws, per run and from the run's seed (a generator of its own, so the noise of
the run is unchanged), dwell times uniform in [min_dwell, max_dwell] s and at each switch one
of the other modes uniformly.

Fault channels the plant file cannot carry without changing its identity (the Farhat &
Koenig fault lives in its design file) are declared in the scenario, in the plant-file
syntax, and added after the plant's own channels::

    fault_channels:
      - {name: f, kind: process, F: {mode1: [0.06, 1.2, 0.18], mode2: [0.07, 1.4, 0.49]},
         E: [0.01, 0.01]}

Fault profiles ``beta(k - K0)``: ``abrupt`` (Heracleous et al. eq. 4; magnitude from sample
``K0 = round(time / Ts)`` on) and ``incipient`` (thesis eq. 1.4: ``magnitude (1 -
exp(-rate (t - t_f)))``). An actuator fault with ``relative: true`` is the loss of
effectiveness ``f = -beta u`` (thesis Sec. 1.2); otherwise it adds ``beta`` to the input.

Why one module of ~650 lines: the scenario schema (a 60-line docstring), its value types and
one short parser per key sharing one ``Checker``, as in ``plant_sections.py``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.model.errors import ScenarioError, SystemFileError
from fd_monitor.model.nonlinear import SCHEDULING_MAPS
from fd_monitor.model.paths import find_config_file
from fd_monitor.model.plant_schema import MAX_MAGNITUDE
from fd_monitor.model.system import System, load_system, parse_system
from fd_monitor.model.validate import Checker
from fd_monitor.model.yaml_io import read_yaml, require_memory

__all__ = ["FaultEvent", "Profile", "PIController", "Scenario", "Scheduling", "check_horizon",
           "load_scenario", "parse_scenario"]

_DISTRIBUTIONS = ("uniform", "extreme")


@dataclass(frozen=True)
class Profile:
    """A time profile of one scalar, s -> value.

    Attributes
    ----------
    kind : str
        ``constant``, ``steps``, ``ramp`` or ``sine``.
    data : tuple of float
        Parameters: (c,), (t0, v0, t1, v1, ...), (start, end, from, to),
        (amplitude, period, offset, phase).
    """

    kind: str
    data: tuple[float, ...]

    def value(self, t: float) -> float:
        """The profile's value at time ``t`` (s)."""
        d = self.data
        if self.kind == "constant":
            return d[0]
        if self.kind == "steps":
            v = 0.0
            for i in range(0, len(d), 2):
                if t >= d[i]:
                    v = d[i + 1]
            return v
        if self.kind == "ramp":
            start, end, v0, v1 = d
            if t <= start:
                return v0
            if t >= end:
                return v1
            return v0 + (v1 - v0) * (t - start) / (end - start)
        amplitude, period, offset, phase = d
        return offset + amplitude * math.sin(2.0 * math.pi * t / period + phase)

    def bounds(self) -> tuple[float, float]:
        """(min, max) of the profile over all t >= 0."""
        d = self.data
        if self.kind == "constant":
            return d[0], d[0]
        if self.kind == "steps":
            vals = list(d[1::2]) + ([0.0] if d[0] > 0 else [])
            return min(vals), max(vals)
        if self.kind == "ramp":
            return min(d[2], d[3]), max(d[2], d[3])
        return d[2] - abs(d[0]), d[2] + abs(d[0])


@dataclass(frozen=True)
class Scheduling:
    """The scheduling signal rho of a scenario: per parameter a profile of time, or a named
    map of the true state.

    Attributes
    ----------
    names : tuple of str
        Parameter names (d).
    profiles : tuple of Profile
        One per name (empty with a map).
    state_map : str or None
        A key of :data:`fd_monitor.model.nonlinear.SCHEDULING_MAPS`.
    params : dict
        Parameters of the map.
    """

    names: tuple[str, ...]
    profiles: tuple[Profile, ...] = ()
    state_map: str | None = None
    params: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class PIController:
    """A PI controller ``u = clip(kp e + ki int e, lo, hi)``, ``e = reference(t) - y[output]``.

    Attributes
    ----------
    output : int
        Index of the measured output it regulates.
    reference : Profile
        Set point, in the output's unit.
    kp, ki : float
        Gains (input unit per output unit, and per output unit and second).
    lo, hi : float
        Saturation of the input.
    """

    output: int
    reference: Profile
    kp: float
    ki: float
    lo: float
    hi: float


@dataclass(frozen=True)
class FaultEvent:
    """One injected fault.

    Attributes
    ----------
    channel : int
        Index of the plant's fault channel.
    profile : str
        ``abrupt`` or ``incipient``.
    time : float
        Onset time t_f, s.
    magnitude : float
        delta, in the channel's unit (a fraction for relative actuator faults).
    rate : float
        alpha of an incipient fault, 1/s.
    relative : bool
        Actuator loss of effectiveness (``f = -beta u``).
    """

    channel: int
    profile: str
    time: float
    magnitude: float
    rate: float = 0.0
    relative: bool = False

    def beta(self, t: np.ndarray | float, dt: float) -> np.ndarray:
        """``beta(t - t_f)`` on sample times ``t`` (s); the onset sample is round(t_f / dt)."""
        t = np.asarray(t, dtype=float)
        k = np.rint(t / dt)
        k0 = round(self.time / dt)
        on = k >= k0
        if self.profile == "abrupt":
            return np.where(on, self.magnitude, 0.0)
        tau = (k - k0) * dt
        return np.where(on, self.magnitude * (1.0 - np.exp(-self.rate * np.maximum(tau, 0.0))),
                        0.0)


@dataclass(frozen=True)
class Scenario:
    """A validated scenario for one plant.

    Attributes
    ----------
    name : str
    description : str
    system : System
    duration : float
        s; the run has ``n_samples = round(duration / Ts)`` samples (k = 0 .. n_samples-1).
    seed : int
    initial_mode : int
    initial_state : numpy.ndarray
        (n,)
    noise_scale, uncertainty_scale : float
        Multipliers of the plant's bounds (1 = the bounds; > 1 breaks the guarantees).
    noise_distribution, uncertainty_distribution : str
        ``uniform`` in [-bound, bound], or ``extreme`` (+-bound).
    inputs : tuple
        Per input, a Profile or a PIController.
    faults : tuple of FaultEvent
    source : str
    scheduling : Scheduling or None
        rho(t) (``scheduling`` key).
    switching : tuple of (float, int) or None
        Imposed mode schedule ``(time s, mode index)`` (``switching.schedule``); None: guards.
    switching_dwell : tuple of float or None
        ``(min_dwell, max_dwell)`` s of random switching (``switching.random``).
    """

    name: str
    description: str
    system: System
    duration: float
    seed: int
    initial_mode: int
    initial_state: np.ndarray
    noise_scale: float
    noise_distribution: str
    uncertainty_scale: float
    uncertainty_distribution: str
    inputs: tuple[Profile | PIController, ...]
    faults: tuple[FaultEvent, ...] = field(default_factory=tuple)
    source: str = "<dict>"
    scheduling: Scheduling | None = None
    switching: tuple[tuple[float, int], ...] | None = None
    switching_dwell: tuple[float, float] | None = None

    @property
    def rho_names(self) -> tuple[str, ...]:
        """Names of the scheduling parameters (empty without ``scheduling``)."""
        return self.scheduling.names if self.scheduling is not None else ()

    @property
    def n_samples(self) -> int:
        """Number of samples of a run."""
        return round(self.duration / self.system.sample_time)


def load_scenario(source: str | Path, system: System | None = None) -> Scenario:
    """Load and validate a scenario file (a path, or a name in ``config/scenarios/``).

    Parameters
    ----------
    source : str or pathlib.Path
    system : System, optional
        Use this plant instead of the one the file names.
    """
    path = find_config_file(source, "scenarios", ScenarioError, what="scenario")
    data = read_yaml(path, ScenarioError)
    return parse_scenario(data, str(path), system)


def check_horizon(system: System, duration: float, what: str,
                  error: type[Exception] = ScenarioError, runs: int = 1) -> int:
    """Samples of a run of ``duration`` s; refuse, before allocating, a horizon whose
    per-sample arrays would not fit in memory. Returns the sample count.

    Estimate: per sample and run, the simulated record (mode, state, inputs, outputs,
    faults) and about three times as much again for the monitor's per-sample outputs
    (residuals, thresholds, estimates), float64."""
    n = duration / system.sample_time
    width = 4 * (system.n + system.nu + system.ny + len(system.faults) + 1)
    require_memory(8.0 * width * n * max(runs, 1),
                   f"{what} {duration:g} s at {system.sample_time:g} s per sample "
                   f"({n:.3g} samples)", error)
    return round(n)


def _checker(origin: str) -> Checker:
    """The :class:`~fd_monitor.model.validate.Checker` of a scenario file."""
    return Checker(origin, ScenarioError, clip=None)


def _profile(ck: Checker, key: str, v: Any) -> Profile:
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return Profile("constant", (ck.number(key, v),))
    if not isinstance(v, Mapping) or len(v) != 1:
        ck.fail(key, "a number or one of {constant, steps, ramp, sine}", v)
    (kind, spec), = v.items()
    if kind == "constant":
        return Profile("constant", (ck.number(f"{key}.constant", spec),))
    if kind == "steps":
        if not isinstance(spec, list) or not spec:
            ck.fail(f"{key}.steps", "a list of [time, value] pairs", spec)
        flat: list[float] = []
        last = -math.inf
        for i, pair in enumerate(spec):
            if not isinstance(pair, list) or len(pair) != 2:
                ck.fail(f"{key}.steps[{i}]", "a [time, value] pair", pair)
            t = ck.number(f"{key}.steps[{i}][0]", pair[0])
            if t < last:
                ck.fail(f"{key}.steps[{i}][0]", "times in increasing order", pair[0])
            last = t
            flat += [t, ck.number(f"{key}.steps[{i}][1]", pair[1])]
        return Profile("steps", tuple(flat))
    if kind == "ramp":
        if not isinstance(spec, Mapping) or set(spec) != {"start", "end", "from", "to"}:
            ck.fail(f"{key}.ramp", "{start, end, from, to}", spec)
        vals = [ck.number(f"{key}.ramp.{k}", spec[k]) for k in ("start", "end", "from", "to")]
        if vals[1] <= vals[0]:
            ck.fail(f"{key}.ramp.end", "end > start", spec["end"])
        return Profile("ramp", tuple(vals))
    if kind == "sine":
        if not isinstance(spec, Mapping) or not {"amplitude", "period"} <= set(spec):
            ck.fail(f"{key}.sine", "{amplitude, period[, offset, phase]}", spec)
        return Profile("sine", (
            ck.number(f"{key}.sine.amplitude", spec["amplitude"]),
            ck.number(f"{key}.sine.period", spec["period"], positive=True),
            ck.number(f"{key}.sine.offset", spec.get("offset", 0.0)),
            ck.number(f"{key}.sine.phase", spec.get("phase", 0.0))))
    ck.fail(key, "one of {constant, steps, ramp, sine, pi}", kind)


def parse_scenario(data: Any, origin: str = "<dict>", system: System | None = None) -> Scenario:
    """Validate parsed YAML ``data`` into a :class:`Scenario` (see the module docstring)."""
    ck = _checker(origin)
    if not isinstance(data, Mapping):
        ck.fail("(top level)", "a mapping of scenario keys", type(data).__name__)
    ck.keys("", data, _TOP_KEYS)
    system = _plant(ck, data, system)
    name = str(data.get("name", Path(origin).stem))
    duration, seed = _duration_and_seed(ck, data, system)
    q0, x0 = _initial(ck, data, system)
    nscale, ndist = _noise_spec(ck, data, "noise")
    uscale, udist = _noise_spec(ck, data, "uncertainty")
    inputs = _inputs(ck, data, system)
    faults = _faults(ck, data, system, duration)
    description = data.get("description", "")
    if not isinstance(description, str):
        ck.fail("description", "a string", type(description).__name__)
    scheduling = _scheduling(ck, system, data.get("scheduling"), np.asarray(x0, float))
    switching, dwell = _switching(ck, system, data.get("switching"))
    return Scenario(name, description, system, duration, seed, q0,
                    np.asarray(x0, dtype=float), nscale, ndist, uscale, udist, inputs,
                    faults, origin, scheduling, switching, dwell)


_TOP_KEYS = {"name", "description", "system", "duration", "seed", "initial", "noise",
             "uncertainty", "inputs", "faults", "scheduling", "switching", "fault_channels"}


def _plant(ck: Checker, data: Mapping[str, Any], system: System | None) -> System:
    """The plant ``system`` names (relative to the scenario's folder first) unless one is
    given, with the scenario's ``fault_channels`` added."""
    if system is None:
        if "system" not in data:
            ck.fail("system", "a plant name or path (missing key)", show=False)
        ref = str(data["system"])
        rel = Path(ck.origin).parent / ref
        try:
            system = load_system(rel if rel.is_file() else ref)
        except SystemFileError as exc:
            raise ScenarioError(f"{ck.origin}: system: {exc}") from None
    if data.get("fault_channels"):
        system = _with_fault_channels(ck, system, data["fault_channels"])
    return system


def _duration_and_seed(ck: Checker, data: Mapping[str, Any], system: System
                       ) -> tuple[float, int]:
    """``duration`` (s, at least one sample, within memory) and ``seed`` (default 0)."""
    if "duration" not in data:
        ck.fail("duration", "the run length in s (missing key)", show=False)
    duration = ck.number("duration", data["duration"], positive=True)
    if duration < system.sample_time:
        ck.fail("duration", f"at least one sample ({system.sample_time} s)", duration)
    check_horizon(system, duration, f"{ck.origin}: duration", ScenarioError)
    seed = ck.integer("seed", data.get("seed", 0))
    return duration, seed


def _initial(ck: Checker, data: Mapping[str, Any], system: System) -> tuple[int, np.ndarray]:
    """``initial: {mode, state}``, each defaulting to the plant's."""
    q0, x0 = system.initial_mode, system.initial_state
    if "initial" in data:
        init = data["initial"]
        if not isinstance(init, Mapping):
            ck.fail("initial", "{mode, state}", init)
        if "mode" in init:
            if init["mode"] not in system.mode_names:
                ck.fail("initial.mode", f"one of {list(system.mode_names)}", init["mode"])
            q0 = system.mode_index(init["mode"])
        if "state" in init:
            st = init["state"]
            if not isinstance(st, list) or len(st) != system.n:
                ck.fail("initial.state", f"a list of {system.n} numbers", st)
            x0 = np.array([ck.number(f"initial.state[{i}]", v) for i, v in enumerate(st)])
    return q0, x0


def _noise_spec(ck: Checker, data: Mapping[str, Any], key: str) -> tuple[float, str]:
    """``noise`` / ``uncertainty``: ``{scale, distribution}``."""
    spec = data.get(key, {}) or {}
    if not isinstance(spec, Mapping) or not set(spec) <= {"scale", "distribution"}:
        ck.fail(key, "{scale, distribution}", spec)
    scale = ck.number(f"{key}.scale", spec.get("scale", 1.0), nonneg=True)
    dist = spec.get("distribution", "uniform")
    if dist not in _DISTRIBUTIONS:
        ck.fail(f"{key}.distribution", f"one of {list(_DISTRIBUTIONS)}", dist)
    return scale, str(dist)


def _inputs(ck: Checker, data: Mapping[str, Any], system: System
            ) -> tuple[Profile | PIController, ...]:
    """``inputs``: a profile or a PI controller for every plant input."""
    raw_inputs = data.get("inputs", {}) or {}
    if not isinstance(raw_inputs, Mapping):
        ck.fail("inputs", "a mapping of input names to profiles", raw_inputs)
    for k in raw_inputs:
        if k not in system.inputs:
            ck.fail(f"inputs.{k}", f"an input of plant {system.name!r}: "
                    f"{list(system.inputs)}", show=False)
    inputs: list[Profile | PIController] = []
    for name_u in system.inputs:
        key = f"inputs.{name_u}"
        if name_u not in raw_inputs:
            ck.fail(key, "a profile for every plant input (missing input)", show=False)
        spec = raw_inputs[name_u]
        if isinstance(spec, Mapping) and "pi" in spec:
            inputs.append(_pi_controller(ck, f"{key}.pi", spec["pi"], system))
        else:
            prof = _profile(ck, key, spec)
            _within(ck, key, prof, system.input_limits[system.inputs.index(name_u)],
                    f"the limits of input {name_u}")
            inputs.append(prof)
    return tuple(inputs)


def _within(ck: Checker, key: str, prof: Profile, limits: Any, what: str) -> None:
    """Refuse a profile whose values leave ``limits`` ([low, high], the plant file's physical
    range of the channel; +-MAX_MAGNITUDE where it declares none)."""
    lo, hi = (float(v) for v in limits)
    p = prof.data
    values: Any = ((p[2] - abs(p[0]), p[2] + abs(p[0])) if prof.kind == "sine" else
                   {"constant": p[:1], "steps": p[1::2], "ramp": p[2:4]}.get(prof.kind, ()))
    for v in values:
        if not lo <= v <= hi:
            ck.fail(key, f"values inside {what} [{lo:g}, {hi:g}] (a value outside is no "
                    f"input the plant can take)", v)


def _pi_controller(ck: Checker, key: str, pi: Any, system: System) -> PIController:
    """``{pi: {output, reference, kp, ki, min, max}}``."""
    need = {"output", "reference", "kp", "ki", "min", "max"}
    if not isinstance(pi, Mapping) or set(pi) != need:
        ck.fail(key, f"the keys {sorted(need)}", pi)
    if pi["output"] not in system.outputs:
        ck.fail(f"{key}.output", f"one of {list(system.outputs)}", pi["output"])
    lo = ck.number(f"{key}.min", pi["min"])
    hi = ck.number(f"{key}.max", pi["max"])
    if hi <= lo:
        ck.fail(f"{key}.max", "max > min", pi["max"])
    return PIController(system.outputs.index(pi["output"]),
                        _profile(ck, f"{key}.reference", pi["reference"]),
                        ck.number(f"{key}.kp", pi["kp"]), ck.number(f"{key}.ki", pi["ki"]),
                        lo, hi)


def _faults(ck: Checker, data: Mapping[str, Any], system: System, duration: float
            ) -> tuple[FaultEvent, ...]:
    """``faults``: the fault events of the run."""
    raw_faults = data.get("faults", []) or []
    if not isinstance(raw_faults, list):
        ck.fail("faults", "a list of faults", raw_faults)
    return tuple(_fault_event(ck, f"faults[{i}]", f, system, duration)
                 for i, f in enumerate(raw_faults))


def _fault_event(ck: Checker, key: str, f: Any, system: System, duration: float
                 ) -> FaultEvent:
    """One entry ``faults[i]``: ``{channel, profile, time, magnitude[, rate, relative]}``."""
    names = [fc.name for fc in system.faults]
    if not isinstance(f, Mapping):
        ck.fail(key, "{channel, profile, time, magnitude[, rate, relative]}", f)
    extra = set(f) - {"channel", "profile", "time", "magnitude", "rate", "relative"}
    if extra:
        ck.fail(f"{key}.{sorted(extra)[0]}", "channel, profile, time, magnitude, "
                "rate or relative (unknown key)", show=False)
    ck.require(key, f, ("channel", "profile", "time", "magnitude"))
    if f["channel"] not in names:
        ck.fail(f"{key}.channel", f"a fault channel of plant {system.name!r}: {names}",
                f["channel"])
    ch = names.index(f["channel"])
    prof = f["profile"]
    if prof not in ("abrupt", "incipient"):
        ck.fail(f"{key}.profile", "'abrupt' or 'incipient'", prof)
    rate = 0.0
    if prof == "incipient":
        if "rate" not in f:
            ck.fail(f"{key}.rate", "the decay rate alpha > 0 of an incipient fault "
                    "(thesis eq. 1.4; missing key)", show=False)
        rate = ck.number(f"{key}.rate", f["rate"], positive=True)
    relative = ck.boolean(f"{key}.relative", f.get("relative", False))
    if relative and system.faults[ch].kind != "actuator":
        ck.fail(f"{key}.relative", "relative faults only on actuator channels", show=False)
    t_f = ck.number(f"{key}.time", f["time"], nonneg=True)
    if round(t_f / system.sample_time) >= round(duration / system.sample_time):
        ck.fail(f"{key}.time", f"a time inside the run [0, {duration:g}) s (a fault "
                f"after the end would never be applied)", f["time"])
    mag = ck.number(f"{key}.magnitude", f["magnitude"])
    fc = system.faults[ch]
    span = {"sensor_bias": system.output_limits, "actuator": system.input_limits}.get(fc.kind)
    # physical range: a sensor bias or an absolute actuator fault within the channel's span,
    # a relative one within +-10 x the input, anything else within MAX_MAGNITUDE
    bound = (10.0 if relative else
             float(span[fc.index, 1] - span[fc.index, 0]) if span is not None
             and fc.index >= 0 else MAX_MAGNITUDE)
    if not abs(mag) <= min(bound, MAX_MAGNITUDE):
        ck.fail(f"{key}.magnitude", f"a magnitude of at most {min(bound, MAX_MAGNITUDE):g} "
                f"(the physical range of {fc.kind} channel {fc.name})", f["magnitude"])
    return FaultEvent(ch, str(prof), t_f, mag, rate, relative)


def _with_fault_channels(ck: Checker, system: System, raw: Any) -> System:
    """The plant with the scenario's ``fault_channels`` appended (plant-file syntax)."""
    if not isinstance(raw, list):
        ck.fail("fault_channels", "a list of fault channels (plant-file syntax)", raw)
    if not Path(system.source).is_file():
        ck.fail("fault_channels", "a plant read from a file", system.source)
    doc = dict(read_yaml(Path(system.source)))
    doc["faults"] = list(doc.get("faults") or []) + list(raw)
    try:
        # The plant keeps its identity (what a gain file is bound to): the added channels
        # exist in the simulation only.
        return replace(parse_system(doc, system.source), canonical=system.canonical,
                       sha256=system.sha256)
    except SystemFileError as exc:
        # Renumber the plant's message: faults[i] of the merged list is fault_channels[j].
        n0 = len(system.faults)
        msg = str(exc).split(": ", 1)[-1]
        m = re.match(r"faults\[(\d+)\](.*)", msg)
        if m and int(m.group(1)) >= n0:
            msg = f"fault_channels[{int(m.group(1)) - n0}]{m.group(2)}"
        else:
            msg = f"fault_channels: {msg}"
        raise ScenarioError(f"{ck.origin}: {msg}") from None


def _scheduling(ck: Checker, system: System, raw: Any, x0: np.ndarray) -> Scheduling | None:
    lpv = {p.name: p for p in system.lpv}
    needs = any(m.A_rho is not None or m.B_rho is not None for m in system.modes)
    if raw is None:
        if needs:
            ck.fail("scheduling", f"rho(t) for the lpv parameters {list(lpv)} of plant "
                  f"{system.name!r} (missing key)", show=False)
        return None
    if not isinstance(raw, Mapping) or not raw:
        ck.fail("scheduling", "a profile per parameter, or {map, names, params}", raw)
    if "map" in raw:
        extra = set(raw) - {"map", "names", "params"}
        if extra:
            ck.fail(f"scheduling.{sorted(extra)[0]}", "map, names or params (unknown key)",
                  show=False)
        if raw["map"] not in SCHEDULING_MAPS:
            ck.fail("scheduling.map", f"one of {sorted(SCHEDULING_MAPS)}", raw["map"])
        params = raw.get("params") or {}
        if not isinstance(params, Mapping):
            ck.fail("scheduling.params", "a mapping", params)
        try:
            d = int(np.asarray(SCHEDULING_MAPS[raw["map"]](x0, dict(params))).size)
        except (IndexError, ValueError, TypeError) as exc:
            ck.fail("scheduling.map", f"a map of the {system.n} states of plant "
                  f"{system.name!r} ({exc})", raw["map"])
        names = raw.get("names", list(lpv) if lpv else [f"rho{i + 1}" for i in range(d)])
        if (not isinstance(names, list) or len(names) != d
                or not all(isinstance(n, str) and n for n in names)):
            ck.fail("scheduling.names", f"{d} parameter names (the map gives {d})", names)
        if lpv and list(names) != list(lpv):
            ck.fail("scheduling.names", f"the plant's lpv parameters {list(lpv)}", names)
        return Scheduling(tuple(names), (), str(raw["map"]), dict(params))
    profiles = []
    if lpv and set(raw) != set(lpv):
        missing = sorted(set(lpv) - set(raw))
        key = f"scheduling.{missing[0]}" if missing else \
            f"scheduling.{sorted(set(raw) - set(lpv))[0]}"
        ck.fail(key, f"a profile for each lpv parameter {list(lpv)} of plant "
              f"{system.name!r} and no other", show=False)
    names = list(lpv) if lpv else [str(k) for k in raw]
    for nm in names:
        prof = _profile(ck, f"scheduling.{nm}", raw[nm])
        if nm in lpv:
            lo, hi = prof.bounds()
            if lo < lpv[nm].min or hi > lpv[nm].max:
                ck.fail(f"scheduling.{nm}", f"values inside the parameter box "
                      f"[{lpv[nm].min:g}, {lpv[nm].max:g}] (the profile spans "
                      f"[{lo:g}, {hi:g}])", show=False)
        profiles.append(prof)
    return Scheduling(tuple(names), tuple(profiles))


def _switching(ck: Checker, system: System, raw: Any
               ) -> tuple[tuple[tuple[float, int], ...] | None, tuple[float, float] | None]:
    if raw is None:
        return None, None
    if not isinstance(raw, Mapping) or len(raw) != 1 or set(raw) > {"schedule", "random"}:
        ck.fail("switching", "{schedule: [[time, mode], ...]} or {random: {min_dwell, "
              "max_dwell}}", raw)
    if "random" in raw:
        rnd = raw["random"]
        if not isinstance(rnd, Mapping) or set(rnd) != {"min_dwell", "max_dwell"}:
            ck.fail("switching.random", "{min_dwell, max_dwell} (s)", rnd)
        lo = ck.number("switching.random.min_dwell", rnd["min_dwell"], positive=True)
        hi = ck.number("switching.random.max_dwell", rnd["max_dwell"], positive=True)
        if lo < system.sample_time:
            ck.fail("switching.random.min_dwell", f"at least one sample "
                  f"({system.sample_time:g} s)", lo)
        if hi < lo:
            ck.fail("switching.random.max_dwell", "max_dwell >= min_dwell", hi)
        if len(system.modes) < 2:
            ck.fail("switching.random", f"a plant with two modes or more ({system.name!r} "
                  f"has one)", show=False)
        return None, (lo, hi)
    sched = raw["schedule"]
    if not isinstance(sched, list) or not sched:
        ck.fail("switching.schedule", "a non-empty list of [time, mode] pairs", sched)
    out: list[tuple[float, int]] = []
    last = -math.inf
    for i, pair in enumerate(sched):
        key = f"switching.schedule[{i}]"
        if not isinstance(pair, list) or len(pair) != 2:
            ck.fail(key, "a [time, mode] pair", pair)
        t = ck.number(f"{key}[0]", pair[0], nonneg=True)
        if t < last:
            ck.fail(f"{key}[0]", "times in increasing order", pair[0])
        last = t
        if pair[1] not in system.mode_names:
            ck.fail(f"{key}[1]", f"one of the modes {list(system.mode_names)}", pair[1])
        out.append((t, system.mode_index(pair[1])))
    return tuple(out), None
