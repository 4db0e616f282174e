"""Base of the diagnosis-chain nodes: lifecycle, parameters, plant and gains, joined inputs,
diagnostics.

Each chain node (observer, detector, agei, bias_estimator) is a lifecycle node
(:class:`rclpy.lifecycle.LifecycleNode`). ``configure`` loads and verifies the plant and the
gain file, creates publishers and subscriptions and calls the subclass's :meth:`setup`;
``activate`` starts processing (messages received while inactive are counted and dropped);
``deactivate`` stops it (every /diagnostics status reads ``inactive``); ``cleanup`` destroys
what configure made; ``shutdown`` (also at the end of the process: :meth:`FdNode.finish`)
stops everything. Each transition is one log line. With ``autostart`` (default true) a node
configures and activates itself when constructed, and hands over to a lifecycle manager: the
first ``configure`` asked on ``~/change_state`` (nav2's lifecycle_manager, launch_ros'
``LifecycleNode``) takes the autostarted node back through deactivate and cleanup, then
configures it as asked (see :meth:`FdNode._on_change_state_request`). ``~/reset``
(``std_srvs/Trigger``) starts a new run of the whole chain: the chain's entry (the node that
reads ``plant/y``: observer or monitor) forgets the stream, so its next complete sample starts
a new run, flagged ``restart`` to every node downstream; any other node asks the entry on
``fd/reset``.

Each node declares its inputs (relative topic, expected labels, required or feedback with its
initial value) and implements ``process(k, inputs)`` — message -> ``np.asarray`` -> core step
-> message -> publish. This base decodes and validates every message
(:func:`~fd_monitor.wire.conversions.decode`), pairs plain (unstamped) messages by
sample-and-hold (a plain ``plant/y`` gets the latest ``plant/u`` published before it, by
the DDS source timestamps; no u yet: reported, sample not processed), joins inputs on the stamp
through the input policy offline reading shares (:class:`~fd_monitor.wire.stream.InputStream`:
per-topic order check, :class:`~fd_monitor.wire.join.StampJoin`: holes, stray stamps beyond
``stamp_horizon``, a stream that restarts lower = a new run after ``restart_after`` s),
and reports on
``/diagnostics``: an ``input`` channel (OK; WARN with the de-duplicated reasons of the bad
messages; STALE when no input came for ``stale_timeout`` s), a ``ros graph`` channel
(incompatible QoS, a second publisher on this node's output topics) plus the node's own
channels. A bad message is logged (throttled: one line per ``log_throttle`` s with the count
of the others), reported, and dropped before it reaches the join.

Feedback messages (``fd/bias_estimate``, ``fd/guard_event``, ``fd/threshold_override``) are
stamped with the sample they are *for* (k + 1 when decided at k), so every join is on equal
stamps.

Why one module of ~760 lines: one lifecycle base class with its inputs and reports; issue 22
item 2 (reports as small objects, one job per file) splits it, deferred while the nodes were
being changed by other work.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
from lifecycle_msgs.msg import State, Transition
from rcl_interfaces.msg import SetParametersResult
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message
from rclpy.subscription import Subscription
from std_msgs.msg import Empty, Float64MultiArray

from fd_monitor.core.methods import load_gains
from fd_monitor.model.errors import FdMonitorError, ImplausibleError, MessageError
from fd_monitor.model.gains import GainFile
from fd_monitor.model.system import System, load_system
from fd_monitor.nodes.adapter_input import AdapterInput
from fd_monitor.nodes.common import (
    DEFAULT_DEPTH,
    MAX_MESSAGE,
    OK,
    WAITING,
    WARN,
    DataInput,
    Diagnostics,
    Param,
    SerializedArray,
    data_pub_qos,
    declare_parameters,
    default_hardware_id,
    incompatible_text,
    pub_events,
)
from fd_monitor.wire.conversions import ArrivalStamper, RawDecoder, readable_stamp
from fd_monitor.wire.join import Sample, StampJoin
from fd_monitor.wire.stream import (
    BATCH_PACE,
    MAX_GAP,
    MAX_LAG,
    RESTART_AFTER,
    STAMP_HORIZON,
    InputStream,
    TopicOrder,
)
from fd_monitor.wire.stream import GAP_TIMEOUT as GAP_TIMEOUT_S
from fd_monitor.wire.topics import RESET, Layout, Topic

__all__ = ["COMMON_PARAMS", "FAULT_PARAMS", "MAX_GAP_PARAM", "RUNTIME_PARAMS", "FdNode",
           "Input", "load_plant_and_gains"]

#: The join's hole timeout, of every node that joins plant/u and plant/y.
GAP_TIMEOUT = Param("gap_timeout", GAP_TIMEOUT_S, "s a later sample must have been complete "
                    "before a missing one is declared lost (a hole: restart at the next valid "
                    "sample); absorbs out-of-order publication", low=0.001, high=3600.0)
#: The longest hole bridged, of every node that joins plant/u and plant/y.
MAX_GAP_PARAM = Param("max_gap", MAX_GAP, "lost samples in a row that are bridged: the run "
                      "goes on with its estimates, alarm and isolation memory; a longer hole "
                      "restarts the run (fresh state); 0: every hole restarts", low=0,
                      high=1000000)
#: The per-channel WARN level of every node that detects.
WARN_SHARE = Param("warn_share", 0.8, "WARN when |residual| exceeds this share of its "
                   "threshold", read_only=False, low=0.0, high=1.0)

COMMON_PARAMS = (
    Param("system", "three_tank", "plant file, or the name of a shipped plant"),
    Param("gains", "three_tank_thresholds", "gain file (path or name in config/gains/); "
          "loaded and its certificate re-verified at configure; settable at runtime (a bad "
          "one is refused, the old one keeps running)", read_only=False),
    Param("autostart", True, "configure and activate at start; a lifecycle manager's first "
          "configure then takes over (deactivate, cleanup, configure as asked); false: wait "
          "for lifecycle transitions"),
    Param("hardware_id", "", "hardware_id of the /diagnostics statuses; empty: "
          "<namespace>/<plant> (the plant alone in the root namespace)"),
    Param("stale_timeout", 2.0, "s without input before the input channel turns STALE",
          read_only=False, low=0.01, high=1.0e6),
    Param("diagnostics_period", 1.0, "s between /diagnostics publications",
          read_only=False, low=0.01, high=3600.0),
    Param("log_throttle", 1.0, "s between two log lines about bad input (the others are "
          "counted)", read_only=False, low=0.0, high=3600.0),
    Param("stamp_horizon", STAMP_HORIZON, "samples above the next expected stamp beyond which a "
          "stamp is held as a possible new run, not joined", low=1, high=2**53),
    Param("restart_after", RESTART_AFTER, "s without progress before held stamps (a stream that "
          "restarted lower, or jumped beyond the horizon) become a new run", low=0.001,
          high=3600.0),
    Param("qos_depth", DEFAULT_DEPTH, "history depth of the publishers", low=10,
          high=1000000),
    Param("max_pending", 100000, "samples buffered while waiting for inputs", low=10,
          high=10000000),
    Param("max_lag", MAX_LAG, "s a complete sample may wait behind a backlog before the "
          "node sheds load: it skips to the newest complete sample (counted: shed_samples "
          "on /diagnostics); at least gap_timeout; never for a batch (batch_pace); 0.0: "
          "never", low=0.0, high=3600.0),
    Param("batch_pace", BATCH_PACE, "x real time: a backlog that came faster than this "
          "(a flat-out replay or simulation, lossless) is a batch: processed completely, "
          "never shed; 0.0: nothing is a batch (every backlog older than max_lag is shed)",
          low=0.0, high=1.0e9),
)

#: The fault verdict's rule (:class:`~fd_monitor.core.verdict.VerdictRule`), of the nodes
#: that publish ``fd/fault`` (monitor, bias_estimator).
FAULT_PARAMS = (
    Param("fault_confirm", 3, "fault verdict: alarms of a channel within fault_window that "
          "set its fault", low=1, high=100000),
    Param("fault_window", 1.0, "fault verdict: s of plant time over which alarms are counted",
          low=0.0, high=1.0e6),
    Param("fault_clear_after", 5.0, "fault verdict: s of plant time without evidence (alarm, "
          "isolation, significant estimate) after which a fault clears (or ~/reset)",
          low=0.0, high=1.0e6),
)

#: s a plain sample waits for a later held input (``plant/u``) before it is paired with the
#: latest one published before it.
HOLD_WAIT = 0.1

#: The ``ros graph`` status without a standing problem.
_GRAPH_OK = "no QoS incompatibility, no other publisher on our outputs"

#: Input-policy reports that are warnings, not dropped messages (wire.stream kinds).
_WARN_ONLY = frozenset(("out_of_order", "hole", "bridge", "feedback_lost", "new_run",
                        "shed", "feedback_back"))

#: Parameters that take effect when set (the others are read-only).
RUNTIME_PARAMS = ("gains", "stale_timeout", "diagnostics_period", "log_throttle",
                  "warn_share")


@dataclass(frozen=True)
class Input:
    """One joined input of a node.

    Attributes
    ----------
    name : str
        Key in ``process``'s inputs.
    topic : str
        Relative topic name (resolved in the node's namespace).
    labels : tuple of str, optional
        Expected channel names (None: accept any, check ``size`` only).
    size : int, optional
    initial : object
        For feedback inputs: the value at the node's first sample; ``None`` = required.
    plain_ok : bool
        Accept unstamped messages (a user's driver).
    hold : bool
        A plain message is held (sample-and-hold): each plain message of the other plain
        inputs (``plant/y``) gets the latest held one published before it.
    allow_nan : bool
        NaN is a value (``fd/threshold_override``: no override).
    stamp_offset : int
        Joined at ``stamp + stamp_offset``: -1 for a feedback message (stamped k + 1) that
        is needed at the sample it was decided at (k).
    sequence : bool
        ``fd/state_estimate`` of the entry node: its stamps are the samples this node
        processes and its ``restart`` field flags a restart (downstream role of
        :class:`~fd_monitor.wire.join.StampJoin`).
    layout : Layout, optional
        The topic's layout for the plant (:meth:`of`): labels and field index table, built
        once; ``process`` reads the fields through it.
    """

    name: str
    topic: str
    labels: tuple[str, ...] | None = None
    size: int | None = None
    initial: Any = None
    plain_ok: bool = False
    hold: bool = False
    allow_nan: bool = False
    stamp_offset: int = 0
    sequence: bool = False
    layout: Layout | None = None

    def __post_init__(self) -> None:
        if self.sequence and self.layout is None:
            raise ValueError(f"input {self.name}: a sequence input is read by field: give "
                             f"its layout (Input.of)")

    @classmethod
    def of(cls, name: str, topic: Topic, source: Any, **kwargs: Any) -> Input:
        """The input of a declared topic (:mod:`fd_monitor.wire.topics`) for a plant."""
        return cls.laid_out(name, topic, topic.layout(source), **kwargs)

    @classmethod
    def laid_out(cls, name: str, topic: Topic, layout: Layout, **kwargs: Any) -> Input:
        """The input of a declared topic with a given layout (a runtime's own labels)."""
        return cls(name, topic.name, layout.labels, layout=layout, **kwargs)


def load_plant_and_gains(system_src: str, gains_src: str) -> tuple[System, GainFile]:
    """Load the plant and its gain file (certificate re-verified); one-line errors."""
    system = load_system(system_src)
    return system, load_gains(gains_src, system)


class FdNode(LifecycleNode):
    """A chain node: subclasses implement :meth:`setup` and :meth:`process`.

    Parameters
    ----------
    node_name : str
    params : sequence of Param
        The node's own parameters (the common ones are added).
    system, gains : optional
        Injected plant and gain file (tests, composition); default from the parameters.
    qos : rclpy.qos.QoSProfile, optional
        Publisher QoS.
    **kwargs
        Passed to :class:`rclpy.lifecycle.LifecycleNode`.

    Raises
    ------
    FdMonitorError
        With ``autostart``: configure failed (bad plant, gain file, parameter).
    """

    inputs: Sequence[Input] = ()
    #: ``run_node`` runs the node on rclpy's EventsExecutor (plain inputs still get their
    #: source timestamps: :func:`~fd_monitor.nodes.common.with_message_info`).
    events_executor = True
    #: Gain-file method (a name of :data:`fd_monitor.core.methods.METHODS`) -> the function
    #: building the node's runtime for it, called with the node (:meth:`start_runtime`).
    runtimes: Mapping[str, Callable[[Any], None]] = {}
    #: Output topics, for the start line and the second-publisher check.
    outputs: Sequence[Topic] = ()

    def __init__(self, node_name: str, params: Sequence[Param] = (),
                 system: System | None = None, gains: GainFile | None = None,
                 qos: QoSProfile | None = None, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = declare_parameters(self, (*COMMON_PARAMS, *params))
        self._injected = (system, gains)
        self._qos_arg = qos
        self.active = False
        self.configured = False
        self._error: FdMonitorError | None = None
        self._autostarting = False
        #: configured by autostart, and no lifecycle request came yet (a manager's first
        #: configure takes over)
        self._autostarted = False
        self._shut_down = False
        self._entities: list[Any] = []
        #: labels -> serialized layout of publish_array
        self._serialized: dict[tuple[str, ...], SerializedArray] = {}
        #: The robot's topics giving u and y, when the node has an adapter file (at start).
        self.adapter_input: AdapterInput | None = None
        from std_srvs.srv import Trigger

        self.create_service(Trigger, "~/reset", self._on_reset)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        srv = getattr(self, "_service_change_state", None)
        if srv is not None:
            # rclpy's own handler, behind the hand-over to a lifecycle manager
            srv.callback = partial(self._on_change_state_request, srv.callback)
        if self.params.autostart:
            self.start()
            self._autostarted = True

    # -- lifecycle ------------------------------------------------------------------------------

    def start(self) -> None:
        """Configure and activate (autostart); raise the configure error, if any."""
        self._error = None
        self._autostarting = True
        try:
            self.trigger_configure()
        finally:
            self._autostarting = False
        if self._error is not None:
            raise self._error
        if not self.configured:
            raise FdMonitorError(f"node {self.get_name()}: configure failed")
        self.trigger_activate()

    def _on_change_state_request(self, handler: Callable[[Any, Any], Any], request: Any,
                                 response: Any) -> Any:
        """``~/change_state``: hand an autostarted node over to a lifecycle manager.

        nav2's lifecycle_manager and launch_ros' ``LifecycleNode(autostart=True)`` start a
        node with ``configure`` then ``activate`` (and check the state reached). A node that
        configured itself (``autostart``) would refuse that ``configure`` ("Unknown
        transition requested"), so the first ``configure`` requested of it takes it back
        through deactivate and cleanup (its run is forgotten) and then configures as asked;
        from then on the manager's requests go to rclpy's state machine unchanged.
        """
        t = request.transition
        if self._autostarted:
            self._autostarted = False
            asked = t.label == "configure" or (not t.label
                                               and t.id == Transition.TRANSITION_CONFIGURE)
            state = self._state_machine.current_state[0]
            if asked and state in (State.PRIMARY_STATE_ACTIVE, State.PRIMARY_STATE_INACTIVE):
                self.get_logger().info("lifecycle manager: configure asked of this "
                                       "autostarted node: handing over (deactivate, cleanup, "
                                       "then configure as asked)")
                if state == State.PRIMARY_STATE_ACTIVE:
                    self.trigger_deactivate()
                self.trigger_cleanup()
        return handler(request, response)

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Load and verify plant and gain file, create publishers and subscriptions."""
        try:
            self._configure()
        except FdMonitorError as exc:
            self._error = exc
            self._destroy_entities()
            if not self._autostarting:           # else start() raises: one line from main
                self.get_logger().error(f"configure failed: {exc}")
            return TransitionCallbackReturn.FAILURE
        self.configured = True
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Start processing."""
        self.active = True
        waits = ", ".join(self._waits_for())
        self.get_logger().info(f"active: waiting for {waits}")
        self.diag.set_waiting(WAITING, {"input": f"active: waiting for {waits}"})
        self._graph_status()                   # a standing graph problem is still one
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop processing (messages are dropped and counted until activated again); every
        status reads ``inactive``."""
        self.active = False
        self.get_logger().info(f"inactive: processed {self.processed} samples; input is "
                               f"dropped until activated")
        self.diag.set_inactive("inactive: input dropped until activated")
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Destroy what configure made; forget plant, gains and state."""
        self._destroy_entities()
        self.configured = False
        self.get_logger().info("cleaned up: unconfigured")
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop processing and destroy what configure made (one log line)."""
        self._log_shutdown(state.label)
        self.active = False
        self._destroy_entities()
        self.configured = False
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """A transition raised: log it, destroy what configure made (back to unconfigured)."""
        self.get_logger().error(f"error in a lifecycle transition (from {state.label}): "
                                f"unconfigured")
        self.active = False
        self._destroy_entities()
        self.configured = False
        return TransitionCallbackReturn.SUCCESS

    def _shutdown_text(self, label: str) -> str:
        done = f"; processed {self.processed} samples" if self.configured else ""
        return f"shut down (from {label}){done}"

    def _log_shutdown(self, label: str) -> None:
        if not self._shut_down:
            self._shut_down = True
            self.get_logger().info(self._shutdown_text(label))

    def finish(self) -> None:
        """The shutdown transition at the end of the process (before ``destroy_node``).

        When the context is gone already (SIGINT, SIGTERM) no transition can be announced and
        the node's rosout publisher is dead: the log line is left in ``final_log`` (logger
        name, text) for :func:`~fd_monitor.nodes.common.run_node` to write once the node is
        destroyed (console and log file only).
        """
        state_id, label = self._state_machine.current_state
        if state_id == State.PRIMARY_STATE_FINALIZED or self._shut_down:
            return
        if self.context.ok():
            try:
                self.trigger_shutdown()
                return
            except Exception:  # shut down meanwhile: as below
                pass
        self._shut_down, self.active = True, False
        self.final_log = (self.get_logger().name, self._shutdown_text(label))

    def _destroy_entities(self) -> None:
        for e in reversed(self._entities):
            if isinstance(e, (DataInput, Diagnostics)):
                e.destroy()
            elif hasattr(e, "cancel"):
                self.destroy_timer(e)
            elif isinstance(e, Subscription):
                self.destroy_subscription(e)
            else:
                self.destroy_publisher(e)
        self._entities = []

    def _configure(self) -> None:
        system, gains = self._injected
        if system is None or gains is None:
            system, gains = load_plant_and_gains(self.params.system, self.params.gains)
        self.system, self.gain_file = system, gains
        name = self.get_name()
        if gains.method not in self.runtimes:
            raise FdMonitorError(f"node {name}: {gains.path}: method {gains.method!r}: "
                                 f"{name} runs {' and '.join(self.runtimes)} gain files "
                                 f"only (qb designs run on observer + detector; design a "
                                 f"thresholds one with `python -m fd_monitor design "
                                 f"thresholds {system.name}`)")
        self._qos = (self._qos_arg if self._qos_arg is not None
                     else data_pub_qos(self.params.qos_depth))
        self.diag = Diagnostics(self, default_hardware_id(self, system.name,
                                                          self.params.hardware_id),
                                self.params.diagnostics_period)
        self._entities.append(self.diag)
        self.diag.add("input", self.params.stale_timeout)
        # no input of its own: STALE with the input (an aggregator reads a stopped node as
        # STALE, not as the ERROR of a group with some STALE statuses)
        self.diag.add("ros graph", follows="input", message=_GRAPH_OK)
        self.bad_messages = 0
        self.processed = 0
        self.holes = 0
        self.inactive_dropped = 0
        #: True while :meth:`process` handles a restart sample (first, or first after a hole
        #: longer than max_gap), and a bridge sample (first after a shorter one).
        self.restarting = False
        self.bridging = False
        # Reasons of the bad messages since the last /diagnostics publication, each once.
        self._reasons: list[str] = []
        #: standing ROS-graph problems, by cause (cleared when the cause goes away)
        self._graph_notes: dict[str, str] = {}
        #: inputs switched to best effort (handled: reported in the values, not a WARN)
        self._best_effort: list[str] = []
        self._last_bad = -float("inf")
        self._last_log = -float("inf")
        self._suppressed = 0
        self._pubs: list[Any] = []
        self.diag.on_publish.append(self._reasons.clear)
        self.setup()
        self._entities.append(self.create_timer(5.0, self._check_outputs))
        g = self.gain_file
        self.get_logger().info(
            f"configured: plant {system.name}, gain file {g.path} ({g.id}, certificate "
            f"{g.certificate_status}); subscribes {', '.join(self._topic_names(True))}; "
            f"publishes {', '.join(self._topic_names(False))}, /diagnostics")

    def setup(self) -> None:  # pragma: no cover
        """Create the node's publishers, runtime and inputs (subclasses; at configure)."""
        raise NotImplementedError

    def _topic_names(self, inputs: bool) -> list[str]:
        topics = [i.topic for i in self._subscribed()] if inputs else [t.name for t in self.outputs]
        extra = self.adapter_input
        return [self.resolve_topic_name(t) for t in topics] + (
            extra.topics if inputs and extra is not None else [])

    def _subscribed(self) -> list[Input]:
        """The inputs subscribed as fd_monitor topics (not those an adapter replaces)."""
        adapted = self.adapter_input is not None
        return [i for i in self.inputs if not (adapted and i.name in ("u", "y"))]

    def _waits_for(self) -> list[str]:
        extra = self.adapter_input
        return [self.resolve_topic_name(i.topic) for i in self._subscribed()
                if i.initial is None] + (extra.topics if extra is not None else [])

    # -- services and parameters --------------------------------------------------------------

    def _on_reset(self, request: Any, response: Any) -> Any:
        """``~/reset``: the entry starts a new run; another node asks the entry
        (``fd/reset``), whose next sample restarts every node downstream."""
        if not self.configured:
            response.success, response.message = False, "not configured"
            return response
        if self._reset_pub is not None:
            topic = self._reset_pub.topic_name
            entries = self._reset_pub.get_subscription_count()
            if not entries:
                response.success = False
                response.message = (f"no chain entry (observer or monitor) subscribes to "
                                    f"{topic}: nothing reset")
                return response
            self._reset_pub.publish(Empty())
            self.get_logger().info(f"reset (service): asked the chain's entry on {topic}")
            response.success = True
            response.message = (f"reset: asked the chain's entry on {topic}; its next sample "
                                f"starts a new run of the whole chain")
            return response
        self._reset_run("service")
        response.success, response.message = True, "reset: the next sample starts a new run"
        return response

    def _reset_run(self, why: str) -> None:
        """Forget the stream: the next complete sample starts a new run (``restart``)."""
        self.join.reset()
        if self.adapter_input is not None:
            self.adapter_input.reset()
        self._waiting.clear()
        for hist in self._held.values():
            hist.clear()
        self.reset()
        self.get_logger().info(f"reset ({why}): the next complete sample starts a new run")

    def _on_reset_request(self, msg: Any) -> None:
        if self.configured:
            self._reset_run(f"asked on {self.resolve_topic_name(RESET.name)}")

    def _on_set_parameters(self, params: Sequence[Any]) -> SetParametersResult:
        for p in params:
            if p.name == "gains" and self.configured:
                reason = self._swap_gains(str(p.value))
                if reason is not None:
                    return SetParametersResult(successful=False, reason=reason)
        for p in params:
            if p.name in RUNTIME_PARAMS:
                setattr(self.params, p.name, p.value)
                if not self.configured:
                    continue
                if p.name == "stale_timeout":
                    self.diag.set_stale_timeout(float(p.value))
                elif p.name == "diagnostics_period":
                    self.diag.set_period(float(p.value))
                if p.name != "gains":
                    self.get_logger().info(f"parameter {p.name} set to {p.value!r}")
        return SetParametersResult(successful=True)

    def _swap_gains(self, source: str) -> str | None:
        """Load, verify and run another gain file; a one-line refusal, or None."""
        old = self.gain_file
        try:
            new = load_gains(source, self.system)
            if new.method != old.method:
                raise FdMonitorError(f"{new.path}: method {new.method!r}: the running "
                                     f"runtime is {old.method!r}")
            self.build_core(new)
        except FdMonitorError as exc:
            reason = f"gains {source}: refused ({exc}); still running {old.path}"
            self.get_logger().error(reason)
            self._graph_note(reason, "gains")
            return reason
        self.gain_file = new
        self._graph_clear("gains")
        self.join.reset()
        self.reset()
        self.get_logger().info(f"gain file swapped: {new.path} ({new.id}, certificate "
                               f"{new.certificate_status}); the next sample starts a new run")
        return None

    def build_core(self, gains: GainFile) -> None:
        """Rebuild the core component for another gain file (subclasses; runtime swap)."""
        raise FdMonitorError(f"node {self.get_name()} cannot swap gain files at runtime")

    # -- set-up helpers for subclasses --------------------------------------------------------

    def start_runtime(self) -> None:
        """Build the runtime of the gain file's method (the one factory of the chain nodes)."""
        self.runtimes[self.gain_file.method](self)

    def publisher(self, topic: Topic) -> Any:
        """A data-path publisher of Float64MultiArray (a declared topic, relative)."""
        name = self.resolve_topic_name(topic.name)
        pub = self.create_publisher(
            Float64MultiArray, topic.name, self._qos,
            **pub_events(lambda info: self._graph_note(
                incompatible_text(name, "publisher", info))))
        self._entities.append(pub)
        self._pubs.append(pub)
        return pub

    def subscribe(self, topic: str, callback: Callable[..., None],
                  with_info: bool = False, raw: bool = False) -> DataInput:
        """A data-path subscription of Float64MultiArray (relative topic name); with
        ``with_info`` the callback gets ``(msg, info)``; ``raw``: serialized messages."""
        name = self.resolve_topic_name(topic)
        sub = DataInput(self, Float64MultiArray, topic, callback,
                        partial(self._graph_note, cause=f"qos {name}"), raw=raw,
                        with_info=with_info, switched=partial(self._switched, name))
        self._entities.append(sub)
        return sub

    def start_inputs(self, inputs: Sequence[Input], gap_timeout: float | None = None) -> None:
        """Subscribe to every input and set up the stamp join.

        Without a ``sequence`` input the node is the chain's entry: it declares holes (a
        rejected message, or a later stamp complete for ``gap_timeout`` s), checked on
        message arrival and on a timer.
        """
        self.inputs = tuple(inputs)
        seq = [i.name for i in inputs if i.sequence]
        # One reset for the chain: the entry (no sequence input) listens on fd/reset, the
        # other nodes' ~/reset asks it there.
        self._reset_pub: Any = None
        if seq:
            self._reset_pub = self.create_publisher(Empty, RESET.name, 10)
            self._entities.append(self._reset_pub)
        else:
            self._entities.append(self.create_subscription(Empty, RESET.name,
                                                           self._on_reset_request, 10))
        max_gap = int(getattr(self.params, "max_gap", 0))
        self.join = StampJoin([i.name for i in inputs if i.initial is None],
                              {i.name: i.initial for i in inputs if i.initial is not None},
                              self.params.max_pending, sequence=seq[0] if seq else None,
                              gap_timeout=None if seq else gap_timeout,
                              horizon=self.params.stamp_horizon,
                              restart_after=self.params.restart_after,
                              feedback_source=self._feedback_source,
                              max_gap=max_gap, max_lag=self.params.max_lag or None,
                              sample_time=float(self.system.sample_time),
                              batch_pace=self.params.batch_pace)
        #: The input policy shared with offline reading (order check, join, release).
        self.stream = InputStream(self.join, self._run, self._note)
        self._stamper = ArrivalStamper()
        self._held: dict[str, deque[tuple[int, np.ndarray]]] = {
            i.name: deque(maxlen=DEFAULT_DEPTH) for i in inputs if i.hold}
        self._waiting: deque[tuple[int, float, Input, int, np.ndarray]] = deque()
        self._data_inputs = {}
        # an adapter file (nodes whose parameters have one): the robot's topics give u and y
        self.adapter_input = None
        if getattr(self.params, "adapter", ""):
            self.adapter_input = AdapterInput(self, self.params.adapter)
            inputs = [i for i in inputs if i.name not in ("u", "y")]
        for inp in inputs:
            cb = self._callback(inp)
            self._data_inputs[inp.name] = self.subscribe(inp.topic, cb, inp.plain_ok,
                                                         raw=True)
        self._open_loop: set[str] = set()
        if self._held:
            self._entities.append(self.create_timer(HOLD_WAIT / 2, self._on_hold_timer))
        # A hole, lost feedback or a new run must be declared even when no further message
        # arrives.
        period = min(0.25, max(0.01, min(gap_timeout or 1.0, self.params.restart_after) / 4))
        self._entities.append(self.create_timer(period, self._on_gap_timer))

    def _feedback_source(self, name: str) -> bool:
        """Whether a publisher of feedback input ``name`` is matched (the join waits for its
        feedback only then). A change is logged once: without the node that feeds it back
        (e.g. no bias_estimator) this node runs open loop at full rate."""
        there = self._data_inputs[name].sub.get_publisher_count() > 0
        if there == (name in self._open_loop):
            topic = self._data_inputs[name].sub.topic_name
            if there:
                self._open_loop.discard(name)
                self.get_logger().info(f"{topic}: a publisher is here: waiting for its "
                                       f"feedback again")
            else:
                self._open_loop.add(name)
                self.get_logger().info(f"{topic}: no publisher: running without this "
                                       f"feedback (its initial value) until one appears")
        return there

    def _callback(self, inp: Input) -> Callable[..., None]:
        stamper = self._stamper
        topic = self.resolve_topic_name(inp.topic)
        order = TopicOrder(topic)
        stream = self.stream
        # the restart and bridge flags of the sequence input, by field (resolved once)
        i_restart = inp.layout.index["restart"] if inp.sequence and inp.layout else None
        i_bridge = inp.layout.index["bridge"] if inp.sequence and inp.layout else None
        # serialized messages in, decoded without a message object (rclpy's deserializer
        # only for what the CDR parser leaves: big-endian)
        dec = RawDecoder(partial(deserialize_message, message_type=Float64MultiArray), topic,
                         labels=inp.labels, size=inp.size, require_stamp=not inp.plain_ok,
                         allow_nan=inp.allow_nan)

        def cb(raw: bytes, info: Any = None) -> None:
            if not self.active:
                self.inactive_dropped += 1
                return
            try:
                d = dec.decode(raw)
            except MessageError as exc:
                self.bad_input(str(exc))
                k = readable_stamp(dec.message(raw)) if inp.initial is None else None
                if k is not None:
                    stream.refused(k + inp.stamp_offset, time.monotonic())
                return
            if d.stamp is None:
                t = int(info["source_timestamp"]) if info is not None else time.time_ns()
                if inp.hold:
                    self._held[inp.name].append((t, d.values))
                else:
                    d = stamper.stamp(d)
                    self._waiting.append((t, time.monotonic(), inp, int(d.stamp or 0),
                                          d.values))
                self._pair_plain()
                return
            if stream.stamped(order, inp.name, int(d.stamp), d.values, time.monotonic(),
                              inp.stamp_offset, bool(inp.sequence and d.values[i_restart] > 0.5),
                              bool(inp.sequence and d.values[i_bridge] > 0.5)):
                self._input_ok()
        return cb

    def _pair_plain(self, now: float | None = None) -> None:
        """Sample-and-hold: pair each plain sample with the latest held input (``plant/u``)
        published before it (source timestamps). A sample waits until a later held input
        arrived (every earlier one is then in) or for :data:`HOLD_WAIT` s."""
        while self._waiting:
            t, arrival, inp, k, values = self._waiting[0]
            later = all(h and h[-1][0] > t for h in self._held.values())
            if not later and (now is None or now - arrival < HOLD_WAIT):
                return
            self._waiting.popleft()
            missing = []
            for name, hist in self._held.items():
                before = [v for tu, v in hist if tu <= t]
                if before:
                    self.on_input(name, k, before[-1])
                else:
                    missing.append(name)
                # Keep the one held at t: the next samples may still need it.
                while len(hist) > 1 and hist[1][0] <= t:
                    hist.popleft()
            if missing:
                topics = [self.resolve_topic_name(i.topic) for i in self.inputs
                          if i.name in missing]
                self.bad_input(f"{self.resolve_topic_name(inp.topic)} sample {k}: no "
                               f"{', '.join(topics)} received before it; sample not "
                               f"processed")
                self.stream.refused(k, time.monotonic())
                continue
            self.on_input(inp.name, k, values)

    # -- reporting ----------------------------------------------------------------------------

    def bad_input(self, reason: str) -> None:
        """Log a rejected message and report it on /diagnostics (WARN); keep running."""
        self.bad_messages += 1
        self._warn(reason)

    def _warn(self, reason: str) -> None:
        """Log ``reason`` (throttled) and report it on the ``input`` channel (WARN)."""
        now = time.monotonic()
        self._last_bad = now
        if now - self._last_log >= self.params.log_throttle:
            more = (f" (and {self._suppressed} more bad-input lines in the last "
                    f"{now - self._last_log:.1f} s)" if self._suppressed else "")
            self.get_logger().warning(reason + more)
            self._last_log, self._suppressed = now, 0
        else:
            self._suppressed += 1
        if reason not in self._reasons and len(self._reasons) < 10:
            self._reasons.append(reason)
        # every reason of this period when they fit in a status line, else the latest (all
        # of them in the values)
        message = "; ".join(self._reasons)
        if len(message) > MAX_MESSAGE and len(self._reasons) > 1:
            message = f"{reason} (and {len(self._reasons) - 1} more: see reasons)"
        self.diag.update("input", WARN, message,
                         {"reasons": "; ".join(self._reasons),
                          "bad_messages": self.bad_messages, "holes": self.holes,
                          "bridged": self.join.bridges, "restarted": self.join.restarts,
                          "new_runs": self.join.new_runs, "processed": self.processed,
                          **self._load_counts(), "last_warning": reason,
                          **self._time_base()})

    def _load_counts(self) -> dict[str, Any]:
        """Load shed and lost feedback (wire/join.py), for the ``input`` status."""
        j = self.join
        return {"shed_samples": j.shed, "shed_episodes": j.shed_episodes,
                "batch_waits": j.batch_waits,
                "feedback_lost": j.feedback_losses,
                "feedback_not_waited_for": ",".join(sorted(j.lost_feedback)) or "none"}

    def _time_base(self) -> dict[str, Any]:
        """The adapter's time-base counts (held samples, gaps, late/duplicate/decimated
        messages) for the ``input`` status; empty without an adapter."""
        if self.adapter_input is None:
            return {}
        c = self.adapter_input.join.counts()
        out: dict[str, Any] = {"grid_samples": c["samples"]}
        for key in ("held", "late", "duplicate", "stray", "decimated"):
            for what, n in c.get(key, {}).items():
                out[f"{key} {what}"] = n
        for reason, per in c["gaps"].items():
            for ch, n in per.items():
                out[f"gap {reason} {ch}"] = n
        return out

    def _graph_note(self, line: str, cause: str | None = None) -> None:
        """Log a ROS-graph problem (QoS, another publisher, a refused gain file) and report
        it (WARN) until its ``cause`` (default: the line) is cleared."""
        self.get_logger().warning(line)
        self._graph_notes[cause or line] = line
        self._graph_status()

    def _graph_clear(self, cause: str) -> None:
        """The problem of ``cause`` is gone (a valid gain file set, a switch done, the other
        publisher left): the ``ros graph`` status goes back to OK when none is left."""
        if self._graph_notes.pop(cause, None) is not None:
            self._graph_status()

    def _graph_status(self) -> None:
        notes = list(self._graph_notes.values())
        values: dict[str, Any] = ({"best_effort_inputs": ", ".join(self._best_effort)}
                                  if self._best_effort else {})
        if notes:
            # all of them when they fit in a status line, else the latest (all in values)
            message = "; ".join(notes)
            if len(message) > MAX_MESSAGE and len(notes) > 1:
                message = f"{notes[-1]} (and {len(notes) - 1} more: see problem 1, ...)"
            values.update({f"problem {i + 1}": n for i, n in enumerate(notes)})
            self.diag.update("ros graph", WARN, message, values)
        else:
            self.diag.update("ros graph", OK, _GRAPH_OK + (
                " (some inputs switched to best effort)" if self._best_effort else ""), values)

    def _switched(self, topic: str) -> None:
        """A subscription met a best-effort publisher by switching: handled, not a WARN."""
        self.get_logger().info(f"{topic}: subscription now best effort (meets every "
                               f"publisher)")
        self._best_effort.append(topic)
        self._graph_clear(f"qos {topic}")

    def _check_outputs(self) -> None:
        """Warn while another node publishes on one of our output topics (a second
        monitor); the warning clears when it left."""
        me = (self.get_namespace(), self.get_name())
        for pub in self._pubs:
            others = [f"{i.node_namespace.rstrip('/')}/{i.node_name}"
                      for i in self.get_publishers_info_by_topic(pub.topic_name)
                      if (i.node_namespace, i.node_name) != me]
            cause = f"also {pub.topic_name}"
            if others:
                line = (f"{pub.topic_name}: also published by {', '.join(sorted(others))} "
                        f"(a second monitor on the same topics? its outputs mix with ours)")
                if self._graph_notes.get(cause) != line:
                    self._graph_note(line, cause)
            else:
                self._graph_clear(cause)

    def on_input(self, name: str, stamp: int, values: np.ndarray,
                 restart: bool = False) -> None:
        """Join one decoded input; process every sample that became complete."""
        if self.stream.put(name, stamp, values, time.monotonic(), restart):
            self._input_ok()

    def _input_ok(self) -> None:
        """An input was joined: the ``input`` channel (OK, or the WARN of recent bad input)."""
        level = self.diag.level("input")
        if level == WARN and time.monotonic() - self._last_bad < self.diag.period:
            self.diag.touch("input")
        elif level != OK or self.processed % 50 == 0:
            self.diag.update("input", OK, "receiving", {
                "bad_messages": self.bad_messages, "processed": self.processed,
                "holes": self.holes, "bridged": self.join.bridges,
                "restarted": self.join.restarts, "new_runs": self.join.new_runs,
                "next_sample": self.join.k_next, "waiting_for": self.join.waiting_for(),
                **self._load_counts(), **self._time_base()})
        else:
            self.diag.touch("input")

    def _on_hold_timer(self) -> None:
        if self.active and self._waiting:
            self._pair_plain(time.monotonic())

    def _on_gap_timer(self) -> None:
        if self.active and (self.join.pending or self.join.held):
            self._drain()

    def _drain(self) -> None:
        """Process every sample the join releases now; report holes and restarts."""
        self.stream.release(time.monotonic())

    def _note(self, kind: str, line: str, stamp: Any) -> None:
        """A report of the input policy (:class:`~fd_monitor.wire.stream.InputStream`):
        out of order, holes and new runs are warnings; the others are dropped messages."""
        if kind == "hole":
            self.holes += 1
        if kind in _WARN_ONLY:
            self._warn(line)
        else:
            self.bad_input(line)

    def _run(self, s: Sample) -> bool:
        """Process one released sample (reset first at a restart, bridge first at a bridge);
        False when the core refused it (the stream counts it lost: the next sample bridges
        or restarts)."""
        if s.restart:
            self.reset()
        self.restarting, self.bridging = s.restart, s.bridge
        try:
            if s.bridge:
                self.bridge(s.k, s.inputs)
            self.process(s.k, s.inputs)
        except ImplausibleError as exc:
            # Refused by the core (an implausible value): reported like a bad message and a
            # hole at k (core/plausibility.py).
            self.bad_input(str(exc))
            return False
        self.processed += 1
        return True

    def reset(self) -> None:
        """Reset the core component as :meth:`~fd_monitor.core.monitor.Monitor.reset` does
        (subclasses); called before every restart sample."""

    def bridge(self, k: int, inputs: dict[str, Any]) -> None:
        """Carry the core component over lost samples before sample ``k`` (its joined
        ``inputs`` follow in :meth:`process`), as
        :meth:`~fd_monitor.core.runtime.Runtime.bridge` does (subclasses; default: nothing
        to carry, its state simply goes on); called before every bridge sample. Raises
        :class:`~fd_monitor.model.errors.ImplausibleError` for a sample the core refuses."""

    def process(self, k: int, inputs: dict[str, Any]) -> None:  # pragma: no cover
        """Process sample k (subclasses)."""
        raise NotImplementedError

    def publish_array(self, pub: Any, labels: Sequence[str], stamp: int, values: Any) -> None:
        """Publish one stamped, labelled message (serialized directly:
        :class:`~fd_monitor.nodes.common.SerializedArray`, one per layout)."""
        key = tuple(labels)
        ser = self._serialized.get(key)
        if ser is None:
            ser = self._serialized[key] = SerializedArray(key)
        pub.publish(ser.encode(stamp, values))

    def mode_name(self, mode: int) -> str:
        """The plant's name of mode index ``mode`` (the index itself when it has none: a
        switching signal outside the design)."""
        modes = self.system.mode_names
        return modes[mode] if 0 <= mode < len(modes) else str(mode)

    def gain_values(self) -> dict[str, str]:
        """Gain-file id and certificate status, for /diagnostics (per sample: cached)."""
        g = self.gain_file
        cached = getattr(self, "_gain_values", None)
        if cached is None or cached[0] is not g:
            cached = self._gain_values = (g, {"gain_file": g.id,
                                              "certificate": g.certificate_status})
        return cached[1]
