"""Time to analyse and to report every bag of the library.

Run: .venv/bin/python benchmarks/bench_bags.py [--repeat 1] [--only NAME ...]

Per bag of ``bags/library.yaml``: samples, size on disk, the wall time of the regression
summary (:func:`fd_monitor.analysis.expectations.analyze_summary`: ``analyze``'s chain, or
the QB runtime for pwa_cascade bags) and of the full report
(:func:`fd_monitor.analysis.report.bag_report`: one more
pass for the per-sample arrays, 3-4 PNG figures, summary.md), best of ``--repeat``.
"""

from __future__ import annotations

import argparse
import tempfile
import time

from fd_monitor.analysis.expectations import analyze_summary
from fd_monitor.analysis.library import load_library
from fd_monitor.analysis.report import bag_report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--only", nargs="+", default=None)
    args = ap.parse_args()
    lib = load_library()
    print(f"{'bag':<26} {'samples':>7} {'size kB':>8} {'analyze s':>10} {'samples/s':>10} "
          f"{'report s':>9}")
    for name in args.only or lib.names:
        spec = lib[name]
        size = sum(f.stat().st_size for f in spec.folder.iterdir()) / 1e3
        ta, tr, n = [], [], 0
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            s = analyze_summary(spec.folder, spec.gains, transient=spec.transient)
            ta.append(time.perf_counter() - t0)
            n = s["samples"]
            with tempfile.TemporaryDirectory() as d:
                t0 = time.perf_counter()
                bag_report(spec.folder, d)
                tr.append(time.perf_counter() - t0)
        print(f"{name:<26} {n:>7} {size:>8.0f} {min(ta):>10.2f} {n / min(ta):>10.0f} "
              f"{min(tr):>9.2f}")


if __name__ == "__main__":
    main()
