"""A fleet's bags: which robot, which day, which sensor.

``python -m fd_monitor analyze BAG_OR_DIR_OR_GLOB ... --gains G`` over many bags runs
batches of bags as tasks (:mod:`fd_monitor.commands.fleet`, on
:mod:`fd_monitor.analysis.scaleout`) and reduces each bag's ``analyze --json`` document
to table rows here:

* :func:`find_bags` -- bags from paths, folders (searched recursively) and glob patterns;
* :class:`FleetMap` -- a mapping file: the robot (or the bag's path, or a key of its
  metadata's ``custom_data``) -> gain file (and plant file, adapter) of that bag;
* :func:`bag_identity` -- robot, start time and duration of a bag, from its
  ``metadata.yaml``;
* :func:`bag_row`, :func:`alarm_rows` -- one row per bag (:func:`bag_schema`) and one per
  alarm episode (:func:`alarm_schema`), built from the analyze document; a bag that could not
  be analysed is one row with its ``error``;
* :class:`FleetTables` -- the two Parquet tables, written as results arrive;
* :func:`fleet_summary` -- per robot, and per robot, day and channel;
* :func:`fleet_report` -- the fleet page of ``report``: ``fleet.md`` and
  ``alarms_over_time.png``.

Nothing here imports rclpy.

Why one module of ~610 lines: the fleet's tables (schemas, one row per bag and per alarm
episode), its mapping file, summary and report page are one product; each function is short.
"""

from __future__ import annotations

import datetime as _dt
import fnmatch
import glob
import json
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from fd_monitor.model.errors import FdMonitorError
from fd_monitor.wire.topics import PLANT_Y

__all__ = ["ALARMS_FILE", "BAGS_FILE", "FleetMap", "FleetRule", "FleetTables", "alarm_rows",
           "alarm_schema", "bag_identity", "bag_row", "bag_schema", "error_row", "find_bags",
           "fleet_report", "fleet_summary", "is_bag", "read_tables"]

#: File names of the two tables in the output folder.
BAGS_FILE = "bags.parquet"
ALARMS_FILE = "alarms.parquet"


def _schemas() -> tuple[Any, Any]:
    import pyarrow as pa

    ts = pa.timestamp("ns", tz="UTC")
    bags = pa.schema([
        ("bag", pa.string()), ("robot", pa.string()), ("start_time", ts),
        ("duration_s", pa.float64()), ("plant", pa.string()), ("gains", pa.string()),
        ("method", pa.string()), ("samples", pa.int64()), ("integrity", pa.string()),
        ("alarms", pa.int64()), ("first_alarm_channel", pa.string()),
        ("first_alarm_sample", pa.int64()), ("first_alarm_time_s", pa.float64()),
        ("isolated", pa.list_(pa.string())),
        ("bias_estimate", pa.map_(pa.string(), pa.float64())),
        ("outside_region", pa.bool_()), ("outside_alarms", pa.int64()),
        ("error", pa.string()),
    ])
    alarms = pa.schema([
        ("bag", pa.string()), ("robot", pa.string()), ("start_time", ts),
        ("channel", pa.string()), ("first_sample", pa.int64()), ("last_sample", pa.int64()),
        ("samples", pa.int64()), ("time_s", pa.float64()), ("at", ts),
        ("outside_certified_region", pa.bool_()), ("outside_detail", pa.string()),
    ])
    return bags, alarms


def bag_schema() -> Any:
    """The bags table's ``pyarrow.Schema`` (one row per bag)."""
    return _schemas()[0]


def alarm_schema() -> Any:
    """The alarms table's ``pyarrow.Schema`` (one row per alarm episode and channel)."""
    return _schemas()[1]


# --------------------------------------------------------------------------------------
# finding bags


def is_bag(path: str | Path) -> bool:
    """A rosbag2 bag: an ``.mcap`` file, or a folder with ``metadata.yaml`` or ``.mcap``
    files (a bag whose recorder died has no metadata)."""
    p = Path(path)
    if p.is_file():
        return p.suffix == ".mcap"
    return p.is_dir() and ((p / "metadata.yaml").is_file() or any(p.glob("*.mcap")))


def _bags_under(root: Path) -> list[Path]:
    out: list[Path] = []
    for here, dirs, _files in os.walk(root):
        d = Path(here)
        if is_bag(d):
            out.append(d)
            dirs[:] = []                   # a bag's folder holds no further bag
        else:
            dirs.sort()
    return out


def find_bags(sources: Sequence[str]) -> list[Path]:
    """Bags named by ``sources``: each a bag, a folder searched recursively for bags, or a
    glob pattern (``**`` allowed) whose matches are either. Sorted, each bag once.

    Raises
    ------
    FdMonitorError
        A source that names no bag (one line naming it).
    """
    found: dict[str, Path] = {}
    for src in sources:
        if Path(src).exists():
            matches = [Path(src)]
        else:
            matches = [Path(m) for m in sorted(glob.glob(src, recursive=True))]
        bags: list[Path] = []
        for m in matches:
            bags += [m] if is_bag(m) else _bags_under(m) if m.is_dir() else []
        if not bags:
            raise FdMonitorError(f"{src}: no bag there (expected a bag folder, an .mcap file, "
                                 f"a folder of bags or a glob pattern matching them)")
        for b in bags:
            found.setdefault(os.path.normpath(str(b)), b)
    return [found[k] for k in sorted(found)]


# --------------------------------------------------------------------------------------
# which robot, which gain file


def _metadata(bag: Path) -> dict[str, Any]:
    """The bag's ``metadata.yaml`` information ({} when there is none or it is unreadable:
    the analysis then says what is wrong)."""
    meta = bag / "metadata.yaml" if bag.is_dir() else bag.parent / "metadata.yaml"
    try:
        info = yaml.safe_load(meta.read_text(encoding="utf-8"))
        got = info["rosbag2_bagfile_information"]
        return got if isinstance(got, dict) else {}
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError):
        return {}


def bag_identity(bag: str | Path) -> dict[str, Any]:
    """Robot, start time and duration of a bag, from its ``metadata.yaml``.

    The robot is, first found: ``custom_data.robot`` of the metadata; the namespace of its
    measurement topic (``/<robot>/plant/y``); the name of the folder the bag is in.

    Returns
    -------
    dict
        ``robot`` (str), ``start_ns`` (int ns since the epoch, or None), ``duration_s``
        (float or None), ``custom_data`` (dict of str, maybe empty).
    """
    p = Path(bag)
    info = _metadata(p)
    custom = info.get("custom_data") or {}
    custom = {str(k): str(v) for k, v in custom.items()} if isinstance(custom, dict) else {}
    robot = custom.get("robot")
    if robot is None:
        tail = PLANT_Y.absolute
        for t in info.get("topics_with_message_count") or []:
            name = str(((t or {}).get("topic_metadata") or {}).get("name", ""))
            if name.endswith(tail) and len(name) > len(tail):
                robot = name[:-len(tail)].strip("/")
                break
    if robot is None:
        parent = p.resolve().parent
        robot = parent.name or p.name
    start = ((info.get("starting_time") or {}).get("nanoseconds_since_epoch"))
    dur = (info.get("duration") or {}).get("nanoseconds")
    return {"robot": str(robot), "start_ns": None if start is None else int(start),
            "duration_s": None if dur is None else int(dur) * 1e-9, "custom_data": custom}


@dataclass(frozen=True)
class FleetRule:
    """One rule of a fleet map: when every ``match`` pattern matches, analyse with these.

    ``match`` keys: ``robot`` (glob on the robot name), ``bag`` (glob on the bag's path),
    any other key: glob on that key of the bag metadata's ``custom_data``.
    """

    match: Mapping[str, str]
    gains: str
    system: str | None = None
    adapter: str | None = None

    def matches(self, bag: str, robot: str, custom: Mapping[str, str]) -> bool:
        """Every pattern matches (an absent metadata key matches nothing)."""
        for key, pat in self.match.items():
            value = robot if key == "robot" else bag if key == "bag" else custom.get(key)
            if value is None or not fnmatch.fnmatchcase(value, pat):
                return False
        return True


@dataclass(frozen=True)
class FleetMap:
    """A fleet's mapping file: rules tried in order, the first that matches wins.

    The file (YAML)::

        format_version: 1
        rules:
          - match: {robot: "tank_*"}                 # glob on the robot name
            gains: three_tank_thresholds            # a shipped name or a path
          - match: {plant: pwa_cascade}             # a key of the bag's custom_data
            gains: pwa_cascade_qb
            system: path/to/plant.yaml               # optional, as analyze --system
          - match: {bag: "*/arm_*"}                  # glob on the bag's path
            gains: arm_thresholds
            adapter: config/adapters/arm.yaml        # optional, as analyze --adapter

    A bag no rule matches is analysed with ``--gains`` (an error row when none was given).
    Relative paths in the file are relative to the file's folder when they exist there.
    """

    rules: tuple[FleetRule, ...] = ()
    source: str = ""

    @classmethod
    def load(cls, path: str | Path) -> FleetMap:
        """Read a mapping file; FdMonitorError naming the file and key on a bad one."""
        p = Path(path)
        try:
            doc = yaml.safe_load(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
            raise FdMonitorError(f"{p}: cannot read the fleet map: "
                                 f"{str(exc).splitlines()[0]}") from None
        if not isinstance(doc, dict) or not isinstance(doc.get("rules"), list):
            raise FdMonitorError(f"{p}: expected a mapping with a list `rules`")
        if doc.get("format_version", 1) != 1:
            raise FdMonitorError(f"{p}: format_version: expected 1, got "
                                 f"{doc.get('format_version')!r}")
        rules = []
        for i, r in enumerate(doc["rules"]):
            where = f"{p}: rules[{i}]"
            if not isinstance(r, dict) or not isinstance(r.get("match"), dict) \
                    or not r["match"] or not isinstance(r.get("gains"), str):
                raise FdMonitorError(f"{where}: expected `match` (a non-empty mapping of "
                                     f"key -> glob) and `gains` (a gain file)")
            extra = set(r) - {"match", "gains", "system", "adapter"}
            if extra:
                raise FdMonitorError(f"{where}: unknown key(s) {sorted(extra)} (expected "
                                     f"match, gains, system, adapter)")
            rules.append(FleetRule({str(k): str(v) for k, v in r["match"].items()},
                                   str(_near(p, r["gains"])), _near(p, r.get("system")),
                                   _near(p, r.get("adapter"))))
        return cls(tuple(rules), str(p))

    def choose(self, bag: str, robot: str, custom: Mapping[str, str]) -> FleetRule | None:
        """The first rule that matches, or None."""
        return next((r for r in self.rules if r.matches(bag, robot, custom)), None)


def _near(mapfile: Path, value: Any) -> str | None:
    """A path in a mapping file: relative to the file's folder when it exists there (else as
    written: a shipped name)."""
    if value is None:
        return None
    v = str(value)
    q = mapfile.parent / v
    return str(q) if not Path(v).is_absolute() and q.exists() else v


# --------------------------------------------------------------------------------------
# rows


def _integrity(doc: Mapping[str, Any]) -> dict[str, Any]:
    """The bag's integrity as ``analyze --json`` reports it (its ``integrity`` object when
    it has one; else the sample counts, input errors per kind, restarts and bridges)."""
    if isinstance(doc.get("integrity"), Mapping):
        return dict(doc["integrity"])
    kinds: dict[str, int] = {}
    for e in doc.get("input_errors") or []:
        kinds[str(e.get("kind"))] = kinds.get(str(e.get("kind")), 0) + 1
    return {"sample_counts": doc.get("sample_counts"), "input_errors": kinds,
            "restarts": len(doc.get("restarts") or []),
            "bridges": len(doc.get("bridges") or [])}


def _ts(start_ns: int | None) -> Any:
    return None if start_ns is None else _dt.datetime.fromtimestamp(start_ns * 1e-9,
                                                                    _dt.UTC)


def bag_row(doc: Mapping[str, Any], ident: Mapping[str, Any]) -> dict[str, Any]:
    """The bags-table row of one bag from its ``analyze --json`` document ``doc`` and
    :func:`bag_identity` ``ident``."""
    alarms = list(doc.get("alarms") or [])
    first = alarms[0] if alarms else None
    marked = [a for a in alarms if "outside_certified_region" in a]
    outside = [a for a in marked if a["outside_certified_region"]]
    return {
        "bag": str(doc["bag"]), "robot": str(ident["robot"]),
        "start_time": _ts(ident.get("start_ns")), "duration_s": ident.get("duration_s"),
        "plant": doc.get("plant"), "gains": doc.get("gains"), "method": doc.get("method"),
        "samples": int(doc.get("samples", 0)),
        "integrity": json.dumps(_plain(_integrity(doc)), sort_keys=True),
        "alarms": len(alarms),
        "first_alarm_channel": None if first is None else str(first["channel"]),
        "first_alarm_sample": None if first is None else int(first["first_sample"]),
        "first_alarm_time_s": None if first is None else float(first["time"]),
        "isolated": [str(c) for c in doc.get("isolated") or []],
        "bias_estimate": [(str(k), float(v)) for k, v in
                          (doc.get("bias_estimate") or {}).items()],
        # None: no alarm carries the mark (no region in the gain file, or no alarm)
        "outside_region": bool(outside) if marked else None,
        "outside_alarms": len(outside) if marked else None,
        "error": None,
    }


def error_row(bag: str, ident: Mapping[str, Any], error: str,
              gains: str | None = None) -> dict[str, Any]:
    """The bags-table row of a bag that could not be analysed."""
    row: dict[str, Any] = {name: None for name in _schemas()[0].names}
    row.update({"bag": str(bag), "robot": str(ident.get("robot", "")),
                "start_time": _ts(ident.get("start_ns")),
                "duration_s": ident.get("duration_s"), "gains": gains,
                "isolated": [], "bias_estimate": [], "error": error})
    return row


def alarm_rows(doc: Mapping[str, Any], ident: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The alarms-table rows of one bag: one per alarm episode and channel."""
    start = ident.get("start_ns")
    out = []
    for a in doc.get("alarms") or []:
        t = float(a["time"])
        out.append({
            "bag": str(doc["bag"]), "robot": str(ident["robot"]), "start_time": _ts(start),
            "channel": str(a["channel"]), "first_sample": int(a["first_sample"]),
            "last_sample": int(a["last_sample"]), "samples": int(a["samples"]), "time_s": t,
            "at": None if start is None else _ts(int(start) + round(t * 1e9)),
            "outside_certified_region": a.get("outside_certified_region"),
            "outside_detail": a.get("outside_detail"),
        })
    return out


def _plain(v: Any) -> Any:
    """JSON-able copy (numpy scalars and tuples as Python's)."""
    if isinstance(v, Mapping):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if hasattr(v, "item") and not isinstance(v, (str, bytes)):
        return v.item()
    return v


# --------------------------------------------------------------------------------------
# the tables


class FleetTables:
    """The two Parquet tables of a fleet run, written as rows arrive.

    Rows (one at a time, :meth:`add`, or Arrow tables of a batch, :meth:`add_tables`) are
    buffered and written as a row group every ``flush_every`` bags, and at :meth:`close`;
    a run stopped with Ctrl-C closes them, so the files hold every bag that finished.
    Rows are in completion order (sort by ``bag`` to compare runs).

    Parameters
    ----------
    folder : str or pathlib.Path
        Created; :data:`BAGS_FILE` and :data:`ALARMS_FILE` are written there.
    """

    def __init__(self, folder: str | Path, flush_every: int = 64) -> None:
        import pyarrow.parquet as pq

        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self._schemas = _schemas()
        self._writers = [pq.ParquetWriter(self.folder / BAGS_FILE, self._schemas[0]),
                         pq.ParquetWriter(self.folder / ALARMS_FILE, self._schemas[1])]
        self._buf: list[list[dict[str, Any]]] = [[], []]
        self._tables: list[list[Any]] = [[], []]
        self.flush_every = max(1, int(flush_every))
        self._pending = 0
        self.bags = 0
        self.alarms = 0
        self.errors = 0

    def add(self, row: Mapping[str, Any], alarms: Iterable[Mapping[str, Any]] = ()) -> None:
        """One bag's row and its alarm episodes."""
        self._buf[0].append(dict(row))
        al = [dict(a) for a in alarms]
        self._buf[1] += al
        self.bags += 1
        self.alarms += len(al)
        self.errors += row.get("error") is not None
        self._pending += 1
        if self._pending >= self.flush_every:
            self.flush()

    def add_tables(self, bags: Any, alarms: Any) -> None:
        """Rows already in Arrow tables of :func:`bag_schema` and :func:`alarm_schema` (a
        batch of bags analysed by a worker: no per-row work here)."""
        self._tables[0].append(bags)
        self._tables[1].append(alarms)
        self.bags += bags.num_rows
        self.alarms += alarms.num_rows
        self.errors += bags.num_rows - bags.column("error").null_count
        self._pending += bags.num_rows
        if self._pending >= self.flush_every:
            self.flush()

    def flush(self) -> None:
        """Write the buffered rows as a row group of each table."""
        import pyarrow as pa

        for w, schema, buf, tabs in zip(self._writers, self._schemas, self._buf,
                                        self._tables):
            if buf:
                tabs.append(pa.Table.from_pylist(buf, schema=schema))
                buf.clear()
            if tabs:
                w.write_table(pa.concat_tables(tabs) if len(tabs) > 1 else tabs[0])
                tabs.clear()
        self._pending = 0

    def close(self) -> None:
        """Flush and close both files (readable from now on)."""
        self.flush()
        for w in self._writers:
            w.close()

    def __enter__(self) -> FleetTables:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def read_tables(folder: str | Path) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The bags and alarms rows of a fleet folder, sorted by bag (and alarm order)."""
    import pyarrow.parquet as pq

    f = Path(folder)
    if not (f / BAGS_FILE).is_file():
        raise FdMonitorError(f"{f}: no {BAGS_FILE} (expected the --out folder of a fleet "
                             f"analyze)")
    bags = pq.read_table(f / BAGS_FILE).to_pylist()
    alarms = pq.read_table(f / ALARMS_FILE).to_pylist() if (f / ALARMS_FILE).is_file() \
        else []
    bags.sort(key=lambda r: r["bag"])
    alarms.sort(key=lambda r: (r["bag"], r["first_sample"], r["channel"]))
    return bags, alarms


# --------------------------------------------------------------------------------------
# summaries


def _day(ts: Any) -> str:
    return "-" if ts is None else ts.strftime("%Y-%m-%d")


@dataclass
class _Acc:
    bags: int = 0
    errors: int = 0
    samples: int = 0
    hours: float = 0.0
    episodes: int = 0
    with_alarm: int = 0
    outside: int = 0
    first: Any = None
    channels: dict[str, int] = field(default_factory=dict)


def fleet_summary(bags: Sequence[Mapping[str, Any]], alarms: Sequence[Mapping[str, Any]]
                  ) -> dict[str, list[dict[str, Any]]]:
    """Per robot, and per robot, day and channel.

    Returns
    -------
    dict
        ``robots``: per robot ``robot, bags, errors, samples, hours, alarm_episodes,
        bags_with_alarms, outside_region, first_alarm`` (ISO time or None);
        ``days``: per (robot, UTC day of the bag's start, channel) ``robot, day, channel,
        episodes, alarm_samples, bags``.
    """
    per: dict[str, _Acc] = {}
    for b in bags:
        a = per.setdefault(b["robot"], _Acc())
        a.bags += 1
        a.errors += b.get("error") is not None
        a.samples += int(b.get("samples") or 0)
        a.hours += float(b.get("duration_s") or 0.0) / 3600.0
        a.episodes += int(b.get("alarms") or 0)
        a.with_alarm += bool(b.get("alarms"))
        a.outside += int(b.get("outside_alarms") or 0)
    cells: dict[tuple[str, str, str], dict[str, Any]] = {}
    for r in alarms:
        a = per.setdefault(r["robot"], _Acc())
        at = r.get("at")
        if at is not None and (a.first is None or at < a.first):
            a.first = at
        key = (r["robot"], _day(r.get("start_time")), r["channel"])
        c = cells.setdefault(key, {"robot": key[0], "day": key[1], "channel": key[2],
                                   "episodes": 0, "alarm_samples": 0, "bags": set()})
        c["episodes"] += 1
        c["alarm_samples"] += int(r["samples"])
        c["bags"].add(r["bag"])
    robots = [{"robot": k, "bags": a.bags, "errors": a.errors, "samples": a.samples,
               "hours": round(a.hours, 3), "alarm_episodes": a.episodes,
               "bags_with_alarms": a.with_alarm, "outside_region": a.outside,
               "first_alarm": None if a.first is None else a.first.isoformat()}
              for k, a in sorted(per.items())]
    days = [{**c, "bags": len(c["bags"])} for _k, c in sorted(cells.items())]
    return {"robots": robots, "days": days}


# --------------------------------------------------------------------------------------
# the fleet page of `report`


def _md(rows: Sequence[Sequence[Any]], header: Sequence[str]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join("-" if v is None else str(v) for v in r) + " |" for r in rows]
    return out


def figure_alarms_over_time(bags: Sequence[Mapping[str, Any]],
                            alarms: Sequence[Mapping[str, Any]], path: str | Path) -> Path:
    """``alarms_over_time.png``: one line per robot, a mark per alarm episode at its wall
    time (bag start + alarm time), coloured by channel; the recorded spans in grey."""
    from fd_monitor.analysis.report import _plt, _save

    plt = _plt()
    robots = sorted({b["robot"] for b in bags} | {a["robot"] for a in alarms})
    ypos = {r: i for i, r in enumerate(robots)}
    fig, ax = plt.subplots(figsize=(9, 1.2 + 0.45 * max(len(robots), 1)))
    for b in bags:
        t0 = b.get("start_time")
        if t0 is not None and b.get("duration_s"):
            t1 = t0 + _dt.timedelta(seconds=float(b["duration_s"]))
            ax.plot([t0, t1], [ypos[b["robot"]]] * 2, color="0.8", lw=6,
                    solid_capstyle="butt", zorder=1)
    channels = sorted({a["channel"] for a in alarms})
    cmap = plt.get_cmap("tab10")
    for j, ch in enumerate(channels):
        pts = [(a["at"], ypos[a["robot"]]) for a in alarms
               if a["channel"] == ch and a.get("at") is not None]
        if pts:
            ax.scatter([p[0] for p in pts], [p[1] for p in pts], marker="|", s=160,
                       color=cmap(j % 10), label=ch, zorder=2)
    ax.set_yticks(range(len(robots)), robots)
    ax.set_ylim(-0.7, len(robots) - 0.3)
    ax.set_xlabel("time (UTC): bag start + alarm time")
    ax.set_title("alarm episodes over time per robot")
    if channels:
        ax.legend(title="channel", loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    fig.autofmt_xdate()
    return Path(_save(fig, path))


def fleet_report(folder: str | Path, out_dir: str | Path) -> dict[str, Any]:
    """The fleet page: ``fleet.md`` (per-robot table, per robot/day/channel table, bags that
    could not be analysed) and ``alarms_over_time.png``, from a fleet folder's tables.

    Returns
    -------
    dict
        ``summary_md`` (path), ``figures`` (name -> path), ``summary``
        (:func:`fleet_summary`), ``bags``, ``errors``.
    """
    bags, alarms = read_tables(folder)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    s = fleet_summary(bags, alarms)
    fig = figure_alarms_over_time(bags, alarms, out / "alarms_over_time.png")
    errs = [b for b in bags if b.get("error") is not None]
    lines = [f"# Fleet report: {len(bags)} bags, {len({b['robot'] for b in bags})} robots",
             "", f"Tables: `{Path(folder) / BAGS_FILE}`, `{Path(folder) / ALARMS_FILE}`.", "",
             "## Per robot", ""]
    lines += _md([[r["robot"], r["bags"], r["errors"], r["samples"], r["hours"],
                   r["alarm_episodes"], r["bags_with_alarms"], r["outside_region"],
                   r["first_alarm"]] for r in s["robots"]],
                 ["robot", "bags", "errors", "samples", "hours", "alarm episodes",
                  "bags with alarms", "outside region", "first alarm (UTC)"])
    lines += ["", "## Alarms per robot, day and channel", ""]
    lines += _md([[d["robot"], d["day"], d["channel"], d["episodes"], d["alarm_samples"],
                   d["bags"]] for d in s["days"]],
                 ["robot", "day (UTC)", "channel", "episodes", "alarm samples", "bags"]) \
        if s["days"] else ["No alarm in any bag."]
    lines += ["", "## Alarms over time", "", f"![alarms over time per robot]({fig.name})", ""]
    if errs:
        lines += ["## Bags that could not be analysed", ""]
        lines += _md([[b["bag"], b["robot"], b["error"]] for b in errs],
                     ["bag", "robot", "error"])
        lines.append("")
    md = out / "fleet.md"
    md.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return {"summary_md": str(md), "figures": {"alarms_over_time": str(fig)}, "summary": s,
            "bags": len(bags), "errors": len(errs)}
