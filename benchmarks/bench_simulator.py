"""Simulator throughput: samples per second for both shipped plants.

Run: .venv/bin/python benchmarks/bench_simulator.py [--repeat 3]

Prints, per plant, the median over repeats of (a) one run stepped sample by sample (what the
plant_sim node does) and (b) a batch of 100 runs in lock step (what Monte Carlo campaigns
do), as samples per second (batch: run-samples per second).
"""

from __future__ import annotations

import argparse
import statistics
import time

from fd_monitor.core.simulator import simulate, simulate_batch
from fd_monitor.model.scenario import load_scenario

CASES = [("three_tank", "three_tank_bias_h1", 4000),
         ("pwa_cascade", "pwa_cascade_b1_step", 10000)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--batch", type=int, default=100)
    args = ap.parse_args()
    batch_head = f"batch of {args.batch} [run-samples/s]"
    print(f"{'plant':<12} {'single run [samples/s]':>24} {batch_head:>30}")
    for plant, scenario, K in CASES:
        sc = load_scenario(scenario)
        single, batch = [], []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            simulate(sc, n_samples=K)
            single.append(K / (time.perf_counter() - t0))
            kb = K // 4
            t0 = time.perf_counter()
            simulate_batch(sc, list(range(args.batch)), n_samples=kb)
            batch.append(args.batch * kb / (time.perf_counter() - t0))
        print(f"{plant:<12} {statistics.median(single):>24,.0f} {statistics.median(batch):>30,.0f}")


if __name__ == "__main__":
    main()
