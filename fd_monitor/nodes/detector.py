"""``detector``: filtered residuals, thresholds and alarms (Heracleous et al., eq. 8-18).

The detector node alone: one node of the four-process chain, fed ``fd/state_estimate`` by
an ``observer``. To detect on ``plant/u`` and ``plant/y`` alone run ``monitor`` (the whole
chain as one node; ``-p layout:=nodes``: its four nodes in one process): a detector started
without an observer says so once, :data:`ENTRY_HINT` s after it activated.

Joins, per sample k: ``/fd/state_estimate`` (q^_k, x^_k, y~_k) and
``/fd/threshold_override`` (AGEI's override decided at k - 1, stamped k; NaN = none).
Publishes (stamp k) ``/fd/residual`` (``r:<out>``, ``w:<out>``), ``/fd/threshold``
(``R:<out>`` in force, ``rbar:<out>`` nominal) and ``/fd/alarm`` (0/1 per output).

``/diagnostics``: one status per output channel (``residual <out>``): OK; WARN when
|r| > ``warn_share`` x R; ERROR on alarm; STALE when no input came for ``stale_timeout`` s;
values: residual, threshold, margin (R - |r|), mode, sigma_hat (the latest bias estimate),
gain file id, certificate status.

While ``agei``'s threshold overrides are absent (agei killed, restarting, not started) the
detector takes them from its own copy of AGEI (``agei_fallback``,
:class:`~fd_monitor.core.local_agei.LocalAgei` on its own ``q^``, ``w``, ``r`` and nominal
threshold: what agei would send), so the threshold is widened around a guard crossing as the
fused monitor widens it; the ``agei`` status says so (WARN) and an alarm's status message
is marked ``(agei absent: own AGEI)``.

With a ``qb`` gain file it runs :class:`~fd_monitor.core.qb.QBDetector`: per channel of
``QBDetector.channels`` (fault-model states, ``fault_norm``, ``r_<out>``, ``r_norm``) it
publishes the compared signal on ``/fd/residual``, rho x bound on ``/fd/threshold`` and the
alarm on ``/fd/alarm``, as :func:`fd_monitor.analysis.offline.run_bag` computes them.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from rclpy.qos import QoSProfile

from fd_monitor.core.detector import ResidualDetector, no_override
from fd_monitor.core.filters import as_floats
from fd_monitor.core.qb import QBDetector, QBObserver
from fd_monitor.core.thresholds import as_gains
from fd_monitor.model.errors import FdMonitorError, MessageError
from fd_monitor.model.gains import GainFile
from fd_monitor.model.system import System
from fd_monitor.nodes.agei_fallback import AGEI_FALLBACK, AgeiFallback
from fd_monitor.nodes.chain_params import COMMON_PARAMS, WARN_SHARE
from fd_monitor.nodes.fd_node import FdNode
from fd_monitor.nodes.inputs import Input
from fd_monitor.nodes.params import Param
from fd_monitor.nodes.process import run_node
from fd_monitor.nodes.reports import ResidualReport
from fd_monitor.nodes.usage import NodeUsage
from fd_monitor.wire.conversions import decode
from fd_monitor.wire.topics import (
    ALARM,
    BIAS_ESTIMATE,
    DIAGNOSTICS,
    RESIDUAL,
    STATE_ESTIMATE,
    THRESHOLD,
    THRESHOLD_OVERRIDE,
)

__all__ = ["DetectorNode", "USAGE", "main"]

#: ``layout`` is no longer the detector's to choose: the detector executable is the detector
#: node alone, and the in-process chain is ``monitor``'s (``layout: nodes``). The parameter
#: stays declared for its old values: ``chain`` (the detector alone: what it is now) is
#: accepted with one deprecation warning; ``standalone`` (the whole chain in this process) is
#: refused in one line naming ``monitor`` -- a detector alone, fed only plant/u and plant/y,
#: would wait for fd/state_estimate for ever instead of detecting.
LAYOUT = Param("layout", "", "deprecated, leave it unset: the detector is always the detector "
               "node alone (fed fd/state_estimate by an observer); chain is accepted with a "
               "warning, standalone refused (the whole chain in one process is monitor, "
               "-p layout:=nodes for its four nodes)", choices=("", "chain", "standalone"))

PARAMS = (
    WARN_SHARE,
    LAYOUT,
    AGEI_FALLBACK,
)

#: s after activation before a detector without an observer says so (once).
ENTRY_HINT = 5.0

USAGE = NodeUsage(
    "detector", "detector: filtered residuals, thresholds and alarms (QB bounds for a qb "
    "gain file).", (*COMMON_PARAMS, *PARAMS),
    subscribes=((STATE_ESTIMATE, "mode, x^_k, y~_k from observer"),
                (THRESHOLD_OVERRIDE, "AGEI override for k (stamped k; NaN = none)"),
                (BIAS_ESTIMATE, "latest sigma^ (diagnostics only)")),
    publishes=((RESIDUAL, "r:<out>, w:<out> (stamp k)"),
               (THRESHOLD, "R:<out> in force, rbar:<out> nominal"),
               (ALARM, "0/1 per channel"),
               (DIAGNOSTICS, "one status per channel: residual, threshold, margin; agei "
                "(WARN while agei's overrides are absent)")))


class DetectorNode(FdNode):
    """Residual detector node: thresholds (``thresholds``) or QB bounds (``qb``).

    Parameters
    ----------
    detector : ResidualDetector, optional
        ``thresholds`` only; default: built from the gain file.
    system, gains, qos, **kwargs
        See :class:`~fd_monitor.nodes.fd_node.FdNode`.
    """

    outputs = (RESIDUAL, THRESHOLD, ALARM)

    def __init__(self, detector: ResidualDetector | None = None, system: System | None = None,
                 gains: GainFile | None = None, qos: QoSProfile | None = None,
                 node_name: str = "detector", **kwargs: Any) -> None:
        self._detector_arg = detector
        self._layout_checked = False
        super().__init__(node_name, PARAMS, system, gains, qos, **kwargs)
        self._check_layout()

    def start(self) -> None:
        """Check the (deprecated) layout, configure and activate (autostart)."""
        self._check_layout()
        super().start()

    def _check_layout(self) -> None:
        """Refuse ``layout: standalone`` (one line), warn once about ``layout: chain``."""
        if self._layout_checked:
            return
        self._layout_checked = True
        layout = self.params.layout
        if layout == "standalone":
            raise FdMonitorError(
                f"node {self.get_name()}: parameter layout: 'standalone' was removed: the "
                f"detector executable runs the detector node alone; for the whole chain in "
                f"one process run `monitor` (one node) or `monitor -p layout:=nodes` (its four "
                f"nodes)")
        if layout == "chain":
            self.get_logger().warning(
                "parameter layout: 'chain' is deprecated and has no effect: the detector is "
                "always the detector node alone (what layout: chain was); remove it")

    def setup(self) -> None:
        """Publishers, detector and inputs (at configure)."""
        self.detector: Any = self._detector_arg
        self._fallback: AgeiFallback | None = None      # thresholds: set at start
        self.pubs = {t: self.publisher(t) for t in self.outputs}
        est = STATE_ESTIMATE.layout(self.system)
        # the fields of the state estimate, resolved once
        self._i_est = (est.index["mode"], est.index["x_hat"], est.index["y_tilde"])
        self.sigma_hat = np.zeros(self.system.ny)
        self.start_runtime()
        for ch in self.channels:
            self.diag.add(ch, self.params.stale_timeout)
        self.residual_report = ResidualReport(self.diag, self.get_logger(), self.system,
                                              self.channels, lambda: self.params.warn_share,
                                              self.gain_values)
        self._hint = self.create_timer(ENTRY_HINT, self._hint_entry)
        self._entities.append(self._hint)

    def _hint_entry(self) -> None:
        """Once: say so when nothing publishes the state estimate (a detector started alone
        beside a robot, expecting the whole chain)."""
        self._hint.cancel()
        if self.active and not self.count_publishers(STATE_ESTIMATE.name):
            self.get_logger().warning(
                f"no publisher of {self.resolve_topic_name(STATE_ESTIMATE.name)}: the detector "
                f"needs an observer (the four-process chain); to detect on plant/u and "
                f"plant/y alone run `monitor` (the whole chain)")

    def build_core(self, gains: Any) -> None:
        """A new detector for another gain file (runtime swap)."""
        s = self.system
        self.detector = (ResidualDetector(s, as_gains(s, gains)) if gains.method == "thresholds"
                         else QBDetector(s, gains))
        if self._fallback is not None:
            self._fallback.new_gains(gains)

    def _start_thresholds(self) -> None:
        s = self.system
        if self.detector is None:
            self.detector = ResidualDetector(s, as_gains(s, self.gain_file))
        self.channels = [f"residual {o}" for o in s.outputs]
        self._layouts = {t: t.layout(s) for t in self.outputs}
        # The latest bias estimate, for diagnostics only (not joined: it does not enter r_k).
        self._bias = BIAS_ESTIMATE.layout(s)
        self.subscribe(BIAS_ESTIMATE.name, self._on_bias)
        none = no_override(s.ny)
        self._fallback = AgeiFallback(self, False, none, "thresholds")
        self.start_inputs([
            Input.of("est", STATE_ESTIMATE, s, sequence=True),
            Input.of("override", THRESHOLD_OVERRIDE, s, initial=none, allow_nan=True),
        ])
        self._step = self._step_thresholds

    def _start_qb(self) -> None:
        s = self.system
        self.detector = QBDetector(s, self.gain_file)
        # r = y - C_q x^ summed as the observer and the offline runtime sum it
        self._qb_observer = QBObserver(s, self.gain_file)
        self.channels = [f"residual {c}" for c in self.detector.channels]
        self._layouts = {t: t.channels(self.detector.channels) for t in self.outputs}
        self.start_inputs([Input.of("est", STATE_ESTIMATE, s, sequence=True)])
        self._step = self._step_qb

    runtimes: Mapping[str, Callable[[Any], None]] = {
        "thresholds": _start_thresholds, "qb": _start_qb}

    def _on_bias(self, msg: Any) -> None:
        if not self.active:
            return
        try:
            d = decode(msg, self.resolve_topic_name(BIAS_ESTIMATE.name),
                       labels=self._bias.labels, require_stamp=True)
        except MessageError as exc:
            self.input_status.bad_input(str(exc))
            return
        self.sigma_hat = d.values[self._bias.index["sigma_hat"]]

    def reset(self) -> None:
        """Forget the filters' history (Monitor.reset); the QB detector has no state."""
        if isinstance(self.detector, ResidualDetector):
            self.detector.reset()
            if self._fallback is not None:
                self._fallback.reset()
        elif self.detector is None:
            self.detector = ResidualDetector(self.system, as_gains(self.system,
                                                                   self.gain_file))

    def bridge(self, k: int, inputs: dict[str, Any]) -> None:
        """The residual filters start again over a bridged gap (Monitor.bridge); the override
        in force and the alarm episode count are kept."""
        if isinstance(self.detector, ResidualDetector):
            self.detector.reset()

    def process(self, k: int, inputs: dict[str, Any]) -> None:
        """(q^_k, x^_k, y~_k), override -> residual, threshold, alarm at k."""
        est = inputs["est"]
        i_mode, i_x, i_y = self._i_est
        mode, x_hat, y_t = int(est[i_mode]), est[i_x], est[i_y]
        pay = self._step(k, mode, x_hat, y_t, inputs)
        for topic, pub in self.pubs.items():
            lay = self._layouts[topic]
            self.publish_array(pub, lay.labels, k, lay.encode(pay))
        thresholds = isinstance(self.detector, ResidualDetector)
        self.residual_report.report(k, mode, pay["residual"], pay["threshold"], pay["alarm"],
                                    self.sigma_hat if thresholds else None,
                                    self._fallback.note if self._fallback is not None else "")

    def _step_thresholds(self, k: int, mode: int, x_hat: np.ndarray, y_t: np.ndarray,
                         inputs: dict[str, Any]) -> dict[str, Any]:
        override, fb = inputs["override"], self._fallback
        assert fb is not None                    # set with this runtime
        local = fb.local
        # agei's override; while it is absent, the one the local AGEI decided at k - 1
        ov = (local.override if fb.absent(k, override, self.restarting) and local is not None
              else as_floats(override))
        det, r, w, nominal, _ = self.detector.step1(k, as_floats(y_t), as_floats(x_hat), mode,
                                                    ov)
        if local is not None:
            local.decide(k, mode, w, r, nominal)
        return det.payload()

    def _step_qb(self, k: int, mode: int, x_hat: np.ndarray, y_t: np.ndarray,
                 inputs: dict[str, Any]) -> dict[str, Any]:
        det = self.detector
        sig = det.signals(x_hat, self._qb_observer.residual(mode, x_hat, y_t))
        thr = det.rho * det.bounds(mode)
        return {"residual": sig, "threshold": thr, "alarm": sig > thr}


def main(args: Sequence[str] | None = None) -> int:
    """Run the detector node (alone: the in-process chain is ``monitor -p layout:=nodes``)."""
    return run_node(DetectorNode, args, prog="detector", usage=[USAGE])


if __name__ == "__main__":
    import sys

    sys.exit(main())
