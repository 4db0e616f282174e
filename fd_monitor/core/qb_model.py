"""The quadratic-boundedness (QB) model of a plant: its modes in the form of Alessandri, Boem &
Parisini, ``dx = A_i x + B_i u + D_i w``, ``y = C_i x + E_i w`` with ``|w_j| <= 1``.

Bounds are folded into D and E and measurement noise appended as extra w channels, in
continuous or discrete time (:func:`qb_model`, :func:`sampled_model` for the exact ZOH of a
continuous plant); :func:`default_fault_states` names the states that model faults. The
designer (:mod:`fd_monitor.design.qb`), the certificate (:mod:`fd_monitor.core.qb_certificate`),
the runtime (:mod:`fd_monitor.core.qb`) and the Kalman baseline all start from it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fd_monitor.core.plant import zoh
from fd_monitor.model.errors import DesignError
from fd_monitor.model.system import System

__all__ = [
    "QBModel",
    "qb_model",
    "sampled_model",
    "unobservable_unstable",
    "spectral_abscissa",
    "default_fault_states",
]


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
