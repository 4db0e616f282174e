"""``python -m fd_monitor replay BAGDIR``: publish a bag's messages on their topics.

Paced by the bag timestamps times ``--rate`` (1.0 = as recorded), or ``--rate 0`` = as fast
as the subscribers keep up without loss (reliable QoS, wait for ``--wait-subscribers``,
pace by acknowledgements). Ends once every message is published and acknowledged.

A recorded stream is a batch: the Float64MultiArray messages go out with the batch mark
(:data:`~fd_monitor.wire.conversions.BATCH_LABEL`), at any rate, so a node that falls more than
``max_lag`` s behind processes every one however late; ``--live`` publishes them without it,
as a robot would (such a node sheds them to stay current).
"""

from __future__ import annotations

import argparse
import re
import signal
import sys
from collections.abc import Sequence

from fd_monitor.analysis.integrity import add_strict_flag
from fd_monitor.commands._common import add_json_flag, count, emit, number

__all__ = ["add_arguments", "run", "main"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """BAGDIR, --topics, --rate, --live, --wait-subscribers, --remap, --json, --strict."""
    parser.add_argument("bag", metavar="BAGDIR", help="rosbag2 bag folder")
    parser.add_argument("--topics", nargs="+", default=None, metavar="TOPIC",
                        help="topics to replay (default: every Float64MultiArray topic)")
    parser.add_argument("--rate", type=number(0), default=1.0,
                        help="speed factor on the bag's timestamps; 0 = flat out, lossless "
                             "(default 1.0)")
    parser.add_argument("--live", action="store_true",
                        help="publish as a live source: without the batch mark (a node more "
                             "than max_lag s behind sheds samples to stay current; default: "
                             "marked, every sample processed however late)")
    parser.add_argument("--wait-subscribers", type=count(0, 10_000), default=0, metavar="N",
                        help="wait until every topic has N matched subscriptions")
    parser.add_argument("--wait-timeout", type=number(0), default=30.0, metavar="S",
                        help="s to wait for them, then fail (0 = forever; default 30)")
    parser.add_argument("--remap", action="append", default=[], metavar="FROM:=TO",
                        type=_remap, help="publish bag topic FROM on TO (repeatable)")
    add_json_flag(parser)
    add_strict_flag(parser)


_TOPIC = re.compile(r"^[~/]?[A-Za-z_{][A-Za-z0-9_/{}]*$")


def _remap(text: str) -> tuple[str, str]:
    """``FROM:=TO`` with two ROS topic names (argparse type)."""
    src, sep, dst = text.partition(":=")
    if not sep or not _TOPIC.match(src) or not _TOPIC.match(dst) or "//" in src + dst:
        raise argparse.ArgumentTypeError(f"expected FROM:=TO with two topic names, got "
                                         f"{text!r}")
    return src, dst


def run(args: argparse.Namespace) -> int:
    """Replay; print how many messages were published."""
    from fd_monitor.nodes.bag_nodes import ReplayNode
    from fd_monitor.nodes.process import run_node
    remap = dict(args.remap)
    from fd_monitor.analysis.integrity import bag_integrity

    doc = bag_integrity(args.bag, args.strict, note="replayed as recorded")[1]
    nodes: list[ReplayNode] = []

    def make() -> ReplayNode:
        nodes.append(ReplayNode(args.bag, args.topics, args.rate, remap,
                                args.wait_subscribers, args.wait_timeout,
                                batch=not args.live))
        return nodes[0]

    got: list[int] = []

    def remember(signum: int, _frame: object) -> None:
        got.append(signum)
        if signum == signal.SIGINT:
            raise KeyboardInterrupt

    # rclpy chains its own SIGINT/SIGTERM handlers to these: the signal is remembered, and
    # an interrupted replay exits 128 + signal (130, 143) like any shell tool, not 0.
    old = {s: signal.signal(s, remember) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        code = run_node(make, ["replay"], prog="replay", pacing=True)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    if got or (nodes and not code and not nodes[0].done.done()):
        sig = got[0] if got else signal.SIGTERM
        sent = nodes[0].published if nodes else 0
        print(f"fd_monitor: error: replay interrupted by {signal.Signals(sig).name} after "
              f"{sent} messages", file=sys.stderr)
        return 128 + sig
    if code or not nodes:
        return code
    node = nodes[0]
    summary = {"bag": args.bag, "published": node.published,
               "topics": {t: n for t, n in node.expected.items()}, "integrity": doc}
    if args.json:
        emit(summary, True)
    else:
        emit({"bag": args.bag, "published": node.published}, False)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """The ``replay`` console script / ``ros2 run fd_monitor replay``."""
    from fd_monitor.commands.cli import main as cli_main

    return cli_main(["replay", *(sys.argv[1:] if argv is None else argv)])
