"""``python -m fd_monitor design <method> SYSTEM -o GAINS``: run a designer, write a gain file.

The methods, their help lines and their designers come from the method registry
(:data:`fd_monitor.core.methods.METHODS`): each names its designer's command module
(``fd_monitor.commands.design_<method>`` for the shipped ones) with ``add_arguments(parser)``
(its own options; SYSTEM, ``-o`` and ``--json`` are added here) and ``run(args) -> int``; only
the chosen method's is imported (the designer it calls, ``fd_monitor.design.<method>``, is
the only place cvxpy is imported).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from fd_monitor.commands._common import add_json_flag
from fd_monitor.core.methods import METHODS, MethodRegistry

__all__ = ["METHODS", "add_arguments", "run", "main"]


def add_arguments(parser: argparse.ArgumentParser,
                  methods: MethodRegistry | None = None) -> None:
    """Add one sub-parser per method of ``methods`` (default the registry,
    :data:`~fd_monitor.core.methods.METHODS`); only the chosen method's designer module is
    imported."""
    sub = parser.add_subparsers(dest="method", metavar="<method>", required=True,
                                parser_class=type(parser))
    from fd_monitor.commands.cli import ARGV

    chosen = _chosen_method(ARGV)
    for name, method in (METHODS if methods is None else methods).items():
        help_ = method.help
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
            mod = importlib.import_module(method.designer)
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
