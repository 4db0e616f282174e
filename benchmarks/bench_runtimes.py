"""Single-stream rate of every gain file's runtime (the registry of fd_monitor.core.runtime).

Run from the repository root::

    python benchmarks/bench_runtimes.py [--samples 2000]

For every file of ``config/gains/``: ``runtime.run`` over one stream (``step`` per sample,
validation and plausibility included: what ``analyze`` and a node do per sample), samples per
second. ``thresholds`` and ``qb`` run a simulated scenario of their plant; the others a
synthetic stream (small random measurements, inputs zero, side signals mid-range / random
modes): their per-sample cost does not depend on the values. No assertion: figures only.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from fd_monitor.core.methods import load_gains, runtime_for
from fd_monitor.core.simulator import simulate
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system

SCENARIOS = {"three_tank": "three_tank_nominal", "pwa_cascade": "pwa_cascade_nominal",
             "three_tank_lpv": "three_tank_lpv_nominal"}


def _stream(system, rt, K: int, rng: np.random.Generator):
    if system.name in SCENARIOS:
        tr = simulate(load_scenario(SCENARIOS[system.name]), 0, K)
        return tr.u[0], tr.y[0], {}
    side = {}
    if "rho" in rt.side_inputs:
        m = rt.bank.model
        side["rho"] = np.tile(0.5 * (m.rho_min + m.rho_max), (K, 1))
    if "mode" in rt.side_inputs:
        side["mode"] = rng.integers(0, len(system.modes), K)
    return np.zeros((K, system.nu)), 1e-3 * rng.standard_normal((K, system.ny)), side


def print_rates(samples: int = 2000) -> None:
    """Print every shipped gain file's single-stream rate (samples per second)."""
    rng = np.random.default_rng(0)
    root = Path(__file__).resolve().parents[1] / "config" / "gains"
    print(f"load average {os.getloadavg()[0]:.2f}")
    print(f"{'gain file':34s} {'method':16s} {'samples/s':>10s}")
    for path in sorted(root.glob("*.yaml")):
        raw = load_gains(path, verify=False)
        system = load_system(raw.system_name)
        gf = load_gains(path, system)
        rt = runtime_for(system, gf)
        u, y, side = _stream(system, rt, samples, rng)
        k = np.arange(samples)
        t = time.perf_counter()
        rt.run(k, u, y, side or None)
        dt = time.perf_counter() - t
        print(f"{path.stem:34s} {gf.method:16s} {samples / dt:10,.0f}")


def main() -> None:
    """Measure and print."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=2000)
    print_rates(ap.parse_args().samples)


if __name__ == "__main__":
    main()
