"""The ``hinf_sc`` design section of a plant's design file, read and checked.

:func:`parse_spec` turns the section (thesis ch. 4-7: nominal, uncertain and LPV banks) into a
:class:`BankSpec`: the affine model and its parameter box, the fault directions and the
generator each one gets, the lambda grid, the noise and nuisance inputs, the scheduling and
the Lyapunov structure. Every error is one line naming the file and the key path
(:class:`~fd_monitor.model.validate.Checker`). :func:`check_assumptions` refuses a bank the
thesis' construction does not cover. The LMIs are in :mod:`fd_monitor.design.hinf_sc`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fd_monitor.core.hinf_model import AffineModel, vertices
from fd_monitor.model.errors import DesignError
from fd_monitor.model.nonlinear import SCHEDULING_MAPS
from fd_monitor.model.system import System
from fd_monitor.model.validate import Checker

from ._lmi_common import design_checker, is_observable, region_blocks

__all__ = ["MAX_GRID_POINTS", "BankSpec", "FaultDir", "check_assumptions", "parse_spec"]

#: Most points of a ``lambda_grid`` (each is one LMI solve; the shipped designs use 50).
MAX_GRID_POINTS = 1000
_SECTION_KEYS = {"kind", "faults", "directions", "weights", "lambda_grid", "lambda", "noise",
                 "region", "compare_pure", "parameters", "A_rho", "B_rho", "model",
                 "scheduling", "thresholds", "description", "lyapunov", "rate"}


@dataclass(frozen=True)
class FaultDir:
    """How one fault enters the plant.

    Attributes
    ----------
    name : str
    kind : str
        Plant fault kind (``actuator``, ``process``, ``sensor_bias``, ``parameter``).
    F : numpy.ndarray
        (n, q) state directions: one column, or ``[F_pa, A F_pa]`` for a sensor fault.
    E : numpy.ndarray
        (p, 1) output direction (zero except for sensor faults).
    k : int
        Least k with ``C A^k F != 0`` (A-4.4).
    V : numpy.ndarray
        (n, q) eigen-assigned directions ``A^k F`` (4.31).
    """

    name: str
    kind: str
    F: np.ndarray
    E: np.ndarray
    k: int
    V: np.ndarray


@dataclass
class BankSpec:
    """A validated ``hinf_sc`` design specification."""

    kind: str
    model: AffineModel
    faults: list[FaultDir]
    generators: list[str]
    weights: dict[str, float]
    grid: np.ndarray
    fixed_lambda: float | None
    Dw: np.ndarray
    Ew: np.ndarray
    Dn: np.ndarray
    region: list[tuple[np.ndarray, np.ndarray]]
    region_spec: Any
    compare_pure: bool
    thresholds: Mapping[str, Any]
    origin: str
    sha256: str
    extra: dict[str, Any] = field(default_factory=dict)
    lyapunov: str = "common"


# --------------------------------------------------------------------------------------
# specification


def parse_spec(system: System, section: Mapping[str, Any], origin: str, sha: str
               ) -> BankSpec:
    """Validate the ``hinf_sc`` section against the plant; build the model and directions."""
    ctx = design_checker(origin, "hinf_sc")
    ctx.mapping("", section, _SECTION_KEYS)
    kind = _kind(ctx, system, section)
    A0, B0, C = _nominal_model(ctx, system, section)
    box = _parameter_box(ctx, system, section, kind)
    sched = _scheduling(ctx, section, kind)
    lyap, rate_min, rate_max = _lyapunov(ctx, section, kind, len(box.names))
    model = AffineModel(A0, box.A_rho, B0, box.B_rho, C, box.rmin, box.rmax, box.names,
                        sched, rate_min, rate_max)
    faults = _with_k(_fault_directions(ctx, system, section, A0, B0, C), A0, C, origin, kind)
    w = ctx.mapping("weights", section.get("weights") or {}, {"a", "b", "c"})
    weights = {k: ctx.number(f"weights.{k}", w.get(k, 1.0), positive=True)
               for k in ("a", "b", "c")}
    grid, fixed = _lambdas(ctx, section)
    Dw, Ew, Dn = _nuisance_inputs(ctx, system, section, kind)
    region_spec = section.get("region")
    region = region_blocks(ctx, "region", region_spec)
    cp_ = ctx.boolean("compare_pure", section.get("compare_pure", False))
    th = ctx.mapping("thresholds", section.get("thresholds") or {"method": "none"})
    if th.get("method", "none") not in ("none", "bound", "monte_carlo"):
        ctx.fail("thresholds.method", "none, bound or monte_carlo", th.get("method"))
    return BankSpec(str(kind), model, faults, [f.name for f in faults], weights, grid, fixed,
                    Dw, Ew, Dn, region, region_spec, cp_, th, origin, sha, lyapunov=str(lyap))


def _plant_lpv(system: System, section: Mapping[str, Any]) -> bool:
    """Whether the parameter box and A_rho / B_rho come from the plant file (its lpv key)."""
    return bool(system.lpv) and "parameters" not in section


def _kind(ctx: Checker, system: System, section: Mapping[str, Any]) -> str:
    """``kind``: lti, uncertain or lpv (default: from the plant's lpv parameters)."""
    if _plant_lpv(system, section):
        default_kind = "lpv" if all(p.measured for p in system.lpv) else "uncertain"
    else:
        default_kind = "lti"
    kind = section.get("kind", default_kind)
    if kind not in ("lti", "uncertain", "lpv"):
        ctx.fail("kind", "lti, uncertain or lpv", kind)
    return str(kind)


def _nominal_model(ctx: Checker, system: System, section: Mapping[str, Any]
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``model: {A0, B0, C}`` of the design file, else the plant's single continuous-time
    linear mode: (n, n) A0, (n, nu) B0, (p, n) C."""
    n, p, nu = system.n, system.ny, system.nu
    mode = system.modes[0]
    if "model" in section:
        m = ctx.mapping("model", section["model"], {"A0", "B0", "C"})
        A0 = ctx.matrix("model.A0", m.get("A0"), (n, n))
        B0 = ctx.matrix("model.B0", m["B0"], (n, nu)) if "B0" in m else np.zeros((n, nu))
        C = ctx.matrix("model.C", m["C"], (p, n)) if "C" in m else mode.C
        return A0, B0, C
    if mode.dynamics != "linear" or mode.time != "continuous" or len(system.modes) != 1:
        ctx.fail("model", "{A0, B0, C}: the plant is not a single continuous-time linear "
                 "mode, so the design needs its continuous-time (LPV) model (thesis "
                 "ch. 4-6 are continuous-time)", show=False)
    assert mode.A is not None
    return mode.A, mode.B, mode.C


@dataclass(frozen=True)
class _Box:
    """The parameter box of an uncertain / LPV design: names, (d,) bounds, (d, n, n) A_rho
    and (d, n, nu) B_rho (d = 0 for lti)."""

    names: tuple[str, ...]
    rmin: np.ndarray
    rmax: np.ndarray
    A_rho: np.ndarray
    B_rho: np.ndarray


def _parameter_box(ctx: Checker, system: System, section: Mapping[str, Any], kind: str
                   ) -> _Box:
    """The parameters: from the plant's lpv key, or ``parameters`` / ``A_rho`` / ``B_rho``
    of the design file."""
    n, nu = system.n, system.nu
    if kind in ("uncertain", "lpv") and _plant_lpv(system, section):
        return _plant_box(ctx, system, section, kind)
    if kind in ("uncertain", "lpv"):
        return _design_file_box(ctx, system, section, kind)
    if any(k in section for k in ("parameters", "A_rho", "B_rho")):
        ctx.fail("kind", "uncertain or lpv when parameters / A_rho are given", kind)
    return _Box((), np.zeros(0), np.zeros(0), np.zeros((0, n, n)), np.zeros((0, n, nu)))


def _plant_box(ctx: Checker, system: System, section: Mapping[str, Any], kind: str) -> _Box:
    """The box and affine parts the plant file declares (its lpv key and modes)."""
    n, nu = system.n, system.nu
    mode = system.modes[0]
    for k in ("A_rho", "B_rho"):
        if k in section:
            ctx.fail(k, f"no {k} in the design file: plant {system.name!r} declares its "
                     f"lpv parameters, so {k} belongs in its modes", show=False)
    if kind == "lpv" and not all(p.measured for p in system.lpv):
        ctx.fail("kind", "uncertain: the plant's lpv parameters "
                 f"{[p.name for p in system.lpv if not p.measured]} are not measured", kind)
    names = tuple(p.name for p in system.lpv)
    d = len(names)
    A_rho = mode.A_rho if mode.A_rho is not None else np.zeros((d, n, n))
    B_rho = np.zeros((0, n, nu))
    if mode.B_rho is not None:
        if kind == "uncertain":
            ctx.fail("kind", "lpv: the plant has B_rho (5.1 has a constant B)", kind)
        B_rho = mode.B_rho
    return _Box(names, np.array([p.min for p in system.lpv]),
                np.array([p.max for p in system.lpv]), A_rho, B_rho)


def _design_file_box(ctx: Checker, system: System, section: Mapping[str, Any], kind: str
                     ) -> _Box:
    """``parameters: {names, min, max}``, ``A_rho`` and ``B_rho`` of the design file."""
    n, nu = system.n, system.nu
    if "parameters" not in section:
        ctx.fail("parameters", "{names, min, max} of the parameter box (missing key)",
                 show=False)
    pr = ctx.mapping("parameters", section["parameters"], {"names", "min", "max"})
    nm = pr.get("names")
    if not isinstance(nm, list) or not nm or not all(isinstance(s, str) for s in nm):
        ctx.fail("parameters.names", "a non-empty list of names", nm)
    names = tuple(nm)
    d = len(names)
    rmin = ctx.vector("parameters.min", pr.get("min"), d)
    rmax = ctx.vector("parameters.max", pr.get("max"), d)
    if np.any(rmax < rmin):
        ctx.fail("parameters.max", "max >= min for every parameter", pr.get("max"))
    raw = section.get("A_rho")
    if not isinstance(raw, list) or len(raw) != d:
        ctx.fail("A_rho", f"a list of {d} {n}x{n} matrices (one per parameter)", raw)
    A_rho = np.array([ctx.matrix(f"A_rho[{j}]", a, (n, n)) for j, a in enumerate(raw)])
    B_rho = np.zeros((0, n, nu))
    if "B_rho" in section:
        if kind == "uncertain":
            ctx.fail("B_rho", "no B_rho in an uncertain design (5.1 has a constant B)",
                     show=False)
        rb = section["B_rho"]
        if not isinstance(rb, list) or len(rb) != d:
            ctx.fail("B_rho", f"a list of {d} {n}x{nu} matrices", rb)
        B_rho = np.array([ctx.matrix(f"B_rho[{j}]", b, (n, nu)) for j, b in enumerate(rb)])
    return _Box(names, rmin, rmax, A_rho, B_rho)


def _scheduling(ctx: Checker, section: Mapping[str, Any], kind: str) -> dict[str, Any] | None:
    """``scheduling: {map, params}``: rho computed from y at run time (kind lpv only)."""
    if "scheduling" not in section:
        return None
    if kind != "lpv":
        ctx.fail("scheduling", "a scheduling map only for kind lpv", show=False)
    s = ctx.mapping("scheduling", section["scheduling"], {"map", "params"})
    if s.get("map") not in SCHEDULING_MAPS:
        ctx.fail("scheduling.map", f"one of {sorted(SCHEDULING_MAPS)}", s.get("map"))
    return {"map": s["map"], "params": dict(s.get("params") or {})}


def _lyapunov(ctx: Checker, section: Mapping[str, Any], kind: str, d: int
              ) -> tuple[str, np.ndarray | None, np.ndarray | None]:
    """``lyapunov`` (common or affine) and, for affine, the (d,) ``rate`` bounds (1/s)."""
    lyap = section.get("lyapunov", "common")
    if lyap not in ("common", "affine"):
        ctx.fail("lyapunov", "common or affine", lyap)
    if lyap != "affine":
        if "rate" in section:
            ctx.fail("rate", "rate bounds only with lyapunov: affine", show=False)
        return str(lyap), None, None
    if kind != "lpv":
        ctx.fail("lyapunov", "affine only for kind lpv (thesis 6.4: rho and its rate "
                 "measured)", lyap)
    if "rate" not in section:
        ctx.fail("rate", "{min, max} bounds of d rho/dt (6.52), needed by lyapunov: "
                 "affine (missing key)", show=False)
    rt = ctx.mapping("rate", section["rate"], {"min", "max"})
    rate_min = ctx.vector("rate.min", rt.get("min"), d)
    rate_max = ctx.vector("rate.max", rt.get("max"), d)
    if np.any(rate_max < rate_min):
        ctx.fail("rate.max", "max >= min for every parameter", rt.get("max"))
    return str(lyap), rate_min, rate_max


def _fault_directions(ctx: Checker, system: System, section: Mapping[str, Any],
                      A0: np.ndarray, B0: np.ndarray, C: np.ndarray) -> list[FaultDir]:
    """How each fault enters (``directions``, else from the plant's fault channel), for the
    faults the section selects (``faults``, default every fault with a direction)."""
    n, p = system.n, system.ny
    origin = ctx.origin
    dirs_raw = ctx.mapping("directions", section.get("directions") or {})
    faults: list[FaultDir] = []
    for f in system.faults:
        if f.name in dirs_raw:
            F = ctx.vector(f"directions.{f.name}", dirs_raw[f.name], n)[:, None]
            E = np.zeros((p, 1))
        elif f.kind == "actuator":
            F, E = B0[:, [f.index]], np.zeros((p, 1))
        elif f.kind == "process":
            if f.E is not None and np.any(f.E):
                raise DesignError(f"{origin}: hinf_sc: process fault {f.name!r} has an output "
                                  f"part E: not supported by (4.47) as implemented (model it "
                                  f"as a sensor fault)")
            F, E = f.direction(0, n)[:, None], np.zeros((p, 1))
        elif f.kind == "sensor_bias":
            E = np.zeros((p, 1))
            E[f.index, 0] = 1.0
            Fpa, *_ = np.linalg.lstsq(C, E, rcond=None)
            if np.linalg.norm(C @ Fpa - E) > 1e-9:
                raise DesignError(
                    f"{origin}: hinf_sc: sensor fault {f.name!r}: (4.57) has no solution: "
                    f"no F with C F = E (output {system.outputs[f.index]!r} is not a "
                    f"combination of the states seen by C)")
            F = np.hstack([Fpa, A0 @ Fpa])  # pseudo-actuator fault (4.58)
        else:
            continue  # parameter / state_jump without a direction: no generator
        faults.append(FaultDir(f.name, f.kind, F, E, 0, F))
    for name in dirs_raw:
        if name not in [f.name for f in system.faults]:
            ctx.fail(f"directions.{name}", f"a fault channel of plant {system.name!r}: "
                     f"{[f.name for f in system.faults]}", show=False)
    known = [f.name for f in faults]
    gens = section.get("faults", known)
    if not isinstance(gens, list) or not gens or not all(g in known for g in gens):
        ctx.fail("faults", f"a non-empty list of faults with a direction: {known}", gens)
    return [f for f in faults if f.name in gens] if "faults" in section else faults


def _lambdas(ctx: Checker, section: Mapping[str, Any]) -> tuple[np.ndarray, float | None]:
    """``lambda_grid`` (a list, or ``{start, stop, num}``; every lambda < 0) and the fixed
    ``lambda`` (< 0) when given."""
    g = section.get("lambda_grid", {"start": -10.0, "stop": -0.1, "num": 50})
    if isinstance(g, list):
        if len(g) > MAX_GRID_POINTS:
            ctx.fail("lambda_grid", f"at most {MAX_GRID_POINTS} values (MAX_GRID_POINTS: one "
                     f"LMI solve each)", f"{len(g)} values")
        grid = ctx.vector("lambda_grid", g, None)
    else:
        g = ctx.mapping("lambda_grid", g, {"start", "stop", "num"})
        num = ctx.integer("lambda_grid.num", g.get("num", 50), 1)
        if num > MAX_GRID_POINTS:
            ctx.fail("lambda_grid.num", f"an integer in [1, {MAX_GRID_POINTS}] "
                     f"(MAX_GRID_POINTS: one LMI solve per point)", num)
        grid = np.linspace(ctx.number("lambda_grid.start", g.get("start", -10.0)),
                           ctx.number("lambda_grid.stop", g.get("stop", -0.1)), num)
    if grid.size == 0 or np.any(grid >= 0):
        ctx.fail("lambda_grid", "values lambda < 0 (stability, thesis 4.41)", grid.tolist())
    fixed = None
    if section.get("lambda") is not None:
        fixed = ctx.number("lambda", section["lambda"], negative=True)
    return grid, fixed


def _nuisance_inputs(ctx: Checker, system: System, section: Mapping[str, Any], kind: str
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Disturbances (the plant's (n, nw) D and (p, nw) E) and, with ``noise: true``,
    measurement noise (p, p_noisy) D_n = I on the noisy outputs."""
    n, p = system.n, system.ny
    mode = system.modes[0]
    if "model" in section or mode.dynamics != "linear":
        Dw, Ew = np.zeros((n, 0)), np.zeros((p, 0))
    else:
        Dw, Ew = mode.D, mode.E
    noise = ctx.boolean("noise", section.get("noise", False))
    Dn = np.eye(p)[:, system.measurement_noise > 0] if noise else np.zeros((p, 0))
    if kind == "uncertain" and (Dw.shape[1] or Dn.shape[1]):
        ctx.fail("kind", "an uncertain design (5.45) without disturbances or noise (it "
                 "attenuates the nuisance faults only)", show=False)
    return Dw, Ew, Dn


def _with_k(faults: list[FaultDir], A: np.ndarray, C: np.ndarray, origin: str,
            kind: str) -> list[FaultDir]:
    """Fill k (A-4.4) and V = A^k F; name the failing assumption."""
    n = A.shape[0]
    out = []
    for f in faults:
        if np.linalg.matrix_rank(f.F) < f.F.shape[1] or np.linalg.norm(f.F) == 0:
            raise DesignError(f"{origin}: hinf_sc: assumption A-4.2 fails: the direction of "
                              f"fault {f.name!r} is not monic (F = 0 or rank deficient)")
        k_found = None
        Ak = np.eye(n)
        for k in range(n):
            if np.linalg.norm(C @ Ak @ f.F) > 1e-12 * max(1.0, float(np.linalg.norm(f.F))):
                k_found = k
                break
            Ak = A @ Ak
        if k_found is None:
            raise DesignError(f"{origin}: hinf_sc: assumption A-4.4 fails: C A^k F = 0 for "
                              f"k = 0..{n - 1} for fault {f.name!r} (not input observable)")
        if k_found > 0 and kind != "lti":
            a = "A-5.4" if kind == "uncertain" else "A-6.3"
            raise DesignError(f"{origin}: hinf_sc: assumption {a} fails: C F = 0 for fault "
                              f"{f.name!r} ({kind} designs need C F_i != 0)")
        V = np.linalg.matrix_power(A, k_found) @ f.F
        out.append(FaultDir(f.name, f.kind, f.F, f.E, k_found, V))
    return out


def check_assumptions(spec: BankSpec) -> None:
    """A-4.1 (A-5.2 / A-6.1 at the vertices) and A-4.3; raise ``DesignError`` naming it."""
    m = spec.model
    tag = {"lti": "A-4.1", "uncertain": "A-5.2", "lpv": "A-6.1"}[spec.kind]
    for v in vertices(m.rho_min, m.rho_max):
        A = m.A(v)
        if not is_observable(A, m.C):
            where = "" if spec.kind == "lti" else f" at the vertex rho = {v.tolist()}"
            raise DesignError(f"{spec.origin}: hinf_sc: assumption {tag} fails: (A, C) is "
                              f"not observable{where}")
    CV = np.hstack([m.C @ f.V for f in spec.faults])
    r = np.linalg.matrix_rank(CV, tol=1e-9 * max(1.0, float(np.abs(CV).max())))
    if r < CV.shape[1]:
        a = {"lti": "A-4.3", "uncertain": "A-5.5", "lpv": "A-6.4"}[spec.kind]
        raise DesignError(f"{spec.origin}: hinf_sc: assumption {a} fails (output "
                          f"separability): rank C[A^k F_1 ... A^k F_r] = {r} < {CV.shape[1]}; "
                          f"faults {[f.name for f in spec.faults]} cannot all be isolated")
