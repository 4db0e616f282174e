"""The input contract's bag reader: one pass, in chunks, every check, nothing kept per message.

Every command that reads a bag's ``/plant/...`` topics (``analyze``, ``report``, ``replay``,
``identify``, ``bag check``, the regression suite) reads it through :func:`read_pass`:

* the MCAP is read once, record by record (:func:`fd_monitor.wire.bag_scanner.read_raw`: every
  chunk's CRC checked, damage skipped and reported by byte position), in batches of
  :data:`BATCH` records; no record is kept after its batch;
* the census of the bag (every topic's type and readable-message count, the labels of the
  first message of each ``/plant/...`` topic) is taken on the way, and at the end the damage
  and ``metadata.yaml``'s disagreements with the MCAP
  (:func:`~fd_monitor.wire.input_checks.metadata_problems`) are said once each (warnings) and
  kept in the :class:`BagScan`;
* the joined topics' messages are decoded (a message with the layout of the topic's last good
  one is read straight from its CDR bytes, a batch at a time; any other through
  :func:`~fd_monitor.wire.conversions.decode`, whose errors it gives), the label limits
  checked (:data:`~fd_monitor.wire.input_checks.MAX_LABEL_CHARS`,
  :data:`~fd_monitor.wire.input_checks.MAX_DISTINCT_LABELS`), and pushed, in record order with
  the record's log time as ``now``, through the nodes' input policy
  (:class:`~fd_monitor.wire.stream.InputStream`); each released sample goes to the caller's
  ``step`` (a runtime step, identify's collector, or nothing: ``bag check``);
* ``/plant/truth`` is read into arrays chunk by chunk (all its columns, or only ``mode``).

Checks that need the whole census (a topic missing, of another type, or whose first message
names other channels) are made at the end of the pass in the order a two-pass reader makes
them, so the error is the same; a problem found on the way stops the decoding (the census goes
on) and is raised after them. What was not used is :class:`InputReport`, and with the scan
the :func:`~fd_monitor.wire.input_checks.integrity` record.

Memory: a batch of records and what the caller keeps (``analyze``: ~30 bytes a sample), not
the bag: ``analyze`` of 10^6 samples stays under 150 MB (``benchmarks/bench_analyze_memory.py``).

Why one module of ~700 lines: the census, the decoding, the label limits, the input policy
and the report of what was not used are one pass over the bag, which every command shares.
"""

from __future__ import annotations

import bisect
import collections
import contextlib
import gc
import itertools
import math
import operator
import threading
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from fd_monitor.model.errors import (
    BagError,
    FdMonitorError,
    ImplausibleError,
    MessageError,
    NonFiniteError,
    WrongLengthError,
)
from fd_monitor.wire.bag_reader import TopicArrays, _deserialize, arrays_from_raw
from fd_monitor.wire.bag_scanner import BagDamage, BagDamageWarning, read_raw
from fd_monitor.wire.conversions import MAX_STAMP, cdr_shape, decode, readable_stamp
from fd_monitor.wire.input_checks import MAX_DISTINCT_LABELS, MAX_LABEL_CHARS, metadata_problems
from fd_monitor.wire.join import Sample, StampJoin
from fd_monitor.wire.stream import (
    GAP_TIMEOUT,
    MAX_GAP,
    RESTART_AFTER,
    STAMP_HORIZON,
    InputStream,
    TopicOrder,
)
from fd_monitor.wire.topics import FLOAT64_MULTI_ARRAY, PLANT_TRUTH, PLANT_U, PLANT_Y

__all__ = ["BATCH", "BagScan", "INPUT_ERROR_KINDS", "InputReport", "TruthReader", "read_pass",
           "scan_bag", "stamp_runs"]

#: Records read per batch (decoded together, then joined): what the reader holds of a bag.
BATCH = 4096
#: Prefix of the plant's topics in a bag (the topics whose first labels the census keeps).
_PLANT = PLANT_U.absolute.rsplit("/", 1)[0] + "/"
#: The joined inputs, as an error report names them.
UY = f"{PLANT_U.absolute},{PLANT_Y.absolute}"

#: Kinds of input errors the analysis reports (``input_errors`` of expected.yaml): the
#: decode errors, the input policy's reports (:mod:`fd_monitor.wire.stream`: ``late``, a
#: message for a stamp inside a declared hole; ``held``, the first stamp of an episode below
#: the stream or beyond the stamp horizon; ``dropped``, a full join buffer) and the runtime's
#: refusal (``implausible``).
INPUT_ERROR_KINDS = ("non_finite", "wrong_length", "malformed", "duplicate", "out_of_order",
                     "missing", "implausible", "late", "held", "dropped", "stale", "no_value",
                     "stray", "decimated")
#: Kinds whose ``sample`` is a run ``[first, last]`` of samples not used.
_SAMPLE_KINDS = ("missing", "stale", "no_value")
#: Kinds whose ``sample`` is one stamp not used (a refused message or sample).
_STAMP_KINDS = ("non_finite", "wrong_length", "malformed", "implausible")


@dataclass
class InputReport:
    """What was wrong with a bag's input messages.

    Attributes
    ----------
    errors : list of dict
        ``{kind, topic, sample, message}`` per rejected or suspicious message; ``kind`` one of
        :data:`INPUT_ERROR_KINDS`. ``sample`` is the stamp (None when unreadable).
    restarts : list of int
        Samples at which the monitor restarted (after a hole longer than ``MAX_GAP``, a
        refused restart sample, or at a new run), the first processed sample not counted.
    bridges : list of int
        Samples at which the monitor bridged a shorter hole (its memory kept).
    """

    errors: list[dict[str, Any]] = field(default_factory=list)
    restarts: list[int] = field(default_factory=list)
    bridges: list[int] = field(default_factory=list)
    used: int = 0
    timebase: dict[str, Any] = field(default_factory=dict)

    def sample_counts(self) -> dict[str, Any]:
        """Samples ``present`` (used + skipped), ``used`` (processed by the runtime) and
        ``skipped``: reason -> samples not used (a ``missing`` run counts its stamps; an
        adapter's ``stale``/``no_value`` gaps their samples; a refused message or sample its
        stamp). Messages dropped without losing a sample (duplicates, late, out of order)
        are not samples: they are in :attr:`errors` and :attr:`timebase`."""
        lost: dict[str, set[int] | int] = {}
        for e in self.errors:
            s = e["sample"]
            if e["kind"] in _SAMPLE_KINDS and isinstance(s, (list, tuple)):
                n = lost.get(e["kind"], 0)
                assert isinstance(n, int)  # a kind is a count or a set of stamps, never both
                lost[e["kind"]] = n + int(s[1]) - int(s[0]) + 1
            elif e["kind"] in _STAMP_KINDS and isinstance(s, int) and s >= 0:
                got = lost.setdefault(e["kind"], set())
                assert isinstance(got, set)
                got.add(s)
        skipped = {k: (len(v) if isinstance(v, set) else v) for k, v in sorted(lost.items())}
        return {"present": self.used + sum(skipped.values()), "used": self.used,
                "skipped": skipped}

    def by_kind(self) -> dict[str, list[Any]]:
        """kind -> sorted stamps (``missing``, ``stale``, ``no_value``: ``[first, last]``
        runs; -1: no stamp); a kind's entries sort by their first stamp whatever their form."""
        out: dict[str, list[Any]] = {}
        for e in self.errors:
            s = e["sample"]
            out.setdefault(e["kind"], []).append(-1 if s is None else
                                                 list(s) if isinstance(s, tuple) else s)
        return {k: sorted(v, key=lambda x: (x[0], x[-1]) if isinstance(x, list) else (x, x))
                for k, v in out.items()}


#: Input-error kind of each MessageError class (the first that matches); any other: malformed.
_KIND_OF = ((ImplausibleError, "implausible"), (NonFiniteError, "non_finite"),
            (WrongLengthError, "wrong_length"))


def classify(exc: MessageError) -> str:
    """The :data:`INPUT_ERROR_KINDS` entry of a refused message, by the error's class."""
    return next((kind for cls, kind in _KIND_OF if isinstance(exc, cls)), "malformed")


@dataclass
class BagScan:
    """The census of one pass over a bag (no message kept).

    Attributes
    ----------
    bag : str
    present : dict
        topic -> (message type, number of readable messages), every topic of the bag.
    first : dict
        ``/plant/...`` Float64MultiArray topic -> the channel labels of its first message
        (None: it names none), or the BagError its bytes gave.
    damage : list
        What the read found wrong (:class:`~fd_monitor.wire.bag_scanner.BagDamage`, CRC-less chunks
        included as ``kind="unchecked"``).
    metadata : list of str
        Where ``metadata.yaml`` disagrees with the MCAP
        (:func:`~fd_monitor.wire.input_checks.metadata_problems`).
    truth : TopicArrays or None
        ``/plant/truth`` when the pass was asked to read it (absent or unreadable: None).
    """

    bag: str
    present: dict[str, tuple[str, int]]
    first: dict[str, tuple[str, ...] | BagError | None] = field(default_factory=dict)
    damage: list[Any] = field(default_factory=list)
    metadata: list[str] = field(default_factory=list)
    truth: TopicArrays | None = None

    def first_labels(self, topic: str) -> tuple[str, ...] | None:
        """Channel labels of the first message of a Float64MultiArray ``topic`` (None when
        it has none or no message); BagError when the topic has another type or its first
        message is not a valid message."""
        if topic in self.present and self.present[topic][0] != FLOAT64_MULTI_ARRAY:
            raise BagError(f"{self.bag}: {topic} is {self.present[topic][0]}, not "
                           f"{FLOAT64_MULTI_ARRAY}")
        got = self.first.get(topic)
        if isinstance(got, BagError):
            raise got
        return got

    def check_topics(self, topics: Sequence[str],
                     then: Callable[[str], None] | None = None) -> None:
        """BagError unless every topic is in the bag as a Float64MultiArray; ``then(topic)``
        after each topic's type check (its labels)."""
        present = self.present
        missing = [t for t in topics if t not in present]
        if missing:
            raise BagError(f"{self.bag}: no topic {', '.join(missing)} in the bag (topics: "
                           f"{', '.join(sorted(present)) or 'none'})")
        for t in topics:
            if present[t][0] != FLOAT64_MULTI_ARRAY:
                raise BagError(f"{self.bag}: {t} is recorded as {present[t][0]}, expected "
                               f"{FLOAT64_MULTI_ARRAY}")
            if then is not None:
                then(t)


class TruthReader:
    """``/plant/truth`` read batch by batch into one
    :class:`~fd_monitor.wire.bag_reader.TopicArrays` (the arrays
    :func:`~fd_monitor.wire.bag_reader.read_bag` gives; None as soon as a message does not
    decode: the truth is then unused).

    Parameters
    ----------
    bag : str
    columns : tuple of str, optional
        Keep only these columns (those the truth has; ``("mode",)``: what ``analyze``
        reads, 12 bytes a sample; values as float32 when that is exact, no receive times);
        None: all.
    """

    def __init__(self, bag: str, columns: tuple[str, ...] | None = None) -> None:
        self.bag, self.columns = bag, columns
        self.labels: tuple[str, ...] | None = None
        self.cols: list[int] | None = None
        self.parts: list[TopicArrays] = []
        self.unstamped = 0                       # ArrivalStamper's count so far
        self.bad = False

    def add(self, records: list[tuple[str, str, int, bytes]]) -> None:
        """One batch's ``/plant/truth`` records."""
        if self.bad or not records:
            return
        try:
            with bag_errors(self.bag):
                a = arrays_from_raw(self.bag, records)[PLANT_TRUTH.absolute]
        except BagError:
            self.bad = True
            return
        if self.labels is None:
            self.labels = a.labels
            self.cols = ([i for i, n in enumerate(a.labels) if n in self.columns]
                         if self.columns is not None else None)
        elif a.labels != self.labels:
            # another layout than the first batch's: read message by message with the first
            # labels, as a whole-bag read does (a message naming other channels: unusable)
            self.bad = True
            return
        stamps = a.stamps
        if cdr_shape(records[0][3]) is not None and not _stamped(records[0][3]):
            stamps = stamps + self.unstamped     # plain messages numbered on arrival
            self.unstamped += len(stamps)
        if self.cols is None:
            self.parts.append(TopicArrays(a.topic, a.labels, stamps, a.values, a.receive_ns))
            return
        values = a.values[:, self.cols]
        # a mode index (and NaN) is exact in float32: half the memory a long bag keeps; the
        # receive times are not kept (nothing that reads only some columns uses them)
        small = values.astype(np.float32)
        exact = np.array_equal(small, values, equal_nan=True)
        self.parts.append(TopicArrays(a.topic, a.labels, stamps,
                                      small if exact else values.copy(), np.zeros(0, np.int64)))

    def arrays(self) -> TopicArrays | None:
        """The truth read (None: absent or unusable)."""
        if self.bad or self.labels is None:
            return None
        labels = (self.labels if self.cols is None
                  else tuple(self.labels[i] for i in self.cols))
        parts, self.parts = self.parts, []
        return TopicArrays(PLANT_TRUTH.absolute, labels,
                           np.concatenate([p.stamps for p in parts]),
                           np.concatenate([p.values for p in parts]),
                           np.concatenate([p.receive_ns for p in parts]))


def _stamped(raw: bytes) -> bool:
    shape = cdr_shape(raw)
    return shape is not None and shape[1].data_offset == 1


def scan_bag(bag: str | Path, warn: bool = True) -> BagScan:
    """The census of a bag (:func:`read_pass` joining nothing): every topic's type and count,
    the first labels of the ``/plant/...`` topics, damage and metadata problems (each said
    once with ``warn``).

    Raises
    ------
    BagError
        Missing bag, not a bag, unreadable data (the bag named).
    """
    return read_pass(bag, [], {}, InputReport(), warn=warn)


def read_pass(bag: str | Path, topics: Sequence[str],
              labels: dict[str, tuple[str, ...] | None], rep: InputReport,
              step: Callable[[Sample], bool] | None = None, *, names: dict[str, str] | None
              = None, max_gap: int = MAX_GAP, truth: tuple[str, ...] | bool | None = False,
              checks: Callable[[BagScan], None] | None = None,
              on_message: Callable[[str, int, int | None], Any] | None = None,
              warn: bool = True) -> BagScan:
    """One pass over a bag: census, damage, metadata, and ``topics`` joined through the input
    policy into ``step`` (see the module docstring).

    Parameters
    ----------
    bag : str or pathlib.Path
    topics : sequence of str
        The joined Float64MultiArray topics, every one required at every sample.
    labels : dict
        topic -> the expected channel labels, or None: its first message's (a first message
        naming none, or names over :data:`MAX_LABEL_CHARS` characters, is refused); such
        entries are filled in when the pass reads the topic's first message.
    rep : InputReport
        Filled with what the policy reported.
    step : callable, optional
        ``step(sample) -> bool`` per released sample (False: refused, the sample is lost).
    names : dict, optional
        topic -> the join's input name (default the topic).
    max_gap : int
        Holes of at most this many samples are bridged.
    truth : bool or tuple of str or None
        Read ``/plant/truth`` into :attr:`BagScan.truth`: False no, True (or None) every
        column, a tuple only those columns.
    checks : callable, optional
        ``checks(scan)`` run on the census before the reader's own checks (a command's own
        wording of them); raises BagError.
    on_message : callable, optional
        ``on_message(topic, log time ns, readable stamp or None)`` per joined message, in
        record order.
    warn : bool
        Say damage and metadata problems once each (warnings).

    Returns
    -------
    BagScan
        The census (the labels of the joined topics in :attr:`BagScan.first`).

    Raises
    ------
    BagError
        Missing bag, not a bag, unreadable data, a joined topic missing or of another type or
        naming other channels, too many distinct label strings.
    """
    if not Path(bag).exists():
        raise BagError(f"{bag}: no such bag")
    bag = str(bag)
    topics = list(topics)
    names = dict(names or {t: t for t in topics})
    want = set(topics)
    truth_topic = PLANT_TRUTH.absolute
    truth_reader = (None if truth is False else
                    TruthReader(bag, None if truth is True or truth is None else tuple(truth)))
    present: dict[str, tuple[str, int]] = {}
    first: dict[str, tuple[str, ...] | BagError | None] = {}
    damage: list[BagDamage] = []
    decoder = _Decoder(bag, topics, labels)
    refused: set[int] = set()                    # stamps of messages that did not decode
    where = [UY]                                 # topic of the message being joined
    stream = policy_stream([names[t] for t in topics], rep, refused, where,
                            step or _accept, max_gap)
    join = stream.join
    orders = {t: TopicOrder(t) for t in topics}
    problem: BagError | None = None              # found on the way: raised after the checks
    width = len(topics)
    with bag_errors(bag), _fewer_collections():
        records = read_raw(bag, damage=damage)
        for batch in iter(lambda: list(itertools.islice(records, BATCH)), []):
            # the census per batch, in C (Counter, dict of pairs): per record only the
            # comprehensions below; a topic's type is its last record's, as record by record
            counts = collections.Counter(map(_TOPIC, batch))
            types = dict(map(_TOPIC_TYPE, batch))
            for topic, c in counts.items():
                got = present.get(topic)
                if got is None:
                    rec = next(r for r in batch if r[0] == topic)      # its first record
                    if topic.startswith(_PLANT) and rec[1] == FLOAT64_MULTI_ARRAY:
                        first[topic] = _labels_of(bag, rec)
                present[topic] = (types[topic], c if got is None else got[1] + c)
            mine = [r for r in batch if r[0] in want]
            if truth_reader is not None and truth_topic in counts and truth_topic not in want:
                truth_reader.add([r for r in batch if r[0] == truth_topic
                                  and r[1] == FLOAT64_MULTI_ARRAY])
            if problem is not None or not mine:
                continue
            try:
                decoded = decoder.batch(mine, first)
            except BagError as exc:                 # stop decoding; the census goes on
                problem = exc
                continue
            i, n = 0, len(decoded)
            release, step_sample, lost = join.release_complete, stream.step, join.lost
            while i < n:
                if i + width <= n and _in_step(decoded, i, width, join.k_next, orders):
                    # the next stamp's messages together: released at once (the sample and
                    # join state putting them one by one gives; nothing to report)
                    grp = decoded[i:i + width]
                    k = grp[0][3]
                    s = release(k, {names[e[0]]: e[2] for e in grp}, grp[-1][1] * 1e-9)
                    if s is not None:
                        for e in grp:
                            orders[e[0]].last = k
                            if on_message is not None:
                                on_message(e[0], e[1], k)
                        if not step_sample(s):
                            lost(k)
                        i += width
                        continue
                topic, t_ns, d, k = decoded[i]
                i += 1
                if on_message is not None:
                    on_message(topic, t_ns, k)
                now = t_ns * 1e-9
                if join.pending or join.held:       # what is due by this record's time (a
                    where[0] = UY                   # node's gap timer, at the same guard)
                    stream.release(now)
                where[0] = topic
                if isinstance(d, MessageError):
                    rep.errors.append({"kind": classify(d), "topic": topic, "sample": k,
                                       "message": str(d)})
                    if k is not None:
                        refused.add(k)
                    stream.refused(k, now)
                    continue
                stream.stamped(orders[topic], names[topic], k, d, now)
        if problem is None and topics:
            where[0] = UY
            stream.release(math.inf)             # the end of the bag: every wait is over
    damaged = any(d.kind == "damage" for d in damage)
    scan = BagScan(bag, present, first, damage, metadata_problems(bag, present, damaged),
                   None if truth_reader is None or present.get(truth_topic, ("", 0))[0]
                   != FLOAT64_MULTI_ARRAY else truth_reader.arrays())
    if warn:
        for dmg in damage:
            if dmg.kind == "damage":   # one location: said once even when read again
                warnings.warn(str(dmg), BagDamageWarning, stacklevel=1)
        for line in scan.metadata:
            warnings.warn(f"{bag}: {line}", BagDamageWarning, stacklevel=1)
    if checks is not None:
        checks(scan)
    scan.check_topics(topics, lambda t: decoder.check_first(scan, t))
    if problem is not None:
        raise problem
    return scan


_TOPIC = operator.itemgetter(0)
_TOPIC_TYPE = operator.itemgetter(0, 1)


def _in_step(decoded: list[list[Any]], i: int, width: int, k: int | None,
             orders: dict[str, TopicOrder]) -> bool:
    """``decoded[i:i + width]`` is one message of each joined topic, decoded, all of stamp
    ``k`` (the join's next), each after a lower stamp on its topic (no order report)."""
    if k is None:
        return False
    seen = set()
    ndarray = np.ndarray
    for e in decoded[i:i + width]:
        if e[3] != k or type(e[2]) is not ndarray:
            return False
        last = orders[e[0]].last
        if last is not None and last >= k:
            return False
        seen.add(e[0])
    return len(seen) == width


def _accept(_s: Sample) -> bool:
    return True


def _labels_of(bag: str, rec: tuple[str, str, int, bytes]) -> tuple[str, ...] | BagError | None:
    """The labels of a record's message (None: none), or the BagError of bytes that are not
    a valid message (as reading it would raise)."""
    topic, ty, t, raw = rec
    try:
        msg = _deserialize(raw, ty)
    except Exception as exc:  # rosbags raises assorted errors on CDR of another type
        return BagError(f"{bag}: {topic} at {t * 1e-9:.3f} s: not a valid {ty} "
                        f"({type(exc).__name__})")
    dims = msg.layout.dim
    return tuple(dims[0].label.split(",")) if dims and dims[0].label else None


class _Decoder:
    """The joined topics' records of a batch -> ``[topic, log time ns, values or
    MessageError, stamp or None]`` in record order.

    A message is decoded by :func:`~fd_monitor.wire.conversions.decode` (errors and results
    are its, bit for bit) unless it has the bytes before the data of the topic's last
    message that decoded (labels, sizes, offset: a bag's messages share them) and the same
    length: those are read as one block per batch, and any whose stamp or values would not
    pass decode goes through decode after all (for its error)."""

    def __init__(self, bag: str, topics: Sequence[str],
                 labels: dict[str, tuple[str, ...] | None]) -> None:
        self.bag = bag
        self.labels = labels                      # the caller's: None entries filled in
        for t in topics:
            labels.setdefault(t, None)
        #: topic -> (length, the bytes before the data, data start, float64 count)
        self.known: dict[str, tuple[int, bytes, int, int]] = {}
        self.seen: dict[str, set[str]] = {t: set() for t in topics}
        self.checked: set[str] = set()            # topics whose label checks passed

    def check_first(self, scan: BagScan, topic: str) -> None:
        """The topic's first message names the expected channels (a bag of another plant, or
        u and y swapped, would have every message refused), or names some when none are
        expected."""
        expected = self.labels.get(topic)
        got = scan.first_labels(topic)
        if expected is None:
            if got is None:
                raise BagError(f"{self.bag}: {topic}: its first message names no channels "
                               f"(layout.dim[0].label): cannot tell them apart")
            if len(",".join(got)) > MAX_LABEL_CHARS:
                raise BagError(f"{self.bag}: {topic}: channel labels of over "
                               f"{MAX_LABEL_CHARS} characters (limit MAX_LABEL_CHARS)")
        elif got and tuple(got) != tuple(expected):
            raise BagError(f"{self.bag}: {topic} has channels {list(got)[:10]} but the plant "
                           f"has {list(expected)}: a bag of another plant?")

    def batch(self, records: list[tuple[str, str, int, bytes]],
              first: dict[str, tuple[str, ...] | BagError | None]
              ) -> list[list[Any]]:
        out: list[Any] = []
        block: dict[str, list[int]] = {}         # topic -> positions in out read as a block
        checked = self.checked
        for topic, ty, t, raw in records:
            # (the end of the pass says these problems in the words of its checks)
            if ty != FLOAT64_MULTI_ARRAY:
                raise BagError(f"{self.bag}: {topic} is recorded as {ty}, expected "
                               f"{FLOAT64_MULTI_ARRAY}")
            if topic in checked:
                pass
            elif self.labels[topic] is None:
                got = first.get(topic)
                if isinstance(got, BagError):
                    raise got
                if got is None or len(",".join(got)) > MAX_LABEL_CHARS:
                    raise BagError(f"{self.bag}: {topic}: its first message names no usable "
                                   f"channels")
                self.labels[topic] = tuple(got)
            elif isinstance(first.get(topic), tuple) and first[topic] != self.labels[topic]:
                raise BagError(f"{self.bag}: {topic}: other channels than the plant's")
            else:
                # first[topic] (set at the topic's first record) and labels[topic] no longer
                # change: these checks would pass again
                checked.add(topic)
            known = self.known.get(topic)
            if known is not None and len(raw) == known[0] and raw.startswith(known[1]):
                block.setdefault(topic, []).append(len(out))
                out.append([topic, t, raw, None])
                continue
            out.append(self._one(topic, ty, t, raw))
        for topic, where in block.items():
            self._block(topic, [out[i] for i in where])
        for e in out:
            if isinstance(e, list) and isinstance(e[2], bytes):   # the block refused it
                e[2], e[3] = self._one(e[0], FLOAT64_MULTI_ARRAY, e[1], e[2])[2:]
        return out

    def _block(self, topic: str, entries: list[list[Any]]) -> None:
        """Read the entries' values as one block (stamp in data[0], finite values), in
        place; an entry that would not decode keeps its bytes (decoded one by one)."""
        n, _head, start, size = self.known[topic]
        data = np.frombuffer(b"".join([e[2] for e in entries]), np.uint8).reshape(
            len(entries), n)[:, start:start + 8 * size].copy().view("<f8")
        s = data[:, 0]
        vals = data[:, 1:]
        ok = (s >= 0) & (s < MAX_STAMP) & (s == np.floor(s)) & np.isfinite(vals).all(axis=1)
        stamps = s.astype(np.int64, copy=False) if ok.all() else np.where(ok, s, 0).astype(
            np.int64)
        if ok.all():                              # the usual case: rows in order
            for e, row, k in zip(entries, vals, stamps.tolist()):
                e[2], e[3] = row, k
            return
        for i in np.flatnonzero(ok).tolist():
            e = entries[i]
            e[2], e[3] = vals[i], int(stamps[i])

    def _one(self, topic: str, ty: str, t: int, raw: bytes) -> Any:
        """One message through decode (the label limits first)."""
        try:
            msg = _deserialize(raw, ty)
        except Exception as exc:  # rosbags raises assorted errors on CDR of another type
            raise BagError(f"{self.bag}: {topic} at {t * 1e-9:.3f} s: not a valid {ty} "
                           f"({type(exc).__name__})") from None
        msg = self._bounded(topic, msg)
        try:
            d = decode(msg, topic, labels=self.labels[topic], require_stamp=True)
        except MessageError as exc:
            return [topic, t, exc, readable_stamp(msg)]
        shape = cdr_shape(raw)
        if shape is not None and shape[1].data_offset == 1 and shape[3] >= 1:
            self.known[topic] = (len(raw), shape[0], shape[2], shape[3])
        return [topic, t, d.values, int(d.stamp or 0)]

    def _bounded(self, topic: str, msg: Any) -> Any:
        """The label limits of offline reading: more than :data:`MAX_DISTINCT_LABELS` label
        strings on a topic refuse the bag (BagError); a label longer than
        :data:`MAX_LABEL_CHARS` is replaced by a short marker, so the message is refused for
        its channels with a short line (and no long string is kept)."""
        dims = msg.layout.dim
        label = str(dims[0].label) if dims else ""
        if len(label) > MAX_LABEL_CHARS:
            # one name per value, so the message is refused for its channels (malformed)
            marker = ",".join([f"<label of {len(label)} characters over {MAX_LABEL_CHARS}>"]
                              + ["?"] * max(int(dims[0].size) - 1, 0))
            msg = SimpleNamespace(data=msg.data, layout=SimpleNamespace(
                dim=[SimpleNamespace(label=marker, size=dims[0].size, stride=dims[0].stride)],
                data_offset=msg.layout.data_offset))
            label = marker
        got = self.seen[topic]
        if label not in got:
            got.add(label)
            if len(got) > MAX_DISTINCT_LABELS:
                raise BagError(f"{self.bag}: {topic}: more than {MAX_DISTINCT_LABELS} distinct "
                               f"channel label strings (limit MAX_DISTINCT_LABELS: one topic "
                               f"carries one plant's channels)")
        return msg


def policy_stream(required: Sequence[str], rep: InputReport, refused: set[int],
                   where: list[str], step: Callable[[Sample], bool],
                   max_gap: int = MAX_GAP) -> InputStream:
    """The nodes' input policy (an entry :class:`~fd_monitor.wire.join.StampJoin` with the
    nodes' defaults) reporting into ``rep``: holes as ``missing`` less the ``refused`` stamps
    (reported already with their own kind), restarts in ``rep.restarts``, bridges in
    ``rep.bridges``, used samples counted; ``where[0]`` is the topic a report names."""
    join = StampJoin(required, gap_timeout=GAP_TIMEOUT, horizon=STAMP_HORIZON,
                     restart_after=RESTART_AFTER, max_gap=max_gap)
    processed = [False]

    def note(kind: str, line: str, stamp: Any) -> None:
        if kind == "hole":                       # its stamps minus the refused ones
            a, b = stamp
            inside = sorted(j for j in refused if a <= j <= b)
            decided = line.split("; ", 1)[1].split(" (", 1)[0]   # bridged / restarted at k
            for lo, hi in _gaps([a - 1, b + 1], inside):
                rep.errors.append({"kind": "missing", "topic": where[0], "sample": [lo, hi],
                                   "message": f"no message for stamps {lo}..{hi} "
                                              f"({hi - lo + 1} samples); {decided}"})
        elif kind not in ("new_run", "feedback_lost", "bridge"):  # in rep.restarts, bridges
            rep.errors.append({"kind": kind, "topic": where[0], "sample": stamp,
                               "message": line})

    def run(s: Sample) -> bool:
        if s.restart and processed[0]:
            rep.restarts.append(s.k)
        elif s.bridge:
            rep.bridges.append(s.k)
        ok = step(s)
        processed[0] = processed[0] or ok
        rep.used += ok
        return ok

    return InputStream(join, run, note)


#: The cyclic collector's first threshold during a pass (Python's default is 700): the pass
#: allocates a few short-lived objects per record and sample, nearly none in cycles, and the
#: default made ~10 % of ``analyze``'s CPU collections that find nothing (memory unchanged).
GC_THRESHOLD0 = 100_000
_gc_lock = threading.Lock()
_gc_depth = [0, 0]                               # passes running, the threshold before them


@contextlib.contextmanager
def _fewer_collections() -> Iterator[None]:
    """Raise the collector's first threshold while a pass runs (passes may overlap in
    threads: the first one in saves the threshold, the last one out restores it)."""
    with _gc_lock:
        if _gc_depth[0] == 0:
            _gc_depth[1] = gc.get_threshold()[0]
            gc.set_threshold(max(GC_THRESHOLD0, _gc_depth[1]), *gc.get_threshold()[1:])
        _gc_depth[0] += 1
    try:
        yield
    finally:
        with _gc_lock:
            _gc_depth[0] -= 1
            if _gc_depth[0] == 0:
                gc.set_threshold(_gc_depth[1], *gc.get_threshold()[1:])


@contextlib.contextmanager
def bag_errors(bag: str | Path) -> Iterator[None]:
    """Turn the bag decoders' own errors (zstd, lz4, CDR, struct, rosbags) on corrupted
    bytes into one :class:`BagError` naming the bag: they are no stable API to list."""
    try:
        yield
    except FdMonitorError:
        raise
    except Exception as exc:
        raise BagError(f"{bag}: unreadable bag data ({type(exc).__name__}: "
                       f"{str(exc).splitlines()[0] if str(exc) else 'no detail'})") from None


def _gaps(ks: Sequence[int], rejected: Sequence[int]) -> list[tuple[int, int]]:
    """Inclusive runs of stamps between the sorted valid stamps ``ks`` that are neither valid
    nor in the sorted ``rejected``; computed per gap, never per stamp (stamps may be 2^53
    apart)."""
    out: list[tuple[int, int]] = []
    for a, b in itertools.pairwise(ks):
        lo = a + 1
        i = bisect.bisect_left(rejected, lo)
        while lo < b:
            r = rejected[i] if i < len(rejected) and rejected[i] < b else b
            if r > lo:
                out.append((lo, r - 1))
            lo, i = r + 1, i + 1
    return out


def stamp_runs(ks: Sequence[int]) -> list[tuple[int, int]]:
    """Sorted stamps -> inclusive runs ``(first, last)`` of consecutive stamps."""
    out: list[tuple[int, int]] = []
    for k in ks:
        if out and k == out[-1][1] + 1:
            out[-1] = (out[-1][0], k)
        else:
            out.append((k, k))
    return out
