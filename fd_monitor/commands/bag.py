"""``python -m fd_monitor bag check|recover``: a bag's integrity, and bags whose writer died.

``bag check BAG`` reads every message (every chunk's CRC checked) and prints the messages
per topic and each damage found, by byte position; exit status 1 when there is damage.

``bag recover BAG [-o OUT]`` rewrites every readable message of BAG into a new, complete bag
OUT (default ``BAG_recovered``): for a bag whose recorder was killed (no summary, no
``metadata.yaml``) or a damaged one. What was lost is printed as warnings, one line each.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from fd_monitor.commands._common import add_json_flag, emit
from fd_monitor.model.errors import FdMonitorError

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Sub-subcommands ``check`` and ``recover``."""
    sub = parser.add_subparsers(dest="action", metavar="<action>", required=True,
                                parser_class=type(parser))
    check = sub.add_parser("check", help="read every message and report damage",
                           description="read every message and report damage")
    check.add_argument("bag", metavar="BAG", help="bag folder (or its .mcap file)")
    add_json_flag(check)
    rec = sub.add_parser("recover", help="rewrite the readable messages into a complete bag",
                         description="rewrite the readable messages into a complete bag")
    rec.add_argument("bag", metavar="BAG", help="bag folder (or its .mcap file)")
    rec.add_argument("-o", "--output", metavar="OUT", default=None,
                     help="bag folder to create (default: BAG_recovered; must not exist)")
    add_json_flag(rec)


def run(args: argparse.Namespace) -> int:
    """Check or recover; print messages per topic (and damage as warnings)."""
    from fd_monitor.wire.bags import BagDamage, BagDamageWarning, bag_topics, recover_bag

    damage: list[BagDamage]
    if args.action == "check":
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", BagDamageWarning)
            topics = bag_topics(args.bag)
        lines = [str(w.message) for w in caught if issubclass(w.category, BagDamageWarning)]
        counts = {t: n for t, (_, n) in topics.items()}
        emit({"bag": str(args.bag), "messages": counts, "damage": lines} if args.json
             else counts, args.json, title=f"{args.bag}: {len(lines)} damage(s)")
        for line in lines if not args.json else []:
            print(f"damage: {line}")
        return 1 if lines else 0
    src = Path(args.bag)
    out = Path(args.output) if args.output else src.with_name(
        (src.name if src.is_dir() else src.stem) + "_recovered")
    if out.exists():
        raise FdMonitorError(f"{out}: already exists (a bag is never overwritten; give -o)")
    counts, damage = recover_bag(src, out)
    for d in damage:
        warnings.warn(str(d), BagDamageWarning, stacklevel=1)
    emit({"bag": str(out), "messages": counts, "damage": [str(d) for d in damage]}
         if args.json else counts, args.json, title=f"recovered {out}")
    return 0
