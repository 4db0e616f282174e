"""Benchmark of the QB designer: the Sec. VI example, and growth with the number of states.

Run from the repository root::

    python benchmarks/bench_qb_design.py [--repeat 5] [--sizes 4,8,12,16,20]

Prints, for pwa_cascade, the median wall time of ``design_qb`` with beta searched and with
beta = 0.486 fixed, and one Clarabel solve of step 5 (the DPP problem re-solved at a new beta);
then, for random 3-mode PWA plants of n states (n/2 outputs, n disturbances, modes differing
by output injection like Sec. VI), the design time with the search (one run) and the median
at the beta it found.
No assertion: figures only.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from fd_monitor.core.qb import qb_model
from fd_monitor.design.qb import QBProblem, design_qb
from fd_monitor.errors import DesignError
from fd_monitor.system import load_system, parse_system


def _median_time(fn, repeat: int) -> float:
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def _pwa(n: int, seed: int = 0):
    """3 modes sharing C, D, E; A_2, A_3 differ from A_1 on measured states only."""
    rng = np.random.default_rng(seed)
    ny = max(1, n // 2)
    A = rng.normal(scale=0.5, size=(n, n)) - np.eye(n)
    C = np.hstack([np.eye(ny), np.zeros((ny, n - ny))])
    D = 0.1 * rng.normal(size=(n, n))
    E = 0.01 * rng.normal(size=(ny, n))
    modes = {}
    for i in range(3):
        Ai = A.copy()
        Ai[: ny, : ny] -= 0.5 * i * np.eye(ny)
        modes[f"m{i}"] = {"A": Ai.tolist()}
    data = {"format_version": 1, "name": f"bench{n}", "time": "continuous",
            "sample_time": 0.01, "states": [f"x{i}" for i in range(n)],
            "outputs": [f"y{i}" for i in range(ny)], "disturbances": [f"w{i}" for i in range(n)],
            "bounds": {"disturbance": [1.0] * n},
            "shared": {"C": C.tolist(), "D": D.tolist(), "E": E.tolist()}, "modes": modes,
            "initial": {"mode": "m0", "state": [0.0] * n}}
    return parse_system(data, "<bench>")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--sizes", default="4,8,12,16,20")
    args = ap.parse_args()
    pwa = load_system("pwa_cascade")
    design_qb(pwa, 0.486)  # warm-up: imports, cvxpy canonicalisation caches
    t_search = _median_time(lambda: design_qb(pwa), args.repeat)
    t_fixed = _median_time(lambda: design_qb(pwa, 0.486), args.repeat)
    prob = QBProblem(qb_model(pwa))
    prob.solve(0.486)
    t_solve = _median_time(lambda: prob.solve(0.486), max(args.repeat, 20))
    d = design_qb(pwa)
    print("pwa_cascade (n=4, 3 modes, 2 outputs, 4 disturbances)")
    print(f"  design, beta searched : {t_search * 1e3:8.1f} ms median of {args.repeat} "
          f"({d.solver['solves']} solves, rho_max {d.rho_max:.5f}, beta {d.beta:.4f})")
    print(f"  design, beta = 0.486  : {t_fixed * 1e3:8.1f} ms median of {args.repeat}")
    print(f"  one step-5 re-solve   : {t_solve * 1e3:8.1f} ms (DPP parameter update + Clarabel)")
    print("\nrandom 3-mode PWA plants, n states, n/2 outputs, n disturbances")
    print(f"  {'n':>3} {'beta fixed [s]':>15} {'beta searched [s]':>18} {'solves':>7} "
          f"{'rho_max':>9}")
    for n in (int(s) for s in args.sizes.split(",")):
        sys_ = _pwa(n)
        rep = max(1, args.repeat // 2) if n > 12 else args.repeat
        t0 = time.perf_counter()
        try:
            dn = design_qb(sys_)
        except DesignError as exc:
            print(f"  {n:>3} design failed: {exc}")
            continue
        ts = time.perf_counter() - t0
        tf = _median_time(lambda s=sys_, b=dn.beta: design_qb(s, b), rep)
        print(f"  {n:>3} {tf:>15.3f} {ts:>18.3f} {dn.solver['solves']:>7} {dn.rho_max:>9.4f}")

if __name__ == "__main__":
    main()
