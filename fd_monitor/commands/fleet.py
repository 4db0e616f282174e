"""``python -m fd_monitor analyze BAG_OR_DIR_OR_GLOB ... --gains G``: a fleet's bags on Dask.

``analyze`` with more than one bag, a folder of bags, a glob pattern or any of the options
below runs here: the bags in batches, one task each (:func:`analyze_batch`; each bag by
:func:`analyze_task`, the single-bag ``analyze --json`` document reduced to table rows by
:mod:`fd_monitor.analysis.fleet`; the gain file loaded once per worker) on an embedded Dask
``LocalCluster`` (one worker per core; ``--workers N``) or on a running Dask scheduler
(``--scheduler tcp://HOST:PORT``; its workers need the fd_monitor package and the bags at the
same paths). Results are written to ``--out``'s Parquet tables as they finish; a bag that
cannot be read or analysed is one row with its ``error``; Ctrl-C stops, keeping every bag
that finished. Then the summary per robot, and per robot, day and channel.
"""

from __future__ import annotations

import argparse
import glob
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fd_monitor.analysis.fleet import (
    ALARMS_FILE,
    BAGS_FILE,
    FleetMap,
    FleetTables,
    alarm_rows,
    bag_identity,
    bag_row,
    error_row,
    find_bags,
    fleet_summary,
    is_bag,
    read_tables,
)
from fd_monitor.analysis.scaleout import (
    RateBar,
    TaskRun,
    guided_batches,
    open_client,
    run_tasks,
)
from fd_monitor.commands._cluster import add_cluster_arguments
from fd_monitor.commands._common import print_json, print_table
from fd_monitor.model.errors import FdMonitorError

__all__ = ["add_fleet_arguments", "analyze_batch", "analyze_fleet", "analyze_task",
           "fleet_jobs", "is_fleet", "load_gains_cached", "run_fleet"]

#: This process's gain files and plants, loaded and verified once: (gain file's path, its
#: SHA-256, plant file's path, its SHA-256) -> (GainFile, System). A worker analyses many
#: bags with the same few gain files; loading one costs 10-25 ms (a library bag: 150-300
#: ms), and an edited file has another digest, so it is loaded again.
_LOADED: dict[tuple[str | None, ...], tuple[Any, Any]] = {}
_LOADED_MAX = 64


def add_fleet_arguments(parser: argparse.ArgumentParser) -> None:
    """The many-bag options of ``analyze``."""
    g = parser.add_argument_group("many bags (a folder of bags, a glob, or several BAGs)")
    g.add_argument("--out", default=None, metavar="DIR",
                   help=f"folder for the tables {BAGS_FILE} (one row per bag) and "
                        f"{ALARMS_FILE} (one row per alarm episode) (default: ./fleet)")
    g.add_argument("--map", default=None, metavar="FLEETMAP",
                   help="mapping file: robot, bag path or bag metadata -> gain file (and "
                        "plant file, adapter); --gains for the bags no rule matches")
    g.add_argument("--force", action="store_true", help="overwrite the tables in --out")
    g.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_cluster_arguments(g)


def is_fleet(args: argparse.Namespace) -> bool:
    """``analyze``'s arguments ask for the many-bag run (else: the single-bag output)."""
    srcs = list(args.bag)
    if len(srcs) > 1 or any(getattr(args, o, None) is not None
                            for o in ("out", "map", "workers", "scheduler")):
        return True
    src = srcs[0]
    if Path(src).exists():
        return not is_bag(src) and Path(src).is_dir()
    return glob.has_magic(src)


def _local(path: str | None) -> str | None:
    """An existing file given relative to this directory, made absolute (a worker's working
    directory is its own); a shipped name is left as it is."""
    return None if path is None else str(Path(path).resolve()) if Path(path).exists() \
        else path


def _fingerprint(source: str | None, kind: str) -> tuple[str | None, str | None]:
    """(resolved path, SHA-256 of its bytes) of a gain or plant file; (None, None) for none;
    (source, None) when it cannot be found (the loader then says why)."""
    import hashlib

    from fd_monitor.model.paths import find_config_file

    if source is None:
        return None, None
    try:
        path = find_config_file(source, kind, FdMonitorError)
        return str(path.resolve()), hashlib.sha256(path.read_bytes()).hexdigest()
    except (FdMonitorError, OSError):
        return str(source), None


def load_gains_cached(gains: str, system: str | None = None) -> tuple[Any, Any]:
    """The gain file and its plant as ``analyze`` loads them (digest, plant SHA-256 and
    certificate checked), once per process for each content of the two files.

    Raises
    ------
    FdMonitorError
        As :func:`fd_monitor.core.methods.load_gains` (a failure is not cached).
    """
    from fd_monitor.core.methods import load_gains
    from fd_monitor.model.system import gain_system

    key = (*_fingerprint(gains, "gains"), *_fingerprint(system, "systems"))
    hit = _LOADED.get(key) if key[1] is not None else None
    if hit is not None:
        return hit
    raw = load_gains(gains, verify=False)
    plant = gain_system(raw, system)
    got = (load_gains(gains, plant), plant)
    if key[1] is not None and (system is None or key[3] is not None):
        if len(_LOADED) >= _LOADED_MAX:
            _LOADED.clear()
        _LOADED[key] = got
    return got


def analyze_task(job: dict[str, Any]) -> dict[str, Any]:
    """One bag (a Dask task): its robot, gain file and ``analyze`` document, as table rows.

    Parameters
    ----------
    job : dict
        ``bag`` (path to read), ``name`` (the bag as the user named it: the ``bag``
        column), ``gains``, ``system``, ``adapter``, ``agei``, ``map`` (FleetMap or None),
        ``analyze`` (the single-bag analysis,
        :func:`fd_monitor.commands.analyze.analyze_bag`).

    Returns
    -------
    dict
        ``row`` (the bags table's row) and ``alarms`` (the alarms table's rows). Every
        failure -- an unreadable or corrupt bag, no gain file for it, a bug -- is the row's
        ``error``, never an exception.
    """
    analyze_bag = job["analyze"]             # commands.analyze.analyze_bag, by reference
    bag, name = job["bag"], job["name"]
    ident: dict[str, Any] = {"robot": Path(name).parent.name}
    gains = job.get("gains")
    try:
        ident = bag_identity(bag)
        gains, system, adapter = job.get("gains"), job.get("system"), job.get("adapter")
        fm: FleetMap | None = job.get("map")
        rule = None if fm is None else fm.choose(name, ident["robot"], ident["custom_data"])
        if rule is not None:
            gains, system, adapter = rule.gains, rule.system, rule.adapter
        if gains is None:
            raise FdMonitorError(f"no rule of {fm.source if fm else 'the fleet map'} matches "
                                 f"(robot {ident['robot']}) and no --gains")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            doc = analyze_bag(bag, gains, system, agei=job.get("agei", True), adapter=adapter,
                              loaded=load_gains_cached(gains, system))
        doc = {**doc, "bag": name}
        if caught and "integrity" not in doc:
            doc["damage"] = [str(w.message) for w in caught]
        return {"row": bag_row(doc, ident), "alarms": alarm_rows(doc, ident)}
    except FdMonitorError as exc:      # the bag named as the user named it
        return {"row": error_row(name, ident, str(exc).replace(bag, name), gains),
                "alarms": []}
    except Exception as exc:  # a bag must never fail the fleet: name what went wrong
        return {"row": error_row(name, ident, f"{name}: {type(exc).__name__}: {exc}", gains),
                "alarms": []}


def analyze_batch(jobs: list[dict[str, Any]]) -> dict[str, Any]:
    """Several bags in one Dask task (:func:`analyze_task` each), their rows as Arrow
    tables: one transfer and one append to the tables per batch, not per bag or per row.

    Returns
    -------
    dict
        ``bags`` and ``alarms``: ``pyarrow.Table`` of :func:`~fd_monitor.analysis.fleet.
        bag_schema` and :func:`~fd_monitor.analysis.fleet.alarm_schema`.
    """
    import pyarrow as pa

    from fd_monitor.analysis.fleet import alarm_schema, bag_schema

    rows, alarms = [], []
    for job in jobs:
        r = analyze_task(job)
        rows.append(r["row"])
        alarms += r["alarms"]
    return {"bags": pa.Table.from_pylist(rows, schema=bag_schema()),
            "alarms": pa.Table.from_pylist(alarms, schema=alarm_schema())}


def _bag_bytes(path: str) -> int:
    """Bytes of a bag's files (0 when it cannot be listed): how long it takes, roughly."""
    try:
        with os.scandir(path) as it:
            return sum(e.stat().st_size for e in it if e.is_file())
    except OSError:
        return 0


def fleet_jobs(sources: list[str], gains: str | None, analyze: Callable[..., Any],
               system: str | None = None, adapter: str | None = None, agei: bool = True,
               fleet_map: FleetMap | None = None) -> list[dict[str, Any]]:
    """One :func:`analyze_task` job per bag of ``sources`` (:func:`find_bags`): paths made
    absolute for the workers, the ``bag`` column as the user named it; ``analyze`` is
    :func:`fd_monitor.commands.analyze.analyze_bag` (passed in: that module imports this
    one)."""
    return [{"bag": str(Path(b).resolve()), "name": os.path.normpath(str(b)),
             "gains": _local(gains), "system": _local(system), "adapter": _local(adapter),
             "agei": agei, "map": fleet_map, "analyze": analyze} for b in find_bags(sources)]


def analyze_fleet(client: Any, jobs: list[dict[str, Any]], out: str | Path,
                  progress: bool = False, per_worker: int = 4) -> tuple[TaskRun, FleetTables]:
    """Run the jobs on ``client`` and write the tables into ``out`` as they finish.

    The largest bags go first and the bags are sent in batches (:func:`analyze_batch`,
    :func:`~fd_monitor.analysis.scaleout.guided_batches`: large while many remain, single
    bags at the end), so the workers finish together and many small bags do not cost one
    task each (``per_worker``: batches of the remaining bags per worker). The rows are the
    same whatever the batches (each bag is analysed alone).

    Returns
    -------
    (TaskRun, FleetTables)
        What ran (``stopped`` after Ctrl-C; ``total``/``done`` count tasks) and the closed
        tables (their counts).
    """
    workers = max(1, len(client.scheduler_info().get("workers", {})))
    order = sorted(jobs, key=lambda j: -_bag_bytes(j["bag"]))
    batches = [order[b.start:b.stop] for b in guided_batches(len(order), workers,
                                                                  per_worker=per_worker)]
    bar = RateBar(len(jobs), "analyze", "bags", enabled=progress)
    with FleetTables(out) as tables:
        run = run_tasks(client, analyze_batch, batches,
                        lambda _i, r: tables.add_tables(r["bags"], r["alarms"]), bar,
                        [len(b) for b in batches])
    return run, tables


def run_fleet(args: argparse.Namespace, analyze: Callable[..., Any]) -> int:
    """Analyse many bags on Dask (``analyze``: the single-bag analysis), write the tables,
    print the summary."""
    from fd_monitor.model.paths import check_output

    out = Path(args.out or "fleet")
    check_output(out, "--out", FdMonitorError, folder=True)
    if not args.force and any((out / f).exists() for f in (BAGS_FILE, ALARMS_FILE)):
        raise FdMonitorError(f"--out {out}: holds the tables of an earlier run (would "
                             f"overwrite; use --force)")
    fmap = FleetMap.load(args.map) if args.map else None
    jobs = fleet_jobs(args.bag, args.gains, analyze, args.system, args.adapter,
                      not args.no_agei, fmap)
    with open_client(args.workers, args.scheduler) as client:
        run, tables = analyze_fleet(client, jobs, out, progress=not args.no_progress)
    bag_rows, alarms = read_tables(out)
    s = fleet_summary(bag_rows, alarms)
    if args.json:
        print_json({"bags": len(bag_rows), "of": len(jobs), "errors": tables.errors,
                    "alarm_episodes": len(alarms), "stopped": run.stopped,
                    "workers": run.workers, "seconds": round(run.seconds, 3),
                    "tables": {"bags": str(out / BAGS_FILE), "alarms": str(out / ALARMS_FILE)},
                    **s})
        return 130 if run.stopped else 0
    print(f"analyze: {len(bag_rows)} of {len(jobs)} bags on {run.workers} worker(s) in "
          f"{run.seconds:.1f} s ({tables.errors} could not be analysed)"
          + ("; STOPPED by Ctrl-C: the tables hold the bags that finished" if run.stopped
             else ""))
    print(f"tables: {out / BAGS_FILE}, {out / ALARMS_FILE}")
    print()
    print_table([(r["robot"], r["bags"], r["errors"], r["samples"], f"{r['hours']:.2f}",
                  r["alarm_episodes"], r["bags_with_alarms"], r["outside_region"],
                  r["first_alarm"] or "-") for r in s["robots"]],
                header=("robot", "bags", "errors", "samples", "hours", "alarm_episodes",
                        "bags_with_alarms", "outside_region", "first_alarm_utc"),
                title="per robot")
    print()
    if s["days"]:
        print_table([(d["robot"], d["day"], d["channel"], d["episodes"], d["alarm_samples"],
                      d["bags"]) for d in s["days"]],
                    header=("robot", "day_utc", "channel", "episodes", "alarm_samples",
                            "bags"), title="alarms per robot, day and channel")
    else:
        print("alarms: none")
    errs = [b for b in bag_rows if b["error"] is not None]
    if errs:
        print()
        print_table([(b["bag"], b["error"]) for b in errs[:20]], header=("bag", "error"),
                    title=f"bags that could not be analysed ({len(errs)}"
                          + (", first 20)" if len(errs) > 20 else ")"))
    return 130 if run.stopped else 0
