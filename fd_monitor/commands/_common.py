"""Helpers shared by the subcommands: table and JSON output."""

from __future__ import annotations

import json
import sys
from collections.abc import Mapping, Sequence
from typing import Any

from fd_monitor.model.gains import to_plain

__all__ = ["add_json_flag", "print_json", "print_table", "emit"]


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
