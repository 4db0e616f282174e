"""``observer``: the hybrid automaton observer (Heracleous et al., eq. 5-7) as a node.

Joins, per sample k: ``/plant/u`` (u_k), ``/plant/y`` (y_k) (plain messages from a driver
are accepted and stamped on arrival), ``/fd/bias_estimate`` (sigma^_k, published by the
bias estimator at k - 1, stamped k) and ``/fd/guard_event`` (the AGEI trigger decided at
k - 1, stamped k). Publishes ``/fd/state_estimate`` (stamp k): ``mode``, x^_k (states),
y~_k = y_k - sigma^_k (``y~<output>``), ``restart`` (1 at the first sample and at the first
valid sample after a hole longer than ``max_gap``: downstream nodes reset there) and ``bridge``
(1 at the first valid sample after a shorter hole: downstream nodes bridge it too).

With a ``qb`` gain file it runs :class:`~fd_monitor.core.qb.QBObserver` on ``/plant/u`` (when
the plant has inputs) and ``/plant/y`` and publishes the same layout (y~ = y).

The observer is the chain's entry: it declares the holes in the data (a rejected message, or
a later sample complete for ``gap_timeout`` s) and bridges (at most ``max_gap`` lost
samples) or restarts at the next valid sample, as the offline runner does
(:func:`fd_monitor.analysis.offline.run_bag`).

While ``agei``'s guard events are absent (agei killed, restarting, not started) the observer
takes them from its own copy of AGEI (``agei_fallback``,
:class:`~fd_monitor.core.local_agei.LocalAgei`: the same code on the same residuals), so a
guard crossing during the outage switches the mode as the fused monitor does; the ``agei``
status says so (WARN).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from rclpy.qos import QoSProfile

from fd_monitor.core.envelope import CertifiedRegion
from fd_monitor.core.filters import as_floats
from fd_monitor.core.hybrid_observer import NO_TRIGGER, HybridObserver, ObserverOutput
from fd_monitor.core.qb import QBObserver
from fd_monitor.model.gains import GainFile
from fd_monitor.model.system import System
from fd_monitor.nodes.agei_fallback import AGEI_FALLBACK, AgeiFallback
from fd_monitor.nodes.chain_params import COMMON_PARAMS, GAP_TIMEOUT, MAX_GAP_PARAM
from fd_monitor.nodes.fd_node import FdNode
from fd_monitor.nodes.inputs import Input
from fd_monitor.nodes.process import run_node
from fd_monitor.nodes.reports import EstimateReport
from fd_monitor.nodes.usage import NodeUsage
from fd_monitor.wire.topics import (
    BIAS_ESTIMATE,
    DIAGNOSTICS,
    GUARD_EVENT,
    PLANT_U,
    PLANT_Y,
    STATE_ESTIMATE,
)

__all__ = ["ObserverNode", "USAGE", "main"]

PARAMS = (
    GAP_TIMEOUT,
    MAX_GAP_PARAM,
    AGEI_FALLBACK,
)

USAGE = NodeUsage(
    "observer", "observer: the hybrid observer (or the QB observer for a qb gain file).",
    (*COMMON_PARAMS, *PARAMS),
    subscribes=((PLANT_U, "u_k (stamped, or plain: stamped on arrival)"),
                (PLANT_Y, "y_k (stamped, or plain: stamped on arrival)"),
                (BIAS_ESTIMATE, "sigma^_k from bias_estimator (stamped k)"),
                (GUARD_EVENT, "AGEI trigger for k (stamped k)")),
    publishes=((STATE_ESTIMATE, "mode, x^_k, y~_k, restart (1: first sample, or "
                "first after a hole longer than max_gap), bridge (1: first after a shorter "
                "one) (stamp k)"),
               (DIAGNOSTICS, "input and estimate status (WARN 'outside certified "
                "region' when x^ or u leave the gain file's certified envelope), agei (WARN "
                "while agei's guard events are absent)")))


class ObserverNode(FdNode):
    """Observer node: the hybrid observer (``thresholds``) or the QB observer (``qb``).

    Parameters
    ----------
    observer : HybridObserver, optional
        ``thresholds`` only; default: built for the ``system`` parameter.
    system, gains, qos, **kwargs
        See :class:`~fd_monitor.nodes.fd_node.FdNode`.
    """

    outputs = (STATE_ESTIMATE,)

    def __init__(self, observer: HybridObserver | None = None, system: System | None = None,
                 gains: GainFile | None = None, qos: QoSProfile | None = None,
                 node_name: str = "observer", **kwargs: Any) -> None:
        self._observer_arg = observer
        super().__init__(node_name, PARAMS, system, gains, qos, **kwargs)

    def setup(self) -> None:
        """Publisher, observer and inputs (at configure)."""
        self.observer: Any = self._observer_arg
        self._fallback: AgeiFallback | None = None      # thresholds: set by _start_hybrid
        self._outside: np.ndarray | None = None
        self.pub = self.publisher(STATE_ESTIMATE)
        self._state = STATE_ESTIMATE.layout(self.system)
        self.diag.add("estimate", self.params.stale_timeout)
        self.estimate_report = EstimateReport(self.diag, self.get_logger(), self.system,
                                              self.gain_values)
        self.start_runtime()

    def build_core(self, gains: Any) -> None:
        """A new observer for another gain file (the hybrid observer does not use gains)."""
        if gains.method == "qb":
            self.observer = QBObserver(self.system, gains)
        elif self._fallback is not None:
            self._fallback.new_gains(gains)

    def _start_hybrid(self) -> None:
        s = self.system
        if self.observer is None:
            self.observer = HybridObserver(
                s, region=CertifiedRegion.from_results(s, self.gain_file.results))
        bias, guard = BIAS_ESTIMATE.layout(s), GUARD_EVENT.layout(s)
        # fields of the feedback, resolved once: sigma^ and the guard trigger
        self._i_sigma, self._i_trigger = bias.index["sigma_hat"], guard.index["trigger"]
        no_trigger = np.zeros(len(guard.labels))
        no_trigger[self._i_trigger] = float(NO_TRIGGER)
        self._fallback = AgeiFallback(self, True, no_trigger, "guard events")
        self.start_inputs([
            Input.of("u", PLANT_U, s, plain_ok=True, hold=True),
            Input.of("y", PLANT_Y, s, plain_ok=True),
            Input.of("sigma", BIAS_ESTIMATE, s, initial=np.zeros(len(bias.labels))),
            Input.of("guard", GUARD_EVENT, s, initial=no_trigger),
        ], gap_timeout=self.params.gap_timeout)
        self._step = self._step_hybrid

    def _start_qb(self) -> None:
        s = self.system
        self.observer = QBObserver(s, self.gain_file)
        # The region the QB file certifies, when it states one (as the qb runtime checks it).
        self._qb_region = CertifiedRegion.from_results(s, self.gain_file.results)
        # A plant without inputs has no /plant/u (offline: u = () at every sample).
        self.start_inputs([
            *([Input.of("u", PLANT_U, s, plain_ok=True, hold=True)] if s.nu else []),
            Input.of("y", PLANT_Y, s, plain_ok=True),
        ], gap_timeout=self.params.gap_timeout)
        self._step = self._step_qb

    runtimes: Mapping[str, Callable[[Any], None]] = {
        "thresholds": _start_hybrid, "qb": _start_qb}

    def reset(self) -> None:
        """Fresh observer state, as the offline runner restarts it after a hole."""
        if isinstance(self.observer, QBObserver):
            self.observer = QBObserver(self.system, self.gain_file)
        elif self.observer is None:
            self.observer = HybridObserver(self.system)
        else:
            self.observer.reset()                # Monitor.reset
        if self._fallback is not None:
            self._fallback.reset()

    def bridge(self, k: int, inputs: dict[str, Any]) -> None:
        """Carry the observer over a bridged gap, as the fused runtime does: the hybrid
        observer re-initialises x^ from the next compensated measurement (mode kept), the QB
        observer predicts through the gap (u and y interpolated)."""
        if isinstance(self.observer, QBObserver):
            u = inputs["u"] if self.system.nu else np.zeros(0)
            self.observer.bridge(k, u, inputs["y"])
        elif self.observer is not None:
            self.observer.bridge()
            if self._fallback is not None:
                self._fallback.bridge()

    def _step_hybrid(self, k: int, inputs: dict[str, Any]) -> ObserverOutput:
        guard, fb = inputs["guard"], self._fallback
        assert fb is not None                    # set with this runtime
        local = fb.local
        # agei's trigger; while it is absent, the one the local AGEI decided at k - 1
        trigger = (local.trigger if fb.absent(k, guard, self.restarting) and local is not None
                   else int(guard[self._i_trigger]))
        out, x_hat, y_t = self.observer.step1(k, as_floats(inputs["u"]), as_floats(inputs["y"]),
                                              as_floats(inputs["sigma"][self._i_sigma]),
                                              trigger)
        if local is not None:
            local.observe(k, int(out.mode), y_t, x_hat)
        self._outside = out.outside
        return out

    def _step_qb(self, k: int, inputs: dict[str, Any]) -> ObserverOutput:
        u = inputs["u"] if self.system.nu else np.zeros(0)
        mode, x_hat = self.observer.step(k, u, inputs["y"])
        self._outside = (None if self._qb_region is None
                         else self._qb_region.excess(mode, x_hat, np.asarray(u, float)))
        # y~ = y (no accommodation)
        return ObserverOutput(k, mode, x_hat, np.asarray(inputs["y"], float))

    def process(self, k: int, inputs: dict[str, Any]) -> None:
        """Inputs of k -> ObserverOutput.payload and ``restart`` on the state estimate."""
        out = self._step(k, inputs)
        lay = self._state
        self.publish_array(self.pub, lay.labels, k,
                           lay.encode(out.payload(), restart=self.restarting,
                                      bridge=self.bridging))
        self.estimate_report.report(k, int(out.mode), np.ravel(out.x_hat), self._outside)


def main(args: Sequence[str] | None = None) -> int:
    """Run the observer node."""
    return run_node(ObserverNode, args, prog="observer", usage=[USAGE])


if __name__ == "__main__":
    import sys

    sys.exit(main())
