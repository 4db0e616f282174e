"""The scenario bag library: ``bags/library.yaml``, regenerating its bags, checking expectations.

The library is a spec file listing small rosbag2 MCAP bags, each simulated from a scenario
file with a fixed seed and duration (so ``python -m fd_monitor simulate --library
bags/library.yaml`` rebuilds every bag bit for bit) and analysed with a named gain file::

    format_version: 1
    bags:
      - name: three_tank_bias_h1                 # bags/<name>/ is the bag folder
        scenario: bag_three_tank_bias_h1         # shipped name (config/scenarios/) or path
        seed: 12
        duration: 250.0                          # s
        gains: three_tank_thresholds             # shipped name (config/gains/) or path
        transient: 0.0                           # s: alarms before it are not counted
        live: true                               # also replayed through the live nodes
        corruptions: []                          # bad input applied to the messages

Each bag folder holds ``metadata.yaml``, ``<name>.mcap`` (zstd-compressed chunks) and
``expected.yaml``: what analysing the bag must give (see :func:`check_expected`)::

    alarms:                       # channel -> first alarm sample k (after the transient)
      h1: {first_sample: 1000, tolerance: 10}
    no_alarm: [h2, h3]            # channels that never alarm (after the transient)
    isolated: [h1]                # exactly the isolated channels at the end
    bias_estimate:                # final estimate, output units, |value - expected| <= tol
      h1: {value: 0.03, tolerance: 0.003}
    modes: [closed_dry]           # estimated mode sequence (repeats collapsed)
    mode_min_dwell: 1             # runs shorter than this (samples) are dropped first
    input_errors:                 # bad-input bag: what the monitor must report, by kind
      non_finite: [300, 301]      # sample stamps
      missing: [[700, 749]]       # runs of stamps with no message at all
    restarts: [451, 650]          # samples at which the monitor restarted (after a hole)

Corruptions (applied to the simulated messages, in this order; ``samples`` are stamps k):

* ``{kind: nan, topic, channel, samples}`` -- that channel's value is NaN;
* ``{kind: wrong_length, topic, samples}`` -- the message loses its last channel;
* ``{kind: gap, start, samples}`` -- no message on any topic for stamps
  ``start .. start + samples - 1`` (a hole of ``samples * Ts`` seconds);
* ``{kind: duplicate, topic, samples}`` -- the message is recorded twice;
* ``{kind: out_of_order, topic, samples}`` -- messages k and k + 1 are recorded in the
  opposite order (stamp k + 1 arrives first).

Nothing here imports rclpy; the analysis itself is :func:`fd_monitor.analysis.offline.run_bag` (the
same run as ``python -m fd_monitor analyze``), summarised by :func:`analyze_summary`.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.analysis.offline import (
    INPUT_ERROR_KINDS,
    collapse,
    run_bag,
    summarize_run,
)
from fd_monitor.model.errors import FdMonitorError, ScenarioError
from fd_monitor.wire.topics import PLANT_TRUTH, PLANT_U, PLANT_Y, side_topic

__all__ = [
    "CORRUPTION_KINDS",
    "BagSpec",
    "Corruption",
    "Library",
    "LibraryError",
    "analyze_summary",
    "bag_messages",
    "check_expected",
    "check_truth",
    "core_summary",
    "default_library",
    "expected_path",
    "generate_bag",
    "generate_library",
    "load_expected",
    "load_library",
    "propose_expected",
    "read_bag_truth",
    "settled_modes",
    "truth_facts",
    "write_expected",
]

CORRUPTION_KINDS = ("nan", "wrong_length", "gap", "duplicate", "out_of_order")

FORMAT_VERSION = 1


class LibraryError(FdMonitorError, ValueError):
    """The library spec or an expected.yaml is invalid (file and key named)."""


# --------------------------------------------------------------------------------------
# spec


@dataclass(frozen=True)
class Corruption:
    """One corruption of the simulated messages (see the module docstring).

    Attributes
    ----------
    kind : str
        One of :data:`CORRUPTION_KINDS`.
    topic : str
        Topic it applies to (``gap``: every topic).
    samples : tuple of int
        Stamps k it applies to (``gap``: the first missing stamp and the count).
    channel : str or None
        ``nan`` only: the channel set to NaN.
    """

    kind: str
    topic: str = PLANT_Y.absolute
    samples: tuple[int, ...] = ()
    channel: str | None = None


@dataclass(frozen=True)
class BagSpec:
    """One bag of the library.

    Attributes
    ----------
    name : str
    scenario : str
        Scenario name or path (resolved against the spec's folder first).
    seed : int
    duration : float
        s
    gains : str
        Gain file name or path.
    transient : float
        s; alarms before it do not count (QB observers: the bound holds after eq. 5's
        transient).
    live : bool
        Part of the live-node regression subset.
    description : str
    corruptions : tuple of Corruption
    folder : pathlib.Path
        The bag folder (``<library folder>/<name>``).
    """

    name: str
    scenario: str
    seed: int
    duration: float
    gains: str
    transient: float = 0.0
    live: bool = False
    description: str = ""
    corruptions: tuple[Corruption, ...] = ()
    folder: Path = Path(".")

    @property
    def expected_file(self) -> Path:
        """``<folder>/expected.yaml``."""
        return self.folder / "expected.yaml"


@dataclass(frozen=True)
class Library:
    """A loaded ``library.yaml``.

    Attributes
    ----------
    path : pathlib.Path
    bags : tuple of BagSpec
    """

    path: Path
    bags: tuple[BagSpec, ...]

    def __getitem__(self, name: str) -> BagSpec:
        for b in self.bags:
            if b.name == name:
                return b
        raise LibraryError(f"{self.path}: no bag {name!r} (bags: "
                           f"{', '.join(b.name for b in self.bags)})")

    @property
    def names(self) -> tuple[str, ...]:
        """Bag names in spec order."""
        return tuple(b.name for b in self.bags)


def default_library() -> Path:
    """``bags/library.yaml`` beside the shipped ``config/``: of the source checkout, or
    ``share/fd_monitor/bags`` of a pip or colcon install."""
    from fd_monitor.model.paths import config_dirs

    for d in config_dirs():
        if (d.parent / "bags" / "library.yaml").is_file():
            return d.parent / "bags" / "library.yaml"
    raise LibraryError("no bag library found (bags/library.yaml): give the path of a "
                       "library.yaml")


def _fail(origin: Any, key: str, expected: str, got: Any = None) -> None:
    tail = "" if got is None else f", got {got!r}"
    raise LibraryError(f"{origin}: {key}: expected {expected}{tail}")


def _int_list(origin: Any, key: str, v: Any) -> tuple[int, ...]:
    if isinstance(v, int) and not isinstance(v, bool):
        v = [v]
    if not isinstance(v, list) or not v or not all(
            isinstance(i, int) and not isinstance(i, bool) and i >= 0 for i in v):
        _fail(origin, key, "a non-empty list of sample indices >= 0", v)
    return tuple(int(i) for i in v)


def _corruption(origin: Any, key: str, c: Any) -> Corruption:
    if not isinstance(c, Mapping) or c.get("kind") not in CORRUPTION_KINDS:
        _fail(origin, f"{key}.kind", f"one of {list(CORRUPTION_KINDS)}",
              c.get("kind") if isinstance(c, Mapping) else c)
    kind = str(c["kind"])
    allowed = {"kind", "topic", "samples", "channel", "start"}
    extra = set(c) - allowed
    if extra:
        _fail(origin, f"{key}.{sorted(extra)[0]}", f"one of {sorted(allowed)} (unknown key)")
    topic = str(c.get("topic", PLANT_Y.absolute))
    if kind == "gap":
        if "start" not in c or "samples" not in c:
            _fail(origin, key, "{kind: gap, start: k0, samples: count}", dict(c))
        start = _int_list(origin, f"{key}.start", c["start"])
        count = c["samples"]
        if not isinstance(count, int) or isinstance(count, bool) or count < 1:
            _fail(origin, f"{key}.samples", "a count >= 1", count)
        return Corruption(kind, "*", (start[0], int(count)))
    if "samples" not in c:
        _fail(origin, f"{key}.samples", "a list of sample indices (missing key)")
    samples = _int_list(origin, f"{key}.samples", c["samples"])
    channel = None
    if kind == "nan":
        if not isinstance(c.get("channel"), str):
            _fail(origin, f"{key}.channel", "the channel to set to NaN", c.get("channel"))
        channel = str(c["channel"])
    return Corruption(kind, topic, samples, channel)


def load_library(path: str | Path | None = None) -> Library:
    """Load and validate a library spec (default ``bags/library.yaml``).

    Raises
    ------
    LibraryError
        One line naming the file and the key.
    """
    from fd_monitor.model.system import read_yaml

    p = Path(path) if path is not None else default_library()
    if not p.is_file():
        raise LibraryError(f"{p}: library spec not found")
    data = read_yaml(p, LibraryError)
    if not isinstance(data, Mapping) or not isinstance(data.get("bags"), list):
        _fail(p, "bags", "a list of bag entries")
    if (isinstance(data.get("format_version"), bool)
            or data.get("format_version", FORMAT_VERSION) != FORMAT_VERSION):
        _fail(p, "format_version", str(FORMAT_VERSION), data.get("format_version"))
    bags: list[BagSpec] = []
    seen: set[str] = set()
    for i, e in enumerate(data["bags"]):
        key = f"bags[{i}]"
        if not isinstance(e, Mapping):
            _fail(p, key, "a mapping {name, scenario, seed, duration, gains, ...}", e)
        allowed = {"name", "scenario", "seed", "duration", "gains", "transient", "live",
                   "description", "corruptions"}
        extra = set(e) - allowed
        if extra:
            _fail(p, f"{key}.{sorted(extra)[0]}", f"one of {sorted(allowed)} (unknown key)")
        for req in ("name", "scenario", "seed", "duration", "gains"):
            if req not in e:
                _fail(p, f"{key}.{req}", "a value (missing key)")
        name = str(e["name"])
        if not name.replace("_", "").isalnum() or name in seen:
            _fail(p, f"{key}.name", "a unique name of letters, digits and _", name)
        seen.add(name)
        seed = e["seed"]
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            _fail(p, f"{key}.seed", "an integer >= 0", seed)
        dur = e["duration"]
        if isinstance(dur, bool) or not isinstance(dur, (int, float)) or not dur > 0:
            _fail(p, f"{key}.duration", "a duration > 0 in s", dur)
        tr = e.get("transient", 0.0)
        if isinstance(tr, bool) or not isinstance(tr, (int, float)) or tr < 0:
            _fail(p, f"{key}.transient", "a time >= 0 in s", tr)
        cors = e.get("corruptions") or []
        if not isinstance(cors, list):
            _fail(p, f"{key}.corruptions", "a list", cors)
        scen = str(e["scenario"])
        rel = p.parent / scen
        bags.append(BagSpec(
            name=name, scenario=str(rel) if rel.is_file() else scen, seed=int(seed),
            duration=float(dur), gains=str(e["gains"]), transient=float(tr),
            live=bool(e.get("live", False)), description=str(e.get("description", "")),
            corruptions=tuple(_corruption(p, f"{key}.corruptions[{j}]", c)
                              for j, c in enumerate(cors)),
            folder=p.parent / name))
    return Library(p, tuple(bags))


# --------------------------------------------------------------------------------------
# generation


@dataclass
class _Msg:
    t_ns: int
    topic: str
    stamp: int
    labels: tuple[str, ...]
    values: np.ndarray


def bag_messages(spec: BagSpec) -> tuple[list[_Msg], Any]:
    """Simulate ``spec`` and return its messages in recording order, corruptions applied.

    Returns
    -------
    (list, Scenario)
        Messages (bag timestamp ``k Ts`` in ns, topic, stamp, labels, values), and the
        scenario.
    """
    from fd_monitor.core.simulator import (
        measured_signals,
        simulate,
        truth_values,
    )
    from fd_monitor.model.scenario import load_scenario

    sc = load_scenario(spec.scenario)
    sys_ = sc.system
    dt = sys_.sample_time
    K = max(1, round(spec.duration / dt))
    traj = simulate(sc, spec.seed, K)
    topics = {PLANT_U.absolute: (PLANT_U.labels(sys_), traj.u[0]),
              PLANT_Y.absolute: (PLANT_Y.labels(sys_), traj.y[0]),
              **{side_topic(n).absolute: lv for n, lv in measured_signals(traj).items()},
              PLANT_TRUTH.absolute: (PLANT_TRUTH.labels(sc), truth_values(traj))}
    msgs = [_Msg(round(k * dt * 1e9), topic, int(k), labels, vals[k].copy())
            for k in range(K) for topic, (labels, vals) in topics.items()]
    for c in spec.corruptions:
        msgs = _corrupt(msgs, c, spec)
    return msgs, sc


def _find(msgs: list[_Msg], topic: str, k: int, spec: BagSpec) -> int:
    for i, m in enumerate(msgs):
        if m.topic == topic and m.stamp == k:
            return i
    raise LibraryError(f"bag {spec.name}: corruption on {topic} stamp {k}: no such message")


def _corrupt(msgs: list[_Msg], c: Corruption, spec: BagSpec) -> list[_Msg]:
    if c.kind == "gap":
        k0, n = c.samples
        return [m for m in msgs if not k0 <= m.stamp < k0 + n]
    for k in c.samples:
        i = _find(msgs, c.topic, k, spec)
        m = msgs[i]
        if c.kind == "nan":
            if c.channel not in m.labels:
                raise LibraryError(f"bag {spec.name}: nan corruption: no channel "
                                   f"{c.channel!r} on {c.topic}")
            m.values[m.labels.index(str(c.channel))] = math.nan
        elif c.kind == "wrong_length":
            m.values, m.labels = m.values[:-1], m.labels[:-1]
        elif c.kind == "duplicate":
            msgs.insert(i + 1, _Msg(m.t_ns, m.topic, m.stamp, m.labels, m.values.copy()))
        else:  # out_of_order: stamp k + 1 recorded (and replayed) before stamp k
            j = _find(msgs, c.topic, k + 1, spec)
            a, b = msgs[i], msgs[j]
            a.stamp, b.stamp = b.stamp, a.stamp
            a.values, b.values = b.values, a.values
            a.labels, b.labels = b.labels, a.labels
    return msgs


def _write_messages(path: Path, msgs: Sequence[_Msg]) -> None:
    from fd_monitor.wire.bags import BagWriter, serialize_array

    with BagWriter(path) as w:
        for topic in dict.fromkeys(m.topic for m in msgs):
            w.add_topic(topic)
        for m in msgs:
            w.write_raw(m.topic, m.t_ns, serialize_array(m.labels, m.stamp, m.values))


def generate_bag(spec: BagSpec, folder: str | Path | None = None) -> Path:
    """(Re)write the bag of ``spec`` into ``folder`` (default ``spec.folder``).

    An existing bag there is replaced; other files of the folder (``expected.yaml``) are
    kept. Same spec, same bytes.

    Returns
    -------
    pathlib.Path
        The bag folder.
    """
    dest = Path(folder) if folder is not None else spec.folder
    msgs, _ = bag_messages(spec)
    dest.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=dest.parent, prefix=f".{spec.name}.") as tmp:
        out = Path(tmp) / spec.name
        _write_messages(out, msgs)
        dest.mkdir(exist_ok=True)
        for old in [*dest.glob("*.mcap"), dest / "metadata.yaml"]:
            if old.exists():
                old.unlink()
        for f in out.iterdir():
            shutil.move(str(f), str(dest / f.name))
    return dest


def generate_library(library: Library, names: Sequence[str] | None = None,
                     out_root: str | Path | None = None) -> list[dict[str, Any]]:
    """Regenerate the bags of a library (all, or ``names``).

    Parameters
    ----------
    library : Library
    names : sequence of str, optional
    out_root : str or pathlib.Path, optional
        Write ``<out_root>/<name>/`` instead of the library's own folders.

    Returns
    -------
    list of dict
        Per bag: name, folder, samples, bytes.
    """
    out = []
    for name in (names or library.names):
        spec = library[name]
        dest = spec.folder if out_root is None else Path(out_root) / spec.name
        generate_bag(spec, dest)
        size = sum(f.stat().st_size for f in dest.iterdir() if f.is_file())
        out.append({"name": spec.name, "folder": str(dest),
                    "samples": round(spec.duration / _sample_time(spec)), "bytes": size})
    return out


def _sample_time(spec: BagSpec) -> float:
    from fd_monitor.model.scenario import load_scenario

    return float(load_scenario(spec.scenario).system.sample_time)


# --------------------------------------------------------------------------------------
# reading input streams (tolerant of bad input) and the offline run
























# --------------------------------------------------------------------------------------
# summaries and expectations






def settled_modes(segments: Sequence[Sequence[Any]], min_dwell: int) -> list[str]:
    """Mode sequence without the runs shorter than ``min_dwell`` samples (but the first).

    Chatter of a mode predictor at a guard (QB eq. 13b from a noisy estimate) produces runs of
    a few samples; dropping them and collapsing repeats gives the settled sequence.
    """
    kept = [str(s[0]) for i, s in enumerate(segments) if i == 0 or int(s[2]) >= min_dwell]
    return collapse(kept)




def analyze_summary(bag: str | Path, gains: str | Path, *,
                    transient: float = 0.0) -> dict[str, Any]:
    """The summary the regression suite checks: :func:`fd_monitor.analysis.offline.run_bag` (what
    ``python -m fd_monitor analyze`` runs, for every gain-file method alike)
    summarised by :func:`fd_monitor.analysis.offline.summarize_run`.

    Returns
    -------
    dict
        ``alarms`` (``{channel, first_sample, time}``, first alarm per channel at or after the
        transient), ``isolated``, ``bias_estimate``, ``modes`` (estimated mode sequence,
        repeats collapsed; a restart begins in the plant's initial mode), ``mode_segments``,
        ``input_errors`` (kind -> stamps), ``restarts`` (samples where the monitor restarted
        after a hole), ``samples``.
    """
    return summarize_run(run_bag(bag, gains, transient=transient))


def expected_path(bag: str | Path) -> Path:
    """``<bag>/expected.yaml``."""
    return Path(bag) / "expected.yaml"


def load_expected(path: str | Path) -> dict[str, Any]:
    """Read and validate an ``expected.yaml`` (see the module docstring).

    Raises
    ------
    LibraryError
    """
    from fd_monitor.model.system import read_yaml

    p = Path(path)
    if p.is_dir():
        p = expected_path(p)
    if not p.is_file():
        raise LibraryError(f"{p}: expected results not found")
    d = read_yaml(p, LibraryError)
    if not isinstance(d, Mapping):
        _fail(p, "(top level)", "a mapping")
    allowed = {"bag", "gains", "description", "alarms", "no_alarm", "isolated",
               "bias_estimate", "modes", "mode_min_dwell", "input_errors", "restarts",
               "fault_onset_sample", "transient"}
    extra = set(d) - allowed
    if extra:
        _fail(p, sorted(extra)[0], f"one of {sorted(allowed)} (unknown key)")
    alarms = d.get("alarms") or {}
    if not isinstance(alarms, Mapping):
        _fail(p, "alarms", "channel -> {first_sample, tolerance}", alarms)
    for c, a in alarms.items():
        if not isinstance(a, Mapping) or set(a) != {"first_sample", "tolerance"}:
            _fail(p, f"alarms.{c}", "{first_sample, tolerance}", a)
    for key in ("no_alarm", "isolated", "modes", "restarts"):
        if key in d and not isinstance(d[key], list):
            _fail(p, key, "a list", d[key])
    be = d.get("bias_estimate") or {}
    for c, a in be.items():
        if not isinstance(a, Mapping) or set(a) != {"value", "tolerance"}:
            _fail(p, f"bias_estimate.{c}", "{value, tolerance}", a)
    ie = d.get("input_errors")
    if ie is not None:
        if not isinstance(ie, Mapping) or not set(ie) <= set(INPUT_ERROR_KINDS):
            _fail(p, "input_errors", f"a mapping with keys among {list(INPUT_ERROR_KINDS)}", ie)
    return dict(d)


def check_expected(expected: Mapping[str, Any], summary: Mapping[str, Any]) -> list[str]:
    """Compare an analysis summary with expected results.

    Checks: no channel alarms before ``fault_onset_sample`` (when given: a false alarm);
    every channel of ``alarms`` alarms first at ``first_sample +- tolerance``; no
    channel of ``no_alarm`` alarms; ``isolated`` equals the isolated set; every
    ``bias_estimate`` is within its tolerance; ``modes`` equals the estimated mode sequence;
    ``input_errors`` (kind -> stamps) equals what was reported for those kinds and no other
    kind was reported; ``restarts`` equals the restart samples.

    Returns
    -------
    list of str
        One line per failed expectation (empty: all hold).
    """
    fails: list[str] = []
    first = {a["channel"]: int(a["first_sample"]) for a in summary.get("alarms", [])}
    onset = expected.get("fault_onset_sample")
    for c, f in sorted(first.items()):
        if onset is not None and f < int(onset):
            fails.append(f"alarms.{c}: alarm at sample {f}, before the fault onset {onset} "
                         f"(false alarm)")
    for c, a in (expected.get("alarms") or {}).items():
        want, tol = int(a["first_sample"]), int(a["tolerance"])
        if c not in first:
            fails.append(f"alarms.{c}: expected a first alarm at sample {want} +- {tol}, "
                         f"got no alarm")
        elif abs(first[c] - want) > tol:
            fails.append(f"alarms.{c}: expected a first alarm at sample {want} +- {tol}, "
                         f"got {first[c]}")
    for c in expected.get("no_alarm") or []:
        if c in first:
            fails.append(f"no_alarm: channel {c} alarmed at sample {first[c]}")
    if "isolated" in expected:
        got = sorted(summary.get("isolated", []))
        if got != sorted(expected["isolated"]):
            fails.append(f"isolated: expected {sorted(expected['isolated'])}, got {got}")
    est = summary.get("bias_estimate", {})
    for c, a in (expected.get("bias_estimate") or {}).items():
        if c not in est:
            fails.append(f"bias_estimate.{c}: no estimate reported")
        elif not abs(float(est[c]) - float(a["value"])) <= float(a["tolerance"]):
            fails.append(f"bias_estimate.{c}: expected {a['value']} +- {a['tolerance']}, "
                         f"got {float(est[c]):.6g}")
    if "modes" in expected:
        dwell = int(expected.get("mode_min_dwell", 1))
        got_modes = list(summary.get("modes", []))
        if dwell > 1 and "mode_segments" in summary:
            got_modes = settled_modes(summary["mode_segments"], dwell)
        if got_modes != list(expected["modes"]):
            fails.append(f"modes: expected {list(expected['modes'])}, got {got_modes}"
                         + (f" (runs shorter than {dwell} samples dropped)" if dwell > 1
                            else ""))
    if "input_errors" in expected:
        want_ie = {k: sorted(v) for k, v in (expected["input_errors"] or {}).items()}
        got_ie = {k: sorted(v) for k, v in (summary.get("input_errors") or {}).items()}
        for kind in sorted(set(want_ie) | set(got_ie)):
            if want_ie.get(kind, []) != got_ie.get(kind, []):
                fails.append(f"input_errors.{kind}: expected samples {want_ie.get(kind, [])}, "
                             f"got {got_ie.get(kind, [])}")
    if "restarts" in expected and sorted(summary.get("restarts", [])) != \
            sorted(expected["restarts"]):
        fails.append(f"restarts: expected {sorted(expected['restarts'])}, got "
                     f"{sorted(summary.get('restarts', []))}")
    return fails


def truth_facts(bag: str | Path, system: Any = None) -> dict[str, Any]:
    """What the bag's ``/plant/truth`` says: fault onsets, final fault values, true modes.

    Returns
    -------
    dict
        ``faults``: name -> ``{onset_sample, final, kind, target}`` for every fault channel
        that is ever non-zero (``target`` the output or state it acts on); ``modes``: the true
        mode sequence (repeats collapsed); ``samples``.
    """
    from fd_monitor.wire.bags import read_bag

    tr = read_bag(bag, [PLANT_TRUTH.absolute])[PLANT_TRUTH.absolute]
    if system is None:
        raise ScenarioError("truth_facts: give the plant")
    faults: dict[str, Any] = {}
    for f in system.faults:
        lab = f"f.{f.name}"
        if lab not in tr.labels:
            continue
        v = tr.column(lab)
        nz = np.flatnonzero(v != 0.0)
        if nz.size:
            # what an isolation names: the biased output, the jumping state, else the fault
            # itself (an hinf_sc bank has one channel per fault)
            target = (system.outputs[f.index] if f.kind == "sensor_bias"
                      else system.states[f.index] if f.kind == "state_jump" else f.name)
            faults[f.name] = {"onset_sample": int(tr.stamps[nz[0]]), "final": float(v[-1]),
                              "kind": f.kind, "target": target}
    modes = collapse([system.mode_names[int(q)] for q in tr.column("mode")])
    return {"faults": faults, "modes": modes, "samples": len(tr)}


def propose_expected(spec: BagSpec, summary: Mapping[str, Any], system: Any, *,
                     alarm_tolerance: int | None = None, bias_tolerance: float | None = None,
                     qb_min_dwell: int = 20) -> dict[str, Any]:
    """Expected results for a bag from one analysis and the bag's truth (to be reviewed).

    Physical quantities come from ``/plant/truth``, not from the analysis: the final bias
    estimate is expected at the true final bias (0 for healthy sensors), within
    ``bias_tolerance`` (``thresholds``; default 3 mm) or within the QB guarantee
    ``sqrt((P^-1)_jj)`` of that state (``qb``); the mode sequence is the true one. The first
    alarm samples (``alarm_tolerance``: 10 samples, 20 for ``qb``), the isolated set and the
    input errors are the analysis'; :func:`check_truth` then asserts they agree with the truth
    (no alarm before the onset, the faulty sensor isolated).
    """
    from fd_monitor.model.gains import load_gains

    facts = truth_facts(spec.folder, system)
    # fault-model states estimated with a guaranteed band (qb): looser alarm tolerance
    qb = summary.get("estimate_kind") == "state"
    tol_k = alarm_tolerance if alarm_tolerance is not None else (20 if qb else 10)
    first = {a["channel"]: int(a["first_sample"]) for a in summary["alarms"]}
    channels = list(summary.get("channels") or system.outputs)
    doc: dict[str, Any] = {"bag": spec.name, "gains": spec.gains,
                           "description": spec.description}
    onsets = [f["onset_sample"] for f in facts["faults"].values()]
    if onsets:
        doc["fault_onset_sample"] = min(onsets)
    if spec.transient:
        doc["transient"] = spec.transient
    doc["alarms"] = {c: {"first_sample": first[c], "tolerance": tol_k}
                     for c in channels if c in first}
    doc["no_alarm"] = [c for c in channels if c not in first]
    doc["isolated"] = sorted(summary["isolated"])
    be: dict[str, Any] = {}
    if qb:
        gf = load_gains(spec.gains, system)
        comp = np.asarray(gf.results["component_bound"], dtype=float)
        tr = read_bag_truth(spec.folder)
        for name in summary["bias_estimate"]:
            j = system.states.index(name)
            be[name] = {"value": round(float(tr.column(f"x.{name}")[-1]), 6),
                        "tolerance": round(float(comp[j]), 6)}
        doc["mode_min_dwell"] = qb_min_dwell
    else:
        tol = bias_tolerance if bias_tolerance is not None else 0.003
        true_bias = {f["target"]: f["final"] for f in facts["faults"].values()
                     if f["kind"] == "sensor_bias"}
        for name in summary["bias_estimate"]:
            be[name] = {"value": round(float(true_bias.get(name, 0.0)), 6), "tolerance": tol}
    doc["bias_estimate"] = be
    doc["modes"] = list(facts["modes"])
    if spec.corruptions:
        doc["input_errors"] = dict(summary["input_errors"])
        doc["restarts"] = list(summary["restarts"])
    return doc


def core_summary(spec: BagSpec, system: Any = None) -> dict[str, Any]:
    """The summary of :func:`analyze_summary` for a bag whose gain file ``analyze`` does not
    run in this version (``hinf_sc``, ``hminus_switched``), computed with the method's core
    runtime on the bag's ``/plant/u`` and ``/plant/y``:

    * ``hinf_sc``: :class:`fd_monitor.core.residual_bank.ResidualBank` (the gain file's
      thresholds; an LPV bank schedules itself from the measurements); channels are the
      generators' faults, alarm ``||r_i|| > J_i``; a generator alarming at the last sample
      isolates its fault;
    * ``hminus_switched``: :class:`fd_monitor.core.generalized_observer.GeneralizedObserver`
      with the true mode read from ``/plant/truth`` (the measured switching signal); one
      channel ``r_norm`` (``||r||`` against the gain file's threshold, +inf when it has none).

    Returns
    -------
    dict
        ``method``, ``channels``, ``alarms``, ``isolated``, ``bias_estimate`` (empty),
        ``modes`` (the plant's mode for a bank; the switching signal it was given for the
        switched observer), ``samples``, ``input_errors`` and ``restarts`` (empty: library
        bags of these methods carry no corruption).
    """
    from fd_monitor.model.gains import load_gains
    from fd_monitor.model.system import load_system
    from fd_monitor.wire.bags import read_bag

    if system is None:
        system = load_system(load_gains(spec.gains, verify=False).system_name)
    gf = load_gains(spec.gains, system)
    t_u, t_y, t_tr = PLANT_U.absolute, PLANT_Y.absolute, PLANT_TRUTH.absolute
    b = read_bag(spec.folder, [t_u, t_y, t_tr])
    u, y, tr = b[t_u], b[t_y], b[t_tr]
    k = np.asarray(y.stamps)
    if gf.method == "hinf_sc":
        from fd_monitor.core.residual_bank import ResidualBank

        bank = ResidualBank(system, gf)
        sig = bank.run(u.values, y.values)
        alarm = sig > bank.thresholds
        channels = list(bank.faults)
        modes = np.full(len(k), system.initial_mode)    # a bank has one (LTI / LPV) mode
    elif gf.method == "hminus_switched":
        from fd_monitor.core.generalized_observer import GeneralizedObserver

        obs = GeneralizedObserver(system, gf)
        modes = tr.column("mode").astype(int)
        _, r = obs.run(u.values, y.values, modes)
        alarm = (np.linalg.norm(r, axis=1) > obs.threshold)[:, None]
        channels = ["r_norm"]
    else:
        raise LibraryError(f"bag {spec.name}: core_summary runs hinf_sc and hminus_switched "
                           f"gain files, not {gf.method!r} (use analyze_summary)")
    k_tr = round(spec.transient / float(system.sample_time))
    alarms = []
    for i, c in enumerate(channels):
        hits = np.flatnonzero(alarm[:, i] & (k >= k_tr))
        if hits.size:
            alarms.append({"channel": c, "first_sample": int(k[hits[0]]),
                           "time": round(int(k[hits[0]]) * float(system.sample_time), 9)})
    return {"method": gf.method, "channels": channels, "alarms": alarms,
            "isolated": [c for i, c in enumerate(channels) if alarm[-1, i]],
            "bias_estimate": {}, "samples": len(k), "input_errors": {}, "restarts": [],
            "modes": collapse([system.mode_names[int(q)] for q in modes])}


def read_bag_truth(bag: str | Path) -> Any:
    """``/plant/truth`` of a bag as :class:`~fd_monitor.wire.bags.TopicArrays`."""
    from fd_monitor.wire.bags import read_bag

    return read_bag(bag, [PLANT_TRUTH.absolute])[PLANT_TRUTH.absolute]


def write_expected(path: str | Path, doc: Mapping[str, Any], header: str = "") -> Path:
    """Write an ``expected.yaml`` (flow style for short lists and mappings)."""
    import yaml

    from fd_monitor.model.gains import to_plain

    lines = [f"# {h}" if h else "#" for h in header.splitlines()]
    body = yaml.safe_dump(to_plain(dict(doc)), sort_keys=False, default_flow_style=None,
                          width=96)
    p = Path(path)
    p.write_text("\n".join([*lines, body]) if lines else body, encoding="utf-8")
    return p


def check_truth(spec: BagSpec, expected: Mapping[str, Any], system: Any) -> list[str]:
    """Check that expected results agree with the bag's truth and spec (honest expectations).

    No expected first alarm is before the fault onset (no false alarm is expected);
    a fault-free bag expects no alarm; the isolated set is the set of biased sensors (or
    fault-model states); the expected bias values are the true final biases; the expected mode
    sequence is the true one; a corrupted bag expects exactly its corrupted stamps.

    Returns
    -------
    list of str
        One line per disagreement.
    """
    facts = truth_facts(spec.folder, system)
    out: list[str] = []
    onsets = [f["onset_sample"] for f in facts["faults"].values()]
    alarms = expected.get("alarms") or {}
    if not onsets and alarms:
        out.append(f"fault-free bag expects alarms {sorted(alarms)}")
    for c, a in alarms.items():
        if onsets and int(a["first_sample"]) < min(onsets):
            out.append(f"alarms.{c}: expected before the fault onset {min(onsets)}")
    targets = sorted({f["target"] for f in facts["faults"].values() if f["target"]})
    # a residual bank (hinf_sc) isolates faults by name, not by the channel they act on
    if sorted(expected.get("isolated", [])) not in (targets, sorted(facts["faults"])):
        out.append(f"isolated {expected.get('isolated')} but the faulty channels are "
                   f"{targets} (faults {sorted(facts['faults'])})")
    if list(expected.get("modes", [])) != facts["modes"]:
        out.append(f"modes {expected.get('modes')} but the true sequence is {facts['modes']}")
    true_bias = {f["target"]: f["final"] for f in facts["faults"].values()
                 if f["kind"] == "sensor_bias"}
    for c, a in (expected.get("bias_estimate") or {}).items():
        if c in system.outputs and abs(float(a["value"]) - true_bias.get(c, 0.0)) > 1e-6:
            out.append(f"bias_estimate.{c}: {a['value']} is not the true bias "
                       f"{true_bias.get(c, 0.0)}")
    if spec.corruptions:
        want: dict[str, list[Any]] = {}
        names = {"nan": "non_finite", "wrong_length": "wrong_length",
                 "duplicate": "duplicate", "out_of_order": "out_of_order"}
        for c in spec.corruptions:
            if c.kind == "gap":
                want.setdefault("missing", []).append([c.samples[0],
                                                       c.samples[0] + c.samples[1] - 1])
            else:
                want.setdefault(names[c.kind], []).extend(c.samples)
        got = {k: sorted(v) for k, v in (expected.get("input_errors") or {}).items()}
        if got != {k: sorted(v) for k, v in want.items()}:
            out.append(f"input_errors {got} but the corruptions are {want}")
    return out
