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

import math
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
    """The verdict at sample ``k`` (per-channel tuples: cheap to build at every sample).

    Attributes
    ----------
    k : int
    fault : tuple of bool
        (m,) a fault is present on the channel.
    isolated : tuple of bool
        (m,) isolated by the estimator during the current fault episode.
    estimate : tuple of float
        (m,) the latest estimate (sensor bias, in the output's unit); NaN without one.
    since : tuple of int
        (m,) the sample the fault was set at; -1 without a fault.
    changed : bool
        The verdict (fault, isolated, since) changed at k, or the estimate of a faulty
        channel moved by more than its significance since the last change: what is worth
        publishing.
    """

    k: int
    fault: tuple[bool, ...]
    isolated: tuple[bool, ...]
    estimate: tuple[float, ...]
    since: tuple[int, ...]
    changed: bool

    def payload(self) -> dict[str, Any]:
        """Field name -> (m,) array: ``fault``, ``isolated``, ``estimate``, ``since``."""
        return {"fault": np.array(self.fault, dtype=float),
                "isolated": np.array(self.isolated, dtype=float),
                "estimate": np.array(self.estimate, dtype=float),
                "since": np.array(self.since, dtype=float)}

    def faulty(self, channels: Sequence[str]) -> list[str]:
        """The names of the channels at fault."""
        return [c for c, f in zip(channels, self.fault) if f]


def _floats(v: Any) -> list[float]:
    return [float(x) for x in (v.tolist() if hasattr(v, "tolist") else v)]


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
        self.significance: list[float] | None = None
        if significance is not None:
            sig = [abs(x) for x in _floats(np.ravel(np.asarray(significance, dtype=float)))]
            if len(sig) != self.n:
                raise ValueError(f"verdict: {len(sig)} significance values for {n} channels")
            self.significance = sig
        self.reset()

    def reset(self) -> None:
        """No fault on any channel (a new run)."""
        n = self.n
        self._alarms: list[deque[int]] = [deque() for _ in range(n)]
        self.fault = [False] * n
        self.isolated = [False] * n
        self.since = [-1] * n
        self._last_evidence = [-1] * n
        self._reported: list[float] = [math.nan] * n
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
        al = _floats(alarm)
        est = [math.nan] * n if estimate is None else _floats(estimate)
        iso = [0.0] * n if isolated is None else _floats(isolated)
        if len(al) != n or len(est) != n or len(iso) != n:
            raise ValueError(f"verdict at sample {k}: expected {n} values per input")
        sig = self.significance if estimate is not None else None
        changed = not self._started
        moved = False
        for i in range(n):
            alarms = self._alarms[i]
            if al[i]:
                alarms.append(k)
            while alarms and alarms[0] <= k - rule.window:
                alarms.popleft()
            if al[i] or iso[i] or (sig is not None and abs(est[i]) > sig[i]):
                self._last_evidence[i] = k
            if not self.fault[i]:
                if iso[i] or len(alarms) >= rule.confirm:
                    self.fault[i], self.since[i] = True, k
                    self.isolated[i] = bool(iso[i])
                    changed = True
            elif k - self._last_evidence[i] >= rule.clear_after:
                self.fault[i], self.isolated[i], self.since[i] = False, False, -1
                changed = True
            else:
                if iso[i] and not self.isolated[i]:
                    self.isolated[i] = changed = True
                # a faulty channel's estimate that moved by more than its significance
                if sig is not None and abs(est[i] - self._reported[i]) > sig[i]:
                    moved = True
        changed = changed or moved
        if changed:
            self._reported = list(est)
        self._started = True
        return VerdictOutput(int(k), tuple(self.fault), tuple(self.isolated), tuple(est),
                             tuple(self.since), changed)
