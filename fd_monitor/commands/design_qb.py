"""``design qb``: options and summary of the quadratic-boundedness observer (Alessandri, Boem &
Parisini) of :mod:`fd_monitor.design.qb`.
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from fd_monitor.commands._common import emit, gain_path, number
from fd_monitor.core.qb_certificate import guarantee
from fd_monitor.core.qb_model import default_fault_states
from fd_monitor.design.qb import XATOL, design_qb, write_gain_file
from fd_monitor.model.errors import DesignError
from fd_monitor.model.system import load_system

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """QB options (SYSTEM, -o and --json are added by the design dispatcher)."""
    parser.add_argument("--beta", type=number(0, low_open=True), default=None,
                        help="fix the S-procedure multiplier beta (default: search for the "
                             "beta that minimises rho_max)")
    parser.add_argument("--margin", type=number(0), default=1e-6,
                        help="strictness margin of the LMIs (default 1e-6)")
    parser.add_argument("--sampled", action="store_true",
                        help="design for the sampled plant the runtime runs (exact ZOH at the "
                             "plant's sample time, discrete-time QB LMI; gain file time: "
                             "discrete); default: the plant's own time domain")
    parser.add_argument("--fault-states", default=None, metavar="S1,S2",
                        help="states that model faults, monitored by the detector (default: "
                             "state_jump targets and states constant in every mode)")



def run(args: argparse.Namespace) -> int:
    """Design, verify, write the gain file and print a summary."""
    system = load_system(args.system)
    if args.fault_states:
        fs = tuple(s.strip() for s in args.fault_states.split(",") if s.strip())
        unknown = [s for s in fs if s not in system.states]
        if unknown:
            raise DesignError(f"--fault-states: {unknown} are not states of {system.name} "
                              f"({', '.join(system.states)})")
    else:
        fs = default_fault_states(system)
    d = design_qb(system, args.beta, margin=args.margin, sampled=args.sampled)
    out = gain_path(args, system, "qb_sampled" if args.sampled else "qb")
    params = {"beta": "search" if args.beta is None else args.beta, "margin": args.margin,
              "search": ("reduced LMIs (Y eliminated), max lambda_min(P): log grid + bounded "
                         f"Brent in log(beta), xatol {XATOL}"),
              "tie_break": ("P, alpha from step 5 with inner margin k x margin (k = 10, 100, "
                            "1000); minimum |(P L_i)_i|_F s.t. the LMIs with margin"),
              "fault_states": list(fs)}
    if args.sampled:
        params["sampled"] = True
    write_gain_file(out, system, d, fs, params)
    summary: dict[str, Any] = {
        "gain_file": str(out), "plant": system.name, "time": d.model.time,
        "guarantee": guarantee({"time": d.model.time}, system),
        "beta": d.beta, "rho_max": d.rho_max, "lambda_min": d.bounds["lambda_min"],
        "alpha": np.round(d.alpha, 6).tolist(),
        "component_bound": dict(zip(system.states, np.round(d.bounds["component_bound"], 6)
                                    .tolist())),
        "r_max": float(np.max(d.bounds["r_max"])),
        "output_bound": dict(zip(system.outputs, np.round(np.max(d.bounds["output_bound"],
                                                                 axis=0), 6).tolist())),
        "lmi_max_eig": max(d.lmi_max_eig), "spectral_abscissa": max(d.spectral_abscissa),
        "solves": d.solver["solves"], "solve_time_s": d.solver["time_s"],
    }
    if args.json:
        summary["P"] = d.P
        summary["L"] = {n: d.L[i] for i, n in enumerate(system.mode_names)}
        summary["search"] = [{"beta": b, "lambda": v, "status": s} for b, v, s in d.search]
    emit(summary, args.json, title=f"QB design of {system.name} -> {out}")
    return 0
