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

Readings of the paper (see the README section): ``L_{2,i}`` acts through an orthonormal
basis ``U_i`` of range(Gamma_i^perp) (``L_{2,i} = Lt_i U_i'``, the same family of observers,
better conditioned); LMI (26)/(39) are read with ``V_k = eps_k' P_{alpha(k-1)} eps_k``
(``U_i = P_i L_i``); in (44) ``P^a_i = diag(P_eps,i, P_h,i)`` so that ``L_i = P_eps,i^-1 U_i``
exactly, the output of (43) is ``r' = D_h r~ + C_h x^h`` (the print has ``D_h A2``), and
(44b) is the stability LMI of the augmented closed loop (fault rows dropped).

Design file section::

    hminus_switched:
      E: [[10, 10, 4], [-200, 1, -10]]            # q x n, common to all modes
      fault:
        E_f: {mode1: [[0.06], [1.2], [0.18]], mode2: [[0.07], [1.4], [0.49]]}  # n x nf
        F_f: [[0.01], [0.01]]                     # p x nf (all modes)
      D_add: [[0.046], [0.04]]                    # p x nf
      filter: {omega1: 0.095, omega2: 8.0, order: 2}   # F_H(s) (41), ZOH at Ts
      threshold: {method: none}                   # or {method: monte_carlo, runs, ...}
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import cvxpy as cp
import numpy as np

from fd_monitor.core.freq import sigma
from fd_monitor.core.generalized_observer import check_certificate, residual_ss
from fd_monitor.core.plant import zoh
from fd_monitor.errors import DesignError, GainFileError
from fd_monitor.gains import save_gains
from fd_monitor.paths import default_gain_path
from fd_monitor.system import System, load_system

from ._lmi_common import Ctx, load_design_section, solve

__all__ = ["add_arguments", "design", "run", "FREQS"]

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
    ctx = Ctx(origin, "hminus_switched")
    ctx.mapping("", sec, {"E", "fault", "D_add", "filter", "threshold", "description",
                          "require_hminus"})
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
        order = f.get("order", 1)
        if not isinstance(order, int) or isinstance(order, bool) or order < 1:
            ctx.fail("filter.order", "an integer >= 1", order)
        if w2 * system.sample_time >= np.pi:
            ctx.fail("filter.omega2", f"a corner below the Nyquist frequency "
                     f"{np.pi / system.sample_time:.4g} rad/s", w2)
        filt = (w1, w2, int(order))
    if (filt is None) != (Dadd is None):
        ctx.fail("filter", "filter and D_add together (the loop-shaping design (41)-(44))",
                 show=False)
    th = ctx.mapping("threshold", sec.get("threshold") or {"method": "none"})
    req = sec.get("require_hminus", False)
    if not isinstance(req, bool):
        ctx.fail("require_hminus", "true or false", req)
    return {"E": E, "Ef": Ef, "Ff": Ff, "Dadd": Dadd, "filter": filt, "threshold": th,
            "require_hminus": req}


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
    """F_H(s) = ((s/w1 + 1)/(s/w2 + 1))^m (41) on each of the p residuals, ZOH at dt."""
    w1, w2, m = filt
    # m first-order sections (s/w1 + 1)/(s/w2 + 1) = d + c b / (s + w2) in cascade, with
    # d = w2/w1, c b = w2 (1 - w2/w1) split evenly (a well-scaled realisation).
    d = w2 / w1
    cb = w2 * (1.0 - d)
    b1, c1 = np.sqrt(abs(cb)), np.sign(cb) * np.sqrt(abs(cb))
    Ac, Bc, Cc, Dc = (np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)),
                      np.ones((1, 1)))
    for _ in range(m):
        # series: previous (Ac, Bc, Cc, Dc) then the section (-w2, b1, c1, d)
        k = Ac.shape[0]
        Ac = np.block([[Ac, np.zeros((k, 1))], [b1 * Cc, np.array([[-w2]])]])
        Bc = np.vstack([Bc, b1 * Dc])
        Cc = np.hstack([d * Cc, np.array([[c1]])])
        Dc = d * Dc
    Ad, Bd = zoh(Ac, Bc, dt)
    k = np.eye(p)
    return {"A": np.kron(k, Ad), "B": np.kron(k, Bd), "C": np.kron(k, Cc),
            "D": np.kron(k, Dc), "omega1": w1, "omega2": w2, "order": m}


def _hminus(st: dict[str, Any], spec: dict[str, Any], filt: dict[str, Any], origin: str
            ) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray], float, str, float]:
    """Step 4 with the loop-shaped H-minus LMIs (44a)-(44b): maximise beta^2."""
    q, r = st["q"], st["r"]
    modes = st["modes"]
    N = len(modes)
    Ah, Bh, Ch, Dh = filt["A"], filt["B"], filt["C"], filt["D"]
    nh = Ah.shape[0]
    Dadd = spec["Dadd"]
    T = st["T"]
    Pe = [cp.Variable((q, q), symmetric=True) for _ in range(N)]
    Ph = [cp.Variable((nh, nh), symmetric=True) for _ in range(N)]
    Ws = [cp.Variable((q, r)) for _ in range(N)]
    b = cp.Variable(nonneg=True)
    scale = [float(np.linalg.norm(md["A2"])) for md in modes]
    Z = np.zeros
    cons = []

    def Pa(i: int) -> Any:
        return cp.bmat([[Pe[i], Z((q, nh))], [Z((nh, q)), Ph[i]]])

    for i, md in enumerate(modes):
        cons += [Pe[i] >> np.eye(q), Ph[i] >> EPS * np.eye(nh)]
        Cr = -md["C"] @ md["M"]
        Df = (np.eye(md["C"].shape[0]) - md["C"] @ md["N"]) @ spec["Ff"]
        B1f = md["G1"] @ spec["Ff"] - T @ spec["Ef"][i]
        B2f = md["G2"] @ spec["Ff"]
        A0 = np.block([[md["A1"], Z((q, nh))], [Bh @ Cr, Ah]])
        Bf0 = np.vstack([B1f, Bh @ (Df + Dadd)])
        Ca = np.hstack([Dh @ Cr, Ch])
        Da = Dh @ (Df + Dadd)
        nf = Da.shape[1]
        A2s, B2s = md["A2"] / scale[i], B2f / scale[i]
        PA = Pa(i) @ A0 - cp.bmat([[Ws[i] @ A2s, Z((q, nh))], [Z((nh, q)), Z((nh, nh))]])
        PB = Pa(i) @ Bf0 - cp.vstack([Ws[i] @ B2s, Z((nh, nf))])
        na = q + nh
        for j in range(N):
            M1 = cp.bmat([[-Pa(j) - Ca.T @ Ca, -Ca.T @ Da, PA.T],
                          [-(Da.T @ Ca), -Da.T @ Da + b * np.eye(nf), PB.T],
                          [PA, PB, -Pa(i)]])
            cons.append(0.5 * (M1 + M1.T) << -EPS * np.eye(2 * na + nf))
            M2 = cp.bmat([[-Pa(j), PA.T], [PA, -Pa(i)]])
            cons.append(0.5 * (M2 + M2.T) << -EPS * np.eye(2 * na))
    prob = cp.Problem(cp.Maximize(b), cons)
    status, dt = solve(prob, f"{origin}: hminus_switched: LMIs (44a)-(44b)")
    Pev = [np.asarray(p.value) for p in Pe]
    Lt = [np.linalg.solve(Pev[i], np.asarray(Ws[i].value)) / scale[i] for i in range(N)]
    Paug = [np.block([[Pev[i], Z((q, nh))], [Z((nh, q)), np.asarray(Ph[i].value)]])
            for i in range(N)]
    return Lt, Pev, Paug, float(b.value), status, dt


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
            Lh, Pe, Paug, beta2, hminus_status, _ = _hminus(st, spec, filt, origin)
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
                             "filter": {k: filt[k] for k in ("A", "B", "C", "D", "omega1",
                                                             "omega2", "order")}}
            observers["hminus"] = obs
    wall = time.perf_counter() - t0
    results: dict[str, Any] = {"E": spec["E"], "T": st["T"], "K": st["K"],
                               "sample_time": system.sample_time, "observers": observers}
    try:
        cert = check_certificate(system, results)
    except GainFileError as exc:
        raise DesignError(f"hminus_switched: the solver's answer does not verify: {exc}") \
            from None
    summary = {"q": st["q"], "beta": None if beta2 is None else float(np.sqrt(beta2)),
               "hminus_status": hminus_status,
               "sigma_min_db": sigma_table(results)}
    parameters = {"E": spec["E"], "filter": None if spec["filter"] is None else
                  dict(zip(("omega1", "omega2", "order"), spec["filter"])),
                  "D_add": spec["Dadd"], "design_file": origin, "design_file_sha256": sha,
                  "lmi_margin": EPS}
    return {"parameters": parameters, "results": results, "certificate": cert,
            "solver": {"name": "CLARABEL", "status": "optimal", "time_s": wall},
            "summary": summary}


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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``design hminus_switched``."""
    parser.add_argument("--design-file", metavar="PATH", default=None,
                        help="design file (default: <plant file stem>.design.yaml beside it)")
    parser.add_argument("--plot", metavar="DIR", default=None,
                        help="write the sensitivity plot (Fig. 3) into DIR")


def run(args: argparse.Namespace) -> int:
    """Design, write the gain file, print the summary."""
    from fd_monitor.commands._common import print_json, print_table

    system = load_system(args.system)
    sec, origin, sha = load_design_section(system, "hminus_switched", args.design_file)
    if not sec:
        raise DesignError(f"{origin}: hminus_switched: missing section (E, fault, ...)")
    out = design(system, sec, origin, sha)
    path = Path(args.output) if args.output else default_gain_path(system.name, "hminus_switched")
    save_gains(path, "hminus_switched", system, out["parameters"], out["results"],
               out["certificate"], out["solver"])
    plots: list[str] = []
    if args.plot:
        from fd_monitor.report_hinf import plot_switched

        plots = [str(p) for p in plot_switched(system, out["results"], args.plot)]
    doc = {"method": "hminus_switched", "system": system.name, "gain_file": str(path),
           "q": out["summary"]["q"], "beta": out["summary"]["beta"],
           "hminus_status": out["summary"]["hminus_status"],
           "frequencies_rad_s": list(FREQS), "sigma_min_db": out["summary"]["sigma_min_db"],
           "plots": plots}
    if args.json:
        print_json(doc)
    else:
        rows = [(d, m, *[f"{v:.2f}" for v in vals])
                for d, per in out["summary"]["sigma_min_db"].items() for m, vals in per.items()]
        print(f"H-minus design (44): {out['summary']['hminus_status']}")
        print_table(rows, header=["design", "mode", *[f"{w:g} rad/s" for w in FREQS]],
                    title=f"hminus_switched for {system.name} (q = {out['summary']['q']}, "
                          f"beta = {out['summary']['beta']}) -> {path}; sigma_min T_rf, dB")
    return 0
