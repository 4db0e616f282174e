"""The fused monitor for any gain file: one join, one ``Runtime.step`` per sample.

The runtime comes from the registry (:func:`fd_monitor.core.runtime.runtime_for`), so the
node runs every method a designer writes -- ``qb``, ``hinf_sc`` (LTI, uncertain, LPV),
``hminus_switched`` -- with the arithmetic of the offline run
(:func:`fd_monitor.analysis.offline.run_bag`)
and the same rules for holes and restarts (the entry role of
:class:`~fd_monitor.wire.join.StampJoin`).

Joins, per sample k: ``plant/u`` (when the plant has inputs), ``plant/y`` and the side
signals the runtime needs (``plant/rho``: the measured scheduling parameters of an LPV bank
without a scheduling map; ``plant/mode``: the switching signal of a plant no guard switches),
stamped. Publishes (stamp k), labels = the runtime's channels (one per generator / output):

- ``fd/residual`` -- the residual evaluation signal per channel (``||r_i||`` for hinf_sc and
  hminus_switched, the QB detector's signal for qb), output units;
- ``fd/threshold`` -- the threshold in force per channel (``inf`` while a bank settles or
  when the gain file has none);
- ``fd/alarm`` -- 1.0 / 0.0 per channel;
- ``fd/state_estimate`` -- ``mode`` then the estimate ``x_hat`` flattened (labels
  ``x.<state>``, or ``<channel>.<state>`` for a bank of observers);

and ``/diagnostics``: ``input``, ``ros graph``, ``estimate`` (WARN ``outside certified
region`` with the variable and the excess: rho outside its design box, a mode the design
lacks, x^ or u outside a stated envelope) and one ``residual <channel>`` status per channel.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from fd_monitor.core.runtime import RUNTIMES, runtime_for
from fd_monitor.model.errors import FdMonitorError, GainFileError, ImplausibleError, MessageError
from fd_monitor.model.gains import GainFile, load_gains
from fd_monitor.model.system import load_system
from fd_monitor.nodes.adapter_input import ADAPTER_PARAM
from fd_monitor.nodes.common import ERROR, OK, WARN, NodeUsage
from fd_monitor.nodes.detector import ResidualReport
from fd_monitor.nodes.fd_node import COMMON_PARAMS, GAP_TIMEOUT, WARN_SHARE, FdNode, Input
from fd_monitor.nodes.observer import EstimateReport
from fd_monitor.wire.topics import (
    ALARM,
    DIAGNOSTICS,
    PLANT_MODE,
    PLANT_RHO,
    PLANT_U,
    PLANT_Y,
    RESIDUAL,
    STATE_ESTIMATE,
    THRESHOLD,
    Layout,
    runtime_estimate,
    side_topic,
)

__all__ = ["RuntimeNode", "PARAMS", "USAGE", "gain_method"]

PARAMS = (
    GAP_TIMEOUT,
    WARN_SHARE,
    ADAPTER_PARAM,
)


USAGE = NodeUsage(
    "monitor", "monitor with a qb, hinf_sc or hminus_switched gain file: one node, one "
    "runtime step per sample (the registry's runtime, as analyze runs it).",
    (*COMMON_PARAMS, *PARAMS),
    subscribes=((PLANT_U, "u_k (plants with inputs; stamped, or plain)"),
                (PLANT_Y, "y_k (stamped, or plain: stamped on arrival)"),
                (PLANT_RHO, "measured scheduling parameters (LPV bank without a "
                            "scheduling map; stamped k)"),
                (PLANT_MODE, "switching signal (no guard decides the mode; stamped k)")),
    publishes=((RESIDUAL, "residual evaluation signal per channel (stamp k)"),
               (THRESHOLD, "threshold in force per channel, inf = none (stamp k)"),
               (ALARM, "0/1 per channel (stamp k)"),
               (STATE_ESTIMATE, "mode, x^ (flattened per generator) (stamp k)"),
               (DIAGNOSTICS, "input, estimate (WARN outside certified region), residual "
                                "<channel>")))


class RuntimeNode(EstimateReport, ResidualReport, FdNode):
    """One node running the registry's runtime of any gain file (see the module docstring).

    Parameters
    ----------
    system, gains, qos, **kwargs
        See :class:`~fd_monitor.nodes.fd_node.FdNode`.
    node_name : str
    """

    runtimes: Mapping[str, str] = {m: "_start" for m in RUNTIMES}
    outputs = (RESIDUAL, THRESHOLD, ALARM, STATE_ESTIMATE)

    def __init__(self, system=None, gains=None, qos=None, node_name: str = "monitor",
                 **kwargs: Any) -> None:
        super().__init__(node_name, PARAMS, system, gains, qos, **kwargs)

    def setup(self) -> None:
        """Publishers, the runtime, the inputs (at configure)."""
        self.pubs = {t: self.publisher(t) for t in self.outputs}
        self.start_runtime()

    def _start(self) -> None:
        self.build_core(self.gain_file)
        s = self.system
        rt = self.runtime
        self.diag.add("estimate", self.params.stale_timeout)
        for ch in self.channels:
            self.diag.add(ch, self.params.stale_timeout)
        self.start_inputs([
            *([Input.of("u", PLANT_U, s, plain_ok=True, hold=True)] if s.nu else []),
            Input.of("y", PLANT_Y, s, plain_ok=True),
            *(Input.laid_out(n, side_topic(n), side_topic(n).with_labels({n: rt.side_labels[n]}))
              for n in rt.side_inputs),
        ], gap_timeout=self.params.gap_timeout)

    def build_core(self, gains: GainFile) -> None:
        """The runtime of ``gains`` (a swap keeps the method, so channels and inputs hold)."""
        try:
            rt = runtime_for(self.system, gains)
        except GainFileError as exc:
            raise FdMonitorError(str(exc)) from None
        old = getattr(self, "runtime", None)
        if old is not None and (rt.channels != old.channels
                                or rt.side_inputs != old.side_inputs):
            raise FdMonitorError(f"{gains.path}: channels {', '.join(rt.channels)} or side "
                                 f"signals differ from the running ones")
        self.runtime = rt
        #: /diagnostics status (and alarm log) name of each of the runtime's channels.
        self.channels = tuple(f"residual {c}" for c in rt.channels)
        #: residual, threshold, alarm: one value per channel of the runtime
        self._layouts = [(t, t.channels(rt.channels)) for t in (RESIDUAL, THRESHOLD, ALARM)]
        #: fd/state_estimate: mode and x^ (its labels known at the first estimate's shape)
        self._state: Layout | None = None
        self._alarmed: set[str] = set()
        self._episode = 0
        self._was_outside = False

    def reset(self) -> None:
        """Fresh runtime state, as the offline run restarts it after a hole."""
        self.runtime.reset()

    def process(self, k: int, inputs: dict[str, Any]) -> None:
        """Inputs of k -> one ``Runtime.step`` -> outputs and /diagnostics."""
        rt = self.runtime
        u = inputs["u"] if self.system.nu else np.zeros(0)
        side = {n: inputs[n] for n in rt.side_inputs}
        try:
            out = rt.step(k, u, inputs["y"], side or None)
        except MessageError as exc:
            # refused by the runtime: reported like a bad message, and a hole at k
            raise ImplausibleError(str(exc)) from None
        pay = {"residual": out.residual, "threshold": out.threshold, "alarm": out.alarm}
        for t, lay in self._layouts:
            self.publish_array(self.pubs[t], lay.labels, k, lay.encode(pay))
        x_hat = np.asarray(out.estimates.get("x_hat", np.zeros(0)), float)
        if self._state is None:
            self._state = runtime_estimate(self.system, rt.channels, x_hat)
        self.publish_array(self.pubs[STATE_ESTIMATE], self._state.labels, k,
                           self._state.encode({"mode": out.mode, "x_hat": x_hat}))
        self._report_sample(k, out, x_hat)

    def _report_sample(self, k: int, out: Any, x_hat: np.ndarray) -> None:
        self.report_estimate(k, out.mode, x_hat, out.outside, self.runtime.region_names)
        mode = self.mode_name(out.mode)
        self._log_alarms(k, out.residual, out.threshold, out.alarm)
        share = self.params.warn_share
        for i, c in enumerate(self.channels):
            r, R = float(out.residual[i]), float(out.threshold[i])
            if out.alarm[i]:
                level, msg = ERROR, "alarm: |residual| > threshold"
            elif abs(r) > share * R:
                level, msg = WARN, f"|residual| > {share:g} x threshold"
            else:
                level, msg = OK, "ok"
            self.diag.update(c, level, msg,
                             {"sample": k, "residual": r, "threshold": R,
                              "margin": R - abs(r), "mode": mode, **self.gain_values()})


def gain_method(node_name: str = "monitor", **kwargs: Any) -> str | None:
    """The ``method`` of the gain file a node called ``node_name`` would load, from its
    parameters as the node would see them (``--params-file``, ``-p``, ``parameter_overrides``),
    before the node exists: ``monitor`` picks its node class by it. None when the plant or
    the gain file does not load (the node itself then reports why, at configure).
    """
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    defaults = {p.name: p.default for p in COMMON_PARAMS}
    peek = Node(node_name, allow_undeclared_parameters=True,
                automatically_declare_parameters_from_overrides=True, **kwargs)
    try:
        values = {n: peek.get_parameter_or(n, Parameter(n, value=defaults[n])).value
                  for n in ("system", "gains")}
    finally:
        peek.destroy_node()
    try:
        system = load_system(str(values["system"]))
        return str(load_gains(str(values["gains"]), system, verify=False).method)
    except FdMonitorError:
        return None
