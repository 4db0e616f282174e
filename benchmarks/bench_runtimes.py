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
  generators, the norms, the alarms);
* ``floor C``: the same arithmetic compiled: a C kernel (:data:`C_KERNEL`) compiled with
  ``gcc -O2`` when the benchmark starts and called through ``ctypes`` once per pass (the
  loop over the samples in C), so no Python per sample. Benchmark only: the package's
  runtime path is pure Python/numpy and does not need a compiler; without ``gcc`` the column
  prints ``-`` and says why.

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
import atexit
import ctypes
import math
import os
import shutil
import subprocess
import tempfile
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


#: The compiled floor: K samples of G generators, ``out = Phi_g [x_g; u_k; y_k]``,
#: ``x_g = out[:n]``, ``r = out[n:]``, its 2-norm and its alarms ``|r_i| > R_i``.
C_KERNEL = r"""
#include <math.h>
double floor_run(int K, int G, int n, int nu, int p, const double *phi, double *x,
                 const double *u, const double *y, const double *thr, unsigned char *alarm)
{
    int r = n + nu + p, m = n + p;
    double z[256], out[256], acc = 0.0;
    for (int k = 0; k < K; k++) {
        for (int g = 0; g < G; g++) {
            const double *P = phi + (long)g * m * r;
            double *xg = x + (long)g * n;
            for (int i = 0; i < n; i++) z[i] = xg[i];
            for (int i = 0; i < nu; i++) z[n + i] = u[(long)k * nu + i];
            for (int i = 0; i < p; i++) z[n + nu + i] = y[(long)k * p + i];
            for (int i = 0; i < m; i++) {
                double s = 0.0;
                for (int j = 0; j < r; j++) s += P[i * r + j] * z[j];
                out[i] = s;
            }
            double ss = 0.0;
            for (int i = 0; i < n; i++) xg[i] = out[i];
            for (int i = 0; i < p; i++) {
                double v = out[n + i];
                ss += v * v;
                alarm[i] = fabs(v) > thr[i];
            }
            acc += sqrt(ss);
        }
    }
    return acc;
}
"""

_C_LIB: Any = None
_C_WHY = ""


def c_library() -> Any:
    """The compiled :data:`C_KERNEL` (ctypes), or None with the reason in ``_C_WHY``."""
    global _C_LIB, _C_WHY
    if _C_LIB is not None or _C_WHY:
        return _C_LIB
    gcc = shutil.which("gcc") or shutil.which("cc")
    if gcc is None:
        _C_WHY = "no gcc/cc on PATH"
        return None
    tmp = Path(tempfile.mkdtemp(prefix="fd_bench_c_"))
    atexit.register(shutil.rmtree, tmp, True)
    src, lib = tmp / "floor.c", tmp / "floor.so"
    src.write_text(C_KERNEL)
    try:
        subprocess.run([gcc, "-O2", "-shared", "-fPIC", "-o", str(lib), str(src), "-lm"],
                       check=True, capture_output=True, text=True)
        dll = ctypes.CDLL(str(lib))
    except (OSError, subprocess.CalledProcessError) as exc:
        _C_WHY = f"compiling the C floor failed: {exc}"
        return None
    dll.floor_run.restype = ctypes.c_double
    _C_LIB = dll
    return dll


def floor_c(G: int, n: int, nu: int, p: int, K: int) -> Callable[[], None] | None:
    """K samples of the floor arithmetic in the compiled kernel (one ctypes call)."""
    dll = c_library()
    if dll is None or n + nu + p > 256:
        return None
    rng = np.random.default_rng(1)
    r = n + nu + p
    phi = np.ascontiguousarray(0.1 * rng.standard_normal((G, n + p, r)))
    x = np.zeros((G, max(n, 1)))
    us = np.ascontiguousarray(rng.standard_normal((K, max(nu, 1))))
    ys = np.ascontiguousarray(rng.standard_normal((K, p)))
    thr = np.ones(p)
    alarm = np.zeros(p, dtype=np.uint8)
    dp = ctypes.POINTER(ctypes.c_double)
    args = (ctypes.c_int(K), ctypes.c_int(G), ctypes.c_int(n), ctypes.c_int(nu),
            ctypes.c_int(p), phi.ctypes.data_as(dp), x.ctypes.data_as(dp),
            us.ctypes.data_as(dp), ys.ctypes.data_as(dp), thr.ctypes.data_as(dp),
            alarm.ctypes.data_as(ctypes.POINTER(ctypes.c_ubyte)))

    def run() -> None:
        dll.floor_run(*args)
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
    fc = floor_c(G, n, nu, p, K)
    # the C pass is short: many samples per timed call so the clock resolves it
    cpu_c = best_of(lambda: [fc() for _ in range(50)], repeat)[0] / 50 if fc else None
    return {"file": path.stem, "method": gf.method, "dims": f"{G}x(n{n},u{nu},y{p})",
            "step": K / cpu_step, "step_wall": K / wall_step, "run": K / cpu_run,
            "floor_py": K / cpu_py, "floor_np": K / cpu_np,
            "floor_c": None if cpu_c is None else K / max(cpu_c, 1e-9)}


def print_rates(samples: int = 2000, repeat: int = 5) -> list[dict[str, Any]]:
    """Print every shipped gain file's single-stream rates beside the floors."""
    rng = np.random.default_rng(0)
    root = Path(__file__).resolve().parents[1] / "config" / "gains"
    print(f"before: {load()}; best of {repeat} passes of {samples} samples after a warm-up, "
          f"samples per CPU second (wall clock of the best step pass in brackets)")
    c_lib = c_library()
    print("floor C: " + ("C kernel compiled with gcc -O2, called once per pass via ctypes"
                         if c_lib is not None else f"not measured ({_C_WHY})"))
    print(f"{'gain file':32s} {'method':16s} {'floor dims':16s} {'step':>9s} {'(wall)':>9s} "
          f"{'run':>9s} {'floor py':>9s} {'floor np':>9s} {'floor C':>11s} {'step/py':>7s}")
    rows = []
    for path in sorted(root.glob("*.yaml")):
        r = measure(path, samples, repeat, rng)
        rows.append(r)
        print(f"{r['file']:32s} {r['method']:16s} {r['dims']:16s} {r['step']:9,.0f} "
              f"{r['step_wall']:9,.0f} {r['run']:9,.0f} {r['floor_py']:9,.0f} "
              f"{r['floor_np']:9,.0f} "
              f"{'-' if r['floor_c'] is None else format(r['floor_c'], ',.0f'):>11s} "
              f"{r['step'] / r['floor_py']:7.2f}", flush=True)
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
