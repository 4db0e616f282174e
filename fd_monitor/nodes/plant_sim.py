"""``plant_sim``: the core plant simulator as a ROS 2 node.

Publishes, for every sample k of a scenario (:class:`fd_monitor.core.simulator.PlantSimulator`,
a batch of one run), stamped and labelled Float64MultiArray messages (see
:mod:`fd_monitor.wire.conversions`):

- ``/plant/u`` — the commanded inputs u_k (labels: the plant's inputs);
- ``/plant/y`` — the measurements y_k, sensor faults included (labels: the outputs);
- ``/plant/truth`` — ``mode`` (index), ``x.<state>`` (true state), ``f.<fault>`` (fault
  signals), ``rho.<name>`` (scheduling parameters of an LPV scenario): for evaluation
  (:data:`fd_monitor.wire.topics.PLANT_TRUTH`);
- ``/plant/rho``, ``/plant/mode`` — the measured scheduling parameters, the exogenous mode,
  when the plant has them: the runtimes' side signals
  (:func:`fd_monitor.core.simulator.measured_layout`).

Pacing: ``rate_factor`` times the sample rate (1.0 = real time, 100.0 = a hundred times
faster; a timer ticks once per sample, at most every millisecond), or ``0.0`` = as fast
as the subscribers keep up without loss (wait for ``min_subscribers_*`` matched
subscriptions, then pace by acknowledgements every ``ack_window`` samples; see
:mod:`fd_monitor.nodes.pacing`). The node ends after the scenario's samples (or
``duration``), once every sample is acknowledged, unless ``keep_going`` is true.

Flat out, the stream is a *batch* (recorded-like data whose every sample is to be processed):
its messages carry the batch mark (:data:`~fd_monitor.wire.conversions.BATCH_LABEL`), so a
node more than ``max_lag`` s behind processes them however late instead of shedding them as
it sheds a live stream's; ``batch_mark`` (auto, always, never) overrides it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Any

from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.task import Future
from std_msgs.msg import Float64MultiArray

from fd_monitor.core.simulator import (
    PlantSimulator,
    Sample,
    measured_layout,
    measured_values,
    truth_values,
)
from fd_monitor.model.errors import FdMonitorError
from fd_monitor.model.scenario import load_scenario
from fd_monitor.nodes.adapter_input import RobotPublishers
from fd_monitor.nodes.diagnostics import ERROR, OK, Diagnostics, default_hardware_id
from fd_monitor.nodes.pacing import AckPacer, wait_for_subscribers
from fd_monitor.nodes.params import Param, declare_parameters
from fd_monitor.nodes.process import run_node
from fd_monitor.nodes.qos import DEFAULT_DEPTH, data_pub_qos, pub_events
from fd_monitor.nodes.usage import NodeUsage
from fd_monitor.wire.conversions import to_msg
from fd_monitor.wire.topics import (
    DIAGNOSTICS,
    PLANT_MODE,
    PLANT_RHO,
    PLANT_TRUTH,
    PLANT_U,
    PLANT_Y,
    side_topic,
)

__all__ = ["PARAMS", "PlantSimNode", "USAGE", "main"]

PARAMS = (
    Param("scenario", "three_tank_bias_h1", "scenario: a shipped name or a YAML path"),
    Param("seed", -1, "random seed of the run; -1 = the scenario's seed", low=-1,
          high=2**31 - 1),
    Param("rate_factor", 1.0, "pace = sample rate x rate_factor; 0.0 = as fast as the "
          "subscribers keep up without loss", low=0.0, high=1.0e6),
    Param("batch_mark", "auto", "mark plant/* messages as a batch (every sample processed "
          "however late; unmarked, a node more than max_lag s behind sheds them): auto = "
          "when flat out (rate_factor 0.0), always, never", choices=("auto", "always", "never")),
    Param("duration", 0.0, "s of plant time to simulate; 0.0 = the scenario's duration",
          low=0.0, high=1.0e9),
    Param("keep_going", False, "keep simulating after the scenario's end (until shut down)"),
    Param("publish_truth", True, "publish plant/truth (true mode, state, fault signals)"),
    Param("min_subscribers_u", 0, "wait for this many subscriptions on plant/u before "
          "the first sample", low=0, high=1000),
    Param("min_subscribers_y", 0, "wait for this many subscriptions on plant/y", low=0,
          high=1000),
    Param("min_subscribers_truth", 0, "wait for this many subscriptions on plant/truth",
          low=0, high=1000),
    Param("start_delay", 0.0, "s to wait once the subscribers are matched before the first "
          "sample: time for them to match this node's writers too (DDS discovery is not "
          "symmetric; a reliable subscriber that has not matched a writer yet misses its "
          "first samples)", low=0.0, high=60.0),
    Param("subscriber_timeout", 30.0, "s to wait for the subscribers, then exit with an "
          "error; 0.0 = wait forever", low=0.0, high=1.0e6),
    Param("qos_depth", DEFAULT_DEPTH, "history depth of the publishers", low=10,
          high=1000000),
    Param("ack_window", 100, "samples between waits for acknowledgements (< qos_depth)",
          low=1, high=1000000),
    Param("diagnostics_period", 1.0, "s between /diagnostics publications", low=0.01,
          high=3600.0),
    Param("adapter", "", "adapter file (path, or a name in config/adapters/): also publish "
          "u and y as the robot's messages on its topics (header stamps on the plant's "
          "clock); min_subscribers_u/y then count the subscriptions of those topics"),
)

_FLAT_OUT_TICK = 0.001  # s: timer period flat out (rate_factor 0.0), and the shortest one


USAGE = NodeUsage(
    "plant_sim", "plant_sim: simulate a scenario's plant and publish it sample by sample.",
    PARAMS,
    publishes=((PLANT_U, "inputs u_k (stamp k)"), (PLANT_Y, "measurements y_k"),
               (PLANT_RHO, "measured scheduling parameters (LPV plants with measured "
                           "ones)"),
               (PLANT_MODE, "mode index (plants whose switching no guard decides)"),
               (PLANT_TRUTH, "true mode, state, injected faults (evaluation only)"),
               (DIAGNOSTICS, "simulation status")))


class PlantSimNode(Node):
    """Publish a simulated plant's u, y and truth, sample by sample.

    Parameters
    ----------
    simulator : PlantSimulator, optional
        A batch-of-one simulator; default: built from the ``scenario`` and ``seed``
        parameters.
    qos : rclpy.qos.QoSProfile, optional
        Publisher QoS; default :func:`~fd_monitor.nodes.qos.data_pub_qos`.
    node_name : str
    **kwargs
        Passed to :class:`rclpy.node.Node` (e.g. ``parameter_overrides``, ``context``).
    """

    def __init__(self, simulator: PlantSimulator | None = None, qos: QoSProfile | None = None,
                 node_name: str = "plant_sim", **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        p = self.params = declare_parameters(self, PARAMS)
        if simulator is None:
            scenario = load_scenario(p.scenario)
            simulator = PlantSimulator(scenario, [scenario.seed if p.seed < 0 else p.seed])
        if simulator.N != 1:
            raise FdMonitorError(f"plant_sim: expected a simulator of one run, got {simulator.N}")
        if p.ack_window >= p.qos_depth:
            raise FdMonitorError(f"node {node_name}: parameter ack_window ({p.ack_window}) "
                                 f"must be below qos_depth ({p.qos_depth})")
        self.sim = simulator
        sc = simulator.scenario
        sys_ = sc.system
        self.labels_u, self.labels_y = PLANT_U.labels(sys_), PLANT_Y.labels(sys_)
        self._truth = PLANT_TRUTH.layout(sc)
        duration = p.duration if p.duration > 0 else sc.duration
        #: samples of a run (k = 0 .. n_samples-1), unless keep_going.
        self.n_samples = max(1, round(duration / sys_.sample_time))
        self.dt = sys_.sample_time
        qos = qos if qos is not None else data_pub_qos(p.qos_depth)
        self.pub_u = self.create_publisher(Float64MultiArray, PLANT_U.name, qos, **pub_events())
        self.pub_y = self.create_publisher(Float64MultiArray, PLANT_Y.name, qos, **pub_events())
        self.pub_truth = (self.create_publisher(Float64MultiArray, PLANT_TRUTH.name, qos,
                                                **pub_events())
                          if p.publish_truth else None)
        # What a monitor may measure besides u, y: plant/rho, plant/mode (side signals).
        self.pub_side = [(self.create_publisher(Float64MultiArray, side_topic(name).name, qos,
                                                **pub_events()), labels, cols)
                         for name, (labels, cols) in measured_layout(sc).items()]
        pubs = ([self.pub_u, self.pub_y, *(p for p, _, _ in self.pub_side)]
                + ([self.pub_truth] if self.pub_truth else []))
        self.robot = RobotPublishers(self, p.adapter, sys_, qos) if p.adapter else None
        if self.robot is not None:
            pubs += list(self.robot.pubs.values())
        self._pacer = AckPacer(pubs, p.ack_window)
        self._wanted = ([(self.pub_u, p.min_subscribers_u), (self.pub_y, p.min_subscribers_y)]
                        if self.robot is None else
                        self.robot.wanted(p.min_subscribers_u, p.min_subscribers_y))
        if self.pub_truth is not None:
            self._wanted.append((self.pub_truth, p.min_subscribers_truth))
        self.done = Future()
        self.exit_code = 0
        self.published = 0
        self._t0: float | None = None
        self._wait_start = time.monotonic()
        self._matched_at: float | None = None
        self.diag = Diagnostics(self, default_hardware_id(self, sys_.name), p.diagnostics_period)
        self.diag.add("simulation")
        self.diag.update("simulation", OK, "waiting for subscribers",
                         {"scenario": sc.name, "samples": self.n_samples})
        #: s between ticks: one sample per tick when paced (late ticks catch up in bursts).
        self.tick_period = (max(self.dt / p.rate_factor, _FLAT_OUT_TICK) if p.rate_factor > 0
                            else _FLAT_OUT_TICK)
        self._timer = self.create_timer(self.tick_period, self._on_tick)
        #: plant/* messages carry the batch mark (flat out, or batch_mark always)
        self.batch = p.batch_mark == "always" or (p.batch_mark == "auto"
                                                  and p.rate_factor == 0)
        self.get_logger().info(
            f"scenario {sc.name} ({sys_.name}), seed {simulator.seeds[0]}, "
            f"{self.n_samples} samples of {self.dt:g} s, rate_factor {p.rate_factor:g}"
            + ("; a batch (every sample processed)" if self.batch else ""))

    # One tick: wait for subscribers, then publish every sample that is due.
    def _on_tick(self) -> None:
        if self.done.done():
            return
        now = time.monotonic()
        if self._t0 is None:
            if not wait_for_subscribers(self._wanted):
                timeout = self.params.subscriber_timeout
                if timeout > 0 and now - self._wait_start > timeout:
                    counts = ", ".join(f"{pub.topic_name}: {pub.get_subscription_count()}/{n}"
                                       for pub, n in self._wanted)
                    self._finish(1, f"timed out after {self.params.subscriber_timeout:g} s "
                                    f"waiting for subscribers ({counts})")
                self._matched_at = None
                return
            # DDS discovery is not symmetric: a subscriber this writer has matched may not
            # have matched the writer yet, and would miss the first samples
            if self._matched_at is None:
                self._matched_at = now
            if now - self._matched_at < self.params.start_delay:
                return
            self._t0 = now
            self.diag.update("simulation", OK, "running")
        end = None if self.params.keep_going else self.n_samples
        rate = self.params.rate_factor
        if rate > 0:
            # Sample k is due at t0 + k dt / rate; rounding to the nearest tick keeps one
            # sample per tick when a tick comes a little earlier than the first one did.
            due = math.floor((now - self._t0) * rate / self.dt + 0.5) + 1
        else:
            due = self.published + self._pacer.window
        if end is not None:
            due = min(due, end)
        # Bounded bursts keep the executor responsive (shutdown, diagnostics).
        due = min(due, self.published + self._pacer.window)
        while self.published < due:
            self._publish(self.sim.step())
        if end is not None and self.published >= end:
            if not self._pacer.flush():
                self.get_logger().warning("not every sample was acknowledged in time")
            self._finish(0, f"published {self.published} samples")

    def _publish(self, s: Sample) -> None:
        k = s.k
        batch = self.batch
        self.pub_u.publish(to_msg(self.labels_u, k, s.u[0], batch=batch))
        self.pub_y.publish(to_msg(self.labels_y, k, s.y[0], batch=batch))
        if self.robot is not None:
            self.robot.publish(k, s.u[0], s.y[0])
        for pub, labels, cols in self.pub_side:
            pub.publish(to_msg(labels, k, measured_values(cols, s.mode[0], s.rho[0]),
                               batch=batch))
        if self.pub_truth is not None:
            self.pub_truth.publish(to_msg(self._truth.labels, k, truth_values(s), batch=batch))
        self.published += 1
        self.diag.touch("simulation")
        if not self._pacer.published():
            self.get_logger().warning(f"sample {k}: subscribers slow to acknowledge")

    def _finish(self, code: int, message: str) -> None:
        self.exit_code = code
        log = self.get_logger().info if code == 0 else self.get_logger().error
        log(message)
        self.diag.update("simulation", OK if code == 0 else ERROR, message,
                         {"published": self.published})
        self._timer.cancel()
        self.done.set_result(code)


def main(args: Sequence[str] | None = None) -> int:
    """Run ``plant_sim`` until the scenario ends (or SIGINT/SIGTERM)."""
    return run_node(PlantSimNode, args, prog="plant_sim", usage=[USAGE], pacing=True)


if __name__ == "__main__":
    import sys

    sys.exit(main())
