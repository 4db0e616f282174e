"""Runtime of a bank of H-infinity residual generators with a sensitivity constraint.

Runs what ``python -m fd_monitor design hinf_sc`` writes (thesis ch. 4-7): one observer-based
residual generator per fault (thesis eq. 4.5-4.7, 5.8-5.10, 6.9-6.14)::

    dxhat/dt = A(rho) xhat + B(rho) u + L(rho) (y - C xhat),     r = H (y - C xhat)

with ``A(rho) = A0 + sum_j rho_j A_j`` and ``L(rho) = L0 + sum_j rho_j L_j`` (LPV, thesis
ch. 6); an LTI generator has no parameters, and the generator of an uncertain plant
(thesis ch. 5) runs on the nominal ``A0`` only. The continuous-time observer is run at the
plant's sample time ``Ts`` with the input held over a sample (zero-order hold):

* ``exact`` discretisation: ``xhat+ = Ad xhat + Bd u + Ld (y - C xhat)`` with
  ``[Ad, Bd, Ld] = zoh(A, [B, L], Ts)``, so the fault-free error of an LTI plant with
  piecewise-constant input obeys ``e+ = (Ad - Ld C) e`` exactly (no false residual from the
  input); used when ``Ad - Ld C`` is Schur;
* ``hold`` discretisation: ``xhat+ = zoh(A - L C, [B, L], Ts)`` applied to ``(u, y)``, stable
  whenever ``A - L C`` is Hurwitz; used otherwise (fast observer poles, ``|eig| Ts > 1``).

The residual of generator ``i`` is evaluated by its Euclidean norm ``||r_i||`` and compared
with its threshold; an alarm of generator ``i`` isolates fault ``i``. The model and the
generators are :mod:`fd_monitor.core.hinf_model`; the certificate the loader re-verifies is
:mod:`fd_monitor.core.hinf_certificate`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from fd_monitor.core.hinf_model import Generator, bank_results, parse_bank
from fd_monitor.core.plant import zoh
from fd_monitor.model.nonlinear import SCHEDULING_MAPS
from fd_monitor.model.system import System

__all__ = ["ResidualBank"]


def _expm_small(M: np.ndarray) -> np.ndarray:
    """Matrix exponential by scaling and squaring of an order-16 Taylor series.

    For the small matrices of a bank re-discretised at every sample (LPV) this is several
    times faster than ``scipy.linalg.expm`` (no Pade solve, no norm estimates); after
    scaling ``||M / 2^s||_1 <= 1/2``, so the truncation error is below ``0.5^17 / 17!``
    (relative, ~1e-20) before squaring.
    """
    nrm = float(np.abs(M).sum(axis=0).max())
    s = max(0, int(np.ceil(np.log2(nrm / 0.5)))) if nrm > 0.5 else 0
    X = M / (2.0 ** s)
    E = np.eye(M.shape[0])
    T = np.eye(M.shape[0])
    for k in range(1, 17):
        T = T @ X / k
        E = E + T
    for _ in range(s):
        E = E @ E
    return E


class ResidualBank:
    """Step-based runtime of a bank of residual generators (one per fault).

    Parameters
    ----------
    system : System
        The plant (its sample time is the step of the bank).
    gains : GainFile or mapping
        A loaded ``hinf_sc`` gain file (or its ``results`` mapping).
    thresholds : sequence of float, optional
        Per generator, in output units; default ``results.thresholds`` (or +inf).
    discretisation : str
        ``auto`` (``exact`` when stable, else ``hold``), ``exact`` or ``hold``.

    Attributes
    ----------
    faults : tuple of str
        The fault of each generator, in order.
    residuals : list of numpy.ndarray
        The residual vectors ``r_i`` (p,) of the last step.
    """

    def __init__(self, system: System, gains: Any, thresholds: Sequence[float] | None = None,
                 discretisation: str = "auto") -> None:
        results = bank_results(gains)
        self.kind, self.model, self.generators = parse_bank(results)
        self.dt = float(system.sample_time)
        self.faults = tuple(g.fault for g in self.generators)
        n_gen = len(self.generators)
        th = thresholds if thresholds is not None else results.get("thresholds")
        self.thresholds = (np.full(n_gen, np.inf) if th is None
                           else np.asarray(th, dtype=float).reshape(n_gen))
        if discretisation not in ("auto", "exact", "hold"):
            raise ValueError(f"discretisation: expected auto, exact or hold, got "
                             f"{discretisation!r}")
        self._disc_mode = discretisation
        n = self.model.n
        self.xhat = np.zeros((n_gen, n))
        self.residuals: list[np.ndarray] = [np.zeros(self.model.C.shape[0])] * n_gen
        self._lti = [self._discretise(g, None) for g in self.generators] \
            if self.kind != "lpv" else []
        self.discretisation = [d[3] for d in self._lti]

    def _discretise(self, g: Generator, rho: np.ndarray | None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
        A = self.model.A0 if g.kind == "uncertain" else self.model.A(rho)
        B = self.model.B(None if g.kind == "uncertain" else rho)
        L = g.L(rho)
        C = self.model.C
        nu = B.shape[1]
        fast = rho is not None  # LPV: re-discretised at every sample
        if self._disc_mode in ("auto", "exact"):
            Ad, G = zoh(A, np.hstack([B, L]), self.dt, _expm_small if fast else None)
            Bd, Ld = G[:, :nu], G[:, nu:]
            if self._disc_mode == "exact" or \
                    np.abs(np.linalg.eigvals(Ad - Ld @ C)).max() < 1.0 - 1e-9:
                return Ad - Ld @ C, Bd, Ld, "exact"
        Ad, G = zoh(A - L @ C, np.hstack([B, L]), self.dt,
                    _expm_small if fast else None)
        return Ad, G[:, :nu], G[:, nu:], "hold"

    def reset(self, xhat0: np.ndarray | None = None) -> None:
        """Set every observer state to ``xhat0`` (n,) (default zeros)."""
        self.xhat[:] = 0.0 if xhat0 is None else np.asarray(xhat0, dtype=float)

    def schedule(self, y: np.ndarray) -> np.ndarray:
        """Parameter ``rho`` (d,) from the measurement by the bank's scheduling map, clipped to
        the design box; ``ValueError`` when the bank has none."""
        sched = self.model.scheduling
        if not sched:
            raise ValueError("this LPV bank needs the measured parameter rho (no scheduling "
                             "map in its gain file)")
        rho = SCHEDULING_MAPS[str(sched["map"])](np.asarray(y, dtype=float),
                                                  dict(sched.get("params") or {}))
        return np.clip(rho, self.model.rho_min, self.model.rho_max)

    def step(self, k: int, u: np.ndarray, y: np.ndarray,
             rho: np.ndarray | None = None) -> np.ndarray:
        """Process sample ``k``: residuals from ``y_k``, then advance every observer.

        Parameters
        ----------
        k : int
            Sample index (time ``k Ts``; kept for the caller's bookkeeping).
        u : numpy.ndarray
            (nu,) input applied over ``[k Ts, (k+1) Ts)``.
        y : numpy.ndarray
            (p,) measurement at ``k Ts``.
        rho : numpy.ndarray, optional
            (d,) measured parameter of an LPV bank (clipped to the design box); when
            omitted an LPV bank computes it from ``y`` with its scheduling map.

        Returns
        -------
        numpy.ndarray
            (n_gen,) residual norms ``||r_i||`` (output units).
        """
        u = np.asarray(u, dtype=float).reshape(-1)
        y = np.asarray(y, dtype=float).reshape(-1)
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
            raise ValueError(f"sample {k}: u and y must be finite")
        C = self.model.C
        if self.kind == "lpv":
            r_ = self.schedule(y) if rho is None else np.clip(
                np.asarray(rho, dtype=float).reshape(-1), self.model.rho_min,
                self.model.rho_max)
            mats = [self._discretise(g, r_) for g in self.generators]
            self.discretisation = [m[3] for m in mats]
        else:
            mats = self._lti
        norms = np.empty(len(self.generators))
        for i, (g, (Ad, Bd, Ld, _how)) in enumerate(zip(self.generators, mats)):
            innov = y - C @ self.xhat[i]
            r = g.H @ innov
            self.residuals[i] = r
            norms[i] = float(np.linalg.norm(r))
            self.xhat[i] = Ad @ self.xhat[i] + Bd @ u + Ld @ y
        return norms

    def alarms(self, norms: np.ndarray) -> np.ndarray:
        """(n_gen,) bool: ``||r_i|| > threshold_i``."""
        return np.asarray(norms) > self.thresholds

    def run(self, u: np.ndarray, y: np.ndarray, rho: np.ndarray | None = None) -> np.ndarray:
        """Run over a whole record: u (K, nu), y (K, p), rho (K, d) -> norms (K, n_gen)."""
        K = y.shape[0]
        out = np.empty((K, len(self.generators)))
        for k in range(K):
            out[k] = self.step(k, u[k], y[k], None if rho is None else rho[k])
        return out
