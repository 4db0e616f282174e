"""Helpers shared by the subcommands: table and JSON output, checked argparse numbers."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from fd_monitor.model.gains import save_gains, to_plain
from fd_monitor.model.paths import default_gain_path

__all__ = ["MAX_SEED", "add_json_flag", "count", "emit", "gain_path", "number", "print_json",
           "print_table", "save_design"]

#: Largest seed a command takes (numpy's generators take any integer; a seed is stored and
#: compared as a 64-bit integer everywhere else).
MAX_SEED = 2**63 - 1


def _bound(v: float) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def number(low: float = -math.inf, high: float = math.inf, *, low_open: bool = False,
           high_open: bool = False) -> Callable[[str], float]:
    """An argparse ``type``: a finite float in the range (``low_open``: ``> low``, else
    ``>= low``; likewise ``high``). NaN, inf and anything outside are refused by argparse
    with one line (``argument --margin: expected a finite number > 0, got 'nan'``)."""
    parts = []
    if low > -math.inf:
        parts.append(f"{'>' if low_open else '>='} {_bound(low)}")
    if high < math.inf:
        parts.append(f"{'<' if high_open else '<='} {_bound(high)}")
    want = "a finite number" + (" " + " and ".join(parts) if parts else "")

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {want}, got {text!r}") from None
        ok = (math.isfinite(v) and (v > low if low_open else v >= low)
              and (v < high if high_open else v <= high))
        if not ok:
            raise argparse.ArgumentTypeError(f"expected {want}, got {text!r}")
        return v

    parse.__name__ = "number"     # argparse names the type in its messages
    return parse


def count(low: int = 0, high: int = MAX_SEED) -> Callable[[str], int]:
    """An argparse ``type``: an integer in ``[low, high]`` (written as an integer: ``1e12``
    and ``2.5`` are refused, so a typo never becomes a huge or truncated count)."""
    want = f"an integer in [{low}, {high}]" if high < MAX_SEED else f"an integer >= {low}"

    def parse(text: str) -> int:
        try:
            v = int(text.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {want}, got {text!r}") from None
        if not low <= v <= high:
            raise argparse.ArgumentTypeError(f"expected {want}, got {text!r}")
        return v

    parse.__name__ = "count"
    return parse


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
