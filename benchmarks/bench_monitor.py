"""Throughput of the core diagnosis chain (Heracleous et al.) on three_tank, offline.

Run from the repository root::

    python benchmarks/bench_monitor.py [--gains three_tank_thresholds] [--runs 200]

Prints samples per second of

* ``Monitor.step`` (one stream, one sample per call, input validation included: what
  ``analyze`` and the in-process node pipeline do);
* ``run_batch`` over N runs in lock step (Monte Carlo; all per-sample arrays kept) for several N.

Target of the issue: 50,000 samples/s or more. No assertion: figures only.
"""

from __future__ import annotations

import argparse
import time

from fd_monitor.core.monitor import Monitor, run_batch
from fd_monitor.core.simulator import simulate_batch
from fd_monitor.gains import load_gains
from fd_monitor.scenario import load_scenario
from fd_monitor.system import load_system


def main() -> None:
    """Measure and print."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gains", default="three_tank_thresholds")
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--scenario", default="three_tank_bias_h1")
    args = ap.parse_args()
    system = load_system("three_tank")
    gains = load_gains(args.gains, system)
    sc = load_scenario(args.scenario)
    tr = simulate_batch(sc, list(range(args.runs)))
    K = tr.y.shape[1]
    mon = Monitor(system, gains)
    t0 = time.perf_counter()
    for j in range(K):
        mon.step(j, tr.u[0, j], tr.y[0, j])
    dt = time.perf_counter() - t0
    print(f"scenario {sc.name}, {K} samples per run")
    print(f"Monitor.step (single stream):      {K / dt:12,.0f} samples/s "
          f"({1e6 * dt / K:.0f} us/sample)")
    for n in sorted({1, 10, 50, args.runs}):
        sub = type(tr)(tr.scenario, tr.seeds[:n], tr.k, tr.t, tr.u[:n], tr.y[:n], tr.x[:n],
                       tr.mode[:n], tr.faults[:n])
        t0 = time.perf_counter()
        run_batch(system, gains, sub)
        dt = time.perf_counter() - t0
        print(f"run_batch, N = {n:4d} runs:          {n * K / dt:12,.0f} samples/s "
              f"({dt:.2f} s)")


if __name__ == "__main__":
    main()
