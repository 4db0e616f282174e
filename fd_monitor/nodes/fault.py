"""``fd/fault``: the latched fault verdict of a node (monitor, bias_estimator), published and
reported.

The decision is :class:`fd_monitor.core.verdict.FaultVerdict` (pure, stepped on the
runtime's alarms, estimates and isolation flags); this module only builds it from the node's
parameters (``fault_confirm``, ``fault_window``, ``fault_clear_after``), publishes its
output on ``fd/fault`` when it changes (reliable, transient local, depth 1: a subscriber that
joins later gets the verdict in force at once) and reports it on ``/diagnostics`` as the
``fault`` status: OK ``no fault``, ERROR ``fault on h1 since sample 42 ...`` (kept, marked
stale, when the input stops).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray

from fd_monitor.core.verdict import FaultVerdict, VerdictOutput, VerdictRule
from fd_monitor.model.system import System
from fd_monitor.nodes.diagnostics import ERROR, OK, Diagnostics
from fd_monitor.nodes.qos import incompatible_text, pub_events
from fd_monitor.wire.topics import FAULT, Layout, fault_layout

__all__ = ["FaultHost", "FaultReport", "fault_qos"]


def fault_qos() -> QoSProfile:
    """``fd/fault`` QoS: reliable, transient local, keep last 1 (a latched state)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


class FaultHost(Protocol):
    """What :class:`FaultReport` needs of its node (a protocol: mypy checks each host)."""

    params: Any
    system: System
    diag: Diagnostics
    fault_status: str
    verdict: FaultVerdict
    _fault_names: list[str]
    _fault_layout: Layout
    _fault_pub: Any
    _faulty_before: list[str]
    _entities: list[Any]
    _pubs: list[Any]

    def _graph_note(self, line: str, cause: str | None = None) -> None: ...
    def publish_array(self, pub: Any, labels: Sequence[str], stamp: int,
                      values: Any) -> None: ...
    def get_logger(self) -> Any: ...
    def fault_text(self, out: VerdictOutput) -> str: ...


class FaultReport:
    """The fault verdict of a chain node (a mixin of :class:`~fd_monitor.nodes.fd_node.FdNode`
    subclasses; :class:`FaultHost`)."""

    fault_status = "fault"
    verdict: FaultVerdict
    _fault_names: list[str]
    _fault_layout: Layout
    _fault_pub: Any
    _faulty_before: list[str]

    def start_verdict(self: FaultHost, channels: Sequence[str],
                      significance: Any = None) -> None:
        """Build the verdict for ``channels`` (at configure; ``significance``: (m,) |estimate|
        that counts as evidence, None without an estimator), its publisher and status."""
        p = self.params
        rule = VerdictRule.in_seconds(self.system.sample_time, p.fault_confirm,
                                      p.fault_window, p.fault_clear_after)
        self.verdict = FaultVerdict(len(channels), rule, significance)
        self._fault_names = list(channels)
        self._fault_layout = fault_layout(channels)
        node: Any = self                        # an rclpy Node
        name = node.resolve_topic_name(FAULT.name)
        self._fault_pub = node.create_publisher(
            Float64MultiArray, FAULT.name, fault_qos(),
            **pub_events(lambda info: self._graph_note(
                incompatible_text(name, "publisher", info), f"qos {name}")))
        self._entities.append(self._fault_pub)
        self._pubs.append(self._fault_pub)
        self.diag.add(self.fault_status, self.params.stale_timeout, keep_on_stale=True)

    def reset_verdict(self: FaultHost) -> None:
        """No fault (a new run)."""
        verdict = getattr(self, "verdict", None)
        if verdict is not None:
            verdict.reset()
        self._faulty_before: list[str] = []

    def step_verdict(self: FaultHost, k: int, alarm: Any, estimate: Any = None,
                     isolated: Any = None) -> VerdictOutput:
        """Step the verdict with sample ``k``; publish and report it when it changed."""
        out = self.verdict.step(k, alarm, estimate, isolated)
        if not out.changed:
            self.diag.touch(self.fault_status)
            return out
        lay = self._fault_layout
        self.publish_array(self._fault_pub, lay.labels, k, lay.encode(out.payload()))
        faulty = out.faulty(self._fault_names)
        values: dict[str, Any] = {"sample": k}
        for i, c in enumerate(self._fault_names):
            values[f"{c} fault"] = bool(out.fault[i])
            values[f"{c} since"] = int(out.since[i])
            values[f"{c} isolated"] = bool(out.isolated[i])
            if not np.isnan(out.estimate[i]):
                values[f"{c} estimate"] = float(out.estimate[i])
        if faulty != getattr(self, "_faulty_before", []):
            log = self.get_logger()
            if faulty:
                log.warning(f"fault verdict at sample {k}: {self.fault_text(out)}")
            else:
                log.info(f"fault verdict at sample {k}: no fault (evidence gone for "
                         f"{self.verdict.rule.clear_after} samples)")
        self._faulty_before = faulty
        if faulty:
            self.diag.update(self.fault_status, ERROR, self.fault_text(out), values)
        else:
            self.diag.update(self.fault_status, OK, "no fault", values)
        return out

    def fault_text(self: FaultHost, out: VerdictOutput) -> str:
        """``fault on h1 (since sample 42, isolated)`` for every channel at fault."""
        parts = []
        for i, c in enumerate(self._fault_names):
            if out.fault[i]:
                iso = ", isolated" if out.isolated[i] else ""
                parts.append(f"{c} (since sample {int(out.since[i])}{iso})")
        return "fault on " + ", ".join(parts)
