"""``bias_estimator``: the adaptive sensor-bias estimator (Heracleous et al., Sec. 3.4).

Joins, per sample k: ``/plant/u`` (u_k), ``/plant/y`` (raw y_k), ``/fd/state_estimate``
(q^_k), ``/fd/alarm`` (alarm_k; the first alarm starts the estimator) and the AGEI decision
at k (``/fd/guard_event`` stamped k + 1: its ``mode_uncertain``, 1 while q^ may be wrong, in
which case sigma^ is held). Publishes
``/fd/bias_estimate`` stamped k + 1: sigma^_{k+1} (per output), ``iso:<out>`` isolation
flags, ``active``, ``k_detect`` (-1 before detection).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from rclpy.qos import QoSProfile

from fd_monitor.core.bias_estimator import BiasEstimator
from fd_monitor.core.thresholds import as_gains
from fd_monitor.model.gains import GainFile
from fd_monitor.model.system import System
from fd_monitor.nodes.chain_params import COMMON_PARAMS, FAULT_PARAMS
from fd_monitor.nodes.fault import FaultReport, fault_report
from fd_monitor.nodes.fd_node import FdNode
from fd_monitor.nodes.inputs import Input
from fd_monitor.nodes.process import run_node
from fd_monitor.nodes.reports import BiasReport
from fd_monitor.nodes.usage import NodeUsage
from fd_monitor.wire.topics import (
    ALARM,
    BIAS_ESTIMATE,
    DIAGNOSTICS,
    FAULT,
    GUARD_EVENT,
    PLANT_U,
    PLANT_Y,
    STATE_ESTIMATE,
)

__all__ = ["BiasEstimatorNode", "USAGE", "main"]

PARAMS: tuple = FAULT_PARAMS

USAGE = NodeUsage(
    "bias_estimator", "bias_estimator: adaptive sensor-bias estimator (thresholds gain files "
    "only).", (*COMMON_PARAMS, *PARAMS),
    subscribes=((PLANT_U, "u_k"), (PLANT_Y, "raw y_k"),
                (STATE_ESTIMATE, "q^_k from observer"),
                (ALARM, "alarm_k from detector (the first one starts estimation)"),
                (GUARD_EVENT, "AGEI mode_uncertain at k (stamped k + 1)")),
    publishes=((BIAS_ESTIMATE, "sigma^_{k+1}, iso:<out>, active, k_detect "
                "(stamp k + 1)"),
               (FAULT, "the latched fault verdict per output: fault, isolated, estimate, "
                "since (on change; transient local)"),
               (DIAGNOSTICS, "input, estimate and fault status")))


class BiasEstimatorNode(FdNode):
    """Bias estimator node.

    Parameters
    ----------
    estimator : BiasEstimator, optional
        Default: built from the gain file.
    system, gains, qos, **kwargs
        See :class:`~fd_monitor.nodes.fd_node.FdNode`.
    """

    outputs = (BIAS_ESTIMATE,)

    def __init__(self, estimator: BiasEstimator | None = None, system: System | None = None,
                 gains: GainFile | None = None, qos: QoSProfile | None = None,
                 node_name: str = "bias_estimator", **kwargs: Any) -> None:
        self._estimator_arg = estimator
        self.bias_report: BiasReport | None = None
        self.fault: FaultReport | None = None
        super().__init__(node_name, PARAMS, system, gains, qos, **kwargs)

    def setup(self) -> None:
        """Publisher, estimator and inputs (at configure)."""
        self.start_runtime()
        self._start(self._estimator_arg)

    def build_core(self, gains: Any) -> None:
        """A new estimator for another gain file (runtime swap)."""
        self.estimator = BiasEstimator(self.system, as_gains(self.system, gains))

    def _thresholds_only(self) -> None:
        """The sensor-bias chain's runtime (any other method is refused at start)."""

    runtimes: Mapping[str, Callable[[Any], None]] = {"thresholds": _thresholds_only}

    def _start(self, estimator: BiasEstimator | None) -> None:
        s = self.system
        self.estimator = (estimator if estimator is not None
                          else BiasEstimator(s, as_gains(s, self.gain_file)))
        self.pub = self.publisher(BIAS_ESTIMATE)
        self._bias = BIAS_ESTIMATE.layout(s)
        # A fault found stays visible (with its estimate) when the input stops.
        self.diag.add("estimate", self.params.stale_timeout, keep_on_stale=True)
        self.bias_report = BiasReport(self.diag, self.get_logger(), s.outputs,
                                      self.gain_values)
        self.fault = fault_report(self, s.outputs,
                                  as_gains(s, self.gain_file).isolation_threshold)
        inputs = [
            Input.of("u", PLANT_U, s, plain_ok=True, hold=True),
            Input.of("y", PLANT_Y, s, plain_ok=True),
            Input.of("est", STATE_ESTIMATE, s, sequence=True),
            Input.of("alarm", ALARM, s),
            Input.of("guard", GUARD_EVENT, s, stamp_offset=-1),
        ]
        # the fields read, resolved once: q^, the alarms, mode_uncertain
        lay = {i.name: i.layout.index for i in inputs if i.layout is not None}
        self._i = (lay["est"]["mode"], lay["alarm"]["alarm"], lay["guard"]["mode_uncertain"])
        self.start_inputs(inputs)

    def reset(self) -> None:
        """Back to inactive, sigma^ = 0 (Monitor.reset)."""
        self.estimator.reset()
        if self.bias_report is not None:
            self.bias_report.reset()
        if self.fault is not None:
            self.fault.reset()

    def bridge(self, k: int, inputs: dict[str, Any]) -> None:
        """sigma^, K_d and isolation kept over a bridged gap, the state predicted through it
        (Monitor.bridge)."""
        self.estimator.bridge(k, inputs["u"], inputs["y"])

    def process(self, k: int, inputs: dict[str, Any]) -> None:
        """u_k, y_k, q^_k, alarm_k, AGEI row at k -> sigma^_{k+1}, isolation flags."""
        i_mode, i_alarm, i_uncertain = self._i
        out = self.estimator.step(k, inputs["u"], inputs["y"], int(inputs["est"][i_mode]),
                                  inputs["alarm"][i_alarm] > 0.5,
                                  bool(inputs["guard"][i_uncertain] > 0.5))
        lay = self._bias
        self.publish_array(self.pub, lay.labels, k + 1, lay.encode(out.payload()))
        assert self.bias_report is not None and self.fault is not None   # configured
        self.bias_report.report(k, out)
        self.fault.step(k, inputs["alarm"][i_alarm] > 0.5, out.sigma_hat, out.isolated)


def main(args: Sequence[str] | None = None) -> int:
    """Run the bias estimator node."""
    return run_node(BiasEstimatorNode, args, prog="bias_estimator", usage=[USAGE])


if __name__ == "__main__":
    import sys

    sys.exit(main())
