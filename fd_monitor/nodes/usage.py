"""``<exe> --help``: a node's parameters and topics as text, without starting ROS.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass

from fd_monitor.nodes.params import Param
from fd_monitor.nodes.ros_args import shown_params_file
from fd_monitor.wire.topics import Topic

__all__ = ["NodeUsage", "usage_text", "wants_help"]


@dataclass(frozen=True)
class NodeUsage:
    """What ``<exe> --help`` prints for one node: its parameters and topics.

    Attributes
    ----------
    name : str
        Node name (the key in its ``config/<name>.yaml``).
    summary : str
        One line.
    params : sequence of Param
        The same declarations the node passes to :func:`declare_parameters`.
    subscribes, publishes : sequence of (Topic, str)
        ``(topic, meaning)`` (:mod:`fd_monitor.wire.topics`).
    """

    name: str
    summary: str
    params: Sequence[Param]
    subscribes: Sequence[tuple[Topic, str]] = ()
    publishes: Sequence[tuple[Topic, str]] = ()


def wants_help(args: Sequence[str] | None) -> bool:
    """True when ``-h``/``--help`` comes before ``--ros-args`` (``args[0]`` is the program)."""
    argv = list(sys.argv if args is None else args)[1:]
    if "--ros-args" in argv:
        argv = argv[:argv.index("--ros-args")]
    return "-h" in argv or "--help" in argv


def usage_text(prog: str, usages: Sequence[NodeUsage], config: str | None = None) -> str:
    """The ``--help`` text of an executable running the nodes ``usages``.

    Parameters
    ----------
    prog : str
        Executable name.
    usages : sequence of NodeUsage
    config : str, optional
        Parameter file stem under ``config/``; default ``prog``.
    """
    cfg = shown_params_file(config or prog)
    lines = [f"usage: {prog} [-h] [--ros-args [-p NAME:=VALUE ...] [--params-file {cfg}] "
             f"[-r FROM:=TO ...]]", ""]
    lines.append(usages[0].summary if len(usages) == 1 else
                 f"{prog}: the nodes {', '.join(u.name for u in usages)} on one executor in "
                 f"one process, each with its own parameters (one section per node in {cfg}).")
    lines += ["", "Parameters come from a ROS 2 parameter file or -p overrides:",
              f"  {prog} --ros-args --params-file {cfg}",
              f"  python -m fd_monitor run {prog} --ros-args --params-file {cfg} "
              f"-p NAME:=VALUE",
              "Doubles are typed: write 1.0, not 1. Topics are relative: -r __ns:=/robot1 moves "
              "them all (/diagnostics stays); -r plant/y:=x/y remaps one.",
              "Lifecycle nodes (autostart true by default; a lifecycle manager's first "
              "configure takes over); ~/reset (std_srvs/Trigger) starts a new run of the "
              "whole chain.",
              "-r __node:=NAME names the nodes of a several-node executable NAME, "
              "NAME_observer, ...",
              "A relative --params-file that is not found from the current directory is "
              "looked up in the installed config/ folder."]
    for u in usages:
        if len(usages) > 1:
            lines += ["", f"-- {u.summary}"]
        lines += ["", f"parameters ({u.name}):"]
        width = max((len(p.name) for p in u.params), default=0)
        for p in u.params:
            rng = (f", range [{p.low:g}, {p.high:g}]" if p.low is not None and p.high is not None
                   and not isinstance(p.default, bool) else "")
            lines.append(f"  {p.name:<{width}}  {p.description} (default {p.default!r}{rng})")
        for head, declared in (("subscribes", u.subscribes), ("publishes", u.publishes)):
            # The names as the node resolves them: data topics relative to its namespace.
            topics = [(t.name, m) for t, m in declared]
            if topics:
                lines += ["", f"{head} ({u.name}):"]
                tw = max(len(t) for t, _ in topics)
                lines += [f"  {t:<{tw}}  {m}" for t, m in topics]
    lines += ["", "options:", "  -h, --help  show this message and exit (ROS is not started)"]
    return "\n".join(lines) + "\n"
