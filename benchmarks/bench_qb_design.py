"""Benchmark of the QB designer: the Sec. VI example, and growth with the number of states.

Run from the repository root::

    python benchmarks/bench_qb_design.py [--repeat 5] [--sizes 4,8,12,16,20]

Prints, for pwa_cascade, the median wall time of ``design_qb`` with beta searched and with
beta = 0.486 fixed, and one Clarabel re-solve of the search's step-5 problem (reduced LMIs,
DPP parameter update) and of the full step-5 problem; then a table for random 3-mode PWA
plants of n states (n/2 outputs, n disturbances, modes differing by output injection like
Sec. VI): Clarabel solves of the searched design, median wall time with beta searched, median
with beta fixed at the value found, one reduced and one full step-5 re-solve, rho_max and the
tie-break used. Large n use fewer repeats (``--repeat`` // 2, at least 1, for n > 12).
No assertion: figures only.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from fd_monitor.core.qb_model import qb_model
from fd_monitor.design.qb import QBProblem, design_qb
from fd_monitor.model.errors import DesignError
from fd_monitor.model.system import load_system, parse_system


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


def _resolve_times(sys_, beta: float, repeat: int) -> tuple[float, float]:
    """Median time of one re-solve of the reduced (search) and the full step-5 problem."""
    model = qb_model(sys_)
    out = []
    for reduced in (True, False):
        prob = QBProblem(model, reduced=reduced)
        prob.solve(beta)  # first solve compiles the DPP problem
        out.append(_median_time(lambda p=prob: p.solve(beta), repeat))
    return out[0], out[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--sizes", default="4,8,12,16,20")
    args = ap.parse_args()
    t_all = time.perf_counter()
    pwa = load_system("pwa_cascade")
    design_qb(pwa, 0.486)  # warm-up: imports, cvxpy canonicalisation caches
    t_search = _median_time(lambda: design_qb(pwa), args.repeat)
    t_fixed = _median_time(lambda: design_qb(pwa, 0.486), args.repeat)
    t_red, t_full = _resolve_times(pwa, 0.486, max(args.repeat, 20))
    d = design_qb(pwa)
    df = design_qb(pwa, 0.486)
    print("pwa_cascade (n=4, 3 modes, 2 outputs, 4 disturbances)")
    print(f"  design, beta searched : {t_search * 1e3:8.1f} ms median of {args.repeat} "
          f"({d.solver['solves']} solves, rho_max {d.rho_max:.5f}, beta {d.beta:.4f})")
    print(f"  design, beta = 0.486  : {t_fixed * 1e3:8.1f} ms median of {args.repeat} "
          f"({df.solver['solves']} solves, rho_max {df.rho_max:.5f}, "
          f"tie-break {df.solver['tie_break']})")
    print(f"  one step-5 re-solve   : {t_red * 1e3:8.1f} ms reduced (search), "
          f"{t_full * 1e3:.1f} ms full (DPP parameter update + Clarabel)")
    print("\nrandom 3-mode PWA plants, n states, n/2 outputs, n disturbances")
    print(f"  {'n':>3} {'solves':>6} {'searched [s]':>12} {'fixed [s]':>10} "
          f"{'re-solve red./full [s]':>22} {'rho_max':>9}  tie-break")
    for n in (int(s) for s in args.sizes.split(",")):
        sys_ = _pwa(n)
        rep = max(1, args.repeat // 2) if n > 12 else args.repeat
        try:
            dn = design_qb(sys_)
        except DesignError as exc:
            print(f"  {n:>3} design failed: {exc}")
            continue
        ts = _median_time(lambda s=sys_: design_qb(s), rep)
        tf = _median_time(lambda s=sys_, b=dn.beta: design_qb(s, b), rep)
        tr, tfull = _resolve_times(sys_, dn.beta, rep)
        tb = dn.solver["tie_break"].split(" (")[0]
        print(f"  {n:>3} {dn.solver['solves']:>6} {ts:>12.3f} {tf:>10.3f} "
              f"{tr:>10.3f} / {tfull:<9.3f} {dn.rho_max:>9.4f}  {tb}", flush=True)
    print(f"\ntotal benchmark time {time.perf_counter() - t_all:.0f} s")


if __name__ == "__main__":
    main()
