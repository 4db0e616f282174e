"""An ``agei`` outage around every mode switch: false alarms with and without the nodes' own
AGEI (issue 26 item 0; doc/howto/overload-and-recovery.md).

Run from the repository root::

    python benchmarks/agei_outage_sweep.py [--seeds 6] [--samples 4000]

For each fault-free scenario (``three_tank_nominal``, ``three_tank_guard_high``) and seed,
the fused monitor gives the mode switches; around each, ``agei`` is away from ``d1`` samples
before to ``d2`` after (``d1`` in 1, 5, 30, 80; ``d2`` in 1, 5, 20, 60, 150), and the
four-process chain's arithmetic is run in process with the nodes' rule per sample (the one
``test/test_agei_outage.py`` checks: the observer's and the detector's ``LocalAgei`` decide
while agei's decisions are absent; the estimator, which needs agei, stops; agei comes back
fresh). Prints the outages with a false alarm, with the fallback and without it (figures
only, no assertion).
"""

from __future__ import annotations

import argparse
import time
from typing import Any

from fd_monitor.core.hybrid_observer import NO_TRIGGER
from fd_monitor.core.local_agei import LocalAgei
from fd_monitor.core.methods import load_gains
from fd_monitor.core.monitor import Monitor
from fd_monitor.core.simulator import simulate
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system


def chain_alarms(system: Any, gains: Any, U: list[list[float]], Y: list[list[float]], a: int,
                 b: int, fallback: bool) -> tuple[list[int], list[int]]:
    """Alarmed samples and q^ per sample of the chain with agei away for ``[a, b)``."""
    m = Monitor(system, gains)
    obs_agei = LocalAgei(system, m.gains, residuals=True) if fallback else None
    det_agei = LocalAgei(system, m.gains, residuals=False) if fallback else None
    zero = [0.0] * system.ny
    alarms, modes = [], []
    for k in range(len(U)):
        absent = a <= k - 1 < b                  # agei did not decide at k - 1
        if k == b:
            m.agei.reset()
            m.estimator.reset()
        trigger = (obs_agei.trigger if obs_agei else NO_TRIGGER) if absent else m._trigger
        obs, x_hat, y_t = m.observer.step1(k, U[k], Y[k], zero if absent else m._sigma, trigger)
        q = int(obs.mode)
        if obs_agei:
            obs_agei.observe(k, q, y_t, x_hat)
        override = (det_agei.override if det_agei else None) if absent else m._override
        _, r, w, nominal, alarm = m.detector.step1(k, y_t, x_hat, q, override)
        if det_agei:
            det_agei.decide(k, q, w, r, nominal)
        if not a <= k < b:
            ag, ov = m.agei.step1(k, q, w, r, nominal)
            m._override = ov if ag.row >= 0 else None
            m._trigger = int(ag.trigger)
            _, m._sigma = m.estimator.step1(k, U[k], Y[k], q, alarm, bool(ag.mode_uncertain))
        if any(alarm):
            alarms.append(k)
        modes.append(q)
    return alarms, modes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=6, help="seeds 0 .. N-1 per scenario")
    ap.add_argument("--samples", type=int, default=4000, help="samples per run")
    args = ap.parse_args()
    system = load_system("three_tank")
    gains = load_gains("three_tank_thresholds", system)
    t0 = time.perf_counter()
    runs, alarmed = 0, {True: 0, False: 0}
    for name in ("three_tank_nominal", "three_tank_guard_high"):
        for seed in range(args.seeds):
            traj = simulate(load_scenario(name), seed, args.samples)
            U, Y = traj.u[0].tolist(), traj.y[0].tolist()
            base, modes = chain_alarms(system, gains, U, Y, len(U), len(U), True)
            switch = [k for k in range(1, len(modes)) if modes[k] != modes[k - 1]]
            for kc in switch:
                for d1 in (1, 5, 30, 80):
                    for d2 in (1, 5, 20, 60, 150):
                        runs += 1
                        for fb in (True, False):
                            got = chain_alarms(system, gains, U, Y, kc - d1, kc + d2, fb)[0]
                            extra = sorted(set(got) - set(base))
                            alarmed[fb] += bool(extra)
                            if extra and fb:
                                print(f"{name} seed {seed}: away {kc - d1}..{kc + d2}: "
                                      f"alarms {extra[:5]}")
            print(f"{name} seed {seed}: switches {switch}, alarms without outage {base}")
    print(f"{runs} outages: with a false alarm {alarmed[True]} with the nodes' own AGEI, "
          f"{alarmed[False]} without ({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
