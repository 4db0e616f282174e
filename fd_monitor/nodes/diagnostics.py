"""``/diagnostics``: per-channel DiagnosticStatus of a node, shaped like diagnostic_updater
(levels, short messages, staleness, bursts merged).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from fd_monitor.nodes.qos import (
    diagnostics_qos,
    pub_events,
)
from fd_monitor.wire.topics import DIAGNOSTICS

__all__ = ["OK", "WARN", "ERROR", "STALE", "LEVEL_NAMES", "BURST_INTERVAL", "Diagnostics",
           "MAX_MESSAGE", "WAITING", "default_hardware_id", "short_message"]


OK: bytes = DiagnosticStatus.OK
WARN: bytes = DiagnosticStatus.WARN
ERROR: bytes = DiagnosticStatus.ERROR
STALE: bytes = DiagnosticStatus.STALE
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}

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

    def touch_all(self, channels: Sequence[str]) -> None:
        """:meth:`touch` each of ``channels`` (one clock reading for all: a node marking its
        channels fresh at every sample)."""
        now = self._clock()
        chs = self._channels
        for name in channels:
            ch = chs[name]
            ch.last_input = now
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
