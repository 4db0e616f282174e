"""An ``agei`` outage around every mode switch: false alarms with and without the nodes' own
AGEI (issue 26 item 0; doc/howto/overload-and-recovery.md).

Run from the repository root::

    python benchmarks/agei_outage_sweep.py [--seeds 6] [--samples 4000]

For each fault-free scenario (``three_tank_nominal``, ``three_tank_guard_high``) and seed,
the fused monitor gives the mode switches; around each, ``agei`` is away from ``d1`` samples
before to ``d2`` after (``d1`` in 1, 5, 30, 80; ``d2`` in 1, 5, 20, 60, 150), and the
four-process chain's arithmetic is run in process with the nodes' rule per sample (the one
``test/test_agei_outage.py`` checks: the observer's and the detector's ``LocalAgei`` decide
while agei's decisions are absent, the estimator's its ``mode_uncertain``; agei comes
back fresh). Prints the outages with a false alarm, with the fallback and without it (figures
only, no assertion).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from fd_monitor.core.methods import load_gains
from fd_monitor.core.simulator import simulate
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "test"))

from test_agei_outage import chain


def chain_alarms(system: Any, gains: Any, U: list[list[float]], Y: list[list[float]], a: int,
                 b: int, fallback: bool) -> tuple[list[int], list[int]]:
    """Alarmed samples and q^ per sample of the chain with agei away for ``[a, b)``: the
    test's harness (:func:`test_agei_outage.chain`, one copy of the nodes' rule)."""
    run = chain((system, gains, U, Y), a, b, fallback=fallback)
    return [k for k, s in enumerate(run) if any(s[3])], [s[0] for s in run]


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
