"""A chain node's input path: subscriptions, decoding, the hold rule, the stamp join.

:class:`InputPath` is built by :meth:`FdNode.start_inputs
<fd_monitor.nodes.fd_node.FdNode.start_inputs>` from the node's declared inputs
(:class:`~fd_monitor.nodes.inputs.Input`) and held by it. Per input it subscribes
(serialized messages, :class:`~fd_monitor.nodes.data_input.DataInput`), decodes and
validates each message (:class:`~fd_monitor.wire.conversions.RawDecoder`; a bad one is
reported on the node's ``input`` status and dropped), pairs plain (unstamped) messages by the
one hold rule (:class:`~fd_monitor.wire.hold.HeldPairing`: a plain ``plant/y`` gets the latest
``plant/u`` published at or before it, by the DDS source timestamps) and joins everything on
the stamp through the input policy offline reading shares
(:class:`~fd_monitor.wire.stream.InputStream` over a
:class:`~fd_monitor.wire.join.StampJoin`), which hands each complete sample to the node. With
an ``adapter`` parameter the robot's own topics give u and y
(:class:`~fd_monitor.nodes.adapter_input.AdapterInput`). One reset for the chain: the entry
(no ``sequence`` input) listens on ``fd/reset``; the other nodes' ``~/reset`` asks it there.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import numpy as np
from rclpy.serialization import deserialize_message
from std_msgs.msg import Empty, Float64MultiArray

from fd_monitor.model.errors import MessageError
from fd_monitor.nodes.adapter_input import AdapterInput
from fd_monitor.nodes.data_input import DataInput
from fd_monitor.nodes.inputs import Input
from fd_monitor.nodes.qos import DEFAULT_DEPTH
from fd_monitor.wire.conversions import ArrivalStamper, RawDecoder, readable_stamp
from fd_monitor.wire.hold import HOLD_WAIT, HeldPairing
from fd_monitor.wire.join import StampJoin
from fd_monitor.wire.stream import InputStream, SentTime, TopicOrder
from fd_monitor.wire.topics import RESET

__all__ = ["InputPath"]


class InputPath:
    """The inputs of a configured chain node (see the module docstring).

    Without a ``sequence`` input the node is the chain's entry: it declares holes (a
    rejected message, or a later stamp complete for ``gap_timeout`` s), checked on message
    arrival and on a timer.

    Parameters
    ----------
    node : FdNode
        Configured: ``params``, ``input_status``, its ``_run`` of a released sample (typed
        Any: fd_node imports this module, and the layers test refuses import cycles).
    inputs : sequence of Input
    gap_timeout : float, optional
        s (the entry only).
    """

    def __init__(self, node: Any, inputs: Sequence[Input],
                 gap_timeout: float | None = None) -> None:
        self.node = node
        self.inputs = tuple(inputs)
        params = node.params
        seq = [i.name for i in inputs if i.sequence]
        #: ``fd/reset`` publisher of a node that is not the entry (its ``~/reset`` asks the
        #: entry), else None (the entry subscribes to it)
        self.reset_pub: Any = None
        if seq:
            self.reset_pub = node.create_publisher(Empty, RESET.name, 10)
            node._entities.append(self.reset_pub)
        else:
            node._entities.append(node.create_subscription(Empty, RESET.name,
                                                           node._on_reset_request, 10))
        max_gap = int(getattr(params, "max_gap", 0))
        self.join = StampJoin([i.name for i in inputs if i.initial is None and not i.optional],
                              {i.name: i.initial for i in inputs if i.initial is not None},
                              params.max_pending, sequence=seq[0] if seq else None,
                              gap_timeout=None if seq else gap_timeout,
                              horizon=params.stamp_horizon,
                              restart_after=params.restart_after,
                              feedback_source=self.feedback_source,
                              max_gap=max_gap, max_lag=params.max_lag or None,
                              sample_time=float(node.system.sample_time),
                              batch_pace=params.batch_pace,
                              optional=[i.name for i in inputs if i.optional])
        node.input_status.join = self.join
        #: The input policy shared with offline reading (order check, join, release).
        self.stream = InputStream(self.join, node._run, node.input_status.note)
        self._stamper = ArrivalStamper()
        #: plain samples and the held inputs they are paired with (the one hold rule)
        self.pairing = HeldPairing([i.name for i in inputs if i.hold], HOLD_WAIT,
                                   DEFAULT_DEPTH)
        self.data_inputs: dict[str, DataInput] = {}
        # an adapter file (nodes whose parameters have one): the robot's topics give u and y
        self.adapter: AdapterInput | None = None
        if getattr(params, "adapter", ""):
            self.adapter = AdapterInput(node, params.adapter)
            node.input_status.adapter_join = self.adapter.join
            inputs = [i for i in inputs if i.name not in ("u", "y")]
        for inp in inputs:
            # with the MessageInfo: the DDS reception time (a load shed counts the lag of a
            # backlog held in DDS from it) and, for plain messages, the source time
            self.data_inputs[inp.name] = node.subscribe(inp.topic, self.callback(inp),
                                                        True, raw=True)
        self._open_loop: set[str] = set()
        # The hold rule's timer (a plain sample whose held input never comes is released
        # after HOLD_WAIT) starts with the first plain message: a stamped stream never waits,
        # and a 20 Hz timer costs an idle node's executor more than its samples' bookkeeping.
        self._hold_timer: Any = None
        # A hole, lost feedback or a new run must be declared even when no further message
        # arrives.
        period = min(0.25, max(0.01, min(gap_timeout or 1.0, params.restart_after) / 4))
        node._entities.append(node.create_timer(period, self._on_gap_timer))

    def reset(self) -> None:
        """Forget the stream (``~/reset``): the next complete sample starts a new run."""
        self.join.reset()
        if self.adapter is not None:
            self.adapter.reset()
        self.pairing.clear()

    def feedback_source(self, name: str) -> bool:
        """Whether a publisher of feedback input ``name`` is matched (the join waits for its
        feedback only then). A change is logged once: without the node that feeds it back
        (e.g. no bias_estimator) this node runs open loop at full rate."""
        sub = self.data_inputs[name].sub
        there = sub.get_publisher_count() > 0
        if there == (name in self._open_loop):
            topic = sub.topic_name
            log = self.node.get_logger()
            if there:
                self._open_loop.discard(name)
                log.info(f"{topic}: a publisher is here: waiting for its feedback again")
            else:
                self._open_loop.add(name)
                log.info(f"{topic}: no publisher: running without it (feedback at its "
                         f"initial value, an optional input absent) until one appears")
        return there

    def callback(self, inp: Input) -> Callable[..., None]:
        """The subscription callback of input ``inp``: serialized message (and, for a plain
        input, the DDS MessageInfo) -> decoded, paired or joined."""
        node, status = self.node, self.node.input_status
        stamper, pairing = self._stamper, self.pairing
        topic = node.resolve_topic_name(inp.topic)
        order = TopicOrder(topic)
        stream = self.stream
        sent = SentTime()
        # the restart and bridge flags of the sequence input, by field (resolved once)
        i_restart = inp.layout.index["restart"] if inp.sequence and inp.layout else None
        i_bridge = inp.layout.index["bridge"] if inp.sequence and inp.layout else None
        # serialized messages in, decoded without a message object (rclpy's deserializer
        # only for what the CDR parser leaves: big-endian)
        dec = RawDecoder(partial(deserialize_message, message_type=Float64MultiArray), topic,
                         labels=inp.labels, size=inp.size, require_stamp=not inp.plain_ok,
                         allow_nan=inp.allow_nan)

        def cb(raw: bytes, info: Any = None) -> None:
            if not node.active:
                node.inactive_dropped += 1
                return
            try:
                d = dec.decode(raw)
            except MessageError as exc:
                status.bad_input(str(exc))
                k = readable_stamp(dec.message(raw)) if inp.initial is None else None
                if k is not None:
                    stream.refused(k + inp.stamp_offset, time.monotonic())
                return
            if d.stamp is None:
                if self._hold_timer is None and pairing:
                    self._hold_timer = node.create_timer(HOLD_WAIT / 2, self._on_hold_timer)
                    node._entities.append(self._hold_timer)
                t = int(info["source_timestamp"]) if info is not None else time.time_ns()
                if inp.hold:
                    pairing.hold(inp.name, t, d.values)
                else:
                    d = stamper.stamp(d)
                    pairing.sample(t, time.monotonic(), (inp, int(d.stamp or 0), d.values))
                self.pair_plain()
                return
            now = time.monotonic()
            src = info["source_timestamp"] if info is not None else 0
            if src > 0:
                # when it was published (on our clock): the lag of a load shed counts from
                # then, wherever the message waited (the join, DDS, the publisher)
                wall = time.time_ns()
                arrived: float | None = sent.sent(src * 1e-9, (info["received_timestamp"]
                                                               or wall) * 1e-9, now, wall * 1e-9)
            else:
                arrived = None
            if stream.stamped(order, inp.name, int(d.stamp), d.values, now,
                              inp.stamp_offset, bool(inp.sequence and d.values[i_restart] > 0.5),
                              bool(inp.sequence and d.values[i_bridge] > 0.5), d.batch,
                              arrived):
                status.ok()
        return cb

    def pair_plain(self, now: float | None = None) -> None:
        """Pair each plain sample with the held inputs (``plant/u``) by the one hold rule
        (:class:`~fd_monitor.wire.hold.HeldPairing`: the latest held value published at or
        before it, by source timestamps) and join it; a sample with no held value before it
        is reported and not processed."""
        node = self.node
        for (inp, k, values), held, missing in self.pairing.pairs(now):
            for name, value in held.items():
                self.put(str(name), k, value)
            if missing:
                topics = [node.resolve_topic_name(i.topic) for i in self.inputs
                          if i.name in missing]
                node.input_status.bad_input(
                    f"{node.resolve_topic_name(inp.topic)} sample {k}: no "
                    f"{', '.join(topics)} received before it; sample not processed")
                self.stream.refused(k, time.monotonic())
                continue
            self.put(inp.name, k, values)

    def put(self, name: str, stamp: int, values: np.ndarray, restart: bool = False) -> None:
        """Join one decoded input; process every sample that became complete."""
        if self.stream.put(name, stamp, values, time.monotonic(), restart):
            self.node.input_status.ok()

    def _on_hold_timer(self) -> None:
        if self.node.active and self.pairing.waiting:
            self.pair_plain(time.monotonic())

    def _on_gap_timer(self) -> None:
        if self.node.active and (self.join.pending or self.join.held):
            self.drain()

    def drain(self) -> None:
        """Process every sample the join releases now; report holes and restarts."""
        self.stream.release(time.monotonic())
