"""Quadratic-boundedness (QB) observers: hybrid Luenberger observer, QB detection, certificate.

Alessandri, Boem & Parisini, "Model-based fault detection and estimation for LTI and PWA
systems by using quadratic boundedness". The designer (:mod:`fd_monitor.design.qb`) solves the
LMIs; this module (numpy/scipy only) holds everything the runtime needs:

* :func:`qb_model` -- the plant's modes in the paper's form ``dx = A_i x + B_i u + D_i w``,
  ``y = C_i x + E_i w`` with ``|w_j| <= 1`` (bounds folded into D and E, measurement noise
  appended as extra w channels), continuous or discrete time;
* :func:`lmi_blocks` -- the LMIs (7a)/(14a) (continuous) or their discrete-time counterpart
  evaluated at a point, used by the designer's self-check and by :func:`check_certificate`;
* :func:`qb_bounds` -- rho_max (eq. 6), r_max (eq. 11) and the tighter bounds that follow from
  the same ellipsoid ``e' P e <= 1``: ``|e_j| <= sqrt((P^-1)_jj)`` and per output
  ``|r_i| <= sqrt(c_i P^-1 c_i') + sum_j |E_ij|``;
* :class:`QBObserver` -- the hybrid Luenberger observer (13a)-(13b), discretised exactly (ZOH
  with u and y held over the sample) when the design is continuous;
* :class:`QBDetector` -- alarms when a fault-model state estimate leaves its bound (eq. 8, or
  the per-component bound) or a residual leaves its bound (eq. 11, or the per-output bound);
* :func:`run_batch` -- both, vectorised over a batch of simulated runs (also with a hybrid
  Kalman filter as the estimator, for the paper's comparison).

Discrete-time counterpart (plants given in discrete time). With ``e_{k+1} = Phi e_k + G w_k``,
``Phi = A - L C``, ``G = D - L E``, QB asks ``V(e_{k+1}) < V(e_k)`` whenever ``V(e_k) >= 1``
and ``w_j^2 <= 1``, ``V(e) = e' P e``. The S-procedure (multipliers beta, alpha_j >= 0) gives
the sufficient condition ``V(e_{k+1}) - (1 - beta) V(e_k) - sum alpha_j w_j^2 + (sum alpha_j -
beta) < 0`` for all (e, w), i.e. ``sum alpha_j <= beta`` and
``[Phi'P Phi - (1-beta) P, Phi'P G; G'P Phi, G'P G - diag(alpha)] < 0``; a Schur complement
with ``Y = P L`` makes it the LMI ::

    [ -(1-beta) P        0           (PA - YC)' ]
    [      0       -diag(alpha)      (PD - YE)' ]  < 0,   sum_j alpha_j - beta <= 0,  0 < beta < 1.
    [  PA - YC        PD - YE            -P     ]

It gives ``V(e_{k+1}) <= (1-beta) V(e_k) + beta`` so the ellipsoid ``e'Pe <= 1`` is positively
invariant and attractive, and (6), (8), (11) hold as in continuous time.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import expm

from fd_monitor.core.batch import BatchResult
from fd_monitor.core.plant import SampledPlant, zoh
from fd_monitor.core.plausibility import Plausibility
from fd_monitor.errors import DesignError, GainFileError
from fd_monitor.system import System

__all__ = [
    "QBModel",
    "QBObserver",
    "QBDetector",
    "check_certificate",
    "default_fault_states",
    "ellipsoid_bound",
    "gains_model",
    "guarantee",
    "lmi_blocks",
    "observer_matrices",
    "qb_bounds",
    "qb_model",
    "run_batch",
    "sampled_model",
    "spectral_abscissa",
    "stress_runs",
    "STRESS_POLICIES",
    "unobservable_unstable",
]

#: Relative tolerance when the loader compares a recorded number with its recomputation.
_REL_TOL = 1e-6


@dataclass(frozen=True)
class QBModel:
    """The plant's linear modes in the paper's normalised form (|w_j| <= 1).

    Attributes
    ----------
    time : str
        ``"continuous"`` or ``"discrete"`` (common to all modes).
    mode_names : tuple of str
        (s,)
    A : numpy.ndarray
        (s, n, n) state matrices, 1/s (continuous) or dimensionless (discrete).
    B : numpy.ndarray
        (s, n, nu)
    C : numpy.ndarray
        (s, ny, n)
    D : numpy.ndarray
        (s, n, q) disturbance matrices for unit-bounded w (plant D times the bound of each w).
    E : numpy.ndarray
        (s, ny, q) as D for the outputs; measurement noise bounds are extra w channels.
    offset : numpy.ndarray
        (s, n) affine terms.
    w_names : tuple of str
        (q,) what each normalised disturbance channel is.
    """

    time: str
    mode_names: tuple[str, ...]
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    E: np.ndarray
    offset: np.ndarray
    w_names: tuple[str, ...]

    @property
    def s(self) -> int:
        """Number of modes."""
        return int(self.A.shape[0])

    @property
    def n(self) -> int:
        """Number of states."""
        return int(self.A.shape[1])

    @property
    def q(self) -> int:
        """Number of unit-bounded disturbance channels."""
        return int(self.D.shape[2])


def qb_model(system: System, time: str | None = None) -> QBModel:
    """Put the plant's modes in the paper's form with ``|w_j| <= 1``.

    ``time="discrete"`` for a continuous-time plant gives the *sampled* model instead, the
    exact map between samples that the simulator and the runtime see (see
    :func:`sampled_model`); ``None`` (default) keeps the plant's own time domain.

    Disturbance ``w_j`` with bound ``wbar_j`` becomes ``wbar_j * w~_j``; measurement noise
    ``|v_i| <= vbar_i > 0`` becomes an extra channel with ``D`` column 0 and ``E`` column
    ``vbar_i e_i``; modelling uncertainty ``|eta_i| <= ubar_i`` (added to ``x_{k+1}``) becomes
    a channel with ``D`` column ``ubar_i e_i`` in discrete time, and ``ubar_i / Ts e_i`` in
    continuous time (the same increment spread over one sample: a first-order equivalent).

    Raises
    ------
    DesignError
        A nonlinear mode, or modes that mix continuous and discrete time.
    """
    for m in system.modes:
        if m.dynamics != "linear" or m.A is None:
            raise DesignError(f"plant {system.name}: mode {m.name!r} is nonlinear; the QB "
                              f"observer needs linear (affine) modes")
    times = {m.time for m in system.modes}
    if len(times) != 1:
        raise DesignError(f"plant {system.name}: modes mix continuous and discrete time; the "
                          f"QB design needs one time domain for all modes")
    time_ = times.pop()
    if time is not None and time not in ("continuous", "discrete"):
        raise DesignError(f"time: expected 'continuous' or 'discrete', got {time!r}")
    if time == "continuous" and time_ == "discrete":
        raise DesignError(f"plant {system.name}: modes are discrete time; a continuous-time QB "
                          f"design needs continuous-time modes")
    if time == "discrete" and time_ == "continuous":
        return sampled_model(system, _qb_model(system, time_))
    return _qb_model(system, time_)


def _qb_model(system: System, time: str) -> QBModel:
    n, ny = system.n, system.ny
    wbar = np.asarray(system.disturbance_bound, dtype=float)
    vbar = np.asarray(system.measurement_noise, dtype=float)
    unc = np.array([m.uncertainty for m in system.modes], dtype=float)  # (s, n)
    v_idx = [i for i in range(ny) if vbar[i] > 0]
    u_idx = [j for j in range(n) if np.any(unc[:, j] > 0)]
    w_names = (tuple(system.disturbances) + tuple(f"v_{system.outputs[i]}" for i in v_idx)
               + tuple(f"eta_{system.states[j]}" for j in u_idx))
    eta_scale = 1.0 if time == "discrete" else 1.0 / system.sample_time
    Ds, Es = [], []
    for qi, m in enumerate(system.modes):
        Dv = np.zeros((n, len(v_idx)))
        Ev = np.zeros((ny, len(v_idx)))
        for c, i in enumerate(v_idx):
            Ev[i, c] = vbar[i]
        Du = np.zeros((n, len(u_idx)))
        for c, j in enumerate(u_idx):
            Du[j, c] = unc[qi, j] * eta_scale
        Eu = np.zeros((ny, len(u_idx)))
        Ds.append(np.hstack([m.D * wbar, Dv, Du]))
        Es.append(np.hstack([m.E * wbar, Ev, Eu]))
    A = np.array([m.A for m in system.modes], dtype=float)
    return QBModel(time, system.mode_names, A, np.array([m.B for m in system.modes], dtype=float),
                   np.array([m.C for m in system.modes], dtype=float), np.array(Ds),
                   np.array(Es), np.array([m.offset for m in system.modes], dtype=float),
                   w_names)


def sampled_model(system: System, model: QBModel) -> QBModel:
    """The exact sampled model of a continuous-time QB model (what runs at the samples).

    Over one sample ``[t_k, t_k + Ts)`` the simulator (and a zero-order-hold plant) holds u, the
    disturbance w and the affine term, adds the modelling uncertainty ``eta_k`` once per sample
    and measures ``y_k = C x_k + E w_k + v_k``. So, exactly (Van Loan), ::

        x_{k+1} = Ad_i x_k + Bd_i u_k + cd_i + Dd_i w_k,   y_k = C_i x_k + E_i w_k,
        Ad_i = e^{A_i Ts},  [Bd_i Dd_i^w cd_i] = int_0^Ts e^{A_i s} ds [B_i D_i^w c_i],

    with the unit-bounded channels of :func:`qb_model`: disturbance columns ZOH-discretised,
    measurement-noise columns unchanged (D part zero), uncertainty columns ``ubar_j e_j``
    (an increment per sample, not a rate). The disturbance is *held* over the sample, as the
    simulator holds it; one that varies inside the sample (``|w(t)| <= 1`` only) reaches a
    set larger by a term of order ``Ts^2 |A D| / 2``, which this model does not cover.

    Parameters
    ----------
    system : System
        The plant (its ``sample_time`` is Ts, s).
    model : QBModel
        ``qb_model(system)`` in continuous time.

    Returns
    -------
    QBModel
        ``time == "discrete"``, same channels and names.
    """
    dt = system.sample_time
    nw = len(system.disturbances)
    wbar = np.asarray(system.disturbance_bound, dtype=float)
    A, B, D, off = [], [], [], []
    for i, m in enumerate(system.modes):
        assert m.A is not None
        nu = m.B.shape[1]
        G = np.column_stack([m.B, m.D * wbar, m.offset[:, None]])
        Ad, Gd = zoh(np.asarray(m.A, dtype=float), G, dt)
        Dd = model.D[i].copy()
        Dd[:, :nw] = Gd[:, nu:nu + nw]
        # uncertainty channels: continuous columns are ubar/Ts e_j; per sample it is ubar e_j
        Dd[:, nw:] = model.D[i][:, nw:] * dt
        A.append(Ad)
        B.append(Gd[:, :nu])
        D.append(Dd)
        off.append(Gd[:, nu + nw])
    return QBModel("discrete", model.mode_names, np.array(A), np.array(B).reshape(model.B.shape),
                   model.C, np.array(D), model.E, np.array(off), model.w_names)


def unobservable_unstable(A: np.ndarray, C: np.ndarray, time: str,
                          tol: float = 1e-9) -> list[complex]:
    """Eigenvalues of A that make (A, C) not detectable (PBH test).

    Parameters
    ----------
    A : numpy.ndarray
        (n, n)
    C : numpy.ndarray
        (ny, n)
    time : str
        ``"continuous"`` (unstable: Re >= 0) or ``"discrete"`` (unstable: |z| >= 1).

    Returns
    -------
    list of complex
        Empty when (A, C) is detectable.
    """
    n = A.shape[0]
    bad = []
    for lam in np.linalg.eigvals(A):
        unstable = lam.real >= -tol if time == "continuous" else abs(lam) >= 1.0 - tol
        if not unstable:
            continue
        M = np.vstack([lam * np.eye(n) - A, C.astype(complex)])
        sv = np.linalg.svd(M, compute_uv=False)
        if sv[-1] <= tol * max(1.0, float(sv[0])):
            bad.append(complex(lam))
    return bad


def spectral_abscissa(M: np.ndarray, time: str) -> float:
    """max Re(eig) (continuous) or max |eig| (discrete) of the square matrix ``M``."""
    ev = np.linalg.eigvals(M)
    return float(ev.real.max() if time == "continuous" else np.abs(ev).max())


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


def default_fault_states(system: System) -> tuple[str, ...]:
    """States that model faults: targets of ``state_jump`` faults, and states that are constant
    in every mode (zero row in A, B, D, offset, uncertainty), the paper's augmented states."""
    names = []
    jump = {f.index for f in system.faults if f.kind == "state_jump"}
    for j, name in enumerate(system.states):
        const = all(m.A is not None and not np.any(m.A[j]) and not np.any(m.B[j])
                    and not np.any(m.D[j]) and not m.offset[j] and not m.uncertainty[j]
                    for m in system.modes)
        if j in jump or const:
            names.append(name)
    return tuple(names)


# --------------------------------------------------------------------------------------
# certificate


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


# --------------------------------------------------------------------------------------
# runtime


def observer_matrices(model: QBModel, L: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-mode update ``x_{k+1} = Phi_i x_k + Gam_i [u_k; y_k; 1]`` of the observer (13a).

    Continuous designs are discretised exactly (zero-order hold: u and y held over the
    sample): ``Phi_i = e^{(A_i - L_i C_i) dt}``, ``Gam_i = int_0^dt e^{(A_i - L_i C_i) s} ds
    [B_i, L_i, c_i]``. Discrete designs: ``Phi_i = A_i - L_i C_i``, ``Gam_i = [B_i, L_i, c_i]``.

    Parameters
    ----------
    model : QBModel
    L : numpy.ndarray
        (s, n, ny) gains.
    dt : float
        Sample time, s.

    Returns
    -------
    Phi : numpy.ndarray
        (s, n, n)
    Gam : numpy.ndarray
        (s, n, nu + ny + 1)
    """
    Phis, Gams = [], []
    for i in range(model.s):
        F = model.A[i] - L[i] @ model.C[i]
        G = np.column_stack([model.B[i], L[i], model.offset[i]])
        if model.time == "continuous":
            n, m = G.shape
            M = np.zeros((n + m, n + m))
            M[:n, :n], M[:n, n:] = F, G
            Md = expm(M * dt)
            Phis.append(Md[:n, :n])
            Gams.append(Md[:n, n:])
        else:
            Phis.append(F)
            Gams.append(G)
    return np.array(Phis), np.array(Gams)


def _as_array(x: Any, shape: tuple[int, ...], what: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.shape != shape:
        raise ValueError(f"{what}: expected shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: NaN or Inf")
    return a


class QBObserver:
    """Hybrid Luenberger observer (13a)-(13b) for one run, step by step.

    ``step(k, u, y)`` takes the measurement of sample k and returns the estimate at sample k
    (the prediction from samples < k, which is what the QB bounds hold for) and the mode used;
    it then advances to k + 1: ``x_{k+1} = Phi_m x_k + Gam_m [u_k; y_k; 1]`` and the mode is
    predicted from the estimate through the plant's guards (13b): controlled guards on
    ``u_k``, then autonomous guards on ``x_{k+1}``.

    Parameters
    ----------
    system : System
    gains : GainFile
        A QB gain file (``method: qb``) for ``system``.
    x0 : numpy.ndarray, optional
        (n,) initial estimate; default zeros.
    mode0 : int, optional
        Initial mode estimate; default the plant's initial mode.
    L : numpy.ndarray, optional
        (s, n, ny) gains overriding the file's (used by the Kalman baseline).
    """

    def __init__(self, system: System, gains: Any, x0: np.ndarray | None = None,
                 mode0: int | None = None, L: np.ndarray | None = None,
                 matrices: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        self.system = system
        self.model = gains_model(system, gains.results) if gains is not None else qb_model(system)
        if matrices is None:
            if L is None:
                L = gains_matrices(system, gains.results)[1]
            matrices = observer_matrices(self.model, L, system.sample_time)
        self.Phi, self.Gam = matrices
        self._plant = SampledPlant(system)
        self.x = (np.zeros(system.n) if x0 is None
                  else _as_array(x0, (system.n,), "x0")).copy()
        self.mode = system.initial_mode if mode0 is None else int(mode0)
        self.k: int | None = None
        self.plausibility = Plausibility(system)

    @property
    def channels(self) -> tuple[str, ...]:
        """Names of the published estimate: ``mode`` then the states."""
        return ("mode", *self.system.states)

    def step(self, k: int, u: Any, y: Any) -> tuple[int, np.ndarray]:
        """Process sample ``k``.

        Parameters
        ----------
        k : int
            Sample index; must increase by one per call (a gap raises ValueError).
        u : array_like
            (nu,) inputs at sample k.
        y : array_like
            (ny,) measurements at sample k, output units.

        Returns
        -------
        mode_hat : int
            Estimated mode at sample k.
        x_hat : numpy.ndarray
            (n,) state estimate at sample k, state units.
        """
        sys_ = self.system
        if self.k is not None and k != self.k + 1:
            raise ValueError(f"QBObserver.step: sample {k} after {self.k}: samples must be "
                             f"consecutive (reset the observer after a gap)")
        uu = _as_array(u, (sys_.nu,), "u")
        yy = _as_array(y, (sys_.ny,), "y")
        # Range test only: the estimate converges from x0, it is no one-sample prediction.
        self.plausibility.check(k, uu, yy)
        mode, x = self.mode, self.x.copy()
        z = np.concatenate([uu, yy, [1.0]])
        xn = self.Phi[mode] @ x + self.Gam[mode] @ z
        q = np.array([mode])
        q = self._plant.next_mode(q, x[None], uu[None], "controlled")
        q = self._plant.next_mode(q, xn[None], uu[None], "autonomous")
        self.x, self.mode, self.k = xn, int(q[0]), k
        return mode, x

    def residual(self, mode: int, x_hat: np.ndarray, y: Any) -> np.ndarray:
        """(ny,) residual ``r = y - C_mode x_hat`` (Remark 1), output units."""
        return np.asarray(y, dtype=float) - self.model.C[mode] @ x_hat


class QBDetector:
    """QB fault detection: compare estimates and residuals with guaranteed bounds times rho.

    Channels, in order: one per fault-model state ``j`` (its name):
    ``|x_hat_j - x_nom_j| > rho * bound_j`` with ``bound_j = sqrt((P^-1)_jj)`` (per-component
    bound, ``state_bound="component"``) or ``rho_max`` (eq. 8, ``state_bound="rho_max"``);
    ``fault_norm``: ``|x_hat_F - x_nom_F| > rho * rho_max`` (eq. 8 on the fault-model states);
    one per output ``r_<name>``: ``|r_i| > rho * output_bound_i``; ``r_norm``: ``|r| > rho *
    r_max`` (eq. 11). Bounds hold after the transient of the observer (eq. 5).

    Parameters
    ----------
    system : System
    gains : GainFile
        A QB gain file for ``system``.
    rho : float
        Threshold scale (Table II's rho); 1 gives the guaranteed bounds.
    state_bound : str
        ``"component"`` or ``"rho_max"``.
    """

    def __init__(self, system: System, gains: Any, rho: float = 1.0,
                 state_bound: str = "component") -> None:
        if state_bound not in ("component", "rho_max"):
            raise ValueError(f"state_bound: expected 'component' or 'rho_max', got "
                             f"{state_bound!r}")
        if not rho > 0:
            raise ValueError(f"rho: expected > 0, got {rho}")
        res = gains.results
        self.system = system
        self.rho = float(rho)
        names = list(res.get("fault_states", default_fault_states(system)))
        self.fault_idx = np.array([system.states.index(s) for s in names], dtype=int)
        nominal = res.get("fault_nominal")
        self.nominal = (np.asarray(nominal, dtype=float).reshape(-1) if nominal is not None
                        else system.initial_state[self.fault_idx])
        rho_max = float(res["rho_max"])
        comp = np.asarray(res["component_bound"], dtype=float)
        self.state_bounds = (comp[self.fault_idx] if state_bound == "component"
                             else np.full(len(names), rho_max))
        self.rho_max = rho_max
        self.output_bound = np.atleast_2d(np.asarray(res["output_bound"], dtype=float))
        self.r_max = np.atleast_1d(np.asarray(res["r_max"], dtype=float))
        self.channels: tuple[str, ...] = (*names, "fault_norm",
                                          *(f"r_{o}" for o in system.outputs), "r_norm")

    def bounds(self, mode: int | np.ndarray) -> np.ndarray:
        """Unscaled thresholds per channel: (n_channels,) for one mode, (N, n_channels) for a
        batch of modes (N,)."""
        m = np.asarray(mode)
        nf = len(self.fault_idx)
        head = np.concatenate([self.state_bounds, [self.rho_max]])
        if m.ndim == 0:
            return np.concatenate([head, self.output_bound[int(m)], [self.r_max[int(m)]]])
        return np.column_stack([np.tile(head, (m.shape[0], 1)), self.output_bound[m],
                                self.r_max[m]]).reshape(m.shape[0], nf + 2 + self.system.ny)

    def signals(self, x_hat: np.ndarray, residual: np.ndarray) -> np.ndarray:
        """Compared signals per channel (absolute values): x_hat (..., n), residual (..., ny)
        -> (..., n_channels)."""
        d = x_hat[..., self.fault_idx] - self.nominal
        return np.concatenate([np.abs(d), np.linalg.norm(d, axis=-1, keepdims=True),
                               np.abs(residual),
                               np.linalg.norm(residual, axis=-1, keepdims=True)], axis=-1)

    def step(self, x_hat: Any, residual: Any, mode: int = 0) -> np.ndarray:
        """Alarms of one sample.

        Parameters
        ----------
        x_hat : array_like
            (n,) state estimate at the sample.
        residual : array_like
            (ny,) residual ``y - C x_hat``.
        mode : int
            Estimated mode (selects the residual bounds of that mode's C and E).

        Returns
        -------
        numpy.ndarray
            (n_channels,) bool alarm per channel (see :attr:`channels`).
        """
        sig = self.signals(np.asarray(x_hat, dtype=float), np.asarray(residual, dtype=float))
        return np.asarray(sig > self.rho * self.bounds(mode))


def run_batch(system: System, gains: Any, traj: Any, *, rho: float = 1.0,
              state_bound: str = "component", estimator: str = "qb",
              kalman: Mapping[str, Any] | None = None,
              x0: np.ndarray | None = None) -> BatchResult:
    """Run the hybrid observer and the QB detector over a batch of simulated runs.

    Parameters
    ----------
    system : System
    gains : GainFile
        QB gain file for ``system`` (its bounds are the thresholds).
    traj : Trajectory
        Simulated batch: ``u`` (N, K, nu), ``y`` (N, K, ny).
    rho : float
        Threshold scale.
    state_bound : str
        See :class:`QBDetector`.
    estimator : str
        ``"qb"`` (the designed hybrid Luenberger observer) or ``"kalman"`` (the hybrid Kalman
        filter baseline of :mod:`fd_monitor.core.kalman`, same mode predictor and thresholds).
    kalman : mapping, optional
        Keyword arguments of :func:`fd_monitor.core.kalman.kalman_gains`.
    x0 : numpy.ndarray, optional
        (n,) initial estimate of every run; default zeros.

    Returns
    -------
    BatchResult
        ``alarm`` (N, K, n_channels); ``residual`` the compared signals; ``threshold``
        (N, K, n_channels) the unscaled bounds (``alarm = residual > rho * threshold``;
        ``extra["threshold_scalable"]`` is True); ``x_hat`` (N, K, n); ``mode_hat`` (N, K).
    """
    model = gains_model(system, gains.results)
    if estimator == "qb":
        L = gains_matrices(system, gains.results)[1]
        Phi, Gam = observer_matrices(model, L, system.sample_time)
    elif estimator == "kalman":
        from fd_monitor.core.kalman import kalman_gains

        Phi, Gam = kalman_gains(system, **dict(kalman or {})).matrices
    else:
        raise ValueError(f"estimator: expected 'qb' or 'kalman', got {estimator!r}")
    det = QBDetector(system, gains, rho=rho, state_bound=state_bound)
    u, y = np.asarray(traj.u, dtype=float), np.asarray(traj.y, dtype=float)
    N, K = y.shape[:2]
    plant = SampledPlant(system)
    xh = np.zeros((N, system.n)) if x0 is None else np.tile(np.asarray(x0, float), (N, 1))
    qh = np.full(N, system.initial_mode, dtype=int)
    X = np.empty((N, K, system.n))
    Q = np.empty((N, K), dtype=int)
    r = np.empty((N, K, system.ny))
    n, ny, s = system.n, system.ny, model.s
    # One matmul per sample for every mode at once: [x; u; y; 1] -> (x_next, C x) per mode,
    # then pick each run's mode; cheaper than gathering a matrix per run.
    M = np.concatenate([np.concatenate([Phi, Gam], axis=2),
                        np.concatenate([model.C, np.zeros((s, ny, Gam.shape[2]))], axis=2)],
                       axis=1)                                   # (s, n + ny, n + nu + ny + 1)
    MT = M.reshape(s * (n + ny), -1).T
    v = np.empty((N, MT.shape[0]))
    v[:, -1] = 1.0
    rows = np.arange(N)
    has_controlled = any(g.kind == "controlled" for g in system.guards)
    for k in range(K):
        X[:, k], Q[:, k] = xh, qh
        v[:, :n], v[:, n:n + system.nu], v[:, n + system.nu:-1] = xh, u[:, k], y[:, k]
        out = (v @ MT).reshape(N, s, n + ny)[rows, qh]
        r[:, k] = y[:, k] - out[:, n:]
        xn = out[:, :n]
        qm = plant.next_mode(qh, xh, u[:, k], "controlled") if has_controlled else qh
        qh = plant.next_mode(qm, xn, u[:, k], "autonomous")
        xh = xn
    sig = det.signals(X, r)
    thr = det.bounds(Q.reshape(-1)).reshape(N, K, -1)
    return BatchResult(alarm=sig > rho * thr, channels=det.channels, residual=sig,
                       threshold=thr, x_hat=X, mode_hat=Q,
                       extra={"threshold_scalable": True, "estimator": estimator,
                              "rho": rho, "state_bound": state_bound})


def summary_bounds(gains: Any, names: Sequence[str]) -> dict[str, float]:
    """Per-state guaranteed bounds of a gain file as a name -> value mapping (for reports)."""
    comp = np.asarray(gains.results["component_bound"], dtype=float)
    return {n: float(c) for n, c in zip(names, comp)}


#: Disturbance policies of :func:`stress_runs`.
STRESS_POLICIES = ("uniform", "extreme", "held", "adversarial")


def stress_runs(system: System, gains: Any, policy: str, n_runs: int, n_samples: int,
                seed: int = 0, hold_prob: float = 0.002) -> dict[str, np.ndarray]:
    """Fault-free sampled runs of an autonomous plant under extreme disturbance policies.

    The plant is the exact sampled plant (:class:`~fd_monitor.core.plant.SampledPlant`,
    ``y_k = C x_k + E w_k``, w held over each sample), started from the plant file's initial
    state, with the unit-bounded disturbance ``w_k`` (the plant's w times its bound) drawn by
    ``policy``:

    * ``uniform``: uniform in the box, redrawn every sample (the simulator's default);
    * ``extreme``: a random vertex of the box every sample;
    * ``held``: a random vertex held, switched to another random vertex with probability
      ``hold_prob`` per sample (slow switching lets the state settle at the box's extremes);
    * ``adversarial``: the vertex that maximises ``V(e_{k+1}) = e_{k+1}'P e_{k+1}`` of the
      gain file's observer as it runs (true next state minus the runtime's next estimate,
      for every vertex), greedy.

    Parameters
    ----------
    system : System
        Autonomous plant (no inputs) with linear modes.
    gains : GainFile
        QB gain file (its observer is the one attacked by ``adversarial``).
    policy : str
        One of :data:`STRESS_POLICIES`.
    n_runs, n_samples : int
    seed : int

    Returns
    -------
    dict
        ``x`` (N, K, n) true states, ``y`` (N, K, ny), ``u`` (N, K, 0), ``mode`` (N, K) true
        modes, ``w`` (N, K, nw) unit-bounded disturbances.
    """
    if policy not in STRESS_POLICIES:
        raise ValueError(f"policy: expected one of {STRESS_POLICIES}, got {policy!r}")
    if system.nu:
        raise ValueError(f"stress_runs: plant {system.name} has inputs; only autonomous plants")
    model = gains_model(system, gains.results)
    P, L, _, _ = gains_matrices(system, gains.results)
    Phi, Gam = observer_matrices(model, L, system.sample_time)
    plant = SampledPlant(system)
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    N, K, n, nw = n_runs, n_samples, system.n, len(system.disturbances)
    wbar = np.asarray(system.disturbance_bound, dtype=float)
    verts = np.array(np.meshgrid(*([[-1.0, 1.0]] * nw), indexing="ij")).reshape(nw, -1).T
    x = np.tile(system.initial_state, (N, 1)).astype(float)
    q = np.full(N, system.initial_mode, dtype=int)
    xh, qh = np.zeros((N, n)), q.copy()
    u0 = np.zeros((N, 0))
    held = verts[rng.integers(len(verts), size=N)]
    out = {"x": np.empty((N, K, n)), "y": np.empty((N, K, system.ny)),
           "u": np.empty((N, K, 0)), "mode": np.empty((N, K), dtype=int),
           "w": np.empty((N, K, nw))}
    nv = len(verts)
    for k in range(K):
        if policy == "uniform":
            w = rng.uniform(-1.0, 1.0, size=(N, nw))
        elif policy == "extreme":
            w = verts[rng.integers(len(verts), size=N)]
        elif policy == "held":
            sw = rng.random(N) < hold_prob
            held[sw] = verts[rng.integers(len(verts), size=int(sw.sum()))]
            w = held
        else:
            # every run x every vertex: next true state minus next estimate (the runtime's map)
            wv = np.tile(verts, (N, 1)) * wbar
            qv, xv = np.repeat(q, nv), np.repeat(x, nv, axis=0)
            yv = plant.output(qv, xv, wv)
            zv = np.concatenate([yv, np.ones((N * nv, 1))], axis=1)
            qhv = np.repeat(qh, nv)
            ev = (plant.step(qv, xv, np.zeros((N * nv, 0)), wv)
                  - np.einsum("nij,nj->ni", Phi[qhv], np.repeat(xh, nv, axis=0))
                  - np.einsum("nij,nj->ni", Gam[qhv], zv))
            Vv = np.einsum("ni,ij,nj->n", ev, P, ev).reshape(N, nv)
            w = verts[Vv.argmax(axis=1)]
        y = plant.output(q, x, w * wbar)
        out["x"][:, k], out["y"][:, k], out["mode"][:, k], out["w"][:, k] = x, y, q, w
        z = np.concatenate([y, np.ones((N, 1))], axis=1)
        xh_next = np.einsum("nij,nj->ni", Phi[qh], xh) + np.einsum("nij,nj->ni", Gam[qh], z)
        qh = plant.next_mode(qh, xh_next, u0, "autonomous")
        xh = xh_next
        x_next = plant.step(q, x, u0, w * wbar)
        q = plant.next_mode(q, x_next, u0, "autonomous")
        x = x_next
    return out
