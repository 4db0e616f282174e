"""``bias_estimator``: the adaptive sensor-bias estimator (Heracleous et al., Sec. 3.4).

Joins, per sample k: ``/plant/u`` (u_k), ``/plant/y`` (raw y_k), ``/fd/state_estimate``
(q^_k), ``/fd/alarm`` (alarm_k; the first alarm starts the estimator) and the AGEI decision
at k (``/fd/guard_event`` stamped k + 1: its ``row`` says whether q^ is uncertain, in which
case sigma^ is held). Publishes
``/fd/bias_estimate`` stamped k + 1: sigma^_{k+1} (per output), ``iso:<out>`` isolation
flags, ``active``, ``k_detect`` (-1 before detection).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from fd_monitor.core.bias_estimator import BiasEstimator
from fd_monitor.core.thresholds import as_gains
from fd_monitor.nodes.common import OK, WARN, run_node
from fd_monitor.nodes.detector import state_labels
from fd_monitor.nodes.fd_node import FdNode, Input
from fd_monitor.nodes.observer import GUARD_LABELS

__all__ = ["BiasEstimatorNode", "main"]


class BiasEstimatorNode(FdNode):
    """Bias estimator node.

    Parameters
    ----------
    estimator : BiasEstimator, optional
        Default: built from the gain file.
    system, gains, qos, **kwargs
        See :class:`~fd_monitor.nodes.fd_node.FdNode`.
    """

    def __init__(self, estimator: BiasEstimator | None = None, system=None, gains=None,
                 qos=None, node_name: str = "bias_estimator", **kwargs: Any) -> None:
        super().__init__(node_name, (), system, gains, qos, **kwargs)
        s = self.system
        self.estimator = (estimator if estimator is not None
                          else BiasEstimator(s, as_gains(s, self.gain_file)))
        self.pub = self.publisher("/fd/bias_estimate")
        self.diag.add("estimate", self.params.stale_timeout)
        self.start_inputs([
            Input("u", "/plant/u", s.inputs, plain_ok=True),
            Input("y", "/plant/y", s.outputs, plain_ok=True),
            Input("est", "/fd/state_estimate", state_labels(s)),
            Input("alarm", "/fd/alarm", tuple(s.outputs)),
            Input("guard", "/fd/guard_event", GUARD_LABELS, stamp_offset=-1),
        ])
        # Rows of the AGEI matrix whose events residuals can see (AgeiOutput.mode_uncertain
        # is "row >= 0 and the row affects a residual"; /fd/guard_event carries the row).
        self._visible = [bool(r.affected) for r in as_gains(s, self.gain_file).agei_rows]

    def mode_uncertain(self, row: int) -> bool:
        """AGEI's mode_uncertain from the row it published."""
        return 0 <= row < len(self._visible) and self._visible[row]

    def process(self, k: int, inputs: dict[str, Any]) -> None:
        """u_k, y_k, q^_k, alarm_k, AGEI row at k -> sigma^_{k+1}, isolation flags."""
        s = self.system
        out = self.estimator.step(k, inputs["u"], inputs["y"], int(inputs["est"][0]),
                                  inputs["alarm"] > 0.5,
                                  self.mode_uncertain(int(inputs["guard"][2])))
        labels, values = out.payload(s)
        self.publish_array(self.pub, labels, k + 1, values)
        isolated = [o for o, f in zip(s.outputs, out.isolated) if f]
        if out.active:
            level, msg = WARN, (f"bias on {', '.join(isolated)}" if isolated
                                else "estimating (fault detected)")
        else:
            level, msg = OK, "no fault detected"
        self.diag.update("estimate", level, msg, {
            "sample": k, "active": bool(out.active), "k_detect": int(out.k_detect),
            "sigma_hat": out.sigma_hat, "isolated": ",".join(isolated) or "none",
            **self.gain_values()})


def main(args: Sequence[str] | None = None) -> int:
    """Run the bias estimator node."""
    return run_node(BiasEstimatorNode, args, prog="bias_estimator")


if __name__ == "__main__":
    import sys

    sys.exit(main())
