"""``python -m fd_monitor record [TOPIC ...] -o BAGDIR``: record topics to an MCAP bag.

Subscribes (reliable, keep all) to the topics and writes every message's CDR bytes with its
receive time. Stops on SIGINT/SIGTERM, after ``--messages N`` in total, when every
``--until TOPIC=N`` topic has N messages, or after ``--duration S``; the bag is closed
cleanly in every case. Without TOPICs it records every fd_monitor topic and /diagnostics; with
``--adapter MAP`` the robot's mapped topics (their own types) and, without TOPICs, the
monitor's ``fd/*`` outputs and /diagnostics.
Messages reach the file in CRC-checked chunks at least every 0.5 s, so a recorder killed
with SIGKILL (or a power cut after the OS wrote its cache) loses at most the last second;
``python -m fd_monitor bag recover`` rewrites such a bag with its summary and metadata.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from fd_monitor.commands._common import add_json_flag, count, emit, number
from fd_monitor.model.errors import FdMonitorError

__all__ = ["add_arguments", "run", "main"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """TOPICs, -o, --until, --messages, --duration, --type, --json."""
    parser.add_argument("topics", nargs="*", metavar="TOPIC",
                        help="topics to record (default: every fd_monitor topic and "
                             "/diagnostics)")
    parser.add_argument("-o", "--output", metavar="BAGDIR", required=True,
                        help="bag folder to create (must not exist)")
    parser.add_argument("--until", action="append", default=[], metavar="TOPIC=N",
                        help="stop once TOPIC has N messages (repeatable: all must hold)")
    parser.add_argument("--messages", type=count(1), default=None, metavar="N",
                        help="stop after N messages in total")
    parser.add_argument("--duration", type=number(0, low_open=True), default=None, metavar="S",
                        help="stop after S seconds")
    parser.add_argument("--adapter", default=None, metavar="MAP",
                        help="also record the robot topics of this adapter file "
                             "(config/adapters/), with their types; without TOPICs: the "
                             "robot topics, the monitor's fd/* topics and /diagnostics")
    parser.add_argument("--type", action="append", default=[], metavar="TOPIC=TYPE",
                        help="message type of a topic that is not an fd_monitor topic "
                             "(std_msgs/msg/Float64MultiArray or "
                             "diagnostic_msgs/msg/DiagnosticArray)")
    add_json_flag(parser)


def _pairs(items: Sequence[str], what: str) -> dict[str, str]:
    out = {}
    for it in items:
        key, sep, val = it.rpartition("=")
        if not sep or not key or not val:
            raise FdMonitorError(f"{what} {it!r}: expected TOPIC=VALUE")
        out[key] = val
    return out


def run(args: argparse.Namespace) -> int:
    """Record until a stop condition; print per-topic counts."""
    from fd_monitor.nodes.bag_nodes import KNOWN_TYPES, RecorderNode
    from fd_monitor.nodes.process import run_node
    from fd_monitor.wire.bag_writer import FLUSH_SECONDS, BagWriter

    types = dict(KNOWN_TYPES)
    types.update(_pairs(args.type, "--type"))
    topics = list(args.topics) or list(KNOWN_TYPES)
    if args.adapter:
        from fd_monitor.wire.adapters import load_adapter
        from fd_monitor.wire.topics import CHAIN_OUTPUTS, DIAGNOSTICS

        robot = load_adapter(args.adapter).topics
        types.update(robot)
        if not args.topics:
            # the robot's topics replace plant/u, plant/y (and the simulator's truth): what
            # the monitor reads and what it says about them
            topics = [t.absolute for t in (*CHAIN_OUTPUTS, DIAGNOSTICS)]
        topics = [t for t in robot if t not in topics] + topics
    unknown = [t for t in topics if t not in types]
    if unknown:
        raise FdMonitorError(f"record: unknown type of {', '.join(unknown)} (give --type "
                             f"TOPIC=std_msgs/msg/Float64MultiArray)")
    until: dict[str, int] = {}
    for t, n in _pairs(args.until, "--until").items():
        if not n.isdigit():
            raise FdMonitorError(f"--until {t}={n}: expected a count >= 0")
        if t not in topics:
            raise FdMonitorError(f"--until {t}: not a recorded topic")
        until[t] = int(n)
    if args.messages is not None and args.messages < 1:
        raise FdMonitorError(f"--messages {args.messages}: expected >= 1")
    if args.duration is not None and args.duration <= 0:
        raise FdMonitorError(f"--duration {args.duration}: expected > 0")
    writer = BagWriter(args.output, flush_seconds=FLUSH_SECONDS)
    try:
        code = run_node(lambda: RecorderNode(writer, {t: types[t] for t in topics}, until,
                                             args.messages, args.duration),
                        ["record"], prog="record")
    finally:
        writer.close()
    if code:
        return code
    counts = dict(writer.counts)
    if args.json:
        emit({"bag": str(args.output), "messages": counts}, True)
    else:
        emit({t: n for t, n in counts.items()}, False, title=f"recorded {args.output}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """The ``record`` console script / ``ros2 run fd_monitor record``."""
    from fd_monitor.commands.cli import main as cli_main

    return cli_main(["record", *(sys.argv[1:] if argv is None else argv)])



