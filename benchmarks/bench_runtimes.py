"""Single-stream rate of every gain file's runtime against two floors, in one run.

Run from the repository root::

    python benchmarks/bench_runtimes.py [--samples 2000] [--repeat 5]

For every file of ``config/gains/`` (the registry of :mod:`fd_monitor.core.runtime`):

* ``step``: ``runtime.step`` once per sample over one stream (validation and plausibility
  included: what a node does per sample), samples per second;
* ``run``: ``runtime.run`` over the same stream (``step`` plus the trace ``analyze`` keeps);
* ``floor py``: the arithmetic every observer-based monitor of the runtime's dimensions does
  per sample, in plain Python floats: for each generator (one for a single observer)
  ``[x^+; r] = Phi [x^; u; y]`` with a constant ``Phi`` ((n + p) x (n + nu + p)), the norm of
  ``r`` and its alarm ``|r| > R``; nothing else (no validation, no scheduling, no
  nonlinear model, no output object). A runtime cannot be cheaper than this in pure Python;
* ``floor np``: the same arithmetic vectorised with numpy (one ``matmul`` over the
  generators, the norms, the alarms).

Timing: one untimed warm-up pass, then the best of ``--repeat`` timed passes (the machine is
shared: the best pass is the one least disturbed), CPU time of this process
(``time.process_time``) -- what the code costs when it has a core -- beside the wall-clock
rate of the same pass. The 1-minute load average is printed before and after.

``thresholds`` and ``qb`` run a simulated scenario of their plant; the others a synthetic
stream (small random measurements around the middle of the plant's range, inputs zero, side
signals mid-range / random modes): their per-sample cost does not depend on the values.
No assertion: figures only (the speed goals are in doc/reference/benchmarks-runtimes.md).
"""

from __future__ import annotations

import argparse
import math
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.core.methods import load_gains, runtime_for
from fd_monitor.core.simulator import simulate
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system

SCENARIOS = {"three_tank": "three_tank_nominal", "pwa_cascade": "pwa_cascade_nominal",
             "three_tank_lpv": "three_tank_lpv_nominal"}


def load() -> str:
    """The 1-minute load average and the core count."""
    return f"load average {os.getloadavg()[0]:.2f} (1 min, {os.cpu_count()} cores)"


def _stream(system: Any, rt: Any, K: int, rng: np.random.Generator
            ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    if system.name in SCENARIOS:
        tr = simulate(load_scenario(SCENARIOS[system.name]), 0, K)
        return tr.u[0], tr.y[0], {}
    side: dict[str, np.ndarray] = {}
    if "rho" in rt.side_inputs:
        m = rt.bank.model
        side["rho"] = np.tile(0.5 * (m.rho_min + m.rho_max), (K, 1))
    if "mode" in rt.side_inputs:
        side["mode"] = rng.integers(0, len(system.modes), K)
    lo, hi = system.output_limits[:, 0], system.output_limits[:, 1]
    mid = np.where(np.isfinite(lo + hi), 0.5 * (lo + hi), 0.0)
    return (np.zeros((K, system.nu)), mid + 1e-3 * rng.standard_normal((K, system.ny)), side)


def dimensions(system: Any, rt: Any) -> tuple[int, int, int, int]:
    """(generators, n, nu, p) of the floor: a bank's generators, else one observer."""
    bank = getattr(rt, "bank", None)
    if bank is not None:
        return len(bank.generators), bank.model.n, system.nu, system.ny
    return 1, system.n, system.nu, system.ny


def floor_python(G: int, n: int, nu: int, p: int, K: int) -> Callable[[], None]:
    """K samples of the floor arithmetic in plain Python floats (loops over lists)."""
    rng = np.random.default_rng(1)
    r = n + nu + p
    phis = [(0.1 * rng.standard_normal((n + p, r))).tolist() for _ in range(G)]
    zs = [[0.0] * r for _ in range(G)]
    thr = [1.0] * p
    us = rng.standard_normal((K, nu)).tolist()
    ys = rng.standard_normal((K, p)).tolist()

    def run() -> None:
        for k in range(K):
            uy = us[k] + ys[k]
            for g in range(G):
                z = zs[g]
                z[n:] = uy
                out = [sum([a * b for a, b in zip(row, z)]) for row in phis[g]]
                z[:n] = out[:n]
                res = out[n:]
                _ = math.sqrt(sum([v * v for v in res]))
                _ = [abs(v) > t for v, t in zip(res, thr)]
    return run


def floor_numpy(G: int, n: int, nu: int, p: int, K: int) -> Callable[[], None]:
    """K samples of the floor arithmetic with numpy (one matmul over the generators)."""
    rng = np.random.default_rng(1)
    r = n + nu + p
    phi = 0.1 * rng.standard_normal((G, n + p, r))
    Z = np.zeros((G, r))
    thr = np.ones(p)
    uys = np.hstack([rng.standard_normal((K, nu)), rng.standard_normal((K, p))])

    def run() -> None:
        for k in range(K):
            Z[:, n:] = uys[k]
            out = np.matmul(phi, Z[:, :, None])[:, :, 0]
            Z[:, :n] = out[:, :n]
            res = out[:, n:]
            _ = np.sqrt((res * res).sum(axis=1))
            _ = np.abs(res) > thr
    return run


def best_of(fn: Callable[[], Any], repeat: int, reset: Callable[[], Any] | None = None
            ) -> tuple[float, float]:
    """(best CPU s, best wall s) of ``repeat`` timed calls after one untimed warm-up."""
    if reset:
        reset()
    fn()
    cpu = wall = float("inf")
    for _ in range(repeat):
        if reset:
            reset()
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        cpu = min(cpu, time.process_time() - c0)
        wall = min(wall, time.perf_counter() - t0)
    return cpu, wall


def measure(path: Path, samples: int, repeat: int, rng: np.random.Generator) -> dict[str, Any]:
    """The rates of one gain file's runtime and of its floors (samples per CPU second)."""
    raw = load_gains(path, verify=False)
    system = load_system(raw.system_name)
    gf = load_gains(path, system)
    rt = runtime_for(system, gf)
    u, y, side = _stream(system, rt, samples, rng)
    K = len(y)
    k = np.arange(K)
    sides = [{n: v[j] for n, v in side.items()} or None for j in range(K)]

    def steps() -> None:
        for j in range(K):
            rt.step(j, u[j], y[j], sides[j])

    cpu_step, wall_step = best_of(steps, repeat, rt.reset)
    cpu_run, _ = best_of(lambda: rt.run(k, u, y, side or None), repeat, rt.reset)
    G, n, nu, p = dimensions(system, rt)
    cpu_py, _ = best_of(floor_python(G, n, nu, p, K), repeat)
    cpu_np, _ = best_of(floor_numpy(G, n, nu, p, K), repeat)
    return {"file": path.stem, "method": gf.method, "dims": f"{G}x(n{n},u{nu},y{p})",
            "step": K / cpu_step, "step_wall": K / wall_step, "run": K / cpu_run,
            "floor_py": K / cpu_py, "floor_np": K / cpu_np}


def print_rates(samples: int = 2000, repeat: int = 5) -> list[dict[str, Any]]:
    """Print every shipped gain file's single-stream rates beside the floors."""
    rng = np.random.default_rng(0)
    root = Path(__file__).resolve().parents[1] / "config" / "gains"
    print(f"before: {load()}; best of {repeat} passes of {samples} samples after a warm-up, "
          f"samples per CPU second (wall clock of the best step pass in brackets)")
    print(f"{'gain file':32s} {'method':16s} {'floor dims':16s} {'step':>9s} {'(wall)':>9s} "
          f"{'run':>9s} {'floor py':>9s} {'floor np':>9s} {'step/py':>7s}")
    rows = []
    for path in sorted(root.glob("*.yaml")):
        r = measure(path, samples, repeat, rng)
        rows.append(r)
        print(f"{r['file']:32s} {r['method']:16s} {r['dims']:16s} {r['step']:9,.0f} "
              f"{r['step_wall']:9,.0f} {r['run']:9,.0f} {r['floor_py']:9,.0f} "
              f"{r['floor_np']:9,.0f} {r['step'] / r['floor_py']:7.2f}", flush=True)
    print(f"after: {load()}")
    return rows


def main() -> None:
    """Measure and print."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=5, help="timed passes (best kept)")
    args = ap.parse_args()
    print_rates(args.samples, args.repeat)


if __name__ == "__main__":
    main()
