"""Identify a plant file from fault-free bags: read, label modes, fit, bound, validate, write.

``python -m fd_monitor identify BAG [BAG ...] -o PLANT.yaml`` (:mod:`fd_monitor.commands.identify`)
calls :func:`identify_bags`; the numerics are :mod:`fd_monitor.core.identify`.

What the written plant file is (schema: :mod:`fd_monitor.model.system`):

* ``time: discrete``, the bags' sample time; ``states`` = ``outputs`` = the measured channels
  (``C = I``: ``y = x + v``, the plant class of the ``thresholds`` chain); ``inputs`` = the
  input channels;
* one ``dynamics: linear`` mode per combination of the stated guard conditions that the data
  visit (``--guard "h3 > 0.35"``: a condition on an output is an autonomous guard, evaluated
  on ``y_k``; on an input a controlled one, evaluated on ``u_{k-1}``, as the simulator and the
  observer apply a controlled guard from the sample after the input), or one per value of a
  mode channel (``--mode-topic``: ``switching: arbitrary``); guards between modes that differ
  in one condition, both ways;
* ``bounds.measurement_noise`` and each mode's ``uncertainty`` from held-out data
  (:mod:`fd_monitor.core.identify`), times ``margin``;
* ``envelope``: the range of every state and input the data covered, narrowed per mode: the
  region the bounds were measured in and a ``design thresholds --envelope declared`` certifies;
* ``faults``: a ``sensor_bias`` per output, an ``actuator`` fault per input;
* provenance as comments at the top (bags with SHA-256, method, fit and validation errors,
  sample counts, the candidates with their held-out simulation fit, the quality warnings) and
  a summary in ``description``; no date, so the same bags and options give the same file
  byte for byte.

How good the model is (held-out simulation fit, standard errors, excitation, bounds measured
or assumed, halves, physical parameters) is :mod:`fd_monitor.analysis.identify_quality`, in
every run's summary (``quality``, ``warnings``).

Why one module of ~1,250 lines: one command's pipeline (bags to a dataset, modes and guards,
the fit driver and its candidates, bounds, validation, the written file, the plot); the
numerics are in ``core/identify.py``, the quality figures in ``identify_quality``.
"""

from __future__ import annotations

import hashlib
import itertools
import math
import re
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from fd_monitor.analysis.identify_quality import (
    closed_loop,
    coefficient_statistics,
    excitation,
    halves,
    n4sid_models,
    noise_check,
    physical_parameters,
    simulation,
)
from fd_monitor.analysis.integrity import describe, enforce_strict, read_joined
from fd_monitor.analysis.integrity import integrity as bag_integrity_record
from fd_monitor.analysis.offline import adapted_streams, scan_bag
from fd_monitor.core.identify import (
    AffineModel,
    IdentificationError,
    clip_radius,
    fit_modes,
    hf_noise_std,
    noise_bound,
    one_step_bound,
    one_step_errors,
    rms,
    spectral_radius,
    uncertainty_bound,
)
from fd_monitor.model.errors import BagError, FdMonitorWarning
from fd_monitor.model.system import System, parse_system
from fd_monitor.wire.bag_reader import read_bag
from fd_monitor.wire.series import Series
from fd_monitor.wire.topics import PLANT_U, PLANT_Y

__all__ = [
    "Dataset",
    "GuardCondition",
    "Identified",
    "MODELS",
    "PER_MODE",
    "ESTIMATORS",
    "load_dataset",
    "parse_guard",
    "identify",
    "identify_bags",
    "write_plant",
    "plot_validation",
    "add_physical",
]

MODELS = ("auto", "linear", "affine", "sparse")
PER_MODE = ("offset", "full")
ESTIMATORS = ("auto", "iv", "ls", "n4sid")
#: One-step samples needed per fitted coefficient (of one output's row).
SAMPLES_PER_COEFFICIENT = 10
_OPS = {">": "gt", ">=": "ge", "<": "lt", "<=": "le"}
_NEG = {">": "<=", ">=": "<", "<": ">=", "<=": ">"}
_GUARD_RE = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*(>=|<=|>|<)\s*(\S+)\s*$")


@dataclass(frozen=True)
class Dataset(Series):
    """One record of inputs and outputs (a bag, or arrays from an adapter): a
    :class:`~fd_monitor.wire.series.Series` (``name`` where it came from, used in messages
    and the provenance; ``k`` (K,) increasing, a gap is a hole (no one-step pair across it);
    ``u`` (K, nu) held over each sample; ``y`` (K, ny) output units; ``sample_time`` s or
    None) with what identification needs besides.

    Attributes
    ----------
    mode : numpy.ndarray or None
        (K,) int mode of each sample (a measured mode channel), or None.
    sha256 : str
        Digest of the source (the bag's files), for the provenance.
    topics : tuple of str
        (u, y[, mode]) topic names, for messages.
    """

    mode: np.ndarray | None = None
    sha256: str = ""
    topics: tuple[str, ...] = (PLANT_U.absolute, PLANT_Y.absolute)

    def check(self) -> None:
        """Refuse NaN/Inf (naming topic, channel and sample) and inconsistent shapes."""
        K = self.k.size
        for arr, labels, topic in ((self.u, self.inputs, self.topics[0]),
                                   (self.y, self.outputs, self.topics[1])):
            if arr.shape != (K, len(labels)):
                raise IdentificationError(f"{self.name}: {topic}: expected {K} samples of "
                                          f"{len(labels)} channels, got shape {arr.shape}")
            bad = ~np.isfinite(arr)
            if bad.any():
                r, c = (int(i[0]) for i in np.nonzero(bad))
                what = "NaN" if np.isnan(arr[r, c]) else "Inf"
                raise IdentificationError(
                    f"{self.name}: {topic} channel {labels[c]} sample {int(self.k[r])}: {what} "
                    f"({int(bad.sum())} non-finite values in all; identify needs finite data: "
                    f"cut the bag or drop the samples)")
        if K > 1 and not np.all(np.diff(self.k) > 0):
            raise IdentificationError(f"{self.name}: sample indices are not increasing")


def _bag_sha256(path: Path) -> str:
    """SHA-256 over the bag folder's files (sorted names and bytes)."""
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for p in files:
        h.update(p.name.encode())
        with open(p, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def _joined(u_arr: Any, y_arr: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Samples whose stamp is on both topics (first message of a repeated stamp)."""
    def first(a: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ks, idx = np.unique(np.asarray(a.stamps), return_index=True)
        return ks, np.asarray(a.values)[idx], np.asarray(a.receive_ns)[idx]

    ku, vu, _ = first(u_arr)
    ky, vy, ty = first(y_arr)
    k, iu, iy = np.intersect1d(ku, ky, return_indices=True)
    return k, vu[iu], vy[iy], ty[iy]


def load_dataset(bag: str | Path, *, u_topic: str = PLANT_U.absolute,
                 y_topic: str = PLANT_Y.absolute,
                 mode_topic: str | None = None, adapter: Any = None,
                 sample_time: float | None = None, strict: bool = False,
                 integrity: dict[str, Any] | None = None) -> Dataset:
    """Read a bag's inputs and outputs (and mode channel) into a :class:`Dataset`.

    Parameters
    ----------
    bag : str or pathlib.Path
        rosbag2 folder.
    u_topic, y_topic : str
        Float64MultiArray topics of the inputs and outputs (labelled channels).
    mode_topic : str, optional
        ``TOPIC`` or ``TOPIC:CHANNEL``: a Float64MultiArray whose channel (default the first)
        holds the mode as an integer.
    adapter : object, optional
        A message mapping of :mod:`fd_monitor.wire.adapters` (robots' own message types):
        the bag is read through it instead of ``u_topic``/``y_topic`` (messages it cannot
        use are skipped with one warning naming the first).
    sample_time : float, optional
        s, for an adapter's sample numbering (default: the output stamps' median spacing).
    strict : bool
        Refuse a bag not used whole (:func:`fd_monitor.analysis.integrity.enforce_strict`).
    integrity : dict, optional
        Receives bag -> its integrity record (:func:`fd_monitor.analysis.integrity.integrity`).

    Raises
    ------
    BagError
        No such bag, a topic missing, a malformed message.
    IdentificationError
        NaN/Inf, no common sample.
    """
    path = Path(bag)
    if not path.exists():
        raise BagError(f"{bag}: no such bag")
    if adapter is not None:
        # the contract: the bag's census (damage, metadata.yaml) and the samples through the
        # adapter and the nodes' input policy, as analyze --adapter reads them
        scan = scan_bag(path)
        s, rep = adapted_streams(path, adapter, sample_time=sample_time, keep=True)
        doc = bag_integrity_record(scan, rep)
        enforce_strict(doc, bag, strict)
        if integrity is not None:
            integrity[str(bag)] = doc
        if doc["skipped_chunks"] or doc["metadata"]:
            warnings.warn(f"{bag}: {describe(doc)}", FdMonitorWarning, stacklevel=2)
        c = s.counts
        gaps = {r: sum(n.values()) for r, n in c["gaps"].items()}
        odd = {kind: sum(c.get(kind, {}).values())
               for kind in ("late", "duplicate", "stray", "decimated")}
        if s.errors or gaps or c["held"] or sample_time is None:
            warnings.warn(
                f"{bag}: {s.sample_time_note}; {c['samples']} samples"
                + "".join(f", {n} {r} gaps" for r, n in gaps.items())
                + "".join(f", {n} held ({ch})" for ch, n in c["held"].items())
                + "".join(f", {n} {kind} messages" for kind, n in odd.items() if n)
                + (f"; the first note: {s.errors[0][1]}" if s.errors else ""),
                FdMonitorWarning, stacklevel=2)
        ds = Dataset(str(bag), tuple(s.inputs), tuple(s.outputs), np.asarray(s.k),
                     np.asarray(s.u, dtype=float), np.asarray(s.y, dtype=float),
                     float(s.sample_time), None, _bag_sha256(path), ("inputs", "outputs"))
        ds.check()
        return ds
    mtopic, mchan = [*mode_topic.split(":", 1), ""][:2] if mode_topic else ("", "")
    # analyze's input checks (integrity, stamps, duplicates, labels, limits, metadata)
    k, u, y, t_ns, u_labels, y_labels, doc = read_joined(path, u_topic, y_topic,
                                                         strict=strict)
    if integrity is not None:
        integrity[str(bag)] = doc
    mode = None
    if mtopic:
        m = read_bag(path, [mtopic])[mtopic]
        col = m.labels.index(mchan) if mchan else 0
        if mchan and mchan not in m.labels:
            raise BagError(f"{bag}: {mtopic}: no channel {mchan!r} (channels: "
                           f"{', '.join(m.labels)})")
        km, vm, _ = (np.unique(m.stamps, return_index=True)[0],
                     m.values[np.unique(m.stamps, return_index=True)[1], col], None)
        keep = np.isin(k, km)
        k, u, y, t_ns = k[keep], u[keep], y[keep], t_ns[keep]
        mv = vm[np.searchsorted(km, k)]
        if not np.all(np.isfinite(mv)) or not np.all(mv == np.round(mv)):
            j = int(np.nonzero(~np.isfinite(mv) | (mv != np.round(mv)))[0][0])
            raise IdentificationError(f"{bag}: {mtopic} sample {int(k[j])}: mode {mv[j]!r} "
                                      f"is not an integer")
        mode = mv.astype(int)
    ts = None
    if k.size > 1:
        dk = np.diff(k)
        ts = float(np.median(np.diff(t_ns) / dk)) * 1e-9
        ts = ts if ts > 0 else None
    ds = Dataset(str(bag), u_labels, y_labels, k, u, y, ts, mode, _bag_sha256(path),
                 (u_topic, y_topic))
    ds.check()
    return ds


@dataclass(frozen=True)
class GuardCondition:
    """A stated condition ``var op value`` (``--guard``).

    Attributes
    ----------
    var : str
    op : str
        ``>``, ``>=``, ``<`` or ``<=``.
    value : float
    kind : str
        ``autonomous`` (var is an output, i.e. a state) or ``controlled`` (an input).
    index : int
        Index of var among the outputs or the inputs.
    """

    var: str
    op: str
    value: float
    kind: str
    index: int

    def holds(self, v: np.ndarray) -> np.ndarray:
        """(N,) bool: the condition on the values v (N,)."""
        return {">": np.greater, ">=": np.greater_equal, "<": np.less,
                "<=": np.less_equal}[self.op](v, self.value)

    def label(self, truth: bool) -> str:
        """Mode-name part: ``h3_gt_0p35`` when it holds, ``h3_le_0p35`` when not."""
        op = self.op if truth else _NEG[self.op]
        val = repr(self.value).replace("-", "m").replace(".", "p").replace("+", "")
        return f"{self.var}_{_OPS[op]}_{val}"


def parse_guard(text: str, inputs: Sequence[str], outputs: Sequence[str]) -> GuardCondition:
    """Parse ``"h3 > 0.35"``; the variable must be an output (state) or an input."""
    m = _GUARD_RE.match(text)
    if not m:
        raise IdentificationError(f"--guard {text!r}: expected 'CHANNEL OP VALUE' with OP one "
                                  f"of >, >=, <, <= (e.g. 'h3 > 0.35')")
    var, op, raw = m.groups()
    try:
        value = float(raw)
    except ValueError:
        raise IdentificationError(f"--guard {text!r}: {raw!r} is not a number") from None
    if not math.isfinite(value):
        raise IdentificationError(f"--guard {text!r}: expected a finite value")
    if var in outputs:
        return GuardCondition(var, op, value, "autonomous", list(outputs).index(var))
    if var in inputs:
        return GuardCondition(var, op, value, "controlled", list(inputs).index(var))
    raise IdentificationError(f"--guard {text!r}: {var!r} is not a channel (outputs: "
                              f"{', '.join(outputs)}; inputs: {', '.join(inputs)})")


@dataclass
class _Rows:
    """One-step rows (k -> k + 1) of several datasets, with their lagged instruments."""

    X: np.ndarray      # (N, n) y_k
    U: np.ndarray      # (N, nu) u_k
    Xn: np.ndarray     # (N, n) y_{k+1}
    Xp: np.ndarray     # (N, n) y_{k-1} (valid where lag)
    Up: np.ndarray     # (N, nu) u_{k-1}
    lag: np.ndarray    # (N,) bool: k - 1 is in the record
    key: np.ndarray    # (N,) int combination key (mode label before mapping)
    seg: np.ndarray    # (N,) int record id (windows never cross records or holes)
    k: np.ndarray      # (N,) int sample index
    ds: np.ndarray     # (N,) int dataset index

    def take(self, sel: np.ndarray) -> _Rows:
        return _Rows(*(getattr(self, f)[sel] for f in
                       ("X", "U", "Xn", "Xp", "Up", "lag", "key", "seg", "k", "ds")))

    @property
    def size(self) -> int:
        return int(self.X.shape[0])


def _keys(ds: Dataset, guards: Sequence[GuardCondition], use_mode: bool) -> np.ndarray:
    """(K,) combination key of each sample: the mode of the step k -> k + 1."""
    if use_mode:
        assert ds.mode is not None
        return ds.mode.astype(np.int64)
    key = np.zeros(ds.k.size, dtype=np.int64)
    # controlled guards take effect at the sample after the input (u_{k-1}); at the start
    # of a record (or after a hole) the input of the sample itself
    u_prev = ds.u.copy()
    cont = np.concatenate([[False], np.diff(ds.k) == 1])
    u_prev[cont] = ds.u[np.nonzero(cont)[0] - 1]
    for j, g in enumerate(guards):
        v = ds.y[:, g.index] if g.kind == "autonomous" else u_prev[:, g.index]
        key |= g.holds(v).astype(np.int64) << j
    return key


def _rows(datasets: Sequence[Dataset], parts: Sequence[tuple[int, int]],
          guards: Sequence[GuardCondition], use_mode: bool, seg0: int = 0) -> _Rows:
    """One-step rows of ``datasets[i]`` samples ``parts[i] = [a, b)``."""
    acc: list[tuple[np.ndarray, ...]] = []
    for i, (ds, (a, b)) in enumerate(zip(datasets, parts)):
        key = _keys(ds, guards, use_mode)
        k = ds.k[a:b]
        j = np.nonzero(np.diff(k) == 1)[0] + a          # rows: sample j -> j + 1
        if j.size == 0:
            continue
        lag = np.zeros(j.size, dtype=bool)
        lag[j > a] = ds.k[j[j > a] - 1] == ds.k[j[j > a]] - 1
        jp = np.where(lag, j - 1, j)
        # a new record id after every hole
        brk = np.concatenate([[0], np.cumsum(np.diff(j) != 1)])
        acc.append((ds.y[j], ds.u[j], ds.y[j + 1], ds.y[jp], ds.u[jp], lag, key[j],
                    seg0 + 1000003 * i + brk, ds.k[j], np.full(j.size, i)))
    if not acc:
        n = datasets[0].y.shape[1] if datasets else 0
        nu = datasets[0].u.shape[1] if datasets else 0
        z = np.zeros(0, dtype=np.int64)
        return _Rows(np.zeros((0, n)), np.zeros((0, nu)), np.zeros((0, n)), np.zeros((0, n)),
                     np.zeros((0, nu)), np.zeros(0, dtype=bool), z, z, z, z)
    return _Rows(*(np.concatenate(c) for c in zip(*acc)))


def _segments(E: np.ndarray, rows: _Rows) -> list[np.ndarray]:
    """Split errors (N, n) of rows (one mode) into runs of consecutive samples."""
    if rows.size == 0:
        return []
    brk = np.nonzero((np.diff(rows.k) != 1) | (np.diff(rows.seg) != 0))[0] + 1
    return [E[r] for r in np.split(np.arange(rows.size), brk)]


@dataclass
class Identified:
    """Result of :func:`identify`.

    Attributes
    ----------
    doc : dict
        The plant file as a mapping (what :func:`fd_monitor.model.system.parse_system` reads).
    text : str
        The plant file as written (provenance comments + YAML).
    system : System
        ``doc`` parsed.
    summary : dict
        Method, modes, sample counts, errors and bounds (the ``--json`` document).
    validation : dict
        Held-out one-step predictions of the first held-out record, for the plot: ``record``,
        ``k`` (N,), ``measured``, ``predicted``, ``bound`` (N, ny), ``outputs``; and
        ``simulation``: ``k``, ``measured``, ``simulated`` of the free-run simulation of the
        first held-out run.
    models : tuple of AffineModel
        One per mode, in the order of ``system.modes``.
    conditions : tuple of GuardCondition
        The stated guard conditions (mode labelling).
    mode_keys : tuple of int
        Combination key (bit j: condition j holds) or mode-channel value of each mode.
    use_mode : bool
        Modes come from a mode channel.
    noise : numpy.ndarray
        (ny,) ``v_bar``, output units.
    uncertainty : numpy.ndarray
        (modes, ny) ``eta_bar`` per mode, state units per sample.
    """

    doc: dict[str, Any]
    text: str
    system: System
    summary: dict[str, Any]
    validation: dict[str, Any] = field(default_factory=dict)
    models: tuple[AffineModel, ...] = ()
    conditions: tuple[GuardCondition, ...] = ()
    mode_keys: tuple[int, ...] = ()
    use_mode: bool = False
    noise: np.ndarray = field(default_factory=lambda: np.zeros(0))
    uncertainty: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def one_step(self, ds: Dataset) -> dict[str, np.ndarray]:
        """One-step prediction errors of a record against the stated bounds.

        Returns
        -------
        dict
            ``k`` (N,) the predicted sample, ``error`` (N, ny), ``bound`` (N, ny)
            (``v_bar + |A_q| v_bar + eta_bar_q``), ``mode`` (N,) int (-1: a combination
            without a mode, left out of ``error`` and ``bound``: zeros there).
        """
        R = _rows([ds], [(0, ds.k.size)], self.conditions, self.use_mode)
        lut = {kk: q for q, kk in enumerate(self.mode_keys)}
        q = np.array([lut.get(int(kk), -1) for kk in R.key], dtype=int)
        E = _errors(self.models, R, q)
        bound = np.zeros_like(E)
        for j, M in enumerate(self.models):
            bound[q == j] = one_step_bound(M.A, self.noise, self.uncertainty[j])
        return {"k": R.k + 1, "error": E, "bound": bound, "mode": q}


def _sample_time(datasets: Sequence[Dataset], given: float | None) -> float:
    if given is not None:
        if not (math.isfinite(given) and given > 0):
            raise IdentificationError(f"--sample-time {given}: expected a positive number of s")
        return float(given)
    ts = [d.sample_time for d in datasets if d.sample_time is not None]
    if not ts:
        raise IdentificationError("no sample time in the data (one sample per record?): give "
                                  "--sample-time")
    ref = ts[0]
    for d in datasets:
        if d.sample_time is not None and abs(d.sample_time - ref) > 0.01 * ref:
            raise IdentificationError(f"{d.name}: sample time {d.sample_time:g} s differs from "
                                      f"{datasets[0].name}'s {ref:g} s")
    # the sample time is a setting, not a measurement: 6 significant digits
    return float(f"{ref:.6g}")


def _check_channels(datasets: Sequence[Dataset]) -> None:
    a = datasets[0]
    for d in datasets[1:]:
        for what, x, y in (("input", a.inputs, d.inputs), ("output", a.outputs, d.outputs)):
            if x != y:
                raise IdentificationError(
                    f"{d.name}: {what} channels [{', '.join(y)}] differ from {a.name}'s "
                    f"[{', '.join(x)}] (every bag must carry the same channels in the same "
                    f"order)")
        if (a.mode is None) != (d.mode is None):
            raise IdentificationError(f"{d.name}: the mode channel is in one bag and not in "
                                      f"{a.name}")


def _excited(rows: _Rows, names: Sequence[str], exclude: Sequence[int]) -> np.ndarray:
    """Indices of the inputs to fit; refuses an input that never changes."""
    fit = []
    for j, nm in enumerate(names):
        if j in exclude:
            continue
        col = rows.U[:, j]
        spread = float(col.max() - col.min()) if col.size else 0.0
        if not spread > 1e-12 * max(1.0, float(np.abs(col).max(initial=0.0))):
            val = float(col[0]) if col.size else float("nan")
            raise IdentificationError(
                f"input {nm} is constant ({val:g}) over all {rows.size} one-step samples of "
                f"the fit data: no excitation, its effect cannot be identified (excite it, "
                f"state it as a guard, or leave it out with --exclude-input {nm})")
        fit.append(j)
    return np.asarray(fit, dtype=int)


def identify(fit: Sequence[Dataset], holdout: Sequence[Dataset] = (), *, name: str,
             model: str = "auto", modes: str = "offset", guards: Sequence[str] = (),
             margin: float = 1.2, split: float = 0.3, max_window: float = 10.0,
             estimator: str = "auto", sparsity: float = 0.01,
             sample_time: float | None = None, exclude_inputs: Sequence[str] = (),
             sources: Sequence[str] | None = None,
             max_radius: float | None = None,
             stated_noise: Sequence[float] | None = None) -> Identified:
    """Identify a plant file from fault-free records (module doc).

    Parameters
    ----------
    fit : sequence of Dataset
        Records to fit on (fault free).
    holdout : sequence of Dataset
        Held-out records (validation and bounds); empty: the last ``split`` of each fit record.
    name : str
        Plant name ([A-Za-z_][A-Za-z0-9_]*).
    model : str
        ``auto`` (lowest held-out one-step RMS), ``linear``, ``affine`` or ``sparse``.
    modes : str
        ``offset`` (shared A, B, an offset per mode) or ``full`` (each mode its own).
    guards : sequence of str
        Conditions ``"h3 > 0.35"``.
    margin : float
        Factor (>= 1) on every bound.
    split : float
        Held-out fraction of each fit record when ``holdout`` is empty, in (0, 1).
    max_window : float
        Longest moving-average window the uncertainty bound looks through, s: a modelling
        error smaller than the noise shows only in averages (the ``thresholds`` designer's
        filters are at most 2 s long by default).
    estimator : str
        ``iv`` (lagged instruments), ``ls``, ``n4sid`` (subspace, ``nfoursid``; one mode,
        affine) or ``auto`` (every one, the lowest held-out simulation error).
    sparsity : float
        STLSQ threshold of ``sparse``.
    sample_time : float, optional
        s; default from the records.
    exclude_inputs : sequence of str
        Inputs left out of the fit (zero columns of B).
    sources : sequence of str, optional
        How the records were given, for the provenance (default their names).
    max_radius : float, optional
        Clip the eigenvalue magnitudes of a mode's A to it and refit B and the offsets
        (closed-loop data often leave a plant's slowest mode unexcited and its fitted
        eigenvalue a hair above 1; the ``thresholds`` estimator needs a stable model).
    stated_noise : sequence of float, optional
        The measurement-noise bound from the sensors' datasheet (one per output, or one for
        every output; output units): used as it is (assumed, not measured) instead of the
        bound measured on the held-out data; the uncertainty bounds are measured against it.

    Raises
    ------
    IdentificationError
        Data it cannot identify from, or bad options (one line each).
    """
    _check_options(fit, holdout, name, model, modes, estimator, margin, split, max_radius)
    every = [*fit, *holdout]
    for d in every:
        d.check()
    _check_channels(every)
    inputs, outputs = fit[0].inputs, fit[0].outputs
    Ts = _sample_time(every, sample_time)
    use_mode = fit[0].mode is not None
    if use_mode and guards:
        raise IdentificationError("give either --guard conditions or a mode channel, not both")
    conds = tuple(parse_guard(g, inputs, outputs) for g in guards)
    for nm in exclude_inputs:
        if nm not in inputs:
            raise IdentificationError(f"--exclude-input {nm}: not an input (inputs: "
                                      f"{', '.join(inputs)})")
    left_out = sorted({inputs.index(nm) for nm in exclude_inputs}
                      | {c.index for c in conds if c.kind == "controlled"})
    W = max(1, round(max_window / Ts))

    # one-step rows: fit part and held-out part (held-out bags, or the tail of each fit bag)
    if holdout:
        R_fit = _rows(fit, [(0, d.k.size) for d in fit], conds, use_mode)
        R_val = _rows(holdout, [(0, d.k.size) for d in holdout], conds, use_mode, seg0=1 << 40)
        val_sets = list(holdout)
    else:
        cut = [round((1.0 - split) * d.k.size) for d in fit]
        R_fit = _rows(fit, [(0, c) for c in cut], conds, use_mode)
        R_val = _rows(fit, [(c, d.k.size) for c, d in zip(cut, fit)], conds, use_mode,
                      seg0=1 << 40)
        val_sets = list(fit)
    tab = _mode_table(R_fit, conds, use_mode, len(outputs) + len(inputs) - len(left_out) + 1,
                      modes)
    Rf, qf = tab.select(R_fit)
    Rv, qv = tab.select(R_val)
    fit_inputs = _excited(Rf, inputs, left_out)
    held = Rv.size > 0
    Re, qe = (Rv, qv) if held else (Rf, qf)     # what validation and bounds are taken from
    candidates = _fit_candidates(Rf, qf, Re, qe, tab, model, modes, estimator, fit_inputs,
                                 sparsity, max_radius)
    # `auto` (of the model or the estimator) keeps the lowest held-out simulation error (mean
    # over the outputs of 100 - fit %, MATLAB's `compare`); a single candidate is itself.
    # Equal scores (within 1e-9 relative: round-off, e.g. `sparse` keeping every term of
    # `affine`) go to the fewer parameters, then the first candidate, so the pick does not
    # depend on the last bits of a machine's floating-point sums.
    # On closed-loop data (an input reacts to the output noise of the sample before) least
    # squares is biased, and its simulation with the measured inputs is rewarded for the bias:
    # the input carries the controller's reaction to the noise, which a biased model reads as
    # the input's effect (three_tank: ls simulates h2 at 50 % fit against iv's 12 % with a
    # pump gain of 58 for the true 6.5). Its candidates are then listed, not chosen.
    ref = next((c for c in candidates if c["estimator"] != "ls"), candidates[0])
    loop = closed_loop([Rf, Re], [_errors(ref["models"], Rf, qf), _errors(ref["models"], Re, qe)],
                       fit_inputs, inputs)
    eligible = [c for c in candidates
                if not (estimator == "auto" and loop["inputs"] and c["estimator"] == "ls")]
    s0 = min(c["sim_error"] for c in eligible)
    best = min(eligible, key=lambda c: (
        c["sim_error"] if not c["sim_error"] <= s0 + 1e-9 * max(abs(s0), 1e-300) else -1.0,
        c["parameters"]))
    Ms = best["models"]
    given = _stated_noise(stated_noise, outputs)
    bnd = _bounds(Ms, Rf, qf, Re, qe, margin, W, held, given)
    env = _envelope([Rf, Rv], [qf, qv], tab.names, inputs, outputs)
    k0 = _keys(fit[0], conds, use_mode)[0]
    doc = _plant_doc(name, Ts, inputs, outputs, tab, Ms, bnd, env, conds,
                     tab.names[tab.key_to_q.get(int(k0), 0)], fit[0].y[0])
    doc["description"] = (f"Identified from {len(fit)} fault-free record(s) by fd_monitor "
                          f"identify ({best['kind']} modes, {modes}; {best['estimator']}); "
                          f"bounds from {Re.size} {bnd['source']} one-step samples x margin "
                          f"{margin:g}")
    bags = [{"bag": src, "sha256": d.sha256, "samples": int(d.k.size)}
            for src, d in zip(sources or [d.name for d in every], every)]
    Ef, Ev = _errors(Ms, Rf, qf), _errors(Ms, Re, qe)
    quality = _quality(best, Ms, Rf, qf, Re, qe, Ev, tab, modes, fit_inputs, sparsity,
                       max_radius, inputs, outputs, Ts, bnd, given is not None, loop)
    summary: dict[str, Any] = {
        "plant": name,
        "model": best["kind"], "model_requested": model, "modes_structure": modes,
        "estimator": best["estimator"], "estimator_requested": estimator,
        "sample_time": Ts, "margin": margin,
        "max_radius": max_radius, "max_window_samples": W,
        "fit_bags": bags[:len(fit)], "holdout_bags": bags[len(fit):],
        "holdout": "bags" if holdout else f"last {split:g} of each fit bag",
        "fit_samples": int(Rf.size), "validation_samples": int(Rv.size),
        "candidates": [{"model": c["kind"], "estimator": c["estimator"],
                        "validation_rms": c["rms"], "parameters": c["parameters"],
                        "simulation_fit": _floats(np.where(np.isfinite(c["sim_fit"]),
                                                           c["sim_fit"], -1e300)),
                        "simulation_error": c["sim_error"] if math.isfinite(c["sim_error"])
                        else None,
                        "chosen": c is best} for c in candidates],
        "fit_rms": _floats(rms(Ef)), "validation_rms": _floats(rms(Ev)),
        "validation_max_abs": _floats(np.abs(Ev).max(axis=0)),
        "outputs": list(outputs), "inputs": list(inputs),
        "fitted_inputs": [inputs[j] for j in fit_inputs],
        "measurement_noise": {"bound": _floats(bnd["v_bar"]), "explained": _floats(bnd["v"]),
                              "samples": int(Re.size), "source": bnd["source"],
                              "assumed": given is not None},
        "modes": [{"name": tab.names[q], "fit_samples": int((qf == q).sum()),
                   "validation_samples": int((qv == q).sum()),
                   "fit_seconds": float((qf == q).sum() * Ts),
                   "validation_seconds": float((qv == q).sum() * Ts),
                   "uncertainty": _floats(bnd["eta"][q]),
                   "uncertainty_excess": _floats(bnd["excess"][q]),
                   "uncertainty_samples": bnd["samples"][q], "source": bnd["sources"][q],
                   "one_step_bound": _floats(one_step_bound(Ms[q].A, bnd["v_bar"],
                                                            bnd["eta"][q])),
                   "spectral_radius": spectral_radius(Ms[q].A)}
                  for q in range(len(Ms))],
        "not_covered": tab.not_covered,
        "envelope": env,
        "quality": quality,
        "closed_loop": {**loop, "least_squares_chosen_from": not (
            estimator == "auto" and loop["inputs"])},
        "warnings": [*quality["warnings"]],
    }
    text = _render(doc, summary)
    system = parse_system(yaml.safe_load(text), f"<identified {name}>")
    validation = _validation(Ms, Re, qe, bnd["v_bar"], bnd["eta"], val_sets if held else fit,
                             outputs)
    if validation:
        validation["simulation"] = quality.pop("_simulation_trace", {})
    else:
        quality.pop("_simulation_trace", None)
    return Identified(doc, text, system, summary, validation, tuple(Ms), conds,
                      tuple(tab.keys), use_mode, bnd["v_bar"], np.array(bnd["eta"]))


def _quality(best: Mapping[str, Any], Ms: Sequence[AffineModel], Rf: _Rows, qf: np.ndarray,
             Re: _Rows, qe: np.ndarray, Ev: np.ndarray, tab: _ModeTable, modes: str,
             fit_inputs: np.ndarray, sparsity: float, max_radius: float | None,
             inputs: Sequence[str], outputs: Sequence[str], Ts: float,
             bnd: Mapping[str, Any], assumed: bool, loop: dict[str, Any]) -> dict[str, Any]:
    """Model quality of the chosen candidate (:mod:`fd_monitor.analysis.identify_quality`)."""
    nmod = len(tab.keys)
    est, kind = best["estimator"], best["kind"]

    def stats_of(rows: np.ndarray | None = None,
                 at: Sequence[AffineModel] | None = None) -> list[dict[str, Any]]:
        R, q = (Rf, qf) if rows is None else (Rf.take(rows), qf[rows])
        if est == "n4sid" and at is None:         # the n4sid model itself, at these rows
            at = _fit_one(Rf, qf, nmod, kind, modes, est, fit_inputs, sparsity, None, rows)
        return coefficient_statistics(R, q, nmod, kind=kind, per_mode=modes,
                                      estimator="ls" if est == "n4sid" else est,
                                      inputs=fit_inputs, mode_names=tab.names, at=at)

    stats = stats_of()
    sim = simulation(Ms, Re, qe)
    # the noise's standard deviation from the held-out errors' high-frequency part, per mode
    # (weighted by its samples)
    s2, cnt = np.zeros(len(outputs)), 0
    for q in range(nmod):
        m = qe == q
        if m.sum() > 3:
            Rq = Re.take(m)
            brk = np.ones(Rq.size, dtype=bool)
            brk[1:] = (np.diff(Rq.k) != 1) | (np.diff(Rq.seg) != 0)
            s2 += m.sum() * hf_noise_std(Ev[m], Ms[q].A, brk) ** 2
            cnt += int(m.sum())
    sigma = np.sqrt(s2 / max(cnt, 1))
    exc, exc_warn = excitation(Rf, qf, Re, qe, Ev, stats, inputs=inputs,
                               fit_inputs=fit_inputs, mode_names=tab.names, per_mode=modes,
                               sigma=sigma, Ts=Ts, As=[M.A for M in Ms], loop=loop)
    noise_rows, noise_warn = noise_check(np.asarray(bnd["v_bar"]), sigma, outputs, assumed)
    half = halves(lambda rows: _fit_one(Rf, qf, nmod, kind, modes, est, fit_inputs, sparsity,
                                        max_radius, rows),
                  Rf, lambda M: np.asarray(simulation(M, Re, qe)["fit"]), stats_of,
                  np.asarray(sim["fit"]), outputs, inputs)
    coef = []
    for st in stats:
        e = st["eig"]
        z = float(e["z"])
        coef.append({
            "mode": st["mode"], "samples": st["samples"], "condition_number": st["condition"],
            "rank": st["rank"], "columns": st["columns"],
            "A": _floats(st["A"]), "se_A": _floats(st["se_A"]),
            "B": _floats(st["B"]), "se_B": _floats(st["se_B"]),
            "eigenvalues": [{"real": float(lam.real), "imag": float(lam.imag),
                             "se_real": float(sr), "se_imag": float(si),
                             "interval_real": [float(lam.real - z * sr),
                                               float(lam.real + z * sr)],
                             "interval_imag": [float(lam.imag - z * si),
                                               float(lam.imag + z * si)]}
                            for lam, sr, si in zip(e["eig"], e["se_real"], e["se_imag"])],
            "interval_level": float(e["level"]), "interval_z": z})
    bounds = [{"bound": "measurement_noise",
               "how": ("assumed (--noise-bound, the sensor's datasheet)" if assumed else
                       f"measured: LP on {bnd['samples_noise']} {bnd['source']} one-step "
                       f"errors x margin"),
               "samples": 0 if assumed else int(bnd["samples_noise"]),
               "seconds": 0.0 if assumed else float(bnd["samples_noise"] * Ts)}]
    bounds += [{"bound": f"uncertainty {nm}",
                "how": f"measured: window means of {bnd['sources'][q]} one-step errors over the "
                       f"noise bound x margin",
                "samples": int(bnd["samples"][q]), "seconds": float(bnd["samples"][q] * Ts)}
               for q, nm in enumerate(tab.names)]
    bounds.append({"bound": "envelope", "how": "measured: the range the fit and held-out "
                                               "data covered",
                   "samples": int(Rf.size + Re.size), "seconds": float((Rf.size + Re.size) * Ts)})
    warns = [*exc_warn, *noise_warn]
    if not half.get("stable", True):
        warns.append("how much data: " + half["verdict"])
    return {
        "simulation": {"fit_percent": _floats(np.where(np.isfinite(sim["fit"]), sim["fit"],
                                                       -1e300)),
                       "rms": _floats(np.where(np.isfinite(sim["rms"]), sim["rms"], 1e300)),
                       "samples": sim["samples"], "records": sim["records"],
                       "source": bnd["source"]},
        "one_step_rms": _floats(rms(Ev)),
        "coefficients": coef,
        "excitation": exc,
        "noise_check": noise_rows,
        "noise_std_hf": _floats(sigma),
        "bounds": bounds,
        "halves": {k: (_floats(v) if isinstance(v, np.ndarray) else v)
                   for k, v in half.items()},
        "warnings": warns,
        "_simulation_trace": {k: sim[k] for k in ("k", "measured", "simulated") if k in sim},
    }


def _stated_noise(values: Sequence[float] | None, outputs: Sequence[str]) -> np.ndarray | None:
    """``--noise-bound``: one value per output or one for all, each positive and finite."""
    if values is None:
        return None
    v = [float(x) for x in values]
    if len(v) not in (1, len(outputs)):
        raise IdentificationError(f"--noise-bound: expected 1 or {len(outputs)} values (one per "
                                  f"output: {', '.join(outputs)}), got {len(v)}")
    for x in v:
        if not (math.isfinite(x) and x > 0):
            raise IdentificationError(f"--noise-bound {x:g}: expected a positive number (output "
                                      f"units)")
    return np.array(v * len(outputs) if len(v) == 1 else v)


def _check_options(fit: Sequence[Dataset], holdout: Sequence[Dataset], name: str, model: str,
                   modes: str, estimator: str, margin: float, split: float,
                   max_radius: float | None) -> None:
    if not fit:
        raise IdentificationError("no bag to identify from")
    for opt, val, allowed in (("--model", model, MODELS), ("--modes", modes, PER_MODE),
                              ("--estimator", estimator, ESTIMATORS)):
        if val not in allowed:
            raise IdentificationError(f"{opt} {val!r}: expected one of {', '.join(allowed)}")
    if estimator == "n4sid" and model not in ("auto", "affine"):
        raise IdentificationError(f"--estimator n4sid: a subspace model is affine (offset from "
                                  f"the means), not {model} (use --model affine)")
    if not (math.isfinite(margin) and margin >= 1.0):
        raise IdentificationError(f"--margin {margin}: expected a number >= 1")
    if not holdout and not 0.0 < split < 1.0:
        raise IdentificationError(f"--split {split}: expected a fraction in (0, 1)")
    if max_radius is not None and not (math.isfinite(max_radius) and max_radius > 0):
        raise IdentificationError(f"--max-radius {max_radius}: expected a positive number")
    if not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", name):
        raise IdentificationError(f"--name {name!r}: expected letters, digits and _")


@dataclass(frozen=True)
class _ModeTable:
    """The modes: combination keys the fit data visit often enough, and their names."""

    keys: tuple[int, ...]
    names: tuple[str, ...]
    not_covered: list[dict[str, Any]]

    @property
    def key_to_q(self) -> dict[int, int]:
        return {kk: q for q, kk in enumerate(self.keys)}

    def select(self, R: _Rows) -> tuple[_Rows, np.ndarray]:
        """The rows of known modes and their mode indices."""
        Rk = R.take(np.isin(R.key, self.keys))
        lut = self.key_to_q
        return Rk, np.array([lut[int(kk)] for kk in Rk.key], dtype=int)


def _mode_name(key: int, conds: Sequence[GuardCondition], use_mode: bool) -> str:
    if use_mode:
        return f"mode_{key}"
    if conds:
        return "__".join(c.label(bool(key >> j & 1)) for j, c in enumerate(conds))
    return "nominal"


def _mode_table(R: _Rows, conds: Sequence[GuardCondition], use_mode: bool, p_row: int,
                modes: str) -> _ModeTable:
    """Modes with enough fit samples; refuses data too short for any."""
    need_total = SAMPLES_PER_COEFFICIENT * p_row
    need_mode = SAMPLES_PER_COEFFICIENT * (p_row if modes == "full" else 1)
    keys, counts = np.unique(R.key, return_counts=True)
    kept = [int(kk) for kk, c in zip(keys, counts) if c >= need_mode]
    if R.size < need_total or not kept:
        raise IdentificationError(
            f"too short: {R.size} one-step samples in the fit data"
            + (f" ({int(counts.max(initial=0))} in the best-covered mode)"
               if use_mode or conds else "")
            + f", at least {max(need_total, need_mode)} needed ({SAMPLES_PER_COEFFICIENT} per "
              f"coefficient of a {p_row}-coefficient row)")
    seen = {int(kk): int(c) for kk, c in zip(keys, counts)}
    every = sorted(seen) if use_mode else range(1 << len(conds))
    missing = [{"mode": _mode_name(kk, conds, use_mode), "fit_samples": seen.get(kk, 0)}
               for kk in every if kk not in kept]
    return _ModeTable(tuple(kept), tuple(_mode_name(kk, conds, use_mode) for kk in kept),
                      missing)


def _fit_one(Rf: _Rows, qf: np.ndarray, n_modes: int, kind: str, modes: str, estimator: str,
             fit_inputs: np.ndarray, sparsity: float, max_radius: float | None,
             rows: np.ndarray | None = None) -> list[AffineModel]:
    """One candidate's models (``rows``: a mask of the fit rows to use; default all)."""
    if rows is not None:
        Rf, qf = Rf.take(rows), qf[rows]
    if estimator == "n4sid":
        Ms = n4sid_models(Rf, n_modes, inputs=fit_inputs, nu=Rf.U.shape[1])
        if max_radius is not None and spectral_radius(Ms[0].A) > max_radius:
            A = clip_radius(Ms[0].A, max_radius)
            Ms = [AffineModel(A, Ms[0].B, Ms[0].offset, Ms[0].kind, Ms[0].parameters)]
        return Ms
    iv = estimator == "iv"
    sel = Rf.lag if iv else np.ones(Rf.size, dtype=bool)
    return fit_modes(Rf.X[sel], Rf.U[sel], Rf.Xn[sel], qf[sel], n_modes, kind=kind,
                     per_mode=modes, inputs=fit_inputs, Xp=Rf.Xp[sel] if iv else None,
                     Up=Rf.Up[sel] if iv else None, tol=sparsity, max_radius=max_radius)


def _fit_candidates(Rf: _Rows, qf: np.ndarray, Re: _Rows, qe: np.ndarray, tab: _ModeTable,
                    model: str, modes: str, estimator: str, fit_inputs: np.ndarray,
                    sparsity: float, max_radius: float | None) -> list[dict[str, Any]]:
    """Every requested (model kind, estimator) fitted, with its held-out one-step RMS over
    every output and its held-out simulation fit per output."""
    kinds = ["linear", "affine", "sparse"] if model == "auto" else [model]
    ests = ["ls", "iv", "n4sid"] if estimator == "auto" else [estimator]
    if estimator == "n4sid" and len(tab.names) != 1:
        raise IdentificationError(f"--estimator n4sid: one mode only (the data have "
                                  f"{len(tab.names)}: use --estimator iv or ls)")
    if estimator == "iv":
        for q, nm in enumerate(tab.names):
            if not np.any(Rf.lag & (qf == q)):
                raise IdentificationError(f"mode {nm}: no run of 3 consecutive samples for "
                                          f"the instrumental-variable fit (use --estimator ls)")
    out = []
    for est in ests:
        for kind in kinds:
            if est == "iv" and estimator == "auto" and not all(
                    np.any(Rf.lag & (qf == q)) for q in range(len(tab.names))):
                continue
            if est == "n4sid":
                # a subspace model: one mode, an offset from the means (listed once)
                if kind != kinds[0] or len(tab.names) != 1 or model not in ("auto", "affine"):
                    continue
                kind = "affine"
                try:
                    Ms = _fit_one(Rf, qf, 1, kind, modes, est, fit_inputs, sparsity,
                                  max_radius)
                except (IdentificationError, np.linalg.LinAlgError, ValueError,
                        IndexError) as exc:       # a failed optional candidate is skipped
                    if estimator == "n4sid":
                        raise IdentificationError(f"--estimator n4sid: {exc}") from None
                    continue
            else:
                Ms = _fit_one(Rf, qf, len(tab.keys), kind, modes, est, fit_inputs, sparsity,
                              max_radius)
            Ev = _errors(Ms, Re, qe)
            sim = simulation(Ms, Re, qe)
            fit = np.asarray(sim["fit"], dtype=float)
            score = float(np.mean(100.0 - fit)) if np.all(np.isfinite(fit)) else math.inf
            out.append({"kind": kind, "estimator": est, "models": Ms,
                        "rms": float(np.sqrt(np.mean(Ev ** 2))),
                        "parameters": Ms[0].parameters, "sim_fit": fit,
                        "sim_error": score})
    return out


def _bounds(Ms: Sequence[AffineModel], Rf: _Rows, qf: np.ndarray, Re: _Rows, qe: np.ndarray,
            margin: float, W: int, held: bool,
            given: np.ndarray | None = None) -> dict[str, Any]:
    """Noise bound (every mode's one-step errors, or ``given``: the sensor's datasheet bound,
    used as it is) and each mode's uncertainty bound."""
    source = "held-out" if held else "fit (no held-out sample)"
    Ef, Ee = _errors(Ms, Rf, qf), _errors(Ms, Re, qe)
    per_mode = []
    for q in range(len(Ms)):
        if np.any(qe == q):
            per_mode.append((Re.take(qe == q), Ee[qe == q], source))
        else:
            per_mode.append((Rf.take(qf == q), Ef[qf == q],
                             "fit (no held-out sample in this mode)"))
    v_bar, v = noise_bound([np.abs(E).max(axis=0) for _, E, _ in per_mode],
                           [M.A for M in Ms], margin)
    if given is not None:
        v_bar = np.asarray(given, dtype=float)
    out: dict[str, Any] = {"v_bar": v_bar, "v": v, "source": source, "eta": [], "excess": [],
                           "samples": [], "sources": [src for _, _, src in per_mode],
                           "samples_noise": int(sum(E.shape[0] for _, E, _ in per_mode))}
    for M, (rows, E, _) in zip(Ms, per_mode):
        eta, excess, cnt = uncertainty_bound(_segments(E, rows), M.A, v_bar, W, margin)
        out["eta"].append(eta)
        out["excess"].append(excess)
        out["samples"].append(cnt)
    return out


def _envelope(Rs: Sequence[_Rows], qs: Sequence[np.ndarray], names: Sequence[str],
              inputs: Sequence[str], outputs: Sequence[str]) -> dict[str, Any]:
    """The range of every state and input the data covered, narrowed per mode (the states a
    mode was seen at, y_k of its steps)."""
    def box(X: np.ndarray, labels: Sequence[str]) -> dict[str, list[float]]:
        return {nm: [float(X[:, i].min()), float(X[:, i].max())] for i, nm in enumerate(labels)}

    X = np.vstack([np.vstack([r.X, r.Xn]) for r in Rs])
    U = np.vstack([r.U for r in Rs])
    Xq = np.vstack([r.X for r in Rs])
    q = np.concatenate(qs)
    env: dict[str, Any] = {"states": box(X, outputs), "inputs": box(U, inputs)}
    if len(names) > 1:
        env["modes"] = {nm: {"states": box(Xq[q == j], outputs), "inputs": box(U[q == j], inputs)}
                        for j, nm in enumerate(names)}
    return env


def _plant_doc(name: str, Ts: float, inputs: Sequence[str], outputs: Sequence[str],
               tab: _ModeTable, Ms: Sequence[AffineModel], bnd: Mapping[str, Any],
               env: Mapping[str, Any], conds: Sequence[GuardCondition], mode0: str,
               x0: np.ndarray) -> dict[str, Any]:
    """The plant file as a mapping (``description`` filled in by the caller)."""
    doc: dict[str, Any] = {
        "format_version": 1, "name": name, "description": "", "time": "discrete",
        "sample_time": Ts, "states": list(outputs), "inputs": list(inputs),
        "outputs": list(outputs),
        "bounds": {"measurement_noise": _floats(bnd["v_bar"])},
        "shared": {"C": _floats(np.eye(len(outputs)))},
        "modes": {nm: {"dynamics": "linear", "A": _floats(M.A), "B": _floats(M.B),
                       "offset": _floats(M.offset), "uncertainty": _floats(eta)}
                  for nm, M, eta in zip(tab.names, Ms, bnd["eta"])},
    }
    if conds:
        doc["guards"] = _guards(conds, tab.keys, tab.key_to_q, tab.names)
    elif len(tab.names) > 1:
        doc["switching"] = "arbitrary"    # a measured mode channel: no guard decides
    doc["faults"] = ([{"name": f"bias_{o}", "kind": "sensor_bias", "output": o}
                      for o in outputs]
                     + [{"name": f"actuator_{u}", "kind": "actuator", "input": u}
                        for u in inputs])
    doc["envelope"] = dict(env)
    doc["initial"] = {"mode": mode0, "state": _floats(x0)}
    return doc


def _errors(Ms: Sequence[AffineModel], R: _Rows, q: np.ndarray) -> np.ndarray:
    E = np.zeros_like(R.X)
    for j, M in enumerate(Ms):
        m = q == j
        if m.any():
            E[m] = one_step_errors(M, R.X[m], R.U[m], R.Xn[m])
    return E


def _guards(conds: Sequence[GuardCondition], kept: Sequence[int], key_to_q: Mapping[int, int],
            names: Sequence[str]) -> list[dict[str, Any]]:
    """Guards between modes that differ in one condition, both ways."""
    out = []
    for a, b in itertools.permutations(kept, 2):
        diff = a ^ b
        if diff == 0 or diff & (diff - 1):
            continue
        j = diff.bit_length() - 1
        c = conds[j]
        op = c.op if b >> j & 1 else _NEG[c.op]
        out.append({"name": f"{names[key_to_q[a]]}_to_{names[key_to_q[b]]}"[:120],
                    "from": names[key_to_q[a]], "to": names[key_to_q[b]], "kind": c.kind,
                    "when": [{"var": c.var, "op": op, "value": c.value}]})
    return out


def _floats(a: Any) -> Any:
    """numpy -> nested lists of Python floats (YAML writes them with every digit)."""
    arr = np.asarray(a, dtype=float)
    return [_floats(r) for r in arr] if arr.ndim else float(arr) + 0.0


def _render(doc: Mapping[str, Any], summary: Mapping[str, Any]) -> str:
    """Provenance comments + the YAML of ``doc`` (matrices one row per line)."""
    lines = [
        f"# Plant {doc['name']}: identified by `python -m fd_monitor identify` from fault-free",
        "# bags (fd_monitor.analysis.identify). No date: the same bags and options give the",
        "# same file. States = the measured outputs (C = I, y = x + v).",
        f"# model: {summary['model']} modes, structure {summary['modes_structure']} "
        f"(offset: shared A, B and one offset per mode), estimator {summary['estimator']}"
        f" (iv: lagged measurements as instruments)",
        "# candidates (held-out one-step RMS over every output; simulation fit %, MATLAB "
        "compare):",
        *(f"#   {c['model']}/{c['estimator']} {c['validation_rms']:.4g}; "
          + ", ".join(_pct(f) for f in c["simulation_fit"])
          + (" (chosen: the lowest simulation error" + (
              "" if summary["closed_loop"]["least_squares_chosen_from"] else
              "; closed-loop data: least squares not chosen") + ")"
             if c["chosen"] and len(summary["candidates"]) > 1 else "")
          for c in summary["candidates"]),
        "# fit bags:",
        *(f"#   {b['bag']}  sha256 {b['sha256']}  ({b['samples']} samples)"
          for b in summary["fit_bags"]),
        f"# held out: {summary['holdout']}",
        *(f"#   {b['bag']}  sha256 {b['sha256']}  ({b['samples']} samples)"
          for b in summary["holdout_bags"]),
        f"# one-step samples: {summary['fit_samples']} fit, {summary['validation_samples']} "
        f"held out; RMS per output ({', '.join(summary['outputs'])}):",
        f"#   fit        {_vec(summary['fit_rms'])}",
        f"#   validation {_vec(summary['validation_rms'])} (max abs "
        f"{_vec(summary['validation_max_abs'])})",
        f"# bounds.measurement_noise = {summary['margin']:g} x the smallest noise bound that "
        f"explains every",
        f"#   {summary['measurement_noise']['source']} one-step error "
        f"({summary['measurement_noise']['samples']} samples): "
        f"{_vec(summary['measurement_noise']['explained'])}",
        f"# modes.*.uncertainty = {summary['margin']:g} x the largest excess of a "
        f"moving-average window (1..{summary['max_window_samples']} samples)",
        "#   of the one-step error over its noise bound, per mode:",
        *(f"#   {m['name']}: {m['uncertainty_samples']} samples ({m['source']}), excess "
          f"{_vec(m['uncertainty_excess'])}; one-step bound {_vec(m['one_step_bound'])}"
          for m in summary["modes"]),
        "# envelope: the range of every state and input the data covered (the region these",
        "# bounds hold in; a `design thresholds --envelope declared` certifies exactly it).",
    ]
    q = summary["quality"]
    lines.append("# quality (held-out): simulation fit % "
                 + ", ".join(_pct(f) for f in q["simulation"]["fit_percent"])
                 + "; regression condition number "
                 + ", ".join(f"{c['condition_number']:.3g}" for c in q["coefficients"])
                 + f"; {len(summary['warnings'])} warning(s)")
    lines += [f"#   WARNING: {w}"[:2000] for w in summary["warnings"]]
    if summary["not_covered"]:
        lines.append("# not covered by the data (no mode): " + ", ".join(
            f"{m['mode']} ({m['fit_samples']} fit samples)" for m in summary["not_covered"]))
    body = yaml.safe_dump(dict(doc), sort_keys=False, default_flow_style=None, width=100,
                          allow_unicode=False)
    return "\n".join(lines) + "\n" + body


def _pct(x: float) -> str:
    return "diverges" if x < -1e6 else f"{x:.2f}"


def add_physical(result: Identified, adapter: Any) -> list[dict[str, Any]]:
    """Physical parameters of the joints an adapter names, into ``summary['quality']``
    (:func:`fd_monitor.analysis.identify_quality.physical_parameters`)."""
    s = result.summary
    phys = physical_parameters(adapter, result.models, [m["name"] for m in s["modes"]],
                               s["inputs"], s["outputs"], float(s["sample_time"]))
    s["quality"]["physical"] = phys
    return phys


def _vec(v: Sequence[float]) -> str:
    return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"


def _validation(Ms: Sequence[AffineModel], R: _Rows, q: np.ndarray, v_bar: np.ndarray,
                eta: Sequence[np.ndarray], sets: Sequence[Dataset],
                outputs: Sequence[str]) -> dict[str, Any]:
    """Held-out one-step predictions of the first held-out record (for the plot)."""
    if R.size == 0:
        return {}
    d0 = int(R.ds[0])
    m = R.ds == d0
    Rm, qm = R.take(m), q[m]
    pred = Rm.Xn - _errors(Ms, Rm, qm)
    bound = np.array([one_step_bound(Ms[j].A, v_bar, eta[j]) for j in qm])
    return {"record": sets[d0].name, "k": Rm.k + 1, "measured": Rm.Xn, "predicted": pred,
            "bound": bound, "outputs": list(outputs)}


def identify_bags(bags: Sequence[str | Path], *, holdout: Sequence[str | Path] = (),
                  u_topic: str = PLANT_U.absolute, y_topic: str = PLANT_Y.absolute,
                  mode_topic: str | None = None, adapter: Any = None, strict: bool = False,
                  integrity: dict[str, Any] | None = None,
                  progress: Callable[[str], Any] | None = None, **options: Any) -> Identified:
    """:func:`identify` on bags (read with :func:`load_dataset`, ``strict`` and
    ``integrity`` as there); ``options`` as there; ``progress`` is called with a line
    before each bag is read and before the fit."""
    if not bags:
        raise IdentificationError("no bag to identify from")
    read = dict(u_topic=u_topic, y_topic=y_topic, mode_topic=mode_topic, adapter=adapter,
                sample_time=options.get("sample_time"), strict=strict, integrity=integrity)
    say = progress or (lambda _line: None)
    every = [*bags, *holdout]
    fit: list[Dataset] = []
    held: list[Dataset] = []
    for i, b in enumerate(every):
        say(f"identify: reading {b} ({i + 1}/{len(every)})")
        (fit if i < len(bags) else held).append(load_dataset(b, **read))
    say(f"identify: fitting {len(fit)} record(s), {len(held)} held out")
    return identify(fit, held, sources=[str(b) for b in [*bags, *holdout]], **options)


def write_plant(result: Identified, path: str | Path, force: bool = False) -> Path:
    """Write the plant file (refuses to overwrite unless ``force``)."""
    out = Path(path)
    if out.is_dir():
        raise IdentificationError(f"{out}: is a folder, expected a file name")
    if out.exists() and not force:
        raise IdentificationError(f"{out}: exists (would overwrite; use --force)")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(result.text, encoding="utf-8")
    except OSError as exc:
        raise IdentificationError(f"{out}: cannot write there: {exc.strerror}") from None
    return out


def plot_validation(result: Identified, path: str | Path) -> Path:
    """PNG: held-out measured vs one-step predicted per output, the error in its bound, and
    the multi-step (free-run) simulation vs the measurement (the one-step plot always looks
    good; the simulation shows what the model does on its own)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    v = result.validation
    if not v:
        raise IdentificationError("no held-out sample to plot")
    ny = len(v["outputs"])
    sim = v.get("simulation") or {}
    fig, axes = plt.subplots(ny, 3, figsize=(15, 2.4 * ny), squeeze=False)
    Ts = float(result.system.sample_time)
    t = v["k"] * Ts
    fits = result.summary.get("quality", {}).get("simulation", {}).get("fit_percent", [])
    for i, o in enumerate(v["outputs"]):
        ax = axes[i][0]
        ax.plot(t, v["measured"][:, i], lw=0.8, label="measured y(k+1)")
        ax.plot(t, v["predicted"][:, i], lw=0.8, label="one-step predicted")
        ax.set_ylabel(o)
        ax = axes[i][1]
        ax.plot(t, v["measured"][:, i] - v["predicted"][:, i], lw=0.6, label="error")
        ax.plot(t, v["bound"][:, i], "k--", lw=0.8, label="stated bound")
        ax.plot(t, -v["bound"][:, i], "k--", lw=0.8)
        if i == 0:
            axes[0][0].legend(fontsize=7)
            ax.legend(fontsize=7)
        ax = axes[i][2]
        if sim:
            ts = sim["k"] * Ts
            ax.plot(ts, sim["measured"][:, i], lw=0.8, label="measured")
            with np.errstate(invalid="ignore"):
                ax.plot(ts, np.clip(sim["simulated"][:, i], -1e300, 1e300), lw=0.8,
                        label="simulated (free run)")
            if i < len(fits):
                ax.set_title(f"simulation fit {_pct(fits[i])} % (all held-out records)",
                             fontsize=8)
            if i == 0:
                ax.legend(fontsize=7)
    for j in range(3):
        axes[-1][j].set_xlabel("t (s)")
    fig.suptitle(f"{result.summary['plant']}: held-out one-step prediction ({v['record']}) "
                 f"and multi-step simulation", fontsize=9)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out
