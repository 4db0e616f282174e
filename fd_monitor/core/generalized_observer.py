"""Generalized Luenberger observers for switched discrete-time plants (Farhat & Koenig).

Runtime (numpy only) of what ``python -m fd_monitor design hminus_switched`` writes. For the
plant ``x+ = A_i x + B_i u + E_f,i f``, ``y = C_i x + F_f,i f`` (eq. 2) in mode ``i`` (measured,
A.3) the observer (eq. 3) is::

    z+ = F_i z + G_i y + J_i u,     xhat = M_i z + N_i y,     r = y - C_i xhat

with ``eps = z - T x`` obeying ``eps+ = F_i eps`` (10) when the algebraic constraints hold::

    F_i T + G_i C_i - T A_i = 0   (6a),   J_i - T B_i = 0   (6b),   M_i T + N_i C_i = I   (6c)

(a common ``T`` for every mode: with ``T_j`` of the next mode in (6a) the observer would need
to know the next mode). The residual is ``r = -C_i M_i eps + (I - C_i N_i) F_f,i f``
(from the definitions; the paper's (36) prints ``C_i M_i`` and ``C_i N_i + I``).

:func:`check_certificate` re-verifies (6a)-(6c) against the plant file and the switched
Lyapunov LMI (26) for every ordered pair of modes (i, j)::

    [[-P_j, F_i' P_i], [P_i F_i, -P_i]] < 0

read with the switched Lyapunov function ``V_k = eps_k' P_{alpha(k-1)} eps_k`` (so that
``U_i = P_i L_i`` carries the current mode's index), which proves convergence of the
estimation error under arbitrary switching.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from fd_monitor.model.errors import GainFileError
from fd_monitor.model.system import System

__all__ = ["GeneralizedObserver", "check_certificate", "stability_lmi", "hminus_lmi",
           "residual_ss", "simulate_switched"]


def _results(gains: Any) -> Mapping[str, Any]:
    return gains.results if hasattr(gains, "results") else gains


def _arr(v: Any, rows: int | None = None) -> np.ndarray:
    a = np.atleast_2d(np.asarray(v, dtype=float))
    return a.reshape(rows, -1) if rows is not None else a


def stability_lmi(Fi: np.ndarray, Pi: np.ndarray, Pj: np.ndarray) -> np.ndarray:
    """LMI (26) for the pair (i, j): ``[[-P_j, F_i' P_i], [P_i F_i, -P_i]]`` (symmetric)."""
    X = Pi @ Fi
    M = np.block([[-Pj, X.T], [X, -Pi]])
    return 0.5 * (M + M.T)


def hminus_lmi(Acl: np.ndarray, Bcl: np.ndarray, Ca: np.ndarray, Da: np.ndarray,
               Pi: np.ndarray, Pj: np.ndarray, beta2: float) -> np.ndarray:
    """H-minus inequality (39)/(44a) for the pair (i, j), non-Schur (KYP) form::

        [Acl Bcl]' P_i [Acl Bcl] - diag(P_j, -beta^2 I) - [Ca Da]' [Ca Da]  < 0

    i.e. ``V+ - V - r'r + beta^2 f'f < 0`` (40) with ``V_k = x_k' P_{alpha(k-1)} x_k``. Unlike
    the printed Schur form (whose ``-P_i`` block forces ``P_i > 0``) it is valid for
    sign-indefinite ``P`` (Remark 4); with ``x_0 = 0`` and a convergent switched error it
    gives ``||r||_2 >= beta ||f||_2`` under arbitrary switching.
    """
    nf = Bcl.shape[1]
    AB = np.hstack([Acl, Bcl])
    CD = np.hstack([Ca, Da])
    Z = np.zeros((Acl.shape[0], nf))
    M = AB.T @ Pi @ AB - np.block([[Pj, Z], [Z.T, -beta2 * np.eye(nf)]]) - CD.T @ CD
    return 0.5 * (M + M.T)


def residual_ss(obs: Mapping[str, Any], i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                        np.ndarray]:
    """Discrete-time map ``f -> r`` of mode ``i`` (37): ``(A, B, C, D)`` =
    ``(F_i, G_i F_f,i - T E_f,i, -C_i M_i, (I - C_i N_i) F_f,i)``."""
    m = obs["modes"][i]
    F, G, M, N = (_arr(m[k]) for k in ("F", "G", "M", "N"))
    T = _arr(obs["T"])
    C = _arr(m["C"])
    Ef, Ff = _arr(m["E_f"], T.shape[1]), _arr(m["F_f"], C.shape[0])
    p = C.shape[0]
    return F, G @ Ff - T @ Ef, -C @ M, (np.eye(p) - C @ N) @ Ff


class GeneralizedObserver:
    """Step-based generalized observer of a switched plant.

    Parameters
    ----------
    system : System
    gains : GainFile or mapping
        A loaded ``hminus_switched`` gain file (or its ``results``).
    design : str
        ``hminus`` (the H-minus / loop-shaped design, default) or ``stability`` (LMI 26 only).
    threshold : float, optional
        On ``||r||`` (output units); default the design's ``observers.<design>.threshold``
        (``design hminus_switched`` writes it), else ``results.threshold``, else +inf.

    Attributes
    ----------
    z : numpy.ndarray
        (q,) observer state.
    xhat : numpy.ndarray
        (n,) state estimate of the last step.
    """

    def __init__(self, system: System, gains: Any, design: str = "hminus",
                 threshold: float | None = None) -> None:
        res = _results(gains)
        if design not in res["observers"]:
            raise ValueError(f"design: expected one of {sorted(res['observers'])}, got "
                             f"{design!r}")
        obs = res["observers"][design]
        self.design = design
        self.modes = [{k: _arr(m[k]) for k in ("F", "G", "J", "M", "N", "C")}
                      for m in obs["modes"]]
        self.q = self.modes[0]["F"].shape[0]
        self.n = self.modes[0]["M"].shape[0]
        self.z = np.zeros(self.q)
        self.xhat = np.zeros(self.n)
        th = threshold if threshold is not None else obs.get("threshold",
                                                            res.get("threshold"))
        self.threshold = float("inf") if th is None else float(th)
        self.nu = system.nu

    def reset(self, z0: np.ndarray | None = None) -> None:
        """Observer state to ``z0`` (q,) (default zeros)."""
        self.z = np.zeros(self.q) if z0 is None else np.asarray(z0, dtype=float).copy()

    def step(self, k: int, u: np.ndarray, y: np.ndarray, mode: int) -> np.ndarray:
        """Process sample ``k`` in mode ``mode``; return the residual ``r_k`` (p,).

        Parameters
        ----------
        k : int
            Sample index.
        u : numpy.ndarray
            (nu,) input.
        y : numpy.ndarray
            (p,) measurement.
        mode : int
            Active mode index ``alpha(k)`` (measured).
        """
        m = self.modes[int(mode)]
        y = np.asarray(y, dtype=float).reshape(-1)
        u = np.asarray(u, dtype=float).reshape(-1)
        self.xhat = m["M"] @ self.z + m["N"] @ y
        r = y - m["C"] @ self.xhat
        zn = m["F"] @ self.z + m["G"] @ y
        if m["J"].size:
            zn = zn + m["J"] @ u
        self.z = zn
        return r

    def run(self, u: np.ndarray, y: np.ndarray, modes: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
        """Whole record: u (K, nu), y (K, p), modes (K,) -> (xhat (K, n), r (K, p))."""
        K = y.shape[0]
        xs, rs = np.empty((K, self.n)), np.empty((K, y.shape[1]))
        for k in range(K):
            rs[k] = self.step(k, u[k] if u.size else np.zeros(0), y[k], int(modes[k]))
            xs[k] = self.xhat
        return xs, rs


def check_certificate(system: System, gains: Any) -> dict[str, Any]:
    """Re-verify an ``hminus_switched`` gain file; ``GainFileError`` when it fails.

    For every stored design: the constraints (6a)-(6c) against the plant's discrete-time
    modes, and LMI (26) for every ordered pair of modes; for the H-minus design also the
    H-minus inequality (44a) (non-Schur form, indefinite ``P_aug``) of the loop-shaped
    augmented system of each mode (frozen mode, pair (i, i)) at the stored ``beta^2``.
    """
    res = _results(gains)
    obsd = res["observers"]
    T = _arr(res["T"])
    if len(system.modes) < 1:
        raise GainFileError("the plant has no modes")
    out: dict[str, Any] = {}
    for name, obs in obsd.items():
        modes = obs["modes"]
        if len(modes) != len(system.modes):
            raise GainFileError(f"observers.{name}: expected {len(system.modes)} modes, got "
                                f"{len(modes)}")
        Ps = [_arr(m["P"]) for m in modes]
        info: dict[str, Any] = {"constraint_residual": 0.0, "lmi26_max_eig": []}
        for i, (m, pm) in enumerate(zip(modes, system.modes)):
            if pm.dynamics != "linear" or pm.time != "discrete" or pm.A is None:
                raise GainFileError(f"mode {pm.name!r}: expected a discrete-time linear mode")
            F, G, J, M, N = (_arr(m[k]) for k in ("F", "G", "J", "M", "N"))
            if not np.allclose(_arr(m["C"]), pm.C, rtol=1e-12, atol=1e-12):
                raise GainFileError(f"observers.{name}.modes[{i}].C differs from the plant's "
                                    f"C of mode {pm.name!r}")
            n = pm.A.shape[0]
            scale = max(1.0, float(np.abs(T).max()) * max(1.0, float(np.abs(pm.A).max())))
            r6a = np.abs(F @ T + G @ pm.C - T @ pm.A).max() / scale
            r6b = np.abs(J - T @ pm.B).max() / scale if pm.B.size else 0.0
            r6c = np.abs(M @ T + N @ pm.C - np.eye(n)).max()
            worst = float(max(r6a, r6b, r6c))
            info["constraint_residual"] = max(info["constraint_residual"], worst)
            if worst > 1e-8:
                raise GainFileError(f"observers.{name}: mode {pm.name!r}: the observer "
                                    f"constraints (6a)-(6c) do not hold (residual "
                                    f"{worst:.3e})")
            if np.linalg.eigvalsh(0.5 * (Ps[i] + Ps[i].T)).min() <= 0:
                raise GainFileError(f"observers.{name}: P of mode {pm.name!r} is not positive "
                                    f"definite")
            for j in range(len(modes)):
                lm = float(np.linalg.eigvalsh(stability_lmi(F, Ps[i], Ps[j])).max())
                info["lmi26_max_eig"].append(lm)
                if not lm < 0:
                    raise GainFileError(f"observers.{name}: LMI (26) fails for the mode pair "
                                        f"({system.modes[i].name}, {system.modes[j].name}) "
                                        f"(max eigenvalue {lm:.3e})")
        if "hminus" in obs:
            info["lmi44a_max_eig"] = _check_44a(obs, modes, system)
        out[name] = info
    return out


def _check_44a(obs: Mapping[str, Any], modes: Sequence[Mapping[str, Any]],
               system: System) -> list[float]:
    h = obs["hminus"]
    Ah, Bh, Ch, Dh = (_arr(h["filter"][k]) for k in ("A", "B", "C", "D"))
    beta2 = float(h["beta2"])
    Dadd = _arr(h["D_add"])
    nh = Ah.shape[0]
    if nh and np.abs(np.linalg.eigvals(Ah)).max() >= 1:
        raise GainFileError("observers: the weighting filter F_H is not Schur stable")
    Pa = [_arr(m["P_aug"]) for m in modes]
    out = []
    for i, _m in enumerate(modes):
        F, B, Cr, D = residual_ss(obs, i)
        q = F.shape[0]
        Acl = np.block([[F, np.zeros((q, nh))], [Bh @ Cr, Ah]])
        Bcl = np.vstack([B, Bh @ (D + Dadd)])
        Ca = np.hstack([Dh @ Cr, Ch])
        Da = Dh @ (D + Dadd)
        for j in (i,):  # frozen mode (the mode-coupled pairs are infeasible, see design)
            lm = float(np.linalg.eigvalsh(hminus_lmi(Acl, Bcl, Ca, Da, Pa[i], Pa[j],
                                                     beta2)).max())
            out.append(lm)
            if not lm < 0:
                raise GainFileError(f"observers: H-minus inequality (44a) fails for the mode "
                                    f"pair ({system.modes[i].name}, {system.modes[j].name}) at "
                                    f"beta^2 = {beta2:.4g} (max eigenvalue {lm:.3e})")
    return out


def simulate_switched(A: Sequence[np.ndarray], B: Sequence[np.ndarray],
                      C: Sequence[np.ndarray], Ef: Sequence[np.ndarray],
                      Ff: Sequence[np.ndarray], modes: np.ndarray, x0: np.ndarray,
                      u: np.ndarray | None = None, f: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Simulate the switched plant (2): ``x+ = A_i x + B_i u + E_f,i f``, ``y = C_i x + F_f,i f``.

    Parameters
    ----------
    modes : numpy.ndarray
        (K,) int mode sequence ``alpha(k)``.
    u : numpy.ndarray, optional
        (K, nu); f : (K, nf), optional.

    Returns
    -------
    x : (K, n), y : (K, p)
    """
    K = modes.size
    n = A[0].shape[0]
    x = np.asarray(x0, dtype=float).copy()
    xs, ys = np.empty((K, n)), np.empty((K, C[0].shape[0]))
    for k in range(K):
        i = int(modes[k])
        fk = f[k] if f is not None else np.zeros(Ef[i].shape[1])
        xs[k] = x
        ys[k] = C[i] @ x + Ff[i] @ fk
        xn = A[i] @ x + Ef[i] @ fk
        if u is not None and B[i].size:
            xn = xn + B[i] @ u[k]
        x = xn
    return xs, ys
