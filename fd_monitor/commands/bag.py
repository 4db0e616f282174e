"""``python -m fd_monitor bag check|recover``: a bag's integrity, and bags whose writer died.

``bag check BAG`` reads every message (every chunk's CRC checked) and prints the messages
per topic, each damage found, by byte position, and where ``metadata.yaml`` disagrees with the
MCAP; exit status 1 when there is any. Chunks with CRC 0 ("not computed", as ``rosbags``
writes them) are not damage: one note says they cannot be checked (exit 0).

``bag recover BAG [-o OUT]`` rewrites every readable message of BAG into a new, complete bag
OUT (default ``BAG_recovered``): for a bag whose recorder was killed (no summary, no
``metadata.yaml``) or a damaged one. What was lost is printed as warnings, one line each.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from fd_monitor.analysis.integrity import add_strict_flag
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
    add_strict_flag(check)
    rec = sub.add_parser("recover", help="rewrite the readable messages into a complete bag",
                         description="rewrite the readable messages into a complete bag")
    rec.add_argument("bag", metavar="BAG", help="bag folder (or its .mcap file)")
    rec.add_argument("-o", "--output", metavar="OUT", default=None,
                     help="bag folder to create (default: BAG_recovered; must not exist)")
    add_json_flag(rec)


def run(args: argparse.Namespace) -> int:
    """Check or recover; print messages per topic (and damage as warnings)."""
    from fd_monitor.wire.bag_scanner import BagDamage, BagDamageWarning, BagUncheckedWarning
    from fd_monitor.wire.bag_writer import recover_bag

    damage: list[BagDamage]
    if args.action == "check":
        from fd_monitor.analysis.integrity import bag_integrity, describe, enforce_strict

        scan, doc = bag_integrity(args.bag, args.strict, warn=False, enforce=False)
        lines = doc["damage"] + [f"{args.bag}: {m}" for m in doc["metadata"]]
        counts = {t: n for t, (_, n) in scan.present.items()}
        note = (f"{doc['unchecked_chunks']} chunk(s) carry no CRC (CRC 0: not computed by their "
                f"writer): they cannot be checked for bit errors" if doc["unchecked_chunks"]
                else None)
        emit({"bag": str(args.bag), "messages": counts, "damage": lines,
              "integrity": doc} if args.json
             else counts, args.json, title=f"{args.bag}: {len(lines)} damage(s)")
        if not args.json:
            for line in lines:
                print(f"damage: {line}")
            if note:
                print(f"note: {note}")
            if "samples_present" in doc:
                print(f"samples: {describe(doc)}")
        enforce_strict(doc, args.bag, args.strict)      # after the table, as analyze does
        return 1 if lines else 0
    src = Path(args.bag)
    out = Path(args.output) if args.output else src.with_name(
        (src.name if src.is_dir() else src.stem) + "_recovered")
    if out.exists():
        raise FdMonitorError(f"{out}: already exists (a bag is never overwritten; give -o)")
    counts, damage = recover_bag(src, out)
    for d in damage:
        warnings.warn(str(d), BagDamageWarning if d.kind == "damage" else BagUncheckedWarning,
                      stacklevel=1)
    emit({"bag": str(out), "messages": counts, "damage": [str(d) for d in damage]}
         if args.json else counts, args.json, title=f"recovered {out}")
    return 0
