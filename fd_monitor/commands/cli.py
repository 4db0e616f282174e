"""The fd_monitor command line: ``python -m fd_monitor <subcommand>``.

Every subcommand lives in ``fd_monitor/commands/<name>.py`` and provides
``add_arguments(parser)`` and ``run(args) -> int``; modules are imported only when their
subcommand runs, so ``--help`` is fast and a missing optional dependency (rclpy, cvxpy)
only affects the subcommands that need it. Errors of fd_monitor print one line
``fd_monitor: error: ...`` and exit with status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings
from collections.abc import Sequence
from types import ModuleType
from typing import Any, NoReturn

from fd_monitor.model.errors import FdMonitorError, FdMonitorWarning

__all__ = ["ARGV", "SUBCOMMANDS", "build_parser", "main"]

#: The arguments being parsed (subcommands with sub-subcommands read it to import lazily).
ARGV: list[str] = []

#: name -> one-line help. The module is fd_monitor.commands.<name>.
SUBCOMMANDS: dict[str, str] = {
    "validate": "check a plant file (or scenario) and print its summary",
    "simulate": "simulate a scenario with the core simulator (no ROS) and write an MCAP bag",
    "run": "run one of the ROS 2 nodes (plant_sim, observer, detector, ...)",
    "record": "record topics to a rosbag2 MCAP bag",
    "replay": "replay a rosbag2 MCAP bag onto its topics",
    "demo": "the whole pipeline on the default plant, end to end",
    "design": "design gains (observers, residual generators, thresholds) into a gain file",
    "analyze": "run the monitor over a bag offline and print alarms and estimates",
    "report": "figures and a summary of a bag or a campaign",
    "evaluate": "Monte Carlo campaigns: false-alarm rate, detection rate and delay",
    "identify": "fit a plant file (modes, noise and uncertainty bounds) from fault-free bags",
    "bag": "check a bag's integrity, or recover a bag whose recorder died",
}


class _Parser(argparse.ArgumentParser):
    """argparse that exits with one line on bad usage (status 2)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def _command_module(name: str) -> ModuleType:
    return importlib.import_module(f"fd_monitor.commands.{name}")


def build_parser(argv: Sequence[str]) -> argparse.ArgumentParser:
    """The top-level parser; only the chosen subcommand's module is imported."""
    ARGV[:] = list(argv)
    parser = _Parser(prog="fd_monitor", description=__doc__.splitlines()[0],
                     formatter_class=argparse.RawDescriptionHelpFormatter,
                     epilog="Run `python -m fd_monitor <subcommand> --help` for details.")
    sub = parser.add_subparsers(dest="command", metavar="<subcommand>", parser_class=_Parser)
    chosen = next((a for a in argv if not a.startswith("-")), None)
    for name, help_ in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_, description=help_)
        if name == chosen:
            try:
                mod = _command_module(name)
            except ModuleNotFoundError as exc:
                if exc.name and exc.name.startswith("fd_monitor.commands"):
                    parser.exit(2, f"fd_monitor: error: subcommand {name!r} is not "
                                   f"available in this version\n")
                raise
            mod.add_arguments(p)
            p.set_defaults(_run=mod.run)
    return parser


def _show_warning(message: Any, category: type[Warning], *args: Any, **kwargs: Any) -> None:
    """fd_monitor's warnings as one line ``fd_monitor: warning: ...``; others as Python's."""
    if issubclass(category, FdMonitorWarning):
        print(f"fd_monitor: warning: {message}", file=sys.stderr)
    else:
        _default_showwarning(message, category, *args, **kwargs)


_default_showwarning = warnings.showwarning


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m fd_monitor`` and the ``fd_monitor`` console script."""
    args_list = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(args_list)
    try:
        args = parser.parse_args(args_list)
    except SystemExit as exc:         # usage error (one line printed) or --help
        return int(exc.code or 0) if not isinstance(exc.code, str) else 2
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    warnings.showwarning = _show_warning
    try:
        return int(args._run(args) or 0)
    except FdMonitorError as exc:
        print(f"fd_monitor: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        # Ctrl-C in a long command (evaluate, identify, design): one line, no traceback
        # (evaluate ends its progress bar's line first)
        print(f"fd_monitor: interrupted (Ctrl-C): {args.command} stopped, nothing more "
              f"written", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into `head` and closed: not an error
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
