"""plant_sim over real DDS: labelled, stamped samples; lossless flat out; clean ends."""

from __future__ import annotations

import signal

import numpy as np
import pytest
from ros_util import Collector, Proc, ros_context, spin_until, status_text

from fd_monitor.core.simulator import simulate
from fd_monitor.model.scenario import load_scenario

pytestmark = pytest.mark.ros

TOPICS = ("/plant/u", "/plant/y", "/plant/truth")


def test_plant_sim_process_flat_out_delivers_every_sample():
    """rate_factor 0: all K samples of u, y and truth arrive, equal to the core simulator."""
    from rclpy.executors import SingleThreadedExecutor

    K = 300
    with ros_context() as ctx:
        col = Collector(ctx, TOPICS)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(col.node)
        args = ["run", "plant_sim", "--ros-args", "-p", "rate_factor:=0.0",
                "-p", "duration:=30.0", "-p", "seed:=4", "-p", "min_subscribers_u:=1",
                "-p", "min_subscribers_y:=1", "-p", "min_subscribers_truth:=1",
                "-p", "ack_window:=20"]
        with Proc(args) as proc:
            ok = spin_until(ex, lambda: all(len(col.msgs[t]) >= K for t in TOPICS), 60.0,
                            [proc])
            assert ok, (f"got {[len(col.msgs[t]) for t in TOPICS]} of {K}\n"
                        + proc.output()[-2000:])
            assert proc.wait(30) == 0, proc.output()
        ex.shutdown()
        col.node.destroy_node()
    traj = simulate(load_scenario("three_tank_bias_h1"), 4, K)
    y = col.decoded("/plant/y")
    assert [d.stamp for d in y] == list(range(K))
    assert y[0].labels == ("h1", "h2", "h3")
    np.testing.assert_array_equal(np.array([d.values for d in y]), traj.y[0])
    u = col.decoded("/plant/u")
    assert u[0].labels == ("q1", "q2", "v13")
    np.testing.assert_array_equal(np.array([d.values for d in u]), traj.u[0])
    truth = col.decoded("/plant/truth")
    assert truth[0].labels[:4] == ("mode", "x.h1", "x.h2", "x.h3")
    np.testing.assert_array_equal([d.values[0] for d in truth], traj.mode[0])


def test_plant_sim_in_process_paced_with_diagnostics():
    """A PlantSimNode on an executor (composition): paced run ends itself, reports OK."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from fd_monitor.core.simulator import PlantSimulator
    from fd_monitor.nodes.diagnostics import OK
    from fd_monitor.nodes.plant_sim import PlantSimNode

    sc = load_scenario("three_tank_bias_h1")
    with ros_context() as ctx:
        col = Collector(ctx, ["/plant/y"], diagnostics=True)
        node = PlantSimNode(PlantSimulator(sc, [2]), context=ctx, parameter_overrides=[
            Parameter("rate_factor", value=100.0), Parameter("duration", value=2.0),
            Parameter("min_subscribers_y", value=1), Parameter("diagnostics_period", value=0.1)])
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(col.node)
        ex.add_node(node)
        assert spin_until(ex, lambda: node.done.done(), 30.0)
        assert spin_until(ex, lambda: len(col.msgs["/plant/y"]) == 20, 10.0)
        assert spin_until(ex, lambda: any("published 20" in status_text(s)
                                          for s in col.statuses("plant_sim")), 10.0)
        assert node.exit_code == 0 and node.published == 20
        st = col.statuses("plant_sim: simulation")[-1]
        assert st.level == OK and st.hardware_id == "three_tank"
        assert [d.stamp for d in col.decoded("/plant/y")] == list(range(20))
        ex.shutdown()
        node.destroy_node()
        col.node.destroy_node()



def test_plant_sim_start_delay_holds_the_first_sample():
    """With start_delay the first sample goes out that long after the subscribers are
    matched, not before (time for them to match the writer too)."""
    import time

    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from fd_monitor.core.simulator import PlantSimulator
    from fd_monitor.nodes.plant_sim import PlantSimNode

    sc = load_scenario("three_tank_bias_h1")
    with ros_context() as ctx:
        col = Collector(ctx, ["/plant/y"])
        node = PlantSimNode(PlantSimulator(sc, [2]), context=ctx, parameter_overrides=[
            Parameter("rate_factor", value=0.0), Parameter("duration", value=0.5),
            Parameter("min_subscribers_y", value=1), Parameter("start_delay", value=1.0)])
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(col.node)
        ex.add_node(node)
        assert spin_until(ex, lambda: node.pub_y.get_subscription_count() >= 1, 10.0)
        matched = time.monotonic()
        assert spin_until(ex, lambda: len(col.msgs["/plant/y"]) >= 1, 30.0)
        assert time.monotonic() - matched >= 1.0 - 0.3   # a 0.1 s tick of slack, and more
        assert spin_until(ex, lambda: node.done.done(), 30.0) and node.published == 5
        ex.shutdown()
        node.destroy_node()
        col.node.destroy_node()


@pytest.mark.parametrize("rate_factor, period", [(5.0, 0.02), (0.0, 0.001), (1.0e6, 0.001)])
def test_plant_sim_timer_ticks_once_per_sample(rate_factor, period):
    """Paced: one timer tick per sample (not a 1 ms poll); flat out keeps the 1 ms tick."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from fd_monitor.core.simulator import PlantSimulator
    from fd_monitor.nodes.plant_sim import PlantSimNode

    class Counting(PlantSimNode):
        running_ticks = 0

        def _on_tick(self) -> None:
            if self._t0 is not None and not self.done.done():
                self.running_ticks += 1
            super()._on_tick()

    with ros_context() as ctx:
        node = Counting(PlantSimulator(load_scenario("three_tank_bias_h1"), [2]), context=ctx,
                        parameter_overrides=[Parameter("rate_factor", value=rate_factor),
                                             Parameter("duration", value=2.0)])
        assert node.tick_period == pytest.approx(period)
        assert node._timer.timer_period_ns == round(period * 1e9)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        assert spin_until(ex, lambda: node.done.done(), 30.0)
        assert node.exit_code == 0 and node.published == 20
        if rate_factor == 5.0:
            # 20 samples over 0.4 s: about 19 more ticks (fewer if ticks came late and
            # caught up), where the former 1 ms poll ticked about 400 times.
            assert node.running_ticks <= 22
        ex.shutdown()
        node.destroy_node()


def test_plant_sim_keep_going_stops_cleanly_on_sigterm():
    from rclpy.executors import SingleThreadedExecutor

    with ros_context() as ctx:
        col = Collector(ctx, ["/plant/y"])
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(col.node)
        args = ["run", "plant_sim", "--ros-args", "-p", "rate_factor:=50.0",
                "-p", "duration:=0.5", "-p", "keep_going:=true", "-p", "min_subscribers_y:=1"]
        with Proc(args) as proc:
            # Past the 5 samples of `duration`: it keeps going.
            assert spin_until(ex, lambda: len(col.msgs["/plant/y"]) > 10, 30.0, [proc]), \
                proc.output()
            proc.signal(signal.SIGTERM)
            assert proc.wait(15) == 0, proc.output()
            assert "Traceback" not in proc.output()
        ex.shutdown()
        col.node.destroy_node()


@pytest.mark.parametrize("ros_args, match", [
    (["-p", "rate_factor:=1"], "parameter rate_factor"),
    (["-p", "scenario:=no_such_scenario"], "unknown scenario"),
    (["-p", "ack_window:=2000"], "ack_window (2000) must be below qos_depth"),
])
def test_plant_sim_bad_start_is_one_line_exit_2(ros_args, match):
    with Proc(["run", "plant_sim", "--ros-args", *ros_args]) as proc:
        assert proc.wait(30) == 2
        errors = [ln for ln in proc.output().splitlines() if "error" in ln]
        assert len(errors) == 1 and match in errors[0], proc.output()
        assert "Traceback" not in proc.output()


def test_plant_sim_times_out_waiting_for_subscribers():
    args = ["run", "plant_sim", "--ros-args", "-p", "min_subscribers_y:=5",
            "-p", "subscriber_timeout:=0.5"]
    with Proc(args) as proc:
        assert proc.wait(30) == 1
        assert "waiting for subscribers (/plant/u: 0/0, /plant/y: 0/5" in proc.output()


@pytest.mark.parametrize("scenario", ["thesis_6_5_overlap", "bag_farhat_koenig_fault"])
def test_plant_sim_publishes_rho_and_mode_of_lpv_and_switched_scenarios(scenario):
    """The node runs the same core simulator on an LPV and a switched plant: /plant/truth
    carries rho.<name> and the scheduled mode, equal to the core's truth."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from fd_monitor.core.simulator import (
        PlantSimulator,
        measured_signals,
        truth_values,
    )
    from fd_monitor.nodes.plant_sim import PlantSimNode
    from fd_monitor.wire.topics import PLANT_TRUTH, side_topic

    sc = load_scenario(scenario)
    K = 40
    side = {side_topic(n).absolute: v for n, v in measured_signals(simulate(sc, None, K)).items()}
    assert set(side) == {"thesis_6_5_overlap": {"/plant/rho"},
                         "bag_farhat_koenig_fault": {"/plant/mode"}}[scenario]
    with ros_context() as ctx:
        col = Collector(ctx, ["/plant/truth", *side])
        node = PlantSimNode(PlantSimulator(sc), context=ctx, parameter_overrides=[
            Parameter("rate_factor", value=0.0),
            Parameter("duration", value=K * sc.system.sample_time),
            Parameter("min_subscribers_truth", value=1), Parameter("ack_window", value=10)])
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(col.node)
        ex.add_node(node)
        assert spin_until(ex, lambda: all(len(m) >= K for m in col.msgs.values()), 30.0)
        ex.shutdown()
        node.destroy_node()
        col.node.destroy_node()
    got = col.decoded("/plant/truth")
    assert got[0].labels == PLANT_TRUTH.labels(sc)
    assert [d.stamp for d in got] == list(range(K))
    np.testing.assert_array_equal(np.array([d.values for d in got]),
                                  truth_values(simulate(sc, None, K)))
    # the measured side signals (the runtimes read them live as from a bag)
    for topic, (labels, values) in side.items():
        got = col.decoded(topic)
        assert got[0].labels == labels
        np.testing.assert_array_equal(np.array([d.values for d in got]), values)
