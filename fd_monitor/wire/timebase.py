"""One time base: a robot's topics, at their own rates and clocks, sampled onto the plant's
grid ``t_k = t0 + k Ts`` (pure Python, no ROS; time is an argument).

The monitor runs on the plant's sample time ``Ts``. Each channel (one value of one topic's
messages) is sampled onto that grid from whatever arrives, by the rules below; the nodes
(:mod:`fd_monitor.nodes.adapter_input`) and the offline reader
(:func:`fd_monitor.wire.adapters.read_adapted`) push the same messages, in the same
per-topic order, through the same :class:`GridSampler`, so a bag gives the same samples live
and offline.

* **Time of a message**: its header stamp where the topic's type has one (stamp 0 is a
  stamp), else its receive time (the bag's log time offline). The grid runs on the *clock
  topic*'s kind of time (the adapter's first output); a receive-time topic beside a stamped
  clock belongs to the sample of the last clock message received before it (a command
  answers the measurement before it; after a lost clock message the sample is interpolated
  by receive time), whatever the two clocks' rates (a replay at 4x, sim time).
* **Grid phase**: from the first :data:`WARMUP` clock messages (the circular mean of their
  phases modulo ``Ts``, or ``Ts/m`` for a clock ``m`` times faster), then tracked with gain
  1/:data:`TRACK` per clock message, so a driver's clock drift and stamp jitter do not move
  samples. Messages wait (nothing is released) until the phase is known.
* **Slot**: a message at time ``t`` belongs to sample ``k = round((t - t0) / Ts)``: jitter
  of up to half a sample is absorbed, a command sent shortly after the measurement it
  answers is that sample's input.
* **Value at sample k**: the last message of slot k (``decimate: last``, default) or the
  mean of slot k's messages (``decimate: mean``) -- a faster topic is decimated; with no
  message in slot k the latest earlier value is *held* (zero-order hold: the one hold rule of
  :mod:`fd_monitor.wire.hold`) while its age is at most the channel's ``max_hold`` (s); older,
  the channel is *stale* and sample k is a gap.
  A channel never received is ``no_value``: a gap too.
* **When k is decided**: once every topic is *closed* for k (it has a message in a later
  slot, or as many in slot k as it sends per sample, or -- a slower topic -- its next message
  is not due yet), or the stream has moved :attr:`GridSampler.wait` samples past k (a topic
  that stopped, or one delivered late in a batch), or at the end (offline) / after
  ``hold_wait`` s of silence (live, :meth:`GridSampler.flush`). The decision depends on the
  data, not on when it arrived, so the interleaving of topics (which differs live and in a
  bag) does not change a sample. A message for a decided slot is ``late`` (reported; it is
  the held value from then on when it is newer).
* **A new run**: the clock jumping back by more than :data:`RUN_BACK` s or ahead by more than
  :data:`RUN_AHEAD` s, confirmed by the next clock message (a single stray stamp is reported
  and dropped), ends the run: the sampler releases what it has, emits a :class:`NewRun` and
  starts a new grid (warm-up again), numbering on from the last sample.

Nothing is dropped silently: every gap (its reason and channel), every held sample, every
late, duplicate, stray or decimated message is counted in :attr:`GridSampler.counts` and
reported once in :attr:`GridSampler.notes`. Memory is bounded by the decision window
(``wait`` samples) and the warm-up, not by a message count.

Why one module of ~570 lines: one policy (``GridSampler``) and its small value types; hold,
jitter, decimation, staleness, gaps and new runs are one state machine, and the docstring
states each rule.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from fd_monitor.wire.hold import ZeroOrderHold

__all__ = ["Gap", "GridSample", "GridSampler", "NewRun", "RUN_AHEAD", "RUN_BACK", "TRACK",
           "WAIT", "WARMUP", "snap_sample_time"]

#: Clock messages whose phases set the grid before the first sample is released.
WARMUP = 16
#: Phase tracking gain 1/TRACK per clock message (after the warm-up).
TRACK = 64
#: Clock messages remembered to place header-less messages (at least).
CLOCK_HISTORY = 256
#: s the stream moves on past a sample before a topic not yet heard for it is held (a topic
#: that stopped, or one delivered in a batch behind the others: an executor under a backlog
#: hands over one topic's queue before the next's).
WAIT = 2.0
#: s: a clock stamp this far behind the decided samples starts a new run (if confirmed).
RUN_BACK = 1.0
#: s: a clock stamp this far ahead of the newest starts a new run (if confirmed).
RUN_AHEAD = 10.0

#: Round sample times a driver uses (s), 1-2-2.5-4-5 per decade, and the periods of round
#: rates (Hz): 1-1.25-1.5-2-2.5-3-4-5-6-7.5-8 per decade.
_ROUND_MANTISSAS_T = (1.0, 2.0, 2.5, 4.0, 5.0)
_ROUND_MANTISSAS_F = (1.0, 1.25, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 7.5, 8.0)


def snap_sample_time(step: float, tolerance: float = 0.01) -> tuple[float, bool]:
    """The round sample time a driver would use nearest to a measured median ``step`` (s).

    Candidates are round periods (1, 2, 2.5, 4, 5 x 10^n s) and the periods of round rates
    (1, 1.25, 1.5, 2, 2.5, 3, 4, 5, 6, 7.5, 8 x 10^n Hz). Returns ``(Ts, snapped)``: the
    nearest candidate within ``tolerance`` (relative), else ``step`` itself and False.
    """
    if not (step > 0 and math.isfinite(step)):
        raise ValueError(f"sample step {step!r}: expected a positive number of seconds")
    best, err, found = step, tolerance, False
    e = math.floor(math.log10(step))
    for dec in (e - 1, e, e + 1):
        for m in _ROUND_MANTISSAS_T:
            c = m * 10.0 ** dec
            if abs(c - step) / step <= err:
                best, err, found = c, abs(c - step) / step, True
        for m in _ROUND_MANTISSAS_F:
            c = 1.0 / (m * 10.0 ** -dec)
            if abs(c - step) / step < err:
                best, err, found = c, abs(c - step) / step, True
    return float(f"{best:.15g}"), found


@dataclass(frozen=True)
class GridSample:
    """Sample k of the grid: every channel's value in force at ``t0 + k Ts``.

    Attributes
    ----------
    k : int
    t_ns : int
        The grid instant on the clock topic's time, ns.
    values : dict
        channel -> float.
    held : tuple of str
        Channels whose value came from an earlier sample (zero-order hold, within max_hold).
    """

    k: int
    t_ns: int
    values: dict[str, float]
    held: tuple[str, ...] = ()


@dataclass(frozen=True)
class Gap:
    """Sample k has no valid value of ``channel``: ``reason`` ``stale`` (held longer than
    its max_hold: a lost or late message, a silent topic) or ``no_value`` (never received)."""

    k: int
    reason: str
    channel: str


@dataclass(frozen=True)
class NewRun:
    """The stream restarted (a clock jump, confirmed): samples from ``k`` are a new run."""

    k: int
    line: str


Event = GridSample | Gap | NewRun


@dataclass
class _Topic:
    """Per-topic state: its channels, time kind, slot counts and rate."""

    name: str
    channels: tuple[str, ...]
    header: bool                           # its time is its header stamp
    max_slot: int | None = None            # highest slot seen this run
    counts: dict[int, int] = field(default_factory=dict)  # undecided slot -> messages
    filled: deque[tuple[int, int]] = field(default_factory=lambda: deque(maxlen=31))
    last_stamp: int | None = None
    per_slot: int = 1                      # messages per sample (a faster topic)
    period: int = 1                        # samples per message (a slower topic)


class GridSampler:
    """Messages of several topics -> samples on the grid (see the module docstring).

    Parameters
    ----------
    topics : mapping
        topic -> the channel names its messages carry (values of :meth:`put`).
    clock : str
        The clock topic (the grid's phase and kind of time).
    sample_time : float
        Ts, s.
    header : mapping
        topic -> whether its time is a header stamp (else the receive time).
    max_hold : mapping
        channel -> s a value is held at most (0: only a message of the sample itself).
    mean : iterable of str
        Channels decimated by the mean of their slot (default the last message).
    wait : float
        s the stream moves on before a topic not heard for a sample is held (:data:`WAIT`).
    """

    def __init__(self, topics: Mapping[str, Sequence[str]], clock: str, sample_time: float,
                 header: Mapping[str, bool], max_hold: Mapping[str, float],
                 mean: Iterable[str] = (), wait: float = WAIT) -> None:
        if not (sample_time > 0 and math.isfinite(sample_time)):
            raise ValueError(f"sample time {sample_time!r}: expected a positive number of s")
        if clock not in topics:
            raise ValueError(f"clock topic {clock!r} is not one of the topics")
        self.ts = float(sample_time)
        self.ts_ns = self.ts * 1e9
        self.clock = clock
        ref = bool(header[clock])
        self.topics = {t: _Topic(t, tuple(ch), ref and bool(header[t]))
                       for t, ch in topics.items()}
        # a receive-time topic beside a stamped clock: placed by the clock messages around it
        # (a stamped topic beside a receive-time clock uses its receive time: one kind)
        self._moved = {t: ref and not header[t] for t in topics}
        self.channels = tuple(c for t in self.topics.values() for c in t.channels)
        self.max_hold = {c: float(max_hold.get(c, 0.0)) for c in self.channels}
        self._hold_slots = {c: math.floor(self.max_hold[c] / self.ts + 1e-9)
                            for c in self.channels}
        self.mean = frozenset(mean)
        self.wait = max(1, math.ceil(wait / self.ts - 1e-9))
        self._ahead = max(self.wait + 2, math.ceil(RUN_AHEAD / self.ts))
        self._back = max(self.wait + 2, math.ceil(RUN_BACK / self.ts))
        #: Events (samples, gaps, new runs) decided and not yet taken by :meth:`ready`.
        self._out: deque[Event] = deque()
        #: ``(kind, line)`` reports (first of each kind and topic/channel; see counts).
        self.notes: list[tuple[str, str]] = []
        self._noted: set[tuple[str, str]] = set()
        #: Counters: ``samples``, ``gap:<reason>:<channel>``, ``held:<channel>``,
        #: ``late:<topic>``, ``duplicate:<topic>``, ``stray:<topic>``,
        #: ``decimated:<topic>``, ``messages:<topic>``, ``new_run``.
        self.counts: dict[str, int] = {}
        self.k_base = 0                      # k of slot 0 of this run
        #: Receive-time messages waiting for the next clock message: (topic, receive, values).
        self._moved_q: deque[tuple[str, int, dict[str, float]]] = deque()
        self._reset_run()

    # -- run state ---------------------------------------------------------------------------

    def _reset_run(self) -> None:
        self.t0_int: int | None = None       # grid anchor, ns (int part)
        self.t0_frac = 0.0                   # and its fraction (tracked), ns
        self._harmonic = 1
        self._warm: list[tuple[str, int, int, dict[str, float]]] = []
        self._warm_clock = 0
        self.next_slot = 0                   # the next slot to decide
        self.newest: int | None = None       # highest slot seen on any topic
        self._acc: dict[str, dict[int, list[float]]] = {c: {} for c in self.channels}
        # the hold rule (wire/hold.py) on the grid's slots: the newest decided value per
        # channel, held for at most its max_hold
        self._held = {c: ZeroOrderHold(self._hold_slots[c], depth=1) for c in self.channels}
        self._stray: list[tuple[str, int, int, dict[str, float]]] = []
        self._clock_r: list[int] = []        # recent clock messages: receive times, and
        self._clock_s: list[int] = []        # their stamps
        for t in self.topics.values():
            t.max_slot, t.counts = None, {}

    def _count(self, key: str, n: int = 1) -> None:
        self.counts[key] = self.counts.get(key, 0) + n

    def _note(self, kind: str, what: str, line: str) -> None:
        if (kind, what) not in self._noted:
            self._noted.add((kind, what))
            self.notes.append((kind, line))

    # -- input -------------------------------------------------------------------------------

    def put(self, topic: str, stamp_ns: int, receive_ns: int, values: Mapping[str, float]
            ) -> None:
        """One decoded message of ``topic``: its header stamp (or receive time for a type
        without one), its receive time, and its channels' values. In per-topic arrival
        order; decisions are taken at once (see :meth:`ready`)."""
        tp = self.topics[topic]
        self._count(f"messages:{topic}")
        if tp.header and tp.last_stamp == stamp_ns:
            self._count(f"duplicate:{topic}")
            self._note("duplicate", topic, f"{topic} stamp {stamp_ns * 1e-9:.6f} s: the same "
                       f"stamp again: dropped (the first kept)")
            return
        tp.last_stamp = stamp_ns
        if self._moved[topic]:
            self._moved_q.append((topic, receive_ns, dict(values)))
            if self._clock_r and receive_ns <= self._clock_r[-1]:
                self._map_moved(False)           # handed over after a later clock message
            return
        if topic == self.clock and tp.header:
            self._clock_in(receive_ns, stamp_ns)
            self._map_moved(False)
        self._accept(topic, stamp_ns if tp.header else receive_ns, receive_ns, dict(values))

    def _clock_in(self, receive_ns: int, stamp_ns: int) -> None:
        """A clock message's (receive, stamp): the history header-less messages are placed
        by."""
        rs, ss = self._clock_r, self._clock_s
        if not rs or receive_ns >= rs[-1]:
            rs.append(receive_ns)
            ss.append(stamp_ns)
            if len(rs) > 2 * CLOCK_HISTORY:      # keep the recent ones (amortised)
                del rs[:CLOCK_HISTORY], ss[:CLOCK_HISTORY]

    def _map_moved(self, final: bool) -> None:
        """Place the waiting receive-time messages that the clock has passed (``final``:
        every one) on the clock's time.

        Such a message belongs to the sample of the last clock message received before it
        (a command answers the measurement before it: the order two topics are received in
        is what a header-less message says about time), so its time is that message's
        stamp; when the clock skipped samples (a lost message) the sample is interpolated
        by receive time between the clock messages around it. Only receive times decide,
        not the order messages are handed over in."""
        rs, ss, q = self._clock_r, self._clock_s, self._moved_q
        if not q or not rs or (self.t0_int is None and not final):
            return                               # placed on the grid once it has a phase
        waiting: deque[tuple[str, int, dict[str, float]]] = deque()
        for topic, r, values in q:
            if not final and r > rs[-1]:
                waiting.append((topic, r, values))
                continue
            i = bisect.bisect_right(rs, r) - 1
            if i < 0:                            # before every clock message kept
                t = ss[0] - round(self.ts_ns)
            elif i + 1 < len(rs) and self.t0_int is not None:
                # between two clock messages: the earlier one's sample, or (samples lost
                # between them) the one its receive time falls in; slots of the grid, so
                # stamp jitter does not count as a lost sample
                a, b = self._slot_of(ss[i]), self._slot_of(ss[i + 1])
                off = 0
                if b - a > 1 and rs[i + 1] > rs[i]:
                    off = min(b - a - 1, math.floor((r - rs[i]) / (rs[i + 1] - rs[i])
                                                    * (b - a)))
                t = self.t0_int + round(self.t0_frac + (a + off) * self.ts_ns)
            elif i >= 1 and self.t0_int is not None:
                # after the last one (the end of the data): its sample, or for a slower
                # clock the one its receive time falls in before the next clock message is due
                a, b = self._slot_of(ss[i - 1]), self._slot_of(ss[i])
                off = 0
                if b > a and rs[i] > rs[i - 1]:
                    per = (rs[i] - rs[i - 1]) / (b - a)
                    off = max(0, min(self.topics[self.clock].period - 1,
                                     math.floor((r - rs[i]) / per)))
                t = self.t0_int + round(self.t0_frac + (b + off) * self.ts_ns)
            else:
                t = ss[i]
            self._accept(topic, t, r, values)
        self._moved_q = waiting

    def _accept(self, topic: str, t: int, receive_ns: int, values: dict[str, float]) -> None:
        msg = (topic, t, receive_ns, values)
        if self.t0_int is None:
            self._warm.append(msg)
            if topic == self.clock:
                self._warm_clock += 1
                if self._warm_clock >= WARMUP:
                    self._start_grid()
            return
        self._place(*msg)

    def _start_grid(self) -> None:
        """Phase from the warm-up's clock messages; then place every buffered message."""
        clock = [t for (tp, t, _r, _v) in self._warm if tp == self.clock]
        if not clock:
            return
        c0 = clock[0]
        steps = sorted(b - a for a, b in itertools.pairwise(clock) if b > a)
        m = 1
        if steps:
            med = steps[len(steps) // 2]
            if med < 0.75 * self.ts_ns:
                m = max(1, round(self.ts_ns / med))
        period = self.ts_ns / m
        sx = sy = 0.0
        for c in clock:
            a = 2.0 * math.pi * ((c - c0) / period)
            sx, sy = sx + math.cos(a), sy + math.sin(a)
        frac = math.atan2(sy, sx) / (2.0 * math.pi) if (sx or sy) else 0.0
        self._harmonic = m
        self.t0_int, self.t0_frac = c0, frac * period
        warm, self._warm, self._warm_clock = self._warm, [], 0
        for msg in warm:
            self._place(*msg)
        self._map_moved(False)

    def _slot(self, t: int) -> float:
        assert self.t0_int is not None
        return ((t - self.t0_int) - self.t0_frac) / self.ts_ns

    def _slot_of(self, t: int) -> int:
        """The sample (slot of this run) of time ``t``: the nearest grid instant."""
        return math.floor(self._slot(t) + 0.5)

    def _place(self, topic: str, t: int, receive_ns: int, values: dict[str, float]) -> None:
        tp = self.topics[topic]
        x = self._slot(t)
        j = math.floor(x + 0.5)
        newest = self.newest if self.newest is not None else self.next_slot
        outside = j > newest + self._ahead or j < self.next_slot - self._back
        if outside:
            self._stray.append((topic, t, receive_ns, values))
            if topic == self.clock and sum(1 for s in self._stray if s[0] == self.clock) >= 2:
                self._new_run()
            return
        if self._stray:
            if topic == self.clock:
                for s in self._stray:
                    self._count(f"stray:{s[0]}")
                    self._note("stray", s[0], f"{s[0]} at {s[1] * 1e-9:.6f} s: far from the "
                               f"stream's time (not confirmed by the next message): dropped")
                self._stray = []
        if topic == self.clock:
            m = self._harmonic
            r = m * x - math.floor(m * x + 0.5)
            self.t0_frac += self.ts_ns / m * r / TRACK
        if j < self.next_slot:
            self._late(tp, j, values)
        else:
            n = tp.counts.get(j, 0) + 1
            tp.counts[j] = n
            if n > 1:                            # more than one message for one sample
                self._count(f"decimated:{topic}")
            for c, v in values.items():
                acc = self._acc[c].get(j)
                if acc is None:
                    self._acc[c][j] = [v, 1.0, v]
                else:
                    acc[0] += v
                    acc[1] += 1.0
                    acc[2] = v
            tp.max_slot = j if tp.max_slot is None else max(tp.max_slot, j)
            self.newest = j if self.newest is None else max(self.newest, j)
        self._decide(False)

    def _late(self, tp: _Topic, j: int, values: dict[str, float]) -> None:
        self._count(f"late:{tp.name}")
        self._rate(tp, j, 1)                     # it counts for the topic's rate
        self._note("late", tp.name, f"{tp.name}: a message for sample {self.k_base + j} came "
                   f"after that sample was decided (more than {self.wait} sample(s) late): "
                   f"used as the held value from then on")
        for c, v in values.items():
            self._held[c].put(j, v)              # the held value only when newer

    def _new_run(self) -> None:
        """Two clock messages far from the stream: end this run, start a grid at them."""
        stray = self._stray
        self._stray = []
        self._decide(True)
        k_next = self.k_base + self.next_slot
        self._count("new_run")
        line = (f"{self.clock}: the clock jumped (from sample {k_next - 1} to a time "
                f"{'before' if stray[-1][1] < (self.t0_int or 0) else 'far after'} it): a "
                f"new run from sample {k_next} (fresh state)")
        self.notes.append(("new_run", line))
        self._out.append(NewRun(k_next, line))
        self.k_base = k_next
        self._reset_run()
        for s in stray:
            tp = self.topics[s[0]]
            tp.last_stamp = None
            self._warm.append(s)
            if s[0] == self.clock:
                self._warm_clock += 1

    # -- decisions ---------------------------------------------------------------------------

    def _rate(self, tp: _Topic, j: int, n: int) -> None:
        """Learn a topic's rate on the grid from its decided slots: messages per sample (the
        median count of its non-empty samples) and samples per message (the median distance
        between them). On the grid, not in its own time: a bursty publisher's receive times
        say nothing about its rate."""
        f = tp.filled
        if f and f[-1][0] >= j:                  # a late message of a decided sample
            for i in range(len(f) - 1, -1, -1):
                if f[i][0] == j:
                    f[i] = (j, f[i][1] + n)
                    break
        else:
            f.append((j, n))
        if len(f) >= 5:
            tp.per_slot = sorted(c for _, c in f)[len(f) // 2]
            gaps = sorted(b[0] - a[0] for a, b in itertools.pairwise(f))
            tp.period = gaps[len(gaps) // 2]

    def _closed(self, tp: _Topic, j: int) -> bool:
        """Whether ``tp`` can still bring a value for slot j: not once it is past j, or has
        sent its messages of j, or (a slower topic) its next message is not due before
        j + 1 (one slot of margin for jitter)."""
        m = tp.max_slot
        return m is not None and (m > j or tp.counts.get(j, 0) >= tp.per_slot
                                  or j < m + tp.period - 1)

    def _decide(self, final: bool) -> None:
        if self.newest is None:
            return
        while self.next_slot <= self.newest:
            j = self.next_slot
            if not (final or self.newest >= j + self.wait
                    or all(self._closed(tp, j) for tp in self.topics.values())):
                return
            self._out.append(self._sample(j))
            self.next_slot = j + 1
            for tp in self.topics.values():
                n = tp.counts.pop(j, 0)
                if n:
                    self._rate(tp, j, n)

    def _sample(self, j: int) -> GridSample | Gap:
        k = self.k_base + j
        values: dict[str, float] = {}
        held: list[str] = []
        gap: Gap | None = None
        for c in self.channels:
            acc = self._acc[c].pop(j, None)
            if acc is not None:
                values[c] = acc[0] / acc[1] if c in self.mean else acc[2]
                self._held[c].put(j, acc[2])
                continue
            hold = self._held[c]
            h = hold.at(j)
            if h is None:
                gap = gap or Gap(k, "no_value", c)
            elif hold.too_old(h[0], j):
                gap = gap or Gap(k, "stale", c)
            else:
                values[c] = h[1]
                held.append(c)
        if gap is not None:
            self._count(f"gap:{gap.reason}:{gap.channel}")
            return gap
        self._count("samples")
        for c in held:
            self._count(f"held:{c}")
        assert self.t0_int is not None
        t_ns = self.t0_int + round(self.t0_frac + j * self.ts_ns)
        return GridSample(k, t_ns, values, tuple(held))

    def flush(self) -> None:
        """Decide every slot seen (the live silence of ``hold_wait`` s, or its replay
        offline): a topic not heard by now is held or stale."""
        self._map_moved(True)
        if self.t0_int is None and self._warm:
            if self._warm_clock:
                self._start_grid()
            else:
                for topic, t, _r, _v in self._warm:
                    self._note("no_value", topic, f"{topic} at {t * 1e-9:.6f} s: no "
                               f"message on the clock topic {self.clock} yet: not a sample")
        self._decide(True)

    def ready(self, final: bool = False) -> list[Event]:
        """The events decided so far, in order. ``final`` (the end of a bag, or a live
        silence of ``hold_wait`` s): decide every slot seen, warm-up or not."""
        if final:
            for s in self._stray:
                self._count(f"stray:{s[0]}")
            self._stray = []
            self.flush()
        out = list(self._out)
        self._out.clear()
        return out

    def reset(self) -> None:
        """Forget the run (a reset service): the next messages start a new grid, numbered
        from the next sample."""
        self._decide(True)
        self._out.clear()
        self.k_base += self.next_slot
        self._reset_run()
        for tp in self.topics.values():
            tp.last_stamp = None

    def summary(self) -> dict[str, Any]:
        """Counts by kind: ``samples`` (used), ``gaps`` (reason -> channel -> n), ``held``
        (channel -> n), ``messages``/``late``/``duplicate``/``stray``/``decimated``
        (topic -> n), ``new_runs``."""
        out: dict[str, Any] = {"samples": self.counts.get("samples", 0), "gaps": {},
                               "held": {}, "new_runs": self.counts.get("new_run", 0)}
        for key, n in sorted(self.counts.items()):
            parts = key.split(":", 2)
            if parts[0] == "gap":
                out["gaps"].setdefault(parts[1], {})[parts[2]] = n
            elif parts[0] == "held":
                out["held"][parts[1]] = n
            elif len(parts) == 2:
                out.setdefault(parts[0], {})[parts[1]] = n
        return out
