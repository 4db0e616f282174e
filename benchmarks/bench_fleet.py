"""Issue 24's figures: a fleet's bags and a campaign's runs on Dask, and memory vs bag length.

The 1 vs 2 worker table (run it on a quiet machine; it prints the load before and after)::

    python benchmarks/bench_fleet.py                 # = scaling: fleet, then evaluate

Parts::

    python benchmarks/bench_fleet.py fleet    [--bags 200]   # 1 vs 2 workers, samples/s
    python benchmarks/bench_fleet.py evaluate [--runs 10000] # 1 vs 2 workers, runs/s
    python benchmarks/bench_fleet.py lengths  [--lengths 1e4,1e5,1e6]

``--repeat N`` runs 1 and 2 workers N times each, alternately, and keeps the fastest of each
(a shared machine's load changes from minute to minute).

* ``fleet``: ``--bags`` library-sized bags (copies of the three_tank bags of ``bags/``, 2,000
  to 3,000 samples each, spread over 10 robots and 5 days by their metadata) analysed by
  the many-bag ``analyze`` (:func:`fd_monitor.commands.fleet.analyze_fleet` on an embedded
  LocalCluster, the command's own code) on 1 and then 2 workers; the tables must be
  identical; samples/s per worker against the single-bag ``analyze`` (warm in this process,
  and as one ``python -m fd_monitor analyze BAG`` command).
* ``evaluate``: ``--runs`` runs of a 4-s pwa_cascade bias scenario (400 samples a run) on
  ``pwa_cascade_qb``, chunks of ``--chunk`` 250, on 1 and then 2 workers; the figures must be
  identical.
* ``lengths``: a three_tank_nominal bag of each length (``simulate``: its time and max RSS),
  then ``analyze`` (max RSS, CPU and wall time) and rosbags reading and deserialising every
  message of the same bag, each in its own process (``/usr/bin/time``-style figures from
  ``resource.getrusage`` of the child).

For every run the table gives the wall time and the CPU seconds of every process: each
worker, this process's main thread (submitting, collecting, writing Parquet) and its other
threads (the Dask client, the embedded scheduler and the nannies all live in this process),
the serial share (this process over the total), the balance of the workers, and the wall
time that CPU allows on idle cores: the largest of the busiest worker, this process (one
GIL) and the total CPU over the cores. The ratio of those bounds (1 / 2 workers) is the
speed-up the work allows; the wall ratio is what the machine gave. On a loaded machine the
CPU a task takes grows too (other processes share the caches: 10 % between two runs of the
same work at load 6-12), so the runs' own "total / bound" (how well a run spread its own
CPU over the cores: 2.00 is perfect on 2) is the figure least changed by the load.

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
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

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
    """This process's CPU time, s (run on each worker and nanny)."""
    return time.process_time()


def load() -> str:
    """The 1, 5 and 15 min load averages."""
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


@dataclass
class Usage:
    """CPU seconds of every process of one run on the embedded cluster, and its wall time.

    ``main``: this process's main thread (submitting, collecting, writing the tables);
    ``dask``: this process's other threads (the event loop of the client, of the embedded
    scheduler and of the nannies, which LocalCluster runs in this process too);
    ``workers``: each worker process; ``nannies``: nanny processes other than this one (none
    on the embedded cluster).
    """

    wall: float = 0.0
    main: float = 0.0
    dask: float = 0.0
    workers: dict[str, float] = field(default_factory=dict)
    nannies: float = 0.0
    load_before: str = ""
    load_after: str = ""

    @property
    def total(self) -> float:
        return self.main + self.dask + sum(self.workers.values()) + self.nannies

    @property
    def client(self) -> float:
        """This process (client + embedded scheduler): one GIL, so serial work."""
        return self.main + self.dask

    @property
    def balance(self) -> float:
        """The workers' CPU over the busiest one's (n for a perfect split)."""
        return sum(self.workers.values()) / max(max(self.workers.values()), 1e-9)

    def bound(self, cores: int) -> float:
        """The wall time this run's CPU allows on ``cores`` idle cores: no less than the
        busiest worker, than the client process (one GIL) or than all the CPU spread over
        the cores."""
        return max(max(self.workers.values()), self.client, self.total / cores)

    def cells(self) -> str:
        w = " + ".join(f"{v:.1f}" for v in sorted(self.workers.values(), reverse=True))
        return (f"{self.wall:.1f} | {w} | {self.main:.2f} | {self.dask:.2f} | "
                f"{self.nannies:.2f} | {self.total:.1f} | {self.client / self.total:.1%} | "
                f"{self.balance:.2f} | {self.bound(CORES):.1f} | "
                f"{self.total / self.bound(CORES):.2f}x | {self.load_before} -> "
                f"{self.load_after}")


#: Cores the speed-up is computed for (the machine's; issue 24: 2).
CORES = os.cpu_count() or 1

HEADER = ("| work | workers | wall s | worker CPU s | client main-thread CPU s | "
          "client's other threads (dask: client, embedded scheduler, nannies) CPU s | "
          "other nanny processes CPU s | total CPU s | "
          "serial share (client / total) | balance | wall the CPU allows on idle cores s | "
          "its CPU done in that wall (total / bound) | load 1/5/15 min before -> after |"
          "\n" + "|---" * 13 + "|")


@contextmanager
def measured(client: Any, usage: Usage) -> Iterator[None]:
    """Fill ``usage`` with the CPU every process of ``client``'s cluster spent inside."""
    usage.load_before = load()
    # LocalCluster's nannies live in this process: their CPU is in ``dask`` already
    own = {w for w, pid in client.run(os.getpid, nanny=True).items() if pid == os.getpid()}
    w0, n0 = client.run(_cpu), client.run(_cpu, nanny=True)
    m0, p0, t0 = time.thread_time(), time.process_time(), time.perf_counter()
    yield
    usage.wall = time.perf_counter() - t0
    m1, p1 = time.thread_time(), time.process_time()
    w1, n1 = client.run(_cpu), client.run(_cpu, nanny=True)
    usage.main = m1 - m0
    usage.dask = (p1 - p0) - usage.main
    usage.workers = {w: v - w0[w] for w, v in w1.items()}
    usage.nannies = sum(v - n0.get(w, 0.0) for w, v in n1.items() if w not in own)
    usage.load_after = load()


Pair = tuple[Usage, Usage]


def speedup_lines(work: str, wall: Pair, cpu: Pair) -> list[str]:
    """The two ratios: measured wall (fastest run of each), and what the CPU figures allow
    on idle cores (the run of each with the smallest bound)."""
    return [f"{work}: speed-up 2 vs 1 worker: wall {wall[0].wall / wall[1].wall:.2f}x "
            f"({wall[0].wall:.1f} s / {wall[1].wall:.1f} s; load before "
            f"{wall[0].load_before} / {wall[1].load_before}); allowed by the CPU figures on "
            f"{CORES} idle cores {cpu[0].bound(CORES) / cpu[1].bound(CORES):.2f}x "
            f"({cpu[0].bound(CORES):.1f} s / {cpu[1].bound(CORES):.1f} s) (target >= 1.8x)"]


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


def _cold_analyze(bag: Path) -> dict[str, float]:
    """``python -m fd_monitor analyze BAG --json`` in its own process (a shell loop's cost
    per bag: interpreter start, imports, gain file, analysis)."""
    return child([PY, "-m", "fd_monitor", "analyze", str(bag), "--gains",
                  "three_tank_thresholds", "--json"])


def fleet(args: argparse.Namespace) -> tuple[Pair, Pair]:
    """200 library-sized bags, 1 then 2 workers; samples/s per worker against single-bag
    analyze."""
    from fd_monitor.analysis.fleet import read_tables
    from fd_monitor.analysis.scaleout import open_client
    from fd_monitor.commands.analyze import analyze_bag
    from fd_monitor.commands.fleet import analyze_fleet, fleet_jobs

    root = Path(args.work or tempfile.mkdtemp(prefix="bench_fleet_"))
    bags = _fleet_dir(root, args.bags)
    jobs = fleet_jobs([str(bags)], "three_tank_thresholds", analyze_bag)
    print(f"## fleet: `analyze DIR --gains three_tank_thresholds` over {len(jobs)} "
          f"library-sized bags (copies of {', '.join(TANK_BAGS)}; load before: {load()})",
          flush=True)
    # single-bag analyze of each kind of bag: warm in this process (CPU), and as a command
    for b in TANK_BAGS:
        analyze_bag(str(REPO / "bags" / b), "three_tank_thresholds")   # imports, caches
    c0 = time.process_time()
    warm_samples = sum(analyze_bag(str(REPO / "bags" / b), "three_tank_thresholds")["samples"]
                       for b in TANK_BAGS)
    warm = warm_samples / (time.process_time() - c0)
    cold = _cold_analyze(REPO / "bags" / TANK_BAGS[0])
    cold_samples = analyze_bag(str(REPO / "bags" / TANK_BAGS[0]),
                               "three_tank_thresholds")["samples"]
    usage: dict[int, list[tuple[Usage, int]]] = {1: [], 2: []}
    tables_of = []
    for _rep in range(args.repeat):
        for n in (1, 2):
            t0 = time.perf_counter()
            with open_client(n) as client:
                up = time.perf_counter() - t0
                client.run(lambda: __import__("fd_monitor.commands.analyze"))   # imports
                u = Usage()
                with measured(client, u):
                    run, tables = analyze_fleet(client, jobs, root / f"tables_{n}")
            rows, alarms = read_tables(root / f"tables_{n}")
            samples = sum(r["samples"] or 0 for r in rows)
            usage[n].append((u, samples))
            tables_of.append((rows, alarms))
            print(f"  {n} worker(s): {u.wall:.1f} s ({run.total} tasks), {samples} samples, "
                  f"{tables.errors} errors; cluster start {up:.1f} s; load {load()}",
                  flush=True)
    assert all(t == tables_of[0] for t in tables_of), "tables differ between runs"
    print()
    print(HEADER)
    for u, _s in usage[1] + usage[2]:
        print(f"| fleet, {len(jobs)} bags | {len(u.workers)} | {u.cells()} |")
    print()
    u1, s1 = min(usage[1], key=lambda x: x[0].bound(CORES))
    u2, s2 = min(usage[2], key=lambda x: x[0].bound(CORES))
    print("| samples/s | 1 worker | 2 workers |\n|---|---|---|")
    per_cpu = [s / (sum(u.workers.values()) / len(u.workers)) / len(u.workers)
               for u, s in ((u1, s1), (u2, s2))]
    per_wall = [s / u.wall / len(u.workers) for u, s in ((u1, s1), (u2, s2))]
    print(f"| per worker, on its CPU time | {per_cpu[0]:,.0f} | {per_cpu[1]:,.0f} |")
    print(f"| per worker, on the wall time | {per_wall[0]:,.0f} | {per_wall[1]:,.0f} |")
    print(f"| per worker on its CPU / single-bag analyze warm in one process ({warm:,.0f}/s "
          f"CPU) | {per_cpu[0] / warm:.2f}x | {per_cpu[1] / warm:.2f}x |")
    cold_rate = cold_samples / cold["cpu"]
    print(f"| per worker on its CPU / one `python -m fd_monitor analyze BAG` command "
          f"({cold_rate:,.0f}/s CPU, {cold['wall']:.2f} s wall for {cold_samples} samples) | "
          f"{per_cpu[0] / cold_rate:.2f}x | {per_cpu[1] / cold_rate:.2f}x |")
    cold_wall = cold_samples / cold["wall"]
    print(f"| per worker on the wall time / the same command on its wall time "
          f"({cold_wall:,.0f}/s) | {per_wall[0] / cold_wall:.2f}x | "
          f"{per_wall[1] / cold_wall:.2f}x |")
    print()
    print(f"tables identical on 1 and 2 workers ({len(tables_of)} runs): yes")
    best = (min((u for u, _s in usage[1]), key=lambda u: u.wall),
            min((u for u, _s in usage[2]), key=lambda u: u.wall))
    for line in speedup_lines("fleet", best, (u1, u2)):
        print(line)
    return best, (u1, u2)


def evaluate(args: argparse.Namespace) -> tuple[Pair, Pair]:
    """``--runs`` Monte Carlo runs, 1 then 2 workers; the figures must be identical."""
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
    print(f"## evaluate: {args.runs} runs of a {sc.n_samples}-sample pwa_cascade b1 scenario "
          f"on pwa_cascade_qb, rho 0.05 and 1, chunks of {args.chunk} (load before: {load()})",
          flush=True)
    got = []
    usage: dict[int, list[Usage]] = {1: [], 2: []}
    for _rep in range(args.repeat):
        for n in (1, 2):
            t0 = time.perf_counter()
            with open_client(n) as client:
                up = time.perf_counter() - t0
                client.run(lambda: __import__("fd_monitor.analysis.evaluate_dask"))
                u = Usage()
                with measured(client, u):
                    rows, done = run_campaign_on(client, g, [sc], args.runs,
                                                 chunk=args.chunk, rhos=[0.05, 1.0],
                                                 progress=False)
            got.append([r.as_dict() for r in rows])
            usage[n].append(u)
            print(f"  {n} worker(s): {u.wall:.1f} s ({args.runs / u.wall:.0f} runs/s, "
                  f"{done.total} tasks); cluster start {up:.1f} s; load {load()}", flush=True)
    assert all(g == got[0] for g in got), "figures differ between runs"
    print()
    print(HEADER)
    for u in usage[1] + usage[2]:
        print(f"| evaluate, {args.runs} runs | {len(u.workers)} | {u.cells()} |")
    print()
    print(f"figures identical on 1 and 2 workers ({len(got)} runs): yes ({got[0]})")
    best = (min(usage[1], key=lambda u: u.wall), min(usage[2], key=lambda u: u.wall))
    cpu = (min(usage[1], key=lambda u: u.bound(CORES)), min(usage[2],
                                                             key=lambda u: u.bound(CORES)))
    for line in speedup_lines("evaluate", best, cpu):
        print(line)
    return best, cpu


def scaling(args: argparse.Namespace) -> None:
    """Both, then the 1 vs 2 worker summary."""
    f = fleet(args)
    print()
    e = evaluate(args)
    print()
    print("## summary: 2 vs 1 worker (target >= 1.8x)")
    print("| work | wall 1 worker s | wall 2 workers s | wall ratio | ratio the CPU allows on "
          f"{CORES} idle cores | 2 workers: total CPU / bound | load before (1 / 2 workers) |"
          "\n|---|---|---|---|---|---|---|")
    for what, (wall, cpu) in ((f"fleet, {args.bags} bags", f),
                              (f"evaluate, {args.runs} runs", e)):
        print(f"| {what} | {wall[0].wall:.1f} | {wall[1].wall:.1f} | "
              f"{wall[0].wall / wall[1].wall:.2f}x | "
              f"{cpu[0].bound(CORES) / cpu[1].bound(CORES):.2f}x | "
              f"{cpu[1].total / cpu[1].bound(CORES):.2f}x | {wall[0].load_before} / "
              f"{wall[1].load_before} |")
    print(f"load after: {load()}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("part", nargs="?", default="scaling",
                   choices=("scaling", "fleet", "evaluate", "lengths"))
    p.add_argument("--bags", type=int, default=200)
    p.add_argument("--runs", type=int, default=10_000)
    p.add_argument("--chunk", type=int, default=250, help="evaluate: runs per chunk")
    p.add_argument("--repeat", type=int, default=1,
                   help="run 1 and 2 workers this many times, alternately (the fastest run "
                        "of each counts: on a shared machine)")
    p.add_argument("--lengths", default="1e4,1e5,1e6")
    p.add_argument("--work", default=None, help="folder for the bags (default: a temp one)")
    p.add_argument("--keep", action="store_true", help="keep the generated length bags")
    args = p.parse_args()
    print(f"$ python benchmarks/bench_fleet.py {' '.join(sys.argv[1:])}")
    print(f"$ uptime: load {load()} on {CORES} cores")
    {"scaling": scaling, "fleet": fleet, "evaluate": evaluate,
     "lengths": lengths}[args.part](args)


if __name__ == "__main__":
    main()
