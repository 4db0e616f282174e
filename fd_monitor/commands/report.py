"""``python -m fd_monitor report BAG [--gains GAINS] -o DIR``: figures and a summary of a bag.

Runs the gain file's runtime over the bag, as ``analyze`` does (any method, from the registry
:func:`fd_monitor.core.methods.runtime_for`), and writes into DIR ``residuals.png`` (residuals
against the threshold in force, alarms shaded, fault onset marked), ``modes.png`` (true and
estimated mode), ``bias.png`` (methods that estimate a bias: bias estimate against the true
bias), ``qb_bound.png`` (QB gain files:
the error ellipsoid bound against the estimation error) and ``summary.md`` (summary table,
the check of the bag's ``expected.yaml`` when it has one, the figures). Without ``--gains``
the gain file named by the bag's ``expected.yaml`` is used; its plant is the one the gain file
records (``--system`` to give a plant file). A robot's own bag (JointState, Odometry, ...) is
read through an adapter file with ``--adapter``, as ``analyze --adapter`` does. Campaign
reports are written by ``python -m fd_monitor evaluate ... --report DIR``. BAG may also be the
``--out`` folder of a many-bag ``analyze`` (its ``bags.parquet``): the fleet page ``fleet.md``
(per robot; per robot, day and channel; bags that could not be analysed) and
``alarms_over_time.png`` (doc/howto/fleet.md).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from fd_monitor.analysis.integrity import add_strict_flag
from fd_monitor.commands._common import add_json_flag, emit, number

__all__ = ["add_arguments", "run", "main"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """BAG, --gains, --system, --adapter, -o, --force, --transient, --json, --strict."""
    parser.add_argument("bag", metavar="BAG", help="rosbag2 bag folder with /plant/u, /plant/y "
                                                  "(and /plant/truth for the true values), or "
                                                  "a robot's topics with --adapter")
    parser.add_argument("--gains", default=None, metavar="GAINS",
                        help="gain file (path or shipped name); default: the one named by "
                             "BAG/expected.yaml")
    parser.add_argument("--system", default=None, metavar="SYSTEM",
                        help="plant file (default: the plant the gain file records: its "
                             "plant file, or a shipped plant by name)")
    parser.add_argument("--adapter", default=None, metavar="MAP",
                        help="read u and y from a robot's own topics through this adapter "
                             "file (config/adapters/) instead of /plant/u and /plant/y")
    parser.add_argument("-o", "--output", required=True, metavar="DIR",
                        help="folder for the PNG figures and summary.md (created)")
    parser.add_argument("--force", action="store_true",
                        help="write into a non-empty DIR (overwriting an earlier report)")
    parser.add_argument("--transient", type=number(0), default=None, metavar="S",
                        help="ignore alarms before this time, s (default: expected.yaml's, "
                             "else 0)")
    add_json_flag(parser)
    add_strict_flag(parser)


def run(args: argparse.Namespace) -> int:
    """Write the report; print where it is and the expectation check."""
    from fd_monitor.analysis.integrity import describe, enforce_strict
    from fd_monitor.analysis.report import bag_report
    from fd_monitor.model.errors import FdMonitorError
    from fd_monitor.model.paths import check_output

    if args.transient is not None and not 0 <= args.transient < float("inf"):
        raise FdMonitorError(f"--transient {args.transient}: expected a finite number >= 0")
    check_output(args.output, "-o", FdMonitorError, folder=True, force=args.force)
    if fleet_folder(args.bag):
        return _fleet(args)
    res = bag_report(args.bag, args.output, args.gains, transient=args.transient,
                     system=args.system, adapter=args.adapter)
    s = res["summary"]
    fails = res["expected_failures"]
    doc = {"bag": args.bag, "summary_md": res["summary_md"],
           "figures": res["figures"],
           "alarms": s["alarms"], "isolated": s["isolated"],
           "bias_estimate": s["bias_estimate"],
           "expected": None if fails is None else ("ok" if not fails else fails),
           "integrity": res["integrity"]}
    if args.json:
        emit(doc, True)
    else:
        emit({"report": res["summary_md"],
              "figures": ", ".join(res["figures"].values()),
              "alarms": ", ".join(f"{a['channel']}@{a['first_sample']}" for a in s["alarms"])
              or "none",
              "isolated": ", ".join(s["isolated"]) or "none",
              "expected.yaml": "-" if fails is None else ("all hold" if not fails
                                                         else "; ".join(fails)),
              "integrity": describe(res["integrity"])},
             False, title=f"report of {args.bag}")
    enforce_strict(res["integrity"], args.bag, args.strict)
    return 0


def fleet_folder(path: str) -> bool:
    """``path`` is the tables folder of a many-bag ``analyze`` (not a bag)."""
    from pathlib import Path

    from fd_monitor.analysis.fleet import BAGS_FILE

    return (Path(path) / BAGS_FILE).is_file()


def _fleet(args: argparse.Namespace) -> int:
    """The fleet page of a many-bag ``analyze``'s tables."""
    from fd_monitor.analysis.fleet import fleet_report

    res = fleet_report(args.bag, args.output)
    doc = {"fleet": args.bag, "summary_md": res["summary_md"], "figures": res["figures"],
           "bags": res["bags"], "errors": res["errors"],
           "robots": [r["robot"] for r in res["summary"]["robots"]]}
    if args.json:
        emit(doc, True)
    else:
        emit({"report": res["summary_md"], "figures": ", ".join(res["figures"].values()),
              "bags": res["bags"], "errors": res["errors"],
              "robots": ", ".join(doc["robots"]) or "none"}, False,
             title=f"fleet report of {args.bag}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """The ``report`` console script / ``ros2 run fd_monitor report``."""
    from fd_monitor.commands.cli import main as cli_main

    return cli_main(["report", *(sys.argv[1:] if argv is None else argv)])
