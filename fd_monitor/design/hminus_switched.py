"""``design hminus_switched``: generalized Luenberger observers for switched plants.

Farhat & Koenig (ECC 2016), Sec. III-IV, for a discrete-time switched plant (2) with a
common free matrix ``E`` (q x n):

1. ``E`` from the design file (rank [E; C_i] = n, (5));
2. ``T = E [I; C]^+ [I; 0]``, ``K = E [I; C]^+ [0; I]`` (15);
3. ``Gamma_i = [E; C_i]``, ``Gamma_i^perp = I - Gamma_i Gamma_i^+``, ``Pi_1 = [I_q; 0]``,
   ``Pi_2 = [K; I_p]`` (17); ``M_i = Gamma_i^+ Pi_1``, ``N_i = Gamma_i^+ Pi_2`` (19, L_1 = 0),
   ``J_i = T B_i`` (6b);
4. the gains ``L_i``: stability-only (LMI 26) or H-minus with the loop-shaping filter
   (41)-(44);
5. ``F_i = A1_i - L_i A2_i``, ``G_i = G1_i - L_i G2_i`` (23, 24).

Readings of the paper (see doc/theory/hinf.md): ``L_{2,i}`` acts through an orthonormal
basis ``U_i`` of range(Gamma_i^perp) (``L_{2,i} = Lt_i U_i'``, the same family of observers,
better conditioned); LMI (26)/(39) are read with ``V_k = eps_k' P_{alpha(k-1)} eps_k``
(``U_i = P_i L_i``); in (44) ``P^a_i = diag(P_eps,i, P_h,i)`` so that ``L_i = P_eps,i^-1 U_i``
exactly, the output of (43) is ``r' = D_h r~ + C_h x^h`` (the print has ``D_h A2``).
The H-minus step does not use the printed Schur form of (44a): its ``-P_i`` block forces
``P^a > 0``, infeasible for this plant at any beta (see :func:`_hminus`); the gains maximise
the loop-shaped index subject to (26) with a decay rate (this replaces 44b: the filter is
Schur and fictitious), and the index is certified per mode by (44a) in non-Schur (KYP) form
with an indefinite ``P^a`` (Remark 4). F_H is discretised with Tustin, not ZOH.

Design file section::

    hminus_switched:
      E: [[10, 10, 4], [-200, 1, -10]]            # q x n, common to all modes
      fault:
        E_f: {mode1: [[0.06], [1.2], [0.18]], mode2: [[0.07], [1.4], [0.49]]}  # n x nf
        F_f: [[0.01], [0.01]]                     # p x nf (all modes)
      D_add: [[0.046], [0.04]]                    # p x nf
      filter: {omega1: 0.095, omega2: 8.0, order: 2}   # F_H(s) (41), Tustin at Ts
      decay_rate: 0.98                            # LMI (26) with rho^2 P_j (H-minus gains)
      threshold: {method: none}                   # or {method: monte_carlo, scenario,
                                                  #     runs, settle, margin} (_threshold)

Why one module of ~530 lines: the Farhat & Koenig design is one procedure (E, T, K, the LMIs
per mode, the Monte Carlo threshold section, the checks) read top to bottom against Sec.
III-IV of the paper; split, the derivation would be scattered.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import cvxpy as cp
import numpy as np
from scipy.linalg import solve_discrete_lyapunov
from scipy.optimize import minimize
from scipy.signal import cont2discrete, tf2ss

from fd_monitor.core.freq import freq_response, sigma
from fd_monitor.core.generalized_observer import check_certificate, residual_ss
from fd_monitor.core.runtime import HminusSwitchedRuntime
from fd_monitor.core.simulator import simulate_batch
from fd_monitor.design.hinf_thresholds import fault_free_scenario, monte_carlo_thresholds
from fd_monitor.model.errors import DesignError, GainFileError
from fd_monitor.model.system import System

from ._lmi_common import design_checker, solve

__all__ = [ "design", "FREQS"]

EPS = 1e-6
#: Frequencies (rad/s) of the reported minimum singular values.
FREQS = (0.001, 0.01, 0.1, 1.0, 10.0)


def _detectable_discrete(A: np.ndarray, C: np.ndarray) -> bool:
    n = A.shape[0]
    for z in np.linalg.eigvals(A):
        if abs(z) < 1 - 1e-12:
            continue
        s = np.linalg.svd(np.vstack([z * np.eye(n) - A, C.astype(complex)]), compute_uv=False)
        if s[-1] <= 1e-9 * max(1.0, float(np.linalg.norm(A))):
            return False
    return True


def _parse(system: System, sec: Mapping[str, Any], origin: str) -> dict[str, Any]:
    ctx = design_checker(origin, "hminus_switched")
    ctx.mapping("", sec, {"E", "fault", "D_add", "filter", "threshold", "description",
                          "require_hminus", "decay_rate"})
    n, p = system.n, system.ny
    for m in system.modes:
        if m.dynamics != "linear" or m.time != "discrete":
            raise DesignError(f"{system.source}: modes.{m.name}: expected a discrete-time "
                              f"linear mode (Farhat & Koenig eq. 1)")
    if "E" not in sec:
        ctx.fail("E", "the free q x n matrix E of (5) (missing key)", show=False)
    E = ctx.matrix("E", sec["E"], (None, n))
    fault = ctx.mapping("fault", sec.get("fault") or {}, {"E_f", "F_f"})
    efr = ctx.mapping("fault.E_f", fault.get("E_f") or {}, set(system.mode_names))
    Ef, nf = [], None
    for m in system.modes:
        if m.name not in efr:
            ctx.fail(f"fault.E_f.{m.name}", "an n x nf matrix for every mode (missing mode)",
                     show=False)
        e = ctx.matrix(f"fault.E_f.{m.name}", efr[m.name], (n, nf))
        nf = e.shape[1]
        Ef.append(e)
    assert nf is not None
    Ff = ctx.matrix("fault.F_f", fault.get("F_f"), (p, nf))
    Dadd = ctx.matrix("D_add", sec.get("D_add"), (p, nf)) if "D_add" in sec else None
    filt = None
    if "filter" in sec:
        f = ctx.mapping("filter", sec["filter"], {"omega1", "omega2", "order"})
        w1 = ctx.number("filter.omega1", f.get("omega1"), positive=True)
        w2 = ctx.number("filter.omega2", f.get("omega2"), positive=True)
        if w2 <= w1:
            ctx.fail("filter.omega2", f"omega2 > omega1 = {w1} (41)", w2)
        order = ctx.integer("filter.order", f.get("order", 1), 1)
        if w2 * system.sample_time >= np.pi:
            ctx.fail("filter.omega2", f"a corner below the Nyquist frequency "
                     f"{np.pi / system.sample_time:.4g} rad/s", w2)
        filt = (w1, w2, order)
    if (filt is None) != (Dadd is None):
        ctx.fail("filter", "filter and D_add together (the loop-shaping design (41)-(44))",
                 show=False)
    th = _threshold_spec(system, ctx.mapping("threshold", sec.get("threshold") or
                                             {"method": "none"}), origin)
    req = ctx.boolean("require_hminus", sec.get("require_hminus", False))
    rho = ctx.number("decay_rate", sec.get("decay_rate", 0.98), positive=True)
    if rho > 1:
        ctx.fail("decay_rate", "a number in (0, 1] (LMI 26 with rho^2 P_j)", rho)
    return {"E": E, "Ef": Ef, "Ff": Ff, "Dadd": Dadd, "filter": filt, "threshold": th,
            "require_hminus": req, "decay_rate": rho, "dt": system.sample_time}


def _structure(system: System, E: np.ndarray, origin: str) -> dict[str, Any]:
    """Steps 1-3: T, K, Gamma, M, N, J and A1, A2, G1, G2 per mode."""
    n, p = system.n, system.ny
    q = E.shape[0]
    Ts, Ks, modes = [], [], []
    for m in system.modes:
        assert m.A is not None
        if not _detectable_discrete(m.A, m.C):
            raise DesignError(f"{origin}: hminus_switched: assumption A.1 fails: (A, C) of "
                              f"mode {m.name!r} is not detectable")
        Gam = np.vstack([E, m.C])
        if np.linalg.matrix_rank(Gam) < n:
            raise DesignError(f"{origin}: hminus_switched.E: assumption A.2 fails: rank "
                              f"[E; C] < n = {n} in mode {m.name!r} (5)")
        IC = np.vstack([np.eye(n), m.C])
        X = E @ np.linalg.pinv(IC)
        T, K = X[:, :n], X[:, n:]
        Ts.append(T)
        Ks.append(K)
        Gp = np.linalg.pinv(Gam)
        Gperp = np.eye(q + p) - Gam @ Gp
        U, s, _ = np.linalg.svd(Gperp)
        r = int((s > 1e-9).sum())
        U = U[:, :r]
        Pi1 = np.vstack([np.eye(q), np.zeros((p, q))])
        Pi2 = np.vstack([K, np.eye(p)])
        modes.append({
            "name": m.name, "A": m.A, "B": m.B, "C": m.C, "M": Gp @ Pi1, "N": Gp @ Pi2,
            "A1": T @ m.A @ Gp @ Pi1, "A2": U.T @ Pi1, "G1": T @ m.A @ Gp @ Pi2,
            "G2": U.T @ Pi2, "U": U, "K": K, "T": T,
        })
    for T in Ts[1:]:
        if not np.allclose(T, Ts[0], atol=1e-10):
            raise DesignError(f"{origin}: hminus_switched.E: T differs between modes (the "
                              f"modes' C differ); (6a) would need T of the next mode, unknown "
                              f"under arbitrary switching: use modes with a common C")
    T = Ts[0]
    for md in modes:
        md["J"] = T @ md["B"] if md["B"].size else np.zeros((E.shape[0], 0))
    return {"T": T, "K": Ks[0], "modes": modes, "q": q, "r": modes[0]["A2"].shape[0]}


def _observer(st: dict[str, Any], Lt: list[np.ndarray], Ps: list[np.ndarray],
              spec: dict[str, Any]) -> dict[str, Any]:
    out = []
    for i, md in enumerate(st["modes"]):
        F = md["A1"] - Lt[i] @ md["A2"]
        G = md["G1"] - Lt[i] @ md["G2"]
        out.append({"F": F, "G": G, "J": md["J"], "M": md["M"], "N": md["N"], "C": md["C"],
                    "L2": Lt[i] @ md["U"].T, "P": Ps[i], "E_f": spec["Ef"][i],
                    "F_f": spec["Ff"]})
    return {"T": st["T"], "modes": out}


def _stability(st: dict[str, Any], origin: str) -> tuple[list[np.ndarray], list[np.ndarray],
                                                           str, float]:
    """Step 4 with LMI (26): P_i >= I, minimise sum trace P_i."""
    q, r = st["q"], st["r"]
    modes = st["modes"]
    N = len(modes)
    Ps = [cp.Variable((q, q), symmetric=True) for _ in range(N)]
    Ws = [cp.Variable((q, r)) for _ in range(N)] if r else []
    scale = [max(float(np.linalg.norm(md["A2"])), 1e-300) for md in modes]
    cons = []
    for i, md in enumerate(modes):
        cons.append(Ps[i] >> np.eye(q))
        X = Ps[i] @ md["A1"] - (Ws[i] @ (md["A2"] / scale[i]) if r else 0)
        for j in range(N):
            M = cp.bmat([[-Ps[j], X.T], [X, -Ps[i]]])
            cons.append(0.5 * (M + M.T) << -EPS * np.eye(2 * q))
    prob = cp.Problem(cp.Minimize(sum(cp.trace(P) for P in Ps)), cons)
    status, dt = solve(prob, "", raise_on_failure=False)
    if status != cp.OPTIMAL:
        margins = []
        for md in modes:
            z = np.linalg.eigvals(md["A1"])
            margins.append(min(np.linalg.svd(np.vstack([zz * np.eye(q) - md["A1"], md["A2"]]),
                                             compute_uv=False)[-1] for zz in z) if r else 0.0)
        raise DesignError(
            f"{origin}: hminus_switched: LMI (26) is {status} for this E: no switched "
            f"quadratic Lyapunov function makes the error converge under arbitrary switching "
            f"(eigenvalues of A1_i: "
            f"{[np.round(np.abs(np.linalg.eigvals(md['A1'])), 3).tolist() for md in modes]}, "
            f"smallest PBH margin of (A1_i, A2_i): {[f'{m:.1e}' for m in margins]}); choose "
            f"another E")
    P = [np.asarray(p.value) for p in Ps]
    Lt = [np.linalg.solve(P[i], np.asarray(Ws[i].value)) / scale[i] if r
          else np.zeros((q, 0)) for i in range(N)]
    return Lt, P, status, dt


def _filter(filt: tuple[float, float, int], p: int, dt: float) -> dict[str, Any]:
    """F_H(s) = ((s/w1 + 1)/(s/w2 + 1))^m (41) on each of the p residuals, Tustin at dt.

    The weight is discretised with the bilinear (Tustin) map, not ZOH: ZOH delays the
    strictly proper part by half a sample while the feedthrough ``(w2/w1)^m`` (~7e3 here)
    is kept, so the two no longer cancel at low frequency (|F_H| at 0.1 rad/s became 47
    instead of 2.1 with the Sec. V data). The realisation is balanced (entries <= 1e2).
    """
    w1, w2, m = filt
    num = np.poly1d([1.0 / w1, 1.0]) ** m
    den = np.poly1d([1.0 / w2, 1.0]) ** m
    Ac, Bc, Cc, Dc = tf2ss(num.coeffs, den.coeffs)
    Ad, Bd, Cd, Dd, _ = cont2discrete((Ac, Bc, Cc, Dc), dt, method="bilinear")
    Tm, Ti = _balancing(Ad, Bd, Cd)
    k = np.eye(p)
    return {"A": np.kron(k, Ti @ Ad @ Tm), "B": np.kron(k, Ti @ Bd), "C": np.kron(k, Cd @ Tm),
            "D": np.kron(k, np.atleast_2d(Dd)), "omega1": w1, "omega2": w2, "order": m,
            "discretisation": "tustin"}


def _error_system(st: dict[str, Any], spec: dict[str, Any], i: int, Lt: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(37)-(38) of mode ``i`` for the gain ``Lt``: ``(F, B_f, C_r, D_f)``."""
    md = st["modes"][i]
    F = md["A1"] - Lt @ md["A2"]
    Bf = (md["G1"] - Lt @ md["G2"]) @ spec["Ff"] - st["T"] @ spec["Ef"][i]
    Cr = -md["C"] @ md["M"]
    Df = (np.eye(md["C"].shape[0]) - md["C"] @ md["N"]) @ spec["Ff"]
    return F, Bf, Cr, Df


def _augmented(F: np.ndarray, Bf: np.ndarray, Cr: np.ndarray, Df: np.ndarray,
               filt: Mapping[str, Any], Dadd: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The loop-shaped residual (43): ``r' = F_H (r + D_add f)`` (output read ``D_h r~``)."""
    Ah, Bh, Ch, Dh = filt["A"], filt["B"], filt["C"], filt["D"]
    q, nh = F.shape[0], Ah.shape[0]
    Acl = np.block([[F, np.zeros((q, nh))], [Bh @ Cr, Ah]])
    Bcl = np.vstack([Bf, Bh @ (Df + Dadd)])
    return Acl, Bcl, np.hstack([Dh @ Cr, Ch]), Dh @ (Df + Dadd)


def _stability_fixed_gain(st: dict[str, Any], Lt: list[np.ndarray], rho: float
                          ) -> tuple[Any, list[Any], Any, list[Any]]:
    """LMI (26) with decay rate ``rho`` for given gains (DPP: gains are parameters).

    ``[[-rho^2 P_j, F_i' P_i], [P_i F_i, -P_i]] <= t I``, ``P_i >= I``, ``tr P <= 1e4``;
    minimise ``t``: the gains stabilise under arbitrary switching iff ``t < 0``.
    """
    q = st["q"]
    N = len(st["modes"])
    Fp = [cp.Parameter((q, q)) for _ in range(N)]
    Ps = [cp.Variable((q, q), symmetric=True) for _ in range(N)]
    t = cp.Variable()
    cons = [P >> np.eye(q) for P in Ps] + [sum(cp.trace(P) for P in Ps) <= 1e4]
    for i in range(N):
        X = Ps[i] @ Fp[i]
        for j in range(N):
            M = cp.bmat([[-rho ** 2 * Ps[j], X.T], [X, -Ps[i]]])
            cons.append(0.5 * (M + M.T) << t * np.eye(2 * q))
    prob = cp.Problem(cp.Minimize(t), cons)
    for i in range(N):
        Fp[i].value = st["modes"][i]["A1"] - Lt[i] @ st["modes"][i]["A2"]
    return prob, Fp, t, Ps


def _hminus(st: dict[str, Any], spec: dict[str, Any], filt: dict[str, Any], Lt0: list[np.ndarray],
            origin: str) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray], float,
                                  str, float]:
    """Step 4, loop-shaped H-minus design (41)-(44): maximise beta, then certify it.

    Why the printed LMIs cannot be used as they stand: (39)/(44a) are the Schur-complement
    form of ``[A B]' P_i [A B] - diag(P_j, -beta^2 I) - [C D]'[C D] < 0``; their last
    diagonal block ``-P_i`` forces ``P_i > 0``, which for an H-minus (lower-bound) inequality
    means ``beta^2 < lambda_min(D'D - B'P_i B)`` and, at any beta, a P-contraction of the
    dynamics on ``{(x, f): C x + D f = 0}``. For this plant no ``P^a > 0`` exists even at
    beta = 0 (the largest feasible beta^2 is -3.6e-3 in units of ||D_a||^2, with P^a
    indefinite in the filter block as well), so the colleague's (44a)+(44b) is infeasible by
    structure, not by scaling. The H-minus inequality needs ``P`` sign-indefinite (Remark
    4; it is then the KYP form), which is bilinear in (P, L): not an LMI in the gain.

    Therefore: (a) the gains ``L_i`` (q x r, here 2 x 1 per mode) maximise the loop-shaped
    index ``min_i min_w sigma_min(F_H (T_rf,i + D_add))`` on a frequency grid (Nelder-Mead
    from the stability-only gains) subject to LMI (26) with decay rate ``rho`` (an SDP per
    evaluation, penalty when infeasible); (b) for the gains found, (26) is solved for
    ``P_i >= I`` and the H-minus LMI (44a) in its non-Schur form with indefinite ``X_i``
    (linear in ``X_i`` and ``beta^2``) is maximised over ``beta^2``: ``V+ - V - r'r +
    beta^2 f'f < 0`` with ``V = x' X_{alpha(k-1)} x`` sums to ``||r'||^2 >= beta^2 ||f||^2``
    from ``x_0 = 0`` because the switched error converges (26) and the filter is Schur.
    """
    t0 = time.perf_counter()
    Lt, P = _search_gains(st, spec, filt, Lt0, origin)
    # (b) certified H-minus index per mode: (44a) in non-Schur (KYP) form, X_i indefinite.
    # The mode-coupled version (X_i next to X_j, i != j) is infeasible for these gains
    # (beta^2 < 0): the H-minus bound is certified for each mode, not under arbitrary
    # switching (the error's convergence under arbitrary switching is, by (26)).
    Xa, b2s = [], []
    status = cp.OPTIMAL
    for i in range(len(st["modes"])):
        b2, X, status = _certify_mode(st, spec, filt, i, Lt[i], origin)
        b2s.append(b2)
        Xa.append(X)
    beta2 = min(b2s) * (1 - 1e-4)
    return Lt, P, Xa, beta2, status, time.perf_counter() - t0


def _search_gains(st: dict[str, Any], spec: dict[str, Any], filt: dict[str, Any],
                  Lt0: list[np.ndarray], origin: str
                  ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(a) of :func:`_hminus`: the gains ``L_i`` (q, r) maximising the loop-shaped index
    (Nelder-Mead from ``Lt0``) subject to LMI (26) with decay rate ``rho``, and the ``P_i``
    of (26) at the gains found; ``DesignError`` when they do not satisfy (26)."""
    N = len(st["modes"])
    q, r = st["q"], st["r"]
    dt = spec["dt"]
    rho = spec["decay_rate"]
    Dadd = spec["Dadd"]
    w = np.logspace(-4, np.log10(0.999 * np.pi / dt), 160)
    FH = freq_response(filt["A"], filt["B"], filt["C"], filt["D"], w, dt)  # (K, p, p)
    prob, Fp, tvar, Ps = _stability_fixed_gain(st, Lt0, rho)

    def unpack(x: np.ndarray) -> list[np.ndarray]:
        return [x[i * q * r:(i + 1) * q * r].reshape(q, r) for i in range(N)]

    def index(Lt: list[np.ndarray]) -> float:
        vals = []
        for i in range(N):
            F, Bf, Cr, Df = _error_system(st, spec, i, Lt[i])
            if np.abs(np.linalg.eigvals(F)).max() >= rho:
                return -np.inf
            G = freq_response(F, Bf, Cr, Df + Dadd, w, dt)
            vals.append(np.linalg.svd(FH @ G, compute_uv=False)[:, -1].min())
        return float(min(vals))

    def stab_t(Lt: list[np.ndarray]) -> float:
        for i in range(N):
            Fp[i].value = st["modes"][i]["A1"] - Lt[i] @ st["modes"][i]["A2"]
        try:
            prob.solve(solver=cp.CLARABEL)
        except cp.SolverError:
            return np.inf
        return float(tvar.value) if prob.status == cp.OPTIMAL else np.inf

    def cost(x: np.ndarray) -> float:
        Lt = unpack(x)
        v = index(Lt)
        if not np.isfinite(v):
            return 1e6
        t = stab_t(Lt)
        return -v + (1e3 * (t + 1e-3) if t > -1e-3 else 0.0)

    x0 = np.concatenate([L.ravel() for L in Lt0])
    res = minimize(cost, x0, method="Nelder-Mead",
                   options={"maxiter": 1200, "xatol": 1e-7, "fatol": 1e-10})
    Lt = unpack(res.x)
    if not (stab_t(Lt) < -1e-4 and prob.status == cp.OPTIMAL):
        raise DesignError(f"{origin}: hminus_switched: the H-minus search ended on gains that "
                          f"do not satisfy LMI (26) with decay rate {rho}")
    return Lt, [np.asarray(Pv.value) for Pv in Ps]


def _balancing(A: np.ndarray, B: np.ndarray, C: np.ndarray, scale: float = 1.0,
               reg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(Tm, Ti): balancing transformation ``x = Tm z``, ``z = Ti x`` of a stable discrete
    system (A, B, C / scale), from its Gramians (each plus ``reg I`` when ``reg > 0``)."""
    QB, QC = B @ B.T, C.T @ C / scale ** 2
    if reg > 0:
        QB, QC = QB + reg * np.eye(A.shape[0]), QC + reg * np.eye(A.shape[0])
    Wc = solve_discrete_lyapunov(A, QB)
    Wo = solve_discrete_lyapunov(A.T, QC)
    Lc, Lo = np.linalg.cholesky(Wc), np.linalg.cholesky(Wo)
    U, sv, Vt = np.linalg.svd(Lo.T @ Lc)
    return Lc @ Vt.T @ np.diag(sv ** -0.5), np.diag(sv ** -0.5) @ U.T @ Lo.T


def _certify_mode(st: dict[str, Any], spec: dict[str, Any], filt: dict[str, Any], i: int,
                  Li: np.ndarray, origin: str) -> tuple[float, np.ndarray, str]:
    """(b) of :func:`_hminus` for mode ``i``: the largest beta^2 of (44a) in non-Schur (KYP)
    form with X indefinite, solved in balanced coordinates of the mode's augmented system
    with the output scaled by ``||D_a||``; returns (beta^2, X in original coordinates,
    solver status)."""
    Acl, Bcl, Ca, Da = _augmented(*_error_system(st, spec, i, Li), filt, spec["Dadd"])
    na, nf = Acl.shape[0], Bcl.shape[1]
    sc = float(np.linalg.norm(Da))
    Tm, Ti = _balancing(Acl, Bcl, Ca, sc, 1e-9)
    AB = np.hstack([Ti @ Acl @ Tm, Ti @ Bcl])
    CD = np.hstack([Ca @ Tm, Da]) / sc
    X = cp.Variable((na, na), symmetric=True)
    b = cp.Variable()
    Zf = np.zeros((na, nf))
    M = AB.T @ X @ AB - cp.bmat([[X, Zf], [Zf.T, -b * np.eye(nf)]]) - CD.T @ CD
    hprob = cp.Problem(cp.Maximize(b), [0.5 * (M + M.T) << -EPS * np.eye(na + nf)])
    name = st["modes"][i]["name"]
    status, _ = solve(hprob, f"{origin}: hminus_switched: H-minus certificate (44a), "
                             f"mode {name}")
    if b.value is None or float(b.value) <= 0:
        raise DesignError(f"{origin}: hminus_switched: H-minus certificate (44a) gives "
                          f"beta^2 = {b.value} <= 0 in mode {name}")
    return float(b.value) * sc ** 2, Ti.T @ np.asarray(X.value) @ Ti * sc ** 2, status


def design(system: System, sec: Mapping[str, Any], origin: str = "<dict>", sha: str = ""
           ) -> dict[str, Any]:
    """Design the stability-only and (when a filter is given) the H-minus observers."""
    spec = _parse(system, sec, origin)
    t0 = time.perf_counter()
    st = _structure(system, spec["E"], origin)
    if st["r"] == 0:
        raise DesignError(f"{origin}: hminus_switched.E: q + p = n leaves no design freedom "
                          f"(Gamma^perp = 0); take q > n - p rows in E")
    Lt, Ps, _, _t_s = _stability(st, origin)
    observers = {"stability": _observer(st, Lt, Ps, spec)}
    beta2 = None
    hminus_status = "not requested (no filter)"
    if spec["filter"] is not None:
        filt = _filter(spec["filter"], system.ny, system.sample_time)
        try:
            Lh, Pe, Paug, beta2, hminus_status, _ = _hminus(st, spec, filt, Lt, origin)
        except DesignError as exc:
            # Refused (not optimal): the gain file keeps the stability-only observer and
            # the summary says why; require_hminus: true turns this into an error.
            if spec["require_hminus"]:
                raise
            hminus_status = f"refused: {exc}"
        else:
            obs = _observer(st, Lh, Pe, spec)
            for m, pa in zip(obs["modes"], Paug):
                m["P_aug"] = pa
            obs["hminus"] = {"beta2": beta2, "D_add": spec["Dadd"],
                             "decay_rate": spec["decay_rate"],
                             "filter": {k: filt[k] for k in ("A", "B", "C", "D", "omega1",
                                                             "omega2", "order",
                                                             "discretisation")}}
            observers["hminus"] = obs
    results: dict[str, Any] = {"E": spec["E"], "T": st["T"], "K": st["K"],
                               "sample_time": system.sample_time, "observers": observers}
    th_method = _threshold(system, spec["threshold"], results)
    if th_method is not None:
        results["threshold_method"] = th_method
    wall = time.perf_counter() - t0
    try:
        cert = check_certificate(system, results)
    except GainFileError as exc:
        raise DesignError(f"hminus_switched: the solver's answer does not verify: {exc}") \
            from None
    summary = {"q": st["q"], "beta": None if beta2 is None else float(np.sqrt(beta2)),
               "hminus_status": hminus_status,
               "sigma_min_db": sigma_table(results), "decay_rate": spec["decay_rate"]}
    sm = summary["sigma_min_db"]
    summary["improvement_db"] = None if "hminus" not in sm else {
        m: [h - s0 for h, s0 in zip(sm["hminus"][m], sm["stability"][m])]
        for m in sm["stability"]}
    parameters = {"E": spec["E"], "filter": None if spec["filter"] is None else
                  dict(zip(("omega1", "omega2", "order"), spec["filter"])),
                  "D_add": spec["Dadd"], "design_file": origin, "design_file_sha256": sha,
                  "lmi_margin": EPS}
    return {"parameters": parameters, "results": results, "certificate": cert,
            "solver": {"name": "CLARABEL", "status": "optimal", "time_s": wall},
            "summary": summary}


def _threshold_spec(system: System, th: Mapping[str, Any], origin: str
                    ) -> dict[str, Any] | None:
    """The ``threshold`` section, checked before solving: None (``method: none``) or
    ``{scenario, runs, settle (samples), margin}`` for ``monte_carlo``."""
    ctx = design_checker(origin, "hminus_switched.threshold")
    ctx.mapping("", th, {"method", "scenario", "runs", "settle", "margin"})
    method = th.get("method", "none")
    if method == "none":
        return None
    if method != "monte_carlo":
        ctx.fail("method", "none or monte_carlo", method)
    sc = fault_free_scenario(ctx, th.get("scenario"), system, origin,
                             "hminus_switched.threshold")
    runs = ctx.integer("runs", th.get("runs", 5), 1)
    settle_s = ctx.number("settle", th.get("settle", 0.0), nonneg=True)
    margin = ctx.number("margin", th.get("margin", 1.0), positive=True)
    settle = round(settle_s / system.sample_time)
    if settle >= round(sc.duration / system.sample_time):
        ctx.fail("settle", f"less than the scenario's duration {sc.duration} s", settle_s)
    return {"scenario": sc, "runs": runs, "settle": settle, "margin": margin}


def _threshold(system: System, th: Mapping[str, Any] | None, results: dict[str, Any]
               ) -> dict[str, Any] | None:
    """Monte Carlo threshold on ``||r_k||`` (:func:`_threshold_spec`): ``margin * max
    ||r_k||`` over ``runs`` fault-free simulated runs (seeds ``seed .. seed + runs - 1`` of
    the scenario) after ``settle`` samples, for each observer (stored as
    ``observers.<design>.threshold``), run by the same runtime the nodes and ``analyze`` use
    (:class:`~fd_monitor.core.runtime.HminusSwitchedRuntime`, switching signal: the runs'
    true mode). Returns ``threshold_method`` or None."""
    if th is None:
        return None
    sc = th["scenario"]
    traj = simulate_batch(sc, list(range(sc.seed, sc.seed + th["runs"])))
    for name, obs in results["observers"].items():
        res = HminusSwitchedRuntime.run_batch(system, results, traj, design=name).residual
        assert res is not None  # the H-minus batch always carries its residual norms
        obs["threshold"] = float(monte_carlo_thresholds(res, th["settle"], th["margin"])[0])
    return {"method": "monte_carlo", "scenario": sc.name, "runs": th["runs"],
            "settle_s": th["settle"] * system.sample_time, "margin": th["margin"]}


def sigma_table(results: Mapping[str, Any], freqs: tuple[float, ...] = FREQS
                ) -> dict[str, dict[str, list[float]]]:
    """Minimum singular value (dB) of ``T_rf`` of each design and mode at ``freqs`` rad/s."""
    dt = float(results["sample_time"])
    out: dict[str, dict[str, list[float]]] = {}
    for name, obs in results["observers"].items():
        out[name] = {}
        for i in range(len(obs["modes"])):
            A, B, C, D = residual_ss(obs, i)
            s = sigma(A, B, C, D, np.asarray(freqs), dt)[:, -1]
            out[name][f"mode{i + 1}"] = (20 * np.log10(s)).tolist()
    return out
