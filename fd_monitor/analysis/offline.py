"""Offline runs of a monitor over a bag: tolerant input reading, per-sample arrays, summaries.

One mechanism serves ``analyze`` (:mod:`fd_monitor.commands.analyze`), the bag reports
(:mod:`fd_monitor.analysis.report`) and the regression suite (:mod:`fd_monitor.analysis.library`):

1. :func:`read_streams` pushes the bag's ``/plant/u``, ``/plant/y`` (and side-signal)
   messages, in record order, through the nodes' own input policy
   (:class:`fd_monitor.wire.stream.InputStream`: decode, per-topic order check, the entry
   role of :class:`~fd_monitor.wire.join.StampJoin`) with the time ``now`` = the record's
   log time in s, the nodes' default ``gap_timeout``, ``stamp_horizon`` and
   ``restart_after``, ``max_gap``, and ``now = +inf`` at the end of the bag. So a bag gives
   the samples, holes, bridges, restarts and new runs the live entry node gives when the bag
   is replayed into it:
   a message that does not decode (NaN/Inf, wrong length, bad layout) is reported and its
   stamp lost, duplicates are reported (the first is kept), out-of-order stamps are reported
   and joined in stamp order when they come within ``gap_timeout``, holes are reported as
   ``missing`` (their refused stamps left out), stray stamps as ``held``.
2. :func:`run_bag` steps the gain file's runtime (:func:`fd_monitor.core.methods.runtime_for`,
   one registry keyed by the gain file's ``method``: ``thresholds``, ``qb``, ``hinf_sc``,
   ``hminus_switched``) on each released sample, with the side signals the runtime needs read
   from ``/plant/<name>`` (:func:`~fd_monitor.wire.topics.side_topic`: ``/plant/rho``,
   ``/plant/mode``); a hole of at most ``MAX_GAP`` samples is bridged
   (:meth:`~fd_monitor.core.runtime.Runtime.bridge`: the fault memory kept, the state
   estimate carried over the gap), a longer one restarts it (``reset``: a new run); a sample
   the runtime refuses (implausible) is reported and lost, as live. Every rejected message is
   reported.
3. :mod:`fd_monitor.analysis.summary` reads the resulting :class:`BagRun`
   (:func:`~fd_monitor.analysis.summary.summarize_run`,
   :func:`~fd_monitor.analysis.summary.analyze_run`).

Nothing here imports rclpy (the message decoding is the nodes' pure conversion function).

Why one module of ~770 lines: reading a bag through the one input policy and running a
runtime over it is one pipeline (input report, bag scan, run), which the regression suite
compares bit for bit with the live nodes.
"""

from __future__ import annotations

import bisect
import contextlib
import itertools
import math
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.core.methods import load_gains, runtime_for
from fd_monitor.model.errors import (
    BagError,
    FdMonitorError,
    ImplausibleError,
    MessageError,
    NonFiniteError,
    WrongLengthError,
)
from fd_monitor.model.gains import GainFile
from fd_monitor.model.system import gain_system
from fd_monitor.wire.adapters import Adapter, feed, load_adapter, read_adapted
from fd_monitor.wire.bags import (
    BagDamage,
    BagDamageWarning,
    arrays_from_raw,
    messages_from_raw,
    read_raw,
)
from fd_monitor.wire.conversions import decode, readable_stamp
from fd_monitor.wire.input_checks import bounded_labels, integrity, metadata_problems
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
from fd_monitor.wire.topics import side_topic as _side_topic

__all__ = ["BagRun", "BagScan", "INPUT_ERROR_KINDS", "InputReport", "read_inputs",
           "read_streams", "run_bag", "run_runtime", "run_thresholds", "scan_bag",
           "stamp_runs"]

#: Prefix of the plant's topics in a bag (the records a scan keeps).
_PLANT = PLANT_U.absolute.rsplit("/", 1)[0] + "/"
#: The joined inputs, as an error report names them.
_UY = f"{PLANT_U.absolute},{PLANT_Y.absolute}"

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


def _classify(exc: MessageError) -> str:
    """The :data:`INPUT_ERROR_KINDS` entry of a refused message, by the error's class."""
    return next((kind for cls, kind in _KIND_OF if isinstance(exc, cls)), "malformed")


@dataclass
class BagScan:
    """One pass over a bag (an analysis opens and reads it once).

    Attributes
    ----------
    bag : str
    present : dict
        topic -> (message type, number of readable messages), every topic of the bag.
    records : list
        ``(topic, type, timestamp_ns, cdr_bytes)`` in file order of the ``/plant/...``
        topics (inputs, measurements, side signals, truth).
    """

    bag: str
    present: dict[str, tuple[str, int]]
    records: list[tuple[str, str, int, bytes]]
    #: What the read found wrong (:class:`~fd_monitor.wire.bags.BagDamage`, CRC-less chunks
    #: included as ``kind="unchecked"``) and where ``metadata.yaml`` disagrees with the MCAP
    #: (:func:`fd_monitor.analysis.integrity.metadata_problems`).
    damage: list[Any] = field(default_factory=list)
    metadata: list[str] = field(default_factory=list)

    def messages(self, topics: Sequence[str]) -> Iterator[tuple[str, int, Any]]:
        """``(topic, timestamp_ns, message)`` of ``topics`` in file order (as
        :func:`fd_monitor.wire.bags.read_messages`)."""

        want = set(topics)
        yield from messages_from_raw(self.bag, (r for r in self.records if r[0] in want))

    def first_labels(self, topic: str) -> tuple[str, ...] | None:
        """Channel labels of the first message of a Float64MultiArray ``topic`` (None when
        it has none or no message); BagError when the topic has another type."""
        if topic in self.present and self.present[topic][0] != FLOAT64_MULTI_ARRAY:
            raise BagError(f"{self.bag}: {topic} is {self.present[topic][0]}, not "
                           f"{FLOAT64_MULTI_ARRAY}")
        for _topic, _t, msg in self.messages([topic]):
            dims = msg.layout.dim
            return tuple(dims[0].label.split(",")) if dims and dims[0].label else None
        return None

    def truth(self) -> Any:
        """``/plant/truth`` as :class:`~fd_monitor.wire.bags.TopicArrays`, or None (absent or
        unreadable)."""

        truth = PLANT_TRUTH.absolute
        if self.present.get(truth, ("", 0))[0] != FLOAT64_MULTI_ARRAY:
            return None
        try:
            with _bag_errors(self.bag):
                return arrays_from_raw(self.bag, (r for r in self.records
                                                  if r[0] == truth))[truth]
        except BagError:
            return None


def scan_bag(bag: str | Path, warn: bool = True) -> BagScan:
    """Read a bag once: every topic's type and count, and the ``/plant/...`` records.

    The damage found and ``metadata.yaml``'s disagreements with the MCAP are kept in the
    scan (:func:`fd_monitor.analysis.integrity.integrity`) and, with ``warn``, each said once
    as a warning (stderr); chunks without CRC are not damage and not warned about.

    Raises
    ------
    BagError
        Missing bag, not a bag, unreadable data (the bag named).
    """
    if not Path(bag).exists():
        raise BagError(f"{bag}: no such bag")
    present: dict[str, tuple[str, int]] = {}
    records: list[tuple[str, str, int, bytes]] = []
    damage: list[BagDamage] = []
    with _bag_errors(bag):
        for rec in read_raw(bag, damage=damage):
            topic, ty = rec[0], rec[1]
            present[topic] = (ty, present.get(topic, (ty, 0))[1] + 1)
            if topic.startswith(_PLANT):
                records.append(rec)
    damaged = any(d.kind == "damage" for d in damage)
    scan = BagScan(str(bag), present, records, damage,
                   metadata_problems(bag, present, damaged))
    if warn:
        for d in damage:
            if d.kind == "damage":   # one location: said once even when read again
                warnings.warn(str(d), BagDamageWarning, stacklevel=1)
        for line in scan.metadata:
            warnings.warn(f"{bag}: {line}", BagDamageWarning, stacklevel=1)
    return scan


def read_inputs(bag: str | Path, system: Any) -> tuple[dict[int, np.ndarray],
                                                       dict[int, np.ndarray], InputReport]:
    """Read ``/plant/u`` and ``/plant/y`` message by message, keeping the valid ones.

    The nodes' input policy (:func:`read_streams`): a message that does not decode (NaN/Inf,
    wrong length, bad layout) is rejected; the same stamp twice in a row, or a pending stamp
    again, is a duplicate (the first is kept); a stamp lower than the one before it on its
    topic is reported as out of order and joined in stamp order; holes (stamps with no usable
    ``(u, y)`` pair) are reported as missing.

    Returns
    -------
    (dict, dict, InputReport)
        stamp -> u (nu,), stamp -> y (ny,) of the released samples, the report (with the
        restarts).
    """
    us, ys, _side, rep = read_streams(bag, system)
    return us, ys, rep


def read_streams(bag: str | Path, system: Any,
                 side: dict[str, tuple[str, ...]] | None = None, scan: BagScan | None = None,
                 step: Callable[[Sample], bool] | None = None
                 ) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray],
                            dict[str, dict[int, np.ndarray]], InputReport]:
    """:func:`read_inputs` plus side-signal topics, through the nodes' input policy.

    The messages go, in bag record order, through
    :class:`~fd_monitor.wire.stream.InputStream` (the code a node's subscription callback
    runs) with ``now`` = the record's log time in s: before each message the decisions due by
    its time are taken (as a node's gap timer would), and at the end of the bag ``now =
    +inf``. The join has the nodes' defaults
    (:data:`~fd_monitor.wire.stream.GAP_TIMEOUT`,
    :data:`~fd_monitor.wire.stream.STAMP_HORIZON`,
    :data:`~fd_monitor.wire.stream.RESTART_AFTER`).

    Parameters
    ----------
    bag : str or pathlib.Path
    system : System
    side : dict, optional
        Side signal name -> its labels (read from
        :func:`~fd_monitor.wire.topics.side_topic`); a stamp without a
        valid value of every side signal is not a usable sample (reported as missing).
    scan : BagScan, optional
        The bag already read (:func:`scan_bag`); default: read it now.
    step : callable, optional
        ``step(sample) -> bool`` run on each released
        :class:`~fd_monitor.wire.join.Sample` after its values are kept (a runtime step,
        reset first at a restart, bridged first at a bridge); False: the runtime refused it
        (implausible), the sample is lost (the next one bridges or restarts). Default: every
        sample is accepted.

    Returns
    -------
    (dict, dict, dict, InputReport)
        stamp -> u (nu,), stamp -> y (ny,), name -> (stamp -> value) of the released samples
        (a stamp released twice, in two runs: the last), the report.
    """
    if scan is None:
        scan = scan_bag(bag)
    rep = InputReport()
    side = dict(side or {})
    t_u, t_y = PLANT_U.absolute, PLANT_Y.absolute
    labels = {t_u: PLANT_U.labels(system), t_y: PLANT_Y.labels(system)}
    names = {t_u: "u", t_y: "y"}
    for name, labs in side.items():
        labels[_side_topic(name).absolute] = tuple(labs)
        names[_side_topic(name).absolute] = name
    topics = ([t_y] + ([t_u] if system.nu else [])
              + [_side_topic(n).absolute for n in side])

    present = scan.present
    missing = [t for t in topics if t not in present]
    if missing:
        raise BagError(f"{bag}: no topic {', '.join(missing)} in the bag (topics: "
                       f"{', '.join(sorted(present)) or 'none'})")
    for t in topics:
        if present[t][0] != FLOAT64_MULTI_ARRAY:
            raise BagError(f"{bag}: {t} is recorded as {present[t][0]}, expected "
                           f"{FLOAT64_MULTI_ARRAY}")
        # a bag of another plant (or u and y swapped) would have every message refused
        first = scan.first_labels(t)
        if first and tuple(first) != tuple(labels[t]):
            raise BagError(f"{bag}: {t} has channels {list(first)[:10]} but plant "
                           f"{system.name} has {list(labels[t])}: a bag of another plant?")
    us: dict[int, np.ndarray] = {}
    ys: dict[int, np.ndarray] = {}
    sides: dict[str, dict[int, np.ndarray]] = {n: {} for n in side}
    no_u = np.zeros(0)

    def keep(s: Sample) -> bool:
        v = s.inputs
        us[s.k] = v["u"] if system.nu else no_u
        ys[s.k] = v["y"]
        for n, d in sides.items():
            d[s.k] = v[n]
        return True if step is None else step(s)

    required = [names[t] for t in topics]
    with _bag_errors(bag):
        _join_messages(bounded_labels(scan.messages(topics), bag), labels, names, required,
                       rep, keep,
                       MAX_GAP)
    return us, ys, sides, rep


def _join_messages(messages: Iterable[tuple[str, int, Any]],
                   labels: dict[str, tuple[str, ...]], names: dict[str, str],
                   required: Sequence[str], rep: InputReport,
                   step: Callable[[Sample], bool], max_gap: int = 0) -> None:
    """The message loop of :func:`read_streams`: each ``(topic, log time ns, message)``
    through :class:`~fd_monitor.wire.stream.InputStream`; reports into ``rep``."""

    refused: set[int] = set()                    # stamps of messages that did not decode
    where = [_UY]                                # topic of the message being joined
    stream = _policy_stream(required, rep, refused, where, step, max_gap)
    join = stream.join
    orders = {t: TopicOrder(t) for t in labels}
    # Every message decoded first (pure, per message), then joined and stepped: decoding
    # interleaved with the runtime's steps measured ~35 % slower (three_tank, 3,000 samples).
    decoded: list[tuple[str, float, Any, int | None]] = []
    for topic, t_ns, msg in messages:
        try:
            decoded.append((topic, t_ns * 1e-9,
                            decode(msg, topic, labels=labels[topic], require_stamp=True), None))
        except MessageError as exc:
            decoded.append((topic, t_ns * 1e-9, exc, readable_stamp(msg)))
    for topic, now, d, k in decoded:
        if join.pending or join.held:            # what is due by this record's time (a
            where[0] = _UY                       # node's gap timer, at the same guard)
            stream.release(now)
        where[0] = topic
        if isinstance(d, MessageError):
            rep.errors.append({"kind": _classify(d), "topic": topic, "sample": k,
                               "message": str(d)})
            if k is not None:
                refused.add(k)
            stream.refused(k, now)
            continue
        stream.stamped(orders[topic], names[topic], int(d.stamp or 0), d.values, now)
    where[0] = _UY
    stream.release(math.inf)                     # the end of the bag: every wait is over


def _policy_stream(required: Sequence[str], rep: InputReport, refused: set[int],
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


@contextlib.contextmanager
def _bag_errors(bag: str | Path) -> Iterator[None]:
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


@dataclass
class BagRun:
    """Per-sample outputs of the monitor over one bag (what the report plots).

    Attributes
    ----------
    bag : str
    method : str
        Gain-file method (a key of :data:`fd_monitor.core.methods.RUNTIMES`).
    gains : str
        Gain file path.
    system : System
    k : numpy.ndarray
        (K,) processed sample stamps.
    channels : tuple of str
        Alarm channels.
    units : tuple of str
        Unit of each channel's signal.
    signal, threshold : numpy.ndarray
        (K, m) the compared signal (residual) and the threshold in force.
    alarm : numpy.ndarray
        (K, m) bool
    mode_hat : numpy.ndarray
        (K,) estimated mode.
    estimate : dict
        name -> (K,) estimated bias (the runtime's
        :meth:`~fd_monitor.core.runtime.Runtime.bias_estimates`: ``thresholds``: sigma^ per
        output; ``qb``: the fault-model states; none for ``hinf_sc`` and ``hminus_switched``).
    isolated : numpy.ndarray or None
        (K, ny) bool isolation flags (runtimes with an ``isolated`` estimate: ``thresholds``).
    truth : TopicArrays or None
        ``/plant/truth`` of the bag.
    inputs : InputReport
    transient : float
        s
    qb : dict
        QB only: ``V`` (K,) e' P e with the true state (NaN without truth), ``error`` (K, n),
        ``component_bound`` (n,).
    outside : numpy.ndarray or None
        (K, r) excess over the gain file's certified region (0 inside): x^ and u (states then
        inputs) for ``thresholds``/``qb``, rho for an LPV ``hinf_sc`` bank, the mode for
        ``hminus_switched``; None when the gain file has no region.
    region_names : tuple of str
        Names of the columns of ``outside``.
    signed : bool
        The residual is signed, alarms at ``|r| > R`` (:attr:`Runtime.SIGNED`).
    estimate_kind : str
        :attr:`~fd_monitor.core.runtime.Runtime.ESTIMATE_KIND` of ``estimate``.
    traces : dict
        Every per-sample estimate of the runtime, name -> (K, ...) (e.g. ``x_hat``, ``rho``).
    isolating : tuple of str
        Channels whose alarm isolates the fault they are named after
        (:attr:`~fd_monitor.core.runtime.Runtime.isolating`), used without isolation flags.
    """

    bag: str
    method: str
    gains: str
    system: Any
    k: np.ndarray
    channels: tuple[str, ...]
    units: tuple[str, ...]
    signal: np.ndarray
    threshold: np.ndarray
    alarm: np.ndarray
    mode_hat: np.ndarray
    estimate: dict[str, np.ndarray]
    isolated: np.ndarray | None
    truth: Any
    inputs: InputReport
    transient: float = 0.0
    qb: dict[str, Any] = field(default_factory=dict)
    outside: np.ndarray | None = None
    region_names: tuple[str, ...] = ()
    signed: bool = True
    estimate_kind: str = "sensor_bias"
    traces: dict[str, np.ndarray] = field(default_factory=dict)
    isolating: tuple[str, ...] = ()
    #: What of the bag was not used (:func:`fd_monitor.analysis.integrity.integrity`).
    integrity: dict[str, Any] = field(default_factory=dict)

    @property
    def t(self) -> np.ndarray:
        """(K,) times, s."""
        return self.k * float(self.system.sample_time)


def _load_system_for(bag: str | Path, gains_source: str | Path) -> tuple[Any, Any]:
    """The gain file and its plant (the plant file named by the gain file)."""

    raw = load_gains(gains_source, None, verify=False)
    system = gain_system(raw)
    return system, load_gains(gains_source, system)


def run_bag(bag: str | Path, gains: str | Path | Any, *, transient: float = 0.0,
            system: Any = None, agei: bool = True, scan: BagScan | None = None,
            adapter: Any = None, **options: Any) -> BagRun:
    """Run the runtime of a gain file over a bag's ``/plant/u`` and ``/plant/y``.

    The runtime comes from the registry (:func:`fd_monitor.core.methods.runtime_for`), so
    every gain-file method runs; the side signals it needs are read from
    ``/plant/<name>`` (:func:`~fd_monitor.wire.topics.side_topic`). The runtime bridges a
    hole in the stamps of at most ``MAX_GAP`` samples (``bridge``) and restarts (``reset``) after a
    longer one.

    Parameters
    ----------
    bag : str or pathlib.Path
        Bag folder.
    gains : str, pathlib.Path or GainFile
        Gain file (name, path, or loaded; its plant is loaded by name when ``system`` is None).
    transient : float
        s, recorded for the summary (alarms before it are not counted).
    system : System, optional
    agei : bool
        ``thresholds`` only: run with the AGEI module (False: the ablation).
    scan : BagScan, optional
        The bag already read once (:func:`scan_bag`); default: read it here, once.
    adapter : Adapter or str, optional
        Read u and y from the robot's topics through this adapter
        (:func:`fd_monitor.wire.adapters.read_adapted`) instead of ``/plant/u``, ``/plant/y``.
    **options
        Further runtime options (:func:`~fd_monitor.core.methods.runtime_for`).

    Raises
    ------
    BagError
        Missing bag or topic (a side signal's topic included).
    GainFileError
        Unknown or invalid gain file.
    """

    if not Path(bag).exists():
        raise BagError(f"{bag}: no such bag")
    if isinstance(gains, GainFile):
        gf = gains
        if system is None:
            system = gain_system(gf)
    elif system is None:
        system, gf = _load_system_for(bag, gains)
    else:
        gf = load_gains(gains, system)
    if not agei:
        options["agei"] = False
    rt = runtime_for(system, gf, **options)
    if scan is None:
        scan = scan_bag(bag)
    truth = scan.truth()
    outs: list[Any] = []
    refused: list[tuple[int, MessageError]] = []
    if adapter is not None:
        if rt.side_inputs:
            raise BagError(f"{bag}: the {gf.method} runtime needs "
                           f"{', '.join(rt.side_inputs)}, which an adapter does not map")
        us, _ys, sides, rep = _adapted_streams(bag, adapter, system,
                                              _runtime_step(rt, system.nu, outs, refused))
        if not us:
            raise BagError(f"{bag}: no valid (u, y) sample")
    else:
        us, _ys, sides, rep = read_streams(bag, system, {n: rt.side_labels[n]
                                                        for n in rt.side_inputs}, scan,
                                          _runtime_step(rt, system.nu, outs, refused))
        if not us:
            raise BagError(f"{bag}: no valid (u, y) sample on {PLANT_U.absolute} and "
                           f"{PLANT_Y.absolute}"
                           + "".join(f" and {_side_topic(n).absolute}" for n in sides))
    if not outs:        # every sample refused by the runtime (implausible): nothing to show
        why = ", ".join(f"{n} {k}" for k, n in rep.sample_counts()["skipped"].items())
        raise BagError(f"{bag}: no usable sample: every one was refused ({why}; e.g. "
                       f"{refused[0][1] if refused else 'see the input errors'})")
    out = _fields(rt, rt.stack(outs, list(rep.restarts), list(rep.bridges)), truth, refused,
                  rep)
    return BagRun(bag=str(bag), gains=str(gf.path), system=system, truth=truth, inputs=rep,
                  transient=float(transient), integrity=integrity(scan, rep), **out)


def _runtime_step(rt: Any, nu: int, outs: list[Any],
                  refused: list[tuple[int, MessageError]]) -> Callable[[Sample], bool]:
    """``step(sample) -> bool`` for :func:`read_streams`: one runtime step on a released
    sample (reset first at a restart, bridged first at a bridge), its output appended to
    ``outs``; an implausible sample is appended to ``refused`` (False: the stream counts it
    lost)."""
    no_u = np.zeros(0)

    def step(s: Sample) -> bool:
        v = s.inputs
        if s.restart:
            rt.reset()
        u, side = v["u"] if nu else no_u, {n: v[n] for n in rt.side_inputs} or None
        try:
            if s.bridge:
                rt.bridge(s.k, u, v["y"], side)
            o = rt.step(s.k, u, v["y"], side)
        except MessageError as exc:
            # an implausible sample is refused like a NaN message (read_streams has already
            # left every other invalid message out)
            if not isinstance(exc, ImplausibleError):
                raise
            refused.append((s.k, exc))
            return False
        outs.append(o)
        return True
    return step


def _adapted_streams(bag: str | Path, adapter: Any, system: Any,
                     step: Callable[[Sample], bool] | None = None
                     ) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray],
                                dict[str, dict[int, np.ndarray]], InputReport]:
    """:func:`read_streams` of a robot's bag through an adapter: the time base's events
    (:func:`~fd_monitor.wire.adapters.read_adapted`) fed, at their log times, into the
    nodes' input policy exactly as the live node feeds them
    (:func:`~fd_monitor.wire.adapters.feed`); gaps, late and bad messages in the report."""

    ad = adapter if isinstance(adapter, Adapter) else load_adapter(adapter)
    s = read_adapted(bag, ad, system=system)
    rep = InputReport(timebase={**s.counts, "sample_time": s.sample_time,
                                "sample_time_note": s.sample_time_note})
    topic_of = {c.name: c.topic for c in (*ad.inputs, *ad.outputs)}
    for kind, line in s.errors:
        rep.errors.append({"kind": kind, "topic": line.split(" ", 1)[0].rstrip(":"),
                           "sample": None, "message": line})
    runs: list[list[Any]] = []                   # gap runs [first, last, reason, channel]
    for k, reason, ch in s.gaps:
        if runs and runs[-1][1] == k - 1 and runs[-1][2:] == [reason, ch]:
            runs[-1][1] = k
        else:
            runs.append([k, k, reason, ch])
    for a, b, reason, ch in runs:
        rep.errors.append({"kind": reason, "topic": topic_of.get(ch, ch), "sample": [a, b],
                           "message": f"samples {a}..{b}: {ch} "
                                      + ("never received" if reason == "no_value" else
                                         "not received within its max_hold")})
    us: dict[int, np.ndarray] = {}
    ys: dict[int, np.ndarray] = {}
    nu = len(s.inputs)
    no_u = np.zeros(0)

    def keep(smp: Sample) -> bool:
        us[smp.k] = smp.inputs["u"] if nu else no_u
        ys[smp.k] = smp.inputs["y"]
        return True if step is None else step(smp)

    refused = {k for k, _r, _c in s.gaps}
    where = [s.clock_topic]
    stream = _policy_stream(["u", "y"] if nu else ["y"], rep, refused, where, keep)
    for now, e in s.events:
        if stream.join.pending or stream.join.held:
            stream.release(now)
        feed(stream, e, now, bool(nu))
    stream.release(math.inf)
    return us, ys, {}, rep


def run_runtime(rt: Any, ks: Sequence[int], us: Any, ys: Any, rep: InputReport,
                side: Any = None, truth: Any = None,
                max_gap: int = MAX_GAP) -> dict[str, Any]:
    """A runtime over samples ``ks`` (``us[k]``, ``ys[k]``, ``side[name][k]``); a hole of at
    most ``max_gap`` samples is bridged, a longer one restarts, as live.

    Returns the per-sample fields of a :class:`BagRun`. A sample the runtime refuses as
    implausible (:mod:`fd_monitor.core.plausibility`) is reported in ``rep`` and left out,
    a lost sample like a hole's. Another invalid sample
    raises :class:`~fd_monitor.model.errors.MessageError` naming its stamp (:func:`read_streams`
    has already left such samples out of a bag).

    Parameters
    ----------
    rt : Runtime
        From :func:`fd_monitor.core.methods.runtime_for` (fresh or reset).
    ks : sequence of int
        Increasing stamps.
    us, ys : mapping
        stamp -> (nu,), stamp -> (ny,).
    rep : InputReport
        Refused samples and restarts are added to it.
    side : mapping, optional
        name -> (stamp -> value) for the runtime's side signals.
    truth : TopicArrays, optional
        ``/plant/truth`` (method-specific figures, e.g. the QB error ellipsoid).
    """
    def refuse(k: int, exc: MessageError) -> None:
        # Implausible samples are refused like a NaN message (a bag's NaN never gets here:
        # read_streams leaves it out); any other invalid sample is the caller's error.
        if not isinstance(exc, ImplausibleError):
            raise exc
        _refused(rep, k, exc)

    tr = rt.run(ks, us, ys, side or None, on_refused=refuse,
                max_gap=max_gap)
    rep.restarts.extend(tr.restarts)
    rep.bridges.extend(tr.bridges)
    return _fields(rt, tr, truth)


def _fields(rt: Any, tr: Any, truth: Any, refused: Sequence[tuple[int, MessageError]] = (),
            rep: InputReport | None = None) -> dict[str, Any]:
    """The per-sample fields of a :class:`BagRun` from a runtime's trace; ``refused``
    samples reported into ``rep``."""
    for k, exc in refused:
        assert rep is not None
        _refused(rep, k, exc)
    iso = tr.estimates.get("isolated")
    return {"method": rt.method, "k": tr.k, "channels": tuple(rt.channels),
            "units": tuple(rt.units), "signal": tr.residual, "threshold": tr.threshold,
            "alarm": tr.alarm, "mode_hat": tr.mode, "estimate": rt.bias_estimates(tr.estimates),
            "isolated": None if iso is None else iso.astype(bool), "outside": tr.outside,
            "region_names": tuple(rt.region_names), "qb": rt.offline_extra(tr, truth),
            "signed": rt.SIGNED, "estimate_kind": rt.ESTIMATE_KIND,
            "traces": dict(tr.estimates), "isolating": tuple(rt.isolating)}


def run_thresholds(system: Any, gf: Any, ks: Sequence[int], us: Any, ys: Any,
                   rep: InputReport, agei: bool = True) -> dict[str, Any]:
    """:func:`run_runtime` with the ``thresholds`` runtime (the diagnosis chain)."""
    return run_runtime(runtime_for(system, gf, agei=agei), ks, us, ys, rep)


def _refused(rep: InputReport, k: int, exc: MessageError) -> None:
    """Report sample k refused by the runtime (implausible) as an input error."""
    rep.errors.append({"kind": _classify(exc), "topic": _UY, "sample": k,
                       "message": str(exc)})
