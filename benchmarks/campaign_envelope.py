"""Monte Carlo over the declared operating envelope of three_tank (issue 13).

Run from the repository root::

    python benchmarks/campaign_envelope.py [--setpoints 60] [--seeds 5] [--fault-runs 20]
                                           [--fault-free-only] [--gains GAINS ...]

Fault-free runs at set points spread over the whole declared envelope (not the design
scenarios): h1 and h2 references drawn uniformly in [0.05, 0.65] m, changed twice per run, the
bypass valve toggled at random times; measurement noise and modelling uncertainty at their
bounds (``distribution: extreme``, every sample at a vertex of the noise box). Prints

1. fault-free: runs with a false alarm, alarm samples, samples outside the certified region,
   and the alarm episodes inside the region and marked ``outside_certified_region`` (the
   marking of ``analyze``: :func:`fd_monitor.analysis.summary.region_mark`), for the envelope
   design (``three_tank_envelope``) and the scenario design (``three_tank_thresholds``, the
   default gain file of the nodes and the demo); ``--fault-free-only`` stops here;
2. detection: abrupt bias on each sensor at t = 200 s, per magnitude, the fraction of runs
   with an alarm after the fault (and false alarms before it), and the smallest magnitude
   detected in every run, per sensor and design.

Set point i uses seed ``seed0 + i`` for its references, noise seeds ``seed0 + 1000 i + j``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from typing import Any

import numpy as np

from fd_monitor.analysis.summary import episodes, region_mark
from fd_monitor.core.envelope import CertifiedRegion
from fd_monitor.core.methods import load_gains
from fd_monitor.core.monitor import run_batch
from fd_monitor.core.simulator import simulate_batch
from fd_monitor.model.scenario import FaultEvent, Scenario, parse_scenario
from fd_monitor.model.system import System, load_system

DURATION = 300.0
FAULT_TIME = 200.0
MAGNITUDES = (0.001, 0.002, 0.003, 0.004, 0.006, 0.008)   # m


def envelope_scenario(system: System, seed: int, duration: float = DURATION,
                      lo: float = 0.05, hi: float = 0.65) -> Scenario:
    """A fault-free three_tank run with random set points in [lo, hi] m and valve toggles,
    noise and uncertainty at their bounds (``extreme``)."""
    rng = np.random.default_rng(seed)
    t = [0.0, *sorted(rng.uniform(0.2, 0.7, 2) * duration)]

    def pi(out: str) -> dict[str, Any]:
        steps = [[float(ti), float(rng.uniform(lo, hi))] for ti in t]
        return {"pi": {"output": out, "reference": {"steps": steps}, "kp": 2.0e-3,
                       "ki": 2.0e-5, "min": 0.0, "max": 1.5e-4}}

    valve = [[0.0, float(rng.integers(0, 2))]]
    for tv in sorted(rng.uniform(0.1, 0.9, 2) * duration):
        valve.append([float(tv), 1.0 - valve[-1][1]])
    return parse_scenario({
        "name": f"envelope_{seed}", "system": system.name, "duration": duration,
        "seed": seed, "inputs": {"q1": pi("h1"), "q2": pi("h2"), "v13": {"steps": valve}},
        "noise": {"scale": 1.0, "distribution": "extreme"},
        "uncertainty": {"scale": 1.0, "distribution": "extreme"}}, system=system)


def fault_free(system: System, gains: dict[str, Any], setpoints: int, seeds: int,
               seed0: int) -> dict[str, dict[str, int]]:
    """Table 1: per design, runs with a false alarm, alarm samples, samples outside."""
    out = {name: {"runs": 0, "runs_with_alarm": 0, "alarm_samples": 0,
                  "samples_outside": 0, "episodes_inside": 0, "episodes_outside": 0}
           for name in gains}
    for i in range(setpoints):
        sc = envelope_scenario(system, seed0 + i)
        tr = simulate_batch(sc, [seed0 + 1000 * i + j for j in range(seeds)])
        for name, gf in gains.items():
            res = run_batch(system, gf, tr, keep=("x_hat", "mode"))
            a = res.alarm.any(axis=2)
            o = out[name]
            o["runs"] += a.shape[0]
            o["runs_with_alarm"] += int(a.any(axis=1).sum())
            o["alarm_samples"] += int(a.sum())
            region = CertifiedRegion.from_results(system, gf.results)
            if region is None:
                o["episodes_inside"] = -1
                continue
            ex = region.excess(res.mode_hat, res.x_hat, tr.u)
            o["samples_outside"] += int(np.any(ex != 0.0, axis=-1).sum())
            for r in range(a.shape[0]):
                for c in range(res.alarm.shape[2]):
                    for e0, e1 in episodes(res.alarm[r, :, c]):
                        marked = region_mark(ex[r], np.zeros(0, int), e0, e1)[0]
                        o["episodes_outside" if marked else "episodes_inside"] += 1
    return out


def detection(system: System, gains: dict[str, Any], runs: int, seed0: int
              ) -> dict[str, dict[str, dict[float, tuple[float, float]]]]:
    """Table 2: design -> sensor -> magnitude -> (detection rate, false-alarm rate)."""
    setpoints = max(1, runs // 5)
    base = [envelope_scenario(system, seed0 + 500 + i) for i in range(setpoints)]
    k0 = round(FAULT_TIME / system.sample_time)
    out: dict[str, dict[str, dict[float, tuple[float, float]]]] = {
        n: {o: {} for o in system.outputs} for n in gains}
    for sensor in system.outputs:
        ch = [f.name for f in system.faults].index(f"bias_{sensor}")
        for mag in MAGNITUDES:
            det = {n: [] for n in gains}
            fa = {n: [] for n in gains}
            for i, sc in enumerate(base):
                scf = replace(sc, faults=(FaultEvent(ch, "abrupt", FAULT_TIME, mag),))
                tr = simulate_batch(scf, [seed0 + 7000 + 10 * i + j for j in range(5)])
                for n, gf in gains.items():
                    a = run_batch(system, gf, tr, keep=()).alarm.any(axis=2)
                    det[n] += a[:, k0:].any(axis=1).tolist()
                    fa[n] += a[:, :k0].any(axis=1).tolist()
            for n in gains:
                out[n][sensor][mag] = (float(np.mean(det[n])), float(np.mean(fa[n])))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--setpoints", type=int, default=60)
    ap.add_argument("--seeds", type=int, default=5, help="noise seeds per set point")
    ap.add_argument("--fault-runs", type=int, default=20, help="runs per detection cell")
    ap.add_argument("--seed0", type=int, default=2000)
    ap.add_argument("--fault-free-only", action="store_true",
                    help="only the fault-free table (~2 min per gain file)")
    ap.add_argument("--gains", action="append", default=None, metavar="GAINS",
                    help="gain file (repeatable; default three_tank_envelope and "
                         "three_tank_thresholds)")
    args = ap.parse_args()
    system = load_system("three_tank")
    gains = {n: load_gains(n, system) for n in (args.gains or ("three_tank_envelope",
                                                                "three_tank_thresholds"))}
    t0 = time.perf_counter()
    ff = fault_free(system, gains, args.setpoints, args.seeds, args.seed0)
    print(f"fault-free, set points over the envelope, noise at its bounds "
          f"({time.perf_counter() - t0:.0f} s)")
    print(f"{'gain file':24s} {'runs':>5s} {'runs w/ alarm':>13s} {'alarm samples':>13s} "
          f"{'samples outside region':>22s} {'alarm episodes inside':>21s} "
          f"{'marked outside':>14s}")
    for n, o in ff.items():
        inside = "n/a" if o["episodes_inside"] < 0 else str(o["episodes_inside"])
        print(f"{n:24s} {o['runs']:5d} {o['runs_with_alarm']:13d} {o['alarm_samples']:13d} "
              f"{o['samples_outside']:22d} {inside:>21s} {o['episodes_outside']:14d}")
    if args.fault_free_only:
        return
    t0 = time.perf_counter()
    dt = detection(system, gains, args.fault_runs, args.seed0)
    print(f"\nabrupt bias at t = {FAULT_TIME:.0f} s: detection rate (false-alarm rate before "
          f"the fault), {args.fault_runs} runs per cell ({time.perf_counter() - t0:.0f} s)")
    for n, per in dt.items():
        print(f"\n{n}")
        print(f"{'sensor':6s} " + " ".join(f"{1000 * m:>11.0f}mm" for m in MAGNITUDES)
              + "   smallest detected in every run")
        for sensor, cells in per.items():
            full = [m for m in MAGNITUDES if cells[m][0] == 1.0]
            row = " ".join(f"{cells[m][0]:6.2f} ({cells[m][1]:.2f})" for m in MAGNITUDES)
            print(f"{sensor:6s} {row}   {1000 * min(full):.0f} mm" if full else
                  f"{sensor:6s} {row}   > {1000 * MAGNITUDES[-1]:.0f} mm")


if __name__ == "__main__":
    main()
