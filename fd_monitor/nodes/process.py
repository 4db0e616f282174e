"""The process main of every node executable: :func:`run_node` (rclpy init, executor,
spin, shutdown).
"""

from __future__ import annotations

import gc
import sys
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from fd_monitor.model.errors import FdMonitorError
from fd_monitor.nodes.pacing import use_dds_profile
from fd_monitor.nodes.ros_args import init_ros, take_namespace, take_node_name
from fd_monitor.nodes.usage import NodeUsage, usage_text, wants_help

__all__ = ["run_node"]


def _events_executor() -> Any:
    from rclpy.experimental import EventsExecutor

    return EventsExecutor()


def run_node(factory: Callable[..., Node | Sequence[Node]], args: Sequence[str] | None = None,
             prog: str = "fd_monitor", usage: Sequence[NodeUsage] = (),
             pacing: bool = False, named: bool = False) -> int:
    """Init rclpy, build the node(s), spin until done or shut down; return an exit status.

    When the nodes all allow it (``events_executor`` true: the diagnosis nodes, whose
    callbacks take no MessageInfo, which it cannot pass in these wheels) the executor is
    rclpy's EventsExecutor, driven by a ``spin_once`` loop (its ``spin()`` processes nothing
    in these wheels): no wait-set rebuild per callback (about 0.15 ms per message with the
    SingleThreadedExecutor here), what a node handling thousands of messages per second needs.

    With ``-h``/``--help`` before ``--ros-args`` it prints :func:`usage_text` of ``usage``
    and returns 0 without starting ROS.

    A node may expose ``done`` (an ``rclpy.task.Future``) to end the spin, and
    ``exit_code``. ``pacing``: a source that paces by acknowledgements (its DDS profile:
    :func:`use_dds_profile`). ``named``: an executable of several nodes; a node-name remap
    (``-r __node:=NAME``) and a namespace remap (``-r __ns:=/NS``) are taken out of the ROS
    arguments (:func:`~fd_monitor.nodes.ros_args.take_node_name`,
    :func:`~fd_monitor.nodes.ros_args.take_namespace`: rcl would apply them to every node)
    and passed as ``factory(node_name=NAME, namespace=NS)`` (each only when given), which
    names and places its nodes from them. One executor runs every node the factory made
    (several robots' monitors share the process's one DDS participant). At the end every
    lifecycle node goes through its shutdown transition (``finish()``: one log line) before
    it is destroyed. Start-up errors (``FdMonitorError``: bad gain file, bad scenario, bad
    parameter) print one line ``<prog>: error: ...`` and return 2. SIGINT/SIGTERM end
    cleanly (KeyboardInterrupt / ExternalShutdownException), then ``destroy_node()`` and
    ``rclpy.try_shutdown()``, as the ROS 2 demos do.
    """
    if wants_help(args):
        sys.stdout.write(usage_text(prog, usage))
        return 0
    use_dds_profile(pacing)
    where: dict[str, str] = {}
    if named:
        args, name = take_node_name(sys.argv if args is None else args)
        args, ns = take_namespace(args)
        where = {k: v for k, v in (("node_name", name), ("namespace", ns)) if v}
    try:
        init_ros(args)
    except FdMonitorError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    nodes: list[Node] = []
    try:
        made = factory(**where)
        nodes = list(made) if isinstance(made, Sequence) else [made]
        # What start-up made (modules, plant, gain file, nodes) lives as long as the process:
        # frozen, a full garbage collection later does not rescan it (a ~25 ms pause of the
        # data path otherwise).
        gc.freeze()
        events = all(getattr(n, "events_executor", False) for n in nodes)
        executor = _events_executor() if events else SingleThreadedExecutor()
        for n in nodes:
            executor.add_node(n)
        done = getattr(nodes[0], "done", None)
        if events:
            # rclpy.ok() of the nodes' context, bound once (the loop turns once per message)
            ok = nodes[0].context.ok
            while ok() and (done is None or not done.done()):
                executor.spin_once(timeout_sec=0.1)
        elif done is not None:
            executor.spin_until_future_complete(done)
        else:
            executor.spin()
        return int(getattr(nodes[0], "exit_code", 0))
    except FdMonitorError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    except Exception:
        # SIGINT/SIGTERM shut the context down while a callback was publishing.
        if not rclpy.ok():
            return 0
        raise
    finally:
        for n in nodes:
            finish = getattr(n, "finish", None)
            if finish is not None:
                finish()
        finals = [getattr(n, "final_log", None) for n in nodes]
        for n in nodes:
            n.destroy_node()
        for final in finals:
            if final is not None:
                # after a signal the context is gone: the node's own logger would still try
                # its dead rosout publisher (rcl prints an error per line); a logger of another
                # name writes to the console and the log file only
                rclpy.logging.get_logger(f"{final[0]}.lifecycle").info(final[1])
        rclpy.try_shutdown()
