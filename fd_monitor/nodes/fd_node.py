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

Each node declares its inputs (:class:`~fd_monitor.nodes.inputs.Input`: relative topic,
expected labels, required or feedback with its initial value) and implements
``process(k, inputs)`` -- message -> ``np.asarray`` -> core step -> message -> publish. The
node holds what it is made of: its input path (:class:`~fd_monitor.nodes.input_path.InputPath`:
subscriptions, decoding, the one hold rule for plain messages, the stamp join of the input
policy offline reading shares), its ``input`` and ``ros graph`` statuses
(:mod:`fd_monitor.nodes.node_status`: bad messages logged, throttled, and reported; QoS
problems and a second publisher on its outputs) and its reports
(:mod:`fd_monitor.nodes.reports`, :mod:`fd_monitor.nodes.fault`).

Feedback messages (``fd/bias_estimate``, ``fd/guard_event``, ``fd/threshold_override``) are
stamped with the sample they are *for* (k + 1 when decided at k), so every join is on equal
stamps.

Why one module of ~540 lines: one lifecycle base class (transitions, the hand-over to a
lifecycle manager, configure, ``~/reset``, runtime parameters, the gain-file swap); what it is
made of lives in the modules named above.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import Any

from lifecycle_msgs.msg import State, Transition
from rcl_interfaces.msg import SetParametersResult
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.qos import QoSProfile
from rclpy.subscription import Subscription
from std_msgs.msg import Empty, Float64MultiArray

from fd_monitor.core.methods import load_gains
from fd_monitor.model.errors import FdMonitorError, ImplausibleError
from fd_monitor.model.gains import GainFile
from fd_monitor.model.system import System, load_system
from fd_monitor.nodes.adapter_input import AdapterInput
from fd_monitor.nodes.chain_params import COMMON_PARAMS, RUNTIME_PARAMS
from fd_monitor.nodes.data_input import DataInput
from fd_monitor.nodes.diagnostics import (
    WAITING,
    Diagnostics,
    default_hardware_id,
)
from fd_monitor.nodes.input_path import InputPath
from fd_monitor.nodes.inputs import Input
from fd_monitor.nodes.node_status import GRAPH_OK, GraphStatus, InputStatus
from fd_monitor.nodes.params import Param, declare_parameters
from fd_monitor.nodes.qos import data_pub_qos, incompatible_text, pub_events
from fd_monitor.nodes.serialized import SerializedArray
from fd_monitor.wire.join import Sample
from fd_monitor.wire.topics import RESET, Topic

__all__ = ["FdNode", "load_plant_and_gains"]


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
    #: source timestamps: :func:`~fd_monitor.nodes.data_input.with_message_info`).
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
        #: labels -> serialized layout of publish_array (unmarked, batch-marked)
        self._serialized: dict[tuple[str, ...], SerializedArray] = {}
        self._serialized_batch: dict[tuple[str, ...], SerializedArray] = {}
        #: The sample being processed is part of a batch: its outputs carry the mark.
        self.batch = False
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

    @property
    def holes(self) -> int:
        """Holes declared in the input so far (:class:`InputStatus`)."""
        return int(self.input_status.holes)

    @property
    def bad_messages(self) -> int:
        """Messages refused so far (:class:`InputStatus`)."""
        return int(self.input_status.bad_messages)

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
        self.graph.report()                   # a standing graph problem is still one
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
        name, text) for :func:`~fd_monitor.nodes.process.run_node` to write once the node is
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
        self.diag.add("ros graph", follows="input", message=GRAPH_OK)
        self.processed = 0
        self.inactive_dropped = 0
        #: True while :meth:`process` handles a restart sample (first, or first after a hole
        #: longer than max_gap), and a bridge sample (first after a shorter one).
        self.restarting = False
        self.bridging = False
        log = self.get_logger()
        #: the ``input`` status (bad input, the input policy's warnings, counts)
        self.input_status = InputStatus(self.diag, log, lambda: self.params.log_throttle,
                                        lambda: self.processed)
        #: the ``ros graph`` status (QoS, other publishers, a refused gain file)
        self.graph = GraphStatus(self.diag, log)
        self._pubs: list[Any] = []
        self.setup()
        self._entities.append(self.create_timer(5.0, partial(
            self.graph.check_outputs, self._pubs, (self.get_namespace(), self.get_name()),
            self.get_publishers_info_by_topic)))
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
        reset_pub = self.input_path.reset_pub
        if reset_pub is not None:
            topic = reset_pub.topic_name
            entries = reset_pub.get_subscription_count()
            if not entries:
                response.success = False
                response.message = (f"no chain entry (observer or monitor) subscribes to "
                                    f"{topic}: nothing reset")
                return response
            reset_pub.publish(Empty())
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
        self.input_path.reset()
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
            self.graph.note(reason, "gains")
            return reason
        self.gain_file = new
        self.graph.clear("gains")
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

    def publisher(self, topic: Topic, qos: QoSProfile | None = None,
                  cause: str | None = None) -> Any:
        """A publisher of Float64MultiArray (a declared topic, relative): the data path's QoS,
        or ``qos``; an incompatible-QoS event is a ``ros graph`` problem (of ``cause``,
        default its line)."""
        name = self.resolve_topic_name(topic.name)
        pub = self.create_publisher(
            Float64MultiArray, topic.name, qos if qos is not None else self._qos,
            **pub_events(lambda info: self.graph.note(
                incompatible_text(name, "publisher", info), cause)))
        self._entities.append(pub)
        self._pubs.append(pub)
        return pub

    def subscribe(self, topic: str, callback: Callable[..., None],
                  with_info: bool = False, raw: bool = False) -> DataInput:
        """A data-path subscription of Float64MultiArray (relative topic name); with
        ``with_info`` the callback gets ``(msg, info)``; ``raw``: serialized messages."""
        name = self.resolve_topic_name(topic)
        sub = DataInput(self, Float64MultiArray, topic, callback,
                        partial(self.graph.note, cause=f"qos {name}"), raw=raw,
                        with_info=with_info, switched=partial(self.graph.switched, name))
        self._entities.append(sub)
        return sub

    def start_inputs(self, inputs: Sequence[Input], gap_timeout: float | None = None) -> None:
        """Subscribe to every input and set up the stamp join (:class:`InputPath`).

        Without a ``sequence`` input the node is the chain's entry: it declares holes (a
        rejected message, or a later stamp complete for ``gap_timeout`` s), checked on
        message arrival and on a timer.
        """
        self.inputs = tuple(inputs)
        self.input_path = path = InputPath(self, inputs, gap_timeout)
        #: the stamp join and the input policy over it (offline reading's)
        self.join, self.stream = path.join, path.stream
        self._data_inputs = path.data_inputs
        #: The robot's topics giving u and y, when the node has an adapter file.
        self.adapter_input = path.adapter

    # -- reporting ----------------------------------------------------------------------------

    def _run(self, s: Sample) -> bool:
        """Process one released sample (reset first at a restart, bridge first at a bridge);
        False when the core refused it (the stream counts it lost: the next sample bridges
        or restarts)."""
        if s.restart:
            self.reset()
        self.restarting, self.bridging, self.batch = s.restart, s.bridge, s.batch
        try:
            if s.bridge:
                self.bridge(s.k, s.inputs)
            self.process(s.k, s.inputs)
        except ImplausibleError as exc:
            # Refused by the core (an implausible value): reported like a bad message and a
            # hole at k (core/plausibility.py).
            self.input_status.bad_input(str(exc))
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
        :class:`~fd_monitor.nodes.serialized.SerializedArray`, one per layout); marked as a
        batch when the sample being processed was (the node relays a batch)."""
        key = tuple(labels)
        cache = self._serialized_batch if self.batch else self._serialized
        ser = cache.get(key)
        if ser is None:
            ser = cache[key] = SerializedArray(key, self.batch)
        pub.publish(ser.encode(stamp, values))

    def gain_values(self) -> dict[str, str]:
        """Gain-file id and certificate status, for /diagnostics (per sample: cached)."""
        g = self.gain_file
        cached = getattr(self, "_gain_values", None)
        if cached is None or cached[0] is not g:
            cached = self._gain_values = (g, {"gain_file": g.id,
                                              "certificate": g.certificate_status})
        return cached[1]
