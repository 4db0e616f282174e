"""``monitor``: the diagnosis chain as one node (default), or the four chain nodes on one
executor (``layout:=chain``).

**fused** (default): one lifecycle node joins ``/plant/u`` and ``/plant/y`` on the stamp
(plain messages from a driver are stamped on arrival, as the observer does), calls the
runtime once per sample (:meth:`fd_monitor.core.monitor.Monitor.step`: observer, detector,
AGEI, bias estimator, feedback inside the call) and publishes what the four-node chain
publishes, same topics, same layouts, same bits: ``/fd/state_estimate``, ``/fd/residual``,
``/fd/threshold``, ``/fd/alarm`` (stamp k), ``/fd/guard_event``, ``/fd/threshold_override``,
``/fd/bias_estimate`` (stamp k + 1: decided at k for k + 1), and ``/diagnostics`` (input,
ros graph, estimate, one ``residual <out>`` per output, tracker, bias estimate). One join and
seven publications per sample instead of four joins, seven publications and six
subscriptions: what makes the live path keep up at kHz rates (README, "Measured").

**any other gain file** (qb, hinf_sc, hminus_switched): the fused
:class:`~fd_monitor.nodes.runtime_node.RuntimeNode` (the registry's runtime, generic
outputs), whatever the layout.

**chain**: the four nodes ``observer``, ``detector``, ``agei`` and ``bias_estimator`` on one
executor in one process, each with its own name, parameters and diagnostics: the distributed
form of the chain in one process (bit-identical to the fused node).

The executor is rclpy's EventsExecutor driven by a ``spin_once`` loop (its ``spin()`` does
nothing in these wheels); see :func:`fd_monitor.nodes.common.run_node`.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from typing import Any

from fd_monitor.core.monitor import Monitor, MonitorOutput
from fd_monitor.model.errors import FdMonitorError
from fd_monitor.nodes import agei, bias_estimator, detector, observer, runtime_node
from fd_monitor.nodes.adapter_input import ADAPTER_PARAM
from fd_monitor.nodes.agei import AgeiNode
from fd_monitor.nodes.bias_estimator import BiasEstimatorNode, BiasReport
from fd_monitor.nodes.common import OK, NodeUsage, Param, SerializedArray, run_node
from fd_monitor.nodes.detector import DetectorNode, ResidualReport
from fd_monitor.nodes.fd_node import (
    COMMON_PARAMS,
    GAP_TIMEOUT,
    WARN_SHARE,
    FdNode,
    Input,
)
from fd_monitor.nodes.observer import EstimateReport, ObserverNode
from fd_monitor.nodes.runtime_node import RuntimeNode, gain_method
from fd_monitor.wire.topics import (
    ALARM,
    BIAS_ESTIMATE,
    CHAIN_OUTPUTS,
    DIAGNOSTICS,
    GUARD_EVENT,
    PLANT_U,
    PLANT_Y,
    RESIDUAL,
    STATE_ESTIMATE,
    THRESHOLD,
    THRESHOLD_OVERRIDE,
)

__all__ = ["MonitorNode", "USAGE", "make_chain", "make_nodes", "main"]

LAYOUTS = ("fused", "chain")

#: s between two full diagnostics reports of the fused node while nothing changes.
DIAG_REFRESH = 0.1

PARAMS = (
    Param("layout", "fused", "fused: the chain as one node (one join, one Monitor.step per "
          "sample); chain: the four nodes observer, detector, agei, bias_estimator on one "
          "executor (their own names, parameters and diagnostics)"),
    GAP_TIMEOUT,
    WARN_SHARE,
    Param("enabled", True, "AGEI on; false: the ablation without AGEI (never triggers, no "
          "override)"),
    ADAPTER_PARAM,
)

USAGE = NodeUsage(
    "monitor", "monitor: the diagnosis chain (observer, detector, AGEI, bias estimator) as "
    "one node (layout:=chain: the four nodes in one process).", (*COMMON_PARAMS, *PARAMS),
    subscribes=((PLANT_U, "u_k (stamped, or plain: stamped on arrival)"),
                (PLANT_Y, "y_k (stamped, or plain: stamped on arrival)")),
    publishes=((STATE_ESTIMATE, "mode, x^_k, y~_k, restart (stamp k)"),
               (RESIDUAL, "r:<out>, w:<out> (stamp k)"),
               (THRESHOLD, "R:<out> in force, rbar:<out> nominal (stamp k)"),
               (ALARM, "0/1 per output (stamp k)"),
               (GUARD_EVENT, "trigger, phase, row, mode_uncertain (stamp k + 1)"),
               (THRESHOLD_OVERRIDE, "AGEI override per output, NaN = none "
                "(stamp k + 1)"),
               (BIAS_ESTIMATE, "sigma^_{k+1}, iso:<out>, active, k_detect "
                "(stamp k + 1)"),
               (DIAGNOSTICS, "input, estimate, residual <out>, tracker, bias estimate")))


class MonitorNode(EstimateReport, ResidualReport, BiasReport, FdNode):
    """The fused chain node: one join of ``plant/u`` and ``plant/y``, one runtime step per
    sample, the chain's seven outputs.

    Parameters
    ----------
    system, gains, qos, **kwargs
        See :class:`~fd_monitor.nodes.fd_node.FdNode`.
    """

    runtimes: Mapping[str, str] = {"thresholds": "_start_thresholds"}
    outputs = CHAIN_OUTPUTS
    bias_channel = "bias estimate"

    def __init__(self, system=None, gains=None, qos=None, node_name: str = "monitor",
                 **kwargs: Any) -> None:
        super().__init__(node_name, PARAMS, system, gains, qos, **kwargs)

    def start(self) -> None:
        """Configure and activate (autostart), unless the layout is ``chain``."""
        if self.params.layout not in LAYOUTS:
            raise FdMonitorError(f"node {self.get_name()}: parameter layout: "
                                 f"{self.params.layout!r}: expected one of "
                                 f"{', '.join(LAYOUTS)}")
        if self.params.layout == "fused":
            super().start()

    def setup(self) -> None:
        """Publishers, runtime, diagnostics and inputs (at configure)."""
        s = self.system
        o = s.outputs
        # Each topic's message is serialized directly (SerializedArray: no message object
        # per sample); its values are the runtime's payloads by field name (the layouts,
        # built once).
        self._out = [(self.publisher(t), SerializedArray(t.layout(s).labels), t.layout(s),
                      t.next_sample) for t in self.outputs]
        #: per topic: publisher, serializer, which payload holds each field, k or k + 1
        #: (resolved at the first sample from the runtime's payloads)
        self._plan: list[tuple[Any, SerializedArray, Any, bool]] | None = None
        self.sigma_hat = [0.0] * s.ny
        self._alarmed: set[str] = set()
        self._episode = 0
        self._was_outside = False
        self._last_active, self._last_isolated = False, []
        self.channels = [f"residual {n}" for n in o]
        self.diag.add("estimate", self.params.stale_timeout)
        for ch in self.channels:
            self.diag.add(ch, self.params.stale_timeout)
        self.diag.add("tracker", self.params.stale_timeout)
        self.diag.add(self.bias_channel, self.params.stale_timeout, keep_on_stale=True)
        self._channels_all = ["estimate", *self.channels, "tracker", self.bias_channel]
        self._last_key: Any = None
        self._next_report = 0.0
        self.start_runtime()

    # -- the runtime: built, reset and stepped here only ------------------------------------

    def _start_thresholds(self) -> None:
        s = self.system
        self.build_core(self.gain_file)
        self.start_inputs([
            Input.of("u", PLANT_U, s, plain_ok=True, hold=True),
            Input.of("y", PLANT_Y, s, plain_ok=True),
        ], gap_timeout=self.params.gap_timeout)

    def build_core(self, gains: Any) -> None:
        """The runtime of a gain file (at configure, and when ``gains`` is set)."""
        self.runtime = Monitor(self.system, gains, agei=self.params.enabled)
        # the residual reports ask whether the detector is the thresholds one
        self.detector = self.runtime.detector

    def reset(self) -> None:
        """Fresh runtime state (a new run: first sample, after a hole, ``~/reset``)."""
        self.runtime.reset()

    def step_runtime(self, k: int, inputs: dict[str, Any]) -> MonitorOutput:
        """One sample through the runtime (raises ImplausibleError: refused, no state
        changed)."""
        return self.runtime.step(k, inputs["u"], inputs["y"])

    # -- per sample ---------------------------------------------------------------------------

    def process(self, k: int, inputs: dict[str, Any]) -> None:
        """(u_k, y_k) -> the chain's seven outputs and the diagnostics."""
        out = self.step_runtime(k, inputs)
        ob, det, ag, est = out.observer, out.detector, out.agei, out.estimator
        stamps = (k, k + 1)
        pays = (ob.payload(), det.payload(), ag.payload(), est.payload(),
                {"restart": self.restarting})
        if self._plan is None:
            self._plan = [(pub, ser, lay.sources(pays), nxt) for pub, ser, lay, nxt in self._out]
        for pub, ser, src, nxt in self._plan:
            # values as Python numbers (bools and ints pack exactly as float64)
            data: list[Any] = []
            for i, name, scalar in src:
                v = pays[i][name]
                if scalar:
                    data.append(v)
                else:
                    data.extend(v.tolist())
            pub.publish(ser.encode(stamps[nxt], data))
        alarm = det.alarm.tolist()
        # Diagnostics: a full report when a status can change (alarms, mode, AGEI phase,
        # estimator, certified region) and at least every DIAG_REFRESH s; else the channels
        # are only marked fresh. /diagnostics goes out every diagnostics_period anyway.
        outside = ob.outside is not None and bool((ob.outside != 0.0).any())
        key = (alarm, ob.mode, ag.phase, est.active, est.isolated.tolist(), outside)
        now = time.monotonic()
        if key != self._last_key or now >= self._next_report:
            self._last_key, self._next_report = key, now + DIAG_REFRESH
            self.sigma_hat = est.sigma_hat
            self.report_estimate(k, int(ob.mode), ob.x_hat, ob.outside)
            self._report(k, int(ob.mode), det.residual, det.threshold, alarm)
            self.diag.update("tracker", OK, f"phase {ag.phase}", {
                "sample": k, "trigger": ag.trigger, "phase": ag.phase, "row": ag.row,
                **self.gain_values()})
            self.report_bias(k, est)
        else:
            for ch in self._channels_all:
                self.diag.touch(ch)


def make_chain(**kwargs: Any) -> list:
    """The four chain nodes on one executor (``kwargs`` go to every node, e.g. ``context``).

    The observer, the chain's entry, is created last: by the time it subscribes to
    ``plant/y`` (what a source waits for) the other nodes already subscribe to ``plant/*``
    and to the observer's outputs, so none of them misses the first samples.
    """
    det, ag, est = DetectorNode(**kwargs), AgeiNode(**kwargs), BiasEstimatorNode(**kwargs)
    return [ObserverNode(**kwargs), det, ag, est]


def make_nodes(**kwargs: Any) -> list:
    """The fused monitor node, or with ``layout: chain`` the four chain nodes
    (:func:`make_chain`); for a gain file of another method than ``thresholds`` (qb,
    hinf_sc, hminus_switched) the fused :class:`~fd_monitor.nodes.runtime_node.RuntimeNode`.
    ``kwargs`` go to every node (e.g. ``context``)."""
    method = gain_method(**kwargs)
    if method is not None and method != "thresholds":
        return [RuntimeNode(**kwargs)]
    node = MonitorNode(**kwargs)
    if node.params.layout == "fused":
        return [node]
    node.destroy_node()
    return make_chain(**{**kwargs, "parameter_overrides": [
        p for p in kwargs.get("parameter_overrides", []) if p.name != "layout"]})


def main(args: Sequence[str] | None = None) -> int:
    """Run the fused monitor node (or, with ``layout:=chain``, the four chain nodes)."""
    return run_node(make_nodes, args, prog="monitor",
                    usage=[USAGE, runtime_node.USAGE,
                           *(m.USAGE for m in (observer, detector, agei, bias_estimator))])


if __name__ == "__main__":
    import sys

    sys.exit(main())
