"""The one hold rule: a channel's value at time t is the latest value at or before t
(zero-order hold), while it is at most ``max_age`` old (pure Python, no ROS; time is an
argument).

Two places pair a sample with a slower or unstamped channel by this rule:

* the time base (:class:`~fd_monitor.wire.timebase.GridSampler`, under
  :class:`~fd_monitor.wire.adapters.AdapterJoin`): a channel with no message in slot k holds
  its latest earlier value, on the grid's slots, for at most its ``max_hold``;
* the nodes' plain (unstamped) inputs (:class:`HeldPairing`, used by
  :class:`~fd_monitor.nodes.fd_node.FdNode`): a plain ``plant/y`` gets the latest plain
  ``plant/u`` published at or before it, by the DDS source timestamps.

Both keep their values in a :class:`ZeroOrderHold`; "latest" is by time (ties: the value put
last), so a value that arrives after a newer one never replaces it.
"""

from __future__ import annotations

import bisect
from collections import deque
from collections.abc import Hashable, Iterable, Iterator
from typing import Any

__all__ = ["HOLD_WAIT", "HeldPairing", "ZeroOrderHold"]

#: s a plain sample waits for a later held input (``plant/u``) before it is paired with the
#: latest one published before it.
HOLD_WAIT = 0.1


class ZeroOrderHold:
    """One channel's values over time, and the value in force at a time.

    Parameters
    ----------
    max_age : float, optional
        Longest time a value is held (same unit as the times: s, ns or grid slots); None:
        for ever.
    depth : int, optional
        Values kept at most (the oldest by time go first); None: unbounded. ``depth=1`` keeps
        the newest value only (enough when the times asked only increase).
    """

    __slots__ = ("_items", "_times", "depth", "max_age")

    def __init__(self, max_age: float | None = None, depth: int | None = None) -> None:
        self.max_age = max_age
        self.depth = depth
        self._times: deque[Any] = deque()
        self._items: deque[Any] = deque()

    def __len__(self) -> int:
        return len(self._times)

    def put(self, t: Any, value: Any) -> None:
        """Value ``value`` from time ``t`` on (in any order; ties: this one wins)."""
        times = self._times
        if self.depth == 1 and times:          # the newest only (the time base's slots)
            if t >= times[0]:
                times[0], self._items[0] = t, value
            return
        if not times or t >= times[-1]:
            times.append(t)
            self._items.append(value)
        else:
            i = bisect.bisect_right(times, t)
            times.insert(i, t)
            self._items.insert(i, value)
        if self.depth is not None and len(times) > self.depth:
            times.popleft()
            self._items.popleft()

    def at(self, t: Any) -> tuple[Any, Any] | None:
        """``(time, value)`` in force at ``t``: the latest value at or before ``t``, whatever its
        age (None: nothing before ``t``); :meth:`too_old` tells whether it still holds."""
        times = self._times
        if times and times[-1] <= t:
            return times[-1], self._items[-1]
        i = bisect.bisect_right(times, t)
        return (times[i - 1], self._items[i - 1]) if i else None

    def too_old(self, since: Any, t: Any) -> bool:
        """Whether a value from ``since`` is older than ``max_age`` at ``t`` (a gap)."""
        return self.max_age is not None and t - since > self.max_age

    def newer_than(self, t: Any) -> bool:
        """Whether a value later than ``t`` is in (then every one up to ``t`` is, for values
        put in time order)."""
        return bool(self._times) and self._times[-1] > t

    def forget_before(self, t: Any) -> None:
        """Drop the values no time from ``t`` on can need (keeps the one in force at ``t``)."""
        times, items = self._times, self._items
        while len(times) > 1 and times[1] <= t:
            times.popleft()
            items.popleft()

    def clear(self) -> None:
        """Forget every value (a new run)."""
        self._times.clear()
        self._items.clear()


class HeldPairing:
    """Plain samples paired with held inputs by source time (the hold rule).

    Each held input (``plant/u``) is a :class:`ZeroOrderHold` of its values by source time.
    A plain sample (``plant/y`` at time ``t``) gets, per held input, the value in force at
    ``t``. It waits until every held input has a value later than ``t`` (every earlier one
    is then in) or for ``wait`` s after it arrived; then it is paired, and values older than
    the one in force at ``t`` are forgotten (the next samples may still need that one).

    Parameters
    ----------
    names : iterable of hashable
        The held inputs.
    wait : float
        s a sample waits for later held values (:data:`HOLD_WAIT`).
    depth : int
        Values kept per held input at most.
    """

    def __init__(self, names: Iterable[Hashable], wait: float = HOLD_WAIT,
                 depth: int = 1000) -> None:
        self.wait = float(wait)
        self.holds = {n: ZeroOrderHold(depth=depth) for n in names}
        self._waiting: deque[tuple[Any, float, Any]] = deque()

    def __bool__(self) -> bool:
        """Whether there are held inputs at all."""
        return bool(self.holds)

    @property
    def waiting(self) -> int:
        """Samples waiting to be paired."""
        return len(self._waiting)

    def hold(self, name: Hashable, t: Any, value: Any) -> None:
        """A value of held input ``name`` at source time ``t``."""
        self.holds[name].put(t, value)

    def sample(self, t: Any, arrival: float, item: Any) -> None:
        """A plain sample at source time ``t`` that arrived at ``arrival`` (s, monotonic);
        ``item`` comes back with its pairing."""
        self._waiting.append((t, arrival, item))

    def pairs(self, now: float | None = None
              ) -> Iterator[tuple[Any, dict[Hashable, Any], list[Hashable]]]:
        """``(item, values, missing)`` of each sample that can be paired now, in arrival order:
        the held inputs' values in force at its time, and the held inputs with no value
        before it. ``now``: s (monotonic), for the wait; None: only samples every held input
        has passed."""
        waiting = self._waiting
        while waiting:
            t, arrival, item = waiting[0]
            later = all(h.newer_than(t) for h in self.holds.values())
            if not later and (now is None or now - arrival < self.wait):
                return
            waiting.popleft()
            values: dict[Hashable, Any] = {}
            missing: list[Hashable] = []
            for name, h in self.holds.items():
                held = h.at(t)
                if held is None:
                    missing.append(name)
                else:
                    values[name] = held[1]
                h.forget_before(t)
            yield item, values, missing

    def clear(self) -> None:
        """Forget the waiting samples and the held values (a new run)."""
        self._waiting.clear()
        for h in self.holds.values():
            h.clear()
