"""Join a node's inputs on the sample stamp (pure Python, no ROS).

A node of the diagnosis chain processes sample k once it has every *required* input for k
(e.g. u_k, y_k) and every *feedback* input for k (e.g. sigma^_k, which the estimator
published while processing k - 1). The first sample a node processes, k0, is the smallest
stamp with every required input; feedback for k0 defaults to the initial values (sigma^ = 0,
no trigger, no override), as in :meth:`fd_monitor.core.monitor.Monitor.step`. Samples are
processed in stamp order, consecutively, so the one-sample feedback delays of the in-process
Monitor hold across processes and the numbers are the same.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from typing import Any

__all__ = ["StampJoin"]


class StampJoin:
    """Buffer inputs per stamp; release complete samples in order.

    Parameters
    ----------
    required : sequence of str
        Inputs needed at every sample.
    feedback : mapping of str to object
        Inputs needed at every sample after the first, with their value at the first.
    max_pending : int
        Stamps buffered at most; beyond, the oldest incomplete stamps are dropped (the node
        reports it).
    """

    def __init__(self, required: Sequence[str], feedback: Mapping[str, Any] | None = None,
                 max_pending: int = 100_000) -> None:
        self.required = tuple(required)
        self.feedback = dict(feedback or {})
        self.names = (*self.required, *self.feedback)
        self.max_pending = int(max_pending)
        self.pending: dict[int, dict[str, Any]] = {}
        #: Next stamp to process (None before the first sample).
        self.k_next: int | None = None
        self.dropped = 0

    def put(self, name: str, stamp: int, value: Any) -> str | None:
        """Store one input. Returns a one-line reason when it is ignored, else None."""
        if name not in self.names:
            raise KeyError(name)
        if self.k_next is not None and stamp < self.k_next:
            return f"{name} stamp {stamp}: already processed (next is {self.k_next}); ignored"
        slot = self.pending.setdefault(stamp, {})
        if name in slot:
            return f"{name} stamp {stamp}: duplicate; the first one is kept"
        slot[name] = value
        if len(self.pending) > self.max_pending:
            oldest = min(self.pending)
            del self.pending[oldest]
            self.dropped += 1
            return f"more than {self.max_pending} samples pending: dropped stamp {oldest}"
        return None

    def _complete(self, k: int, first: bool) -> bool:
        slot = self.pending.get(k)
        if slot is None or any(n not in slot for n in self.required):
            return False
        return first or all(n in slot for n in self.feedback)

    def ready(self) -> Iterator[tuple[int, dict[str, Any]]]:
        """Yield ``(k, inputs)`` for every sample that can be processed now, in order."""
        if self.k_next is None:
            firsts = [k for k in sorted(self.pending) if self._complete(k, True)]
            if not firsts:
                return
            k0 = firsts[0]
            for k in [k for k in self.pending if k < k0]:
                del self.pending[k]
            self.k_next = k0
            slot = self.pending.pop(k0)
            self.k_next = k0 + 1
            yield k0, {**self.feedback, **slot}
        while self._complete(self.k_next, False):
            k = self.k_next
            slot = self.pending.pop(k)
            self.k_next = k + 1
            yield k, slot

    def waiting_for(self) -> list[str]:
        """Inputs still missing for the next sample (for diagnostics)."""
        if self.k_next is None:
            return list(self.required)
        slot = self.pending.get(self.k_next, {})
        return [n for n in self.names if n not in slot]
