"""Monte Carlo evidence for the sensor-bias diagnosis chain on three_tank (Heracleous et al.).

Run from the repository root::

    python benchmarks/campaign_three_tank.py [--gains three_tank_thresholds] [--runs 200]
                                             [--fault-runs 50] [--json out.json]

Prints three tables (no assertion: figures only):

1. fault-free runs (scenarios ``three_tank_nominal`` and ``three_tank_guard_high``, both
   crossing the autonomous guard h3 = 0.35 m both ways), with AGEI and without (the ablation in
   which the observer never executes autonomous transitions): runs with a false alarm, alarm
   samples, mode agreement with the truth;
2. bias faults (abrupt, eq. 4) on each sensor at several magnitudes, injected at t = 200 s into
   ``three_tank_nominal`` (``--fault-time``): detection rate, delay (samples), false alarms
   before the fault, isolation rate (the isolated set equals {faulty sensor} at the end of the
   run), |sigma^ - sigma| of the faulty sensor and max |sigma^| of healthy ones at the end
   (200 s after the fault);
3. the smallest magnitude detected in every run, per sensor.

Seeds: run i uses seed ``seed0 + i`` (``--seed0``, default 1000), the same for every cell.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from typing import Any

import numpy as np

from fd_monitor.core.methods import load_gains
from fd_monitor.core.monitor import run_batch
from fd_monitor.core.simulator import simulate_batch
from fd_monitor.model.scenario import FaultEvent, load_scenario
from fd_monitor.model.system import load_system


def _table(rows: list[list[Any]], header: list[str]) -> None:
    cells = [header] + [[f"{c:.4g}" if isinstance(c, float) else str(c) for c in r]
                        for r in rows]
    w = [max(len(r[i]) for r in cells) for i in range(len(header))]
    for j, r in enumerate(cells):
        print("  ".join(c.rjust(w[i]) for i, c in enumerate(r)))
        if j == 0:
            print("  ".join("-" * x for x in w))


def fault_free(system: Any, gains: Any, runs: int, seed0: int) -> list[dict[str, Any]]:
    """Table 1."""
    out = []
    for name in ("three_tank_nominal", "three_tank_guard_high"):
        sc = load_scenario(name)
        tr = simulate_batch(sc, [seed0 + i for i in range(runs)])
        for agei in (True, False):
            t0 = time.perf_counter()
            res = run_batch(system, gains, tr, agei=agei, keep=("mode",))
            dt = time.perf_counter() - t0
            anyal = res.alarm.any(axis=2)
            first = [int(np.argmax(a)) for a in anyal if a.any()]
            assert res.mode_hat is not None
            out.append({
                "scenario": name, "agei": agei, "runs": runs,
                "runs_with_false_alarm": int(anyal.any(axis=1).sum()),
                "false_alarm_samples": int(anyal.sum()),
                "first_alarm_time_s_median": (float(np.median(first)) * system.sample_time
                                              if first else None),
                "mode_agreement": float(np.mean(res.mode_hat == tr.mode)),
                "guard_crossings_per_run": float(np.mean(np.sum(
                    np.diff(tr.mode, axis=1) != 0, axis=1))),
                "monitor_time_s": dt,
                "samples_per_s": runs * tr.y.shape[1] / dt,
            })
    return out


def bias_faults(system: Any, gains: Any, runs: int, seed0: int, mags: list[float],
                t_fault: float) -> list[dict[str, Any]]:
    """Table 2."""
    base = load_scenario("three_tank_nominal")
    dt = system.sample_time
    K0 = round(t_fault / dt)
    seeds = [seed0 + i for i in range(runs)]
    out = []
    for i, out_name in enumerate(system.outputs):
        ch = [f.name for f in system.faults].index(f"bias_{out_name}")
        for mag in mags:
            sc = replace(base, name=f"bias_{out_name}_{mag:g}",
                         faults=(FaultEvent(ch, "abrupt", t_fault, mag),))
            tr = simulate_batch(sc, seeds)
            res = run_batch(system, gains, tr, keep=("sigma_hat", "isolated"))
            anyal = res.alarm.any(axis=2)
            before = anyal[:, :K0].any(axis=1)
            after = anyal[:, K0:]
            det = after.any(axis=1)
            delay = np.array([int(np.argmax(a)) for a in after])[det]
            sig = res.extra["sigma_hat"][:, -1]
            iso = res.extra["isolated"][:, -1]
            want = np.zeros(system.ny, dtype=bool)
            want[i] = True
            iso_ok = np.all(iso == want, axis=1)
            err = np.abs(sig[:, i] - mag)
            healthy = np.abs(np.delete(sig, i, axis=1)).max(axis=1)
            out.append({
                "sensor": out_name, "magnitude": mag, "runs": runs,
                "false_alarm_before_fault": int(before.sum()),
                "detected": int(det.sum()), "detection_rate": float(det.mean()),
                "delay_mean": float(delay.mean()) if delay.size else None,
                "delay_max": int(delay.max()) if delay.size else None,
                "isolated_correctly": int(iso_ok[det].sum()),
                "isolation_rate": float(iso_ok[det].mean()) if det.any() else 0.0,
                "abs_err_max": float(err[det].max()) if det.any() else None,
                "abs_err_median": float(np.median(err[det])) if det.any() else None,
                "healthy_max": float(healthy[det].max()) if det.any() else None,
            })
    return out


def main() -> None:
    """Run the campaigns and print the tables."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gains", default="three_tank_thresholds")
    ap.add_argument("--runs", type=int, default=200, help="fault-free runs per scenario")
    ap.add_argument("--fault-runs", type=int, default=50, help="runs per fault cell")
    ap.add_argument("--magnitudes", default="0.0005,0.001,0.0015,0.002,0.003,0.005,0.01",
                    help="bias magnitudes, m")
    ap.add_argument("--fault-time", type=float, default=200.0)
    ap.add_argument("--seed0", type=int, default=1000)
    ap.add_argument("--json", default=None, help="also write the results to this file")
    args = ap.parse_args()
    system = load_system("three_tank")
    gains = load_gains(args.gains, system)
    t0 = time.perf_counter()
    ff = fault_free(system, gains, args.runs, args.seed0)
    print(f"1. fault-free runs, gains {gains.path}")
    _table([[r["scenario"], "on" if r["agei"] else "off", r["runs"],
             r["runs_with_false_alarm"], r["false_alarm_samples"],
             r["first_alarm_time_s_median"] if r["first_alarm_time_s_median"] is not None
             else "-", 100 * r["mode_agreement"], r["guard_crossings_per_run"],
             r["samples_per_s"]] for r in ff],
           ["scenario", "AGEI", "runs", "runs w/ FA", "FA samples", "median 1st FA s",
            "mode agree %", "transitions/run", "samples/s"])
    mags = [float(m) for m in args.magnitudes.split(",")]
    bf = bias_faults(system, gains, args.fault_runs, args.seed0, mags, args.fault_time)
    print()
    print(f"2. bias faults at t = {args.fault_time:g} s, {args.fault_runs} runs per cell; "
          f"estimate errors at the end of the run")
    _table([[r["sensor"], r["magnitude"] * 1e3, r["false_alarm_before_fault"],
             100 * r["detection_rate"],
             "-" if r["delay_mean"] is None else r["delay_mean"],
             "-" if r["delay_max"] is None else r["delay_max"],
             100 * r["isolation_rate"],
             "-" if r["abs_err_max"] is None else r["abs_err_median"] * 1e3,
             "-" if r["abs_err_max"] is None else r["abs_err_max"] * 1e3,
             "-" if r["healthy_max"] is None else r["healthy_max"] * 1e3] for r in bf],
           ["sensor", "bias mm", "FA before", "detected %", "delay mean", "delay max",
            "isolated %", "|err| med mm", "|err| max mm", "healthy max mm"])
    print()
    print("3. smallest bias detected in every run")
    smallest = {}
    for s in system.outputs:
        ok = [r["magnitude"] for r in bf if r["sensor"] == s and r["detection_rate"] == 1.0]
        smallest[s] = min(ok) if ok else None
        print(f"  {s}: {'none' if not ok else f'{min(ok) * 1e3:g} mm'}")
    print(f"\ntotal time {time.perf_counter() - t0:.1f} s")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"fault_free": ff, "bias": bf, "smallest_detected_all_runs": smallest},
                      fh, indent=2)


if __name__ == "__main__":
    main()
