"""Nodes behind ``record`` (topics -> MCAP bag) and ``replay`` (bag -> topics).

Both move serialized CDR bytes (``raw=True`` subscriptions, ``publish(bytes)``), so a
recorded or replayed message is bit-identical to the published one.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future

from fd_monitor.model.errors import BagError
from fd_monitor.nodes.data_input import DataInput
from fd_monitor.nodes.pacing import AckPacer
from fd_monitor.nodes.qos import (
    DEFAULT_DEPTH,
    data_pub_qos,
    diagnostics_qos,
    pub_events,
    sub_events,
)
from fd_monitor.wire.adapters import ADAPTER_TYPES
from fd_monitor.wire.bag_scanner import bag_topics, read_raw
from fd_monitor.wire.bag_writer import BagWriter
from fd_monitor.wire.conversions import set_batch_mark
from fd_monitor.wire.topics import CHAIN_DATA, DIAGNOSTIC_ARRAY, DIAGNOSTICS, FLOAT64_MULTI_ARRAY

__all__ = ["KNOWN_TYPES", "RecorderNode", "ReplayNode", "message_class"]

#: Default types of the fd_monitor topics.
KNOWN_TYPES: dict[str, str] = {t.absolute: t.msg_type for t in (*CHAIN_DATA, DIAGNOSTICS)}


def message_class(msgtype: str) -> Any:
    """The rclpy message class of ``pkg/msg/Name``: fd_monitor's types and the robot types
    the adapters read (:data:`fd_monitor.wire.adapters.ADAPTER_TYPES`)."""
    supported = (FLOAT64_MULTI_ARRAY, DIAGNOSTIC_ARRAY, *ADAPTER_TYPES)
    if msgtype not in supported:
        raise BagError(f"message type {msgtype}: not supported (supported: "
                       f"{', '.join(supported)})")
    pkg, _, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def _diagnostics_sub_qos() -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


class RecorderNode(Node):
    """Subscribe to topics and write every message to an MCAP bag.

    With a writer made with ``flush_seconds`` (``record`` uses
    :data:`fd_monitor.wire.bag_writer.FLUSH_SECONDS`), every message is in the file within
    about that long of its arrival, so a killed recorder loses at most the last second.

    Parameters
    ----------
    writer : BagWriter
    topics : mapping of str to str
        topic -> message type.
    until : mapping of str to int, optional
        Stop when every named topic has at least that many messages.
    max_messages : int, optional
        Stop after that many messages in total.
    duration : float, optional
        Stop after that many seconds.
    """

    def __init__(self, writer: BagWriter, topics: Mapping[str, str],
                 until: Mapping[str, int] | None = None, max_messages: int | None = None,
                 duration: float | None = None, node_name: str = "record",
                 **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)       # kwargs: rclpy Node's (context, ...)
        self.writer = writer
        self.until = dict(until or {})
        self.max_messages = max_messages
        self.total = 0
        self.done = Future()
        self.exit_code = 0
        #: The data subscriptions (they meet reliable and best-effort publishers alike).
        self.inputs: dict[str, DataInput] = {}
        for topic, msgtype in topics.items():
            writer.add_topic(topic, msgtype)
            if msgtype == DIAGNOSTIC_ARRAY:
                self.create_subscription(message_class(msgtype), topic, self._callback(topic),
                                         _diagnostics_sub_qos(), raw=True, **sub_events())
            else:
                # log time: when DDS received it (its MessageInfo), as rosbag2 records, not
                # when this executor got round to it (a backlog is handed over per topic)
                self.inputs[topic] = DataInput(self, message_class(msgtype), topic,
                                               self._callback(topic), self._report, raw=True,
                                               with_info=True)
        if duration is not None:
            self.create_timer(float(duration), self._stop)
        if writer.flush_seconds is not None:
            # a quiet topic still gets its last messages on disk within ~flush_seconds
            self.create_timer(writer.flush_seconds / 2, writer.tick)

    def _callback(self, topic: str) -> Callable[..., None]:
        def cb(raw: bytes, info: Any = None) -> None:
            if self.done.done():
                return
            t = int(info["received_timestamp"]) if info is not None else 0
            self.writer.write_raw(topic, t or time.time_ns(), raw)
            self.total += 1
            if self._finished():
                self._stop()
        return cb

    def _report(self, line: str) -> None:
        """A QoS incompatibility or the switch to best effort: one log line each."""
        self.get_logger().warning(line)

    def _finished(self) -> bool:
        if self.max_messages is not None and self.total >= self.max_messages:
            return True
        return bool(self.until) and all(self.writer.counts.get(t, 0) >= n
                                        for t, n in self.until.items())

    def _stop(self) -> None:
        if not self.done.done():
            self.done.set_result(True)


class ReplayNode(Node):
    """Publish a bag's messages on their topics, paced or as fast as possible without loss.

    Parameters
    ----------
    bag : str or pathlib.Path
    topics : sequence of str, optional
        Topics to replay (default: every Float64MultiArray topic of the bag).
    rate : float
        Speed factor on the bag timestamps; 0 = flat out, paced by acknowledgements.
    remap : mapping of str to str, optional
        Bag topic -> published topic.
    wait_subscribers : int
        Wait until every topic has at least this many matched subscriptions.
    wait_timeout : float
        s to wait for them (0 = forever), then end with exit code 1.
    depth, ack_window : int
        Publisher history depth and samples between waits for acknowledgements.
    batch : bool
        Float64MultiArray messages are published with the batch mark (a recorded stream
        is a batch: every sample processed however late); False (``replay --live``): without
        it, as a live source (a node more than ``max_lag`` s behind sheds them). The
        recorded bytes are kept otherwise (:func:`~fd_monitor.wire.conversions.set_batch_mark`).
    """

    def __init__(self, bag: str | Path, topics: Sequence[str] | None = None,
                 rate: float = 1.0, remap: Mapping[str, str] | None = None,
                 wait_subscribers: int = 0, wait_timeout: float = 30.0,
                 depth: int = DEFAULT_DEPTH, ack_window: int = 100,
                 node_name: str = "replay", batch: bool = True) -> None:
        super().__init__(node_name)

        available = bag_topics(bag)
        if topics is None:
            topics = [t for t, (ty, _) in available.items() if ty == FLOAT64_MULTI_ARRAY]
        missing = [t for t in topics if t not in available]
        if missing:
            raise BagError(f"{bag}: no topic {', '.join(missing)} in the bag (topics: "
                           f"{', '.join(sorted(available))})")
        remap = dict(remap or {})
        self.batch = bool(batch)
        #: topics whose messages get the batch mark set or cleared
        self._marked = {t for t in topics if available[t][0] == FLOAT64_MULTI_ARRAY}
        self.pubs = {}
        for t in topics:
            msgtype = available[t][0]
            qos = diagnostics_qos() if msgtype == DIAGNOSTIC_ARRAY else data_pub_qos(depth)
            self.pubs[t] = self.create_publisher(message_class(msgtype), remap.get(t, t), qos,
                                               **pub_events())
        self.expected = {t: available[t][1] for t in topics}
        self._iter: Iterator[tuple[str, str, int, bytes]] = read_raw(bag, list(topics))
        self._pending: tuple[str, str, int, bytes] | None = next(self._iter, None)
        self.rate = float(rate)
        self.wait_subscribers = int(wait_subscribers)
        self.wait_timeout = float(wait_timeout)
        self._pacer = AckPacer(list(self.pubs.values()), min(ack_window, depth - 1))
        self.published = 0
        self.done = Future()
        self.exit_code = 0
        self._started = time.monotonic()
        self._t0: float | None = None
        self._bag_t0 = self._pending[2] if self._pending else 0
        self._timer = self.create_timer(0.001, self._on_tick)

    def _on_tick(self) -> None:
        if self.done.done():
            return
        now = time.monotonic()
        if self._t0 is None:
            if any(p.get_subscription_count() < self.wait_subscribers
                   for p in self.pubs.values()):
                if self.wait_timeout > 0 and now - self._started > self.wait_timeout:
                    self.get_logger().error(f"timed out after {self.wait_timeout:g} s waiting "
                                            f"for {self.wait_subscribers} subscribers")
                    self._finish(1)
                return
            self._t0 = now
        burst = 0
        while self._pending is not None and burst < self._pacer.window:
            topic, _, t_ns, raw = self._pending
            if self.rate > 0 and (t_ns - self._bag_t0) * 1e-9 / self.rate > now - self._t0:
                return
            if topic in self._marked:
                raw = set_batch_mark(raw, self.batch)
            self.pubs[topic].publish(raw)
            self.published += 1
            burst += 1
            self._pacer.published()
            self._pending = next(self._iter, None)
        if self._pending is None:
            if not self._pacer.flush():
                self.get_logger().warning("not every message was acknowledged in time")
            self._finish(0)

    def _finish(self, code: int) -> None:
        self.exit_code = code
        self._timer.cancel()
        self.done.set_result(code)
