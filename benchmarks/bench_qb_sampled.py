"""Monte Carlo of the QB guarantee at the samples: continuous (paper) vs sampled design.

Run from the repository root::

    python benchmarks/bench_qb_sampled.py [--runs 250] [--seconds 100]

For each shipped pwa_cascade QB gain file (``pwa_cascade_qb``: continuous-time design of the
paper, run by its ZOH discretisation; ``pwa_cascade_qb_sampled``: the discrete-time design of
the exact sampled plant) and each disturbance policy of
:func:`fd_monitor.core.qb.stress_runs` (uniform, extreme, held vertex, greedy adversarial),
fault-free runs go through the runtime (``run_batch``) and the table prints:

* ``max V/bound``: the largest ``V(e_k) / (1 + (1-beta)^k (V_0 - 1)+)`` (continuous design:
  ``1 + e^{-beta t}(V_0 - 1)+``), over all samples; <= 1 is the guarantee;
* ``max V 20s+``: the largest ``e'Pe`` after the 20 s transient (eq. 6: <= 1);
* ``step viol.``: samples where the estimated mode is the plant's and the one-step bound
  ``V_{k+1} <= 1 + (1-beta)(V_k - 1)+`` (continuous: ``1 + e^{-beta Ts}(V_k - 1)+``) fails
  (the sampled design's theorem; for the continuous design, what its guarantee would imply
  at the samples);
* ``mismatch runs``: runs whose estimated mode differs from the plant's after 20 s;
* ``alarm runs``: runs with a detector alarm (rho = 1, every channel) after 20 s.

No assertion (the test ``test/test_qb_sampled.py`` asserts the guarantee on 200 runs).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from fd_monitor.core.methods import load_gains
from fd_monitor.core.qb import STRESS_POLICIES, run_batch, stress_runs
from fd_monitor.core.qb_certificate import ellipsoid_bound, gains_matrices
from fd_monitor.core.simulator import Trajectory
from fd_monitor.model.system import load_system


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=250, help="runs per policy and design (250)")
    ap.add_argument("--seconds", type=float, default=100.0, help="length of a run, s (100)")
    ap.add_argument("--transient", type=float, default=20.0, help="transient, s (20)")
    args = ap.parse_args()
    pwa = load_system("pwa_cascade")
    K = round(args.seconds / pwa.sample_time)
    k0 = round(args.transient / pwa.sample_time)
    print(f"pwa_cascade, {args.runs} fault-free runs x {args.seconds:g} s per policy, "
          f"transient {args.transient:g} s")
    print(f"{'gain file':24s} {'time':10s} {'policy':12s} {'max V/bound':>11s} "
          f"{'max V 20s+':>10s} {'step viol.':>10s} {'mismatch runs':>13s} {'alarm runs':>10s}"
          f" {'s':>5s}")
    for name in ("pwa_cascade_qb", "pwa_cascade_qb_sampled"):
        g = load_gains(name, pwa)
        P, _, _, beta = gains_matrices(pwa, g.results)
        tm = g.results.get("time", "continuous")
        for policy in STRESS_POLICIES:
            t0 = time.perf_counter()
            runs = stress_runs(pwa, g, policy, args.runs, K, seed=2024)
            ks = np.arange(K)
            traj = Trajectory(None, (), ks, ks * pwa.sample_time, runs["u"], runs["y"],
                              runs["x"], runs["mode"], np.zeros((args.runs, K, 0)))
            res = run_batch(pwa, g, traj)
            e = runs["x"] - res.x_hat
            V = np.einsum("nki,ij,nkj->nk", e, P, e)
            bound = ellipsoid_bound(V[:, :1], beta, ks[None], tm, pwa.sample_time)
            matched = res.mode_hat == runs["mode"]
            step = V[:, 1:] - ellipsoid_bound(V[:, :-1], beta, 1, tm, pwa.sample_time)
            viol = int((step[matched[:, :-1]] > 1e-9).sum())
            mism = int((~matched[:, k0:]).any(axis=1).sum())
            alarms = int(res.alarm[:, k0:].any(axis=(1, 2)).sum())
            print(f"{name:24s} {tm:10s} {policy:12s} {float((V / bound).max()):11.4f} "
                  f"{float(V[:, k0:].max()):10.4f} {viol:10d} {mism:13d} {alarms:10d} "
                  f"{time.perf_counter() - t0:5.1f}")


if __name__ == "__main__":
    main()
