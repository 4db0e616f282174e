"""The scenario bag library's files: ``bags/library.yaml`` and each bag's ``expected.yaml``.

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
        notes: ...                               # added to expected.yaml's header

Each bag folder holds ``metadata.yaml``, ``<name>.mcap`` (zstd-compressed chunks) and
``expected.yaml``: what analysing the bag must give (see
:func:`fd_monitor.analysis.expectations.check_expected`)::

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
    restarts: [750]               # samples at which the monitor restarted (after a long hole)
    bridges: [302, 451]           # samples at which it bridged a short hole (memory kept)

Corruptions (applied to the simulated messages, in this order; ``samples`` are stamps k):

* ``{kind: nan, topic, channel, samples}`` -- that channel's value is NaN;
* ``{kind: wrong_length, topic, samples}`` -- the message loses its last channel;
* ``{kind: gap, start, samples}`` -- no message on any topic for stamps
  ``start .. start + samples - 1`` (a hole of ``samples * Ts`` seconds);
* ``{kind: duplicate, topic, samples}`` -- the message is recorded twice;
* ``{kind: out_of_order, topic, samples}`` -- messages k and k + 1 are recorded in the
  opposite order (stamp k + 1 arrives first).

This module reads and validates both files (:class:`~fd_monitor.model.validate.Checker`: every
error is one line naming the file, the key path and what was expected). The bags are written by
:mod:`fd_monitor.analysis.generate`; the analysis is :func:`fd_monitor.analysis.offline.run_bag`
(the same run as ``python -m fd_monitor analyze``), summarised and checked by
:mod:`fd_monitor.analysis.expectations`. Nothing here imports rclpy.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

from fd_monitor.analysis.offline import INPUT_ERROR_KINDS
from fd_monitor.model.errors import FdMonitorError
from fd_monitor.model.paths import config_dirs, find_config_file
from fd_monitor.model.validate import Checker
from fd_monitor.model.yaml_io import check_regular_file, read_yaml
from fd_monitor.wire.topics import PLANT_Y

__all__ = ["CORRUPTION_KINDS", "FORMAT_VERSION", "BagSpec", "Corruption", "Library",
           "LibraryError", "default_library", "expected_path", "load_expected", "load_library"]

CORRUPTION_KINDS = ("nan", "wrong_length", "gap", "duplicate", "out_of_order")

FORMAT_VERSION = 1


class LibraryError(FdMonitorError, ValueError):
    """The library spec or an expected.yaml is invalid (file and key named)."""


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
    notes : str
        Added to the header of the ``expected.yaml`` the library writes (why its thresholds
        or channels are what they are).
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
    notes: str = ""

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
    for d in config_dirs():
        if (d.parent / "bags" / "library.yaml").is_file():
            return d.parent / "bags" / "library.yaml"
    raise LibraryError("no bag library found (bags/library.yaml): give the path of a "
                       "library.yaml")


def _checker(origin: Path) -> Checker:
    """The :class:`~fd_monitor.model.validate.Checker` of a library file."""
    return Checker(str(origin), LibraryError, clip=None)


def _fail(ck: Checker, key: str, expected: str, got: Any = None) -> NoReturn:
    """:meth:`Checker.fail` that shows what was found unless it is None (missing)."""
    ck.fail(key, expected, got, show=got is not None)


def _int_list(ck: Checker, key: str, v: Any) -> tuple[int, ...]:
    if isinstance(v, int) and not isinstance(v, bool):
        v = [v]
    if not isinstance(v, list) or not v or not all(
            isinstance(i, int) and not isinstance(i, bool) and i >= 0 for i in v):
        _fail(ck, key, "a non-empty list of sample indices >= 0", v)
    return tuple(int(i) for i in v)


def _corruption(ck: Checker, key: str, c: Any) -> Corruption:
    if not isinstance(c, Mapping) or c.get("kind") not in CORRUPTION_KINDS:
        _fail(ck, f"{key}.kind", f"one of {list(CORRUPTION_KINDS)}",
              c.get("kind") if isinstance(c, Mapping) else c)
    kind = str(c["kind"])
    allowed = {"kind", "topic", "samples", "channel", "start"}
    extra = set(c) - allowed
    if extra:
        _fail(ck, f"{key}.{sorted(extra)[0]}", f"one of {sorted(allowed)} (unknown key)")
    topic = str(c.get("topic", PLANT_Y.absolute))
    if kind == "gap":
        if "start" not in c or "samples" not in c:
            _fail(ck, key, "{kind: gap, start: k0, samples: count}", dict(c))
        start = _int_list(ck, f"{key}.start", c["start"])
        count = c["samples"]
        if not isinstance(count, int) or isinstance(count, bool) or count < 1:
            _fail(ck, f"{key}.samples", "a count >= 1", count)
        return Corruption(kind, "*", (start[0], int(count)))
    if "samples" not in c:
        _fail(ck, f"{key}.samples", "a list of sample indices (missing key)")
    samples = _int_list(ck, f"{key}.samples", c["samples"])
    channel = None
    if kind == "nan":
        if not isinstance(c.get("channel"), str):
            _fail(ck, f"{key}.channel", "the channel to set to NaN", c.get("channel"))
        channel = str(c["channel"])
    return Corruption(kind, topic, samples, channel)


def load_library(path: str | Path | None = None) -> Library:
    """Load and validate a library spec (default ``bags/library.yaml``).

    Raises
    ------
    LibraryError
        One line naming the file and the key.
    """
    p = Path(path) if path is not None else default_library()
    check_regular_file(p, LibraryError, "library spec")
    ck = _checker(p)
    data = read_yaml(p, LibraryError)
    if not isinstance(data, Mapping) or not isinstance(data.get("bags"), list):
        _fail(ck, "bags", "a list of bag entries")
    extra = set(data) - {"format_version", "bags"}
    if extra:
        _fail(ck, str(sorted(map(str, extra))[0]), "one of ['bags', 'format_version'] (unknown "
              "key)")
    if (isinstance(data.get("format_version"), bool)
            or data.get("format_version", FORMAT_VERSION) != FORMAT_VERSION):
        _fail(ck, "format_version", str(FORMAT_VERSION), data.get("format_version"))
    bags: list[BagSpec] = []
    for i, e in enumerate(data["bags"]):
        bags.append(_bag_spec(ck, f"bags[{i}]", e, p, {b.name for b in bags}))
    return Library(p, tuple(bags))


def _bag_spec(ck: Checker, key: str, e: Any, p: Path, taken: set[str]) -> BagSpec:
    """One entry ``bags[i]`` of the library spec ``p`` (``taken``: the names before it)."""
    if not isinstance(e, Mapping):
        _fail(ck, key, "a mapping {name, scenario, seed, duration, gains, ...}", e)
    allowed = {"name", "scenario", "seed", "duration", "gains", "transient", "live",
               "description", "corruptions", "notes"}
    extra = set(e) - allowed
    if extra:
        _fail(ck, f"{key}.{sorted(extra)[0]}", f"one of {sorted(allowed)} (unknown key)")
    for req in ("name", "scenario", "seed", "duration", "gains"):
        if req not in e:
            _fail(ck, f"{key}.{req}", "a value (missing key)")
    name = str(e["name"])
    if not name.replace("_", "").isalnum() or name in taken:
        _fail(ck, f"{key}.name", "a unique name of letters, digits and _", name)
    seed = e["seed"]
    if not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed < 2**63:
        _fail(ck, f"{key}.seed", "an integer >= 0", seed)
    dur = e["duration"]
    if isinstance(dur, bool) or not isinstance(dur, (int, float)) or not 0 < dur < math.inf:
        _fail(ck, f"{key}.duration", "a finite duration > 0 in s", dur)
    tr = e.get("transient", 0.0)
    if isinstance(tr, bool) or not isinstance(tr, (int, float)) or not 0 <= tr < math.inf:
        _fail(ck, f"{key}.transient", "a time >= 0 in s", tr)
    cors = e.get("corruptions") or []
    if not isinstance(cors, list):
        _fail(ck, f"{key}.corruptions", "a list", cors)
    corruptions = tuple(_corruption(ck, f"{key}.corruptions[{j}]", c)
                        for j, c in enumerate(cors))
    for ref in ("gains", "scenario"):
        if not isinstance(e[ref], str) or not e[ref]:
            _fail(ck, f"{key}.{ref}", "a shipped name or a path", e[ref])
    try:      # an unknown name refused now, not after simulating the bag
        find_config_file(p.parent / e["gains"] if (p.parent / e["gains"]).is_file()
                         else e["gains"], "gains", LibraryError, "gain file")
    except LibraryError as exc:
        _fail(ck, f"{key}.gains", f"a gain file ({exc})", e["gains"])
    scen = str(e["scenario"])
    rel = p.parent / scen
    return BagSpec(
        name=name, scenario=str(rel) if rel.is_file() else scen, seed=int(seed),
        duration=float(dur), gains=str(e["gains"]), transient=float(tr),
        live=bool(e.get("live", False)), description=str(e.get("description", "")),
        corruptions=corruptions,
        folder=p.parent / name, notes=str(e.get("notes") or ""))


def expected_path(bag: str | Path) -> Path:
    """``<bag>/expected.yaml``."""
    return Path(bag) / "expected.yaml"


def load_expected(path: str | Path) -> dict[str, Any]:
    """Read and validate an ``expected.yaml`` (format: :mod:`fd_monitor.analysis.library`).

    Raises
    ------
    LibraryError
    """
    p = Path(path)
    if p.is_dir():
        p = expected_path(p)
    check_regular_file(p, LibraryError, "expected results file")
    ck = _checker(p)
    d = read_yaml(p, LibraryError)
    if not isinstance(d, Mapping):
        _fail(ck, "(top level)", "a mapping")
    allowed = {"bag", "gains", "description", "alarms", "no_alarm", "isolated",
               "bias_estimate", "modes", "mode_min_dwell", "input_errors", "restarts",
               "bridges",
               "fault_onset_sample", "transient"}
    extra = set(d) - allowed
    if extra:
        _fail(ck, sorted(extra)[0], f"one of {sorted(allowed)} (unknown key)")
    alarms = d.get("alarms") or {}
    if not isinstance(alarms, Mapping):
        _fail(ck, "alarms", "channel -> {first_sample, tolerance}", alarms)
    if "bag" in d and p.name == "expected.yaml" and str(d["bag"]) != p.resolve().parent.name:
        _fail(ck, "bag", f"the name of its bag folder {p.resolve().parent.name!r} (the "
              f"expectations of another bag?)", d["bag"])
    for c, a in alarms.items():
        if not isinstance(a, Mapping) or set(a) != {"first_sample", "tolerance"}:
            _fail(ck, f"alarms.{c}", "{first_sample, tolerance}", a)
        for f in ("first_sample", "tolerance"):
            if isinstance(a[f], bool) or not isinstance(a[f], int) or a[f] < 0:
                _fail(ck, f"alarms.{c}.{f}", "an integer >= 0 (samples)", a[f])
    for key in ("no_alarm", "isolated", "modes", "restarts", "bridges"):
        if key in d and not isinstance(d[key], list):
            _fail(ck, key, "a list", d[key])
    be = d.get("bias_estimate") or {}
    if not isinstance(be, Mapping):
        _fail(ck, "bias_estimate", "channel -> {value, tolerance}", be)
    for c, a in be.items():
        if not isinstance(a, Mapping) or set(a) != {"value", "tolerance"}:
            _fail(ck, f"bias_estimate.{c}", "{value, tolerance}", a)
        for f in ("value", "tolerance"):
            v = a[f]
            if (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
                    or (f == "tolerance" and v < 0)):
                _fail(ck, f"bias_estimate.{c}.{f}", "a finite number" + (" >= 0" if
                                                                           f == "tolerance"
                                                                           else ""), v)
    for key in ("fault_onset_sample", "mode_min_dwell"):
        v = d.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 0):
            _fail(ck, key, "an integer >= 0 (samples)", v)
    tr = d.get("transient")
    if tr is not None and (isinstance(tr, bool) or not isinstance(tr, (int, float))
                           or not 0 <= tr < math.inf):
        _fail(ck, "transient", "a finite time >= 0 in s", tr)
    ie = d.get("input_errors")
    if ie is not None:
        if not isinstance(ie, Mapping) or not set(ie) <= set(INPUT_ERROR_KINDS):
            _fail(ck, "input_errors", f"a mapping with keys among {list(INPUT_ERROR_KINDS)}",
                  ie)
    return dict(d)
