"""Filtered residual and detection threshold (Heracleous et al., eq. 8-19).

Per sample k: ``w_k = H[y~]_k`` (eq. 10), ``w^_k = H[x^]_k`` (eq. 13), ``r_k = w_k - w^_k``
(eq. 14), and the threshold in force

    R_{i,k} = max(nominal_{i,k}, override_{i,k-1})      (override: AGEI, NaN = none)
    nominal_{i,k} = noise_term_i + H_p_bar[eta_bar_i(q^) + remainder_bar_i(q^)]_k

(the combined form of eq. 19, see :mod:`fd_monitor.core.thresholds`). ``alarm_{i,k} = |r_{i,k}| >
R_{i,k}``: no latching (a per-sample flag, as published).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from fd_monitor.core.filters import FilterBank, FilterSpec, FloatFilter, as_floats
from fd_monitor.core.lazy import LazyArray, Output
from fd_monitor.core.thresholds import DiagnosisGains
from fd_monitor.model.system import System

__all__ = ["ResidualDetector", "DetectorOutput", "no_override"]



def no_override(ny: int, batch: int | None = None) -> np.ndarray:
    """The 'no threshold override' value: NaN everywhere, (ny,) or (N, ny)."""
    return np.full(ny if batch is None else (batch, ny), np.nan)


class DetectorOutput(Output):
    """Detector output at sample k.

    Attributes
    ----------
    k : int
    residual : numpy.ndarray
        (ny,) r_k, output units.
    w : numpy.ndarray
        (ny,) w_k = H[y~]_k, the filtered compensated measurement (AGEI input), output units.
    threshold : numpy.ndarray
        (ny,) R_k in force (override included).
    nominal : numpy.ndarray
        (ny,) nominal threshold r_bar at k (without override; AGEI's recognition test).
    alarm : numpy.ndarray
        (ny,) bool, |r_k| > R_k.

    :meth:`payload` names the fields; :mod:`fd_monitor.wire.topics` says which topic
    carries which. The arrays may be given as lists (made arrays on first read:
    :mod:`fd_monitor.core.lazy`).
    """

    __slots__ = ("_alarm", "_nominal", "_residual", "_threshold", "_w", "k")
    #: the keys of :meth:`payload`, in its order
    payload_names = ("residual", "w", "threshold", "nominal", "alarm")
    FIELDS = ("k", "residual", "w", "threshold", "nominal", "alarm")
    residual = LazyArray()
    w = LazyArray()
    threshold = LazyArray()
    nominal = LazyArray()
    alarm = LazyArray()

    def __init__(self, k: int, residual: Any, w: Any, threshold: Any, nominal: Any,
                 alarm: Any) -> None:
        self.k = k
        self._residual, self._w, self._threshold = residual, w, threshold
        self._nominal, self._alarm = nominal, alarm

    def payload(self) -> dict[str, Any]:
        """Field name -> value: ``residual``, ``w``, ``threshold``, ``nominal``, ``alarm``."""
        return {"residual": self.residual, "w": self.w, "threshold": self.threshold,
                "nominal": self.nominal, "alarm": self.alarm}


class ResidualDetector:
    """Residual generator and threshold schedule.

    Parameters
    ----------
    system : System
    gains : DiagnosisGains
    batch : int or None
        None: single stream; N: N runs.
    """

    def __init__(self, system: System, gains: DiagnosisGains, *,
                 batch: int | None = None) -> None:
        self.system = system
        self.gains = gains
        self.batch = batch
        self.N = 1 if batch is None else int(batch)
        ny = system.ny
        self._H_y = FilterBank(gains.filter, (self.N, ny))
        self._H_x = FilterBank(gains.filter, (self.N, ny))
        self._Hbar = FilterBank(FilterSpec(gains.h_p_bar, np.array([1.0])), (self.N, ny))
        self._noise = gains.noise_term[None, :]
        self._b = gains.per_sample_bound  # (s, ny)
        # single stream on floats; H_p_bar's input is a function of the mode only
        self._fyx = FloatFilter(gains.filter, 2 * ny)     # H[y~] and H[x^] side by side
        self._ny = ny
        self._fbar = FloatFilter(FilterSpec(gains.h_p_bar, np.array([1.0])), ny)
        self._bar_len = int(np.asarray(gains.h_p_bar).size)
        self._b1 = [row.tolist() for row in np.atleast_2d(self._b)]
        self._noise1 = gains.noise_term.tolist()
        # (H[y~], H[x^]) -> (w, r = w - w^, alarm = |r| > R), compiled once for ny
        r_ = [f"r{i} = ww[{i}] - ww[{ny + i}]" for i in range(ny)]
        src = ("def post(ww, R):\n" + "".join(f"    {a}\n" for a in r_) +
               f"    return [{', '.join(f'ww[{i}]' for i in range(ny))}], "
               f"[{', '.join(f'r{i}' for i in range(ny))}], "
               f"[{', '.join(f'abs(r{i}) > R[{i}]' for i in range(ny))}]\n")
        ns: dict[str, Any] = {}
        exec(src, ns)
        self._post1 = ns["post"]
        self.reset()

    def reset(self) -> None:
        """Forget the filters' history."""
        for f in (self._H_y, self._H_x, self._Hbar):
            f.reset()
        for g in (self._fyx, self._fbar):
            g.reset()
        self._bar_mode, self._bar_run = -1, 0
        self._nominal1: list[float] = []

    def step1(self, k: int, y_tilde: list[float], x_hat: list[float], mode: int,
              override: list[float] | None) -> tuple[DetectorOutput, list[float], list[float],
                                              list[float], list[bool]]:
        """Single stream on Python floats: the arithmetic of :meth:`step_batch` for one run.

        Returns the output and its r, w, nominal and alarm as lists (for the next component).
        ``override`` None: none (as NaN everywhere).
        """
        ww = self._fyx.step(y_tilde + x_hat[:self._ny])
        # The nominal threshold filters b[q^]: once the window at k and at k - 1 hold
        # b[q^] everywhere (len(h_p_bar) + 1 samples in one mode) its output bits are
        # unchanged; the filter's history, not stepped meanwhile, still holds that window.
        self._bar_run = self._bar_run + 1 if mode == self._bar_mode else 1
        self._bar_mode = mode
        if self._bar_run > self._bar_len and self._nominal1:
            nominal = self._nominal1
        else:
            nominal = [a + b for a, b in zip(self._noise1, self._fbar.step(self._b1[mode]))]
            self._nominal1 = nominal
        # no override (None, or NaN everywhere): R is the nominal threshold itself
        R = nominal if override is None else [
            n if o != o else (n if n >= o else o) for n, o in zip(nominal, override)]
        w, r, alarm = self._post1(ww, R)
        return DetectorOutput(k, r, w, R, nominal, alarm), r, w, nominal, alarm

    def step_batch(self, k: int, y_tilde: np.ndarray, x_hat: np.ndarray, mode: np.ndarray,
                   override: np.ndarray) -> tuple[np.ndarray, ...]:
        """Batched step: (N, ny), (N, n), (N,), (N, ny) -> (r, w, R, nominal, alarm)."""
        w = self._H_y.step(y_tilde)
        w_hat = self._H_x.step(x_hat)
        r = w - w_hat
        nominal = self._noise + self._Hbar.step(self._b[mode])
        R = np.where(np.isnan(override), nominal, np.fmax(nominal, override))
        alarm = np.abs(r) > R
        return r, w, R, nominal, alarm

    def step(self, k: int, y_tilde: np.ndarray, x_hat: np.ndarray, mode: int | np.ndarray,
             override: np.ndarray | None = None) -> DetectorOutput:
        """Process sample k.

        Parameters
        ----------
        k : int
        y_tilde : numpy.ndarray
            (ny,) y~_k from the observer.
        x_hat : numpy.ndarray
            (n,) x^_k from the observer.
        mode : int
            q^_k from the observer.
        override : numpy.ndarray, optional
            (ny,) thresholds decided by AGEI at k - 1 (NaN: none).

        Returns
        -------
        DetectorOutput
        """
        ny = self.system.ny
        if self.batch is None:
            return self.step1(k, as_floats(y_tilde), as_floats(x_hat), int(mode),
                              [math.nan] * ny if override is None else as_floats(override))[0]
        ov = no_override(ny, self.N) if override is None else override
        r, w, R, nom, al = self.step_batch(k, y_tilde, x_hat, np.asarray(mode, int), ov)
        return DetectorOutput(k, r, w, R, nom, al)
