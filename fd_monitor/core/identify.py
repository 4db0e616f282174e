"""Identification numerics: discrete-time affine models and data-based bounds (numpy/scipy).

Pure functions behind ``python -m fd_monitor identify`` (the bags, the modes and the plant
file are :mod:`fd_monitor.analysis.identify`). The measured outputs are the state
(``y_k = x_k + v_k``, C = I: the plant class of the ``thresholds`` chain), and one mode's
dynamics is ``x_{k+1} = A x_k + B u_k + offset + eta_k``.

Fit (:func:`fit_modes`). Least squares of ``y_{k+1}`` on the library ``[y_k, u_k, mode
indicators]``, or its instrumental-variable form with the lagged ``[y_{k-1}, u_{k-1}, ...]``
as instruments (:func:`solve`): ``y_k`` carries the noise ``v_k`` that also enters the error
``-A v_k``, and a controller that reads ``y_k`` puts it into ``u_k`` too, which biases least
squares (closed-loop data); ``v_{k-1}`` is in neither. Or sequentially thresholded least
squares (STLSQ, the sparse regression of SINDy, Brunton et al. 2016) of the increment
``y_{k+1} - y_k`` on the same library (:func:`stlsq`): a term whose contribution (coefficient
x the spread of its regressor) is below ``tol`` x the spread of the increment is dropped and
the rest refitted, until nothing changes. Modes share A and B and differ by their offset
(``per_mode="offset"``, one joint fit: a mode seen briefly still gets a well-conditioned
model), or each has its own (``"full"``).

Bounds (``y = x + v``, ``|v_i| <= v_bar_i``, ``|eta_i| <= eta_bar_i``), from held-out data:

* measurement noise (:func:`noise_bound`): the one-step error is ``e_k = y_{k+1} - A y_k -
  B u_k - offset = v_{k+1} - A v_k + eta_k``; the smallest v with ``(I + |A|) v >= max |e|``
  in every mode explains every one-step error as noise; ``v_bar = margin x v``;
* modelling uncertainty of a mode (:func:`uncertainty_bound`): the noise part of the mean of
  ``e`` over ``W`` consecutive samples is bounded by ``noise_l1(W) = sum_l v_bar_l
  || delta_il h_W - A_il h_W,p ||_1`` (:func:`fd_monitor.core.thresholds.noise_l1_bound`,
  ``h_W`` the moving average), so whatever a window mean exceeds it by is modelling error:
  ``eta_bar = margin x max_W max_k (|mean_W(e)_k| - noise_l1(W))+`` over windows of
  1 .. ``max_window`` samples. They include the moving averages the ``thresholds`` design
  filters residuals with, so the design's inequality ``|H[e]| <= noise_l1 + eta_bar`` holds
  on the data the bounds were taken from (with the margin to spare); the longer ones see a
  modelling error smaller than the noise, which a single sample cannot.

A stable plant identified from closed-loop data may get a slowest eigenvalue a hair above 1
(its slow mode is never excited): :func:`clip_radius` scales such eigenvalues down and
:func:`fit_modes` refits B and the offsets with the clipped A.

Every bound is empirical: it covers the held-out data it was computed from, times the margin;
its sample count is returned with it.

Why one module of ~780 lines: the identification numerics are small pure functions
(fits, bounds, simulation, covariance, physical parameters) that share one model type.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm, logm
from scipy.optimize import linprog, nnls
from scipy.signal import lfilter
from scipy.stats import norm

from fd_monitor.core.thresholds import noise_l1_bound
from fd_monitor.model.errors import FdMonitorError

__all__ = [
    "IdentificationError",
    "AffineModel",
    "design_matrix",
    "solve",
    "stlsq",
    "fit_modes",
    "one_step_errors",
    "spectral_radius",
    "clip_radius",
    "noise_bound",
    "uncertainty_bound",
    "one_step_bound",
    "rms",
    "simulate",
    "nrmse_fit",
    "condition_number",
    "hac_covariance",
    "eigen_intervals",
    "partial_residual",
    "partial_coefficients",
    "pe_order",
    "hf_noise_std",
    "physical_velocity",
    "physical_joint",
]


class IdentificationError(FdMonitorError, ValueError):
    """The data cannot identify a plant (too short, not excited, not finite, inconsistent)."""


@dataclass(frozen=True)
class AffineModel:
    """``x_{k+1} = A x_k + B u_k + offset`` of one mode.

    Attributes
    ----------
    A : numpy.ndarray
        (n, n).
    B : numpy.ndarray
        (n, nu).
    offset : numpy.ndarray
        (n,), state units.
    kind : str
        ``linear`` (offset 0), ``affine`` or ``sparse``.
    parameters : int
        Number of free (nonzero or fitted) coefficients.
    """

    A: np.ndarray
    B: np.ndarray
    offset: np.ndarray
    kind: str
    parameters: int

    def predict(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """One-step prediction: X (N, n), U (N, nu) -> (N, n)."""
        return np.asarray(X @ self.A.T + U @ self.B.T + self.offset)


def design_matrix(X: np.ndarray, U: np.ndarray, q: np.ndarray, n_modes: int, *,
                  inputs: np.ndarray, offsets: bool) -> np.ndarray:
    """Library ``[X, U[:, inputs], onehot(q)]`` of the affine models.

    Parameters
    ----------
    X : numpy.ndarray
        (N, n) states (state units).
    U : numpy.ndarray
        (N, nu) inputs.
    q : numpy.ndarray
        (N,) int mode of each row, in [0, n_modes).
    n_modes : int
    inputs : numpy.ndarray
        Indices of the inputs in the library.
    offsets : bool
        Append one indicator column per mode (one offset per mode; a constant for one mode).

    Returns
    -------
    numpy.ndarray
        (N, n + len(inputs) [+ n_modes]).
    """
    cols = [X, U[:, inputs]]
    if offsets:
        cols.append((q[:, None] == np.arange(n_modes)[None, :]).astype(float))
    return np.hstack(cols)


def solve(Theta: np.ndarray, Y: np.ndarray, Z: np.ndarray | None = None) -> np.ndarray:
    """Least squares ``Y ~ Theta Xi`` or, with instruments Z, ``Z' Theta Xi = Z' Y``.

    Parameters
    ----------
    Theta : numpy.ndarray
        (N, p) regressors.
    Y : numpy.ndarray
        (N, m) targets.
    Z : numpy.ndarray, optional
        (N, p) instruments (IV estimate; consistent when the regressors carry noise that the
        targets' errors share and the instruments do not, e.g. lagged measurements).

    Returns
    -------
    numpy.ndarray
        (p, m).
    """
    if Z is None:
        return np.asarray(np.linalg.lstsq(Theta, Y, rcond=None)[0])
    return np.asarray(np.linalg.lstsq(Z.T @ Theta, Z.T @ Y, rcond=None)[0])


def stlsq(Theta: np.ndarray, Y: np.ndarray, tol: float, *, Z: np.ndarray | None = None,
          keep: np.ndarray | None = None, max_iter: int = 20) -> np.ndarray:
    """Sequentially thresholded least squares ``Y ~ Theta Xi`` (SINDy's STLSQ).

    Parameters
    ----------
    Theta : numpy.ndarray
        (N, p) library of candidate terms.
    Y : numpy.ndarray
        (N, m) targets.
    tol : float
        A term is dropped from target j when ``|Xi_ij| std(Theta_i) < tol std(Y_j)``.
    Z : numpy.ndarray, optional
        (N, p) instruments (see :func:`solve`).
    keep : numpy.ndarray, optional
        (p,) bool: terms never dropped (indicator columns, whose spread says nothing).
    max_iter : int

    Returns
    -------
    numpy.ndarray
        (p, m) coefficients, exact zeros where a term was dropped.
    """
    p, m = Theta.shape[1], Y.shape[1]
    keep = np.zeros(p, dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
    s_th = Theta.std(axis=0)
    s_y = Y.std(axis=0)
    active = np.ones((p, m), dtype=bool)
    Xi = np.zeros((p, m))
    for _ in range(max_iter):
        for j in range(m):
            a = active[:, j]
            Xi[:, j] = 0.0
            if a.any():
                Xi[a, j] = solve(Theta[:, a], Y[:, j:j + 1],
                                 None if Z is None else Z[:, a])[:, 0]
        new = ((np.abs(Xi) * s_th[:, None] >= tol * s_y[None, :]) | keep[:, None]) & active
        if np.array_equal(new, active):
            break
        active = new
    return Xi


def fit_modes(X: np.ndarray, U: np.ndarray, Xn: np.ndarray, q: np.ndarray, n_modes: int, *,
              kind: str, per_mode: str, inputs: np.ndarray, Xp: np.ndarray | None = None,
              Up: np.ndarray | None = None, tol: float = 0.01,
              max_radius: float | None = None) -> list[AffineModel]:
    """Fit the modes' ``x_{k+1} = A_q x_k + B_q u_k + offset_q``.

    Parameters
    ----------
    X, Xn : numpy.ndarray
        (N, n) states at k and k + 1.
    U : numpy.ndarray
        (N, nu) inputs at k.
    q : numpy.ndarray
        (N,) int mode of each row (the mode of the step k -> k + 1).
    n_modes : int
        Every mode must have rows.
    kind : str
        ``linear`` (no offset), ``affine`` or ``sparse`` (STLSQ of the increment, offsets
        always kept).
    per_mode : str
        ``offset``: one A, B for every mode and one offset per mode (one joint fit);
        ``full``: each mode its own A, B and offset (one fit per mode).
    inputs : numpy.ndarray
        Indices of the inputs to fit; the others get zero columns in B.
    Xp, Up : numpy.ndarray, optional
        (N, n), (N, nu) the states and inputs at k - 1: instruments (IV estimate).
    tol : float
        ``sparse``: STLSQ threshold (:func:`stlsq`).
    max_radius : float, optional
        When the fitted A has an eigenvalue of larger magnitude, clip the magnitudes to it
        (:func:`clip_radius`) and refit B and the offsets with that A.

    Returns
    -------
    list of AffineModel
        One per mode.
    """
    n, nu = X.shape[1], U.shape[1]
    offsets = kind != "linear"
    groups = [np.arange(q.size)] if per_mode == "offset" else \
        [np.nonzero(q == j)[0] for j in range(n_modes)]
    out: list[AffineModel] = []
    for rows in groups:
        qq = q[rows] if per_mode == "offset" else np.zeros(rows.size, dtype=int)
        nm = n_modes if per_mode == "offset" else 1
        Th = design_matrix(X[rows], U[rows], qq, nm, inputs=inputs, offsets=offsets)
        Z = None if Xp is None or Up is None else \
            design_matrix(Xp[rows], Up[rows], qq, nm, inputs=inputs, offsets=offsets)
        if kind == "sparse":
            keep = np.zeros(Th.shape[1], dtype=bool)
            keep[n + inputs.size:] = True
            Xi = stlsq(Th, Xn[rows] - X[rows], tol, Z=Z, keep=keep)
            free = int(np.count_nonzero(Xi[:n + inputs.size]))
            Xi[:n] += np.eye(n)
        else:
            Xi = solve(Th, Xn[rows], Z)
            free = int(Xi[:n + inputs.size].size)
        if max_radius is not None and spectral_radius(Xi[:n].T) > max_radius:
            A_s = clip_radius(Xi[:n].T, max_radius)
            Xi[:n] = A_s.T
            Xi[n:] = solve(Th[:, n:], Xn[rows] - X[rows] @ A_s.T, None if Z is None else Z[:, n:])
            if kind == "sparse":   # clipping fills the dropped couplings of A back in
                free = int(np.count_nonzero(A_s - np.eye(n))
                           + np.count_nonzero(Xi[n:n + inputs.size]))
        A = Xi[:n].T.copy()
        B = np.zeros((n, nu))
        B[:, inputs] = Xi[n:n + inputs.size].T
        for j in range(nm):
            c = Xi[n + inputs.size + j].copy() if offsets else np.zeros(n)
            out.append(AffineModel(A, B, c, kind, free + (n if offsets else 0)))
    return out


def spectral_radius(A: np.ndarray) -> float:
    """Largest eigenvalue magnitude of A (n, n)."""
    return float(np.max(np.abs(np.linalg.eigvals(A)))) if A.size else 0.0


def clip_radius(A: np.ndarray, max_radius: float) -> np.ndarray:
    """A (n, n) with every eigenvalue magnitude above ``max_radius`` scaled down to it.

    ``A = V diag(lambda) V^-1`` with ``lambda`` -> ``lambda min(1, max_radius / |lambda|)``;
    conjugate pairs stay conjugate, so the result is real (A must be diagonalisable).
    """
    lam, V = np.linalg.eig(A)
    mag = np.abs(lam)
    scale = np.where(mag > max_radius, max_radius / np.where(mag > 0, mag, 1.0), 1.0)
    out = (V * (lam * scale)) @ np.linalg.inv(V)
    return np.asarray(np.real(out))


def one_step_errors(model: AffineModel, X: np.ndarray, U: np.ndarray,
                    Xn: np.ndarray) -> np.ndarray:
    """``e = Xn - A X - B U - offset``: (N, n), state units."""
    return np.asarray(Xn - model.predict(X, U))


def rms(E: np.ndarray) -> np.ndarray:
    """Root mean square per column of E (N, m) -> (m,); zeros for N = 0."""
    return np.sqrt(np.mean(E ** 2, axis=0)) if E.shape[0] else np.zeros(E.shape[1])


def noise_bound(peaks: list[np.ndarray], As: list[np.ndarray], margin: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """Measurement-noise bound that explains every one-step error as noise.

    The one-step error of mode q is ``e = v_{k+1} - A_q v_k + eta_k``, so with ``eta = 0``
    ``|e_i| <= v_i + sum_l |A_q,il| v_l``. The smallest v (sum of its components, a linear
    programme) with ``(I + |A_q|) v >= peak_q`` for every mode is the noise the data need at
    least; what the longer windows show beyond it is modelling error
    (:func:`uncertainty_bound`).

    Parameters
    ----------
    peaks : list of numpy.ndarray
        Per mode, (n,) the largest ``|e_i|`` over the held-out one-step errors.
    As : list of numpy.ndarray
        Per mode, (n, n) the state matrix.
    margin : float
        Factor on the solution (>= 1).

    Returns
    -------
    v_bar : numpy.ndarray
        (n,) ``margin x v``, output units.
    v : numpy.ndarray
        (n,) the solution itself.
    """
    n = As[0].shape[0]
    G = np.vstack([np.eye(n) + np.abs(A) for A in As])
    h = np.concatenate(peaks)
    res = linprog(np.ones(n), A_ub=-G, b_ub=-h, bounds=[(0.0, None)] * n, method="highs")
    if res.status != 0:
        raise IdentificationError(f"noise bound: the linear programme failed ({res.message})")
    v = np.asarray(res.x, dtype=float)
    # the solver's tolerance: never below what the constraints need
    v = np.maximum(v, 0.0)
    short = np.max(h - G @ v) if h.size else 0.0
    if short > 0.0:
        v = v + short
    return margin * v, v


def _window_means(E: np.ndarray, W: int) -> np.ndarray:
    """Means of E (N, n) over every run of W consecutive rows: (N - W + 1, n)."""
    c = np.vstack([np.zeros((1, E.shape[1])), np.cumsum(E, axis=0)])
    return np.asarray((c[W:] - c[:-W]) / W)


def uncertainty_bound(segments: list[np.ndarray], A: np.ndarray, v_bar: np.ndarray,
                      max_window: int, margin: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Modelling-uncertainty bound of one mode from its one-step errors (module doc).

    Parameters
    ----------
    segments : list of numpy.ndarray
        One-step errors of the mode, each (N_s, n) over consecutive samples.
    A : numpy.ndarray
        (n, n) the mode's state matrix.
    v_bar : numpy.ndarray
        (n,) measurement-noise bound.
    max_window : int
        Longest window W, samples (>= 1).
    margin : float
        Factor on the largest excess.

    Returns
    -------
    eta_bar : numpy.ndarray
        (n,) ``margin x max_W max_k (|mean_W(e)_k| - noise_l1(W))+``, state units per sample.
    excess : numpy.ndarray
        (n,) the largest excess itself (0 where the noise bound explains every window).
    samples : int
        Number of one-step errors behind it.
    """
    n = A.shape[0]
    excess = np.zeros(n)
    for W in range(1, max_window + 1):
        term = noise_l1_bound(np.full(W, 1.0 / W), A, v_bar)
        for E in segments:
            if E.shape[0] >= W:
                m = np.abs(_window_means(E, W)).max(axis=0)
                excess = np.maximum(excess, m - term)
    return margin * excess, excess, int(sum(E.shape[0] for E in segments))


def one_step_bound(A: np.ndarray, v_bar: np.ndarray, eta_bar: np.ndarray) -> np.ndarray:
    """Bound on ``|e_i| = |v_{k+1} - A v_k + eta_k|_i``: ``v_bar + |A| v_bar + eta_bar`` (n,)."""
    return np.asarray(v_bar + np.abs(A) @ v_bar + eta_bar)


# ------------------------------------------------------------------ model quality (issue 20)
#
# What a control engineer checks before trusting a model (MATLAB's ``compare`` and ``present``,
# SIPPY's outputs): the multi-step simulation on held-out data, the standard errors of the
# coefficients and of the eigenvalues, the conditioning of the regression, how much of each
# input's variation is its own (not produced by feedback from the outputs), and whether the
# noise bound is compatible with the residuals.

def simulate(models: list[AffineModel], q: np.ndarray, U: np.ndarray, x0: np.ndarray
             ) -> np.ndarray:
    """Multi-step (free-run) simulation ``x_{k+1} = A_q x_k + B_q u_k + offset_q``.

    Parameters
    ----------
    models : list of AffineModel
        One per mode.
    q : numpy.ndarray
        (N,) int mode of each step k -> k + 1 (the measured labels: an autonomous guard is
        not re-evaluated on the simulated state).
    U : numpy.ndarray
        (N, nu) inputs u_k.
    x0 : numpy.ndarray
        (n,) initial state (the first measurement).

    Returns
    -------
    numpy.ndarray
        (N + 1, n) x_0 .. x_N; a diverging model gives inf/NaN from where it overflows.
    """
    N, n = q.size, x0.size
    X = np.empty((N + 1, n))
    X[0] = x0
    q = np.asarray(q, dtype=int)
    F = np.empty((N, n))                 # the forcing B_q u_k + offset_q, vectorised
    for j, M in enumerate(models):
        m = q == j
        F[m] = U[m] @ M.B.T + M.offset
    As = [M.A for M in models]
    if len(set(q.tolist())) == 1 and N > 0:
        fast = _simulate_modal(As[int(q[0])], F, np.asarray(x0, dtype=float))
        if fast is not None:
            return fast
    with np.errstate(over="ignore", invalid="ignore"):
        if n == 1:                       # scalar: plain floats are ~10 x faster than numpy
            a = [float(A[0, 0]) for A in As]
            f = F[:, 0].tolist()
            ql = q.tolist()
            x = float(x0[0])
            out = [x]
            for k in range(N):
                x = a[ql[k]] * x + f[k]
                out.append(x)
            return np.asarray(out, dtype=float)[:, None]
        xv = np.asarray(x0, dtype=float)
        for k in range(N):
            xv = As[q[k]] @ xv + F[k]
            X[k + 1] = xv
    return X


def _simulate_modal(A: np.ndarray, F: np.ndarray, x0: np.ndarray) -> np.ndarray | None:
    """``x_{k+1} = A x_k + F_k`` in modal coordinates (``A = V diag(lam) V^-1``: one first-order
    recursion per eigenvalue, :func:`scipy.signal.lfilter`), or None when V is ill-conditioned
    (a nearly defective A: the loop is then the accurate way)."""
    lam, V = np.linalg.eig(A)
    if np.linalg.cond(V) > 1e6 or np.any(np.abs(lam) > 1.0 + 1e-9):
        return None                      # a growing mode: the loop reports its overflow as is
    Vi = np.linalg.inv(V)
    G = F @ Vi.T                                           # (N, n) forcing, modal
    z0 = Vi @ x0
    Z = np.empty((F.shape[0] + 1, lam.size), dtype=complex)
    Z[0] = z0
    for i, li in enumerate(lam):
        Z[1:, i], _ = lfilter([1.0], [1.0, -li], G[:, i], zi=[li * z0[i]])
    return np.asarray(np.real(Z @ V.T))


def nrmse_fit(Y: np.ndarray, Yhat: np.ndarray) -> np.ndarray:
    """Fit in percent per column, as MATLAB's ``compare``: ``100 (1 - |y - yhat| / |y - mean y|)``.

    Parameters
    ----------
    Y, Yhat : numpy.ndarray
        (N, m) measured and simulated outputs.

    Returns
    -------
    numpy.ndarray
        (m,) percent; 100 is a perfect fit, 0 no better than the mean, negative worse
        (-inf for a simulation that diverged).
    """
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        num = np.linalg.norm(Y - Yhat, axis=0)      # a diverged simulation: inf, said as such
        den = np.linalg.norm(Y - Y.mean(axis=0), axis=0)
        fit = 100.0 * (1.0 - num / np.where(den > 0, den, np.nan))
    return np.asarray(np.where(np.isfinite(fit), fit, -np.inf))


def condition_number(Theta: np.ndarray) -> float:
    """Condition number of the regression (N, p) with its columns scaled to unit norm.

    Scaling first makes it a statement about collinearity, not about the units of the
    columns (Belsley's diagnostic); a constant (offset) column is scaled like the rest.
    """
    norms = np.linalg.norm(Theta, axis=0)
    if Theta.size == 0 or np.any(norms == 0):
        return float("inf")
    # the square root of the scaled Gram matrix's condition (p x p: LAPACK on the tall
    # matrix itself is slow when the BLAS threads compete for the cores); above ~1e7 the
    # Gram matrix's rounding decides, and the regression is singular for every purpose here
    G = (Theta.T @ Theta) / np.outer(norms, norms)
    ev = np.linalg.eigvalsh(G)
    if ev[0] <= 1e-14 * ev[-1]:
        return float("inf")
    return float(math.sqrt(ev[-1] / ev[0]))


def hac_covariance(Theta: np.ndarray, E: np.ndarray, Z: np.ndarray | None = None, *,
                   breaks: np.ndarray | None = None, lags: int = 2) -> np.ndarray:
    """Covariance of the least-squares / IV coefficients ``Xi`` (p, m), sandwich form.

    ``Xi = M^-1 Z' Y`` with ``M = Z' Theta`` (Z = Theta for least squares), so
    ``Xi - Xi_true = M^-1 sum_k z_k e_k'`` and ``cov(vec Xi) = (I_m (x) M^-1) S (I_m (x) M^-1)'``
    with ``S`` the long-run covariance of ``g_k = e_k (x) z_k`` (Newey-West, Bartlett weights
    over ``lags`` lags).
    The lags are needed: the one-step error ``v_{k+1} - A v_k + eta_k`` of a measured state
    is correlated over one sample, so the textbook ``sigma^2 (X'X)^-1`` misstates the spread.
    Conservative where the measurement noise dominates and A is near I (see the code).

    Parameters
    ----------
    Theta : numpy.ndarray
        (N, p) regressors.
    E : numpy.ndarray
        (N, m) residuals of the fit.
    Z : numpy.ndarray, optional
        (N, p) instruments (IV).
    breaks : numpy.ndarray, optional
        (N,) bool: row k does not follow row k - 1 in time (a new record or a hole); the
        lagged products across it are left out.
    lags : int

    Returns
    -------
    numpy.ndarray
        (m p, m p) covariance of ``vec(Xi)`` (column-major: output j's coefficients at
        ``j p .. j p + p - 1``).
    """
    Zm = Theta if Z is None else Z
    N, p = Theta.shape
    m = E.shape[1]
    if N <= p:
        return np.full((m * p, m * p), np.inf)
    G = (E[:, :, None] * Zm[:, None, :]).reshape(N, m * p)      # e_k (x) z_k
    # centred: zero already at a least-squares / IV solution (its normal equations); at
    # coefficients from elsewhere (a subspace fit) the mean is a bias, not a spread
    G = G - G.mean(axis=0)
    S0 = G.T @ G
    cont = np.ones(N, dtype=bool) if breaks is None else ~np.asarray(breaks, dtype=bool)
    ok = np.ones(N, dtype=bool)
    Gam = []
    for lag in range(1, lags + 1):
        ok = ok[1:] & cont[lag:] if lag > 1 else cont[1:].copy()
        if not ok.any():
            break
        P = G[lag:][ok].T @ G[:-lag][ok]
        Gam.append(P + P.T)
    # Newey-West (Bartlett weights 1 - l / (lags + 1)): always positive semidefinite. Where
    # the measurement noise dominates and A is near I, the MA(1) error's lag-1 covariance
    # nearly cancels its variance and these weights leave part of it in, so the standard
    # errors are conservative there (measured on a simulation of the dc_motor example over 20
    # seeds: 3.8 x the spread of the estimates; on the closed-loop test plant 1.5 x). Uniform
    # weights cancel it in expectation but, estimated, are too noisy (4 standard errors off).
    S = S0 + sum((1.0 - (i + 1) / (lags + 1.0)) * g for i, g in enumerate(Gam))
    S *= N / (N - p)
    # A regressor that is a linear combination of the others (an input that is a static
    # feedback of the measured outputs) has no determined coefficient: the directions of the
    # (column-scaled) normal matrix with a singular value below 1e-9 of the largest are
    # undetermined, and every coefficient they touch gets an infinite standard error, not
    # the small spread of the minimum-norm solution.
    M = Zm.T @ Theta
    sc = np.linalg.norm(Theta, axis=0) * np.linalg.norm(Zm, axis=0)
    sc = np.where(sc > 0, np.sqrt(sc), 1.0)
    Ms = M / sc[:, None] / sc[None, :]
    U_, sv, Vt = np.linalg.svd(Ms)
    null = sv < 1e-9 * sv[0] if sv.size and sv[0] > 0 else np.ones(p, dtype=bool)
    inv_s = np.where(null, 0.0, 1.0 / np.where(null, 1.0, sv))
    Minv = (Vt.T * inv_s) @ U_.T / sc[:, None] / sc[None, :]
    K = np.kron(np.eye(m), Minv)
    cov = np.asarray(K @ S @ K.T)
    if null.any():
        bad = np.any(np.abs(Vt[null]) > 1e-6, axis=0)          # (p,) undetermined columns
        bad_all = np.tile(bad, m)
        cov[bad_all, :] = np.inf
        cov[:, bad_all] = np.inf
    return cov


def eigen_intervals(A: np.ndarray, cov_A: np.ndarray, level: float = 0.95
                    ) -> dict[str, np.ndarray | float]:
    """Eigenvalues of A with standard errors (first-order perturbation) and joint intervals.

    ``d lambda_i = w_i' dA v_i`` (w_i' the rows of V^-1); the variance of the real and the
    imaginary part follows from ``cov_A``. The intervals are simultaneous at ``level``
    (Bonferroni over every real and imaginary part stated), so all of them hold together.

    Parameters
    ----------
    A : numpy.ndarray
        (n, n).
    cov_A : numpy.ndarray
        (n n, n n) covariance of ``A.ravel()`` (row-major: entry (r, c) at ``r n + c``).
    level : float

    Returns
    -------
    dict
        ``eig`` (n,) complex, ``se_real``, ``se_imag`` (n,), ``z`` (the multiplier of the
        standard errors), ``level``.
    """
    lam, V = np.linalg.eig(A)
    W = np.linalg.inv(V)
    n = lam.size
    se_r, se_i = np.zeros(n), np.zeros(n)
    for i in range(n):
        g = np.outer(W[i], V[:, i]).ravel()     # d lambda_i / d A_rc = W_ir V_ci
        for part, se in ((g.real, se_r), (g.imag, se_i)):
            used = np.abs(part) > 1e-12 * max(float(np.abs(g).max()), 1e-300)
            C = cov_A[np.ix_(used, used)]
            if not np.all(np.isfinite(C)):
                se[i] = math.inf            # it depends on an undetermined coefficient
            elif used.any():
                pu = part[used]
                se[i] = math.sqrt(max(float(pu @ C @ pu), 0.0))
    statements = n + int(np.count_nonzero(np.abs(lam.imag) > 0))
    z = float(norm.ppf(1.0 - (1.0 - level) / (2.0 * max(statements, 1))))
    return {"eig": lam, "se_real": se_r, "se_imag": se_i, "z": z, "level": level}


def partial_residual(u: np.ndarray, others: np.ndarray) -> np.ndarray:
    """The part of u (N,) that a linear combination of ``others`` (N, r) does not explain."""
    if others.size == 0:
        return np.asarray(u - u.mean())
    return np.asarray(u - others @ partial_coefficients(u, others))


def partial_coefficients(u: np.ndarray, others: np.ndarray) -> np.ndarray:
    """Least-squares coefficients (r,) of u (N,) on ``others`` (N, r), from the column-scaled
    normal equations (r x r; a dependent column gets the minimum-norm share)."""
    sc = np.linalg.norm(others, axis=0)
    sc = np.where(sc > 0, sc, 1.0)
    O = others / sc
    coef = np.linalg.lstsq(O.T @ O, O.T @ u, rcond=1e-12)[0]
    return np.asarray(coef / sc)


def pe_order(u: np.ndarray, max_order: int, tol: float = 1e-4) -> int:
    """Order of persistent excitation of u (N,): the largest L <= max_order whose L x L
    Toeplitz autocovariance has its smallest eigenvalue above ``tol`` times its largest.

    Ljung (1999, Def. 13.1): a model with L free input coefficients needs excitation of
    order L. A constant has order 0, a single step about 1, white noise any order.
    """
    x = np.asarray(u, dtype=float) - float(np.mean(u))
    N = x.size
    if N < 2 or not np.any(x):
        return 0
    r = np.array([x[:N - l] @ x[l:] / N for l in range(max_order)])
    if r[0] <= 0:
        return 0
    order = 0
    for L in range(1, max_order + 1):
        idx = np.abs(np.arange(L)[:, None] - np.arange(L)[None, :])
        ev = np.linalg.eigvalsh(r[idx])
        if ev[0] <= tol * ev[-1]:
            break
        order = L
    return order


def hf_noise_std(E: np.ndarray, A: np.ndarray, breaks: np.ndarray | None = None) -> np.ndarray:
    """Standard deviation of white measurement noise from the high-frequency part of the
    one-step errors.

    ``e_k = v_{k+1} - A v_k + eta_k``; its first difference removes a slowly varying modelling
    error ``eta`` and leaves ``d_k = v_{k+2} - (I + A) v_{k+1} + A v_k``, whose variance per
    output is ``sum_l sigma_l^2 (delta_il^2 + (delta_il + A_il)^2 + A_il^2)`` for independent
    white noise of standard deviation sigma_l: solved for sigma^2 >= 0 (non-negative least
    squares).

    Parameters
    ----------
    E : numpy.ndarray
        (N, n) one-step errors over consecutive samples.
    A : numpy.ndarray
        (n, n).
    breaks : numpy.ndarray, optional
        (N,) bool: row k does not follow row k - 1 (differences across it are left out).

    Returns
    -------
    numpy.ndarray
        (n,) sigma, output units.
    """
    n = A.shape[0]
    if E.shape[0] < 3:
        return np.zeros(n)
    D = np.diff(E, axis=0)
    if breaks is not None:
        D = D[~np.asarray(breaks, dtype=bool)[1:]]
    I = np.eye(n)
    G = I ** 2 + (I + A) ** 2 + A ** 2
    s2 = nnls(G, np.mean(D ** 2, axis=0))[0]
    return np.asarray(np.sqrt(s2))


def physical_velocity(a: float, beta: float, c: float, Ts: float) -> dict[str, float]:
    """Inertia, viscous damping and constant torque of ``J dw/dt = tau - b w - tau_0``.

    Its exact zero-order hold is ``w+ = a w + beta tau + c`` with ``a = exp(-b Ts / J)``,
    ``beta = (1 - a) / b`` and ``c = -beta tau_0`` (the README's motor: ``tau_0`` the Coulomb
    friction while it turns forward), so ``b = (1 - a) / beta``, ``J = -b Ts / ln a``,
    ``tau_0 = -c / beta``. Needs ``0 < a < 1`` and ``beta > 0``.

    Returns
    -------
    dict
        ``inertia`` (kg m^2), ``damping`` (N m s/rad), ``gain`` (1/J, rad/s^2 per N m),
        ``constant_torque`` (N m); empty when a or beta is outside the physical range.
    """
    if not (0.0 < a < 1.0 and beta > 0.0 and Ts > 0.0):
        return {}
    b = (1.0 - a) / beta
    J = -b * Ts / math.log(a)
    return {"inertia": J, "damping": b, "gain": 1.0 / J, "constant_torque": -c / beta}


def physical_joint(A: np.ndarray, B: np.ndarray, c: np.ndarray, Ts: float) -> dict[str, float]:
    """Inertia, damping, stiffness and constant torque of a joint from its position/velocity
    model (``A`` (2, 2), ``B`` (2,), ``c`` (2,): rows position, velocity; one torque input).

    The continuous model ``dp/dt = v``, ``J dv/dt = tau - b v - k p - tau_0`` is recovered by
    the matrix logarithm ``A_c = log(A) / Ts`` and the inverse of the zero-order hold
    ``B = (int_0^Ts exp(A_c s) ds) B_c`` (the same for the offset):
    ``J = 1 / B_c[v]``, ``b = -A_c[v, v] J``, ``k = -A_c[v, p] J`` (a spring or the gravity's
    slope), ``tau_0 = -c_c[v] J``.

    Returns
    -------
    dict
        ``inertia``, ``damping``, ``stiffness``, ``gain`` (1/J), ``constant_torque``,
        ``kinematic`` (A_c[p, v], 1 for a position that integrates the velocity); empty when
        the logarithm is not real or the gain not positive.
    """
    if Ts <= 0.0 or np.any(np.real(np.linalg.eigvals(A)) <= 0.0):
        return {}
    Ac = np.asarray(logm(A)) / Ts
    if np.max(np.abs(np.imag(Ac))) > 1e-9 * max(1.0, float(np.max(np.abs(Ac)))):
        return {}
    Ac = np.real(Ac)
    # int_0^Ts exp(Ac s) ds: the top-right block of exp([[Ac, I], [0, 0]] Ts) (Van Loan; no
    # inverse of Ac, which is singular for a free joint)
    M = np.zeros((4, 4))
    M[:2, :2] = Ac * Ts
    M[:2, 2:] = np.eye(2) * Ts
    Gam = expm(M)[:2, 2:]
    Bc = np.linalg.solve(Gam, np.asarray(B, dtype=float))
    cc = np.linalg.solve(Gam, np.asarray(c, dtype=float))
    if not Bc[1] > 0.0:
        return {}
    J = 1.0 / Bc[1]
    return {"inertia": float(J), "damping": float(-Ac[1, 1] * J),
            "stiffness": float(-Ac[1, 0] * J), "gain": float(Bc[1]),
            "constant_torque": float(-cc[1] * J), "kinematic": float(Ac[0, 1])}
