"""The worked example of doc/tutorial/own-robot.md, measured over many runs.

A DC motor with viscous and Coulomb friction (config/systems/dc_motor.yaml, the ground truth)
is recorded as a robot records it (sensor_msgs/JointState on /joint_states, the effort
controller's Float64MultiArray commands: config/adapters/dc_motor.yaml), then:

1. identified from three fault-free bags (two fit, one held out) with ``identify --adapter``;
   the identified friction and inertia are compared with the true ones;
2. designed (``design thresholds --envelope declared``);
3. analysed (``analyze --adapter``) on fault-free runs of other seeds (false alarms) and on
   runs with a velocity-sensor bias or an actuator fault of several sizes at 30 s (detection
   rate and delay).

Usage: ``.venv/bin/python benchmarks/robot_example.py [--seeds 10] [--json]`` (a few minutes).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from fd_monitor.analysis.identify import identify_bags, write_plant
from fd_monitor.commands.analyze import analyze_bag
from fd_monitor.commands.simulate import simulate_to_bag
from fd_monitor.design.thresholds import design_thresholds
from fd_monitor.model.gains import save_gains
from fd_monitor.model.paths import find_config_file
from fd_monitor.model.scenario import ScenarioError
from fd_monitor.model.system import load_system

ADAPTER = "dc_motor"
FAULT_SAMPLE = 3000          # the scenarios' faults are at 30 s, Ts = 0.01 s
BIASES = (0.02, 0.05, 0.1)   # rad/s on the velocity sensor
LOSSES = (0.05, 0.1, 0.2)    # N m of effort lost


def physical(system):
    """(J, b, Fc) of a one-state affine model w+ = a w + beta tau + c, the exact zero-order
    hold of J dw/dt = tau - b w - Fc: a = exp(-b Ts/J), beta = (1 - a)/b, c = -beta Fc."""
    m = system.modes[0]
    a, beta, c = float(m.A[0, 0]), float(m.B[0, 0]), float(np.ravel(m.offset)[0])
    b = (1.0 - a) / beta
    return {"inertia": -b * system.sample_time / math.log(a), "viscous": b,
            "coulomb": -c / beta}


def _scenario(d: Path, base: str, magnitude: float | None) -> str:
    """A copy of a shipped scenario with its fault's magnitude changed."""
    if magnitude is None:
        return base
    src = find_config_file(base, "scenarios", ScenarioError)
    text = src.read_text()
    lines = [ln if "magnitude:" not in ln else
             ln[:ln.index("magnitude:")] + f"magnitude: {magnitude}}}" for ln in text.splitlines()]
    path = d / f"{base}_{magnitude}.yaml"
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10, help="runs per case (default 10)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    t0 = time.perf_counter()
    out: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        bags = []
        for s in (1, 2, 3):
            bags.append(d / f"run{s}")
            simulate_to_bag("dc_motor_nominal", bags[-1], seed=s, adapter=ADAPTER)
        ident = identify_bags(bags[:2], holdout=bags[2:], name="dc_motor_identified",
                              adapter=ADAPTER)
        plant = write_plant(ident, d / "dc_motor_identified.yaml")
        system = load_system(plant)
        truth = load_system("dc_motor")
        true_p = dict(truth.modes[0].params)
        got = physical(system)
        out["parameters"] = {k: {"true": float(true_p[k]), "identified": v,
                                 "error_pct": 100.0 * (v / float(true_p[k]) - 1.0)}
                             for k, v in got.items()}
        out["noise_bound"] = {"true": float(truth.measurement_noise[0]),
                              "identified": float(system.measurement_noise[0])}
        out["uncertainty"] = {"true": float(truth.modes[0].uncertainty[0]),
                              "identified": float(system.modes[0].uncertainty[0])}
        des = design_thresholds(system, envelope="declared")
        gains = d / "gains.yaml"
        save_gains(gains, "thresholds", system, des["parameters"], des["results"],
                   des["certificate"], des["solver"])
        out["design"] = {"filter_length": int(des["parameters"]["length"]),
                         "r_bar": float(np.ravel(des["results"]["r_bar"])[0])}
        cases = [("fault-free", "dc_motor_nominal", None)]
        cases += [(f"bias {b:g} rad/s", "dc_motor_bias_velocity", b) for b in BIASES]
        cases += [(f"effort loss {x:g} N m", "dc_motor_actuator", -x) for x in LOSSES]
        rows = []
        for label, base, mag in cases:
            scen = _scenario(d, base, mag)
            before = detected = 0
            delays = []
            outside = 0
            for i in range(args.seeds):
                bag = d / f"b{len(rows)}_{i}"
                simulate_to_bag(scen, bag, seed=100 + i, adapter=ADAPTER)
                doc = analyze_bag(str(bag), str(gains), str(plant), adapter=ADAPTER)
                firsts = [a["first_sample"] for a in doc["alarms"]]
                limit = FAULT_SAMPLE if mag is not None else 10**9
                if any(k < limit for k in firsts):
                    before += 1
                after = [k for k in firsts if k >= FAULT_SAMPLE]
                if mag is not None and after:
                    detected += 1
                    delays.append(min(after) - FAULT_SAMPLE)
                outside += any(a.get("outside_certified_region") for a in doc["alarms"])
            rows.append({"case": label, "runs": args.seeds,
                         "runs_with_false_alarm": before,
                         "detected": None if mag is None else detected,
                         "delay_samples_mean": float(np.mean(delays)) if delays else None,
                         "delay_samples_max": int(max(delays)) if delays else None,
                         "alarms_outside_region": outside})
        out["cases"] = rows
    out["wall_s"] = time.perf_counter() - t0
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    print("identified vs true (dc_motor_identified from 2 fit + 1 held-out bag):")
    for k, v in out["parameters"].items():
        print(f"  {k:8s} true {v['true']:.5g}  identified {v['identified']:.5g}  "
              f"({v['error_pct']:+.2f} %)")
    print(f"  noise bound true {out['noise_bound']['true']:.4g}  identified "
          f"{out['noise_bound']['identified']:.4g} rad/s;  uncertainty true "
          f"{out['uncertainty']['true']:.3g}  identified {out['uncertainty']['identified']:.3g}")
    print(f"design: moving average L = {out['design']['filter_length']}, "
          f"r_bar = {out['design']['r_bar']:.3g} rad/s")
    print(f"{'case':22s} {'runs':>4s} {'false alarm':>11s} {'detected':>8s} "
          f"{'mean delay':>10s} {'max delay':>9s} {'outside region':>14s}")
    for r in rows:
        det = "-" if r["detected"] is None else str(r["detected"])
        mean = "-" if r["delay_samples_mean"] is None else f"{r['delay_samples_mean']:.1f}"
        mx = "-" if r["delay_samples_max"] is None else str(r["delay_samples_max"])
        print(f"{r['case']:22s} {r['runs']:4d} {r['runs_with_false_alarm']:11d} {det:>8s} "
              f"{mean:>10s} {mx:>9s} {r['alarms_outside_region']:14d}")
    print(f"wall time {out['wall_s']:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
