"""Issue 24's figures: a fleet's bags and a campaign's runs on Dask, and memory vs bag length.

Three parts (each prints the load average before and after, the command and a table)::

    python benchmarks/bench_fleet.py fleet    [--bags 200]   # 1 vs 2 workers, samples/s
    python benchmarks/bench_fleet.py evaluate [--runs 10000] # 1 vs 2 workers, runs/s
    python benchmarks/bench_fleet.py lengths  [--lengths 1e4,1e5,1e6]

* ``fleet``: ``--bags`` library-sized bags (copies of the three_tank bags of ``bags/``, 2,500
  to 3,000 samples each, spread over 10 robots and 5 days by their metadata) analysed by
  ``analyze DIR --gains three_tank_thresholds`` on 1 and then 2 workers (an embedded
  LocalCluster, the command's own code); the speed-up, and samples/s per worker against the
  single-bag ``analyze`` of one of them in this process.
* ``evaluate``: ``--runs`` runs of a 4-s pwa_cascade bias scenario (400 samples a run) on
  ``pwa_cascade_qb``, chunks of 250, on 1 and then 2 workers; the figures must be identical.
* ``lengths``: a three_tank_nominal bag of each length (``simulate``: its time and max RSS),
  then ``analyze`` (max RSS, CPU and wall time) and rosbags reading and deserialising every
  message of the same bag, each in its own process (``/usr/bin/time``-style figures from
  ``resource.getrusage`` of the child).

Targets (issue 24): >= 1.8x with 2 workers; analyze max RSS < 150 MB at 10^6 samples and
<= 1.5x rosbags' time at every length.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parent.parent
PY = sys.executable
TANK_BAGS = ["three_tank_nominal", "three_tank_bias_h1", "three_tank_bias_h2",
             "three_tank_incipient_h3", "three_tank_valve"]

ROSBAGS_READ = """
import sys
from pathlib import Path
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
n = 0
with AnyReader([Path(sys.argv[1])], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as r:
    for con, _t, raw in r.messages():
        r.deserialize(raw, con.msgtype)
        n += 1
print(n)
"""


def _cpu() -> float:
    """This process's CPU time, s (run on each worker)."""
    return time.process_time()


def worker_cpu(client: object, before: dict[str, float] | None = None) -> dict[str, float]:
    """CPU seconds of each worker process (since ``before``)."""
    now = client.run(_cpu)  # type: ignore[attr-defined]
    return {w: v - (before or {}).get(w, 0.0) for w, v in now.items()}


def load() -> str:
    """The 1, 5 and 15 min load averages."""
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def child(argv: list[str]) -> dict[str, float]:
    """Run a process; its wall time, CPU time (user + sys) and max RSS (MB), from its own
    resource usage (``os.wait4``)."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(argv, stdout=out, stderr=err, cwd=REPO)
        _pid, status, ru = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            err.seek(0)
            raise SystemExit(f"{' '.join(argv)} failed:\n{err.read().decode()[-2000:]}")
    return {"wall": wall, "cpu": ru.ru_utime + ru.ru_stime, "rss_mb": ru.ru_maxrss / 1024.0}


def lengths(args: argparse.Namespace) -> None:
    work = Path(args.work or tempfile.mkdtemp(prefix="bench_fleet_"))
    print(f"# lengths (load before: {load()}); bags in {work}")
    print("| samples | simulate s (cpu) | simulate max RSS MB | analyze s wall (cpu) | "
          "analyze max RSS MB | rosbags read s wall (cpu) | rosbags max RSS MB | "
          "analyze / rosbags (cpu) |")
    print("|---|---|---|---|---|---|---|---|")
    for text in args.lengths.split(","):
        n = int(float(text))
        bag = work / f"tt_{n}"
        if bag.exists():
            shutil.rmtree(bag)
        sim = child([PY, "-m", "fd_monitor", "simulate", "three_tank_nominal", "-o", str(bag),
                     "--duration", str(n * 0.1)])
        an = child([PY, "-m", "fd_monitor", "analyze", str(bag), "--gains",
                    "three_tank_thresholds", "--json"])
        rb = child([PY, "-c", ROSBAGS_READ, str(bag)])
        print(f"| {n:.0e} | {sim['wall']:.1f} ({sim['cpu']:.1f}) | {sim['rss_mb']:.0f} | "
              f"{an['wall']:.1f} ({an['cpu']:.1f}) | {an['rss_mb']:.0f} | "
              f"{rb['wall']:.1f} ({rb['cpu']:.1f}) | {rb['rss_mb']:.0f} | "
              f"{an['cpu'] / rb['cpu']:.2f} |", flush=True)
        if not args.keep:
            shutil.rmtree(bag)
    print(f"(load after: {load()})")


def _fleet_dir(root: Path, n: int) -> Path:
    """``n`` copies of the three_tank bags in 10 robot folders, starts over 5 days."""
    fleet = root / "fleet"
    if fleet.exists():
        shutil.rmtree(fleet)
    for i in range(n):
        robot, day = f"robot_{i % 10:02d}", (i // 10) % 5
        src = REPO / "bags" / TANK_BAGS[i % len(TANK_BAGS)]
        dst = fleet / robot / f"bag_{i:04d}"
        shutil.copytree(src, dst, ignore=shutil.ignore_patterns("expected.yaml"))
        meta = dst / "metadata.yaml"
        doc = yaml.safe_load(meta.read_text())
        info = doc["rosbag2_bagfile_information"]
        info["starting_time"]["nanoseconds_since_epoch"] = int(
            (1_790_000_000 + day * 86_400 + (i % 37) * 600) * 1e9)
        meta.write_text(yaml.safe_dump(doc))
    return fleet


def fleet(args: argparse.Namespace) -> None:
    from fd_monitor.analysis.fleet import read_tables
    from fd_monitor.analysis.scaleout import open_client
    from fd_monitor.commands.analyze import analyze_bag
    from fd_monitor.commands.fleet import analyze_fleet, fleet_jobs

    root = Path(args.work or tempfile.mkdtemp(prefix="bench_fleet_"))
    bags = _fleet_dir(root, args.bags)
    jobs = fleet_jobs([str(bags)], "three_tank_thresholds", analyze_bag)
    print(f"# fleet: {len(jobs)} bags (load before: {load()})")
    analyze_bag(jobs[0]["bag"], "three_tank_thresholds")           # imports, gain file
    w1 = time.perf_counter()
    one = analyze_bag(jobs[0]["bag"], "three_tank_thresholds")
    single = {"wall": time.perf_counter() - w1, "samples": one["samples"]}
    rows = []
    for n in (1, 2):
        with open_client(n) as client:
            client.run(lambda: __import__("fd_monitor.commands.analyze"))   # warm the workers
            c0 = worker_cpu(client)
            run, tables = analyze_fleet(client, jobs, root / f"tables_{n}")
            cpu = worker_cpu(client, c0)
        b, _a = read_tables(root / f"tables_{n}")
        samples = sum(r["samples"] or 0 for r in b)
        rows.append((n, run.seconds, samples, tables.errors, cpu))
        print(f"  {n} worker(s): {run.seconds:.1f} s, {samples} samples, "
              f"{tables.errors} errors, worker CPU s {sorted(round(v, 1) for v in cpu.values())}"
              f" (load {load()})", flush=True)
    s1, s2 = rows[0][1], rows[1][1]
    print("| workers | s | bags/s | samples/s | samples/s per worker | vs single-bag analyze |")
    print("|---|---|---|---|---|---|")
    per_bag = single["samples"] / single["wall"]
    for n, sec, samples, _e, _c in rows:
        print(f"| {n} | {sec:.1f} | {len(jobs) / sec:.2f} | {samples / sec:,.0f} | "
              f"{samples / sec / n:,.0f} | {samples / sec / n / per_bag:.2f}x |")
    print(f"single-bag analyze in this process (warm): {single['samples']} samples in "
          f"{single['wall']:.2f} s = {per_bag:,.0f} samples/s")
    c2 = rows[1][4]
    print(f"speed-up 2 vs 1 worker: {s1 / s2:.2f}x wall (target >= 1.8); balance of the 2 "
          f"workers (their CPU over the busiest one's, the speed-up on idle cores): "
          f"{sum(c2.values()) / max(c2.values()):.2f}x; load after: {load()}")


def evaluate(args: argparse.Namespace) -> None:
    from fd_monitor.analysis.evaluate_dask import run_campaign_on
    from fd_monitor.analysis.scaleout import open_client
    from fd_monitor.core.methods import load_gains
    from fd_monitor.model.scenario import load_scenario

    root = Path(args.work or tempfile.mkdtemp(prefix="bench_fleet_"))
    root.mkdir(parents=True, exist_ok=True)
    (root / "b1.yaml").write_text(
        "name: short_b1\nsystem: pwa_cascade\nduration: 4.0\nseed: 1\nfaults:\n"
        "  - {channel: b1_step, profile: abrupt, time: 2.0, magnitude: 0.5}\n")
    sc = load_scenario(str(root / "b1.yaml"))
    g = load_gains("pwa_cascade_qb")
    print(f"# evaluate: {args.runs} runs of {sc.n_samples} samples (load before: {load()})")
    got = []
    for n in (1, 2):
        with open_client(n) as client:
            client.run(lambda: __import__("fd_monitor.analysis.evaluate"))
            c0 = worker_cpu(client)
            rows, done = run_campaign_on(client, g, [sc], args.runs, chunk=250,
                                         rhos=[0.05, 1.0], progress=False)
            cpu = worker_cpu(client, c0)
        got.append((n, done.seconds, [r.as_dict() for r in rows], cpu))
        print(f"  {n} worker(s): {done.seconds:.1f} s ({args.runs / done.seconds:.0f} runs/s; "
              f"worker CPU s {sorted(round(v, 1) for v in cpu.values())}; load {load()})",
              flush=True)
    assert got[0][2] == got[1][2], "figures differ between 1 and 2 workers"
    print(f"identical figures: {got[0][2]}")
    c2 = got[1][3]
    print(f"speed-up 2 vs 1 worker: {got[0][1] / got[1][1]:.2f}x wall (target >= 1.8); "
          f"balance of the 2 workers (their CPU over the busiest one's, the speed-up on idle "
          f"cores): {sum(c2.values()) / max(c2.values()):.2f}x; load after: {load()}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("part", choices=("fleet", "evaluate", "lengths"))
    p.add_argument("--bags", type=int, default=200)
    p.add_argument("--runs", type=int, default=10_000)
    p.add_argument("--lengths", default="1e4,1e5,1e6")
    p.add_argument("--work", default=None, help="folder for the bags (default: a temp one)")
    p.add_argument("--keep", action="store_true", help="keep the generated length bags")
    args = p.parse_args()
    print(f"$ python benchmarks/bench_fleet.py {' '.join(sys.argv[1:])}")
    {"fleet": fleet, "evaluate": evaluate, "lengths": lengths}[args.part](args)


if __name__ == "__main__":
    main()
