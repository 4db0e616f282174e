"""Plausibility of a sample: physical range and distance from the one-step prediction.

A finite value can still be nonsense: ``y = 1e300`` from a broken driver, or ``3.5e307``
from one flipped bit in a bag. Let into the observer it ruins the state and, through the
estimator, sigma-hat for good. Such a sample is refused where samples enter the runtime
(:meth:`fd_monitor.core.hybrid_observer.HybridObserver.step`,
:meth:`fd_monitor.core.qb.QBObserver.step`), before any state changes, with a
:class:`~fd_monitor.model.errors.MessageError` whose text contains ``implausible``; the caller
treats it like a NaN message: reported, left out, and the runtime restarts at the next
valid sample (offline: :func:`fd_monitor.analysis.offline.run_thresholds`; nodes: the entry node's
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

import math
from collections.abc import Callable
from operator import le, sub
from typing import Any, cast

import numpy as np

from fd_monitor.model.errors import ImplausibleError
from fd_monitor.model.system import System

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
        self._y_lo, self._y_hi = self.y_lo.tolist(), self.y_hi.tolist()
        self._u_lo, self._u_hi = self.u_lo.tolist(), self.u_hi.tolist()
        self._tol = self.tolerance.tolist()
        self._enter: dict[bool, Callable[..., list[float] | None]] = {}

    def compensator(self, predicted: bool) -> Callable[..., list[float] | None]:
        """The single-stream entry test fused with ``y~ = y - sigma``, compiled once.

        ``predicted=False``: ``f(y, u, s)``; ``True``: ``f(y, u, s, x)`` with ``x`` the
        predicted state (``y_pred = x + s``, C = I). Returns ``[y_i - s_i]`` when the sample
        passes the tests :meth:`check` makes (the same comparisons, on the same values, with
        the bounds written in as constants), else None: then :meth:`check` words the refusal
        (or, for values it accepts, e.g. a NaN prediction, the caller goes on as before).
        """
        if predicted not in self._enter:
            terms = [f"{a!r} <= y[{i}] <= {b!r}"
                     for i, (a, b) in enumerate(zip(self._y_lo, self._y_hi))]
            terms += [f"{a!r} <= u[{i}] <= {b!r}"
                      for i, (a, b) in enumerate(zip(self._u_lo, self._u_hi))]
            if predicted:
                terms += [f"abs(y[{i}] - (x[{i}] + s[{i}])) <= {t!r}"
                          for i, t in enumerate(self._tol)]
            yt = ", ".join(f"y[{i}] - s[{i}]" for i in range(len(self._y_lo)))
            src = (f"lambda y, u, s{', x' if predicted else ''}: "
                   f"[{yt}] if {' and '.join(terms) or 'True'} else None")
            self._enter[predicted] = cast(Callable[..., "list[float] | None"],
                                          eval(src, {"inf": math.inf, "nan": math.nan}))
        return self._enter[predicted]

    def check(self, k: int, u: Any, y: Any, y_pred: Any = None) -> None:
        """Raise :class:`~fd_monitor.model.errors.ImplausibleError` unless sample k is plausible.

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
        # Python floats: one stream, a few channels (a numpy call costs more than the test)
        yy = np.ravel(y).tolist() if not isinstance(y, list) else y
        uu = np.ravel(u).tolist() if not isinstance(u, list) else u
        # the common case in C-level maps; the loops below only to word a refusal
        if all(map(le, self._y_lo, yy)) and all(map(le, yy, self._y_hi)) and \
                all(map(le, self._u_lo, uu)) and all(map(le, uu, self._u_hi)) and \
                (y_pred is None or (isinstance(y_pred, list) and all(
                    map(le, map(abs, map(sub, yy, y_pred)), self._tol)))):
            return
        for name, names, v, lo, hi in (("y", s.outputs, yy, self._y_lo, self._y_hi),
                                       ("u", s.inputs, uu, self._u_lo, self._u_hi)):
            for i, (vi, a, b) in enumerate(zip(v, lo, hi)):
                if vi < a or vi > b:
                    raise ImplausibleError(
                        f"{name} at sample {k}: {names[i]} = {float(vi)!r} outside the "
                        f"physical range [{a:g}, {b:g}] of plant {s.name!r}: implausible "
                        f"(refused like NaN)")
        if y_pred is None:
            return
        yp = np.ravel(y_pred).tolist() if not isinstance(y_pred, list) else y_pred
        for i, (vi, pi, tol) in enumerate(zip(yy, yp, self._tol)):
            d = abs(vi - pi)
            if d > tol:
                raise ImplausibleError(
                    f"y at sample {k}: {s.outputs[i]} = {float(vi)!r} is {d:.3g} away "
                    f"from its prediction, more than {self.factor:g} x the noise bound "
                    f"({tol:g}): implausible (refused like NaN)")
