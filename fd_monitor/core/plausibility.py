"""Plausibility of a sample: physical range and distance from the one-step prediction.

A finite value can still be nonsense: ``y = 1e300`` from a broken driver, or ``3.5e307``
from one flipped bit in a bag. Let into the observer it ruins the state and, through the
estimator, sigma-hat for good. Such a sample is refused where samples enter the runtime
(:meth:`fd_monitor.core.hybrid_observer.HybridObserver.step`,
:meth:`fd_monitor.core.qb.QBObserver.step`), before any state changes, with a
:class:`~fd_monitor.errors.MessageError` whose text contains ``implausible``; the caller
treats it like a NaN message: reported, left out, and the runtime restarts at the next
valid sample (offline: :func:`fd_monitor.offline.run_thresholds`; nodes: the entry node's
bad-input path). Two tests:

1. **Range**: each ``y_i`` and ``u_j`` inside the plant file's ``limits`` (the instruments'
   physical range; ``|v| <= MAX_MAGNITUDE`` for a channel without limits).
2. **Prediction** (observers with a one-step prediction ``y_pred`` of the measurement):
   ``|y_i - y_pred_i| <= PREDICTION_FACTOR * vbar_i`` with ``vbar_i`` the plant's
   measurement-noise bound (skipped where ``vbar_i = 0``).

``PREDICTION_FACTOR = 1000``: for ``three_tank`` (``vbar = 1 mm``) a jump of 1 m away from
the prediction, the whole height of a tank. The largest fault of the bag library is a 30 mm
sensor bias (30 noise bounds), so every fault there is more than 30 times inside the limit and
is detected, never refused as implausible: a fault is a change the monitor must see, an
implausible value is one no plant can produce.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fd_monitor.errors import ImplausibleError
from fd_monitor.system import System

__all__ = ["PREDICTION_FACTOR", "Plausibility"]

#: Factor on the measurement-noise bound beyond which |y - y_pred| is implausible.
PREDICTION_FACTOR = 1000.0


class Plausibility:
    """The plausibility test of one plant's samples (pure, stateless).

    Parameters
    ----------
    system : System
        Its ``output_limits`` (ny, 2), ``input_limits`` (nu, 2) and ``measurement_noise``
        (ny,) are used.
    factor : float
        Factor on the noise bound of the prediction test.
    """

    def __init__(self, system: System, factor: float = PREDICTION_FACTOR) -> None:
        self.system = system
        self.factor = float(factor)
        self.y_lo, self.y_hi = system.output_limits[:, 0], system.output_limits[:, 1]
        self.u_lo, self.u_hi = system.input_limits[:, 0], system.input_limits[:, 1]
        vbar = np.asarray(system.measurement_noise, dtype=float)
        #: (ny,) largest |y - y_pred| accepted (inf where the noise bound is 0).
        self.tolerance = np.where(vbar > 0, self.factor * vbar, np.inf)

    def check(self, k: int, u: Any, y: Any, y_pred: Any = None) -> None:
        """Raise :class:`~fd_monitor.errors.ImplausibleError` unless sample k is plausible.

        Parameters
        ----------
        k : int
            Sample index (for the message).
        u : array_like
            (nu,) finite inputs.
        y : array_like
            (ny,) finite measurements, output units.
        y_pred : array_like, optional
            (ny,) one-step prediction of y (None: the range test only).
        """
        s = self.system
        yy = np.asarray(y, dtype=float).reshape(-1)
        uu = np.asarray(u, dtype=float).reshape(-1)
        for name, names, v, lo, hi in (("y", s.outputs, yy, self.y_lo, self.y_hi),
                                       ("u", s.inputs, uu, self.u_lo, self.u_hi)):
            bad = np.flatnonzero((v < lo) | (v > hi))
            if bad.size:
                i = int(bad[0])
                raise ImplausibleError(
                    f"{name} at sample {k}: {names[i]} = {float(v[i])!r} outside the "
                    f"physical range [{lo[i]:g}, {hi[i]:g}] of plant {s.name!r}: implausible "
                    f"(refused like NaN)")
        if y_pred is None:
            return
        d = np.abs(yy - np.asarray(y_pred, dtype=float).reshape(-1))
        bad = np.flatnonzero(d > self.tolerance)
        if bad.size:
            i = int(bad[0])
            raise ImplausibleError(
                f"y at sample {k}: {s.outputs[i]} = {float(yy[i])!r} is {float(d[i]):.3g} away "
                f"from its prediction, more than {self.factor:g} x the noise bound "
                f"({self.tolerance[i]:g}): implausible (refused like NaN)")
