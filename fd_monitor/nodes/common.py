"""Helpers shared by the fd_monitor nodes: QoS, parameters, diagnostics, flow control, main.

QoS and the lossless data path
------------------------------
Data topics (``plant/*``, ``fd/*``, relative to the node's namespace) are RELIABLE and
VOLATILE: publishers keep the last ``qos_depth`` samples for repairs only, a subscriber that
joins late gets nothing old (as with ROS's default profile). Subscriptions are KEEP_ALL,
RELIABLE, VOLATILE, so they meet ROS's default publishers (reliable, volatile) losslessly;
when a best-effort publisher (the sensor-data profile) appears, the incompatible-QoS event
names RELIABILITY and :class:`DataInput` re-creates the subscription as best effort (logged and
reported on ``/diagnostics``), which meets both kinds. Every policy can be overridden per
topic with ROS's ``qos_overrides.<topic>.subscription.<policy>`` parameters (then no
automatic switch happens). Sources that run flat out (``plant_sim`` with ``rate_factor:
0.0``, ``replay --rate 0``) wait until the expected subscribers are matched, then pace by
acknowledgements: after every ``ack_window`` (< ``qos_depth``) samples they block in
``Publisher.wait_for_all_acked`` so no unacknowledged sample is ever overwritten in the
writer's history. Together: no sample is lost, whatever the rate.

Acknowledgements travel on Fast DDS heartbeats, whose default period (3 s) would make each
wait last about a second; :func:`use_dds_profile` points Fast DDS at
``config/fastdds_pacing.xml`` (2 ms heartbeats) in such a source and at ``config/fastdds.xml``
(20 ms) in the other nodes, unless the user chose a profile file.

Why one module of ~730 lines: the helpers every node shares (QoS, parameters, diagnostics,
pacing, DDS profiles, help text, ``run_node``); issue 22 item 2 splits it into one file per
job, deferred while the nodes were being changed by other work.
"""

from __future__ import annotations

import gc
import os
import struct
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.duration import Duration
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSPolicyKind,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.serialization import serialize_message

from fd_monitor.model.errors import FdMonitorError, MessageError, WrongLengthError
from fd_monitor.model.paths import config_dirs
from fd_monitor.nodes.ros_args import init_ros, shown_params_file, take_node_name
from fd_monitor.wire.conversions import MAX_STAMP, to_msg
from fd_monitor.wire.topics import DIAGNOSTICS, Topic

__all__ = [
    "OK", "WARN", "ERROR", "STALE", "LEVEL_NAMES",
    "AckPacer",
    "DataInput",
    "Diagnostics",
    "MAX_MESSAGE",
    "WAITING",
    "default_hardware_id",
    "short_message",
    "NodeUsage",
    "Param",
    "SerializedArray",
    "data_pub_qos",
    "pub_events",
    "sub_events",
    "data_sub_qos",
    "declare_parameters",
    "diagnostics_qos",
    "run_node",
    "usage_text",
    "use_dds_profile",
    "wants_help",
]

OK: bytes = DiagnosticStatus.OK
WARN: bytes = DiagnosticStatus.WARN
ERROR: bytes = DiagnosticStatus.ERROR
STALE: bytes = DiagnosticStatus.STALE
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}

DEFAULT_DEPTH = 1000


def pub_events(incompatible: Callable[[Any], None] | None = None) -> dict[str, Any]:
    """``create_publisher`` keywords: only the incompatible-QoS handler, if given.

    rclpy's default handlers are off: each handler is one more entity in every wait set the
    executor builds, and rebuilding wait sets is most of a Python node's per-message cost.
    """
    return {"event_callbacks": PublisherEventCallbacks(incompatible_qos=incompatible,
                                                        use_default_callbacks=False)}


def sub_events(incompatible: Callable[[Any], None] | None = None) -> dict[str, Any]:
    """``create_subscription`` keywords: only the incompatible-QoS handler, if given."""
    return {"event_callbacks": SubscriptionEventCallbacks(incompatible_qos=incompatible,
                                                           use_default_callbacks=False)}


def data_pub_qos(depth: int = DEFAULT_DEPTH) -> QoSProfile:
    """Publisher QoS of the data path: reliable, volatile, keep last ``depth``."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth),
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def data_sub_qos(reliable: bool = True) -> QoSProfile:
    """Subscriber QoS of the data path: volatile; reliable keep-all (no drops), or best effort
    keep last :data:`DEFAULT_DEPTH` (meets best-effort publishers too)."""
    if reliable:
        return QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=1,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEFAULT_DEPTH,
                      reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


def incompatible_text(topic: str, side: str, info: Any) -> str:
    """One line for an incompatible-QoS event (``side``: "publisher" or "subscription")."""
    try:
        policy = QoSPolicyKind(int(info.last_policy_kind)).name
    except ValueError:
        policy = str(info.last_policy_kind)
    other = "a subscription" if side == "publisher" else "a publisher"
    return (f"{topic}: QoS incompatible with {other} (policy {policy}; "
            f"{int(info.total_count)} so far): our {side} cannot talk to it")


class SerializedArray:
    """Stamped, labelled Float64MultiArray messages of fixed labels, serialized directly.

    The message of :func:`~fd_monitor.wire.conversions.to_msg` serialized once (CDR, little
    endian); ``data`` is its last field, so a sample's message is that prefix (layout, data
    length) followed by ``[k, *values]`` packed as float64: what a publisher takes as
    serialized bytes, without a message object per sample (the node tests compare every
    published value).

    Parameters
    ----------
    labels : sequence of str
        (m,) channel names.
    """

    def __init__(self, labels: Sequence[str]) -> None:
        self.labels = tuple(labels)
        n = len(self.labels) + 1
        cdr = serialize_message(to_msg(self.labels, 0, [0.0] * len(self.labels)))
        self.prefix = cdr[:-8 * n]
        self._pack = struct.Struct(f"<{n}d").pack

    def encode(self, stamp: int, values: Any) -> bytes:
        """The serialized message ``[stamp, *values]``; ``values`` (m,) array or list."""
        if not 0 <= stamp < MAX_STAMP:
            raise MessageError(f"stamp {stamp!r} out of range [0, 2**53)")
        vals = values.tolist() if hasattr(values, "tolist") else values
        try:
            return self.prefix + self._pack(stamp, *vals)
        except struct.error:
            raise WrongLengthError(f"{len(self.labels)} labels for {len(vals)} values") from None


def with_message_info(sub: Any) -> None:
    """Have ``sub``'s executor pass the DDS MessageInfo with each message.

    rclpy picks the callback form from its signature, and a two-argument callback is what
    breaks its EventsExecutor in these wheels (``SystemError: null argument to internal
    routine``): that executor calls a MessageInfo subscription's callback with ONE argument,
    the tuple ``(msg, info)``, where the SingleThreadedExecutor passes two. So the callback
    takes ``*args`` (one argument: rclpy chooses message-only) and the subscription is then
    marked as wanting the MessageInfo (``_callback_type``, which both executors read at every
    message). Tested: ``test_nodes_chain`` (plain u, y published in a burst, paired by
    their source timestamps under the EventsExecutor).
    """
    sub._callback_type = type(sub).CallbackType.WithMessageInfo


class DataInput:
    """A data-path subscription that meets reliable and best-effort volatile publishers.

    Starts reliable, keep-all (lossless with acknowledgement pacing). ``qos_overrides``
    parameters (``qos_overrides.<topic>.subscription.reliability|history|depth``) apply at
    creation. When a publisher is incompatible on RELIABILITY (a best-effort publisher) and
    the user did not override the reliability, the subscription is re-created best effort;
    every incompatibility is passed to ``report`` (one line naming topic and policy).

    Parameters
    ----------
    node : rclpy.node.Node
    msg_type : type
    topic : str
        As given to ``create_subscription`` (relative names resolve in the namespace).
    callback : callable
    report : callable
        Called with one line per incompatible-QoS event or switch.
    raw : bool
        Serialized messages (record).
    with_info : bool
        ``callback(msg, info)`` with the DDS MessageInfo (``source_timestamp``, ns), under
        either executor (:func:`with_message_info`); else ``callback(msg)``.
    switched : callable, optional
        Called (no argument) once the switch to best effort is done: the incompatibility
        is handled.
    """

    def __init__(self, node: Node, msg_type: Any, topic: str, callback: Callable[..., None],
                 report: Callable[[str], None], raw: bool = False,
                 with_info: bool = False, switched: Callable[[], None] | None = None) -> None:
        self.node, self.msg_type, self.topic = node, msg_type, topic
        self.callback, self.report, self.raw = callback, report, raw
        self.switched = switched
        self.with_info = with_info
        self.name = node.resolve_topic_name(topic)
        want = data_sub_qos()
        self.sub = self._create(want, qos_overriding_options=(
            QoSOverridingOptions.with_default_policies()))
        self.reliable = self.sub.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        #: True when the user set the reliability (no automatic switch).
        self.overridden = self.sub.qos_profile.reliability != want.reliability
        self._switch_timer: Any = None

    def _on_incompatible(self, info: Any) -> None:
        line = incompatible_text(self.name, "subscription", info)
        policy = int(info.last_policy_kind)
        if (policy == QoSPolicyKind.RELIABILITY and self.reliable and not self.overridden
                and self._switch_timer is None):
            line += "; switching to best effort (meets every publisher)"
            # Not inside the subscription's own event callback: on the next executor turn.
            self._switch_timer = self.node.create_timer(0.0, self._switch)
        self.report(line)

    def _switch(self) -> None:
        self.node.destroy_timer(self._switch_timer)
        old = self.sub
        self.sub = self._create(data_sub_qos(reliable=False))
        self.node.destroy_subscription(old)
        self.reliable = False
        self._switch_timer = None
        if self.switched is not None:
            self.switched()

    def _create(self, qos: QoSProfile, **kwargs: Any) -> Any:
        if not self.with_info:
            return self.node.create_subscription(self.msg_type, self.topic, self.callback, qos,
                                                 raw=self.raw, **kwargs,
                                                 **sub_events(self._on_incompatible))
        callback = self.callback

        def deliver(*args: Any) -> None:
            # SingleThreadedExecutor: (msg, info); EventsExecutor: ((msg, info),)
            callback(*(args if len(args) == 2 else args[0]))
        sub = self.node.create_subscription(self.msg_type, self.topic, deliver, qos,
                                           raw=self.raw, **kwargs,
                                           **sub_events(self._on_incompatible))
        with_message_info(sub)
        return sub

    def destroy(self) -> None:
        """Destroy the subscription (lifecycle cleanup)."""
        if self._switch_timer is not None:
            self.node.destroy_timer(self._switch_timer)
        self.node.destroy_subscription(self.sub)


def diagnostics_qos() -> QoSProfile:
    """``/diagnostics`` QoS: reliable, volatile, keep last 100 (like diagnostic_updater)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


# -- parameters ------------------------------------------------------------------------------

@dataclass(frozen=True)
class Param:
    """One node parameter: name, default (fixes the type), description, range.

    Attributes
    ----------
    name : str
    default : bool, int, float, str or list
    description : str
    read_only : bool
        Read at start only (changing it later would have no effect).
    low, high : float, optional
        Inclusive range of a numeric parameter.
    choices : tuple of str
        The values a string parameter may take (empty: any), checked at declaration,
        before the node configures.
    """

    name: str
    default: Any
    description: str
    read_only: bool = True
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()

    def descriptor(self) -> ParameterDescriptor:
        """The ParameterDescriptor declared with the parameter."""
        d = ParameterDescriptor(name=self.name, description=self.description,
                                read_only=self.read_only)
        if self.low is not None and self.high is not None:
            if isinstance(self.default, bool):
                pass
            elif isinstance(self.default, int):
                d.integer_range = [IntegerRange(from_value=int(self.low),
                                                to_value=int(self.high), step=0)]
            elif isinstance(self.default, float):
                d.floating_point_range = [FloatingPointRange(from_value=float(self.low),
                                                             to_value=float(self.high),
                                                             step=0.0)]
        return d


def declare_parameters(node: Node, params: Iterable[Param]) -> SimpleNamespace:
    """Declare every parameter with its descriptor; return their values as attributes.

    A parameter the node's parameter files (or ``-p``) set that it does not declare is
    warned about once, all named in one line (a typo would otherwise be ignored).

    Raises
    ------
    FdMonitorError
        One line naming the node and the parameter when an override has the wrong type, is
        out of range (e.g. ``rate_factor:=1`` for a double: write ``1.0``) or not one of
        its ``choices``.
    """
    out = SimpleNamespace()
    params = tuple(params)
    declared = {p.name for p in params}
    unknown = sorted(n for n in getattr(node, "_parameter_overrides", {})
                     if n not in declared and not node.has_parameter(n)
                     and n not in _ROS_PARAMETERS and not n.startswith("qos_overrides."))
    if unknown:
        node.get_logger().warning(
            f"parameter file sets {', '.join(unknown)}, which node {node.get_name()} does not "
            f"declare: ignored (a typo? `--help` lists its parameters)")
    for p in params:
        try:
            node.declare_parameter(p.name, p.default, p.descriptor())
        except rclpy.exceptions.ParameterException as exc:
            raise FdMonitorError(f"node {node.get_name()}: parameter {p.name}: {exc} "
                                 f"(expected {type(p.default).__name__}, default "
                                 f"{p.default!r})") from None
        value = node.get_parameter(p.name).value
        if p.choices and value not in p.choices:
            raise FdMonitorError(f"node {node.get_name()}: parameter {p.name}: {value!r}: "
                                 f"expected one of {', '.join(p.choices)}")
        setattr(out, p.name, value)
    return out


#: Parameters rclpy itself declares on every node (not a typo when a file sets them).
_ROS_PARAMETERS = frozenset({"use_sim_time", "start_type_description_service"})


# -- diagnostics -----------------------------------------------------------------------------

@dataclass
class _Channel:
    level: bytes
    message: str
    values: dict[str, Any]
    last_input: float | None
    stale_timeout: float | None
    keep_on_stale: bool = False
    stale: bool = False
    #: its level changed since the last publication
    unpublished: bool = False
    #: the channel whose staleness this one shares (a channel without input of its own)
    follows: str | None = None
    #: (level, message) before it went STALE with the channel it follows
    before_stale: tuple[bytes, str] | None = None


#: Longest ``message`` published; a longer one is published as its first clause, the full
#: text going into the ``detail`` value (``ros2 topic echo`` cuts strings at 128 characters,
#: and a status line in rqt_robot_monitor or an aggregator's summary is one line).
MAX_MESSAGE = 120

#: The message of every channel before its first input (an idle node is healthy: OK).
WAITING = "waiting for input"


def short_message(message: str) -> tuple[str, str | None]:
    """``(message, detail)``: ``message`` itself when short enough, else its first clause
    (up to ``"; "``), or its first :data:`MAX_MESSAGE` characters, marked as continued, and
    the full text as ``detail``."""
    if len(message) <= MAX_MESSAGE:
        return message, None
    head = message.split("; ", 1)[0]
    if len(head) > MAX_MESSAGE - 16:
        head = head[:MAX_MESSAGE - 16].rstrip()
    return head + " (see detail)", message


def default_hardware_id(node: Node, plant: str, given: str = "") -> str:
    """``hardware_id`` of a node's statuses: ``given``, else ``<namespace>/<plant>``
    (``robot1/three_tank``; the plant alone in the root namespace), so two robots running the
    same plant are told apart by an aggregator."""
    if given:
        return given
    ns = node.get_namespace().strip("/")
    return f"{ns}/{plant}" if ns else plant


#: s: level changes are published at once, but at most this often (bursts are merged).
BURST_INTERVAL = 0.1


class Diagnostics:
    """Per-channel DiagnosticStatus on ``/diagnostics``, shaped like diagnostic_updater.

    Each channel has a level, a message and key/value strings. The array is published every
    ``period`` s exactly (a timer of that period) and when a channel's level changes (at
    most every :data:`BURST_INTERVAL` s: a burst of changes goes out as one array). A
    channel starts OK, :data:`WAITING` (an idle node is healthy; an aggregator's group with
    some STALE and some other statuses reads ERROR). A channel with a stale timeout turns
    STALE when input flowed and then :meth:`update`/:meth:`touch` has not been called for
    that long (checked on a timer against ``clock``); a channel that ``follows`` another
    (no input of its own: ``ros graph``) turns STALE with it and gets its status back when
    that one is fresh again, so a stopped node is STALE as a whole. A ``keep_on_stale``
    channel (a fault found) keeps its level, message and values when its input stops; its
    message says the input stopped and ``stale`` = true is added. :meth:`set_inactive`
    (lifecycle deactivate) shows every channel ``inactive`` (no staleness while inactive).
    A message longer than :data:`MAX_MESSAGE` goes out as its first clause, the full text in
    the ``detail`` value (:func:`short_message`).

    Status names are ``<node's full name>: <channel>`` (``/robot1/detector: residual h1``).

    Parameters
    ----------
    node : rclpy.node.Node
    hardware_id : str
        :func:`default_hardware_id` (``<namespace>/<plant>``) or the node's parameter.
    period : float
        s between periodic publications.
    clock : callable, optional
        Monotonic seconds; default ``time.monotonic``.
    """

    def __init__(self, node: Node, hardware_id: str, period: float = 1.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._node = node
        self._hardware_id = hardware_id
        self._clock = clock
        self._channels: dict[str, _Channel] = {}
        self._pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS.name, diagnostics_qos(),
                                         **pub_events())
        self._last_publish = -float("inf")
        self._dirty = False
        self.period = float(period)
        #: Called after every publication (e.g. to start a new list of reasons).
        self.on_publish: list[Callable[[], None]] = []
        self._timers: list[Any] = []
        self._start_timers()

    def _start_timers(self) -> None:
        for t in self._timers:
            self._node.destroy_timer(t)
        self._timers = [self._node.create_timer(self.period, self.publish),
                        self._node.create_timer(min(self.period / 4, BURST_INTERVAL),
                                                self._on_check)]

    def set_period(self, period: float) -> None:
        """Change the publication period (takes effect now)."""
        self.period = float(period)
        self._start_timers()

    def set_stale_timeout(self, timeout: float) -> None:
        """Change the stale timeout of every channel that has one."""
        for ch in self._channels.values():
            if ch.stale_timeout is not None:
                ch.stale_timeout = float(timeout)

    def destroy(self) -> None:
        """Stop the timers and the publisher (lifecycle cleanup)."""
        for t in self._timers:
            self._node.destroy_timer(t)
        self._timers = []
        self._node.destroy_publisher(self._pub)

    def add(self, channel: str, stale_timeout: float | None = None,
            message: str = WAITING, keep_on_stale: bool = False,
            follows: str | None = None) -> None:
        """Add a channel, OK with ``message`` until its first update; with ``stale_timeout``
        it turns STALE when its input stops after it flowed; ``follows``: it turns STALE with
        that channel."""
        self._channels[channel] = _Channel(OK, message, {}, None, stale_timeout,
                                           keep_on_stale, follows=follows)

    def set_inactive(self, message: str) -> None:
        """Every channel OK with ``message`` (lifecycle: inactive), except a kept fault
        (``keep_on_stale`` and not OK: its level stays, ``message`` appended); no staleness
        until :meth:`set_waiting`."""
        for ch in self._channels.values():
            ch.last_input, ch.stale, ch.before_stale = None, False, None
            if ch.keep_on_stale and ch.level != OK:
                ch.message = f"{ch.message.split(' (')[0]} ({message})"
            else:
                ch.level, ch.message = OK, message
            ch.unpublished = True
        self._changed()

    def set_waiting(self, message: str = WAITING,
                    messages: dict[str, str] | None = None) -> None:
        """Every channel that is not a kept fault back to OK ``message`` (``messages``: per
        channel; activated: no input yet, no staleness before the first)."""
        for name, ch in self._channels.items():
            ch.last_input, ch.stale, ch.before_stale = None, False, None
            if not (ch.keep_on_stale and ch.level != OK):
                ch.level, ch.message = OK, (messages or {}).get(name, message)
            ch.unpublished = True
        self._changed()

    def update(self, channel: str, level: bytes, message: str,
               values: dict[str, Any] | None = None) -> None:
        """Set a channel's status (fresh input); publish soon on a level change.

        A level that was never published is published before another replaces it: a WARN
        set and cleared within one burst interval (a busy node working through a backlog)
        still reaches /diagnostics.
        """
        ch = self._channels[channel]
        if ch.before_stale is not None:
            # a following channel while its leader is stale: shown when the leader is fresh
            ch.before_stale = (level, message)
            ch.message = f"{message} (input stopped)"
            if values is not None:
                ch.values = dict(values)
            return
        changed = ch.level != level
        if changed and ch.unpublished:
            self.publish()
        ch.level, ch.message, ch.stale = level, message, False
        if values is not None:
            ch.values = dict(values)  # formatted when published (keeps callbacks cheap)
        ch.last_input = self._clock()
        if changed:
            ch.unpublished = True
            self._changed()

    def touch(self, channel: str) -> None:
        """Mark fresh input on a channel without changing its status."""
        ch = self._channels[channel]
        ch.last_input = self._clock()
        ch.stale = False

    def level(self, channel: str) -> bytes:
        """The current level of a channel."""
        return self._channels[channel].level

    def _changed(self) -> None:
        if self._clock() - self._last_publish >= BURST_INTERVAL:
            self.publish()
        else:
            self._dirty = True

    def _on_check(self) -> None:
        now = self._clock()
        for ch in self._channels.values():
            if ch.follows is not None:
                self._follow(ch)
            if ch.stale_timeout is None or ch.level == STALE or ch.stale:
                continue
            if ch.last_input is not None and now - ch.last_input > ch.stale_timeout:
                note = f"no input for more than {ch.stale_timeout:g} s"
                if ch.keep_on_stale and ch.level != OK:
                    ch.message = f"{ch.message} (input stopped: {note})"
                    ch.stale = True
                else:
                    ch.level, ch.message = STALE, note
                self._dirty = True
        if self._dirty and now - self._last_publish >= BURST_INTERVAL:
            self.publish()

    def _follow(self, ch: _Channel) -> None:
        """A following channel: STALE with its leader, its own status back after."""
        lead = self._channels[ch.follows or ""]
        lead_stale = lead.level == STALE or lead.stale
        if lead_stale and ch.before_stale is None:
            ch.before_stale = (ch.level, ch.message)
            ch.level, ch.message = STALE, f"{ch.message} (input stopped)"
            self._dirty = True
        elif not lead_stale and ch.before_stale is not None:
            if ch.level == STALE:
                ch.level, ch.message = ch.before_stale
            ch.before_stale = None
            self._dirty = True

    def publish(self) -> None:
        """Publish every channel's status now."""
        arr = DiagnosticArray()
        arr.header.stamp = self._node.get_clock().now().to_msg()
        prefix = self._node.get_fully_qualified_name()
        for name, ch in self._channels.items():
            st = DiagnosticStatus()
            st.level = ch.level
            st.name = f"{prefix}: {name}"
            st.message, detail = short_message(ch.message)
            st.hardware_id = self._hardware_id
            values = {**ch.values, "stale": True} if ch.stale else ch.values
            if detail is not None:
                values = {**values, "detail": detail}
            st.values = [KeyValue(key=str(k), value=_text(v)) for k, v in values.items()]
            arr.status.append(st)
        self._pub.publish(arr)
        self._last_publish = self._clock()
        self._dirty = False
        for ch in self._channels.values():
            ch.unpublished = False
        for cb in self.on_publish:
            cb()


def _text(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_text(e) for e in v) + "]"
    if hasattr(v, "tolist"):
        return _text(v.tolist())
    return str(v)


# -- flow control ----------------------------------------------------------------------------

class AckPacer:
    """Block every ``window`` publications until every matched reader acknowledged.

    Parameters
    ----------
    publishers : sequence of rclpy.publisher.Publisher
    window : int
        Publications between waits; must be below the publishers' history depth so no
        unacknowledged sample can be overwritten.
    timeout : float
        s to wait for acknowledgements before giving up (a reader that vanished).
    """

    def __init__(self, publishers: Sequence[Any], window: int, timeout: float = 10.0) -> None:
        self.publishers = list(publishers)
        self.window = max(1, int(window))
        self.timeout = Duration(seconds=float(timeout))
        self._count = 0

    def published(self) -> bool:
        """Count one publication round; wait at the end of a window. False on timeout."""
        self._count += 1
        if self._count % self.window:
            return True
        return self.flush()

    def flush(self) -> bool:
        """Wait until every publisher's samples are acknowledged. False on timeout."""
        return all(p.wait_for_all_acked(self.timeout) for p in self.publishers)


def wait_for_subscribers(publishers: Sequence[tuple[Any, int]]) -> bool:
    """True when every ``(publisher, n)`` has at least ``n`` matched subscriptions."""
    return all(p.get_subscription_count() >= n for p, n in publishers)


# -- DDS profile -----------------------------------------------------------------------------

_PROFILE_VARS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


#: fd_monitor's Fast DDS profiles: nodes, and sources that pace by acknowledgements.
PROFILES = {False: "fastdds.xml", True: "fastdds_pacing.xml"}


def use_dds_profile(pacing: bool = False) -> str | None:
    """Point Fast DDS at one of fd_monitor's profiles before rclpy starts.

    ``pacing`` (``plant_sim``, ``replay``: sources that wait for acknowledgements):
    ``config/fastdds_pacing.xml``, 2 ms heartbeats, so each wait lasts milliseconds. Else
    ``config/fastdds.xml``, 20 ms heartbeats: a lost sample is still repaired within tens of
    milliseconds, and a node's writers do not pay 500 heartbeats a second each (the
    four-process chain spent 0.7 ms of CPU per sample on them: README, "Measured").

    Does nothing when the user set a profile file already (one not of fd_monitor), or when
    the XML is not found. Child processes inherit it (and choose again). Returns the profile
    in force, if any.
    """
    dirs = list(config_dirs())
    ours = {str(d / name) for d in dirs for name in PROFILES.values()}
    for var in _PROFILE_VARS:
        if os.environ.get(var) and os.environ[var] not in ours:
            return os.environ[var]
    for d in dirs:
        xml = d / PROFILES[pacing]
        if xml.is_file():
            for var in _PROFILE_VARS:
                os.environ[var] = str(xml)
            return str(xml)
    return None


# -- usage -----------------------------------------------------------------------------------

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


# -- main ------------------------------------------------------------------------------------

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
    (``-r __node:=NAME``) is taken out of the ROS arguments
    (:func:`~fd_monitor.nodes.ros_args.take_node_name`) and passed as
    ``factory(node_name=NAME)``, which names its nodes from it. At the end every lifecycle
    node goes through its shutdown transition (``finish()``: one log line) before it is
    destroyed. Start-up errors (``FdMonitorError``: bad gain file, bad scenario, bad
    parameter) print one line ``<prog>: error: ...`` and return 2. SIGINT/SIGTERM end
    cleanly (KeyboardInterrupt / ExternalShutdownException), then ``destroy_node()`` and
    ``rclpy.try_shutdown()``, as the ROS 2 demos do.
    """
    if wants_help(args):
        sys.stdout.write(usage_text(prog, usage))
        return 0
    use_dds_profile(pacing)
    name = None
    if named:
        args, name = take_node_name(sys.argv if args is None else args)
    try:
        init_ros(args)
    except FdMonitorError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    nodes: list[Node] = []
    try:
        made = factory(node_name=name) if name else factory()
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
            while rclpy.ok() and (done is None or not done.done()):
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
