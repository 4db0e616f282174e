"""``detector``: filtered residuals, thresholds and alarms (Heracleous et al., eq. 8-18).

Joins, per sample k: ``/fd/state_estimate`` (q^_k, x^_k, y~_k) and
``/fd/threshold_override`` (AGEI's override decided at k - 1, stamped k; NaN = none).
Publishes (stamp k) ``/fd/residual`` (``r:<out>``, ``w:<out>``), ``/fd/threshold``
(``R:<out>`` in force, ``rbar:<out>`` nominal) and ``/fd/alarm`` (0/1 per output).

``/diagnostics``: one status per output channel (``residual <out>``): OK; WARN when
|r| > ``warn_share`` x R; ERROR on alarm; STALE when no input came for ``stale_timeout`` s;
values: residual, threshold, margin (R - |r|), mode, sigma_hat (the latest bias estimate),
gain file id, certificate status.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from std_msgs.msg import Float64MultiArray

from fd_monitor.core.detector import ResidualDetector, no_override
from fd_monitor.core.thresholds import as_gains
from fd_monitor.errors import MessageError
from fd_monitor.nodes.common import (
    ERROR,
    OK,
    WARN,
    Param,
    data_sub_qos,
    run_node,
    sub_events,
)
from fd_monitor.nodes.conversions import decode
from fd_monitor.nodes.fd_node import FdNode, Input
from fd_monitor.nodes.observer import bias_labels

__all__ = ["DetectorNode", "state_labels", "main"]

PARAMS = (
    Param("warn_share", 0.8, "WARN when |residual| exceeds this share of its threshold",
          low=0.0, high=1.0),
)


def state_labels(system: Any) -> tuple[str, ...]:
    """Labels of ``/fd/state_estimate`` (ObserverOutput.payload)."""
    return ("mode", *system.states, *(f"y~{o}" for o in system.outputs))


class DetectorNode(FdNode):
    """Residual detector node.

    Parameters
    ----------
    detector : ResidualDetector, optional
        Default: built from the gain file.
    system, gains, qos, **kwargs
        See :class:`~fd_monitor.nodes.fd_node.FdNode`.
    """

    def __init__(self, detector: ResidualDetector | None = None, system=None, gains=None,
                 qos=None, node_name: str = "detector", **kwargs: Any) -> None:
        super().__init__(node_name, PARAMS, system, gains, qos, **kwargs)
        s = self.system
        self.detector = (detector if detector is not None
                         else ResidualDetector(s, as_gains(s, self.gain_file)))
        self.pubs = {t: self.publisher(t) for t in ("/fd/residual", "/fd/threshold",
                                                    "/fd/alarm")}
        self.channels = [f"residual {o}" for o in s.outputs]
        for ch in self.channels:
            self.diag.add(ch, self.params.stale_timeout)
        self.sigma_hat = np.zeros(s.ny)
        # The latest bias estimate, for diagnostics only (not joined: it does not enter r_k).
        self.create_subscription(Float64MultiArray, "/fd/bias_estimate", self._on_bias,
                                 data_sub_qos(), **sub_events())
        self.start_inputs([
            Input("est", "/fd/state_estimate", state_labels(s)),
            Input("override", "/fd/threshold_override", tuple(s.outputs),
                  initial=no_override(s.ny), allow_nan=True),
        ])

    def _on_bias(self, msg: Any) -> None:
        try:
            d = decode(msg, "/fd/bias_estimate", labels=bias_labels(self.system),
                       require_stamp=True)
        except MessageError as exc:
            self.bad_input(str(exc))
            return
        self.sigma_hat = d.values[:self.system.ny]

    def process(self, k: int, inputs: dict[str, Any]) -> None:
        """(q^_k, x^_k, y~_k), override -> r_k, R_k, alarm_k."""
        s = self.system
        est = inputs["est"]
        mode, x_hat, y_t = int(est[0]), est[1:1 + s.n], est[1 + s.n:]
        out = self.detector.step(k, y_t, x_hat, mode, inputs["override"])
        for topic, (labels, values) in out.payloads(s).items():
            self.publish_array(self.pubs[topic], labels, k, values)
        self._report(k, mode, out)

    def _report(self, k: int, mode: int, out: Any) -> None:
        share = self.params.warn_share
        for i, ch in enumerate(self.channels):
            r, R = float(out.residual[i]), float(out.threshold[i])
            if out.alarm[i]:
                level, msg = ERROR, "alarm: |residual| > threshold"
            elif abs(r) > share * R:
                level, msg = WARN, f"|residual| > {share:g} x threshold"
            else:
                level, msg = OK, "ok"
            self.diag.update(ch, level, msg, {
                "sample": k, "residual": r, "threshold": R, "margin": R - abs(r),
                "mode": self.system.mode_names[mode], "sigma_hat": float(self.sigma_hat[i]),
                **self.gain_values()})


def main(args: Sequence[str] | None = None) -> int:
    """Run the detector node."""
    return run_node(DetectorNode, args, prog="detector")


if __name__ == "__main__":
    import sys

    sys.exit(main())
