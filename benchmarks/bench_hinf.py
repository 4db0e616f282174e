"""Timing of the LMI residual-generator designers and runtimes (prints figures, no asserts).

    .venv/bin/python benchmarks/bench_hinf.py
"""

from __future__ import annotations

import time

import numpy as np

from fd_monitor.core.generalized_observer import GeneralizedObserver, simulate_switched
from fd_monitor.core.hinf_model import parse_bank
from fd_monitor.core.residual_bank import ResidualBank
from fd_monitor.core.simulator import simulate
from fd_monitor.design import hinf_sc, hminus_switched
from fd_monitor.design._lmi_common import load_design_section
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system


def main() -> None:
    s = load_system("thesis_4_7")
    sec, origin, sha = load_design_section(s, "hinf_sc")
    sec = dict(sec, compare_pure=False)
    t0 = time.perf_counter()
    out = hinf_sc.design(s, sec, origin, sha)
    dt = time.perf_counter() - t0
    print(f"thesis 4.7 bank, 2 generators x 50-point lambda grid (+ re-solve, verify): "
          f"{dt:.2f} s (target < 5 s)")
    for g in out["results"]["generators"]:
        print(f"  {g['fault']}: lambda* = {g['lambda']:g}, mu = {g['mu']:.4g}")
    sc = load_scenario("thesis_4_7_overlap")
    tr = simulate(sc)
    bank = ResidualBank(s, out["results"])
    t0 = time.perf_counter()
    bank.run(tr.u[0], tr.y[0])
    dt = time.perf_counter() - t0
    K = tr.y.shape[1]
    print(f"thesis 4.7 runtime: {K} samples x 2 generators in {dt:.3f} s "
          f"({1e6 * dt / K:.1f} us/sample)")

    _bench_reproductions()

    fk = load_system("farhat_koenig")
    sec, origin, sha = load_design_section(fk, "hminus_switched")
    t0 = time.perf_counter()
    o = hminus_switched.design(fk, sec, origin, sha)
    print(f"Farhat & Koenig design (LMI 26 + attempted 44): {time.perf_counter() - t0:.2f} s "
          f"(H-minus: {o['summary']['hminus_status'][:40]}...)")
    obs = GeneralizedObserver(fk, o["results"], design="stability")
    modes = np.random.default_rng(0).integers(0, 2, size=10000)
    _x, y = simulate_switched([m.A for m in fk.modes], [m.B for m in fk.modes],
                             [m.C for m in fk.modes], [np.zeros((3, 1))] * 2,
                             [np.zeros((2, 1))] * 2, modes, np.array([1.0, 2.0, 3.0]))
    t0 = time.perf_counter()
    obs.run(np.zeros((10000, 0)), y, modes)
    dt = time.perf_counter() - t0
    print(f"Farhat & Koenig runtime: 10000 samples in {dt:.3f} s ({100 * dt:.1f} us/sample)")


def _bench_reproductions() -> None:
    """Thesis Sec. 5.3, 6.5, 7.1, 7.2: design (no thresholds) and one simulation each."""
    for name in ("thesis_5_3", "thesis_6_5", "f16xl", "three_tank_lpv"):
        s = load_system(name)
        sec, origin, sha = load_design_section(s, "hinf_sc")
        t0 = time.perf_counter()
        out = hinf_sc.design(s, dict(sec, thresholds={"method": "none"}), origin, sha)
        dt = time.perf_counter() - t0
        gens = out["results"]["generators"]
        print(f"{name} ({out['results']['kind']}) bank of {len(gens)}, "
              f"{sum(len(g['mu_grid']['lambda']) for g in gens)} grid solves + {len(gens)} "
              f"re-solves: "
              f"design {dt:.2f} s")
        kind, _model, _g = parse_bank(out["results"])
        bank = ResidualBank(s, out["results"])
        t0 = time.perf_counter()
        sc = load_scenario("three_tank_lpv_incipient" if name == "three_tank_lpv"
                           else f"{name}_overlap")
        tr = simulate(sc)
        y, u = tr.y[0], tr.u[0]
        sim = time.perf_counter() - t0
        t0 = time.perf_counter()
        # an uncertain bank does not measure rho; the LPV thesis bank reads it
        bank.run(u, y, tr.rho[0] if kind == "lpv" and name == "thesis_6_5" else None)
        run = time.perf_counter() - t0
        print(f"  simulation of {y.shape[0]} samples {sim:.2f} s; bank {run:.2f} s "
              f"({1e6 * run / y.shape[0]:.0f} us/sample)")


if __name__ == "__main__":
    main()
