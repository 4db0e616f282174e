"""``design thresholds``: options and summary of the filters, thresholds, AGEI matrix and estimator
gains of :mod:`fd_monitor.design.thresholds`.
"""

from __future__ import annotations

import argparse

from fd_monitor.commands._common import count, emit, number, save_design
from fd_monitor.core.thresholds import DEFAULT_DELTA
from fd_monitor.design.thresholds import design_thresholds
from fd_monitor.model.system import load_system

__all__ = ["MAX_MC_SAMPLES", "add_arguments", "run"]

#: Most Monte Carlo samples per mode (``--mc-samples``).
MAX_MC_SAMPLES = 10_000_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``design thresholds`` (SYSTEM, -o and --json come from the dispatcher)."""
    parser.add_argument("--scenario", action="append", default=None, metavar="SCENARIO",
                        help="design scenario (repeatable); default every shipped "
                             "<plant>_*.yaml scenario, faults removed")
    parser.add_argument("--seeds", type=count(1, 1000), default=4,
                        help="fault-free runs per scenario")
    parser.add_argument("--tube", type=number(0), default=None,
                        help="widening of the operating region, state units (default 20 v_bar)")
    parser.add_argument("--mc-samples", type=count(1, MAX_MC_SAMPLES), default=200000,
                        help="Monte Carlo samples per mode (default 200000)")
    parser.add_argument("--mc-margin", type=number(0), default=0.25,
                        help="relative margin on Monte Carlo maxima (default 0.25)")
    parser.add_argument("--mc-seed", type=count(0), default=0)
    parser.add_argument("--filter", choices=("fir", "iir"), default="fir")
    parser.add_argument("--length", type=count(1, 1_000_000), default=None,
                        help="moving-average length (default: automatic)")
    parser.add_argument("--pole", type=number(0, 1, high_open=True), default=None,
                        help="IIR pole in [0, 1)")
    parser.add_argument("--max-window", type=number(0, low_open=True), default=2.0,
                        help="longest filter window, s (default 2.0)")
    parser.add_argument("--delta", type=number(0), default=DEFAULT_DELTA,
                        help="AGEI band delta of eq. 21 (default 0.05)")
    parser.add_argument("--gamma", type=number(0, low_open=True), default=0.02,
                        help="estimator learning rate: Gamma = gamma I (default 0.02)")
    parser.add_argument("--lambda", dest="lam", type=number(0), default=1e-3,
                        help="estimator output injection: Lambda = lambda I (default 1e-3)")
    parser.add_argument("--alpha", type=number(0, 1), default=0.02,
                        help="presmoother gain (default 0.02)")
    parser.add_argument("--init", choices=("presmoother", "measurement"),
                        default="presmoother",
                        help="estimator initial state at detection (default presmoother; "
                             "measurement = the paper's x^s = y)")
    parser.add_argument("--envelope", choices=("scenarios", "declared"), default="scenarios",
                        help="region to certify: the simulated design scenarios (sampled "
                             "bounds) or the plant file's declared envelope (rho_bar a bound "
                             "over it)")
    parser.add_argument("--box-width", type=number(0, low_open=True), default=0.01,
                        help="--envelope declared: side of the interval-arithmetic boxes, "
                             "state units (default 0.01)")
    parser.add_argument("--m-sigma", type=number(0, low_open=True), default=None,
                        help="projection radius M_sigma (default 100 v_bar)")



def run(args: argparse.Namespace) -> int:
    """Design, write the gain file, re-load it (certificate check) and print a summary."""
    from fd_monitor.core.methods import load_gains

    system = load_system(args.system)
    d = design_thresholds(system, scenarios=args.scenario, seeds=args.seeds, tube=args.tube,
                          mc_samples=args.mc_samples, mc_margin=args.mc_margin,
                          mc_seed=args.mc_seed, filter_kind=args.filter, length=args.length,
                          pole=args.pole, max_window=args.max_window, delta=args.delta,
                          gamma=args.gamma, lam=args.lam, alpha=args.alpha, init=args.init,
                          M_sigma=args.m_sigma, envelope=args.envelope,
                          box_width=args.box_width)
    out = save_design(args, system, "thresholds", d)
    load_gains(out, system)  # re-verifies the certificate
    summary = {"gain_file": str(out), **d["summary"]}
    emit(summary, args.json, title=f"thresholds design of {system.name} -> {out}")
    return 0
