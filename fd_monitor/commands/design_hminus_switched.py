"""``design hminus_switched``: options and summary of the switched H-minus observer (Farhat &
Koenig), :mod:`fd_monitor.design.hminus_switched`.
"""

from __future__ import annotations

import argparse

from fd_monitor.commands._common import print_json, print_table, save_design
from fd_monitor.design._lmi_common import load_design_section
from fd_monitor.design.hminus_switched import FREQS, design
from fd_monitor.model.errors import DesignError
from fd_monitor.model.system import load_system

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``design hminus_switched``."""
    parser.add_argument("--design-file", metavar="PATH", default=None,
                        help="design file (default: <plant file stem>.design.yaml beside it)")
    parser.add_argument("--plot", metavar="DIR", default=None,
                        help="write the sensitivity plot (Fig. 3) into DIR")


def run(args: argparse.Namespace) -> int:
    """Design, write the gain file, print the summary."""
    system = load_system(args.system)
    sec, origin, sha = load_design_section(system, "hminus_switched", args.design_file)
    if not sec:
        raise DesignError(f"{origin}: hminus_switched: missing section (E, fault, ...)")
    out = design(system, sec, origin, sha)
    path = save_design(args, system, "hminus_switched", out)
    plots: list[str] = []
    if args.plot:
        from fd_monitor.analysis.report_hinf import plot_switched

        plots = [str(p) for p in plot_switched(system, out["results"], args.plot)]
    doc = {"method": "hminus_switched", "system": system.name, "gain_file": str(path),
           "q": out["summary"]["q"], "beta": out["summary"]["beta"],
           "hminus_status": out["summary"]["hminus_status"],
           "frequencies_rad_s": list(FREQS), "sigma_min_db": out["summary"]["sigma_min_db"],
           "improvement_db": out["summary"]["improvement_db"],
           "decay_rate": out["summary"]["decay_rate"],
           "thresholds": {d: o.get("threshold")
                          for d, o in out["results"]["observers"].items()},
           "threshold_method": out["results"].get("threshold_method"), "plots": plots}
    if args.json:
        print_json(doc)
    else:
        rows = [(d, m, *[f"{v:.2f}" for v in vals])
                for d, per in out["summary"]["sigma_min_db"].items() for m, vals in per.items()]
        print(f"H-minus design (44): {out['summary']['hminus_status']}")
        if out["summary"]["improvement_db"] is not None:
            rows += [("hminus - stability", m, *[f"{v:+.2f}" for v in vals])
                     for m, vals in out["summary"]["improvement_db"].items()]
        print_table(rows, header=["design", "mode", *[f"{w:g} rad/s" for w in FREQS]],
                    title=f"hminus_switched for {system.name} (q = {out['summary']['q']}, "
                          f"beta = {out['summary']['beta']}) -> {path}; sigma_min T_rf, dB")
        if doc["threshold_method"]:
            print(f"thresholds on ||r|| ({doc['threshold_method']['method']}): " +
                  ", ".join(f"{d} {v:.4g}" for d, v in doc["thresholds"].items()))
    return 0
