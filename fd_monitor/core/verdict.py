"""The fault verdict: one latched "fault present" state per channel.

``fd/alarm`` says whether a residual is above its threshold *now*; with the sensor-bias
chain it is not a fault-present signal: once the bias estimator has learnt the bias, the
observer runs on the compensated measurement and the residual falls back within its
threshold while the bias is still there (three_tank, +2 cm on h1 from sample 40: the alarm
lasts 23 samples, the estimate keeps growing towards 2 cm). A consumer (a behaviour tree, a
safety controller) needs a state that stays set while the evidence lasts. Per channel i, at
sample k:

- **evidence**: an alarm on i, or the estimator isolating i, or a significant estimate
  ``|sigma^_i| > significance_i`` (the estimator's isolation threshold: the bound a healthy
  sensor's estimate stays under once converged);
- **set** when i is isolated, or when i alarmed on at least ``confirm`` of the last
  ``window`` samples (repeated alarms; one stray alarm does not set it); ``since`` is the
  sample it was set at;
- **kept** while evidence lasts; ``isolated`` is latched for the episode (the estimator's
  flag is evaluated per sample);
- **cleared** after ``clear_after`` samples in a row without evidence, or by :meth:`reset`
  (a new run).

Time is the sample index (a hole in the data counts as time passing); nothing here reads a
clock. Pure numpy: the nodes publish :meth:`VerdictOutput.payload` on ``fd/fault`` and report
it on ``/diagnostics``; the offline tests step it on the runtime's outputs.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["FaultVerdict", "VerdictOutput", "VerdictRule"]


@dataclass(frozen=True)
class VerdictRule:
    """When a channel's fault is set and cleared (samples).

    Attributes
    ----------
    confirm : int
        Alarms within ``window`` samples that set the fault (>= 1).
    window : int
        Samples over which alarms are counted (>= confirm).
    clear_after : int
        Samples in a row without evidence after which the fault clears (>= 1).
    """

    confirm: int = 3
    window: int = 10
    clear_after: int = 50

    def __post_init__(self) -> None:
        if not 1 <= self.confirm <= self.window or self.clear_after < 1:
            raise ValueError(f"verdict rule: need 1 <= confirm ({self.confirm}) <= window "
                             f"({self.window}) and clear_after ({self.clear_after}) >= 1")

    @classmethod
    def in_seconds(cls, Ts: float, confirm: int, window: float, clear_after: float
                   ) -> VerdictRule:
        """The rule with ``window`` and ``clear_after`` given in s of plant time (sample
        time ``Ts`` s), rounded to whole samples (at least ``confirm`` and 1)."""
        w = max(int(confirm), round(float(window) / Ts))
        return cls(int(confirm), w, max(1, round(float(clear_after) / Ts)))


@dataclass(frozen=True)
class VerdictOutput:
    """The verdict at sample ``k``.

    Attributes
    ----------
    k : int
    fault : numpy.ndarray
        (m,) bool: a fault is present on the channel.
    isolated : numpy.ndarray
        (m,) bool: isolated by the estimator during the current fault episode.
    estimate : numpy.ndarray
        (m,) the latest estimate (sensor bias, in the output's unit); NaN without one.
    since : numpy.ndarray
        (m,) int: the sample the fault was set at; -1 without a fault.
    changed : bool
        The verdict (fault, isolated, since) changed at k, or the estimate of a faulty
        channel moved by more than its significance since the last change: what is worth
        publishing.
    """

    k: int
    fault: np.ndarray
    isolated: np.ndarray
    estimate: np.ndarray
    since: np.ndarray
    changed: bool

    def payload(self) -> dict[str, Any]:
        """Field name -> value: ``fault``, ``isolated``, ``estimate``, ``since``."""
        return {"fault": self.fault, "isolated": self.isolated, "estimate": self.estimate,
                "since": self.since}

    def faulty(self, channels: Sequence[str]) -> list[str]:
        """The names of the channels at fault."""
        return [c for c, f in zip(channels, self.fault) if f]


class FaultVerdict:
    """Latched per-channel fault state from alarms and (optionally) an estimator.

    Parameters
    ----------
    n : int
        Number of channels m.
    rule : VerdictRule
    significance : array_like, optional
        (m,) |estimate| above which an estimate is evidence; None: estimates are never
        evidence (a method without an estimator).
    """

    def __init__(self, n: int, rule: VerdictRule | None = None,
                 significance: Any = None) -> None:
        self.n = int(n)
        self.rule = rule or VerdictRule()
        self.significance = (None if significance is None
                             else np.abs(np.asarray(significance, dtype=float)).reshape(n))
        self.reset()

    def reset(self) -> None:
        """No fault on any channel (a new run)."""
        n = self.n
        self._alarms: list[deque[int]] = [deque() for _ in range(n)]
        self.fault = np.zeros(n, dtype=bool)
        self.isolated = np.zeros(n, dtype=bool)
        self.since = np.full(n, -1, dtype=np.int64)
        self._last_evidence = np.full(n, -1, dtype=np.int64)
        self._reported_estimate = np.full(n, np.nan)
        self._started = False

    def step(self, k: int, alarm: Any, estimate: Any = None,
             isolated: Any = None) -> VerdictOutput:
        """Update with sample ``k``.

        Parameters
        ----------
        k : int
            Sample index (increasing; holes allowed).
        alarm : array_like
            (m,) alarm flags at k.
        estimate : array_like, optional
            (m,) the estimator's estimate after k (sigma^_{k+1}); None: no estimator.
        isolated : array_like, optional
            (m,) the estimator's isolation flags at k.
        """
        rule, n = self.rule, self.n
        alarm = np.asarray(alarm, dtype=bool).reshape(n)
        est = (np.full(n, np.nan) if estimate is None
               else np.asarray(estimate, dtype=float).reshape(n))
        iso = (np.zeros(n, dtype=bool) if isolated is None
               else np.asarray(isolated, dtype=bool).reshape(n))
        evidence = alarm | iso
        if self.significance is not None and estimate is not None:
            evidence |= np.abs(est) > self.significance
        before = (self.fault.copy(), self.isolated.copy())
        for i in range(n):
            alarms = self._alarms[i]
            if alarm[i]:
                alarms.append(k)
            while alarms and alarms[0] <= k - rule.window:
                alarms.popleft()
            if evidence[i]:
                self._last_evidence[i] = k
            if not self.fault[i]:
                if iso[i] or len(alarms) >= rule.confirm:
                    self.fault[i], self.since[i] = True, k
                    self.isolated[i] = bool(iso[i])
            elif k - self._last_evidence[i] >= rule.clear_after:
                self.fault[i], self.isolated[i], self.since[i] = False, False, -1
            else:
                self.isolated[i] |= bool(iso[i])
        changed = (not self._started or not np.array_equal(before[0], self.fault)
                   or not np.array_equal(before[1], self.isolated))
        if not changed and self.significance is not None and estimate is not None:
            moved = np.abs(est - self._reported_estimate) > self.significance
            changed = bool(np.any(self.fault & ~np.isnan(self._reported_estimate) & moved))
        if changed:
            self._reported_estimate = est.copy()
        self._started = True
        return VerdictOutput(int(k), self.fault.copy(), self.isolated.copy(), est,
                             self.since.copy(), bool(changed))
