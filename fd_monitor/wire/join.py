"""Join a node's inputs on the sample stamp (pure Python, no ROS; time is an argument).

A node of the diagnosis chain processes sample k once it has every *required* input for k
(e.g. u_k, y_k) and every *feedback* input for k (e.g. sigma^_k, which the estimator
published while processing k - 1). Samples are processed in stamp order, so the one-sample
feedback delays of the in-process Monitor hold across processes and the numbers are the
same. At a *restart* (the first sample, a new run, and the first valid sample after a hole
longer than ``max_gap`` samples) feedback takes its initial values (sigma^ = 0, no trigger, no
override), as after :meth:`fd_monitor.core.monitor.Monitor.reset`. After a hole of at most
``max_gap`` samples the sample is a *bridge* (:attr:`Sample.bridge`): the core keeps its
memory (:meth:`fd_monitor.core.runtime.Runtime.bridge`) and the feedback in force is the one
for the first lost stamp (what the last processed sample decided), as the in-process
runtime carries it over the gap.

Two roles (the entry role is the one input policy of the nodes and of offline bag reading,
through :class:`fd_monitor.wire.stream.InputStream`):

* the **entry** node (``sequence=None``: the observer) decides the holes. When its next stamp
  k is incomplete, k is lost if a message for it was rejected (:meth:`StampJoin.reject`) or
  a later stamp has been complete for ``gap_timeout`` s (per-topic delivery is reliable and
  in order, so a later complete stamp means k will not come; the timeout absorbs
  out-of-order publication). Then it bridges to (at most ``max_gap`` lost stamps, counting
  samples the core refused just before) or restarts at the smallest complete stamp after the
  lost ones. Never fills missing data.
* a **downstream** node (``sequence="est"``) follows the entry node: it processes exactly the
  stamps the entry node published on the sequence input (in order, so when est_s arrives,
  every earlier est has arrived and any pending stamp below s without one is dead), and
  restarts or bridges where the entry node flagged a restart or a bridge. A sequence stamp
  that lacks another required input is dead once a later sequence stamp has all of them
  (delivery is in order per topic: the missing message was published before this node
  subscribed, or lost): the node restarts at the later one instead of waiting forever. No
  timeout is involved.

Feedback is waited for only while its source exists (``feedback_source``: the node asks
whether a publisher is matched); without one the sample is released with that feedback at its
initial value and no restart: the node runs open loop.

An *optional* input (downstream role: ``optional``, e.g. the bias estimator's AGEI decision
at k, which the node can compute itself) is data of the sample itself, not feedback: it is
waited for like a required input while its publisher is matched, and released as ``None``
(absent: the node uses its own copy) when it has no publisher, when it is declared lost as
lost feedback is (``restart_after`` s, below; :attr:`Sample.feedback_lost`,
:attr:`StampJoin.lost_feedback`), or when a later stamp has it (delivery is in order per
topic: the message for this stamp will not come -- a restarted publisher's first samples).
Unlike feedback it is never replaced at restarts and bridges: a sample gets the message of
its own stamp or ``None``, so while the publisher is there the node's numbers are those of a
required input.

Lost feedback is not a reason to forget. When the feedback for a sample has not come in time
(``gap_timeout`` s after the sample was complete, entry role; ``restart_after`` s,
downstream), the sample is released with that feedback at its initial value
(:attr:`Sample.feedback_lost`), the run goes on (no restart: the mode, the estimates and the
alarm memory are kept), and that input is not waited for again until a message of it
arrives (:attr:`StampJoin.lost_feedback`). A peer killed without a goodbye stays *matched*
until its DDS lease runs out, so the publisher count alone would make the node wait
``gap_timeout`` s at every sample (a crawl of one sample a second, ever further behind the
source, that a restarted peer -- which gets only the source's new samples -- can never catch
up with). The restarted peer processes the samples published after it subscribed; its first
feedback message, even one for a sample already processed, makes the node wait for that
feedback again from its next sample on: the peer then follows the run in lock step.

A node that cannot keep up sheds load (``max_lag``): when the next sample was received
(``arrived``: live, when it was published) more than ``max_lag`` s ago, the join skips to the
newest complete sample, as across a hole: stamps ``k_next .. newest - 1`` are lost
(:attr:`Sample.shed`, counted in :attr:`StampJoin.shed`); the entry role bridges the newest
(at most ``max_gap`` skipped) or restarts the run there, a downstream node restarts there
(the entry node's stream goes on: its flags are followed again from the next sample). When
nothing newer is here (a node that processes each message in the callback that took it:
its backlog waits in DDS), the old samples are skipped as they are taken, in one episode,
until one at most ``max_lag / 2`` s old comes (:meth:`StampJoin._shed_to`). Live, a sample is
therefore processed at most ``max_lag`` s after it was published, or skipped -- unless the
backlog is a *batch*: its next sample carried the batch mark (``put(batch=True)``: a sender
that asked for every sample, e.g. a replay), processed completely however late (counted in
:attr:`StampJoin.batch_waits`); a skip never passes a marked sample. ``batch_pace`` (opt-in)
makes an unmarked backlog whose stamps span more than ``batch_pace`` times the wall time over
which it arrived a batch too (:attr:`StampJoin.pace_waits`).

A stamp cannot blind the join. A stamp below the next one (a source that restarted its
stamps, a bag replayed again) or more than ``horizon`` samples ahead of it (a stray stamp
like 2**52) is *held* aside, not refused: the first one of an episode is reported. The held
stamps become a new run (restart at the smallest complete one, :attr:`Sample.new_run` set)

* entry role: once the current stream has made no progress for ``restart_after`` s and a
  held stamp arrived after its last progress (held stamps older than the last progress are
  forgotten: a duplicate or a stray stamp inside a live stream);
* downstream role: at once, when the sequence input flags a restart at a held stamp.

Why one module of ~800 lines: one class, ``StampJoin``, whose state (pending samples, holes,
bridges, restarts, feedback waits) keeps one invariant; a third of the lines are docstrings
and comments stating its rules.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any, NamedTuple

__all__ = ["Note", "Sample", "StampJoin"]

#: Holes remembered to recognise late messages for skipped stamps.
_HOLE_HISTORY = 64


class Note(str):
    """The one-line reason :meth:`StampJoin.put` returns for an input it does not join, with
    its kind (so offline reports can group it; a node just logs the line).

    Attributes
    ----------
    kind : str
        ``duplicate`` (a pending stamp again: the first is kept), ``late`` (a required input
        for a stamp inside a declared hole: ignored), ``held`` (the first stamp of an episode
        below the stream or beyond the horizon), ``dropped`` (more than ``max_pending``
        stamps buffered: the oldest dropped).
    stamp : int or None
        The stamp it is about when not the one put (``dropped``: the oldest).
    """

    kind: str
    stamp: int | None

    def __new__(cls, text: str, kind: str, stamp: int | None = None) -> Note:
        self = super().__new__(cls, text)
        self.kind, self.stamp = kind, stamp
        return self


class Sample(NamedTuple):
    """One sample released by :meth:`StampJoin.ready` (a named tuple: one is made per sample,
    and a frozen dataclass of these fields costs three times as much to create).

    Attributes
    ----------
    k : int
    inputs : dict
        Input name -> value (feedback at its initial value at a restart; an absent optional
        input: None).
    restart : bool
        First sample, or first after a hole longer than ``max_gap``: reset the core
        component before it.
    hole : (int, int) or None
        Inclusive stamps skipped just before ``k`` (None: none).
    bridge : bool
        First sample after a gap of at most ``max_gap`` samples (a hole, or samples the core
        refused): the core bridges it (keeps its memory) instead of restarting.
    gap : int
        Samples lost just before ``k`` (the hole and the refused samples before it); 0 at a
        restart that has no hole.
    new_run : (int, int) or None
        First sample of a new run adopted from held stamps: (the old stream's next stamp,
        messages held meanwhile).
    feedback_lost : bool
        The feedback for ``k`` did not come in time (its source died, or the message was
        lost on the way: a burst overflowed a publisher's history): ``inputs`` hold that
        feedback's initial value; no restart (the run and its memory go on).
    shed : int
        Samples skipped just before ``k`` because the node was more than ``max_lag`` s
        behind (load shed; ``hole`` names them).
    batch : bool
        A required input of ``k`` carried the batch mark (:meth:`StampJoin.put`
        ``batch``): the node marks what it publishes for ``k`` (it relays a batch).
    """

    k: int
    inputs: dict[str, Any]
    restart: bool
    hole: tuple[int, int] | None = None
    new_run: tuple[int, int] | None = None
    feedback_lost: bool = False
    bridge: bool = False
    gap: int = 0
    shed: int = 0
    batch: bool = False


class StampJoin:
    """Buffer inputs per stamp; release complete samples in order; decide holes.

    Parameters
    ----------
    required : sequence of str
        Inputs needed at every sample.
    feedback : mapping of str to object
        Inputs needed at every sample but a restart, with their value at a restart.
    optional : sequence of str
        Downstream role: inputs of the sample itself that the node can do without (None
        when absent; see the module docstring). Waited for while ``feedback_source(name)``.
    max_pending : int
        Stamps buffered at most; beyond, the oldest incomplete stamps are dropped (the node
        reports it).
    sequence : str, optional
        Downstream role: the required input published by the entry node (its stamps are the
        samples to process; :meth:`put` with ``restart=True`` flags a restart).
    gap_timeout : float, optional
        Entry role: s a later stamp must have been complete before an incomplete one that
        was not rejected is declared lost; None: only rejections make holes.
    horizon : int, optional
        Stamps more than this many samples above the next one are held, not joined.
    restart_after : float
        Entry role: s without progress before held stamps become a new run.
    feedback_source : callable, optional
        ``feedback_source(name)`` is False when no publisher of feedback input ``name`` is
        matched: the join does not wait for that feedback and uses its initial value (no
        restart), as a node without the node that feeds it back runs open loop. None: always
        wait.
    max_gap : int
        Entry role: lost samples in a row that are bridged (:attr:`Sample.bridge`); more
        restart. 0: every hole restarts. The downstream role follows the entry's flags.
    max_lag : float, optional
        s the next sample may wait after it was complete before the join skips to the
        newest complete one (load shed); at least ``gap_timeout`` (downstream:
        ``restart_after``; a smaller value is raised to it, so a dead feedback source is
        declared lost before load is shed). None: never shed (offline reading).
    sample_time : float, optional
        s of plant time per stamp (the plant's Ts), for ``batch_pace``.
    batch_pace : float
        Opt-in for a fast source that cannot mark its messages: an unmarked backlog that
        came faster than ``batch_pace`` times real time is a batch too: its stamps span
        more than ``batch_pace`` x the wall time between the reception of the next sample
        and of the newest one (of the sample taken before it, when the backlog is held in
        DDS and the next one is the newest here). 0 (or no ``sample_time``, the default):
        only marked messages are a batch.
    """

    def __init__(self, required: Sequence[str], feedback: Mapping[str, Any] | None = None,
                 max_pending: int = 100_000, *, sequence: str | None = None,
                 gap_timeout: float | None = None, horizon: int | None = None,
                 restart_after: float = 1.0,
                 feedback_source: Callable[[str], bool] | None = None,
                 max_gap: int = 0, max_lag: float | None = None,
                 sample_time: float | None = None, batch_pace: float = 0.0,
                 optional: Sequence[str] = ()) -> None:
        self.required = tuple(required)
        self.optional = tuple(optional)
        if self.optional and sequence is None:
            raise ValueError(f"optional inputs {self.optional}: downstream role only (give "
                             f"the sequence input)")
        self.sample_time = sample_time
        self.batch_pace = float(batch_pace) if sample_time else 0.0
        self.max_gap = int(max_gap)
        self.max_lag = (None if max_lag is None else max(
            float(max_lag), gap_timeout or 0.0, restart_after if sequence is not None else 0.0))
        self.feedback_source = feedback_source
        self.feedback = dict(feedback or {})
        self.names = (*self.required, *self.feedback, *self.optional)
        if sequence is not None and sequence not in self.required:
            raise ValueError(f"sequence input {sequence!r} is not a required input")
        self.sequence = sequence
        self.gap_timeout = gap_timeout
        self.max_pending = int(max_pending)
        self.pending: dict[int, dict[str, Any]] = {}
        #: Next stamp to process (None before the first sample).
        self.k_next: int | None = None
        self.dropped = 0
        #: Stamps with a rejected required message (entry role).
        self.rejected: set[int] = set()
        #: Stamps whose required inputs are all here -> time they became complete.
        self._complete_since: dict[int, float] = {}
        self._seq: deque[int] = deque()        # downstream: sequence stamps, arrival order
        self._restart_at: set[int] = set()     # downstream: stamps flagged restart
        self._bridge_at: set[int] = set()      # downstream: stamps flagged bridge
        #: Recent holes ``(first, last)``, inclusive.
        self.holes: deque[tuple[int, int]] = deque(maxlen=_HOLE_HISTORY)
        self.horizon = horizon
        self.restart_after = float(restart_after)
        #: Stamps outside the window (below k_next, beyond the horizon): stamp -> inputs.
        self.held: dict[int, dict[str, Any]] = {}
        self._held_t: dict[int, float] = {}          # stamp -> arrival of its first input
        self._held_seq: deque[int] = deque()          # downstream: held sequence stamps
        self._held_restart: set[int] = set()
        self._held_bridge: set[int] = set()
        #: Messages held in the current episode, and new runs adopted so far.
        self.held_messages = 0
        self.new_runs = 0
        self._progress = -float("inf")                 # time of the last release
        self._restart_next = False                     # the next sample must restart
        self._adopted: tuple[int, int] | None = None
        # Entry role, for a bridge after samples the core refused (lost()): samples lost
        # right before k_next, the feedback in force for them, and of the last release its
        # gap, inputs and whether it restarted.
        self._missing = 0
        self._carry: dict[str, Any] | None = None
        self._last: tuple[int, dict[str, Any], bool] = (0, {}, True)
        #: Samples released as bridges, and as restarts after the first sample.
        self.bridges = 0
        self.restarts = 0
        #: Feedback inputs declared lost: not waited for until a message of theirs arrives.
        self.lost_feedback: set[str] = set()
        #: The feedback inputs the last :attr:`Sample.feedback_lost` sample went without.
        self.last_lost: tuple[str, ...] = ()
        #: Feedback inputs that came back since the caller last cleared this list.
        self.resumed: list[str] = []
        #: Samples released without (some of) their feedback; samples skipped (load shed)
        #: and the times it happened.
        self.feedback_losses = 0
        self.shed = 0
        self.shed_episodes = 0
        #: The newest complete stamp and when it was received (the backlog's pace), and the
        #: one before it.
        self._newest, self._newest_t = -1, 0.0
        self._prev_k, self._prev_t = -1, 0.0
        #: Checks that found the node more than ``max_lag`` s behind on a batch (not shed):
        #: all, and those that were a batch by ``batch_pace`` (unmarked).
        self.batch_waits = 0
        self.pace_waits = 0
        #: Stamps (pending or held) with a required input that carried the batch mark.
        self._marked: set[int] = set()
        #: Complete stamps -> when their completing input was received (``arrived``: the DDS
        #: reception time when the caller knows it, else the time put): the lag of a load
        #: shed counts from it, a backlog held in DDS included.
        self._rx: dict[int, float] = {}
        #: A load shed of a backlog held in DDS in progress: (first stamp skipped, when it
        #: started, samples skipped so far); the next release reports it.
        self._dropping: tuple[int, float, int] | None = None

    def reset(self) -> None:
        """Forget everything: the next complete sample starts a run (a reset service)."""
        # The constructor is the one list of the join's state, so a reset re-runs it (mypy
        # refuses calls of __init__ on an instance: misc).
        self.__init__(self.required, self.feedback, self.max_pending,  # type: ignore[misc]
                      sequence=self.sequence, gap_timeout=self.gap_timeout,
                      horizon=self.horizon, restart_after=self.restart_after,
                      feedback_source=self.feedback_source, max_gap=self.max_gap,
                      max_lag=self.max_lag, sample_time=self.sample_time,
                      batch_pace=self.batch_pace, optional=self.optional)

    # -- input ---------------------------------------------------------------------------------

    def put(self, name: str, stamp: int, value: Any, now: float = 0.0,
            restart: bool = False, bridge: bool = False, batch: bool = False,
            arrived: float | None = None) -> Note | None:
        """Store one input. Returns a one-line reason when it is ignored, else None.

        ``batch``: the message carried the batch mark (a required input with it makes the
        sample part of a batch: never shed). ``arrived``: when the message was received (the
        DDS reception time, on the clock of ``now``; earlier when it waited in DDS for the
        node to take it), for the load shed; default ``now``.

        ``restart``, ``bridge`` (downstream role, sequence input only): the entry node
        restarted, or bridged a gap, at ``stamp``. A late input for a stamp inside a hole is
        dropped silently when it is feedback (its sample was skipped on purpose) and
        reported when it is required.
        """
        if name not in self.names:
            raise KeyError(name)
        if name in self.lost_feedback:
            # its source is back (a restarted peer follows the run): wait for it again
            self.lost_feedback.discard(name)
            self.resumed.append(name)
        if self.k_next is not None and stamp < self.k_next and self._in_hole(stamp):
            # Feedback for a skipped sample, or (downstream) anything of a dead stamp.
            if name in self.feedback or self.sequence is not None:
                return None
            return Note(f"{name} stamp {stamp}: arrived after its hole was declared; ignored",
                        "late")
        if batch and name in self.required:
            self._marked.add(stamp)
        if self.k_next is not None and (stamp < self.k_next or (
                self.horizon is not None and stamp > self.k_next + self.horizon)):
            return self._hold(name, stamp, value, now, restart, bridge)
        slot = self.pending.setdefault(stamp, {})
        if name in slot:
            return Note(f"{name} stamp {stamp}: duplicate; the first one is kept", "duplicate")
        slot[name] = value
        if name == self.sequence:
            self._seq.append(stamp)
            if restart:
                self._restart_at.add(stamp)
            elif bridge:
                self._bridge_at.add(stamp)
        if name in self.required and all(n in slot for n in self.required):
            self._complete_since[stamp] = now
            rx = self._rx[stamp] = now if arrived is None or arrived > now else arrived
            if stamp > self._newest:
                self._prev_k, self._prev_t = self._newest, self._newest_t
                self._newest, self._newest_t = stamp, rx
        if len(self.pending) > self.max_pending:
            oldest = min(self.pending)
            self._forget(oldest)
            self.dropped += 1
            return Note(f"more than {self.max_pending} samples pending: dropped stamp {oldest}",
                        "dropped", oldest)
        return None

    def _hold(self, name: str, stamp: int, value: Any, now: float,
              restart: bool, bridge: bool = False) -> Note | None:
        if name in self.feedback and self.sequence is None:
            return None                          # feedback follows the run it belongs to
        assert self.k_next is not None
        first = not self.held
        slot = self.held.setdefault(stamp, {})
        self._held_t.setdefault(stamp, now)
        if name in slot:
            return Note(f"{name} stamp {stamp}: duplicate; the first one is kept", "duplicate")
        slot[name] = value
        self.held_messages += 1
        if name == self.sequence:
            self._held_seq.append(stamp)
            if restart:
                self._held_restart.add(stamp)
            elif bridge:
                self._held_bridge.add(stamp)
        if len(self.held) > self.max_pending:
            oldest = min(self.held)
            self.held.pop(oldest)
            self._held_t.pop(oldest, None)
            self._marked.discard(oldest)
            self.dropped += 1
        if not first or self.sequence is not None:
            return None
        where = ("below" if stamp < self.k_next
                 else f"more than {self.horizon} samples ahead of")
        return Note(f"{name} stamp {stamp}: {where} the stream (next is {self.k_next}): held; "
                    f"it becomes a new run if the stream stops for {self.restart_after:g} s",
                    "held")

    def _adopt(self) -> int:
        """Make the held stamps the stream: a new run from the smallest complete one."""
        old = self.k_next if self.k_next is not None else -1
        held, held_t, seq, rst = self.held, self._held_t, self._held_seq, self._held_restart
        brg = self._held_bridge
        count = self.held_messages
        self.pending, self._complete_since, self._seq = {}, {}, deque()
        self._restart_at, self.rejected = set(), set()
        self.held, self._held_t, self._held_seq, self._held_restart = {}, {}, deque(), set()
        self._held_bridge = set()
        self.holes.clear()
        self.k_next = None
        self.held_messages = 0
        self._restart_next = False
        self._missing, self._carry = 0, None
        self.new_runs += 1
        self._newest, self._prev_k, self._rx, self._dropping = -1, -1, {}, None
        self._marked &= held.keys()
        for stamp, slot in held.items():
            self.pending[stamp] = slot
            if all(n in slot for n in self.required):
                self._complete_since[stamp] = self._rx[stamp] = held_t[stamp]
                if stamp > self._newest:
                    self._newest, self._newest_t = stamp, held_t[stamp]
        self._seq = seq
        self._restart_at = rst
        self._bridge_at = brg
        self._adopted = (old, count)
        return old

    def _prune_held(self, cutoff: float) -> None:
        """Forget held stamps that arrived at or before ``cutoff``."""
        for stamp in [j for j, t in self._held_t.items() if t <= cutoff]:
            self.held.pop(stamp, None)
            self._held_t.pop(stamp)
            self._marked.discard(stamp)
        if not self.held:
            self.held_messages = 0

    def reject(self, stamp: int) -> None:
        """A required message for ``stamp`` was rejected (entry role): the stamp is lost."""
        if self.sequence is None and (self.k_next is None or stamp >= self.k_next):
            self.rejected.add(stamp)

    def lost(self, stamp: int) -> None:
        """Sample ``stamp``, already released, was refused by the core (implausible): it is
        a hole. The stream goes on at ``stamp + 1`` (a later gap is a hole like any other, a
        late message for ``stamp + 1`` still counts). The next sample bridges the gap (the
        refused samples in a row and any hole after them, at most ``max_gap``) with the
        feedback that was in force for ``stamp``, or restarts (the refused sample was itself
        a restart, or the gap is longer); neither waits for feedback (none comes for a
        refused sample)."""
        self.holes.append((stamp, stamp))
        gap, inputs, restarted = self._last
        if restarted or self.sequence is not None:   # downstream: as the entry decides
            self._restart_next = True
        else:
            self._missing = gap + 1
            self._carry = {n: inputs[n] for n in self.feedback if n in inputs}

    # -- release -------------------------------------------------------------------------------

    def ready(self, now: float = 0.0) -> Iterator[Sample]:
        """Yield every :class:`Sample` that can be processed at time ``now``, in order."""
        step = self._next_downstream if self.sequence is not None else self._next_entry
        while True:
            s = step(now)
            if s is None:
                return
            self._progress = now
            if self.held:
                # Entry: held before this progress = a stray stamp in a live stream.
                # Downstream: a new run's inputs precede its restart flag by little.
                self._prune_held(now if self.sequence is None else now - self.restart_after)
            yield s

    def _release(self, k: int, restart: bool, hole: tuple[int, int] | None,
                 lost: bool = False, bridge: dict[str, Any] | None = None,
                 shed: int = 0) -> Sample:
        """Release sample k; ``bridge``: the feedback in force across a bridged gap;
        ``shed``: samples skipped before it (load shed)."""
        if self.rejected:
            self.rejected = {j for j in self.rejected if j > k}
        marked = k in self._marked
        slot = self._forget(k)
        for n in self.optional:
            if n not in slot:
                slot[n] = None                   # absent: the node uses its own copy
        self._restart_next = False
        adopted, self._adopted = self._adopted, None
        if not restart and hole is None and bridge is None:
            # the common case, kept short: the next sample in order
            self.k_next = k + 1
            self._last = (0, slot, False)
            if marked:
                return Sample(k, slot, False, None, adopted, lost, False, 0, 0, True)
            return Sample(k, slot, False, None, adopted, lost)
        if self._dropping is not None:
            # the first sample after a shed of a backlog held in DDS: it reports the shed
            first, _, dropped = self._dropping
            self._dropping = None
            shed += dropped
            hole = (first, k - 1) if first < k else hole
        gap = self._missing + (0 if hole is None else hole[1] - hole[0] + 1)
        # Stamps below k: a jump, or the partial inputs of a hole's stamps.
        for j in [j for j in self.pending if j < k]:
            self._forget(j)
        if hole is not None:
            self.holes.append(hole)
        first = self.k_next is None
        self.k_next = k + 1
        self._missing, self._carry = 0, None
        if restart:
            # At a restart, feedback decided before the hole does not belong to this run.
            inputs = {**slot, **self.feedback}
            self.restarts += not first
        elif bridge is not None:
            inputs = {**slot, **bridge}
            self.bridges += 1
        else:
            inputs = slot
        self._last = (gap, inputs, restart)
        return Sample(k, inputs, restart, hole, adopted, lost, bridge is not None,
                      gap if (hole is not None or bridge is not None) else 0, shed, marked)

    def release_complete(self, k: int, inputs: dict[str, Any], now: float) -> Sample | None:
        """Release sample ``k`` whose required inputs all came together, without buffering
        them: the :class:`Sample` that :meth:`put` of each input and :meth:`ready` at ``now``
        would give when the join is in step (entry role without feedback or load shedding,
        ``k`` the next stamp, nothing pending, held, rejected or owed). None otherwise: the
        caller puts the inputs one by one. The offline reader's common case (a bag's
        samples in order), at about a third of the cost."""
        if (k != self.k_next or self.pending or self.held or self.rejected or self.feedback
                or self.sequence is not None or self.max_lag is not None
                or self._restart_next or self._missing or self._adopted is not None
                or self._complete_since or inputs.keys() != set(self.required)):
            return None
        self.k_next = k + 1
        self._last = (0, inputs, False)
        self._progress = now
        return Sample(k, inputs, False)

    def _bridge_feedback(self, j: int) -> dict[str, Any] | None:
        """The feedback in force across a gap that starts at stamp ``j`` (the carried one
        after refused samples, else the one stamped ``j``: what the last processed sample
        decided); None while it has not arrived."""
        if self._carry is not None:
            return self._carry
        slot = dict(self.pending.get(j, {}))
        if not self._feedback_here(slot):
            return None
        return {n: slot[n] for n in self.feedback}

    def _forget(self, k: int) -> dict[str, Any]:
        self._complete_since.pop(k, None)
        self._rx.pop(k, None)
        self._marked.discard(k)
        self._restart_at.discard(k)
        self._bridge_at.discard(k)
        return self.pending.pop(k, {})

    def _next_entry(self, now: float) -> Sample | None:
        # Stalled: no progress for restart_after s and nothing complete in the window.
        if (self._held_t and not self._complete_since
                and now - self._progress >= self.restart_after
                and any(self.held[j].keys() >= set(self.required) for j in self.held)):
            self._adopt()
        k = self.k_next
        if k is None:
            if not self._complete_since:
                return None
            return self._release(min(self._complete_since), True, None)
        t = self._complete_since.get(k)
        if t is not None and self.max_lag is not None and now - self._rx[k] > (
                self.max_lag if self._dropping is None else self.max_lag / 2):
            newest = self._shed_to(k, now)
            if newest is not None:
                return None if newest < 0 else self._shed(k, newest)
        if t is not None:
            if self._restart_next or self._missing > self.max_gap:
                return self._release(k, True, None)
            if self._missing:
                # after refused samples: bridged with the feedback carried (none waited for)
                return self._release(k, False, None, bridge=self._carry or {})
            slot = self.pending[k]
            if self._feedback_here(slot):
                return self._release(k, False, None)
            if self._feedback_overdue(k, now, self.gap_timeout):
                self._lose(k, slot)
                return self._release(k, False, None, lost=True)
            return None                          # waiting for feedback, not a hole
        later = [j for j in self._complete_since if j > k]
        if not later:
            return None
        s = min(later)
        timed_out = (self.gap_timeout is not None
                     and now - min(self._complete_since[j] for j in later) >= self.gap_timeout)
        if not timed_out and any(j not in self.rejected for j in range(k, s)):
            return None
        if self._restart_next or self._missing + s - k > self.max_gap:
            return self._release(s, True, (k, s - 1))
        fb = self._bridge_feedback(k)
        if fb is None:
            # the feedback of the last processed sample has not come yet (it is on its way):
            # wait for it as for any feedback, then bridge without it
            if not self._feedback_overdue(s, now, self.gap_timeout):
                return None
            return self._release(s, False, (k, s - 1), lost=True,
                                 bridge=self._lose(k, self.pending.get(k, {})))
        return self._release(s, False, (k, s - 1), bridge=fb)

    def _shed_to(self, k: int, now: float) -> int | None:
        """The node is more than ``max_lag`` s behind at ``k`` (received that long ago):
        the newest complete stamp to skip to; None when the backlog is a batch (``k``
        marked, or by ``batch_pace``) or there is nothing to skip; -1 when nothing newer is
        here -- the backlog is held in DDS, taken a message at a time -- and ``k`` was
        skipped (:meth:`_drop_to`): nothing to release now.

        The skip stops before the first marked stamp beyond ``k`` (a batch that follows a
        live stream is processed completely). A backlog held in DDS is skipped one message
        at a time as the node takes them (cheap: no processing), in one episode, until a
        message received at most ``max_lag / 2`` s ago comes (the node has caught up with
        the source: stopping just under ``max_lag`` would skip a sample every few) or the
        episode has lasted ``max_lag`` s (a source faster than the node can even take
        messages: it then processes the one it has, so it is never blind for longer).
        """
        if k in self._marked:
            self.batch_waits += 1
            return None
        newest = self._newest
        if newest not in self._complete_since:     # released or dropped since: look again
            newest = max(self._complete_since)
            self._newest, self._newest_t = newest, self._rx[newest]
        if self.batch_pace and self.sample_time:
            # the backlog's pace; held in DDS (k the newest here): since the sample before
            a, ta = (k, self._rx[k]) if newest > k else (self._prev_k, self._prev_t)
            if 0 <= a < newest and ((newest - a) * self.sample_time
                                    > self.batch_pace * (self._newest_t - ta)):
                self.batch_waits += 1
                self.pace_waits += 1
                return None
        if self._marked and newest > k:
            first = min((j for j in self._marked if j > k), default=None)
            if first is not None and first <= newest:
                newest = max((j for j in self._complete_since if k < j <= first), default=k)
        if newest > k:
            return newest
        # Nothing newer here: the backlog, if any, is held in DDS (the node takes it a
        # message at a time, each processed in the callback that took it).
        assert self.max_lag is not None
        if self._dropping is None or now - self._dropping[1] < self.max_lag:
            self._drop_to(k, now)
            return -1
        return None

    def _drop_to(self, s: int, now: float) -> None:
        """Skip every stamp up to ``s`` without releasing any (a backlog held in DDS, see
        :meth:`_shed_to`): they are a hole (a late input for one of them is ignored), the
        next release restarts and reports the skip (:attr:`Sample.shed`)."""
        k = self.k_next
        if self.sequence is None:
            assert k is not None
            first, n = k, s - k + 1
            for j in [j for j in self.pending if j <= s]:
                self._forget(j)
        else:
            seq, n = self._seq, 0
            first = k if k is not None else s
            while seq and seq[0] <= s:
                self._forget(seq.popleft())
                n += 1
            for j in [j for j in self.pending if j <= s]:
                self._forget(j)
        if self._dropping is None:
            self._dropping = (first, now, n)
            self.shed_episodes += 1
        else:
            first = self._dropping[0]
            self._dropping = (first, self._dropping[1], self._dropping[2] + n)
        self.shed += n
        self.holes.append((first, s))
        self.k_next = s + 1
        self._restart_next = True
        self._missing, self._carry = 0, None

    def _shed(self, k: int, s: int) -> Sample:
        """The node is more than ``max_lag`` s behind at ``k``: skip to the newest complete
        stamp ``s`` (``k .. s - 1`` lost, as a hole: bridged when short, else a restart;
        a bridge takes the feedback in force for ``k`` when it is here, else the initial
        values -- nothing is waited for when behind)."""
        n = s - k
        self.shed += n
        self.shed_episodes += 1
        if self._restart_next or self._missing + n > self.max_gap:
            return self._release(s, True, (k, s - 1), shed=n)
        fb = self._bridge_feedback(k)
        if fb is None:
            slot = self.pending.get(k, {})
            fb = {f: slot.get(f, init) for f, init in self.feedback.items()}
        return self._release(s, False, (k, s - 1), bridge=fb, shed=n)

    def _next_downstream(self, now: float) -> Sample | None:
        if self._held_restart:
            self._adopt()                        # the entry node started a new run
        seq = self._seq
        while seq and (seq[0] not in self.pending or self.sequence not in self.pending[seq[0]]):
            seq.popleft()                        # already released or dropped
        if not seq:
            return None
        s = seq[0]
        slot = self.pending[s]
        skipped = False
        if any(n not in slot for n in self.required):
            # Per-topic delivery is reliable and in order: once a later sequence stamp has
            # every required input, the missing ones of this stamp will not come (published
            # before this node subscribed, or lost). Skip to it instead of waiting forever.
            later = min(self._complete_since, default=None)
            if later is None or later <= s:
                return None
            while seq[0] != later:
                self._forget(seq.popleft())
            s, slot = later, self.pending[later]
            skipped = True
        t = self._complete_since.get(s)
        if t is not None and self.max_lag is not None and now - self._rx[s] > (
                self.max_lag if self._dropping is None else self.max_lag / 2):
            newest = self._shed_to(s, now)
            if newest is not None and newest < 0:
                return None
            if newest is not None:
                # behind by more than max_lag: skip to the newest complete sequence stamp
                # (a restart of this node there; the entry node's own stamps go on)
                n = 0
                while seq and seq[0] < newest:
                    n += 1
                    self._forget(seq.popleft())
                if seq and seq[0] == newest:
                    seq.popleft()
                self.shed += n
                self.shed_episodes += 1
                k = self.k_next
                return self._release(newest, True, None if k is None else (k, newest - 1),
                                     shed=n)
        lost = False
        k_prev = self.k_next
        if self.optional and not self._optional_here(s, slot):
            # data of this sample, waited for as lost feedback is, from the previous release
            # (from its completion for the first sample); not replaced at a restart or a
            # bridge: it is this stamp's or None
            since = self._progress if k_prev is not None else self._complete_since[s]
            if now - since < self.restart_after:
                return None
            self._lose_optional(slot)
            lost = True
        k = self.k_next
        bridged = s in self._bridge_at and not skipped
        restart = (k is None or s in self._restart_at or self._restart_next
                   or (s != k and not bridged))
        fb: dict[str, Any] | None = None
        if not restart and bridged:
            # across the entry's bridged gap: the feedback stamped k, decided at the last
            # sample this node processed
            assert k is not None
            fb = self._bridge_feedback(k)
            if fb is None:
                if not self._feedback_overdue(s, now, self.restart_after):
                    return None
                fb, lost = self._lose(k, self.pending.get(k, {})), True
        elif not restart and not self._feedback_here(slot):
            if not self._feedback_overdue(s, now, self.restart_after):
                return None
            self._lose(s, slot)
            lost = True
        hole = (k, s - 1) if k is not None and s != k else None
        seq.popleft()
        self._bridge_at.discard(s)
        return self._release(s, restart, hole, lost, None if restart else fb)

    def _feedback_here(self, slot: dict[str, Any]) -> bool:
        """Every feedback input of ``slot`` is here, declared lost, or has no publisher to
        wait for (then its initial value is put in ``slot``)."""
        missing = [n for n in self.feedback if n not in slot]
        if not missing:
            return True
        lost = self.lost_feedback
        if any(n not in lost and (self.feedback_source is None or self.feedback_source(n))
               for n in missing):
            return False
        slot.update((n, self.feedback[n]) for n in missing)
        return True

    def _optional_here(self, k: int, slot: dict[str, Any]) -> bool:
        """Every optional input of ``slot`` (stamp ``k``) is here or not waited for: declared
        lost, no publisher, or a later stamp has it (in order per topic: the message for
        ``k`` will not come). The absent ones are released as None."""
        for n in self.optional:
            if n in slot or n in self.lost_feedback or not (
                    self.feedback_source is None or self.feedback_source(n)):
                continue
            if not any(n in other for j, other in self.pending.items() if j > k):
                return False
        return True

    def _lose_optional(self, slot: dict[str, Any]) -> None:
        """The optional inputs missing from ``slot`` did not come in time: not waited for
        until a message of theirs arrives (as lost feedback)."""
        self.last_lost = tuple(n for n in self.optional if n not in slot)
        self.lost_feedback.update(self.last_lost)
        self.feedback_losses += 1

    def _lose(self, k: int, slot: dict[str, Any]) -> dict[str, Any]:
        """The feedback missing from ``slot`` (stamp ``k``) did not come in time: put its
        initial value in ``slot`` (returned, feedback only) and stop waiting for it -- unless
        a later stamp already has it (its source is alive, only this message was lost)."""
        missing = tuple(n for n in self.feedback if n not in slot)
        for n in missing:
            slot[n] = self.feedback[n]
            if not any(n in other for j, other in self.pending.items() if j > k):
                self.lost_feedback.add(n)
        self.last_lost = missing
        self.feedback_losses += 1
        return {n: slot[n] for n in self.feedback}

    def _feedback_overdue(self, k: int, now: float, timeout: float | None) -> bool:
        """Sample k's required inputs are here and ``timeout`` s have passed since the
        previous sample was released (its feedback could not exist before; it is due then,
        however late k itself came: a downstream node whose est_k came late because the
        entry node waited for a dead peer does not wait as long again), its feedback has
        not come."""
        return (timeout is not None and k in self._complete_since
                and now - self._progress >= timeout)

    # -- queries -------------------------------------------------------------------------------

    def _in_hole(self, stamp: int) -> bool:
        return any(a <= stamp <= b for a, b in self.holes)

    def waiting_for(self) -> list[str]:
        """Inputs still missing for the next sample (for diagnostics)."""
        if self.k_next is None:
            return list(self.required)
        slot = self.pending.get(self.k_next, {})
        return [n for n in self.names if n not in slot]
