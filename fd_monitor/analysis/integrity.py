"""The input contract of every command that reads a bag: what was not used, and why.

``analyze``, ``report``, ``replay``, ``identify`` and ``bag check`` read a bag through
:func:`fd_monitor.analysis.offline.scan_bag` (every chunk's CRC checked, damage skipped and
reported) and its ``/plant/...`` messages through the nodes' input policy
(:func:`fd_monitor.analysis.offline.read_streams`, or :func:`read_samples` when no plant is
known: ``identify``, ``replay``, ``bag check``). What they did not use is one record,
:func:`~fd_monitor.wire.input_checks.integrity`::

    {"clean": false,                       # nothing below (but unchecked_chunks) is non-zero
     "skipped_chunks": 1,                  # damaged regions of the MCAP skipped
     "damage": ["<file>: byte 4711: ..."], # one line each
     "unchecked_chunks": 0,                # chunks with CRC 0 ("not computed"): not damage
     "metadata": [],                       # metadata.yaml disagreeing with the MCAP it names
     "samples_present": 3000, "samples_used": 2950,
     "lost_samples": 50,                   # present - used
     "samples_skipped": {"missing": 48, "non_finite": 2},   # reason -> samples not used
     "refused_samples": {"non_finite": 2}, # received but refused (decode, limits), by reason
     "dropped_messages": {"duplicate": 1}} # messages dropped without losing a sample

``--json`` prints it as ``integrity``; ``--strict`` turns a record that is not ``clean`` into
exit status 2 (:func:`enforce_strict`, one line saying what). The limits of offline reading
(:data:`MAX_LABEL_CHARS`, :data:`MAX_DISTINCT_LABELS`, :data:`MAX_MAGNITUDE`) are checked
message by message before anything is kept.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.model.errors import BagError
from fd_monitor.model.plant_schema import MAX_MAGNITUDE
from fd_monitor.wire.input_checks import (
    MAX_DISTINCT_LABELS,
    MAX_LABEL_CHARS,
    describe,
    integrity,
    metadata_problems,
)

__all__ = ["MAX_DISTINCT_LABELS", "MAX_LABEL_CHARS", "MAX_MAGNITUDE", "add_strict_flag",
           "bag_integrity", "describe",
           "enforce_strict", "integrity", "metadata_problems",
           "read_joined", "read_samples"]



def add_strict_flag(parser: Any, also: str = "") -> None:
    """Add ``--strict`` (exit status 2 when the input was not used whole); ``also``: what
    else the command refuses under it (a help-text clause)."""
    parser.add_argument("--strict", action="store_true",
                        help="exit with status 2 when anything of the bag was not used "
                             "(damaged chunks, refused or missing samples, dropped messages, "
                             "metadata.yaml disagreeing with the MCAP; see `integrity` in "
                             "--json)" + (f", {also}" if also else ""))


def enforce_strict(doc: Mapping[str, Any], bag: str | Path, strict: bool) -> None:
    """``--strict``: raise a one-line :class:`BagError` (exit status 2) unless ``doc`` is
    clean; nothing without ``strict``."""
    if strict and not doc["clean"]:
        raise BagError(f"{bag}: input not used whole (--strict): {describe(doc)}")


def read_samples(bag: str | Path, topics: Sequence[str],
                 labels: Sequence[Sequence[str] | None] = (), limits: Sequence[Any] = (), *,
                 max_gap: int = 0, on_sample: Callable[[int], Any] | None = None,
                 on_message: Callable[[str, int, int | None], Any] | None = None,
                 keep: bool = True, warn: bool = True
                 ) -> tuple[list[int], list[np.ndarray], Any, Any]:
    """The samples of a bag without a plant file (``identify``, ``replay``, ``bag check``),
    through the same one-pass reader and input policy as ``analyze``
    (:func:`fd_monitor.analysis.reader.read_pass`).

    Parameters
    ----------
    bag : str or pathlib.Path
    topics : sequence of str
        The joined Float64MultiArray topics (e.g. u then y); none: the census only.
    labels : sequence
        Per topic the expected channel labels, or None: the first readable message's.
    limits : sequence
        Per topic a (m, 2) array of [low, high] per channel, or None: every value must be
        of magnitude <= :data:`MAX_MAGNITUDE` (a sample outside is refused as
        ``implausible``, like the runtime's range test).
    max_gap : int
        Holes of at most this many samples are bridged (reported in ``bridges``).
    on_sample : callable, optional
        Called with the stamp (as received) of each sample kept.
    on_message : callable, optional
        Called with ``(topic, log time ns, readable stamp or None)`` of each message read.
    keep : bool
        Keep the samples' values (False: only the report).
    warn : bool
        Say the damage and metadata problems once each.

    Returns
    -------
    (list, list, InputReport, BagScan)
        Released stamps (a new run after a restart renumbered to follow the last stamp with
        a hole of one sample, so no one-step pair crosses it), per topic the (K, m) values,
        the report, the bag's census.

    Raises
    ------
    BagError
        A topic missing or not a Float64MultiArray, more than :data:`MAX_DISTINCT_LABELS`
        label strings on a topic.
    """
    from fd_monitor.analysis.reader import InputReport, read_pass
    from fd_monitor.wire.join import Sample

    topics = list(topics)

    def each_present(scan: Any) -> None:         # one topic at a time, as identify says it
        for t in topics:
            scan.check_topics([t])

    given = list(labels) + [None] * (len(topics) - len(labels))
    lims = list(limits) + [None] * (len(topics) - len(limits))
    names = {t: f"s{i}" for i, t in enumerate(topics)}
    rep = InputReport()
    ks: list[int] = []
    cols: list[list[np.ndarray]] = [[] for _ in topics]
    shift = [0]
    labs: list[tuple[str, ...]] = []

    def check(v: np.ndarray, i: int) -> str | None:
        lim = lims[i]
        if lim is None:
            bad = np.flatnonzero(~(np.abs(v) <= MAX_MAGNITUDE))
            if bad.size:
                return (f"{labs[i][bad[0]]} = {v[bad[0]]!r}: outside +-{MAX_MAGNITUDE:g} "
                        f"(implausible)")
            return None
        lo, hi = np.asarray(lim, float)[:, 0], np.asarray(lim, float)[:, 1]
        bad = np.flatnonzero(~((v >= lo) & (v <= hi)))
        if bad.size:
            j = bad[0]
            return (f"{labs[i][j]} = {v[j]!r}: outside its limits [{lo[j]:g}, {hi[j]:g}] "
                    f"(implausible)")
        return None

    def step(s: Sample) -> bool:
        if not labs:                              # the labels the pass settled on
            labs.extend(tuple(scan_labels[t] or ()) for t in topics)
        vals = [np.asarray(s.inputs[names[t]], float) for t in topics]
        for i, v in enumerate(vals):
            why = check(v, i)
            if why is not None:
                rep.errors.append({"kind": "implausible", "topic": topics[i], "sample": s.k,
                                   "message": f"{topics[i]} stamp {s.k}: {why}"})
                return False
        k = s.k + shift[0]
        if ks and k <= ks[-1]:            # a new run whose stamps start again: after a hole
            shift[0] += ks[-1] + 2 - k
            k = ks[-1] + 2
        ks.append(k)
        if on_sample is not None:
            on_sample(s.k)
        if keep:
            for i, v in enumerate(vals):
                cols[i].append(v)
        return True

    scan_labels: dict[str, tuple[str, ...] | None] = {}
    for i, t in enumerate(topics):
        got = given[i]
        scan_labels[t] = None if got is None else tuple(got)
    scan = read_pass(bag, topics, scan_labels, rep, step, names=names, max_gap=max_gap,
                     checks=each_present, on_message=on_message, warn=warn)
    if not labs:
        labs.extend(tuple(scan.first_labels(t) or ()) if scan_labels[t] is None
                    else tuple(scan_labels[t] or ()) for t in topics)
    return ks, [np.vstack(c) if c else np.zeros((0, len(labs[i])))
                for i, c in enumerate(cols)], rep, scan


def read_joined(bag: str | Path, u_topic: str, y_topic: str, *, strict: bool = False
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[str, ...],
                           tuple[str, ...], dict[str, Any]]:
    """A bag's joined (u, y) samples for ``identify``: :func:`read_samples` of
    :func:`~fd_monitor.analysis.offline.scan_bag`, the labels of each topic's first message
    the reference (no plant is known yet), every value of magnitude <=
    :data:`MAX_MAGNITUDE`.

    What was not used is warned once (one line) and returned as the :func:`integrity`
    record; ``strict`` refuses it (:func:`enforce_strict`).

    Returns
    -------
    (k, u, y, t_ns, u_labels, y_labels, integrity)
        (K,) stamps (a new run renumbered after the last, one sample apart), (K, nu),
        (K, ny), (K,) log times of the y messages (ns), the labels, the record.

    Raises
    ------
    BagError
        Missing bag or topic, no usable sample, or ``strict`` and not clean.
    """
    import warnings

    from fd_monitor.model.errors import FdMonitorWarning

    times: dict[int, int] = {}

    def timed(topic: str, t: int, k: int | None) -> None:
        if topic == y_topic and k is not None:
            times.setdefault(k, int(t))

    raw: list[int] = []
    ks, (u, y), rep, scan = read_samples(bag, [u_topic, y_topic], on_sample=raw.append,
                                         on_message=timed)
    doc = integrity(scan, rep)
    if not ks:
        raise BagError(f"{bag}: no usable (u, y) sample on {u_topic} and {y_topic} "
                       f"({describe(doc)})")
    enforce_strict(doc, bag, strict)
    if not doc["clean"]:
        warnings.warn(f"{bag}: {describe(doc)}", FdMonitorWarning, stacklevel=2)
    t_ns = np.array([times.get(k, 0) for k in raw], dtype=np.int64)
    return (np.asarray(ks, dtype=np.int64), u, y, t_ns, tuple(scan.first_labels(u_topic) or ()),
            tuple(scan.first_labels(y_topic) or ()), doc)


def bag_integrity(bag: str | Path, strict: bool = False, *, warn: bool = True,
                  note: str = "", enforce: bool = True) -> tuple[Any, dict[str, Any]]:
    """The contract for a command that reads a bag without a plant file (``replay``, ``bag
    check``): the bag read once (:func:`~fd_monitor.analysis.offline.scan_bag`: damage,
    metadata) and its ``/plant/u``, ``/plant/y`` through the input policy
    (:func:`read_samples`: stamps, labels, limits).

    Returns
    -------
    (BagScan, dict)
        The scan and its :func:`integrity` record; with ``warn`` what was not used is said
        once (one line, ``note`` appended), with ``strict`` refused (:func:`enforce_strict`;
        ``enforce=False``: left to the caller, e.g. after it printed its table; a bag whose
        samples cannot be read at all is refused at once either way).
    """
    import warnings

    from fd_monitor.model.errors import FdMonitorWarning
    from fd_monitor.wire.topics import PLANT_U, PLANT_Y

    topics = [t.absolute for t in (PLANT_U, PLANT_Y)]
    rep = None
    try:
        # one pass: the census, and /plant/u, /plant/y through the input policy
        _ks, _v, rep, scan = read_samples(bag, topics, keep=False, warn=warn)
    except BagError as exc:
        # the census alone (a missing or broken bag fails here, one line); the samples are
        # checked only when the bag has them
        scan = read_samples(bag, [], warn=warn)[3]
        rep = None
        if PLANT_Y.absolute in scan.present:
            have = [t for t in topics if t in scan.present]
            try:
                if have != topics:
                    rep = read_samples(bag, have, keep=False, warn=False)[2]
                else:
                    raise exc
            except BagError as again:
                if strict:
                    raise
                if warn:
                    warnings.warn(f"{again} (stamps and labels not checked)",
                                  FdMonitorWarning, stacklevel=2)
    doc = integrity(scan, rep)
    enforce_strict(doc, bag, strict and enforce)
    if warn and not doc["clean"]:
        warnings.warn(f"{bag}: {describe(doc)}" + (f" ({note})" if note else ""),
                      FdMonitorWarning, stacklevel=2)
    return scan, doc
