"""Hybrid Kalman filter baseline (the comparison of the QB paper, Sec. VI, Table II).

One steady-state Kalman predictor per mode, on the plant's exact zero-order-hold sampling,
with the same mode predictor as the QB observer (the plant's guards applied to the estimate,
eq. 13b). Steady-state gains per mode (instead of a covariance propagated across mode
switches) keep the filter as cheap as the observer and make it a fixed linear filter per mode,
like the QB observer, so Table II compares gains, not implementations.

Noise model: the unit-bounded channels of :func:`fd_monitor.core.qb.qb_model` (disturbances,
measurement noise) are uniform on [-1, 1] in the simulator, i.e. variance 1/3 per sample, held
over the sample. Fault-model states (constant in the fault-free model) get a random-walk
variance ``q_fault`` per sample: the tuning knob that trades detection speed for noise
(``q_fault -> 0`` never tracks a fault; large ``q_fault`` passes the noise to the estimate).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fd_monitor.core.plant import zoh
from fd_monitor.core.qb_model import default_fault_states, qb_model
from fd_monitor.model.system import System

__all__ = ["KalmanDesign", "kalman_gains", "DEFAULT_Q_FAULT"]

#: Default random-walk variance of the fault-model states per sample (state units^2); tuned
#: on pwa_cascade (doc/theory/qb.md): the detection delay of the 0.5 bias step is close to
#: the QB observer's while the fault-free estimate stays smooth.
DEFAULT_Q_FAULT = 1e-7


@dataclass(frozen=True)
class KalmanDesign:
    """Per-mode steady-state Kalman predictors.

    Attributes
    ----------
    K : numpy.ndarray
        (s, n, ny) predictor gains: ``x_{k+1} = Ad x_k + Bd u_k + cd + K (y_k - C x_k)``.
    X : numpy.ndarray
        (s, n, n) steady-state prediction error covariances, state units^2.
    matrices : tuple of numpy.ndarray
        ``(Phi (s, n, n), Gam (s, n, nu + ny + 1))``: the update
        ``x_{k+1} = Phi x_k + Gam [u_k; y_k; 1]`` (the observer form of the QB runtime).
    """

    K: np.ndarray
    X: np.ndarray
    matrices: tuple[np.ndarray, np.ndarray]


def kalman_gains(system: System, q_fault: float = DEFAULT_Q_FAULT,
                 fault_states: tuple[str, ...] | None = None, w_var: float = 1.0 / 3.0,
                 r_floor: float = 1e-12) -> KalmanDesign:
    """Steady-state Kalman predictor gains of each mode.

    Parameters
    ----------
    system : System
        Linear modes only.
    q_fault : float
        Random-walk variance per sample of each fault-model state, state units^2.
    fault_states : tuple of str, optional
        Default :func:`fd_monitor.core.qb.default_fault_states`.
    w_var : float
        Variance of each unit-bounded noise channel (1/3: uniform on [-1, 1]).
    r_floor : float
        Added to the measurement covariance's diagonal so that it is invertible.

    Returns
    -------
    KalmanDesign
    """
    model = qb_model(system)
    dt = system.sample_time
    names = default_fault_states(system) if fault_states is None else fault_states
    idx = [system.states.index(s) for s in names]
    Ks, Xs, Phis, Gams = [], [], [], []
    for i in range(model.s):
        A, B, C, D, E, c = (model.A[i], model.B[i], model.C[i], model.D[i], model.E[i],
                            model.offset[i])
        if model.time == "continuous":
            G = np.column_stack([B, D, c])
            Ad, Gd = zoh(A, G, dt)
            Bd, Dd, cd = Gd[:, :B.shape[1]], Gd[:, B.shape[1]:-1], Gd[:, -1]
        else:
            Ad, Bd, Dd, cd = A, B, D, c
        Q = w_var * Dd @ Dd.T
        Q[idx, idx] += q_fault
        R = w_var * E @ E.T + r_floor * np.eye(system.ny)
        S = w_var * Dd @ E.T
        from scipy.linalg import solve_discrete_are  # not at import: see plant.zoh

        X = solve_discrete_are(Ad.T, C.T, Q, R, s=S)
        K = (Ad @ X @ C.T + S) @ np.linalg.inv(C @ X @ C.T + R)
        Ks.append(K)
        Xs.append(X)
        Phis.append(Ad - K @ C)
        Gams.append(np.column_stack([Bd, K, cd]))
    return KalmanDesign(np.array(Ks), np.array(Xs), (np.array(Phis), np.array(Gams)))
