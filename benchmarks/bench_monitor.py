"""Throughput of the core diagnosis chain (Heracleous et al.) on three_tank, offline.

Run from the repository root::

    python benchmarks/bench_monitor.py [--gains three_tank_thresholds] [--runs 200] [--repeat 5]

Prints samples per second of

* ``Monitor.step`` (one stream, one sample per call, input validation included: what
  ``analyze`` and the fused ``monitor`` node do), on Python floats (the components'
  ``step1``);
* beside it, the same single stream through the batch path with one run (``BatchMonitor``,
  numpy on 1-element arrays: what ``Monitor.step`` did before the float path; same bits);
* ``run_batch`` over N runs in lock step (Monte Carlo; all per-sample arrays kept) for several N;
* every shipped gain file's runtime, single stream (``bench_runtimes.print_rates``).

Single-stream figures are the best of ``--repeat`` passes (the machine is shared: the best
pass is the one least disturbed), wall clock and, for ``Monitor.step``, CPU time of this
process (what the code costs when it has a core to itself); the 1-minute load average is
printed with each. Target (issue 25): 80,000 samples/s or more for ``Monitor.step``
(doc/reference/benchmarks-runtimes.md). No assertion: figures only.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from bench_runtimes import print_rates

from fd_monitor.core.methods import load_gains
from fd_monitor.core.monitor import BatchMonitor, Monitor, run_batch
from fd_monitor.core.simulator import simulate_batch
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system


def _load() -> str:
    return f"load average {os.getloadavg()[0]:.2f} (1 min, {os.cpu_count()} cores)"


def main() -> None:
    """Measure and print."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gains", default="three_tank_thresholds")
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=5, help="single-stream passes (best kept)")
    ap.add_argument("--scenario", default="three_tank_bias_h1")
    args = ap.parse_args()
    system = load_system("three_tank")
    gains = load_gains(args.gains, system)
    sc = load_scenario(args.scenario)
    tr = simulate_batch(sc, list(range(args.runs)))
    K = tr.y.shape[1]
    print(f"scenario {sc.name}, {K} samples per run")
    u0, y0 = tr.u[0], tr.y[0]
    best = cpu = float("inf")
    for _ in range(args.repeat):
        mon = Monitor(system, gains)
        t0, c0 = time.perf_counter(), time.process_time()
        for j in range(K):
            mon.step(j, u0[j], y0[j])
        best = min(best, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    print(f"Monitor.step (single stream, floats): {K / best:10,.0f} samples/s "
          f"({1e6 * best / K:.1f} us/sample; {K / cpu:,.0f} samples per CPU-second)  "
          f"{_load()}")
    old = float("inf")
    u1, y1 = u0[:, None, :], y0[:, None, :]
    for _ in range(max(1, args.repeat // 2)):
        bm = BatchMonitor(system, gains, 1)
        t0 = time.perf_counter()
        for j in range(K):
            bm.step(j, np.asarray(u1[j]), np.asarray(y1[j]))
        old = min(old, time.perf_counter() - t0)
    print(f"single stream on the batch path (N=1): {K / old:9,.0f} samples/s "
          f"({1e6 * old / K:.1f} us/sample; {old / best:.1f}x slower)  {_load()}")
    for n in sorted({1, 10, 50, args.runs}):
        sub = type(tr)(tr.scenario, tr.seeds[:n], tr.k, tr.t, tr.u[:n], tr.y[:n], tr.x[:n],
                       tr.mode[:n], tr.faults[:n])
        t0 = time.perf_counter()
        run_batch(system, gains, sub)
        dt = time.perf_counter() - t0
        print(f"run_batch, N = {n:4d} runs:          {n * K / dt:12,.0f} samples/s "
              f"({dt:.2f} s)  {_load()}")
    print("\nevery runtime of the registry, single stream (benchmarks/bench_runtimes.py):")
    print_rates()


if __name__ == "__main__":
    main()
