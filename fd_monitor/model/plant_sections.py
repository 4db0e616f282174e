"""Reading a plant file's sections: one parser per top-level key (schema:
:mod:`fd_monitor.model.plant_schema`), and the plant's canonical form (its identity).

Every parser takes the file's :class:`~fd_monitor.model.validate.Checker`, so every error
names the file, the key path and what was expected.

Why one module of ~570 lines: one short parser per top-level key of the plant file (15
sections), sharing one ``Checker`` and the canonical form, which must see every section.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

import numpy as np

from fd_monitor.model.nonlinear import get_model
from fd_monitor.model.plant_parts import (
    Condition,
    Envelope,
    FaultChannel,
    Guard,
    LPVParameter,
    Mode,
)
from fd_monitor.model.plant_schema import (
    FAULT_KINDS,
    GUARD_OPS,
    MAX_MAGNITUDE,
    MODE_KEYS,
    SAMPLE_TIME_RANGE,
    SUPPORTED_FORMAT_VERSIONS,
    TIME_KINDS,
)
from fd_monitor.model.validate import NAME_RE, Checker, Got

__all__ = ["Channels", "Header", "canonical_form", "parse_bounds", "parse_channels",
           "parse_envelope", "parse_faults", "parse_guards", "parse_header", "parse_initial",
           "parse_limits", "parse_lpv", "parse_modes", "parse_shared", "parse_switching",
           "parse_units"]


class _HasName(Protocol):
    @property
    def name(self) -> str: ...


_Named = TypeVar("_Named", bound=_HasName)


@dataclass(frozen=True)
class Header:
    """The plant's ``name``, ``description``, default ``time`` and ``sample_time`` (s)."""

    name: str
    description: str
    time: str
    sample_time: float


@dataclass(frozen=True)
class Channels:
    """Names of the states, inputs, outputs and disturbances (lengths n, nu, ny, nw)."""

    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    disturbances: tuple[str, ...]


def parse_header(ck: Checker, data: Mapping[str, Any]) -> Header:
    """``format_version``, ``name``, ``description``, ``time`` and ``sample_time``."""
    version = data.get("format_version", 1)
    if isinstance(version, bool) or version not in SUPPORTED_FORMAT_VERSIONS:
        ck.fail("format_version", f"one of {SUPPORTED_FORMAT_VERSIONS}", version)
    if "name" not in data:
        ck.fail("name", "the plant's name (missing key)", show=False)
    name = ck.name("name", data["name"])
    description = data.get("description", "")
    if not isinstance(description, str):
        ck.fail("description", "a string", Got(type(description).__name__))
    default_time = data.get("time", "continuous")
    if default_time not in TIME_KINDS:
        ck.fail("time", "'continuous' or 'discrete'", default_time)
    if "sample_time" not in data:
        ck.fail("sample_time", "the sample time in s (missing key)", show=False)
    ts = ck.number("sample_time", data["sample_time"], positive=True)
    if not SAMPLE_TIME_RANGE[0] <= ts <= SAMPLE_TIME_RANGE[1]:
        ck.fail("sample_time", f"a sample time in [{SAMPLE_TIME_RANGE[0]:g}, "
                f"{SAMPLE_TIME_RANGE[1]:g}] s", data["sample_time"])
    return Header(name, description, str(default_time), ts)


def parse_channels(ck: Checker, data: Mapping[str, Any]) -> Channels:
    """``states`` and ``outputs`` (at least one each), ``inputs`` and ``disturbances``."""

    def names(key: str, required: bool) -> tuple[str, ...]:
        if key not in data:
            if required:
                ck.fail(key, "a list of names (missing key)", show=False)
            return ()
        return ck.names(key, data[key])

    states = names("states", required=True)
    if not states:
        ck.fail("states", "at least one state", [])
    inputs = names("inputs", required=False)
    outputs = names("outputs", required=True)
    if not outputs:
        ck.fail("outputs", "at least one output", [])
    return Channels(states, inputs, outputs, names("disturbances", required=False))


def parse_bounds(ck: Checker, data: Mapping[str, Any], ch: Channels
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``bounds``: (nw,) disturbance bounds (ones when there are none) and (ny,)
    measurement-noise bounds (zeros by default)."""
    nw, ny = len(ch.disturbances), len(ch.outputs)
    bounds = ck.mapping("bounds", data.get("bounds", {}) or {},
                        {"disturbance", "measurement_noise"})
    wbar = (ck.vector("bounds.disturbance", bounds["disturbance"], nw, nonneg=True)
            if "disturbance" in bounds else np.ones(nw))
    if nw and "disturbance" not in bounds:
        ck.fail("bounds.disturbance", f"a bound for each of the {nw} disturbances (missing key)",
                show=False)
    vbar = (ck.vector("bounds.measurement_noise", bounds["measurement_noise"], ny, nonneg=True)
            if "measurement_noise" in bounds else np.zeros(ny))
    return wbar, vbar


def parse_shared(ck: Checker, data: Mapping[str, Any]) -> Mapping[str, Any]:
    """``shared``: the matrices of every mode that omits them."""
    return ck.mapping("shared", data.get("shared", {}) or {}, {"B", "C", "D", "E", "uncertainty"})


def parse_modes(ck: Checker, data: Mapping[str, Any], ch: Channels, default_time: str,
                shared: Mapping[str, Any], d: int) -> tuple[Mode, ...]:
    """``modes`` (at least one), with the defaults of ``shared``; ``d`` LPV parameters."""
    if "modes" not in data:
        ck.fail("modes", "a mapping of mode names to dynamics (missing key)", show=False)
    modes_raw = ck.mapping("modes", data["modes"])
    if not modes_raw:
        ck.fail("modes", "at least one mode", {})
    return tuple(_parse_mode(ck, mname, spec, shared, ch, default_time, d)
                 for mname, spec in modes_raw.items())


def _parse_mode(ck: Checker, mname: Any, spec: Any, shared: Mapping[str, Any], ch: Channels,
                default_time: str, d: int) -> Mode:
    """One entry ``modes.<mname>``."""
    n, nu, ny, nw = len(ch.states), len(ch.inputs), len(ch.outputs), len(ch.disturbances)
    key = f"modes.{mname}"
    if not isinstance(mname, str) or not NAME_RE.match(mname):
        ck.fail(key, "a mode name of letters, digits and '_'", mname)
    spec = ck.mapping(key, spec, MODE_KEYS)
    merged = {**shared, **spec}
    dyn = spec.get("dynamics", "linear")
    if dyn not in ("linear", "nonlinear"):
        ck.fail(f"{key}.dynamics", "'linear' or 'nonlinear'", dyn)
    mtime = spec.get("time", default_time)
    if mtime not in TIME_KINDS:
        ck.fail(f"{key}.time", "'continuous' or 'discrete'", mtime)

    def mat(k: str, shape: tuple[int, int], required: bool = False) -> np.ndarray:
        if k not in merged:
            if required:
                ck.fail(f"{key}.{k}", f"a {shape[0]}x{shape[1]} matrix (missing key; "
                        f"give it in the mode or in 'shared')", show=False)
            return np.zeros(shape)
        where = f"{key}.{k}" if k in spec else f"shared.{k}"
        return ck.matrix(where, merged[k], shape)

    C = mat("C", (ny, n), required=True)
    B = mat("B", (n, nu))
    D = mat("D", (n, nw))
    E = mat("E", (ny, nw))
    offset = (ck.vector(f"{key}.offset", spec["offset"], n) if "offset" in spec
              else np.zeros(n))
    unc_key = f"{key}.uncertainty" if "uncertainty" in spec else "shared.uncertainty"
    unc = (ck.vector(unc_key, merged["uncertainty"], n, nonneg=True)
           if "uncertainty" in merged else np.zeros(n))
    A: np.ndarray | None = None
    model: str | None = None
    params: dict[str, float] = {}
    A_rho = _stack3(ck, f"{key}.A_rho", spec, d, (n, n), dyn)
    B_rho = _stack3(ck, f"{key}.B_rho", spec, d, (n, nu), dyn)
    if dyn == "linear":
        if "model" in spec or "params" in spec:
            ck.fail(f"{key}.model", "no 'model'/'params' in a linear mode (set "
                    "dynamics: nonlinear)", show=False)
        A = mat("A", (n, n), required=True)
    else:
        if "A" in spec:
            ck.fail(f"{key}.A", "no 'A' in a nonlinear mode (the model gives the "
                    "dynamics)", show=False)
        model, params = _nonlinear_model(ck, key, spec, n, nu)
    return Mode(mname, dyn, mtime, A, B, C, D, E, offset, unc, model, params, A_rho, B_rho)


def _nonlinear_model(ck: Checker, key: str, spec: Mapping[str, Any], n: int, nu: int
                     ) -> tuple[str, dict[str, float]]:
    """``<key>.model`` and ``<key>.params`` of a nonlinear mode: a registered model of n
    states and nu inputs, its parameters checked against the model's list, defaults and
    physical ranges."""
    if "model" not in spec:
        ck.fail(f"{key}.model", "the name of a nonlinear model (missing key)", show=False)
    model = spec["model"]
    try:
        mdl = get_model(str(model))
    except KeyError as exc:
        ck.fail(f"{key}.model", str(exc.args[0]), show=False)
    if mdl.n_states != n or mdl.n_inputs != nu:
        ck.fail(f"{key}.model", f"a model with {n} states and {nu} inputs (model "
                f"{model!r} has {mdl.n_states} and {mdl.n_inputs})", show=False)
    params: dict[str, float] = {}
    praw = ck.mapping(f"{key}.params", spec.get("params", {}) or {})
    for p in praw:
        if p not in mdl.param_names:
            ck.fail(f"{key}.params.{p}", f"a parameter of model {model!r}: "
                    f"{list(mdl.param_names)}", show=False)
    for p in mdl.param_names:
        if p not in praw:
            if p in mdl.defaults:
                params[p] = float(mdl.defaults[p])
                continue
            ck.fail(f"{key}.params.{p}", "a number (missing parameter)", show=False)
        params[p] = ck.number(f"{key}.params.{p}", praw[p])
    for p, (lo, hi, lo_open) in mdl.ranges.items():
        v = params[p]
        if (v <= lo if lo_open else v < lo) or v > hi:
            ck.fail(f"{key}.params.{p}", f"a value in {'(' if lo_open else '['}"
                    f"{lo:g}, {hi:g}] (the physical range of model {model!r})",
                    praw.get(p, v))
    return model, params


def _mode_ref(ck: Checker, modes: Sequence[Mode], key: str, v: Any) -> int:
    """Index of the mode named ``v`` (at ``key``)."""
    mode_names = [m.name for m in modes]
    if v not in mode_names:
        ck.fail(key, f"one of the modes {mode_names} (unknown mode)", v)
    return mode_names.index(v)


def _named_entries(ck: Checker, data: Mapping[str, Any], key: str, list_of: str, unique: str,
                   parse: Callable[[str, Any], _Named]) -> tuple[_Named, ...]:
    """The optional list ``key`` (``list_of`` names what it holds), each entry parsed by
    ``parse(key_path, entry)``; their names must be unique (``unique`` names them)."""
    raw = data.get(key, []) or []
    if not isinstance(raw, list):
        ck.fail(key, f"a list of {list_of}", raw)
    out = tuple(parse(f"{key}[{i}]", e) for i, e in enumerate(raw))
    names = [e.name for e in out]
    if len(set(names)) != len(names):
        ck.fail(key, f"unique {unique} names", names)
    return out


def parse_guards(ck: Checker, data: Mapping[str, Any], ch: Channels,
                 modes: Sequence[Mode]) -> tuple[Guard, ...]:
    """``guards``: transitions between the modes, on states or on inputs."""
    return _named_entries(ck, data, "guards", "guards", "guard",
                          lambda key, g: _parse_guard(ck, key, g, ch, modes))


def _parse_guard(ck: Checker, key: str, g: Any, ch: Channels, modes: Sequence[Mode]) -> Guard:
    """One entry ``guards[i]``."""
    g = ck.mapping(key, g, {"name", "from", "to", "kind", "when"})
    ck.require(key, g, ("from", "to", "kind", "when"))
    src = _mode_ref(ck, modes, f"{key}.from", g["from"])
    dst = _mode_ref(ck, modes, f"{key}.to", g["to"])
    if src == dst:
        ck.fail(f"{key}.to", "a mode other than 'from'", g["to"])
    kind = g["kind"]
    if kind not in ("autonomous", "controlled"):
        ck.fail(f"{key}.kind", "'autonomous' (on states) or 'controlled' (on inputs)", kind)
    names = ch.states if kind == "autonomous" else ch.inputs
    what = "state" if kind == "autonomous" else "input"
    when = g["when"]
    if isinstance(when, Mapping):
        when = [when]
    if not isinstance(when, list) or not when:
        ck.fail(f"{key}.when", "a non-empty list of {var, op, value}", when)
    conds = []
    for ci, c in enumerate(when):
        ckey = f"{key}.when[{ci}]"
        c = ck.mapping(ckey, c, {"var", "op", "value"})
        var = c.get("var")
        if var not in names:
            ck.fail(f"{ckey}.var", f"a {what} of a {kind} guard: {list(names)}", var)
        op = c.get("op")
        if op not in GUARD_OPS:
            ck.fail(f"{ckey}.op", f"one of {list(GUARD_OPS)}", op)
        if "value" not in c:
            ck.fail(f"{ckey}.value", "a number (missing key)", show=False)
        conds.append(Condition(str(var), names.index(var), str(op),
                               ck.number(f"{ckey}.value", c["value"])))
    gname = g.get("name", f"{g['from']}->{g['to']}")
    if not isinstance(gname, str):
        ck.fail(f"{key}.name", "a string", gname)
    return Guard(gname, src, dst, kind, tuple(conds))


def parse_faults(ck: Checker, data: Mapping[str, Any], ch: Channels,
                 modes: Sequence[Mode]) -> tuple[FaultChannel, ...]:
    """``faults``: the fault channels (see :class:`~fd_monitor.model.plant_parts.FaultChannel`)."""
    return _named_entries(ck, data, "faults", "fault channels", "fault",
                          lambda key, f: _parse_fault(ck, key, f, ch, modes))


def _parse_fault(ck: Checker, key: str, f: Any, ch: Channels, modes: Sequence[Mode]
                 ) -> FaultChannel:
    """One entry ``faults[i]``."""
    n, ny = len(ch.states), len(ch.outputs)
    f = ck.mapping(key, f)
    kind = f.get("kind")
    if kind not in FAULT_KINDS:
        ck.fail(f"{key}.kind", f"one of {list(FAULT_KINDS)}", kind)
    target_key = {"sensor_bias": "output", "actuator": "input", "state_jump": "state",
                  "process": "F", "parameter": "parameter"}[kind]
    ck.keys(key, f, {"name", "kind", target_key} | ({"E"} if kind == "process" else set()))
    if target_key not in f:
        ck.fail(f"{key}.{target_key}", f"the {target_key} of a {kind} fault (missing key)",
                show=False)
    fname = ck.name(f"{key}.name", f.get("name"))
    tgt = f[target_key]
    if kind in ("sensor_bias", "actuator", "state_jump"):
        pool = {"sensor_bias": ch.outputs, "actuator": ch.inputs, "state_jump": ch.states}[kind]
        if tgt not in pool:
            ck.fail(f"{key}.{target_key}", f"one of {list(pool)}", tgt)
        return FaultChannel(str(fname), kind, pool.index(tgt))
    if kind == "process":
        Fe = ck.vector(f"{key}.E", f["E"], ny) if "E" in f else None
        if not isinstance(tgt, Mapping):
            return FaultChannel(str(fname), kind, -1, F=ck.vector(f"{key}.F", tgt, n), E=Fe)
        mode_names = [m.name for m in modes]
        for mk in tgt:
            if mk not in mode_names:
                ck.fail(f"{key}.F.{mk}", f"one of the modes {mode_names} (a mapping "
                        f"mode -> {n}-vector)", mk)
        per = [ck.vector(f"{key}.F.{m.name}", tgt[m.name], n) if m.name in tgt
               else np.zeros(n) for m in modes]
        if not tgt:
            ck.fail(f"{key}.F", f"a {n}-vector or a non-empty mapping mode -> {n}-vector", tgt)
        return FaultChannel(str(fname), kind, -1, F_modes=tuple(per), E=Fe)
    if not isinstance(tgt, str):
        ck.fail(f"{key}.parameter", "the name of a model parameter", tgt)
    for m in modes:
        if m.dynamics != "nonlinear" or tgt not in m.params:
            ck.fail(f"{key}.parameter", f"a parameter of the nonlinear model of every "
                    f"mode (mode {m.name!r} lacks it)", tgt)
    return FaultChannel(str(fname), kind, -1, parameter=str(tgt))


def parse_initial(ck: Checker, data: Mapping[str, Any], n: int, modes: Sequence[Mode]
                  ) -> tuple[int, np.ndarray]:
    """``initial: {mode, state}``: the initial mode index and the (n,) initial state."""
    if "initial" not in data:
        ck.fail("initial", "{mode, state} (missing key)", show=False)
    init = ck.mapping("initial", data["initial"], {"mode", "state"})
    if "mode" not in init:
        ck.fail("initial.mode", "a mode name (missing key)", show=False)
    q0 = _mode_ref(ck, modes, "initial.mode", init["mode"])
    if "state" not in init:
        ck.fail("initial.state", f"a list of {n} numbers (missing key)", show=False)
    return q0, ck.vector("initial.state", init["state"], n)


def parse_switching(ck: Checker, data: Mapping[str, Any]) -> str:
    """``switching``: ``guards`` (default) or ``arbitrary``."""
    switching = data.get("switching", "guards")
    if switching not in ("guards", "arbitrary"):
        ck.fail("switching", "'guards' (mode changes by the guards) or 'arbitrary' (any mode "
                "sequence)", switching)
    return str(switching)


def parse_units(ck: Checker, data: Mapping[str, Any], ch: Channels
                ) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
    """The optional ``units: {states: {name: unit}, inputs: {...}, outputs: {...}}``: the
    unit of each state, input and output (``"-"`` where the file gives none)."""
    units = ck.mapping("units", data.get("units", {}) or {}, {"states", "inputs", "outputs"})
    out = []
    for group, names in (("states", ch.states), ("inputs", ch.inputs),
                         ("outputs", ch.outputs)):
        spec = ck.mapping(f"units.{group}", units.get(group, {}) or {}, set(names))
        for nm, u in spec.items():
            if not isinstance(u, str) or not u.strip():
                ck.fail(f"units.{group}.{nm}", "a unit (a non-empty string such as 'm')", u)
        out.append(tuple(str(spec.get(nm, "-")) for nm in names))
    return out[0], out[1], out[2]


def parse_limits(ck: Checker, data: Mapping[str, Any], outputs: Sequence[str],
                  inputs: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """The optional ``limits: {outputs: {name: [min, max]}, inputs: {...}}``."""
    lim = ck.mapping("limits", data.get("limits", {}) or {})
    ck.keys("limits", lim, {"outputs", "inputs"})
    out = []
    for group, names in (("outputs", outputs), ("inputs", inputs)):
        arr = np.tile([-MAX_MAGNITUDE, MAX_MAGNITUDE], (len(names), 1))
        spec = ck.mapping(f"limits.{group}", lim.get(group, {}) or {})
        for ch, rng in spec.items():
            key = f"limits.{group}.{ch}"
            if ch not in names:
                ck.fail(key, f"one of the {group} {list(names)}", ch)
            if not isinstance(rng, list) or len(rng) != 2:
                ck.fail(key, "[min, max]", rng)
            lo = ck.number(f"{key}[0]", rng[0])
            hi = ck.number(f"{key}[1]", rng[1])
            if hi <= lo:
                ck.fail(f"{key}[1]", f"max > min ({lo:g})", rng[1])
            arr[list(names).index(ch)] = (lo, hi)
        out.append(arr)
    return out[0], out[1]


def parse_envelope(ck: Checker, data: Any, states: Sequence[str], inputs: Sequence[str],
                    modes: Sequence[Mode]) -> Envelope:
    """``envelope: {states: {x: [lo, hi]}, inputs: {u: [lo, hi]}, modes: {m: {...}}}``.

    Every state and input needs a range; ``modes`` narrows them per mode (optional).
    """
    env = ck.mapping("envelope", data)
    ck.keys("envelope", env, {"states", "inputs", "modes"})

    def ranges(key: str, spec: Any, names: Sequence[str], lo: np.ndarray, hi: np.ndarray,
               complete: bool) -> None:
        spec = ck.mapping(key, spec if spec is not None else {})
        ck.keys(key, spec, set(names))
        for i, nm in enumerate(names):
            if nm not in spec:
                if complete:
                    ck.fail(f"{key}.{nm}", "a range [lo, hi] (missing key)", show=False)
                continue
            v = spec[nm]
            if not isinstance(v, list) or len(v) != 2:
                ck.fail(f"{key}.{nm}", "a range [lo, hi]", v)
            a = ck.number(f"{key}.{nm}[0]", v[0])
            b = ck.number(f"{key}.{nm}[1]", v[1])
            if not a <= b:
                ck.fail(f"{key}.{nm}", "a range [lo, hi] with lo <= hi", v)
            lo[..., i], hi[..., i] = a, b

    s, n, nu = len(modes), len(states), len(inputs)
    x_lo, x_hi = np.zeros((s, n)), np.zeros((s, n))
    u_lo, u_hi = np.zeros((s, nu)), np.zeros((s, nu))
    ranges("envelope.states", env.get("states"), states, x_lo, x_hi, True)
    ranges("envelope.inputs", env.get("inputs"), inputs, u_lo, u_hi, nu > 0)
    per_mode = ck.mapping("envelope.modes", env.get("modes") or {})
    names = [m.name for m in modes]
    ck.keys("envelope.modes", per_mode, set(names))
    for mname, spec in per_mode.items():
        q = names.index(mname)
        key = f"envelope.modes.{mname}"
        spec = ck.mapping(key, spec)
        ck.keys(key, spec, {"states", "inputs"})
        ranges(f"{key}.states", spec.get("states"), states, x_lo[q], x_hi[q], False)
        ranges(f"{key}.inputs", spec.get("inputs"), inputs, u_lo[q], u_hi[q], False)
    return Envelope(x_lo, x_hi, u_lo, u_hi)


def parse_lpv(ck: Checker, data: Mapping[str, Any]) -> tuple[LPVParameter, ...]:
    """The optional top-level ``lpv: {parameters: [{name, min, max, measured}]}``."""
    if "lpv" not in data:
        return ()
    lp = ck.mapping("lpv", data["lpv"])
    ck.keys("lpv", lp, {"parameters"})
    raw = lp.get("parameters")
    if not isinstance(raw, list) or not raw:
        ck.fail("lpv.parameters", "a non-empty list of {name, min, max, measured}", raw)
    out = []
    for i, pr in enumerate(raw):
        key = f"lpv.parameters[{i}]"
        pr = ck.mapping(key, pr)
        ck.keys(key, pr, {"name", "min", "max", "measured"})
        ck.require(key, pr, ("name", "min", "max", "measured"))
        nm = ck.name(f"{key}.name", pr["name"])
        lo = ck.number(f"{key}.min", pr["min"])
        hi = ck.number(f"{key}.max", pr["max"])
        if hi < lo:
            ck.fail(f"{key}.max", f"a number >= min ({lo})", pr["max"])
        if not isinstance(pr["measured"], bool):
            ck.fail(f"{key}.measured", "true (a scheduling parameter) or false (an "
                     "uncertainty)", pr["measured"])
        out.append(LPVParameter(str(nm), lo, hi, bool(pr["measured"])))
    names = [p.name for p in out]
    if len(set(names)) != len(names):
        ck.fail("lpv.parameters", "unique parameter names", names)
    return tuple(out)


def _stack3(ck: Checker, key: str, spec: Mapping[str, Any], d: int, shape: tuple[int, int],
            dyn: str) -> np.ndarray | None:
    """A per-mode ``A_rho`` / ``B_rho``: a list of d matrices of ``shape``, or None."""
    k = key.rsplit(".", 1)[1]
    if k not in spec:
        return None
    if d == 0:
        ck.fail(key, "no affine parts without a top-level 'lpv: {parameters: [...]}'",
                 show=False)
    if dyn != "linear":
        ck.fail(key, "affine parts only in a linear mode", show=False)
    v = spec[k]
    if not isinstance(v, list) or len(v) != d:
        ck.fail(key, f"a list of {d} {shape[0]}x{shape[1]} matrices (one per lpv parameter)",
                 Got(f"{len(v)} entries") if isinstance(v, list) else v)
    return np.array([ck.matrix(f"{key}[{j}]", m, shape) for j, m in enumerate(v)])


def canonical_form(name: str, ts: float, states: Sequence[str], inputs: Sequence[str],
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
