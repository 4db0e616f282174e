"""``python -m fd_monitor evaluate GAINS -s SCENARIO [...]``: Monte Carlo campaigns.

Simulates ``--runs`` seeded runs of each scenario, replays them through the gain file's method
(looked up by its ``method``, see :data:`fd_monitor.core.methods.RUNTIMES`) and prints the
false-alarm rate, detection rate and delay per scenario, variant and threshold scale, as a
table or as JSON. A scenario simulates its own plant P; the gain file is for P, or for a model
of P with P's inputs, outputs and sample time (an identified plant: its monitor reads P's
measurements). Table II of the QB paper::

    python -m fd_monitor evaluate pwa_cascade_qb -s pwa_cascade_nominal -s pwa_cascade_b1_step \\
        --runs 1000 --transient 20 --rho 0.01,0.05,0.10,0.15,0.20,1 --channels b1,b2 \\
        --state-bound rho_max --estimator qb,kalman
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from fd_monitor.commands._cluster import add_cluster_arguments, campaign_rows
from fd_monitor.commands._common import add_json_flag, count, number, print_json, print_table
from fd_monitor.core.methods import load_gains, runtime_class
from fd_monitor.model.errors import FdMonitorError
from fd_monitor.model.scenario import check_horizon, load_scenario
from fd_monitor.model.system import gain_system

__all__ = ["MAX_RUNS", "add_arguments", "run"]

#: Most runs per scenario (``--runs``): a million runs of a 3,000-sample scenario are hours of
#: work already; a larger number is a typo.
MAX_RUNS = 1_000_000


def _floats(text: str) -> list[float]:
    try:
        vals = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") \
            from None
    if not vals or any(not v > 0 for v in vals):
        raise argparse.ArgumentTypeError(f"expected numbers > 0, got {text!r}")
    return vals


def _names(text: str) -> list[str]:
    return [v.strip() for v in text.split(",") if v.strip()]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``evaluate``."""
    parser.add_argument("gains", metavar="GAINS",
                        help="gain file, or the name of a shipped one (config/gains/)")
    parser.add_argument("-s", "--scenario", action="append", required=True, metavar="SCENARIO",
                        help="scenario file or shipped name (repeatable); a scenario of plant "
                             "P runs on a gain file of P or of a model of P (an identified "
                             "plant with P's inputs, outputs and sample time)")
    parser.add_argument("--system", default=None, metavar="SYSTEM",
                        help="the gain file's plant file when it is not the scenarios' plant "
                             "(default: the plant the gain file records: its plant file, or a "
                             "shipped plant by name)")
    parser.add_argument("-n", "--runs", type=count(1, MAX_RUNS), default=100,
                        help=f"runs per scenario (100; at most {MAX_RUNS:,})")
    parser.add_argument("--seed0", type=count(0), default=0, help="seed of the first run (0)")
    parser.add_argument("--chunk", type=count(1, 1_000_000), default=250,
                        help="runs simulated at once (memory vs speed; 250)")
    parser.add_argument("--transient", type=number(0), default=0.0,
                        help="ignore alarms before this time, s (0)")
    parser.add_argument("--rho", type=_floats, default=None, metavar="R1,R2,...",
                        help="threshold scales to sweep (methods with scalable thresholds)")
    parser.add_argument("--channels", type=_names, default=None, metavar="C1,C2",
                        help="alarm channels that count (default: all of the method's)")
    parser.add_argument("--estimator", type=_names, default=None, metavar="qb,kalman",
                        help="QB only: estimators to compare with the same thresholds")
    parser.add_argument("--state-bound", choices=("component", "rho_max"), default=None,
                        help="QB only: bound of the fault-state channels: per-component "
                             "sqrt((P^-1)_jj) or rho_max (eq. 8, the paper's Table II)")
    parser.add_argument("--q-fault", type=number(0), default=None,
                        help="QB only: random-walk variance of the Kalman baseline's fault "
                             "states per sample")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--report", metavar="DIR", default=None,
                        help="also write summary.md and PNG plots (detection rate and delay "
                             "against fault magnitude, false-alarm rate) into DIR")
    add_json_flag(parser)
    add_cluster_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Run the campaign and print its metrics."""
    from fd_monitor.model.paths import check_output

    if args.runs < 1:
        raise FdMonitorError(f"--runs {args.runs}: expected an integer >= 1")
    if args.chunk < 1:
        raise FdMonitorError(f"--chunk {args.chunk}: expected an integer >= 1")
    if args.seed0 < 0:
        raise FdMonitorError(f"--seed0 {args.seed0}: expected an integer >= 0")
    if not 0 <= args.transient < float("inf"):
        raise FdMonitorError(f"--transient {args.transient}: expected a finite number >= 0")
    if args.report is not None:
        check_output(args.report, "--report", FdMonitorError, folder=True)
    scenarios = [load_scenario(s) for s in args.scenario]
    for sc in scenarios:
        check_horizon(sc.system, sc.duration, f"{sc.source}: duration", FdMonitorError,
                      runs=min(args.chunk, args.runs))
    raw = load_gains(args.gains, verify=False)
    plants = {sc.system.sha256: sc.system for sc in scenarios}
    system = plants.get(raw.system_sha256)
    if system is None:        # a model of the scenarios' plant (an identified one)
        system = gain_system(raw, args.system)
    gains = load_gains(args.gains, system)
    takes = runtime_class(gains.method).batch_options()
    for flag, opt in (("--state-bound", "state_bound"), ("--estimator", "estimator")):
        if getattr(args, opt) and opt not in takes:
            raise FdMonitorError(f"{flag}: method {gains.method!r} has no {opt} option "
                                 f"(its batch options: {', '.join(takes) or 'none'})")
    common: dict[str, Any] = {}
    if args.state_bound is not None:
        common["state_bound"] = args.state_bound
    variants: dict[str, dict[str, Any]] = {}
    if args.estimator:
        for est in args.estimator:
            if est not in ("qb", "kalman"):
                raise FdMonitorError(f"--estimator: expected qb or kalman, got {est!r}")
            opts = dict(common, estimator=est)
            if est == "kalman" and args.q_fault is not None:
                opts["kalman"] = {"q_fault": args.q_fault}
            variants[est] = opts
    else:
        variants[gains.method] = common
    try:
        rows = campaign_rows(args, gains, scenarios, args.runs, seed0=args.seed0,
                             chunk=args.chunk, rhos=args.rho, transient=args.transient,
                             channels=args.channels, variants=variants,
                             progress=not args.no_progress, system=system)
    except KeyboardInterrupt:
        if not args.no_progress:          # end the progress bar's line before the message
            sys.stderr.write("\n")
        raise
    if args.report is not None:
        from fd_monitor.analysis.report import campaign_report

        campaign_report(rows, scenarios, args.report, gains=str(gains.path),
                        transient=args.transient)
    if args.json:
        print_json({"gains": gains.path, "plant": system.name,
                    "simulated": sorted({sc.system.name for sc in scenarios}),
                    "runs": args.runs, "seed0": args.seed0,
                    "transient_s": args.transient, "channels": args.channels,
                    "rows": [r.as_dict() for r in rows]})
        return 0
    table = []
    for r in rows:
        table.append([r.scenario, r.variant, "-" if r.rho is None else f"{r.rho:g}", r.runs,
                      f"{100 * r.false_alarm_rate:.1f}",
                      "-" if r.detection_rate is None else f"{100 * r.detection_rate:.1f}",
                      "-" if r.delay_mean_s is None else f"{r.delay_mean_s:.2f}",
                      "-" if r.delay_median_s is None else f"{r.delay_median_s:.2f}",
                      "-" if r.delay_max_s is None else f"{r.delay_max_s:.2f}"])
    print_table(table, header=["scenario", "variant", "rho", "runs", "false_alarm_%",
                               "detected_%", "delay_mean_s", "delay_median_s", "delay_max_s"],
                title=f"evaluate {gains.path} (plant {system.name}"
                      + "".join(f", scenarios of {p.name}" for p in plants.values()
                                if p.sha256 != system.sha256)
                      + f"; transient {args.transient:g} s)")
    return 0
