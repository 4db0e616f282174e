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

The reading itself (one pass, in chunks: census, damage, metadata, labels, the input policy)
is :mod:`fd_monitor.analysis.reader`; here are the runs over it. Why one module of ~640 lines:
running a runtime over a bag's samples (plant topics or an adapter's), reducing its outputs
chunk by chunk and the in-memory form (:func:`run_runtime`) are one pipeline, which the
regression suite compares bit for bit with the live nodes.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.analysis.reader import (
    INPUT_ERROR_KINDS,
    UY,
    BagScan,
    InputReport,
    classify,
    policy_stream,
    read_pass,
    scan_bag,
    stamp_runs,
)
from fd_monitor.analysis.summary import SparseRows
from fd_monitor.core.methods import load_gains, runtime_for
from fd_monitor.model.errors import BagError, ImplausibleError, MessageError
from fd_monitor.model.gains import GainFile
from fd_monitor.model.system import gain_system
from fd_monitor.wire.adapters import (
    AdaptedSample,
    AdaptedStreams,
    Adapter,
    adapted_events,
    feed,
    load_adapter,
)
from fd_monitor.wire.input_checks import integrity
from fd_monitor.wire.join import Sample
from fd_monitor.wire.series import Series
from fd_monitor.wire.stream import MAX_GAP
from fd_monitor.wire.timebase import Gap, NewRun
from fd_monitor.wire.topics import PLANT_U, PLANT_Y
from fd_monitor.wire.topics import side_topic as _side_topic

__all__ = ["BagRun", "BagScan", "INPUT_ERROR_KINDS", "InputReport", "adapted_streams",
           "read_inputs", "read_streams", "run_bag", "run_runtime", "run_thresholds",
           "scan_bag", "stamp_runs"]

#: Samples stepped between two reductions of the runtime's outputs (a RuntimeOutput is
#: ~4 KB: CHUNK of them are the largest thing a run holds).
CHUNK = 1024


def read_inputs(bag: str | Path, system: Any) -> tuple[Series, InputReport]:
    """Read ``/plant/u`` and ``/plant/y`` message by message, keeping the valid ones.

    The nodes' input policy (:func:`read_streams`): a message that does not decode (NaN/Inf,
    wrong length, bad layout) is rejected; the same stamp twice in a row, or a pending stamp
    again, is a duplicate (the first is kept); a stamp lower than the one before it on its
    topic is reported as out of order and joined in stamp order; holes (stamps with no usable
    ``(u, y)`` pair) are reported as missing.

    Returns
    -------
    (Series, InputReport)
        The released samples, and the report (with the restarts).
    """
    return read_streams(bag, system)


def _plant_topics(system: Any, side: dict[str, tuple[str, ...]]
                  ) -> tuple[list[str], dict[str, tuple[str, ...] | None], dict[str, str]]:
    """The joined topics of a plant (y, u when it has inputs, the side signals), their
    labels and join names."""
    t_u, t_y = PLANT_U.absolute, PLANT_Y.absolute
    labels: dict[str, tuple[str, ...] | None] = {t_u: PLANT_U.labels(system),
                                                  t_y: PLANT_Y.labels(system)}
    names = {t_u: "u", t_y: "y"}
    for name, labs in side.items():
        labels[_side_topic(name).absolute] = tuple(labs)
        names[_side_topic(name).absolute] = name
    topics = ([t_y] + ([t_u] if system.nu else [])
              + [_side_topic(n).absolute for n in side])
    return topics, labels, names


def read_streams(bag: str | Path, system: Any,
                 side: dict[str, tuple[str, ...]] | None = None,
                 step: Callable[[Sample], bool] | None = None
                 ) -> tuple[Series, InputReport]:
    """:func:`read_inputs` plus side-signal topics, through the nodes' input policy, in one
    pass over the bag (:func:`fd_monitor.analysis.reader.read_pass`).

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
    step : callable, optional
        ``step(sample) -> bool`` run on each released
        :class:`~fd_monitor.wire.join.Sample` after its values are kept (a runtime step,
        reset first at a restart, bridged first at a bridge); False: the runtime refused it
        (implausible), the sample is lost (the next one bridges or restarts). Default: every
        sample is accepted.

    Returns
    -------
    (Series, InputReport)
        The released samples in release order (``k`` (K,), ``u`` (K, nu), ``y`` (K, ny),
        ``side`` name -> (K, ...); a new run starts again lower), and the report.
    """
    side = dict(side or {})
    topics, labels, names = _plant_topics(system, side)
    rep = InputReport()
    ks: list[int] = []
    cols: dict[str, list[np.ndarray]] = {n: [] for n in ("u", "y", *side)}
    no_u = np.zeros(0)

    def kept(s: Sample) -> bool:
        v = s.inputs
        ks.append(s.k)
        cols["u"].append(v["u"] if system.nu else no_u)
        for n in cols:
            if n != "u":
                cols[n].append(v[n])
        return True if step is None else step(s)

    read_pass(bag, topics, labels, rep, kept, names=names, max_gap=MAX_GAP)
    K = len(ks)

    def stacked(n: str, width: int) -> np.ndarray:
        return np.asarray(cols[n], dtype=float).reshape(K, width) if K else np.zeros((0, width))

    return Series(str(bag), tuple(system.inputs), tuple(system.outputs),
                  np.asarray(ks, dtype=np.int64), stacked("u", system.nu),
                  stacked("y", system.ny), float(system.sample_time),
                  side={n: np.asarray(cols[n]) for n in side}), rep


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
            system: Any = None, agei: bool = True, adapter: Any = None,
            keep: str = "all", checks: Callable[[BagScan], None] | None = None,
            **options: Any) -> BagRun:
    """Run the runtime of a gain file over a bag's ``/plant/u`` and ``/plant/y``.

    The runtime comes from the registry (:func:`fd_monitor.core.methods.runtime_for`), so
    every gain-file method runs; the side signals it needs are read from
    ``/plant/<name>`` (:func:`~fd_monitor.wire.topics.side_topic`). The runtime bridges a
    hole in the stamps of at most ``MAX_GAP`` samples (``bridge``) and restarts (``reset``) after a
    longer one. The bag is read once, in chunks (:func:`fd_monitor.analysis.reader.read_pass`),
    and the runtime's outputs are stacked every :data:`CHUNK` samples into arrays.

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
    adapter : Adapter or str, optional
        Read u and y from the robot's topics through this adapter
        (:func:`fd_monitor.wire.adapters.read_adapted`) instead of ``/plant/u``, ``/plant/y``.
    keep : str
        ``"all"``: every per-sample output (what ``report`` plots); ``"summary"``: only what
        :func:`~fd_monitor.analysis.summary.analyze_run` reads (stamps, mode, alarm flags, the
        rows outside the certified region, the last estimates, the truth's mode: ~30 bytes a
        sample; ``signal``, ``threshold`` and ``traces`` are left empty).
    checks : callable, optional
        ``checks(scan)``: a command's own checks of the bag's census, before the reader's.
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
    refused: list[tuple[int, MessageError]] = []
    red = _Reducer(rt, full=keep == "all")
    step = _runtime_step(rt, system.nu, red, refused)
    if adapter is not None:
        if rt.side_inputs:
            raise BagError(f"{bag}: the {gf.method} runtime needs "
                           f"{', '.join(rt.side_inputs)}, which an adapter does not map")
        scan = read_pass(bag, [], {}, InputReport(),
                         truth=True if keep == "all" else ("mode",))
        rep = adapted_streams(bag, adapter, system=system, step=step)[1]
        truth = scan.truth
        if not rep.used and not refused:
            raise BagError(f"{bag}: no valid (u, y) sample")
    else:
        side = {n: rt.side_labels[n] for n in rt.side_inputs}
        topics, labels, names = _plant_topics(system, side)
        rep = InputReport()
        scan = read_pass(bag, topics, labels, rep, step, names=names, max_gap=MAX_GAP,
                         truth=True if keep == "all" else ("mode",), checks=checks)
        truth = scan.truth
        if not rep.used and not refused:
            raise BagError(f"{bag}: no valid (u, y) sample on {PLANT_U.absolute} and "
                           f"{PLANT_Y.absolute}"
                           + "".join(f" and {_side_topic(n).absolute}" for n in side))
    if not rep.used:        # every sample refused by the runtime (implausible): nothing to show
        why = ", ".join(f"{n} {k}" for k, n in rep.sample_counts()["skipped"].items())
        raise BagError(f"{bag}: no usable sample: every one was refused ({why}; e.g. "
                       f"{refused[0][1] if refused else 'see the input errors'})")
    for k, exc in refused:                   # reported after the stream's own reports
        _refused(rep, k, exc)
    fields = red.fields(truth, rep)
    return BagRun(bag=str(bag), gains=str(gf.path), system=system, truth=truth, inputs=rep,
                  transient=float(transient), integrity=integrity(scan, rep), **fields)


class _Reducer:
    """A runtime's outputs, stacked every :data:`CHUNK` samples into arrays: all of them
    (``full``), or only what ``analyze`` reads (the ``summary`` of :func:`run_bag`)."""

    def __init__(self, rt: Any, full: bool = True) -> None:
        self.rt, self.full = rt, full
        self.outs: list[Any] = []
        self.parts: list[Any] = []               # full: RuntimeTrace per chunk
        self.k: list[np.ndarray] = []
        self.mode: list[np.ndarray] = []
        self.alarm: list[np.ndarray] = []
        self.nz_index: list[np.ndarray] = []
        self.nz_rows: list[np.ndarray] = []
        self.n = 0
        self.last: dict[str, np.ndarray] = {}

    def append(self, out: Any) -> None:
        self.outs.append(out)
        if len(self.outs) >= CHUNK:
            self.flush()

    def flush(self) -> None:
        outs = self.outs
        if not outs:
            return
        tr = self.rt.stack(outs, [], [])
        self.outs = []
        if self.full:
            self.parts.append(tr)
            return
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
        self.n += len(tr.k)

    def fields(self, truth: Any, rep: InputReport) -> dict[str, Any]:
        """The per-sample fields of a :class:`BagRun`."""
        self.flush()
        rt = self.rt
        if self.full:
            tr = _concat(rt, self.parts, list(rep.restarts), list(rep.bridges))
            self.parts = []
            return _fields(rt, tr, truth)
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
        return {"method": rt.method, "k": k, "channels": tuple(rt.channels),
                "units": tuple(rt.units), "signal": np.zeros((0, m)),
                "threshold": np.zeros((0, m)), "alarm": alarm, "mode_hat": mode,
                "estimate": rt.bias_estimates(self.last),
                "isolated": None if iso is None else iso.astype(bool), "outside": outside,
                "region_names": tuple(rt.region_names), "qb": {}, "signed": rt.SIGNED,
                "estimate_kind": rt.ESTIMATE_KIND, "traces": {},
                "isolating": tuple(rt.isolating)}


def _concat(rt: Any, parts: list[Any], restarts: list[int], bridges: list[int]) -> Any:
    """One :class:`~fd_monitor.core.runtime.RuntimeTrace` of chunks stacked by
    :meth:`~fd_monitor.core.runtime.Runtime.stack` (the arrays ``stack`` gives for all
    outputs at once: an estimate takes the dtype of its first appearance, zeros where a
    chunk has none)."""
    if len(parts) == 1:
        tr = parts[0]
        tr.restarts, tr.bridges = restarts, bridges
        return tr
    if not parts:
        return rt.stack([], restarts, bridges)
    est: dict[str, np.ndarray] = {}
    names = list(dict.fromkeys(n for p in parts for n in p.estimates))
    for name in names:
        ref = next(p.estimates[name] for p in parts if name in p.estimates)
        est[name] = np.concatenate([
            p.estimates[name].astype(ref.dtype, copy=False) if name in p.estimates
            else np.zeros((len(p.k), *ref.shape[1:]), ref.dtype) for p in parts])
    outside = (None if parts[0].outside is None
               else np.concatenate([p.outside for p in parts]))
    tr = type(parts[0])(np.concatenate([p.k for p in parts]),
                        np.concatenate([p.residual for p in parts]),
                        np.concatenate([p.threshold for p in parts]),
                        np.concatenate([p.alarm for p in parts]), outside,
                        np.concatenate([p.mode for p in parts]), est, restarts, bridges)
    return tr


def _runtime_step(rt: Any, nu: int, outs: _Reducer,
                  refused: list[tuple[int, MessageError]]) -> Callable[[Sample], bool]:
    """``step(sample) -> bool`` for :func:`~fd_monitor.analysis.reader.read_pass`: one
    runtime step on a released sample (reset first at a restart, bridged first at a bridge),
    its output appended to ``outs``; an implausible sample is appended to ``refused`` (False:
    the stream counts it lost)."""
    no_u = np.zeros(0)
    side_names = tuple(rt.side_inputs)
    rt_step, append = rt.step, outs.append

    def step(s: Sample) -> bool:
        v = s.inputs
        if s.restart:
            rt.reset()
        u = v["u"] if nu else no_u
        side = {n: v[n] for n in side_names} if side_names else None
        try:
            if s.bridge:
                rt.bridge(s.k, u, v["y"], side)
            o = rt_step(s.k, u, v["y"], side)
        except MessageError as exc:
            # an implausible sample is refused like a NaN message (read_streams has already
            # left every other invalid message out)
            if not isinstance(exc, ImplausibleError):
                raise
            refused.append((s.k, exc))
            return False
        append(o)
        return True
    return step


def adapted_streams(bag: str | Path, adapter: Any, *, system: Any = None,
                    sample_time: float | None = None,
                    step: Callable[[Sample], bool] | None = None, keep: bool = False
                    ) -> tuple[Any, InputReport]:
    """:func:`read_streams` of a robot's bag through an adapter (``analyze --adapter``,
    ``report --adapter``, ``identify --adapter``): the time base's events
    (:func:`~fd_monitor.wire.adapters.adapted_events`, read in bounded memory) fed, at their
    log times, into the nodes' input policy exactly as the live node feeds them
    (:func:`~fd_monitor.wire.adapters.feed`); gaps, late and bad messages in the report,
    every released sample to ``step``.

    Returns
    -------
    (AdaptedStreams or AdaptedRun, InputReport)
        With ``keep`` the adapter's samples (:class:`~fd_monitor.wire.adapters.
        AdaptedStreams`, as :func:`~fd_monitor.wire.adapters.read_adapted`), else the run's
        sample time, notes and counts only; and what the policy and the adapter did not use
        (with :func:`~fd_monitor.wire.input_checks.integrity` of the bag's census: the
        contract's record).
    """

    ad = adapter if isinstance(adapter, Adapter) else load_adapter(adapter)
    run = adapted_events(bag, ad, sample_time, system)
    ad = run.adapter
    nu = len(ad.inputs)
    policy = InputReport()                       # the policy's reports, after the adapter's
    refused: set[int] = set()                    # samples the time base could not fill
    gaps: list[tuple[int, str, str]] = []
    kept: list[tuple[float, Any]] = []
    stream = policy_stream(["u", "y"] if nu else ["y"], policy, refused, [ad.clock_topic],
                           step or (lambda _s: True))
    for now, e in run.events:
        if keep:
            kept.append((now, e))
        if isinstance(e, Gap):
            gaps.append((e.k, e.reason, e.channel))
            refused.add(e.k)
        if stream.join.pending or stream.join.held:
            stream.release(now)
        feed(stream, e, now, bool(nu))
    stream.release(math.inf)
    rep = InputReport(timebase={**run.counts, "sample_time": run.sample_time,
                                "sample_time_note": run.note},
                      restarts=policy.restarts, bridges=policy.bridges, used=policy.used)
    topic_of = {c.name: c.topic for c in (*ad.inputs, *ad.outputs)}
    for kind, line in run.errors:
        rep.errors.append({"kind": kind, "topic": line.split(" ", 1)[0].rstrip(":"),
                           "sample": None, "message": line})
    runs: list[list[Any]] = []                   # gap runs [first, last, reason, channel]
    for k, reason, ch in gaps:
        if runs and runs[-1][1] == k - 1 and runs[-1][2:] == [reason, ch]:
            runs[-1][1] = k
        else:
            runs.append([k, k, reason, ch])
    for a, b, reason, ch in runs:
        rep.errors.append({"kind": reason, "topic": topic_of.get(ch, ch), "sample": [a, b],
                           "message": f"samples {a}..{b}: {ch} "
                                      + ("never received" if reason == "no_value" else
                                         "not received within its max_hold")})
    rep.errors += policy.errors
    if not keep:
        return run, rep
    samples = [e for _, e in kept if isinstance(e, AdaptedSample)]
    t0 = samples[0].t_ns
    return AdaptedStreams(
        str(bag), tuple(c.name for c in ad.inputs), tuple(c.name for c in ad.outputs),
        np.array([s.k for s in samples], dtype=np.int64),
        np.array([s.u for s in samples]).reshape(len(samples), nu),
        np.array([s.y for s in samples]).reshape(len(samples), len(ad.outputs)),
        run.sample_time, np.array([(s.t_ns - t0) * 1e-9 for s in samples]), ad.clock_topic,
        run.errors, gaps, [e.k for _, e in kept if isinstance(e, NewRun)], run.counts,
        run.note, kept), rep


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


def _fields(rt: Any, tr: Any, truth: Any) -> dict[str, Any]:
    """The per-sample fields of a :class:`BagRun` from a runtime's trace."""
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
    rep.errors.append({"kind": classify(exc), "topic": UY, "sample": k,
                       "message": str(exc)})
