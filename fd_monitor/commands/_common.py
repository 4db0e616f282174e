"""Helpers shared by the subcommands: table and JSON output."""

from __future__ import annotations

import json
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from fd_monitor.model.gains import save_gains, to_plain
from fd_monitor.model.paths import default_gain_path

__all__ = ["add_json_flag", "print_json", "print_table", "emit", "gain_path", "save_design"]


def add_json_flag(parser: Any) -> None:
    """Add ``--json`` (machine-readable output on stdout)."""
    parser.add_argument("--json", action="store_true",
                        help="print the summary as JSON instead of a table")


def print_json(doc: Any) -> None:
    """Print ``doc`` (numpy values allowed) as indented JSON on stdout."""
    json.dump(to_plain(doc), sys.stdout, indent=2, sort_keys=False)
    sys.stdout.write("\n")


def print_table(rows: Sequence[Sequence[Any]], header: Sequence[str] | None = None,
                title: str | None = None) -> None:
    """Print rows as an aligned plain-text table."""
    cells = [[_fmt(c) for c in r] for r in rows]
    if header is not None:
        cells.insert(0, [str(h) for h in header])
    if not cells:
        return
    widths = [max(len(r[i]) for r in cells if i < len(r)) for i in range(max(map(len, cells)))]
    if title:
        print(title)
    for i, r in enumerate(cells):
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
        if header is not None and i == 0:
            print("  ".join("-" * w for w in widths))


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def emit(summary: Mapping[str, Any], as_json: bool, title: str | None = None) -> None:
    """Print a flat summary mapping as a two-column table, or as JSON."""
    if as_json:
        print_json(summary)
    else:
        print_table([(k, v) for k, v in summary.items()], title=title)


def gain_path(args: Any, system: Any, name: str) -> Path:
    """The gain file ``design`` writes: ``-o``, else ``<plant>_<name>.yaml`` in the default
    place (:func:`fd_monitor.model.paths.default_gain_path`)."""
    return Path(args.output) if args.output else default_gain_path(system.name, name)


def save_design(args: Any, system: Any, method: str, design: Mapping[str, Any]) -> Path:
    """Write a designer's output (``parameters``, ``results``, ``certificate``, ``solver``) as
    the gain file of :func:`gain_path`; returns its path."""
    path = gain_path(args, system, method)
    save_gains(path, method, system, design["parameters"], design["results"],
               design["certificate"], design["solver"])
    return path
