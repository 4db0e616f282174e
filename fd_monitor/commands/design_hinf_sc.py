"""``design hinf_sc``: options and summary of the bank of sensitivity-constrained H-infinity
generators, :mod:`fd_monitor.design.hinf_sc`.
"""

from __future__ import annotations

import argparse

from fd_monitor.commands._common import number, print_json, print_table, save_design
from fd_monitor.design._lmi_common import load_design_section
from fd_monitor.design.hinf_sc import design
from fd_monitor.model.errors import DesignError
from fd_monitor.model.system import load_system

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``design hinf_sc`` (SYSTEM, -o and --json are added by the dispatcher)."""
    parser.add_argument("--design-file", metavar="PATH", default=None,
                        help="design file (default: <plant file stem>.design.yaml beside it)")
    parser.add_argument("--lambda", dest="lam", type=number(high=0, high_open=True),
                        default=None, metavar="LAMBDA",
                        help="use this eigenvalue (< 0) instead of choosing it on the grid")
    parser.add_argument("--grid", nargs=3, type=number(), default=None,
                        metavar=("START", "STOP", "NUM"),
                        help="lambda grid (default from the design file, else -10 -0.1 50)")
    parser.add_argument("--compare-pure", action="store_true",
                        help="also design the pure attenuation generators (4.24)")
    parser.add_argument("--plot", metavar="DIR", default=None,
                        help="write singular-value and mu(lambda) plots into DIR")
    parser.add_argument("--lyapunov", choices=("common", "affine"), default=None,
                        help="lpv banks: common P (6.40) or affine P(rho) (6.4, needs rate "
                             "bounds: design file 'rate' or --rate); default from the design "
                             "file, else common")
    parser.add_argument("--rate", default=None, metavar="R1,R2,...",
                        help="with --lyapunov affine: |d rho_j/dt| <= R_j, 1/s (overrides the "
                             "design file's rate)")


def run(args: argparse.Namespace) -> int:
    """Design, write the gain file, print the summary."""
    system = load_system(args.system)
    section, origin, sha = load_design_section(system, "hinf_sc", args.design_file)
    section = dict(section)
    if args.lam is not None:
        if args.lam >= 0:
            raise DesignError(f"--lambda: expected a number < 0, got {args.lam}")
        section["lambda"] = args.lam
    if args.grid is not None:
        if not args.grid[2].is_integer() or args.grid[2] < 1:
            raise DesignError(f"--grid NUM {args.grid[2]:g}: expected an integer >= 1")
        section["lambda_grid"] = {"start": args.grid[0], "stop": args.grid[1],
                                  "num": int(args.grid[2])}
    if args.compare_pure:
        section["compare_pure"] = True
    if args.lyapunov is not None:
        section["lyapunov"] = args.lyapunov
    if args.rate is not None:
        try:
            r = [abs(float(v)) for v in args.rate.split(",") if v.strip()]
        except ValueError:
            raise DesignError(f"--rate: expected comma-separated numbers, got "
                              f"{args.rate!r}") from None
        section["rate"] = {"min": [-v for v in r], "max": r}
    out = design(system, section, origin, sha)
    path = save_design(args, system, "hinf_sc", out)
    plots: list[str] = []
    if args.plot:
        from fd_monitor.analysis.report_hinf import plot_bank

        plots = [str(p) for p in plot_bank(system, out["results"], args.plot)]
    doc = {"method": "hinf_sc", "system": system.name, "kind": out["results"]["kind"],
           "gain_file": str(path), "solver_time_s": out["solver"]["time_s"],
           "generators": out["summary"], "thresholds": out["results"].get("thresholds"),
           "threshold_method": out["results"].get("threshold_method"),
           "mu_grid": {g["fault"]: g["mu_grid"] for g in out["results"]["generators"]},
           "plots": plots}
    if args.json:
        print_json(doc)
        return 0
    thr = doc["thresholds"] or [float("inf")] * len(out["summary"])
    rows = [(s["fault"], s["lambda"], s["mu"],
             ", ".join(f"{k}={v:.3g}" for k, v in s["gamma2"].items()), f"{j:.4g}")
            for s, j in zip(out["summary"], thr)]
    method = (doc["threshold_method"] or {"method": "none"})["method"]
    print_table(rows, header=["fault", "lambda", "mu", "gamma^2", f"threshold ({method})"],
                title=f"hinf_sc bank for {system.name} ({out['results']['kind']}) -> {path}")
    grids = doc["mu_grid"]
    lams = next(iter(grids.values()))["lambda"]
    if len(lams) > 1 and all(g["lambda"] == lams for g in grids.values()):
        # The performance ratio mu(lambda) of eq. (4.35) per generator (thesis Fig. 4.3).
        print()
        print_table([(lam, *(g["mu"][i] for g in grids.values()))
                     for i, lam in enumerate(lams)],
                    header=["lambda", *(f"mu_{f}" for f in grids)],
                    title="mu(lambda) over the lambda grid (eq. 4.35)")
    return 0
