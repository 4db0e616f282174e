"""One result summary: what a monitor's outputs over a run say, wherever they come from.

A run's per-sample outputs (:class:`Outputs`: alarm flags per channel, the estimated mode,
the final estimates, isolation flags, restarts) come from an offline run
(:func:`outputs_of_run`, of :func:`fd_monitor.analysis.offline.run_bag`) or from what the live
nodes recorded (:func:`recorded_outputs`); :func:`summarize` reduces them the same way for
``analyze`` (:func:`analyze_run`), the bag report, the library checks
(:func:`summarize_run`), the demo and the live regression tests. What the bag's
``/plant/truth`` says (fault onsets, true biases, true modes) is :func:`truth_facts`.

Nothing here imports rclpy.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.core.envelope import describe_excess
from fd_monitor.wire.bag_reader import read_bag
from fd_monitor.wire.topics import ALARM, BIAS_ESTIMATE, PLANT_TRUTH, STATE_ESTIMATE

__all__ = ["Outputs", "SparseRows", "analyze_run", "collapse", "episodes", "first_alarms",
           "mode_tracking", "outputs_of_run", "region_mark",
           "read_bag_truth", "recorded_outputs", "segments", "settled_modes", "summarize",
           "summarize_run", "transitions", "true_biases", "truth_at", "truth_facts"]


# --------------------------------------------------------------------------------------
# per-sample reductions


def episodes(flags: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index pairs of the True runs of a 1-D bool array."""
    f = np.concatenate([[False], np.asarray(flags, bool), [False]]).astype(int)
    d = np.diff(f)
    return list(zip(np.flatnonzero(d == 1).tolist(), (np.flatnonzero(d == -1) - 1).tolist()))


def collapse(seq: Sequence[Any]) -> list[Any]:
    """``seq`` with repeats in a row collapsed (``a a b a`` -> ``a b a``)."""
    out: list[Any] = []
    for s in seq:
        if not out or out[-1] != s:
            out.append(s)
    return out


def segments(ks: Sequence[int] | np.ndarray, modes: Sequence[str]) -> list[list[Any]]:
    """``[[mode, first_sample, samples], ...]``: runs of one mode."""
    out: list[list[Any]] = []
    for k, m in zip(ks, modes):
        if out and out[-1][0] == m:
            out[-1][2] += 1
        else:
            out.append([m, int(k), 1])
    return out


def settled_modes(segs: Sequence[Sequence[Any]], min_dwell: int) -> list[str]:
    """Mode sequence without the runs shorter than ``min_dwell`` samples (but the first).

    Chatter of a mode predictor at a guard (QB eq. 13b from a noisy estimate) produces runs of
    a few samples; dropping them and collapsing repeats gives the settled sequence.
    """
    kept = [str(s[0]) for i, s in enumerate(segs) if i == 0 or int(s[2]) >= min_dwell]
    return collapse(kept)


def transitions(k: np.ndarray, modes: np.ndarray, names: Sequence[str],
                dt: float) -> list[dict[str, Any]]:
    """``{sample, time, from, to}`` of every change of ``modes`` (K,) (mode indices)."""
    out = []
    for j in np.nonzero(np.diff(modes) != 0)[0] + 1:
        a, b = int(modes[j - 1]), int(modes[j])
        out.append({"sample": int(k[j]), "time": float(k[j] * dt),
                    "from": names[a] if 0 <= a < len(names) else str(a),
                    "to": names[b] if 0 <= b < len(names) else str(b)})
    return out


def mode_tracking(q: np.ndarray, q_hat: np.ndarray, dt: float) -> dict[str, Any]:
    """How the estimated mode follows the true one.

    A true transition to mode m is tracked when the estimated mode becomes m before the
    plant's next transition; the delay is how long that took.

    Parameters
    ----------
    q, q_hat : numpy.ndarray
        (K,) true and estimated mode indices (the shorter length is used).
    dt : float
        Sample time, s.

    Returns
    -------
    dict
        ``true`` (transitions), ``tracked``, ``max_delay_s`` (None when none tracked),
        ``mode_agreement`` (fraction of samples, 4 decimals).
    """
    n = min(len(q), len(q_hat))
    changes = [int(k) for k in np.flatnonzero(np.diff(q[:n]) != 0) + 1]
    delays = []
    for i, k in enumerate(changes):
        end = changes[i + 1] if i + 1 < len(changes) else n
        same = np.flatnonzero(q_hat[k:end] == q[k])
        if same.size:
            delays.append(float(same[0] * dt))
    agree = float(np.mean(q_hat[:n] == q[:n])) if n else 0.0
    return {"true": len(changes), "tracked": len(delays),
            "max_delay_s": round(max(delays), 6) if delays else None,
            "mode_agreement": round(agree, 4)}


def first_alarms(k: np.ndarray, alarm: np.ndarray, channels: Sequence[str], dt: float,
                 transient: float = 0.0) -> list[dict[str, Any]]:
    """First alarm per channel at or after ``transient`` s: ``{channel, first_sample, time}``.

    Parameters
    ----------
    k : numpy.ndarray
        (K,) sample stamps.
    alarm : numpy.ndarray
        (K, m) bool, columns ``channels``.
    dt : float
        Sample time, s.
    """
    k_tr = round(transient / dt)
    out = []
    for i, c in enumerate(channels):
        hits = np.flatnonzero(alarm[:, i] & (k >= k_tr))
        if hits.size:
            s = int(k[hits[0]])
            out.append({"channel": c, "first_sample": s, "time": round(s * dt, 9)})
    return out


# --------------------------------------------------------------------------------------
# the summary


@dataclass
class Outputs:
    """A monitor's outputs over one run, per sample.

    Attributes
    ----------
    k : numpy.ndarray
        (K,) sample stamps.
    dt : float
        Sample time, s.
    channels : tuple of str
        Alarm channels.
    alarm : numpy.ndarray
        (K, m) bool.
    mode : numpy.ndarray
        (K,) estimated mode index.
    mode_names : tuple of str
    estimate : dict
        name -> (K,) estimate (bias estimates; may be empty).
    isolated : numpy.ndarray or None
        (K, len(isolation_channels)) bool isolation flags; None: a channel whose alarm
        isolates (``isolating``) is isolated once it alarmed.
    isolation_channels : tuple of str
        Names of the columns of ``isolated``.
    isolating : tuple of str
        Channels whose alarm isolates the fault they are named after (no isolation flags).
    restarts : list of int
        Samples where the monitor restarted after a hole.
    bridges : list of int
        Samples where the monitor bridged a hole (its memory kept).
    """

    k: np.ndarray
    dt: float
    channels: tuple[str, ...]
    alarm: np.ndarray
    mode: np.ndarray
    mode_names: tuple[str, ...]
    estimate: dict[str, np.ndarray] = field(default_factory=dict)
    isolated: np.ndarray | None = None
    isolation_channels: tuple[str, ...] = ()
    isolating: tuple[str, ...] = ()
    restarts: list[int] = field(default_factory=list)
    bridges: list[int] = field(default_factory=list)


def summarize(out: Outputs, transient: float = 0.0) -> dict[str, Any]:
    """The summary of a run's outputs.

    Returns
    -------
    dict
        ``samples``, ``alarms`` (first alarm per channel after the transient,
        :func:`first_alarms`), ``isolated`` (channels flagged at the last sample, or the
        isolating channels that alarmed), ``bias_estimate`` (``{name: final value}``),
        ``modes`` (estimated mode names, repeats collapsed), ``mode_segments``
        (:func:`segments`), ``restarts``, ``bridges``.
    """
    alarms = first_alarms(out.k, out.alarm, out.channels, out.dt, transient)
    if out.isolated is not None and len(out.k):
        isolated = [c for c, f in zip(out.isolation_channels, out.isolated[-1]) if f]
    else:
        isolated = [a["channel"] for a in alarms if a["channel"] in out.isolating]
    names = [out.mode_names[int(q)] for q in out.mode]
    return {"samples": len(out.k), "alarms": alarms, "isolated": isolated,
            "bias_estimate": {n: float(v[-1]) for n, v in out.estimate.items()},
            "modes": collapse(names), "mode_segments": segments(out.k, names),
            "restarts": list(out.restarts), "bridges": list(out.bridges)}


def outputs_of_run(run: Any) -> Outputs:
    """The :class:`Outputs` of an offline run (:class:`fd_monitor.analysis.offline.BagRun`)."""
    sys_ = run.system
    return Outputs(k=run.k, dt=float(sys_.sample_time), channels=tuple(run.channels),
                   alarm=run.alarm, mode=run.mode_hat, mode_names=tuple(sys_.mode_names),
                   estimate=dict(run.estimate), isolated=run.isolated,
                   isolation_channels=tuple(sys_.outputs), isolating=tuple(run.isolating),
                   restarts=list(run.inputs.restarts), bridges=list(run.inputs.bridges))


@dataclass
class SparseRows:
    """A (n_rows, width) array that is zero but at rows ``index`` (the runtime's ``outside``
    of a long run, kept by :func:`fd_monitor.analysis.offline.run_bag` for ``analyze``: a
    run is mostly inside its region). :func:`region_mark` reads it as it reads the dense array.

    Attributes
    ----------
    index : numpy.ndarray
        (p,) ascending row indices of the non-zero rows.
    rows : numpy.ndarray
        (p, width) those rows.
    n_rows, width : int
    """

    index: np.ndarray
    rows: np.ndarray
    n_rows: int
    width: int

    def worst(self, lo: int, hi: int) -> tuple[bool, int]:
        """Whether rows ``lo..hi-1`` have a non-zero one, and the first row of the largest
        ``max |row|`` among them (``np.argmax`` of the dense slice: ``lo`` when all zero)."""
        i, j = np.searchsorted(self.index, [lo, hi])
        if i == j:
            return False, lo
        m = int(np.argmax(np.abs(self.rows[i:j]).max(axis=1)))
        return True, int(self.index[i + m])

    def row(self, r: int) -> np.ndarray:
        """(width,) row ``r``."""
        i = int(np.searchsorted(self.index, r))
        if i < len(self.index) and int(self.index[i]) == r:
            return np.array(self.rows[i])
        return np.zeros(self.width)


def region_mark(outside: np.ndarray | SparseRows, starts: np.ndarray, a: int, b: int
                ) -> tuple[bool, np.ndarray, int]:
    """Whether the alarm episode of samples ``a..b`` lies outside the certified region.

    A gain file's fault-free guarantee holds for a run that stays inside its region, and the
    monitor carries an excursion in its memory until it restarts (the residual filter's window,
    the estimated mode, a bias estimate started by an alarm raised outside the region; the
    campaign of doc/theory/thresholds.md shows alarms 200 s after the plant came back
    inside, from a 1.5 mm bias estimate started outside). So the episode is outside when the
    region was left at any sample from the run's last (re)start up to ``b``.

    Parameters
    ----------
    outside : numpy.ndarray
        (K, r) signed excess per sample (0 inside), the runtime's ``outside``.
    starts : numpy.ndarray
        Sample indices (into ``outside``) where the monitor restarted, ascending.
    a, b : int
        First and last sample index of the episode.

    Returns
    -------
    outside : bool
    worst : numpy.ndarray
        (r,) the largest excess during the episode, or, when the episode itself is inside,
        before it since the (re)start (zeros when never outside).
    at : int
        Sample index of ``worst``.
    """
    s0 = int(starts[np.searchsorted(starts, a, side="right") - 1]) if np.any(starts <= a) else 0
    if isinstance(outside, SparseRows):          # the same answer from the non-zero rows
        hit, at = outside.worst(a, b + 1)
        if not hit:
            before, at_b = outside.worst(s0, a)
            if before:
                hit, at = True, at_b
        return hit, outside.row(at), at
    part = outside[a:b + 1]
    if not np.any(part != 0.0) and np.any(outside[s0:a] != 0.0):
        part, first = outside[s0:a], s0
    else:
        first = a
    j = int(np.argmax(np.abs(part).max(axis=1)))
    return bool(np.any(part != 0.0)), part[j], first + j


def summarize_run(run: Any) -> dict[str, Any]:
    """The summary of an offline run (:class:`fd_monitor.analysis.offline.BagRun`), as the
    library's expectations check it.

    Returns
    -------
    dict
        :func:`summarize`'s fields, and ``bag``, ``gains``, ``method``, ``input_errors``
        (kind -> stamps), ``transient_s``, ``channels`` (the runtime's alarm channels),
        ``estimate_kind`` (what ``bias_estimate`` estimates) and ``isolates`` (False for a
        detect-only runtime, which reports no isolation).
    """
    s = summarize(outputs_of_run(run), run.transient)
    return {"bag": run.bag, "gains": run.gains, "method": run.method,
            "samples": s["samples"], "alarms": s["alarms"], "isolated": s["isolated"],
            "bias_estimate": s["bias_estimate"], "modes": s["modes"],
            "mode_segments": s["mode_segments"],
            "input_errors": run.inputs.by_kind(), "restarts": s["restarts"],
            "bridges": s["bridges"],
            "transient_s": run.transient, "channels": list(run.channels),
            "estimate_kind": run.estimate_kind,
            "isolates": run.isolated is not None or bool(run.isolating)}


def analyze_run(run: Any) -> dict[str, Any]:
    """The ``analyze`` summary of an offline run (:func:`fd_monitor.analysis.offline.run_bag`).

    Returns
    -------
    dict
        ``samples``, ``alarms`` (one entry per alarm episode and channel: ``channel``,
        ``first_sample``, ``time``, ``last_sample``, ``samples``), ``detection`` (first alarm:
        ``{sample, time}``, or None), ``transitions_estimated``, ``transitions_true`` (or
        None), ``mode_agreement`` (or None), ``isolated``, ``bias_estimate``,
        ``input_errors`` (every rejected or suspicious input message: ``{kind, topic, sample,
        message}``), ``restarts`` (samples where the monitor restarted after a hole longer
        than ``MAX_GAP``, or a new run), ``bridges`` (samples where it bridged a shorter
        one, its memory kept), ``sample_counts`` (``present``, ``used``, ``skipped``:
        reason -> samples; :meth:`~fd_monitor.analysis.offline.InputReport.sample_counts`)
        and ``time_base`` (a robot bag read through an adapter: the sample time and where it
        came from, held samples per channel, gaps, late/duplicate/stray/decimated messages
        per topic).
    """
    system = run.system
    k = run.k
    dt = float(system.sample_time)
    alarms = []
    starts = np.searchsorted(k, np.asarray(run.inputs.restarts, dtype=int))
    for i, name in enumerate(run.channels):
        for a, b in episodes(run.alarm[:, i]):
            ep: dict[str, Any] = {"channel": name, "first_sample": int(k[a]),
                                  "time": float(k[a] * dt), "last_sample": int(k[b]),
                                  "samples": int(b - a + 1)}
            if run.outside is not None:
                # alarms are raised everywhere, but guaranteed only inside the region
                out, worst, at = region_mark(run.outside, starts, a, b)
                ep["outside_certified_region"] = out
                ep["outside_detail"] = describe_excess(run.region_names, worst) + (
                    "" if at >= a else f" at sample {int(k[at])}, before this alarm")
            alarms.append(ep)
    alarms.sort(key=lambda e: (e["first_sample"], e["channel"]))
    names = system.mode_names
    true_mode = None
    if run.truth is not None and "mode" in run.truth.labels:
        tm = truth_at(run.truth, k, ["mode"])[:, 0]
        true_mode = None if np.isnan(tm).any() else tm.astype(int)
    summary = summarize_run(run)
    return {
        "samples": int(k.size),
        "alarms": alarms,
        "detection": None if not alarms else {"sample": alarms[0]["first_sample"],
                                              "time": alarms[0]["time"]},
        "transitions_estimated": transitions(k, run.mode_hat, names, dt),
        "transitions_true": None if true_mode is None else transitions(k, true_mode, names,
                                                                       dt),
        "mode_agreement": None if true_mode is None else float(np.mean(true_mode
                                                                       == run.mode_hat)),
        "isolated": summary["isolated"],
        "bias_estimate": summary["bias_estimate"],
        "input_errors": list(run.inputs.errors),
        "restarts": list(run.inputs.restarts),
        "bridges": list(run.inputs.bridges),
        "sample_counts": run.inputs.sample_counts(),
        "time_base": dict(run.inputs.timebase),
    }


def recorded_outputs(topics: Mapping[str, Any], system: Any) -> Outputs:
    """The :class:`Outputs` the live diagnosis chain published, from a recorded bag.

    Uses ``/fd/alarm`` (a column per output), ``/fd/state_estimate`` (columns ``mode``,
    ``restart`` and ``bridge`` when recorded) and ``/fd/bias_estimate`` (a column per
    output: sigma^; ``iso:<output>``: isolation flag), by label.

    Parameters
    ----------
    topics : mapping
        topic -> :class:`~fd_monitor.wire.bag_reader.TopicArrays`
        (:func:`fd_monitor.wire.bag_reader.read_bag` of the recorded bag).
    system : System
    """
    al, st = topics[ALARM.absolute], topics[STATE_ESTIMATE.absolute]
    be = topics[BIAS_ESTIMATE.absolute]
    outputs = tuple(system.outputs)
    restart = st.column("restart")
    bridge = st.column("bridge") if "bridge" in st.labels else np.zeros(len(st.stamps))
    return Outputs(
        k=np.asarray(al.stamps), dt=float(system.sample_time), channels=outputs,
        alarm=np.column_stack([al.column(c) > 0.5 for c in outputs]),
        mode=st.column("mode").astype(int), mode_names=tuple(system.mode_names),
        estimate={c: be.column(c) for c in outputs},
        isolated=np.column_stack([be.column(f"iso:{c}") > 0.5 for c in outputs]),
        isolation_channels=outputs,
        restarts=[int(k) for k in st.stamps[1:][restart[1:] > 0.5]],
        bridges=[int(k) for k in st.stamps[bridge > 0.5]])


# --------------------------------------------------------------------------------------
# the truth


def read_bag_truth(bag: str | Path) -> Any:
    """``/plant/truth`` of a bag as :class:`~fd_monitor.wire.bag_reader.TopicArrays`."""

    return read_bag(bag, [PLANT_TRUTH.absolute])[PLANT_TRUTH.absolute]


def truth_at(truth: Any, ks: Sequence[int], labels: Sequence[str]) -> np.ndarray:
    """(len(ks), len(labels)) truth values at the given stamps (NaN where absent); a stamp
    recorded twice: its last message."""
    out = np.full((len(ks), len(labels)), np.nan)
    cols = [truth.labels.index(lab) for lab in labels]
    stamps = np.asarray(truth.stamps, dtype=np.int64).reshape(-1)
    if not stamps.size or not len(ks):
        return out
    if stamps.size < 2 or bool(np.all(stamps[1:] > stamps[:-1])):
        uniq, row = stamps, None                 # the usual truth: one message per stamp
    else:
        # sorted, the last message of each stamp (a stable sort keeps the record order)
        order = np.argsort(stamps, kind="stable")
        ss = stamps[order]
        last = np.r_[ss[1:] != ss[:-1], True]
        uniq, row = ss[last], order[last]
    kk = np.asarray([int(k) for k in ks], dtype=np.int64) if not isinstance(ks, np.ndarray) \
        else np.asarray(ks, dtype=np.int64)
    pos = np.minimum(np.searchsorted(uniq, kk), uniq.size - 1)
    hit = uniq[pos] == kk
    idx = pos[hit] if row is None else row[pos[hit]]
    out[hit] = truth.values[idx][:, cols]
    return out


def truth_facts(truth: Any, system: Any) -> dict[str, Any]:
    """What a bag's ``/plant/truth`` says: fault onsets, final fault values, true modes.

    Parameters
    ----------
    truth : fd_monitor.wire.bag_reader.TopicArrays
        ``/plant/truth``.
    system : System

    Returns
    -------
    dict
        ``faults``: name -> ``{onset_sample, final, kind, target}`` for every fault channel
        that is ever non-zero, in the plant's order (``target`` the output or state it acts
        on, else the fault itself); ``modes``: the true mode sequence (repeats collapsed);
        ``samples``.
    """
    faults: dict[str, Any] = {}
    for f in system.faults:
        lab = f"f.{f.name}"
        if lab not in truth.labels:
            continue
        v = truth.column(lab)
        nz = np.flatnonzero(v != 0.0)
        if nz.size:
            # what an isolation names: the biased output, the jumping state, else the fault
            # itself (an hinf_sc bank has one channel per fault)
            target = (system.outputs[f.index] if f.kind == "sensor_bias"
                      else system.states[f.index] if f.kind == "state_jump" else f.name)
            faults[f.name] = {"onset_sample": int(truth.stamps[nz[0]]), "final": float(v[-1]),
                              "kind": f.kind, "target": target}
    modes = (collapse([system.mode_names[int(q)] for q in truth.column("mode")])
             if "mode" in truth.labels else [])
    return {"faults": faults, "modes": modes, "samples": len(truth)}


def true_biases(facts: Mapping[str, Any]) -> dict[str, float]:
    """output -> final true sensor bias, of the faults in :func:`truth_facts`."""
    return {f["target"]: f["final"] for f in facts["faults"].values()
            if f["kind"] == "sensor_bias"}
