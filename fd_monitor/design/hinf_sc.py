"""``design hinf_sc``: a bank of H-infinity residual generators with a sensitivity constraint.

One observer-based residual generator per fault (thesis ch. 4-6, Armeni): generator ``i``
isolates fault ``i``. For a fixed eigenvalue ``lambda < 0`` the fault direction
``V_i = A^k F_i`` (k the least integer with ``C A^k F_i != 0``, A-4.4) is made an eigenvector
of ``A - L C`` (4.37) by the gain parametrisation (4.40)::

    L = (A - lambda I) V (C V)^+ + Lbar (I - C V (C V)^+)

and ``Lbar = P^-1 K`` minimises the weighted attenuation ``a g + b g_w + c g_n`` of the
nuisance faults, the disturbances and the noise (4.42, squared bounds 4.22) -- an LMI for
fixed lambda, solved over a grid of lambda (one DPP-parametrised cvxpy problem re-solved
per grid point); the lambda with the smallest performance ratio (4.35)::

    mu = lambda^2 (a g + b g_w + c g_n) / sigma_min(H C V)^2

is kept. The residual is projected by ``H = I - C Fh (C Fh)^+`` (4.55), Fh the other
faults' directions. A sensor fault ``y += E f`` becomes the pseudo-actuator fault
``[F, A F]`` with ``C F = E`` (4.56-4.64). Options: an LMI pole region (2.26-2.28, 4.66);
the pure attenuation design (4.24) for comparison; an uncertain plant (ch. 5: observer on
``A0``, extended-state vertex LMIs 5.45/5.50); an LPV plant (ch. 6: ``L(rho) = L0 +
sum rho_j L_j``, vertex LMIs 6.40 with a common P). Assumptions A-4.1 to A-4.4 (A-5.x,
A-6.x) are checked before solving and the failing one is named.

Design file section (``config/systems/<plant>.design.yaml``)::

    hinf_sc:
      kind: lti                      # lti | uncertain | lpv
      faults: [f1, f2]               # one generator each (default: every plant fault)
      directions: {leak1: [...]}     # F of faults the plant file cannot express (optional)
      weights: {a: 1.0, b: 1.0, c: 1.0}
      lambda_grid: {start: -10.0, stop: -0.1, num: 50}
      lambda: -1.0                   # optional: use this lambda (no grid selection)
      noise: false                   # include the measurement-noise channel (D_n = I)
      region: [{kind: disk, center: 0.0, radius: 50.0}]
      compare_pure: true             # also design (4.24) for comparison (not run)
      parameters: {names: [rho1], min: [-1.0], max: [1.0]}   # uncertain / lpv
      A_rho: [[[...]]]               # (d, n, n) affine parts of A
      B_rho: [[[...]]]               # (d, n, nu) affine parts of B (lpv, optional)
      model: {A0, B0, C}             # replaces the plant's matrices (nonlinear plants)
      scheduling: {map: three_tank_sqrt, params: {...}}   # rho from y at run time
      thresholds: {method: bound, levels: {nuisance: 1.0, disturbance: 0.0, noise: 0.0},
                   margin: 3.0}      # or {method: monte_carlo, scenario, runs, settle, margin,
                                     #     levels} (levels: the bound term added, see below)
      lyapunov: common               # lpv: common P (6.40) | affine P(rho) (6.4, 6.66)
      rate: {min: [-1.0], max: [1.0]}   # bounds of d rho/dt, 1/s (6.52; lyapunov: affine)

Affine quadratic stability (thesis 6.4, ``lyapunov: affine``): ``P(rho) = P_0 + sum rho_j
P_j`` and ``K(rho) = P(rho) Lbar(rho) = K_0 + sum rho_j K_j``, so the gain is ``L(rho) =
(A(rho) - lambda I) V (C V)^+ + P(rho)^-1 K(rho) (I - C V (C V)^+)``. The bounded-real LMI
gets ``dP/dt = sum rho_dot_j P_j`` and is imposed at every (vertex, rate vertex); it is
quadratic in rho, so multi-convexity (its rho_j^2 coefficient positive semidefinite: ``He(P_j
Abar_j) >= 0`` and ``P_j A_j V (C V)^+ Wout = 0``; for the pole region ``Mr (x) P_j Abar_j +
Mr' (x) (P_j Abar_j)' >= 0``) extends the vertex conditions to the box (6.63). ``P_j = 0``
is the common-P design, so the affine optimum is never worse; the solver's answer can be, by
its tolerance (an absolute gap of 1e-8 is ~1 % of gamma^2 at the 1e-6 LMI margin).

Why one module of ~550 lines: one designer (a generator per fault, the DC gains, the bank
and its gain-file document); its design section and thresholds already live in
``hinf_spec.py`` and ``hinf_thresholds.py``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import cvxpy as cp
import numpy as np

from fd_monitor.core.hinf_certificate import check_generator
from fd_monitor.core.hinf_model import AffineModel, Generator, generator_ss, vertices
from fd_monitor.core.residual_bank import ResidualBank
from fd_monitor.core.simulator import simulate_batch
from fd_monitor.design.hinf_spec import BankSpec, FaultDir, check_assumptions, parse_spec
from fd_monitor.design.hinf_thresholds import (
    bound_thresholds,
    fault_free_scenario,
    monte_carlo_thresholds,
)
from fd_monitor.model.errors import DesignError, GainFileError
from fd_monitor.model.system import System

from ._lmi_common import (
    complement_projector,
    design_checker,
    is_detectable,
    left_pinv,
    solve,
)

__all__ = ["design", "design_generator"]

EPS = 1e-6  # strictness margin of every LMI (M <= -EPS I, P >= EPS I)
# --------------------------------------------------------------------------------------
# one generator


@dataclass
class _GenData:
    fault: FaultDir
    V: np.ndarray
    CVp: np.ndarray
    Pi: np.ndarray
    Fhat: np.ndarray
    H: np.ndarray
    sens: float  # sigma_min(H C V)


def _gen_data(spec: BankSpec, i: int) -> _GenData:
    m = spec.model
    f = spec.faults[i]
    others = [g for j, g in enumerate(spec.faults) if j != i]
    Hdirs = np.hstack([m.C @ g.V for g in others]) if others else np.zeros((m.C.shape[0], 0))
    H = complement_projector(Hdirs)
    Fhat = np.hstack([g.F for g in others]) if others else np.zeros((m.n, 0))
    CV = m.C @ f.V
    CVp = left_pinv(CV)
    Pi = np.eye(m.C.shape[0]) - CV @ CVp
    sens = float(np.linalg.svd(H @ CV, compute_uv=False).min())
    return _GenData(f, f.V, CVp, Pi, Fhat, H, sens)


def _region_lmi(Lr: np.ndarray, Mr: np.ndarray, P: Any, PA: Any, n: int) -> Any:
    """``Lr (x) P + Mr (x) PA + Mr' (x) PA'`` (4.66) built block by block (``cp.kron`` of a
    parametrised argument is not DPP)."""
    k = Lr.shape[0]
    rows = []
    for a in range(k):
        row = []
        for b in range(k):
            blk: Any = np.zeros((n, n))
            if Lr[a, b] != 0:
                blk = blk + Lr[a, b] * P
            if Mr[a, b] != 0:
                blk = blk + Mr[a, b] * PA
            if Mr[b, a] != 0:
                blk = blk + Mr[b, a] * PA.T
            row.append(blk)
        rows.append(row)
    return cp.bmat(rows)


class _Problem:
    """The DPP-parametrised LMI problem of one generator (lambda is a cvxpy Parameter)."""

    def __init__(self, spec: BankSpec, gd: _GenData, sc: bool) -> None:
        self.spec, self.gd, self.sc = spec, gd, sc
        self.lam = cp.Parameter(value=-1.0)
        self.Pj: list[Any] = []
        if spec.kind == "uncertain":
            self.prob = self._uncertain()
        else:
            self.prob = self._bounded_real()

    def _closed_loop(self, P: Any, K: Any, A: np.ndarray) -> tuple[Any, Any]:
        """``(P Acl, P L)`` at the state matrix ``A``: with the sensitivity constraint the gain
        is ``(A - lam I) V (CV)^+ + P^-1 K Pi`` (4.37), otherwise ``P^-1 K``."""
        m, gd, lam = self.spec.model, self.gd, self.lam
        V, CVp, Pi, C = gd.V, gd.CVp, gd.Pi, m.C
        if self.sc:
            PAcl = P @ (A - A @ V @ CVp @ C) + lam * (P @ (V @ CVp @ C)) - K @ (Pi @ C)
            PL = P @ (A @ V @ CVp) - lam * (P @ (V @ CVp)) + K @ Pi
            return PAcl, PL
        return P @ A - K @ C, K

    def _region(self, P: Any, PAcl: Any) -> list[Any]:
        """The pole-region LMIs (4.66) of the spec at ``(P, P Acl)``."""
        n = self.spec.model.n
        out = []
        for Lr, Mr in self.spec.region:
            RM = _region_lmi(Lr, Mr, P, PAcl, n)
            out.append(0.5 * (RM + RM.T) << -EPS * np.eye(RM.shape[0]))
        return out

    def _uncertain(self) -> Any:
        """Thesis 5.30/5.45: ``diag(P1, P2)`` on the state ``[x; e]``, one bound ``g``."""
        spec, gd = self.spec, self.gd
        m = spec.model
        n, p = m.n, m.C.shape[0]
        HC = gd.H @ m.C
        P1 = cp.Variable((n, n), symmetric=True)
        P2 = cp.Variable((n, n), symmetric=True)
        K = cp.Variable((n, p))
        g = cp.Variable(nonneg=True)
        self.P1, self.P2, self.K, self.g = P1, P2, K, g
        A0 = m.A0
        PAcl = self._closed_loop(P2, K, A0)[0]
        mf = gd.Fhat.shape[1]
        cons: list[Any] = []
        Z = np.zeros
        for v in vertices(m.rho_min, m.rho_max):
            Av = m.A(v)
            M = cp.bmat([
                [Av.T @ P1 + P1 @ Av, (Av - A0).T @ P2, P1 @ gd.Fhat, Z((n, p))],
                [P2 @ (Av - A0), PAcl + PAcl.T, P2 @ gd.Fhat, HC.T],
                [gd.Fhat.T @ P1, gd.Fhat.T @ P2, -g * np.eye(mf), Z((mf, p))],
                [Z((p, n)), HC, Z((p, mf)), -g * np.eye(p)]])
            k = M.shape[0]
            cons.append(0.5 * (M + M.T) << -EPS * np.eye(k))
            cons += self._region(P2, PAcl)
        cons += [P1 >> EPS * np.eye(n), P2 >> EPS * np.eye(n)]
        return cp.Problem(cp.Minimize(g), cons)

    def _bounded_real(self) -> Any:
        """Thesis 4.20/4.23 (LTI), 6.40 (LPV, affine gain) and 6.66 (affine P(rho)): one
        bounded-real LMI per vertex (and rate vertex) with a bound per input group."""
        spec, gd = self.spec, self.gd
        m = spec.model
        n, p = m.n, m.C.shape[0]
        HC = gd.H @ m.C
        d = m.d if spec.kind == "lpv" else 0
        P = cp.Variable((n, n), symmetric=True)
        Ks = [cp.Variable((n, p)) for _ in range(d + 1)]
        affine = self.sc and spec.lyapunov == "affine" and d > 0
        Pj = [cp.Variable((n, n), symmetric=True) for _ in range(d)] if affine else []
        self.Pj = Pj
        rates = (vertices(m.rate_min, m.rate_max)
                 if affine and m.rate_min is not None and m.rate_max is not None else [None])
        groups = {"nuisance": gd.Fhat.shape[1], "disturbance": spec.Dw.shape[1],
                  "noise": spec.Dn.shape[1]}
        gv = {k: cp.Variable(nonneg=True) for k, c in groups.items() if c > 0}
        self.P, self.Ks, self.gv = P, Ks, gv
        W = np.hstack([gd.Fhat, spec.Dw, np.zeros((n, spec.Dn.shape[1]))])
        Wout = np.hstack([np.zeros((p, gd.Fhat.shape[1])), spec.Ew, spec.Dn])
        HW = gd.H @ Wout
        diag_parts = [cp.multiply(gv[k], np.ones(c)) for k, c in groups.items() if c > 0]
        if diag_parts:
            Gam = cp.diag(cp.hstack(diag_parts))
        ncol = W.shape[1]
        cons: list[Any] = []
        for v in vertices(m.rho_min, m.rho_max):
            Kv = Ks[0] + sum(float(v[j]) * Ks[j + 1] for j in range(d)) if d else Ks[0]
            Pv = P + sum(float(v[j]) * Pj[j] for j in range(d)) if affine else P
            PAcl, PL = self._closed_loop(Pv, Kv, m.A(v))
            for k in rates:
                top = PAcl + PAcl.T + HC.T @ HC
                if k is not None:
                    top = top + sum(float(k[j]) * Pj[j] for j in range(d))
                if ncol:
                    PB = Pv @ W - PL @ Wout if np.any(Wout) else Pv @ W
                    off = PB + HC.T @ HW
                    M = cp.bmat([[top, off], [off.T, HW.T @ HW - Gam]])
                else:
                    M = top
                cons.append(0.5 * (M + M.T) << -EPS * np.eye(M.shape[0]))
            cons += self._region(Pv, PAcl)
            if affine:
                cons.append(Pv >> EPS * np.eye(n))
        if affine:
            cons += self._multiconvexity(Wout if ncol else None)
        else:
            cons.append(P >> EPS * np.eye(n))
        wk = self._weights()
        obj = sum(wk[k] * gv[k] for k in gv) if gv else cp.Constant(0.0)
        return cp.Problem(cp.Minimize(obj), cons)

    def _multiconvexity(self, Wout: np.ndarray | None) -> list[Any]:
        """Multi-convexity (6.63): the rho_j^2 coefficient of each LMI is PSD."""
        m, gd, n = self.spec.model, self.gd, self.spec.model.n
        V, CVp, C = gd.V, gd.CVp, m.C
        cons: list[Any] = []
        for j, Pj in enumerate(self.Pj):
            Aj = m.A_rho[j]
            X = Pj @ (Aj - Aj @ V @ CVp @ C)
            cons.append(0.5 * (X + X.T) >> 0)
            if Wout is not None and np.any(Wout):
                cons.append(Pj @ (Aj @ V @ CVp @ Wout) == 0)
            for Lr, Mr in self.spec.region:
                if np.allclose(np.diag(Mr), 0.0):
                    # [[0, X], [X', 0]]-type blocks are PSD only for X = 0
                    cons.append(X == 0)
                else:
                    RX = _region_lmi(np.zeros_like(Lr), Mr, np.zeros((n, n)), X, n)
                    cons.append(0.5 * (RX + RX.T) >> 0)
        return cons

    def solve_at(self, lam: float) -> tuple[str, float]:
        """Solve for one lambda (ignored by the pure design); return (status, seconds)."""
        self.lam.value = float(lam)
        return solve(self.prob, "", raise_on_failure=False)

    def gamma2(self) -> dict[str, float]:
        """Squared attenuation bounds at the last solution."""
        # solved scalars (cvxpy types a value as ndarray | None)
        if self.spec.kind == "uncertain":
            g: Any = self.g.value
            return {"nuisance": float(g) ** 2}
        values: dict[str, Any] = {k: v.value for k, v in self.gv.items()}
        return {k: float(v) for k, v in values.items()}

    def cost(self) -> float:
        """``a g + b g_w + c g_n`` (squared bounds) at the last solution."""
        wk = self._weights()
        return sum(wk[k] * v for k, v in self.gamma2().items())

    def _weights(self) -> dict[str, float]:
        """Cost weight of each input group's squared bound: ``a``, ``b``, ``c``."""
        w = self.spec.weights
        return {"nuisance": w["a"], "disturbance": w["b"], "noise": w["c"]}

    def generator(self, lam: float) -> Generator:
        """The generator (L, P, bounds) of the last solution at ``lam``."""
        m, gd = self.spec.model, self.gd
        n, p = m.n, m.C.shape[0]
        if self.spec.kind == "uncertain":
            P2 = np.asarray(self.P2.value)
            Lbar = np.linalg.solve(P2, np.asarray(self.K.value))
            if self.sc:
                L0 = (m.A0 - lam * np.eye(n)) @ gd.V @ gd.CVp + Lbar @ gd.Pi
            else:
                L0 = Lbar
            P = np.block([[np.asarray(self.P1.value), np.zeros((n, n))], [np.zeros((n, n)), P2]])
            L_rho = np.zeros((0, n, p))
        elif self.Pj:
            # affine P(rho): L(rho) = (A(rho) - lam I) V (CV)^+ + P(rho)^-1 K(rho) Pi
            P = np.asarray(self.P.value)
            P_rho = np.array([0.5 * (np.asarray(Q.value) + np.asarray(Q.value).T)
                              for Q in self.Pj])
            K_rho = np.array([np.asarray(K.value) @ gd.Pi for K in self.Ks])
            L0 = (m.A0 - lam * np.eye(n)) @ gd.V @ gd.CVp
            L_rho = np.array([m.A_rho[j] @ gd.V @ gd.CVp for j in range(m.d)])
            P = 0.5 * (P + P.T)
            return Generator(gd.fault.name, self.spec.kind, lam, gd.V, gd.Fhat, self.spec.Dw,
                             self.spec.Ew, self.spec.Dn, gd.H, L0, L_rho, P, self.gamma2(),
                             tuple(self.spec.region), P_rho, K_rho)
        else:
            P = np.asarray(self.P.value)
            Lb = [np.linalg.solve(P, np.asarray(K.value)) for K in self.Ks]
            if self.sc:
                L0 = (m.A0 - lam * np.eye(n)) @ gd.V @ gd.CVp + Lb[0] @ gd.Pi
                L_rho = np.array([m.A_rho[j] @ gd.V @ gd.CVp + Lb[j + 1] @ gd.Pi
                                  for j in range(len(Lb) - 1)]).reshape(-1, n, p)
            else:
                L0 = Lb[0]
                L_rho = np.array(Lb[1:]).reshape(-1, n, p)
        P = 0.5 * (P + P.T)
        return Generator(gd.fault.name, self.spec.kind, lam if self.sc else float("nan"),
                         gd.V, gd.Fhat, self.spec.Dw, self.spec.Ew, self.spec.Dn, gd.H, L0,
                         L_rho, P, self.gamma2(), tuple(self.spec.region))


def _detectable_at(spec: BankSpec, gd: _GenData, lam: float) -> bool:
    """A-4.3.5 / A-5.2.5 / A-6.5: (Abar, Cbar) detectable (at every vertex for lpv)."""
    m = spec.model
    Cb = gd.Pi @ m.C
    verts = vertices(m.rho_min, m.rho_max) if spec.kind == "lpv" else [None]
    for v in verts:
        A = m.A(v) if spec.kind == "lpv" else m.A0
        Ab = A - (A - lam * np.eye(m.n)) @ gd.V @ gd.CVp @ m.C
        if not is_detectable(Ab, Cb):
            return False
    return True


def _solve_verified(prob: _Problem, lam: float, gen_lam: float, failed: str,
                    unverified: str) -> tuple[Generator, dict[str, Any], float]:
    """Solve ``prob`` at ``lam``, build its generator (lambda ``gen_lam``) and verify it with
    the loader's check: (generator, certificate, solve seconds); ``DesignError`` saying
    ``failed`` (status not optimal) or ``unverified`` (certificate fails) otherwise."""
    name = prob.gd.fault.name
    st, dt = prob.solve_at(lam)
    if st != cp.OPTIMAL:
        raise DesignError(f"hinf_sc: generator {name!r}: {failed} {st!r}")
    gen = prob.generator(gen_lam)
    try:
        return gen, check_generator(prob.spec.model, gen), dt
    except GainFileError as exc:
        raise DesignError(f"hinf_sc: generator {name!r}: {unverified}: {exc}") from None


def design_generator(spec: BankSpec, i: int) -> dict[str, Any]:
    """Grid over lambda, pick the smallest mu, re-solve and verify one generator."""
    gd = _gen_data(spec, i)
    name = gd.fault.name
    t0 = time.perf_counter()
    prob = _Problem(spec, gd, sc=True)
    build_s = time.perf_counter() - t0
    grid = np.array([spec.fixed_lambda]) if spec.fixed_lambda is not None else spec.grid
    mus, stats, solve_s = [], [], 0.0
    n_det = 0
    for lam in grid:
        if not _detectable_at(spec, gd, lam):
            mus.append(float("nan"))
            stats.append("not_detectable")
            continue
        n_det += 1
        st, dt = prob.solve_at(lam)
        solve_s += dt
        stats.append(st)
        mus.append(lam ** 2 * prob.cost() / gd.sens ** 2 if st == cp.OPTIMAL else float("nan"))
    tag = {"lti": "A-4.3.5", "uncertain": "A-5.2.5", "lpv": "A-6.5"}[spec.kind]
    if n_det == 0:
        raise DesignError(f"{spec.origin}: hinf_sc: generator {name!r}: assumption {tag} "
                          f"fails: (Abar, Cbar) is not detectable for any lambda of the grid")
    mu_arr = np.asarray(mus)
    if not np.any(np.isfinite(mu_arr)):
        eq = {"lti": "(4.47)", "uncertain": "(5.50)", "lpv": "(6.40)"}[spec.kind]
        raise DesignError(f"{spec.origin}: hinf_sc: generator {name!r}: LMI {eq} infeasible "
                          f"at every lambda of the grid (solver statuses: "
                          f"{sorted(set(stats))})")
    best = int(np.nanargmin(mu_arr))
    lam = float(grid[best])
    gen, cert, dt = _solve_verified(prob, lam, lam, f"re-solve at lambda = {lam} returned",
                                    f"the solver's answer at lambda = {lam} does not verify")
    out: dict[str, Any] = {
        "gen": gen, "cert": cert, "lambda": lam, "mu": float(mu_arr[best]),
        "gamma2": gen.gamma2, "k": gd.fault.k, "sensitivity": gd.sens,
        "mu_grid": {"lambda": grid.tolist(), "mu": mu_arr.tolist(), "status": stats},
        "solve_s": solve_s + dt, "build_s": build_s,
    }
    if spec.compare_pure:
        pg, pcert, _ = _solve_verified(_Problem(spec, gd, sc=False), 0.0, float("nan"),
                                       "pure attenuation design (4.24) returned",
                                       "the pure attenuation design (4.24) does not verify")
        out["pure"] = {"gen": pg, "cert": pcert, "gamma2": pg.gamma2}
    return out


# --------------------------------------------------------------------------------------
# bank


def _gen_to_plain(g: Generator) -> dict[str, Any]:
    out = {"fault": g.fault, "lambda": None if not np.isfinite(g.lam) else g.lam,
           "V": g.V, "Fhat": g.Fhat, "Dw": g.Dw, "Ew": g.Ew, "Dn": g.Dn, "H": g.H,
           "L0": g.L0, "L_rho": g.L_rho, "P": g.P, "gamma2": dict(g.gamma2),
           "region": [{"L": Lr, "M": Mr} for Lr, Mr in g.region]}
    if g.affine:
        out["P_rho"], out["K_rho"] = g.P_rho, g.K_rho
    return out


def dc_gains(model: AffineModel, gen: Generator, faults: Sequence[FaultDir],
             rho: np.ndarray | None = None) -> dict[str, float]:
    """Zero-frequency gains ``S_{f_j r_i}(0) = ||G(0)||^2`` (4.76) for every fault j."""
    out = {}
    for f in faults:
        if f.kind == "sensor_bias":
            Bin, Din = np.zeros((model.n, 1)), f.E
        else:
            Bin, Din = f.F[:, :1], np.zeros((model.C.shape[0], 1))
        A, B, C, D = generator_ss(model, gen, Bin, Din, rho)
        G0 = C @ np.linalg.solve(-A, B) + D
        out[f.name] = float(np.sum(G0 ** 2))
    return out


def design(system: System, section: Mapping[str, Any], origin: str = "<dict>",
           sha: str = "") -> dict[str, Any]:
    """Design the bank: ``system`` + design-file section -> gain-file contents.

    Returns
    -------
    dict
        ``parameters``, ``results``, ``certificate``, ``solver``, ``summary`` (per generator:
        fault, lambda, mu, gamma^2, zero-frequency gains), ``spec``.
    """
    spec = parse_spec(system, section, origin, sha)
    check_assumptions(spec)
    t0 = time.perf_counter()
    outs = [design_generator(spec, i) for i in range(len(spec.faults))]
    wall = time.perf_counter() - t0
    gens = [o["gen"] for o in outs]
    results: dict[str, Any] = {
        "kind": spec.kind,
        "sample_time": system.sample_time,
        "model": {"A0": spec.model.A0, "A_rho": spec.model.A_rho, "B0": spec.model.B0,
                  "B_rho": spec.model.B_rho, "C": spec.model.C,
                  "rho_names": list(spec.model.rho_names), "rho_min": spec.model.rho_min,
                  "rho_max": spec.model.rho_max, "scheduling": spec.model.scheduling,
                  **({"rate_min": spec.model.rate_min, "rate_max": spec.model.rate_max}
                     if spec.lyapunov == "affine" else {})},
        **({"lyapunov": "affine"} if spec.lyapunov == "affine" else {}),
        "generators": [dict(_gen_to_plain(g), k=o["k"], mu=o["mu"],
                            sensitivity=o["sensitivity"], mu_grid=o["mu_grid"])
                       for g, o in zip(gens, outs)],
    }
    if spec.compare_pure:
        results["pure"] = [_gen_to_plain(o["pure"]["gen"]) for o in outs]
    summary = []
    for o in outs:
        g = o["gen"]
        row = {"fault": g.fault, "lambda": o["lambda"], "mu": o["mu"],
               "gamma2": dict(g.gamma2), "k": o["k"]}
        rho0 = None if spec.kind == "lti" else 0.5 * (spec.model.rho_min + spec.model.rho_max)
        row["dc_gain"] = dc_gains(spec.model, g, spec.faults, rho0)
        if "pure" in o:
            row["pure_gamma2"] = dict(o["pure"]["gamma2"])
            row["pure_dc_gain"] = dc_gains(spec.model, o["pure"]["gen"], spec.faults, rho0)
        summary.append(row)
    thr = _thresholds(system, spec, results)
    if thr is not None:
        results["thresholds"] = thr[0]
        results["threshold_method"] = thr[1]
    parameters = {"kind": spec.kind, "faults": spec.generators, "weights": spec.weights,
                  "lambda_grid": spec.grid, "lambda": spec.fixed_lambda,
                  "region": spec.region_spec, "noise": bool(spec.Dn.shape[1]),
                  "compare_pure": spec.compare_pure,
                  **({"lyapunov": "affine", "rate": {"min": spec.model.rate_min,
                                                     "max": spec.model.rate_max}}
                     if spec.lyapunov == "affine" else {}),
                  "design_file": spec.origin,
                  "design_file_sha256": spec.sha256, "thresholds": dict(spec.thresholds),
                  "lmi_margin": EPS}
    certificate = {o["gen"].fault: o["cert"] for o in outs}
    solver = {"name": "CLARABEL", "status": "optimal", "time_s": wall,
              "solves": int(sum(len(o["mu_grid"]["lambda"]) + 1 for o in outs))}
    return {"parameters": parameters, "results": results, "certificate": certificate,
            "solver": solver, "summary": summary, "spec": spec}


def _thresholds(system: System, spec: BankSpec, results: dict[str, Any]
                ) -> tuple[list[float], dict[str, Any]] | None:
    th = dict(spec.thresholds)
    method = th.get("method", "none")
    ctx = design_checker(spec.origin, "hinf_sc.thresholds")
    margin = ctx.number("margin", th.get("margin", 1.0), positive=True)
    if method == "none":
        return None
    if method == "bound":
        lv = ctx.mapping("levels", th.get("levels") or {}, {"nuisance", "disturbance", "noise"})
        levels = {k: ctx.number(f"levels.{k}", v, nonneg=True) for k, v in lv.items()}
        J = bound_thresholds(results, levels, margin)
        return J.tolist(), {"method": "bound", "levels": levels, "margin": margin}
    sc = fault_free_scenario(ctx, th.get("scenario"), system, spec.origin,
                             "hinf_sc.thresholds")
    runs = int(ctx.number("runs", th.get("runs", 5), positive=True))
    settle = int(ctx.number("settle", th.get("settle", 0.0), nonneg=True) /
                 system.sample_time)
    lv = ctx.mapping("levels", th.get("levels") or {}, {"nuisance", "disturbance", "noise"})
    levels = {k: ctx.number(f"levels.{k}", v, nonneg=True) for k, v in lv.items()}
    tr = simulate_batch(sc, list(range(sc.seed, sc.seed + runs)))
    norms = []
    for r in range(runs):
        bank = ResidualBank(system, results)
        bank.reset(tr.x[r, 0])
        # an LPV bank without a scheduling map runs on the measured rho (the runs' rho(t))
        rho = tr.rho[r] if bank.kind == "lpv" and not bank.model.scheduling else None
        norms.append(bank.run(tr.u[r], tr.y[r], rho))
    # superposition (linear generators): the runs measure the fault-free residual (model
    # mismatch the bounds do not cover, e.g. an unmeasured rho, ch. 5), the stated levels add
    # the bound (4.17) on the response to the nuisance inputs the runs do not contain
    J = monte_carlo_thresholds(np.asarray(norms), settle, margin) + \
        bound_thresholds(results, levels, margin)
    return J.tolist(), {"method": "monte_carlo", "scenario": sc.name, "runs": runs,
                        "settle_s": settle * system.sample_time, "margin": margin,
                        **({"levels": levels} if levels else {})}


# --------------------------------------------------------------------------------------
# command line
