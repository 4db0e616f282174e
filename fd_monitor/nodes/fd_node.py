"""Base of the diagnosis-chain nodes: parameters, plant and gains, joined inputs, diagnostics.

Each chain node (observer, detector, agei, bias_estimator) declares its inputs (topic,
expected labels, required or feedback with its initial value) and implements
``process(k, inputs)`` — message -> ``np.asarray`` -> core step -> message -> publish. This
base decodes and validates every message (:func:`~fd_monitor.nodes.conversions.decode`),
joins inputs on the stamp (:class:`~fd_monitor.nodes.join.StampJoin`), and reports on
``/diagnostics``: an ``input`` channel (OK; WARN with the reason of the last bad message;
STALE when no input came for ``stale_timeout`` s) plus the node's own channels. A bad message
is logged, reported, and dropped before it reaches the join: it never changes core state.

Feedback messages (``/fd/bias_estimate``, ``/fd/guard_event``, ``/fd/threshold_override``) are
stamped with the sample they are *for* (k + 1 when decided at k), so every join is on equal
stamps.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

from fd_monitor.errors import FdMonitorError, ImplausibleError, MessageError
from fd_monitor.gains import GainFile, load_gains
from fd_monitor.nodes.common import (
    DEFAULT_DEPTH,
    OK,
    WARN,
    Diagnostics,
    Param,
    data_pub_qos,
    data_sub_qos,
    declare_parameters,
    pub_events,
    sub_events,
)
from fd_monitor.nodes.conversions import ArrivalStamper, decode, readable_stamp, to_msg
from fd_monitor.nodes.join import Sample, StampJoin
from fd_monitor.system import System, load_system

__all__ = ["COMMON_PARAMS", "FdNode", "Input", "load_plant_and_gains"]

#: Gain-file methods the chain nodes can run; each node lists the ones it runs in its
#: ``runtimes`` (method -> name of the method that builds that runtime).
RUNTIMES = ("thresholds", "qb")

COMMON_PARAMS = (
    Param("system", "three_tank", "plant file, or the name of a shipped plant"),
    Param("gains", "three_tank_thresholds", "gain file (path or name in config/gains/); "
          "loaded and its certificate re-verified at start"),
    Param("stale_timeout", 2.0, "s without input before the input channel turns STALE",
          low=0.01, high=1.0e6),
    Param("diagnostics_period", 1.0, "s between /diagnostics publications", low=0.01,
          high=3600.0),
    Param("qos_depth", DEFAULT_DEPTH, "history depth of the publishers", low=10,
          high=1000000),
    Param("max_pending", 100000, "samples buffered while waiting for inputs", low=10,
          high=10000000),
)


@dataclass(frozen=True)
class Input:
    """One joined input of a node.

    Attributes
    ----------
    name : str
        Key in ``process``'s inputs.
    topic : str
    labels : tuple of str, optional
        Expected channel names (None: accept any, check ``size`` only).
    size : int, optional
    initial : object
        For feedback inputs: the value at the node's first sample; ``None`` = required.
    plain_ok : bool
        Accept unstamped messages (a user's driver), stamped on arrival.
    allow_nan : bool
        NaN is a value (``/fd/threshold_override``: no override).
    stamp_offset : int
        Joined at ``stamp + stamp_offset``: -1 for a feedback message (stamped k + 1) that
        is needed at the sample it was decided at (k).
    sequence : bool
        ``/fd/state_estimate`` of the entry node: its stamps are the samples this node
        processes and its last value (``restart``) flags a restart (downstream role of
        :class:`~fd_monitor.nodes.join.StampJoin`).
    """

    name: str
    topic: str
    labels: tuple[str, ...] | None = None
    size: int | None = None
    initial: Any = None
    plain_ok: bool = False
    allow_nan: bool = False
    stamp_offset: int = 0
    sequence: bool = False


def load_plant_and_gains(system_src: str, gains_src: str) -> tuple[System, GainFile]:
    """Load the plant and its gain file (certificate re-verified); one-line errors."""
    system = load_system(system_src)
    return system, load_gains(gains_src, system)


class FdNode(Node):
    """A chain node: subclasses set ``inputs`` and implement :meth:`process`.

    Parameters
    ----------
    node_name : str
    params : sequence of Param
        The node's own parameters (the common ones are added).
    system, gains : optional
        Injected plant and gain file (tests, composition); default from the parameters.
    qos : rclpy.qos.QoSProfile, optional
        Publisher QoS.
    **kwargs
        Passed to :class:`rclpy.node.Node`.
    """

    inputs: Sequence[Input] = ()
    #: Gain-file method -> name of the method building the node's runtime for it.
    runtimes: Mapping[str, str] = {}

    def __init__(self, node_name: str, params: Sequence[Param] = (),
                 system: System | None = None, gains: GainFile | None = None, qos=None,
                 **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = declare_parameters(self, (*COMMON_PARAMS, *params))
        if system is None or gains is None:
            system, gains = load_plant_and_gains(self.params.system, self.params.gains)
        self.system, self.gain_file = system, gains
        if gains.method not in self.runtimes:
            raise FdMonitorError(f"node {node_name}: {gains.path}: method {gains.method!r}: "
                                 f"{node_name} runs {' and '.join(self.runtimes)} gain files "
                                 f"only (qb designs run on observer + detector; design a "
                                 f"thresholds one with `python -m fd_monitor design "
                                 f"thresholds {system.name}`)")
        self._qos = qos if qos is not None else data_pub_qos(self.params.qos_depth)
        self.diag = Diagnostics(self, system.name, self.params.diagnostics_period)
        self.diag.add("input", self.params.stale_timeout, "no input yet")
        self.bad_messages = 0
        self.processed = 0
        self.holes = 0
        #: True while :meth:`process` handles a restart sample (first, or first after a hole).
        self.restarting = False
        # Reasons of the bad messages since the last /diagnostics publication: each one is
        # published (a burst in one status), and WARN holds for one period after the last.
        self._reasons: list[str] = []
        self._last_bad = -float("inf")
        self.diag.on_publish.append(self._reasons.clear)

    # -- set-up helpers for subclasses --------------------------------------------------------

    def start_runtime(self) -> None:
        """Build the runtime of the gain file's method (the one factory of the chain nodes)."""
        getattr(self, self.runtimes[self.gain_file.method])()

    def publisher(self, topic: str) -> Any:
        """A data-path publisher of Float64MultiArray."""
        return self.create_publisher(Float64MultiArray, topic, self._qos, **pub_events())

    def start_inputs(self, inputs: Sequence[Input], gap_timeout: float | None = None) -> None:
        """Subscribe to every input and set up the stamp join.

        Without a ``sequence`` input the node is the chain's entry: it declares holes (a
        rejected message, or a later stamp complete for ``gap_timeout`` s), checked on
        message arrival and on a timer.
        """
        self.inputs = tuple(inputs)
        seq = [i.name for i in inputs if i.sequence]
        self.join = StampJoin([i.name for i in inputs if i.initial is None],
                              {i.name: i.initial for i in inputs if i.initial is not None},
                              self.params.max_pending, sequence=seq[0] if seq else None,
                              gap_timeout=None if seq else gap_timeout)
        for inp in inputs:
            self.create_subscription(Float64MultiArray, inp.topic, self._callback(inp),
                                     data_sub_qos(), **sub_events())
        if not seq and gap_timeout is not None:
            # A hole must be declared even when no further message arrives.
            self.create_timer(min(0.25, max(0.01, gap_timeout / 4)), self._on_gap_timer)

    def _callback(self, inp: Input) -> Callable[[Any], None]:
        stamper = ArrivalStamper()
        order = _TopicOrder(inp.topic)

        def cb(msg: Any) -> None:
            try:
                d = stamper.stamp(decode(msg, inp.topic, labels=inp.labels, size=inp.size,
                                         require_stamp=not inp.plain_ok,
                                         allow_nan=inp.allow_nan))
            except MessageError as exc:
                self.bad_input(str(exc))
                k = readable_stamp(msg) if inp.initial is None else None
                if k is not None and k + inp.stamp_offset >= 0:
                    self.join.reject(k + inp.stamp_offset)
                    self._drain()
                return
            note = order.check(int(d.stamp or 0))
            if note is not None:
                self._warn(note)
                if "duplicate" in note:
                    return
            stamp = int(d.stamp or 0) + inp.stamp_offset
            if stamp >= 0:
                self.on_input(inp.name, stamp, d.values,
                              restart=inp.sequence and d.values[-1] > 0.5)
        return cb

    def bad_input(self, reason: str) -> None:
        """Log a rejected message and report it on /diagnostics (WARN); keep running."""
        self.bad_messages += 1
        self._warn(reason)

    def _warn(self, reason: str) -> None:
        """Log ``reason`` and report it on the ``input`` channel (WARN)."""
        self._last_bad = time.monotonic()
        self.get_logger().warning(reason)
        if len(self._reasons) < 10:
            self._reasons.append(reason)
        self.diag.update("input", WARN, "; ".join(self._reasons),
                         {"bad_messages": self.bad_messages, "holes": self.holes,
                          "processed": self.processed, "last_warning": reason})

    def on_input(self, name: str, stamp: int, values: np.ndarray,
                 restart: bool = False) -> None:
        """Join one decoded input; process every sample that became complete."""
        note = self.join.put(name, stamp, values, time.monotonic(), restart)
        if note is not None:
            self.bad_input(note)
            return
        self._drain()
        level = self.diag.level("input")
        if level == WARN and time.monotonic() - self._last_bad < self.diag.period:
            self.diag.touch("input")
        elif level != OK or self.processed % 50 == 0:
            if self._reasons:
                self.diag.publish()  # the reasons not published yet go out before OK
            self.diag.update("input", OK, "receiving", {
                "bad_messages": self.bad_messages, "processed": self.processed,
                "next_sample": self.join.k_next, "waiting_for": self.join.waiting_for()})
        else:
            self.diag.touch("input")

    def _on_gap_timer(self) -> None:
        if self.join.pending:
            self._drain()

    def _drain(self) -> None:
        """Process every sample the join releases now; report holes and restarts."""
        for s in self.join.ready(time.monotonic()):
            self._run(s)

    def _run(self, s: Sample) -> None:
        if s.hole is not None:
            self.holes += 1
            a, b = s.hole
            span = f"stamp {a}" if a == b else f"stamps {a}..{b}"
            self._warn(f"hole: no valid sample for {span}; restarted at {s.k} (fresh state, "
                       f"feedback at initial values)")
        if s.restart:
            self.reset()
        self.restarting = s.restart
        try:
            self.process(s.k, s.inputs)
        except ImplausibleError as exc:
            # Refused by the core (an implausible value): reported like a bad message and a
            # hole at k, so the next sample restarts the chain (core/plausibility.py).
            self.bad_input(str(exc))
            self.join.lost(s.k)
            return
        self.processed += 1

    def reset(self) -> None:
        """Reset the core component as :meth:`~fd_monitor.core.monitor.Monitor.reset` does
        (subclasses); called before every restart sample."""

    def process(self, k: int, inputs: dict[str, Any]) -> None:  # pragma: no cover
        """Process sample k (subclasses)."""
        raise NotImplementedError

    def publish_array(self, pub: Any, labels: Sequence[str], stamp: int, values: Any) -> None:
        """Publish one stamped, labelled message."""
        pub.publish(to_msg(labels, stamp, values))

    def gain_values(self) -> dict[str, str]:
        """Gain-file id and certificate status, for /diagnostics."""
        return {"gain_file": self.gain_file.id,
                "certificate": self.gain_file.certificate_status}


class _TopicOrder:
    """Per-topic duplicate and out-of-order detection, as :func:`fd_monitor.offline.read_inputs`
    reports them (a duplicate is dropped, the first kept; out of order is only reported)."""

    _MEMORY = 4096  # stamps remembered per topic

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.top: int | None = None
        self._seen: set[int] = set()
        self._order: deque[int] = deque()

    def check(self, k: int) -> str | None:
        """Record stamp k; a one-line report when it is a duplicate or out of order."""
        if k in self._seen:
            return f"{self.topic} stamp {k}: duplicate (first kept)"
        self._seen.add(k)
        self._order.append(k)
        if len(self._order) > self._MEMORY:
            self._seen.discard(self._order.popleft())
        top, self.top = self.top, k if self.top is None else max(self.top, k)
        if top is not None and k < top:
            return f"{self.topic} stamp {k} after stamp {top}: out of order"
        return None


def require(condition: bool, message: str) -> None:
    """Raise a start-up FdMonitorError unless ``condition``."""
    if not condition:
        raise FdMonitorError(message)
