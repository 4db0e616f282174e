"""``analyze`` of one bag against its length: max RSS and CPU time, against rosbags reading it.

Issue 24 item 4's targets: ``analyze`` under 150 MB max RSS at 10^6 samples, and its time at
most 1.5x what ``rosbags`` takes to read and deserialise every message of the same bag, at
every length. Per length (three_tank_nominal bags, 3 messages a sample, written by
``simulate`` unless ``--bags DIR`` holds ``tt_<n>`` folders already)::

    python benchmarks/bench_analyze_memory.py [--lengths 1e4,1e5,1e6] [--bags DIR] [--profile]

each of ``analyze BAG --gains three_tank_thresholds --json`` and the rosbags read runs in its
own process; the table gives their CPU time (user + sys, from ``os.wait4``: the machine is
shared, so CPU, not wall, is compared), wall time and max RSS, and prints the load average
before and after. ``--profile`` adds, per length, where ``analyze``'s CPU goes (cProfile,
cumulative, in this process): reading the MCAP, decoding, the input policy (join), the
runtime's steps, stacking and summarising.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_fleet import ROSBAGS_READ  # the one rosbags reading script (same folder)

REPO = Path(__file__).resolve().parent.parent
PY = sys.executable

#: Profile groups: (label, function-name suffix of the cumulative entry).
_GROUPS = (("read MCAP (CRC, zstd, records)", "bag_scanner.py:"),
           ("decode (batch)", "reader.py:batch"),
           ("runtime steps", "offline.py:step"),
           ("stack outputs", "runtime.py:stack"),
           ("summary", "summary.py:analyze_run"))


def load() -> str:
    """The 1, 5 and 15 min load averages."""
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def child(argv: list[str]) -> dict[str, float]:
    """Run a process: its wall time, CPU time (user + sys) and max RSS (MB)."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(argv, stdout=out, stderr=err, cwd=REPO)
        _pid, status, ru = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        if os.waitstatus_to_exitcode(status) != 0:
            err.seek(0)
            raise SystemExit(f"{' '.join(argv)} failed:\n{err.read().decode()[-2000:]}")
    return {"wall": wall, "cpu": ru.ru_utime + ru.ru_stime, "rss_mb": ru.ru_maxrss / 1024.0}


def profile(bag: Path) -> str:
    """Where analyze's CPU goes (cumulative seconds under cProfile, and shares)."""
    from fd_monitor.commands.analyze import analyze_bag

    prof = cProfile.Profile()
    prof.enable()
    analyze_bag(str(bag), "three_tank_thresholds")
    prof.disable()
    stats = pstats.Stats(prof)
    total = max(v[3] for v in stats.stats.values())  # type: ignore[attr-defined]
    cum: dict[str, float] = {}
    for (file, _line, name), v in stats.stats.items():  # type: ignore[attr-defined]
        key = f"{Path(file).name}:{name}"
        for label, suffix in _GROUPS:
            if key == suffix or (suffix.endswith(":") and key.startswith(suffix)
                                 and name in ("_chunk", "_scan")):
                cum[label] = max(cum.get(label, 0.0), v[3])
    join = max((v[3] for (f, _l, n), v in stats.stats.items()  # type: ignore[attr-defined]
                if f.endswith("stream.py") and n == "stamped"), default=0.0)
    parts = [f"{label} {cum.get(label, 0.0):.1f} s ({100 * cum.get(label, 0.0) / total:.0f} %)"
             for label, _s in _GROUPS]
    return (f"total {total:.1f} s under cProfile: " + "; ".join(parts)
            + f"; join messages one by one (stream.stamped, runtime steps inside) {join:.1f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--lengths", default="1e4,1e5,1e6")
    ap.add_argument("--bags", default=None, help="folder with tt_<n> bags (kept); default a "
                                                 "temporary folder")
    ap.add_argument("--profile", action="store_true")
    args = ap.parse_args()
    work = Path(args.bags or tempfile.mkdtemp(prefix="bench_analyze_"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"# analyze vs bag length (load before: {load()}); bags in {work}")
    print("| samples | analyze CPU s (wall) | analyze max RSS MB | rosbags CPU s (wall) | "
          "rosbags max RSS MB | analyze / rosbags (CPU) |")
    print("|---|---|---|---|---|---|")
    notes = []
    for text in args.lengths.split(","):
        n = int(float(text))
        bag = work / f"tt_{n}"
        if not bag.exists():
            child([PY, "-m", "fd_monitor", "simulate", "three_tank_nominal", "-o", str(bag),
                   "--duration", str(n * 0.1)])
        an = child([PY, "-m", "fd_monitor", "analyze", str(bag), "--gains",
                    "three_tank_thresholds", "--json"])
        rb = child([PY, "-c", ROSBAGS_READ, str(bag)])
        print(f"| {n:.0e} | {an['cpu']:.2f} ({an['wall']:.1f}) | {an['rss_mb']:.0f} | "
              f"{rb['cpu']:.2f} ({rb['wall']:.1f}) | {rb['rss_mb']:.0f} | "
              f"{an['cpu'] / rb['cpu']:.2f} |", flush=True)
        if args.profile:
            notes.append(f"{n:.0e}: {profile(bag)}")
    for line in notes:
        print(line)
    print(f"(load after: {load()})")


if __name__ == "__main__":
    main()
