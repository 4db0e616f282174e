"""A robot's own topics in and out of the nodes, through an adapter file.

:class:`AdapterInput` subscribes the topics an adapter file maps (``sensor_msgs/JointState``,
``nav_msgs/Odometry``, ``geometry_msgs/Twist``, ``std_msgs/Float64``, ...) and feeds the
events of the one time base (:class:`fd_monitor.wire.adapters.AdapterJoin` on
:mod:`fd_monitor.wire.timebase`: every channel sampled onto the plant's grid) into the node's
input policy as ``u`` and ``y`` with :func:`~fd_monitor.wire.adapters.feed` -- the function
the offline reader calls -- so everything after it (gaps, new runs, the runtime step,
diagnostics) is the node's usual path. Subscriptions
meet reliable and best-effort volatile publishers (:class:`~fd_monitor.nodes.data_input.DataInput`).
A message the adapter cannot read (unknown joint, missing field, NaN, another type) is one
line, logged (throttled) and reported WARN on the node's ``input`` channel; the node keeps
going. A mapped topic published with another type is reported on ``ros graph``.

:class:`RobotPublishers` is the other direction, for ``plant_sim -p adapter:=FILE``: each
simulated sample also goes out as the robot's messages (header stamps on the plant's clock).
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Sequence
from functools import partial
from typing import Any

import numpy as np

from fd_monitor.nodes.bag_nodes import message_class
from fd_monitor.nodes.data_input import DataInput
from fd_monitor.nodes.params import Param
from fd_monitor.nodes.qos import pub_events
from fd_monitor.wire.adapters import HOLD_WAIT, Adapter, AdapterJoin, encode, feed, load_adapter

__all__ = ["ADAPTER_PARAM", "AdapterInput", "RobotPublishers"]

ADAPTER_PARAM = Param(
    "adapter", "", "adapter file (path, or a name in config/adapters/): read u and y from "
    "the robot topics it maps (JointState, Odometry, Twist, Float64, Float64MultiArray) "
    "instead of plant/u and plant/y; empty: plant/u and plant/y")

#: s between two checks of the mapped topics' types in the ROS graph.
GRAPH_CHECK = 2.0


def _make(msgtype: str, **fields: Any) -> Any:
    """:func:`~fd_monitor.wire.adapters.encode`'s ``make`` for rclpy messages (nested types
    too: Header, Time, MultiArrayLayout, Vector3, ...)."""
    pkg, _, name = msgtype.split("/")
    out = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in fields.items()}
    return getattr(importlib.import_module(f"{pkg}.msg"), name)(**out)


class AdapterInput:
    """The robot's topics as a node's ``u`` and ``y`` (see the module docstring).

    Parameters
    ----------
    node : FdNode
        Configured: ``system``, ``stream``, ``input_status``, ``graph``, ``_entities``.
    source : str
        The adapter file.
    hold_wait : float
        s of silence after which what waits is decided
        (:data:`~fd_monitor.wire.adapters.HOLD_WAIT`).
    """

    def __init__(self, node: Any, source: str, hold_wait: float = HOLD_WAIT) -> None:
        self.node = node
        self.adapter: Adapter = load_adapter(source).for_system(node.system)
        self.join = AdapterJoin(self.adapter, float(node.system.sample_time), hold_wait)
        self.nu = len(self.adapter.inputs)
        for topic, ty in self.adapter.topics.items():
            cls = message_class(ty)
            # with the DDS MessageInfo: a header-less message's time is when its publisher
            # sent it (source timestamp), not when this executor got round to it
            name = node.resolve_topic_name(topic)
            node._entities.append(DataInput(
                node, cls, topic, lambda msg, info=None, topic=topic: self._on_msg(topic, msg,
                                                                                   info),
                partial(node.graph.note, cause=f"qos {name}"), with_info=True,
                switched=partial(node.graph.switched, name)))
        node._entities.append(node.create_timer(hold_wait / 2, self._release))
        node._entities.append(node.create_timer(GRAPH_CHECK, self._check_types))
        self._type_notes: set[str] = set()

    @property
    def topics(self) -> list[str]:
        """The subscribed topics, resolved."""
        return [self.node.resolve_topic_name(t) for t in self.adapter.topics]

    def _on_msg(self, topic: str, msg: Any, info: Any = None) -> None:
        node = self.node
        if not node.active:
            node.inactive_dropped += 1
            return
        now = time.monotonic()
        sent = int(info["source_timestamp"]) if info is not None else time.time_ns()
        self.join.put(topic, msg, sent, now)
        self._release(now)

    def _release(self, now: float | None = None) -> None:
        node = self.node
        if not node.active:
            return
        if now is None:                          # the timer: a silence decides what waits
            now = time.monotonic()
            self.join.advance(now)
        joined = False
        for e in self.join.events():
            joined = feed(node.stream, e, now, bool(self.nu)) or joined
        if joined:
            node.input_status.ok()
        for _kind, line in self.join.take_errors():
            node.input_status.bad_input(line)

    def reset(self) -> None:
        """Forget the stream (``~/reset``): sample indices start again at 0."""
        self.join.reset()

    def _check_types(self) -> None:
        node = self.node
        graph = dict(node.get_topic_names_and_types())
        for topic, ty in self.adapter.topics.items():
            name = node.resolve_topic_name(topic)
            seen = [t for t in graph.get(name, []) if t != ty]
            if seen:
                line = (f"{name}: published as {', '.join(seen)}, the adapter "
                        f"{self.adapter.source} maps it as {ty}: those messages cannot arrive")
                if line not in self._type_notes:
                    self._type_notes.add(line)
                    node.graph.note(line)


class RobotPublishers:
    """Publish samples as the robot's messages (``plant_sim -p adapter:=FILE``).

    Parameters
    ----------
    node : rclpy.node.Node
    source : str
        The adapter file.
    system : System
        Orders u and y.
    qos : rclpy.qos.QoSProfile
    """

    def __init__(self, node: Any, source: str, system: Any, qos: Any) -> None:
        self.adapter = load_adapter(source).for_system(system)
        self.pubs = {t: node.create_publisher(message_class(ty), t, qos, **pub_events())
                     for t, ty in self.adapter.topics.items()}
        self.dt_ns = round(float(system.sample_time) * 1e9)
        self.t0_ns = time.time_ns()

    def wanted(self, inputs: int, outputs: int) -> list[tuple[Any, int]]:
        """(publisher, subscriptions to wait for): ``outputs`` on the sample clock's topic,
        ``inputs`` on the inputs' topics."""
        clock = self.adapter.clock_topic
        ins = {c.topic for c in self.adapter.inputs} - {clock}
        return [(self.pubs[clock], outputs), *((self.pubs[t], inputs) for t in sorted(ins))]

    def publish(self, k: int, u: Sequence[float], y: Sequence[float]) -> None:
        """Sample k, header stamps t0 + k Ts (the plant's clock from the node's start)."""
        for topic, _ty, msg in encode(self.adapter, self.t0_ns + k * self.dt_ns, u, y, _make):
            self.pubs[topic].publish(msg)
