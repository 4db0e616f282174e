"""``bias_estimator``: the adaptive sensor-bias estimator (Heracleous et al., Sec. 3.4).

Joins, per sample k: ``/plant/u`` (u_k), ``/plant/y`` (raw y_k), ``/fd/state_estimate``
(q^_k), ``/fd/alarm`` (alarm_k; the first alarm starts the estimator) and the AGEI decision
at k (``/fd/guard_event`` stamped k + 1: its ``mode_uncertain``, 1 while q^ may be wrong, in
which case sigma^ is held). Publishes
``/fd/bias_estimate`` stamped k + 1: sigma^_{k+1} (per output), ``iso:<out>`` isolation
flags, ``active``, ``k_detect`` (-1 before detection).

AGEI's decision is an *optional* input (:class:`~fd_monitor.nodes.inputs.Input`): waited
for while ``agei`` is there, absent when it is away (killed, restarting, not started). The
node runs its own copy of AGEI on the state estimate (``agei_fallback``,
:class:`~fd_monitor.core.local_agei.LocalAgei`: the residuals from q^, x^, y~ as the detector
computes them, then AGEI: the same code on the same numbers) and uses its ``mode_uncertain``
for an absent sample, so it keeps estimating and isolating while agei is away; the ``agei``
status says WARN meanwhile. With agei there, its message is used: the numbers are unchanged.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from rclpy.qos import QoSProfile

from fd_monitor.core.bias_estimator import BiasEstimator
from fd_monitor.core.filters import as_floats
from fd_monitor.core.thresholds import as_gains
from fd_monitor.model.gains import GainFile
from fd_monitor.model.system import System
from fd_monitor.nodes.agei_fallback import AGEI_FALLBACK, AgeiFallback
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

PARAMS: tuple = (*FAULT_PARAMS, AGEI_FALLBACK)

USAGE = NodeUsage(
    "bias_estimator", "bias_estimator: adaptive sensor-bias estimator (thresholds gain files "
    "only).", (*COMMON_PARAMS, *PARAMS),
    subscribes=((PLANT_U, "u_k"), (PLANT_Y, "raw y_k"),
                (STATE_ESTIMATE, "q^_k from observer"),
                (ALARM, "alarm_k from detector (the first one starts estimation)"),
                (GUARD_EVENT, "AGEI mode_uncertain at k (stamped k + 1; while agei is away: "
                 "this node's own AGEI's)")),
    publishes=((BIAS_ESTIMATE, "sigma^_{k+1}, iso:<out>, active, k_detect "
                "(stamp k + 1)"),
               (FAULT, "the latched fault verdict per output: fault, isolated, estimate, "
                "since (on change; transient local)"),
               (DIAGNOSTICS, "input, estimate, fault and agei status (WARN while agei's "
                "decisions are absent)")))


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
        self._fallback: AgeiFallback | None = None
        super().__init__(node_name, PARAMS, system, gains, qos, **kwargs)

    def setup(self) -> None:
        """Publisher, estimator and inputs (at configure)."""
        self.start_runtime()
        self._start(self._estimator_arg)

    def build_core(self, gains: Any) -> None:
        """A new estimator for another gain file (runtime swap)."""
        self.estimator = BiasEstimator(self.system, as_gains(self.system, gains))
        if self._fallback is not None:
            self._fallback.new_gains(gains)

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
            # agei's decision at k; absent (None) while agei is away: the local AGEI's
            Input.of("guard", GUARD_EVENT, s, stamp_offset=-1, optional=True),
        ]
        # the fields read, resolved once: q^, x^, y~, the alarms, mode_uncertain
        lay = {i.name: i.layout.index for i in inputs if i.layout is not None}
        self._i = (lay["est"]["mode"], lay["alarm"]["alarm"], lay["guard"]["mode_uncertain"])
        self._i_xy = (lay["est"]["x_hat"], lay["est"]["y_tilde"])
        self._fallback = AgeiFallback(self, True, None, "guard events")
        self.start_inputs(inputs)

    def reset(self) -> None:
        """Back to inactive, sigma^ = 0 (Monitor.reset)."""
        self.estimator.reset()
        if self._fallback is not None:
            self._fallback.reset()
        if self.bias_report is not None:
            self.bias_report.reset()
        if self.fault is not None:
            self.fault.reset()

    def bridge(self, k: int, inputs: dict[str, Any]) -> None:
        """sigma^, K_d and isolation kept over a bridged gap, the state predicted through it
        (Monitor.bridge)."""
        self.estimator.bridge(k, inputs["u"], inputs["y"])
        if self._fallback is not None:
            self._fallback.bridge()

    def process(self, k: int, inputs: dict[str, Any]) -> None:
        """u_k, y_k, q^_k, alarm_k, AGEI row at k -> sigma^_{k+1}, isolation flags."""
        i_mode, i_alarm, i_uncertain = self._i
        est, guard, fb = inputs["est"], inputs["guard"], self._fallback
        assert fb is not None                    # configured
        mode, local = int(est[i_mode]), fb.local
        if local is not None:
            # AGEI's decision at k on this sample's numbers (its filters follow the run)
            i_x, i_y = self._i_xy
            local.observe(k, mode, as_floats(est[i_y]), as_floats(est[i_x]))
        # agei's mode_uncertain; while it is absent, the local AGEI's (none without it)
        if fb.absent(k, guard, False):
            uncertain = local is not None and local.mode_uncertain
        else:
            uncertain = bool(guard[i_uncertain] > 0.5)
        out = self.estimator.step(k, inputs["u"], inputs["y"], mode,
                                  inputs["alarm"][i_alarm] > 0.5, uncertain)
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
