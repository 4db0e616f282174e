"""Singular-value frequency responses of state-space maps (numpy only).

Used to draw and tabulate the fault -> residual and nuisance -> residual maps of residual
generators (thesis Fig. 4.4, 5.1-5.4, 7.4-7.6; Farhat & Koenig Fig. 3).
"""

from __future__ import annotations

import numpy as np

__all__ = ["freq_response", "sigma", "sigma_db"]


def freq_response(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray,
                  omega: np.ndarray, dt: float | None = None) -> np.ndarray:
    """Frequency response ``G(s) = C (s I - A)^-1 B + D`` on ``s = j omega``.

    Parameters
    ----------
    A : numpy.ndarray
        (n, n)
    B : numpy.ndarray
        (n, m)
    C : numpy.ndarray
        (p, n)
    D : numpy.ndarray
        (p, m)
    omega : numpy.ndarray
        (K,) angular frequencies, rad/s.
    dt : float, optional
        Sample time in s of a discrete-time map; then ``s`` is replaced by
        ``z = exp(j omega dt)``.

    Returns
    -------
    numpy.ndarray
        (K, p, m) complex.
    """
    A = np.atleast_2d(np.asarray(A, dtype=float))
    B = np.asarray(B, dtype=float).reshape(A.shape[0], -1)
    C = np.asarray(C, dtype=float).reshape(-1, A.shape[0])
    D = np.asarray(D, dtype=float).reshape(C.shape[0], B.shape[1])
    w = np.atleast_1d(np.asarray(omega, dtype=float))
    s = np.exp(1j * w * dt) if dt is not None else 1j * w
    n = A.shape[0]
    out = np.empty((w.size, C.shape[0], B.shape[1]), dtype=complex)
    eye = np.eye(n)
    for k, sk in enumerate(s):
        out[k] = C @ np.linalg.solve(sk * eye - A, B) + D
    return out


def sigma(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, omega: np.ndarray,
          dt: float | None = None) -> np.ndarray:
    """Singular values of the frequency response, largest first.

    Returns
    -------
    numpy.ndarray
        (K, min(p, m)) singular values (the unit of the output per unit of the input).
    """
    G = freq_response(A, B, C, D, omega, dt)
    return np.linalg.svd(G, compute_uv=False)


def sigma_db(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, omega: np.ndarray,
             dt: float | None = None) -> np.ndarray:
    """:func:`sigma` in dB (``20 log10``), floored at -400 dB. Shape (K, min(p, m))."""
    s = sigma(A, B, C, D, omega, dt)
    return 20.0 * np.log10(np.maximum(s, 1e-20))
