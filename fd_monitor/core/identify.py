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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog

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
