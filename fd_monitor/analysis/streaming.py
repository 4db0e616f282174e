"""``analyze`` of a bag in bounded memory: read, decode, step and reduce in chunks.

:func:`fd_monitor.analysis.offline.run_bag` keeps every record, every decoded message and
every per-sample runtime output before stacking them (a :class:`~fd_monitor.analysis.offline.
BagRun` for the figures of ``report``): about 4.4 KB per sample. ``analyze`` needs much
less, and :func:`analyze_streaming` gives the same document with

* :func:`census` -- one pass over the bag that keeps only each topic's type and count
  (:attr:`StreamScan.present`: what ``analyze`` checks before it starts);
* one more pass, records decoded in batches straight from their CDR bytes
  (:class:`~fd_monitor.wire.conversions.RawDecoder`: :func:`~fd_monitor.wire.conversions.
  decode`'s results and errors without building a message object) and pushed through the
  nodes' input policy exactly as :func:`~fd_monitor.analysis.offline.read_streams` does;
* the runtime's outputs stacked every :data:`CHUNK` samples and reduced at once to what the
  summary reads: the stamps, the mode, the alarm flags (8 + 8 + m bytes a sample), the rows
  where the run was outside the certified region (:class:`~fd_monitor.analysis.summary.
  SparseRows`), the last estimates; the truth's stamps and mode (16 bytes a sample, bags with
  ``/plant/truth``).

So ``analyze`` of a bag of 10^6 samples peaks at 145 MB (the interpreter and its imports
included; the bag reader also drops the pages it has read, :mod:`fd_monitor.wire.bags`)
instead of 4.4 GB (``benchmarks/bench_fleet.py``).
The document is :func:`~fd_monitor.analysis.summary.analyze_run`'s, bit for bit
(``test/test_streaming.py`` on every bag of the library).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.analysis.offline import (
    _UY,
    BagRun,
    InputReport,
    _bag_errors,
    _classify,
    _policy_stream,
    _refused,
    _runtime_step,
)
from fd_monitor.analysis.summary import SparseRows, analyze_run
from fd_monitor.core.methods import runtime_for
from fd_monitor.model.errors import BagError, MessageError
from fd_monitor.wire.bags import TopicArrays, _deserialize, messages_from_raw, read_raw
from fd_monitor.wire.conversions import ArrivalStamper, RawDecoder, readable_stamp
from fd_monitor.wire.stream import MAX_GAP, TopicOrder
from fd_monitor.wire.topics import FLOAT64_MULTI_ARRAY, PLANT_TRUTH, PLANT_U, PLANT_Y
from fd_monitor.wire.topics import side_topic as _side_topic

__all__ = ["CHUNK", "StreamScan", "analyze_streaming", "census"]

#: Records decoded per batch, and samples stepped between two reductions of the runtime's
#: outputs (a RuntimeOutput is ~4 KB: 1024 of them are the largest thing held).
CHUNK = 1024


@dataclass
class StreamScan:
    """What :func:`census` read of a bag: every topic's type and readable-message count
    (no message kept).

    Attributes
    ----------
    bag : str
    present : dict
        topic -> (message type, number of readable messages).
    """

    bag: str
    present: dict[str, tuple[str, int]]

    def first_labels(self, topic: str) -> tuple[str, ...] | None:
        """As :meth:`fd_monitor.analysis.offline.BagScan.first_labels` (reads up to the
        topic's first message)."""
        if topic in self.present and self.present[topic][0] != FLOAT64_MULTI_ARRAY:
            raise BagError(f"{self.bag}: {topic} is {self.present[topic][0]}, not "
                           f"{FLOAT64_MULTI_ARRAY}")
        if topic not in self.present:
            return None
        with _bag_errors(self.bag):
            for _topic, _t, msg in messages_from_raw(self.bag, read_raw(self.bag, [topic])):
                dims = msg.layout.dim
                return tuple(dims[0].label.split(",")) if dims and dims[0].label else None
        return None


def census(bag: str | Path) -> StreamScan:
    """Read a bag once, keeping each topic's type and count (BagError as
    :func:`~fd_monitor.analysis.offline.scan_bag`)."""
    if not Path(bag).exists():
        raise BagError(f"{bag}: no such bag")
    present: dict[str, tuple[str, int]] = {}
    with _bag_errors(bag):
        for topic, ty, _t, _raw in read_raw(bag):
            got = present.get(topic)
            present[topic] = (ty, 1 if got is None else got[1] + 1)
    return StreamScan(str(bag), present)


class _Truth:
    """``/plant/truth``'s stamps and mode column, read record by record as
    :meth:`~fd_monitor.analysis.offline.BagScan.truth` reads them (None: a message that does
    not decode -- the whole truth is then unused, as there)."""

    def __init__(self, bag: str) -> None:
        self.bag = bag
        self.labels: tuple[str, ...] | None = None
        self.col: int | None = None
        self.dec: RawDecoder | None = None
        self.stamper = ArrivalStamper()
        self.stamps: list[np.ndarray] = []
        self.modes: list[np.ndarray] = []
        self._k: list[int] = []
        self._m: list[float] = []
        self.bad = False

    def add(self, ty: str, raw: bytes) -> None:
        if self.bad:
            return
        try:
            if self.dec is None:
                first = RawDecoder(lambda r: _deserialize(r, ty), PLANT_TRUTH.absolute,
                                   allow_nan=True, allow_inf=True).decode(raw)
                # unlabelled: the channels are named by position, as read_bag names them
                self.labels = first.labels or tuple(str(i) for i in range(first.values.size))
                self.col = self.labels.index("mode") if "mode" in self.labels else None
                self.dec = RawDecoder(lambda r: _deserialize(r, ty), PLANT_TRUTH.absolute,
                                      labels=self.labels, allow_nan=True, allow_inf=True)
            d = self.stamper.stamp(self.dec.decode(raw))
        except Exception:          # MessageError, or CDR rosbags cannot read: truth unused
            self.bad = True
            return
        self._k.append(int(d.stamp or 0))
        self._m.append(float(d.values[self.col]) if self.col is not None else math.nan)
        if len(self._k) >= CHUNK:
            self._flush()

    def _flush(self) -> None:
        if self._k:
            self.stamps.append(np.asarray(self._k, dtype=np.int64))
            # float32 holds a mode index (and NaN) exactly, in half the memory
            m = np.asarray(self._m, dtype=float)
            exact = np.array_equal(m.astype(np.float32), m, equal_nan=True)
            self.modes.append(m.astype(np.float32) if exact else m)
            self._k, self._m = [], []

    def arrays(self) -> TopicArrays | None:
        """The truth's ``mode`` column as TopicArrays (None: absent, unreadable, no mode)."""
        self._flush()
        if self.bad or self.labels is None or self.col is None:
            return None
        k = np.concatenate(self.stamps) if self.stamps else np.zeros(0, np.int64)
        m = (np.concatenate(self.modes) if self.modes else np.zeros(0)).astype(float, copy=False)
        self.stamps, self.modes = [], []         # one copy, not two
        return TopicArrays(PLANT_TRUTH.absolute, ("mode",), k, m.reshape(-1, 1),
                           np.zeros(0, np.int64))


class _Reducer:
    """The runtime's outputs, chunk by chunk, reduced to what ``analyze`` reads."""

    def __init__(self, rt: Any) -> None:
        self.rt = rt
        self.k: list[np.ndarray] = []
        self.mode: list[np.ndarray] = []
        self.alarm: list[np.ndarray] = []
        self.nz_index: list[np.ndarray] = []
        self.nz_rows: list[np.ndarray] = []
        self.n = 0
        self.last: dict[str, np.ndarray] = {}

    def add(self, outs: list[Any]) -> None:
        if not outs:
            return
        tr = self.rt.stack(outs, [], [])
        self.k.append(tr.k)
        # a mode index is small: int32 halves what a long run keeps (the values are equal)
        self.mode.append(tr.mode.astype(np.int32) if tr.mode.size and
                         int(np.abs(tr.mode).max()) < 2 ** 31 else tr.mode)
        self.alarm.append(tr.alarm.copy())       # alone: not a view of a larger block
        if tr.outside is not None:
            hit = np.flatnonzero(np.any(tr.outside != 0.0, axis=1))
            self.nz_index.append(hit + self.n)
            self.nz_rows.append(tr.outside[hit].copy())
        # copies: a view would keep the chunk's whole arrays
        self.last = {name: v[-1:].copy() for name, v in tr.estimates.items()}
        self.n += len(outs)
        outs.clear()

    def run(self, bag: str, gains: Any, system: Any, truth: Any, rep: InputReport
            ) -> BagRun:
        """A :class:`BagRun` with only what :func:`analyze_run` reads: the per-sample signals,
        thresholds and traces are not kept (zero rows)."""
        rt = self.rt
        m = len(rt.channels)
        iso = self.last.get("isolated")
        outside: Any = None                      # SparseRows (region_mark reads it as dense)
        if rt.region_names:
            r = len(rt.region_names)
            outside = SparseRows(
                np.concatenate(self.nz_index) if self.nz_index else np.zeros(0, np.int64),
                np.concatenate(self.nz_rows) if self.nz_rows else np.zeros((0, r)),
                self.n, r)
        k, alarm, mode = (np.concatenate(x) for x in (self.k, self.alarm, self.mode))
        self.k, self.alarm, self.mode = [], [], []          # one copy, not two
        return BagRun(bag=bag, method=rt.method, gains=str(gains.path), system=system,
                      k=k, channels=tuple(rt.channels),
                      units=tuple(rt.units), signal=np.zeros((0, m)),
                      threshold=np.zeros((0, m)), alarm=alarm, mode_hat=mode,
                      estimate=rt.bias_estimates(self.last),
                      isolated=None if iso is None else iso.astype(bool), truth=truth,
                      inputs=rep, outside=outside, region_names=tuple(rt.region_names),
                      signed=rt.SIGNED, estimate_kind=rt.ESTIMATE_KIND,
                      isolating=tuple(rt.isolating))


def _batches(it: Iterator[Any], n: int) -> Iterator[tuple[Any, ...]]:
    while True:
        got = tuple(itertools.islice(it, n))
        if not got:
            return
        yield got


def analyze_streaming(bag: str | Path, gains: Any, system: Any, agei: bool = True,
                      scan: StreamScan | None = None) -> dict[str, Any]:
    """:func:`~fd_monitor.analysis.summary.analyze_run` of
    :func:`~fd_monitor.analysis.offline.run_bag` (``/plant/u``, ``/plant/y`` and the side
    signals; no adapter), in memory that grows by about 40 bytes a sample.

    Parameters
    ----------
    bag : str or pathlib.Path
    gains : GainFile
        Loaded and verified.
    system : System
        The gain file's plant.
    agei : bool
        ``thresholds`` only (False: the ablation without AGEI).
    scan : StreamScan, optional
        :func:`census` of the bag (default: read it now).

    Raises
    ------
    BagError
        As :func:`~fd_monitor.analysis.offline.run_bag`.
    """
    bag = str(bag)
    if not Path(bag).exists():
        raise BagError(f"{bag}: no such bag")
    rt = runtime_for(system, gains, **({} if agei else {"agei": False}))
    if scan is None:
        scan = census(bag)
    side = {n: rt.side_labels[n] for n in rt.side_inputs}
    t_u, t_y, t_truth = PLANT_U.absolute, PLANT_Y.absolute, PLANT_TRUTH.absolute
    labels = {t_u: PLANT_U.labels(system), t_y: PLANT_Y.labels(system)}
    names = {t_u: "u", t_y: "y"}
    for name, labs in side.items():
        labels[_side_topic(name).absolute] = tuple(labs)
        names[_side_topic(name).absolute] = name
    topics = [t_y] + ([t_u] if system.nu else []) + [_side_topic(n).absolute for n in side]
    present = scan.present
    missing = [t for t in topics if t not in present]
    if missing:
        raise BagError(f"{bag}: no topic {', '.join(missing)} in the bag (topics: "
                       f"{', '.join(sorted(present)) or 'none'})")
    for t in topics:
        if present[t][0] != FLOAT64_MULTI_ARRAY:
            raise BagError(f"{bag}: {t} is recorded as {present[t][0]}, expected "
                           f"{FLOAT64_MULTI_ARRAY}")
    truth = _Truth(bag) if present.get(t_truth, ("", 0))[0] == FLOAT64_MULTI_ARRAY else None

    rep = InputReport()
    outs: list[Any] = []
    refused: list[tuple[int, MessageError]] = []
    red = _Reducer(rt)
    step1 = _runtime_step(rt, system.nu, outs, refused)

    def step(s: Any) -> bool:
        ok = step1(s)
        if len(outs) >= CHUNK:
            red.add(outs)
        return ok

    bad_stamps: set[int] = set()                 # stamps of messages that did not decode
    where = [_UY]
    stream = _policy_stream([names[t] for t in topics], rep, bad_stamps, where, step, MAX_GAP)
    join = stream.join
    orders = {t: TopicOrder(t) for t in topics}
    now_rec: list[Any] = [None, 0]               # the record being decoded (for errors)

    def unreadable(raw: bytes) -> Any:
        topic, t = now_rec
        try:
            return _deserialize(raw, FLOAT64_MULTI_ARRAY)
        except Exception as exc:  # rosbags raises assorted errors (as messages_from_raw)
            raise BagError(f"{bag}: {topic} at {t * 1e-9:.3f} s: not a valid "
                           f"{FLOAT64_MULTI_ARRAY} ({type(exc).__name__})") from None

    decoders = {t: RawDecoder(unreadable, t, labels=labels[t], require_stamp=True)
                for t in topics}
    wanted = set(topics)
    with _bag_errors(bag):
        for batch in _batches(read_raw(bag), CHUNK):
            # decode a batch, then join it (decoding interleaved with the runtime's steps is
            # slower, offline.py; a batch keeps memory bounded)
            decoded: list[tuple[str, float, Any, int | None]] = []
            for topic, ty, t_ns, raw in batch:
                if topic in wanted:
                    now_rec[0], now_rec[1] = topic, t_ns
                    dec = decoders[topic]
                    try:
                        decoded.append((topic, t_ns * 1e-9, dec.decode(raw), None))
                    except MessageError as exc:
                        decoded.append((topic, t_ns * 1e-9, exc,
                                        readable_stamp(dec.message(raw))))
                elif topic == t_truth and truth is not None:
                    truth.add(ty, raw)
            for topic, now, d, k in decoded:
                if join.pending or join.held:    # what is due by this record's time
                    where[0] = _UY
                    stream.release(now)
                where[0] = topic
                if isinstance(d, MessageError):
                    rep.errors.append({"kind": _classify(d), "topic": topic, "sample": k,
                                       "message": str(d)})
                    if k is not None:
                        bad_stamps.add(k)
                    stream.refused(k, now)
                    continue
                stream.stamped(orders[topic], names[topic], int(d.stamp or 0), d.values, now)
        where[0] = _UY
        stream.release(math.inf)                 # the end of the bag: every wait is over
    red.add(outs)
    if red.n == 0:
        raise BagError(f"{bag}: no valid (u, y) sample on {t_u} and {t_y}"
                       + "".join(f" and {_side_topic(n).absolute}" for n in side))
    for k_ref, why in refused:                   # as run_bag reports them: after the stream
        _refused(rep, k_ref, why)
    run = red.run(bag, gains, system, None if truth is None else truth.arrays(), rep)
    return analyze_run(run)
