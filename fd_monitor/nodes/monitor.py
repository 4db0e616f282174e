"""``monitor``: one node, one join, one runtime step per sample, for every gain file (default),
or the four chain nodes on one executor (``layout:=nodes``, ``thresholds`` gain files): the
one composer of the in-process chain (:func:`make_chain`).

**fused** (default): one lifecycle node joins ``plant/u``, ``plant/y`` and the side signals
the runtime needs (``plant/rho``: the measured scheduling parameters of an LPV bank without a
scheduling map; ``plant/mode``: the switching signal of a plant no guard switches) on the
stamp (plain messages from a driver are stamped on arrival, as the observer does), calls the
registry's runtime of the gain file (:func:`fd_monitor.core.methods.runtime_for`, the one
``analyze`` runs) once per sample, and publishes:

- a ``thresholds`` gain file (:attr:`~fd_monitor.core.runtime.Runtime.CHAIN`): what the
  four-node chain publishes, same topics, same layouts, same bits: ``fd/state_estimate``,
  ``fd/residual``, ``fd/threshold``, ``fd/alarm`` (stamp k), ``fd/guard_event``,
  ``fd/threshold_override``, ``fd/bias_estimate`` (stamp k + 1: decided at k for k + 1);
  /diagnostics channels ``estimate``, ``residual <out>``, ``tracker``, ``bias estimate``;
- any other (qb, hinf_sc, hminus_switched): ``fd/residual`` (the residual evaluation signal
  per channel), ``fd/threshold`` (in force; ``inf`` while a bank settles or when the gain file
  has none), ``fd/alarm`` (1.0 / 0.0), ``fd/state_estimate`` (``mode`` then x^ flattened,
  labels ``x.<state>`` or ``<channel>.<state>`` for a bank), stamp k, labels = the runtime's
  channels; /diagnostics channels ``estimate`` (WARN ``outside certified region``: rho outside
  its design box, a mode the design lacks, x^ or u outside a stated envelope) and
  ``residual <channel>``;

plus ``input`` and ``ros graph``. One join and four or seven publications per sample instead
of the chain's four joins and six subscriptions: what makes the live path keep up at kHz
rates (README, "Measured").

**nodes**: the four nodes ``observer``, ``detector``, ``agei`` and ``bias_estimator`` on one
executor in one process, each with its own name, parameters and diagnostics: the distributed
form of the ``thresholds`` method in one process (bit-identical to the fused node). The old
name of this layout, ``chain``, is still accepted, with one deprecation warning naming
``nodes`` (:data:`DEPRECATED_LAYOUTS`): it only changed its name.

The executor is rclpy's EventsExecutor driven by a ``spin_once`` loop (its ``spin()`` does
nothing in these wheels); see :func:`fd_monitor.nodes.process.run_node`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any, cast

import numpy as np
from rclpy.qos import QoSProfile

from fd_monitor.core.lazy import stored_list
from fd_monitor.core.methods import METHODS, RUNTIMES, load_gains, runtime_class, runtime_for
from fd_monitor.core.runtime import ThresholdsRuntime
from fd_monitor.core.thresholds import as_gains
from fd_monitor.model.errors import FdMonitorError, GainFileError, ImplausibleError, MessageError
from fd_monitor.model.gains import GainFile
from fd_monitor.model.system import System, load_system
from fd_monitor.nodes import agei, bias_estimator, detector, observer
from fd_monitor.nodes.adapter_input import ADAPTER_PARAM
from fd_monitor.nodes.agei import AgeiNode
from fd_monitor.nodes.bias_estimator import BiasEstimatorNode
from fd_monitor.nodes.chain_params import (
    COMMON_PARAMS,
    FAULT_PARAMS,
    GAP_TIMEOUT,
    MAX_GAP_PARAM,
    WARN_SHARE,
)
from fd_monitor.nodes.detector import DetectorNode
from fd_monitor.nodes.diagnostics import OK
from fd_monitor.nodes.fault import FaultReport, fault_report
from fd_monitor.nodes.fd_node import FdNode
from fd_monitor.nodes.inputs import Input
from fd_monitor.nodes.observer import ObserverNode
from fd_monitor.nodes.params import Param
from fd_monitor.nodes.process import run_node
from fd_monitor.nodes.reports import BiasReport, EstimateReport, ResidualReport
from fd_monitor.nodes.robots import ROBOTS, host_robots, robot_namespaces
from fd_monitor.nodes.serialized import SerializedArray
from fd_monitor.nodes.usage import NodeUsage
from fd_monitor.wire.topics import (
    ALARM,
    BIAS_ESTIMATE,
    CHAIN_OUTPUTS,
    DIAGNOSTICS,
    FAULT,
    GUARD_EVENT,
    PLANT_MODE,
    PLANT_RHO,
    PLANT_U,
    PLANT_Y,
    RESIDUAL,
    RUNTIME_OUTPUTS,
    STATE_ESTIMATE,
    THRESHOLD,
    THRESHOLD_OVERRIDE,
    runtime_estimate,
    side_topic,
)

__all__ = ["DEPRECATED_LAYOUTS", "LAYOUTS", "MonitorNode", "USAGE", "companion_name",
           "layout_of", "make_chain", "make_monitors", "make_nodes", "main", "peek_parameters"]

#: u of a plant without inputs; x^ of a runtime without one.
_NO_INPUT = np.zeros(0)

#: monitor's layouts: one fused node, or the chain's four nodes in one process.
LAYOUTS = ("fused", "nodes")
#: Old layout names, accepted with one deprecation warning naming the new one.
DEPRECATED_LAYOUTS = {"chain": "nodes"}

#: s between two full diagnostics reports of the fused node while nothing changes.
DIAG_REFRESH = 0.1

PARAMS = (
    Param("layout", "fused", "fused: one node (one join, one runtime step per sample); "
          "nodes (thresholds gain files): the four nodes observer, detector, agei, "
          "bias_estimator on one executor (their own names, parameters and diagnostics); "
          "chain: the old name of nodes (deprecated)"),
    GAP_TIMEOUT,
    MAX_GAP_PARAM,
    WARN_SHARE,
    Param("enabled", True, "thresholds: AGEI on; false: the ablation without AGEI (never "
          "triggers, no override)"),
    ADAPTER_PARAM,
    *FAULT_PARAMS,
)

USAGE = NodeUsage(
    "monitor", "monitor: one node, one runtime step per sample, for any gain file (the "
    "registry's runtime, as analyze runs it); layout:=nodes with a thresholds gain file: the "
    "four chain nodes in one process; robots:=\"[r1, r2]\": one monitor per robot "
    "namespace in this one process.", (*COMMON_PARAMS, *PARAMS, ROBOTS),
    subscribes=((PLANT_U, "u_k (plants with inputs; stamped, or plain: stamped on arrival)"),
                (PLANT_Y, "y_k (stamped, or plain: stamped on arrival)"),
                (PLANT_RHO, "measured scheduling parameters (LPV bank without a "
                            "scheduling map; stamped k)"),
                (PLANT_MODE, "switching signal (no guard decides the mode; stamped k)")),
    publishes=((STATE_ESTIMATE, "thresholds: mode, x^_k, y~_k, restart, bridge; other methods: "
                "mode, x^ (flattened per generator) (stamp k)"),
               (RESIDUAL, "thresholds: r:<out>, w:<out>; other methods: the residual "
                "evaluation signal per channel (stamp k)"),
               (THRESHOLD, "thresholds: R:<out> in force, rbar:<out> nominal; other "
                "methods: in force per channel, inf = none (stamp k)"),
               (ALARM, "0/1 per channel (stamp k)"),
               (GUARD_EVENT, "thresholds: trigger, phase, row, mode_uncertain "
                "(stamp k + 1)"),
               (THRESHOLD_OVERRIDE, "thresholds: AGEI override per output, NaN = none "
                "(stamp k + 1)"),
               (BIAS_ESTIMATE, "thresholds: sigma^_{k+1}, iso:<out>, active, k_detect "
                "(stamp k + 1)"),
               (FAULT, "the latched fault verdict per channel: fault, isolated, estimate, "
                "since (on change; transient local)"),
               (DIAGNOSTICS, "input, ros graph, estimate, residual <channel>, fault; "
                "thresholds: tracker, bias estimate")))


class MonitorNode(FdNode):
    """The fused node: one join, one registry runtime step per sample, the method's outputs
    (see the module docstring).

    Parameters
    ----------
    system, gains, qos, **kwargs
        See :class:`~fd_monitor.nodes.fd_node.FdNode`.
    node_name : str
    """

    #: the bias estimator's status name (bias_estimator's is ``estimate``)
    bias_channel = "bias estimate"
    #: the fault verdict (at configure)
    fault: FaultReport | None = None

    def __init__(self, system: System | None = None, gains: GainFile | None = None,
                 qos: QoSProfile | None = None, node_name: str = "monitor",
                 **kwargs: Any) -> None:
        super().__init__(node_name, PARAMS, system, gains, qos, **kwargs)

    def start(self) -> None:
        """Check the layout, configure and activate (autostart)."""
        if self.params.layout not in (*LAYOUTS, *DEPRECATED_LAYOUTS):
            raise FdMonitorError(f"node {self.get_name()}: parameter layout: "
                                 f"{self.params.layout!r}: expected one of "
                                 f"{', '.join(LAYOUTS)}")
        super().start()

    def setup(self) -> None:
        """Runtime, publishers, diagnostics and inputs (at configure)."""
        self.start_runtime()

    def _start(self) -> None:
        s = self.system
        self.build_core(self.gain_file)
        rt = self.runtime
        self.pubs = [self.publisher(t) for t in self.outputs]
        self.sigma_hat = [0.0] * s.ny
        stale = self.params.stale_timeout
        self.diag.add("estimate", stale)
        for ch in self.channels:
            self.diag.add(ch, stale)
        if rt.CHAIN:
            self.diag.add("tracker", stale)
            self.diag.add(self.bias_channel, stale, keep_on_stale=True)
        self._channels_all = ["estimate", *self.channels,
                              *(["tracker", self.bias_channel] if rt.CHAIN else [])]
        log = self.get_logger()
        self.estimate_report = EstimateReport(self.diag, log, s, self.gain_values)
        self.residual_report = ResidualReport(self.diag, log, s, self.channels,
                                              lambda: self.params.warn_share, self.gain_values)
        self.bias_report = (BiasReport(self.diag, log, s.outputs, self.gain_values,
                                       self.bias_channel) if rt.CHAIN else None)
        # the verdict: from alarms, and for the chain from the bias estimate and isolation
        self.fault = fault_report(self, rt.channels, as_gains(s, self.gain_file)
                                  .isolation_threshold if rt.CHAIN else None)
        self._last_key: Any = None
        self._next_report = 0.0
        self.start_inputs([
            *([Input.of("u", PLANT_U, s, plain_ok=True, hold=True)] if s.nu else []),
            Input.of("y", PLANT_Y, s, plain_ok=True),
            *(Input.laid_out(n, side_topic(n), side_topic(n).with_labels({n: rt.side_labels[n]}))
              for n in rt.side_inputs),
        ], gap_timeout=self.params.gap_timeout)

    #: every method of the registry runs here
    runtimes: Mapping[str, Callable[[Any], None]] = dict.fromkeys(METHODS, _start)

    # -- the runtime: built, reset and stepped here only ------------------------------------

    def build_core(self, gains: GainFile) -> None:
        """The runtime of ``gains`` (at configure, and when ``gains`` is set: a swap keeps the
        method, channels and side signals)."""
        cls = runtime_class(gains.method)
        options = {"agei": self.params.enabled} if "agei" in cls.options() else {}
        try:
            rt = runtime_for(self.system, gains, **options)
        except GainFileError as exc:
            raise FdMonitorError(str(exc)) from None
        old = getattr(self, "runtime", None)
        if old is not None and (rt.channels != old.channels
                                or rt.side_inputs != old.side_inputs):
            raise FdMonitorError(f"{gains.path}: channels {', '.join(rt.channels)} or side "
                                 f"signals differ from the running ones")
        self.runtime = rt
        #: the thresholds detector (its residual reports add sigma^), else None
        self.detector = cast(ThresholdsRuntime, rt).monitor.detector if rt.CHAIN else None
        #: /diagnostics status (and alarm log) name of each of the runtime's channels
        self.channels = [f"residual {c}" for c in rt.channels]
        self.outputs = CHAIN_OUTPUTS if rt.CHAIN else RUNTIME_OUTPUTS
        #: per topic: its publisher's subscription count and publish, its serializer's
        #: encode, which payload holds each field, k or k + 1 (resolved at the first sample
        #: from the runtime's payloads)
        self._plan: list[tuple[Callable[[], int], Callable[[bytes], None],
                               Callable[[int, Any], bytes], Any, bool]] | None = None

    def reset(self) -> None:
        """Fresh runtime state (a new run: first sample, after a hole, ``~/reset``), as the
        offline run restarts it; no fault."""
        self.runtime.reset()
        if self.fault is not None:
            self.fault.reset()

    def bridge(self, k: int, inputs: dict[str, Any]) -> None:
        """Carry the runtime over a bridged gap (its memory kept), as the offline run
        does."""
        rt = self.runtime
        u = inputs["u"] if self.system.nu else _NO_INPUT
        side = {n: inputs[n] for n in rt.side_inputs} if rt.side_inputs else None
        try:
            rt.bridge(k, u, inputs["y"], side)
        except MessageError as exc:
            raise ImplausibleError(str(exc)) from None

    def _layouts(self, out: Any) -> list[Any]:
        """Each output topic's layout (the generic state estimate's from x^'s shape at the
        first sample: one estimate, or a bank's)."""
        rt, s = self.runtime, self.system
        if rt.CHAIN:
            return [t.layout(s) for t in self.outputs]
        x_hat = out.estimates.get("x_hat", _NO_INPUT)
        return [RESIDUAL.channels(rt.channels), THRESHOLD.channels(rt.channels),
                ALARM.channels(rt.channels), runtime_estimate(s, rt.channels, x_hat)]

    # -- per sample ---------------------------------------------------------------------------

    def process(self, k: int, inputs: dict[str, Any]) -> None:
        """Inputs of k -> one runtime step -> the outputs and the diagnostics."""
        rt = self.runtime
        u = inputs["u"] if self.system.nu else _NO_INPUT
        side = {n: inputs[n] for n in rt.side_inputs} if rt.side_inputs else None
        try:
            out = rt.step(k, u, inputs["y"], side)
        except MessageError as exc:
            # refused by the runtime: reported like a bad message, and a hole at k
            raise ImplausibleError(str(exc)) from None
        pays: Any = None                 # built for the first topic someone subscribes to
        if self._plan is None:
            pays = (*rt.payloads(out), {"restart": self.restarting, "bridge": self.bridging})
            # the count of rclpy's C++ publisher (rclpy's wrapper adds a use count around
            # it: 3-4 calls per topic and sample; the GIL keeps the handle alive meanwhile)
            self._plan = [(pub.handle.get_subscription_count, pub.publish,
                           SerializedArray(lay.labels).encode, lay.sources(pays), t.next_sample)
                          for pub, t, lay in zip(self.pubs, self.outputs, self._layouts(out))]
        stamps = (k, k + 1)
        for subscribed, publish, encode, src, nxt in self._plan:
            # nobody subscribed: DDS would drop the message; skip building it (a count
            # costs ~1 us, a message 5-10 us to assemble, pack and hand to DDS)
            if not subscribed():
                continue
            if pays is None:
                pays = (*rt.payloads(out), {"restart": self.restarting,
                                            "bridge": self.bridging})
            # values as Python numbers (bools and ints pack exactly as float64)
            data: list[Any] = []
            for i, name, scalar in src:
                v = pays[i][name]
                if scalar:
                    data.append(v)
                else:
                    data.extend(v.tolist())
            publish(encode(stamps[nxt], data))
        self._diagnose(k, out)
        # the stored lists: no array made for the verdict's few values
        fault = self.fault
        assert fault is not None                       # configured
        if out.core is not None and self.runtime.CHAIN:
            est = out.core.estimator
            fault.step(k, stored_list(out, "alarm"), stored_list(est, "sigma_hat"),
                       stored_list(est, "isolated"))
        else:
            fault.step(k, stored_list(out, "alarm"))

    def _diagnose(self, k: int, out: Any) -> None:
        """A full report when a status can change (alarms, mode, AGEI phase, estimator,
        certified region) and at least every DIAG_REFRESH s; else the channels are only
        marked fresh. /diagnostics goes out every diagnostics_period anyway."""
        alarm = stored_list(out, "alarm")
        excess = stored_list(out, "outside")
        outside = excess is not None and any(v != 0.0 for v in excess)
        core = out.core if self.runtime.CHAIN else None
        key = (alarm, out.mode, outside, None if core is None else
               (core.agei.phase, core.estimator.active, stored_list(core.estimator,
                                                                    "isolated")))
        now = time.monotonic()
        if key == self._last_key and now < self._next_report:
            self.diag.touch_all(self._channels_all)
            return
        self._last_key, self._next_report = key, now + DIAG_REFRESH
        rt = self.runtime
        x_hat = out.estimates.get("x_hat", _NO_INPUT)
        self.estimate_report.report(k, int(out.mode), x_hat, out.outside,
                                    rt.region_names or None)
        if core is not None:
            self.sigma_hat = core.estimator.sigma_hat
        self.residual_report.report(k, int(out.mode), out.residual, out.threshold, alarm,
                                    self.sigma_hat if self.detector is not None else None)
        if core is not None:
            ag = core.agei
            self.diag.update("tracker", OK, f"phase {ag.phase}", {
                "sample": k, "trigger": ag.trigger, "phase": ag.phase, "row": ag.row,
                **self.gain_values()})
            assert self.bias_report is not None        # a CHAIN runtime
            self.bias_report.report(k, core.estimator)


def companion_name(base: str, default: str, name: str) -> str:
    """The name of node ``name`` beside the main node of a several-node executable: its own
    name when the main one keeps its ``default`` name, else ``<base>_<name>`` (``-r
    __node:=det1``: ``det1_observer``, ``det1_agei``, ...)."""
    return name if base == default else f"{base}_{name}"


def make_chain(**kwargs: Any) -> list:
    """The four chain nodes on one executor: the one composer of the in-process chain
    (``kwargs`` go to every node, e.g. ``context`` and ``parameter_overrides``; a
    ``node_name`` other than ``monitor`` names them ``<name>_observer``, ...).

    The observer, the chain's entry, is created last: by the time it subscribes to
    ``plant/y`` (what a source waits for) the other nodes already subscribe to ``plant/*``
    and to the observer's outputs, so none of them misses the first samples. A node that
    fails to start destroys the ones made before it.
    """
    from rclpy.parameter import Parameter

    base = str(kwargs.pop("node_name", "monitor"))
    given = list(kwargs.pop("parameter_overrides", None) or [])
    # The process's ``layout`` (``-p layout:=nodes`` reaches every node of it) is monitor's:
    # the detector's own, deprecated one is left unset here.
    unset = [Parameter("layout", value="")]
    nodes: list = []
    try:
        for cls, name in ((DetectorNode, "detector"), (AgeiNode, "agei"),
                          (BiasEstimatorNode, "bias_estimator"), (ObserverNode, "observer")):
            nodes.append(cls(**kwargs, node_name=companion_name(base, "monitor", name),
                             parameter_overrides=[*given, *(unset if cls is DetectorNode
                                                           else [])]))
    except Exception:
        for n in nodes:
            n.destroy_node()
        raise
    return [nodes[-1], *nodes[:-1]]


def layout_of(value: str, node_name: str) -> str:
    """``value`` of the ``layout`` parameter, an old name translated (one deprecation
    warning naming the new one, on ``node_name``'s logger)."""
    new = DEPRECATED_LAYOUTS.get(value)
    if new is None:
        return value
    import rclpy.logging

    rclpy.logging.get_logger(node_name).warning(
        f"parameter layout: {value!r} is deprecated: use {new!r} (the same four chain nodes "
        f"in one process; {value!r} will be refused in a later release)")
    return new


def make_nodes(**kwargs: Any) -> list:
    """The fused monitor node, or with ``layout: nodes`` and a gain file whose method has the
    chain (``thresholds``) the four chain nodes (:func:`make_chain`). ``kwargs`` go to every
    node (e.g. ``context``)."""
    name = str(kwargs.get("node_name", "monitor"))
    values = peek_parameters(name, ("system", "gains", "layout"),
                             **{k: v for k, v in kwargs.items() if k != "node_name"})
    layout = layout_of(str(values["layout"]), name)
    method = None
    try:
        system = load_system(str(values["system"]))
        method = load_gains(str(values["gains"]), system, verify=False).method
    except FdMonitorError:
        pass                        # the fused node reports why, at configure
    if layout != "nodes" or method not in RUNTIMES or not runtime_class(method).CHAIN:
        return [MonitorNode(**kwargs)]
    return make_chain(**{**kwargs, "parameter_overrides": [
        p for p in kwargs.get("parameter_overrides", []) if p.name != "layout"]})


def peek_parameters(node_name: str, names: Sequence[str], **kwargs: Any) -> dict[str, Any]:
    """Parameters ``names`` of a node called ``node_name`` as it would see them
    (``--params-file``, ``-p``, ``parameter_overrides``; else their defaults), before the
    node exists: ``monitor`` decides which nodes to make by them."""
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    defaults = {p.name: p.default for p in (*COMMON_PARAMS, *PARAMS, ROBOTS)}
    peek = Node(node_name, allow_undeclared_parameters=True,
                automatically_declare_parameters_from_overrides=True, **kwargs)
    try:
        return {n: peek.get_parameter_or(n, Parameter(n, value=defaults[n])).value
                for n in names}
    finally:
        peek.destroy_node()


def make_monitors(**kwargs: Any) -> list:
    """:func:`make_nodes` once, or with ``robots`` (a process parameter, see
    :mod:`fd_monitor.nodes.robots`) once per robot in ``<namespace>/<robot>``: every robot's
    nodes in this process, on one executor. ``kwargs`` as :func:`make_nodes`'s, plus
    ``namespace`` (the process's)."""
    peek = {k: v for k, v in kwargs.items() if k != "node_name"}
    robots = peek_parameters(str(kwargs.get("node_name", "monitor")), ("robots",),
                             **peek)["robots"]
    if not robots:
        return make_nodes(**kwargs)
    ns = kwargs.pop("namespace", None)
    return host_robots(make_nodes, robot_namespaces(ns, robots), **kwargs)


def main(args: Sequence[str] | None = None) -> int:
    """Run the fused monitor node (or, with ``layout:=nodes``, the four chain nodes), or
    one per robot of ``robots``."""
    return run_node(make_monitors, args, prog="monitor", named=True,
                    usage=[USAGE, *(m.USAGE for m in (observer, detector, agei,
                                                      bias_estimator))])


if __name__ == "__main__":
    import sys

    sys.exit(main())
