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
from typing import Any

import numpy as np
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from fd_monitor.core.verdict import FaultVerdict, VerdictOutput, VerdictRule
from fd_monitor.nodes.diagnostics import ERROR, OK, Diagnostics
from fd_monitor.nodes.serialized import SerializedArray
from fd_monitor.wire.topics import FAULT, Layout, fault_layout

__all__ = ["FaultReport", "fault_qos", "fault_report"]


def fault_qos() -> QoSProfile:
    """``fd/fault`` QoS: reliable, transient local, keep last 1 (a latched state)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


class FaultReport:
    """The fault verdict of a node: stepped per sample, published on ``fd/fault`` and
    reported as the ``fault`` status when it changes (held by the node: monitor,
    bias_estimator).

    Parameters
    ----------
    pub : rclpy.publisher.Publisher
        ``fd/fault`` (:func:`fault_qos`).
    diag : Diagnostics
        The ``fault`` channel is added to it.
    logger : rclpy logger
    rule : VerdictRule
        From the node's ``fault_*`` parameters (:meth:`VerdictRule.in_seconds`).
    channels : sequence of str
        The verdict's channels.
    significance : array_like, optional
        (m,) |estimate| that counts as evidence; None without an estimator.
    stale_timeout : float, optional
        s without a sample before the status is marked stale (it keeps its level).
    """

    status = "fault"

    def __init__(self, pub: Any, diag: Diagnostics, logger: Any, rule: VerdictRule,
                 channels: Sequence[str], significance: Any = None,
                 stale_timeout: float | None = None) -> None:
        self.pub, self.diag, self.logger = pub, diag, logger
        self.verdict = FaultVerdict(len(channels), rule, significance)
        self.names = list(channels)
        self.layout: Layout = fault_layout(channels)
        self._ser = SerializedArray(self.layout.labels)
        self._faulty_before: list[str] = []
        diag.add(self.status, stale_timeout, keep_on_stale=True)

    def reset(self) -> None:
        """No fault (a new run)."""
        self.verdict.reset()
        self._faulty_before = []

    def step(self, k: int, alarm: Any, estimate: Any = None,
             isolated: Any = None) -> VerdictOutput:
        """Step the verdict with sample ``k``; publish and report it when it changed."""
        out = self.verdict.step(k, alarm, estimate, isolated)
        if not out.changed:
            self.diag.touch(self.status)
            return out
        self.pub.publish(self._ser.encode(k, self.layout.encode(out.payload())))
        faulty = out.faulty(self.names)
        values: dict[str, Any] = {"sample": k}
        for i, c in enumerate(self.names):
            values[f"{c} fault"] = bool(out.fault[i])
            values[f"{c} since"] = int(out.since[i])
            values[f"{c} isolated"] = bool(out.isolated[i])
            if not np.isnan(out.estimate[i]):
                values[f"{c} estimate"] = float(out.estimate[i])
        if faulty != self._faulty_before:
            if faulty:
                self.logger.warning(f"fault verdict at sample {k}: {self.text(out)}")
            else:
                self.logger.info(f"fault verdict at sample {k}: no fault (evidence gone for "
                                 f"{self.verdict.rule.clear_after} samples)")
        self._faulty_before = faulty
        if faulty:
            self.diag.update(self.status, ERROR, self.text(out), values)
        else:
            self.diag.update(self.status, OK, "no fault", values)
        return out

    def text(self, out: VerdictOutput) -> str:
        """``fault on h1 (since sample 42, isolated)`` for every channel at fault."""
        parts = []
        for i, c in enumerate(self.names):
            if out.fault[i]:
                iso = ", isolated" if out.isolated[i] else ""
                parts.append(f"{c} (since sample {int(out.since[i])}{iso})")
        return "fault on " + ", ".join(parts)


def fault_report(node: Any, channels: Sequence[str], significance: Any = None) -> FaultReport:
    """The :class:`FaultReport` of a configured chain node (an
    :class:`~fd_monitor.nodes.fd_node.FdNode`): its rule from the node's ``fault_*``
    parameters and plant sample time, its ``fd/fault`` publisher made by the node (so the
    node's second-publisher check and cleanup cover it)."""
    p = node.params
    rule = VerdictRule.in_seconds(node.system.sample_time, p.fault_confirm, p.fault_window,
                                  p.fault_clear_after)
    pub = node.publisher(FAULT, fault_qos(), cause=f"qos {node.resolve_topic_name(FAULT.name)}")
    return FaultReport(pub, node.diag, node.get_logger(), rule, channels, significance,
                       p.stale_timeout)
