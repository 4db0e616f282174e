"""``python -m fd_monitor design <method> SYSTEM -o GAINS``: run a designer, write a gain file.

Each method has a command module ``fd_monitor.commands.design_<method>`` with
``add_arguments(parser)`` (its own options; SYSTEM, ``-o`` and ``--json`` are added here) and
``run(args) -> int``; the designer it calls is ``fd_monitor.design.<method>``, the only place
cvxpy is imported.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from fd_monitor.commands._common import add_json_flag

__all__ = ["METHODS", "add_arguments", "run", "main"]

#: method -> one-line help; the designer is fd_monitor.design.<method>, its command line
#: fd_monitor.commands.design_<method>.
METHODS: dict[str, str] = {
    "qb": "quadratic-boundedness observer (LTI / PWA), Alessandri, Boem & Parisini",
    "thresholds": "filters, filtered-residual thresholds and AGEI matrix, Heracleous et al.",
    "hinf_sc": "bank of H-infinity residual generators with a sensitivity constraint (thesis)",
    "hminus_switched": "switched H-minus generalized observer, Farhat & Koenig",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add one sub-parser per method; only the chosen method's module is imported."""
    sub = parser.add_subparsers(dest="method", metavar="<method>", required=True,
                                parser_class=type(parser))
    from fd_monitor.commands.cli import ARGV

    chosen = _chosen_method(ARGV)
    for name, help_ in METHODS.items():
        p = sub.add_parser(name, help=help_, description=help_)
        p.add_argument("system", metavar="SYSTEM",
                       help="plant file, or the name of a shipped plant (config/systems/)")
        p.add_argument("-o", "--output", metavar="GAINS", default=None,
                       help="gain file to write (default: config/gains/<plant>_<method>.yaml "
                            "in a checkout, else ./<plant>_<method>.yaml)")
        p.add_argument("--force", action="store_true",
                       help="overwrite an existing -o GAINS file")
        add_json_flag(p)
        if name == chosen:
            mod = importlib.import_module(f"fd_monitor.commands.design_{name}")
            mod.add_arguments(p)
            p.set_defaults(_method_run=mod.run)


def _chosen_method(argv: Sequence[str]) -> str | None:
    words = [a for a in argv if not a.startswith("-")]
    if words and words[0] == "design" and len(words) > 1:
        return words[1]
    return None


def run(args: argparse.Namespace) -> int:
    """Run the chosen method's designer."""
    if not hasattr(args, "_method_run"):
        raise SystemExit(f"fd_monitor design: error: method {args.method!r} is not available")
    if args.output is not None:
        # Before the design (minutes for the large ones): a place we cannot write, or an
        # existing file without --force, is refused now, not after the solver ran.
        from fd_monitor.model.errors import DesignError
        from fd_monitor.model.paths import check_output

        check_output(args.output, "-o", DesignError, folder=False, force=args.force)
    return int(args._method_run(args) or 0)


def main(argv: Sequence[str] | None = None) -> int:
    """The ``design`` console script / ``ros2 run fd_monitor design``."""
    from fd_monitor.commands.cli import main as cli_main

    return cli_main(["design", *(sys.argv[1:] if argv is None else argv)])
