"""The one input policy of fd_monitor, live and offline (pure Python, no ROS; time is an
argument).

A node's subscription callback and the offline bag reader
(:func:`fd_monitor.analysis.offline.read_streams`) push every message through the same code:

1. the caller decodes it (:func:`~fd_monitor.wire.conversions.decode`); a message that does
   not decode is reported by the caller and its readable stamp is *refused*
   (:meth:`InputStream.refused`: the join may declare that stamp lost at once);
2. the per-topic order check (:class:`TopicOrder`): the same stamp twice in a row is a
   ``duplicate`` (dropped, the first kept), a step back is ``out_of_order`` (reported, joined);
3. the stamp join (:class:`~fd_monitor.wire.join.StampJoin`, entry role): a pending stamp
   again is a ``duplicate``, an input for a stamp inside a declared hole is ``late``, a stamp
   below the stream or beyond ``stamp_horizon`` is ``held`` (a new run once the stream has
   stopped for ``restart_after`` s), more than ``max_pending`` stamps ``dropped``;
4. release (:meth:`InputStream.release`): every sample the join can decide at time ``now``, in
   stamp order, with its ``hole`` (a missing stamp is lost once a later one has been complete
   for ``gap_timeout`` s, or at once when it was refused), ``restart``, ``bridge`` and
   ``new_run``; the caller's ``step`` runs it and returns False when the core refused it
   (implausible): the join then counts that sample lost.

A hole is not amnesia. A gap of at most ``max_gap`` lost samples (a hole, samples the core
refused, or both in a row) is *bridged*: the sample after it is stepped after
:meth:`~fd_monitor.core.runtime.Runtime.bridge`, which keeps the fault memory (bias estimate,
alarm and isolation history, mode, AGEI phase) and carries the state estimate over the gap.
Only a new run restarts from scratch (:meth:`~fd_monitor.core.runtime.Runtime.reset`): the
first sample, a gap longer than ``max_gap``, stamps that restart lower (``new_run``), a
``~/reset``. Lost feedback in the chain (``feedback_lost``: its source died or a message was
lost) is not a new run: the sample goes on without it (its initial value) and the node stops
waiting for that feedback until it comes again (``feedback_back``: a restarted peer rejoins).

No input pattern blinds a node for good (doc/howto/overload-and-recovery.md): a node more
than ``max_lag`` s behind a live stream sheds load (``shed``: skips to a recent sample, as
across a hole); a *batch* -- messages that carry the batch mark
(:data:`~fd_monitor.wire.conversions.BATCH_LABEL`: ``replay``, ``plant_sim`` flat out), or
with ``batch_pace`` set, a backlog that came faster than that x real time -- is processed
completely. A dead feedback source costs ``gap_timeout`` s once, a stopped or restarted
source is a hole or a new run.

Reports go to the caller's ``note(kind, line, stamp)``; ``kind`` is the step's kind above,
``hole`` (``stamp`` is the inclusive ``(first, last)``; bridged or restarted), ``bridge`` (a
bridge after samples the core refused, no hole), ``feedback_lost``, ``feedback_back``,
``shed`` (``stamp`` the skipped ``(first, last)``) or ``new_run``.
A node logs the line and reports it on ``/diagnostics``; the offline reader turns it into an
:class:`~fd_monitor.analysis.offline.InputReport` entry. Live, ``now`` is the node's
monotonic clock; offline it is each bag record's log time in s, and ``+inf`` at the end of
the bag (every decision that waits for time is taken).

The defaults of the time and stamp limits (:data:`GAP_TIMEOUT`, :data:`STAMP_HORIZON`,
:data:`RESTART_AFTER`, :data:`MAX_GAP`, :data:`MAX_LAG`, :data:`BATCH_PACE`) are declared
here once: the nodes' parameters and the offline reader take them from here.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fd_monitor.wire.join import Sample, StampJoin

__all__ = ["BATCH_PACE", "GAP_TIMEOUT", "InputStream", "MAX_GAP", "MAX_LAG",
           "RESTART_AFTER", "STAMP_HORIZON", "SentTime", "TopicOrder"]

#: s a later sample must have been complete before a missing one is declared lost.
GAP_TIMEOUT = 1.0
#: Samples above the next expected stamp beyond which a stamp is held, not joined.
STAMP_HORIZON = 100_000
#: s without progress before held stamps become a new run.
RESTART_AFTER = 1.0
#: Lost samples in a row that are bridged (the run goes on, its memory kept); more: a restart.
MAX_GAP = 10
#: s a complete sample may wait (since it was received) before the node skips ahead to a
#: recent one; 0: never. A batch -- marked messages (``replay``, ``plant_sim`` flat out: the
#: sender asks for every sample), see :data:`BATCH_PACE` for unmarked ones -- is never shed.
MAX_LAG = 2.0
#: x real time, an opt-in for a fast source that cannot mark its messages: an unmarked
#: backlog that came faster than this is a batch too, processed completely; 0 (default):
#: only marked messages are a batch, any other backlog older than ``max_lag`` is shed
#: whatever its pace (a flood cannot be told from a flat-out simulation by pace alone).
BATCH_PACE = 0.0

#: ``note(kind, line, stamp)``: stamp an int, a hole's ``(first, last)``.
NoteFn = Callable[[str, str, Any], None]


class SentTime:
    """When each message of one topic was published, on the receiver's clock: what the lag
    of a load shed counts from (:meth:`StampJoin.put <fd_monitor.wire.join.StampJoin.put>`
    ``arrived``), so a backlog is seen wherever it waits -- in the node's join, in its DDS
    reader (a node that processes each message in the callback that took it), or in the
    publisher's history once the reader is full (Fast DDS holds 5,000 samples per reader).

    The publisher stamps each message with its own clock (the DDS source timestamp), which
    may be offset from ours (another machine). The offset is estimated as the smallest
    ``receive - source`` difference seen (the transport delay of an unqueued message, plus
    the clock offset); it may grow by :data:`DRIFT` s per s (clocks drift, NTP steps), so a
    queued message -- whose difference is larger by the time it waited -- shows its wait.
    ``sent = now - (now_wall - source - offset)``, never later than ``now``.
    """

    #: s per s the offset estimate may rise (clock drift; 1 ms/s is far above a crystal's
    #: and far below a queue's growth under a flood, which is about 1 s/s).
    DRIFT = 1e-3

    def __init__(self) -> None:
        self.offset: float | None = None
        self._t = 0.0

    def sent(self, source: float, received: float, now: float, now_wall: float) -> float:
        """Publication time of a message on the clock of ``now`` (monotonic, s).

        Parameters
        ----------
        source : float
            The publisher's timestamp of the message (wall clock, s).
        received : float
            When DDS received it here (wall clock, s); ``now_wall`` when unknown.
        now, now_wall : float
            The receiver's monotonic and wall clocks now (s).
        """
        d = received - source
        off = self.offset
        if off is None or d < off + self.DRIFT * (now - self._t):
            off = d
        else:
            off += self.DRIFT * (now - self._t)
        self.offset, self._t = off, now
        return now - max(0.0, now_wall - source - off)


class TopicOrder:
    """Per-topic duplicate and out-of-order report (a duplicate is dropped, the first kept;
    out of order is only reported).

    A duplicate here is the same stamp twice in a row; out of order is one line per step
    back. A stamp seen earlier goes on to the join, which keeps the first of a pending one and
    holds a processed one: dropped if the stream goes on, a new run if it stopped (a source
    that restarted, a second bag) -- not thousands of duplicates.
    """

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.last: int | None = None

    def check(self, k: int) -> tuple[str | None, bool]:
        """Record stamp k: (one-line report or None, True when k is a duplicate)."""
        last, self.last = self.last, k
        if k == last:
            return f"{self.topic} stamp {k}: duplicate (first kept)", True
        if last is not None and k < last:
            return f"{self.topic} stamp {k} after stamp {last}: out of order", False
        return None, False


class InputStream:
    """Decoded messages -> order check -> stamp join -> released samples, one policy.

    Parameters
    ----------
    join : StampJoin
        The join of the inputs (entry role for ``/plant/u``, ``/plant/y`` and side signals).
    step : callable
        ``step(sample) -> bool``: run one released :class:`~fd_monitor.wire.join.Sample`
        (reset first when ``sample.restart``); False when the core refused it (implausible).
    note : callable
        ``note(kind, line, stamp)``: one report (see the module's kinds).
    """

    def __init__(self, join: StampJoin, step: Callable[[Sample], bool], note: NoteFn) -> None:
        self.join = join
        self.step = step
        self.note = note

    def refused(self, stamp: int | None, now: float) -> None:
        """A required message for ``stamp`` did not decode (the caller reported why): the
        stamp is lost (None: unreadable, nothing to refuse)."""
        if stamp is not None and stamp >= 0:
            self.join.reject(stamp)
            self.release(now)

    def stamped(self, order: TopicOrder, name: str, stamp: int, values: Any, now: float,
                offset: int = 0, restart: bool = False, bridge: bool = False,
                batch: bool = False, arrived: float | None = None) -> bool:
        """One decoded stamped message of input ``name`` (its topic's ``order``), joined at
        ``stamp + offset``; ``restart``, ``bridge``: the flags of a sequence input;
        ``batch``: it carried the batch mark; ``arrived``: when it was received, if before
        ``now`` (it waited in DDS). True when joined (samples released), False when
        reported and dropped or held."""
        line, duplicate = order.check(stamp)
        if line is not None:
            self.note("duplicate" if duplicate else "out_of_order", line, stamp)
            if duplicate:
                return False
        stamp += offset
        return stamp >= 0 and self.put(name, stamp, values, now, restart, bridge, batch,
                                       arrived)

    def new_run(self, k: int, line: str) -> None:
        """The source says its stream restarted (an adapter's clock jumped): forget the
        join; the next sample starts a run (fresh state)."""
        self.join.reset()
        self.note("new_run", line, k)

    def put(self, name: str, stamp: int, values: Any, now: float,
            restart: bool = False, bridge: bool = False, batch: bool = False,
            arrived: float | None = None) -> bool:
        """Join one input (already order-checked, or paired by sample-and-hold) and release
        what became ready; False when the join reported and did not join it."""
        join = self.join
        line = join.put(name, stamp, values, now, restart, bridge, batch, arrived)
        if join.resumed:
            for n in join.resumed:
                self.note("feedback_back", f"{n}: feedback came again (stamp {stamp}): waiting "
                          f"for it again from sample {join.k_next}", stamp)
            join.resumed.clear()
        if line is not None:
            self.note(line.kind, line, stamp if line.stamp is None else line.stamp)
            return False
        self.release(now)
        return True

    def release(self, now: float) -> None:
        """Run every sample the join releases at ``now``; report holes and new runs."""
        join = self.join
        for s in join.ready(now):
            if s.feedback_lost:
                names = ", ".join(join.last_lost) or "feedback"
                gone = ", ".join(sorted(join.lost_feedback))
                self.note("feedback_lost", f"feedback for sample {s.k} did not come in time "
                          f"({names}): processed without it (feedback at its initial value, "
                          f"an optional input absent), state kept"
                          + (f"; not waited for until it comes again ({gone})" if gone
                             else " (a later one is here)"), s.k)
            if s.new_run is not None:
                old, count = s.new_run
                self.note("new_run", f"new run: the stream restarted at stamp {s.k} (the old "
                          f"one stopped before {old}; {count} messages held meanwhile); "
                          f"fresh state", s.k)
            elif s.shed:
                a, b = s.hole or (s.k, s.k)
                what = "bridged" if s.bridge else "restarted"
                self.note("shed", f"behind by more than {join.max_lag:g} s on a live "
                          f"stream (unmarked): skipped stamps {a}..{b} ({s.shed} samples) to "
                          f"a recent one; {what} at {s.k}", (a, b))
            elif s.hole is not None:
                a, b = s.hole
                span = f"stamp {a}" if a == b else f"stamps {a}..{b}"
                if s.bridge:
                    limit = (f"at most {join.max_gap} bridged" if join.sequence is None
                             else "bridged as the entry node did")
                    what = (f"bridged at {s.k} ({s.gap} sample(s) lost, {limit}: estimates, "
                            f"alarm and isolation memory kept)")
                else:
                    what = (f"restarted at {s.k} (fresh state, feedback at initial values"
                            + (f"; {s.gap} sample(s) lost, more than {join.max_gap} bridged)"
                               if join.sequence is None and s.gap > join.max_gap else ")"))
                self.note("hole", f"hole: no valid sample for {span}; {what}", s.hole)
            elif s.bridge:
                self.note("bridge", f"bridged at {s.k} after {s.gap} refused sample(s) (at "
                          f"most {join.max_gap} bridged: estimates, alarm and isolation "
                          f"memory kept)", s.k)
            if not self.step(s):
                join.lost(s.k)
