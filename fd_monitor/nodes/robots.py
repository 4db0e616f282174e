"""Several robots' nodes in one process: one node set per robot namespace, one rclpy context
(one DDS participant) and one executor for all of them.

A process per robot costs a DDS participant, its threads and its shared-memory segments each
(a bare rclpy node is 65 MB here, and 34 participants on one host spent more CPU on
discovery and heartbeats than on the monitors: doc/reference/benchmarks-runtimes.md). With
``robots`` (``monitor --ros-args -p robots:="[robot1, robot2]"``) one process hosts a
monitor per robot instead: ``<ns>/robot1/monitor``, ``<ns>/robot2/monitor``, each with its
own relative topics (``robot1/plant/u``, ``robot1/fd/alarm``), lifecycle, ``~/reset``,
parameters (rcl applies a parameter file's ``/robot1/monitor:`` section to that node,
``/**:`` to all) and ``/diagnostics`` statuses (hardware_id ``robot1/<plant>``). The nodes
share nothing but the process: one robot's bad input, reset or lifecycle transition is its
own node's.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from typing import Any

from rclpy.node import Node

from fd_monitor.model.errors import FdMonitorError
from fd_monitor.nodes.params import Param

__all__ = ["ROBOTS", "host_robots", "robot_namespaces"]

#: The process parameter naming the robots one process hosts (read before any node exists;
#: no node declares it).
ROBOTS = Param("robots", [], "robot namespaces this process hosts, e.g. \"[robot1, robot2]\" "
               "or robot1,robot2: one monitor per robot in <namespace>/<robot> on one "
               "executor and one DDS participant; empty: one monitor in the process's "
               "namespace")

#: A relative namespace: ROS name tokens (a letter or _, then letters, digits, _) joined by /.
_RELATIVE_NS = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*")


def robot_namespaces(base: str | None, robots: Any) -> list[str]:
    """The namespace of each robot's nodes: ``<base>/<robot>``.

    Parameters
    ----------
    base : str or None
        The process's namespace (``-r __ns:=/fleet``; None or ``/``: the root).
    robots : sequence of str, or str
        The ``robots`` parameter: a string array, or one string of names separated by
        commas or blanks.

    Returns
    -------
    list of str
        Absolute namespaces, one per robot, in the order given (empty: no robots).

    Raises
    ------
    FdMonitorError
        A name that is not a relative ROS namespace, or one given twice (one line).
    """
    if isinstance(robots, str):
        names = [r for r in re.split(r"[,\s]+", robots) if r]
    elif isinstance(robots, Sequence) and all(isinstance(r, str) for r in robots):
        names = [r.strip() for r in robots]
    else:
        raise FdMonitorError(f"parameter robots: {robots!r}: expected robot names, e.g. "
                             f"\"[robot1, robot2]\"")
    seen: set[str] = set()
    for r in names:
        if not _RELATIVE_NS.fullmatch(r):
            raise FdMonitorError(f"parameter robots: {r!r}: expected a relative ROS "
                                 f"namespace (letters, digits and _, not starting with a "
                                 f"digit; / between levels)")
        if r in seen:
            raise FdMonitorError(f"parameter robots: {r!r} is given twice")
        seen.add(r)
    root = (base or "/").rstrip("/")
    return [f"{root}/{r}" for r in names]


def host_robots(make: Callable[..., list], namespaces: Sequence[str],
                **kwargs: Any) -> list[Node]:
    """Every robot's nodes: ``make(namespace=ns, **kwargs)`` for each of ``namespaces``.

    A robot whose nodes fail to start (a bad gain file in its parameter section) stops the
    start: the nodes made before are destroyed and the error names the robot.
    """
    nodes: list[Node] = []
    try:
        for ns in namespaces:
            try:
                nodes += make(namespace=ns, **kwargs)
            except FdMonitorError as exc:
                raise FdMonitorError(f"robot {ns}: {exc}") from None
    except Exception:
        for n in nodes:
            n.destroy_node()
        raise
    return nodes
