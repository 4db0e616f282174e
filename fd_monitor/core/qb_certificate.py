"""The QB certificate: the LMIs evaluated at a point, the bounds they give, and the loader's check.

* :func:`lmi_blocks` -- the LMIs (7a)/(14a) (continuous) or their discrete-time counterpart
  (derived in :mod:`fd_monitor.core.qb`), used by the designer's self-check and by
  :func:`check_certificate`;
* :func:`qb_bounds` -- rho_max (eq. 6), r_max (eq. 11) and the tighter bounds that follow from
  the same ellipsoid ``e' P e <= 1``: ``|e_j| <= sqrt((P^-1)_jj)`` and per output
  ``|r_i| <= sqrt(c_i P^-1 c_i') + sum_j |E_ij|``;
* :func:`gains_matrices` / :func:`gains_model` -- P, L and the model a gain file was made for;
* :func:`check_certificate` -- what :func:`fd_monitor.core.methods.load_gains` runs on a ``qb``
  gain file: recomputes the LMIs and bounds and refuses a file whose numbers do not hold.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from fd_monitor.core.qb_model import QBModel, qb_model, spectral_abscissa
from fd_monitor.model.errors import DesignError, GainFileError
from fd_monitor.model.system import System

__all__ = [
    "lmi_blocks",
    "qb_bounds",
    "gains_matrices",
    "gains_model",
    "guarantee",
    "ellipsoid_bound",
    "check_certificate",
]


#: Relative tolerance when the loader compares a recorded number with its recomputation.
_REL_TOL = 1e-6


def lmi_blocks(model: QBModel, P: np.ndarray, L: np.ndarray, alpha: np.ndarray,
               beta: float) -> list[np.ndarray]:
    """The QB LMI matrices evaluated at a point; each must be negative definite.

    Continuous time: (7a)/(14a) with ``Y_i = P L_i``; discrete time: the counterpart in the
    module docstring.

    Parameters
    ----------
    model : QBModel
    P : numpy.ndarray
        (n, n) symmetric positive definite.
    L : numpy.ndarray
        (s, n, ny) gains per mode.
    alpha : numpy.ndarray
        (q,) S-procedure multipliers, > 0.
    beta : float
        S-procedure multiplier, > 0 (and < 1 in discrete time).

    Returns
    -------
    list of numpy.ndarray
        One symmetric matrix per mode: (n+q, n+q) continuous, (2n+q, 2n+q) discrete.
    """
    out = []
    Da = np.diag(alpha)
    for i in range(model.s):
        A, C, D, E = model.A[i], model.C[i], model.D[i], model.E[i]
        Y = P @ L[i]
        PA = P @ A - Y @ C
        PG = P @ D - Y @ E
        if model.time == "continuous":
            M = np.block([[PA.T + PA + beta * P, PG], [PG.T, -Da]])
        else:
            n, q = model.n, model.q
            Z = np.zeros((n, q))
            M = np.block([[-(1.0 - beta) * P, Z, PA.T],
                          [Z.T, -Da, PG.T],
                          [PA, PG, -P]])
        out.append(0.5 * (M + M.T))
    return out


def qb_bounds(model: QBModel, P: np.ndarray) -> dict[str, Any]:
    """Guaranteed steady-state bounds from the ellipsoid ``e' P e <= 1``.

    Parameters
    ----------
    model : QBModel
    P : numpy.ndarray
        (n, n)

    Returns
    -------
    dict
        ``lambda_min`` (lambda_min(P)); ``rho_max`` = 1/sqrt(lambda_min(P)) (eq. 6), state
        units; ``component_bound`` (n,) sqrt((P^-1)_jj) >= max |e_j| on the ellipsoid;
        ``r_max`` (s,) |C_i| rho_max + q |E_i| (eq. 11, per mode); ``output_bound`` (s, ny)
        sqrt(c_i P^-1 c_i') + sum_j |E_ij| (per mode and output), output units.
    """
    lam = float(np.linalg.eigvalsh(P)[0])
    Pinv = np.linalg.inv(P)
    rho = 1.0 / np.sqrt(lam)
    comp = np.sqrt(np.diag(Pinv))
    r_max = np.array([np.linalg.norm(model.C[i], 2) * rho
                      + model.q * (np.linalg.norm(model.E[i], 2) if model.E[i].size else 0.0)
                      for i in range(model.s)])
    out_b = np.array([np.sqrt(np.einsum("ij,jk,ik->i", model.C[i], Pinv, model.C[i]))
                      + np.abs(model.E[i]).sum(axis=1) for i in range(model.s)])
    return {"lambda_min": lam, "rho_max": float(rho), "component_bound": comp,
            "r_max": r_max, "output_bound": out_b}


def _close(a: Any, b: Any, what: str) -> None:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape or not np.allclose(a, b, rtol=_REL_TOL, atol=1e-12):
        raise GainFileError(f"results.{what}: recorded {np.array2string(b, precision=6)} but "
                            f"the design's P gives {np.array2string(a, precision=6)}")


def gains_matrices(system: System, results: Mapping[str, Any]) -> tuple[
        np.ndarray, np.ndarray, np.ndarray, float]:
    """``(P (n,n), L (s,n,ny), alpha (q,), beta)`` from a QB gain file's results.

    Raises
    ------
    GainFileError
        A missing mode or a matrix of the wrong shape (naming the key).
    """
    n, ny = system.n, system.ny
    P = np.asarray(results["P"], dtype=float)
    if P.shape != (n, n):
        raise GainFileError(f"results.P: expected {n}x{n}, got shape {P.shape}")
    Lmap = results["L"]
    if not isinstance(Lmap, Mapping):
        raise GainFileError("results.L: expected a mapping mode -> gain matrix")
    Ls = []
    for name in system.mode_names:
        if name not in Lmap:
            raise GainFileError(f"results.L: no gain for mode {name!r}")
        Li = np.asarray(Lmap[name], dtype=float).reshape(-1, ny) if ny else np.zeros((n, 0))
        if Li.shape != (n, ny):
            raise GainFileError(f"results.L.{name}: expected {n}x{ny}, got shape {Li.shape}")
        Ls.append(Li)
    alpha = np.atleast_1d(np.asarray(results["alpha"], dtype=float))
    return P, np.array(Ls), alpha, float(results["beta"])


def gains_model(system: System, results: Mapping[str, Any]) -> QBModel:
    """The model a QB gain file was designed for: the plant's own time domain, or the sampled
    model (:func:`sampled_model`) when a continuous plant's file says ``time: discrete``.

    Raises
    ------
    GainFileError
        Nonlinear modes, or a continuous design for a discrete-time plant.
    """
    try:
        return qb_model(system, results.get("time"))
    except DesignError as exc:
        raise GainFileError(f"results.time: {exc}") from None


def guarantee(results: Mapping[str, Any], system: System) -> str:
    """One line: what a QB gain file guarantees for the sampled runtime, and where.

    A ``time: discrete`` design is proven for what runs (the error at the samples, eq. (6),
    (8), (11) at every sample after the transient, with w held over the sample); a continuous
    design is the paper's guarantee for the continuous-time observer (13a), which the runtime
    only approximates by its ZOH discretisation.
    """
    if results.get("time") == "discrete":
        how = ("sampled (exact ZOH, w held over the sample)"
               if any(m.time == "continuous" for m in system.modes) else "discrete-time plant")
        return (f"discrete-time QB, {how}: e_k'P e_k <= 1 + (1-beta)^k (V_0 - 1)+ at every "
                f"sample while the estimated mode is the plant's")
    return ("continuous-time QB (paper eq. 4-7): proven for the continuous observer; the "
            "sampled runtime runs its ZOH discretisation, not covered by the proof")


def ellipsoid_bound(V0: float | np.ndarray, beta: float, k: np.ndarray | int,
                    time: str, dt: float) -> np.ndarray:
    """Guaranteed ``V(e) = e'Pe`` after ``k`` samples from ``V(e_0) = V0`` (matched modes).

    Discrete time: the LMI gives ``V_{k+1} <= (1-beta) V_k + beta`` (module docstring), so
    ``V_k <= 1 + (1-beta)^k max(V0 - 1, 0)``. Continuous time (eq. 7, S-procedure):
    ``dV/dt <= -beta (V - 1)``, so ``V(t) <= 1 + e^{-beta t} max(V0 - 1, 0)``, t = k dt.
    The discrete-time analogue of eq. (5); after the transient it is eq. (6).

    Parameters
    ----------
    V0 : float or numpy.ndarray
        Initial value(s) of e'Pe.
    beta : float
    k : int or numpy.ndarray
        Sample index(es).
    time : str
        ``"discrete"`` or ``"continuous"``.
    dt : float
        Sample time, s (continuous only).

    Returns
    -------
    numpy.ndarray
        Broadcast of V0 against k.
    """
    kk = np.asarray(k, dtype=float)
    decay = (1.0 - beta) ** kk if time == "discrete" else np.exp(-beta * kk * dt)
    return 1.0 + decay * np.maximum(np.asarray(V0, dtype=float) - 1.0, 0.0)


def check_certificate(system: System, gains: Any) -> None:
    """Re-verify a QB gain file against ``system`` (what the loader calls).

    Recomputes from P, L_i, alpha, beta and the plant (its sampled model for a ``time:
    discrete`` design of a continuous plant): P symmetric positive definite, alpha > 0,
    beta > 0 (< 1 in discrete time), (7b)/(14b) ``sum alpha <= beta``, every LMI (7a)/(14a) (or
    the discrete counterpart) negative definite, every ``A_i - L_i C_i`` Hurwitz (Schur), and
    the recorded bounds and certificate equal to their recomputation.

    Parameters
    ----------
    system : System
    gains : GainFile
        Anything with ``results`` and ``certificate`` mappings.

    Raises
    ------
    GainFileError
        Naming the condition that fails.
    """
    res, cert = gains.results, gains.certificate
    model = gains_model(system, res)
    P, L, alpha, beta = gains_matrices(system, res)
    if alpha.shape != (model.q,):
        raise GainFileError(f"results.alpha: expected {model.q} multipliers "
                            f"({', '.join(model.w_names)}), got {alpha.size}")
    if not np.all(np.isfinite(P)) or not np.all(np.isfinite(L)):
        raise GainFileError("results: P or L has NaN/Inf entries")
    if not np.allclose(P, P.T, rtol=1e-12, atol=1e-12 * float(np.abs(P).max())):
        raise GainFileError("results.P: not symmetric")
    if float(np.linalg.eigvalsh(P)[0]) <= 0:
        raise GainFileError("results.P: not positive definite")
    if np.any(alpha <= 0) or beta <= 0 or (model.time == "discrete" and beta >= 1):
        lim = " < 1" if model.time == "discrete" else ""
        raise GainFileError(f"results: need alpha > 0 and 0 < beta{lim}, got alpha {alpha}, "
                            f"beta {beta}")
    if float(alpha.sum()) - beta > 0:
        raise GainFileError(f"(14b) sum(alpha) - beta = {alpha.sum() - beta:.3g} > 0")
    eigs = []
    for name, M in zip(system.mode_names, lmi_blocks(model, P, L, alpha, beta)):
        e = float(np.linalg.eigvalsh(M)[-1])
        if e >= 0:
            raise GainFileError(f"mode {name!r}: LMI (14a) not negative definite "
                                f"(max eigenvalue {e:.3g})")
        eigs.append(e)
    absc = []
    for i, name in enumerate(system.mode_names):
        a = spectral_abscissa(model.A[i] - L[i] @ model.C[i], model.time)
        if (model.time == "continuous" and a >= 0) or (model.time == "discrete" and a >= 1):
            raise GainFileError(f"mode {name!r}: A - L C is not stable (spectral abscissa "
                                f"{a:.4g})")
        absc.append(a)
    b = qb_bounds(model, P)
    for key in ("rho_max", "component_bound", "r_max", "output_bound"):
        _close(b[key], res[key], key)
    _close(eigs, cert["lmi_max_eig"], "certificate.lmi_max_eig")
    _close(absc, cert["spectral_abscissa"], "certificate.spectral_abscissa")
    unknown = set(res.get("fault_states", [])) - set(system.states)
    if unknown:
        raise GainFileError(f"results.fault_states: {sorted(unknown)} are not states of "
                            f"{system.name}")
