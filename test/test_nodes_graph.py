"""The nodes on a real ROS graph: QoS, namespaces, lifecycle, reset, parameters, stamps.

Every test starts real nodes in-process (one executor with a driver node and a collector) and
talks over real DDS topics.
"""

from __future__ import annotations

import numpy as np
import pytest
from ros_util import Collector, ros_context, spin_until, status_text

from fd_monitor.core.methods import load_gains
from fd_monitor.core.monitor import Monitor
from fd_monitor.core.simulator import simulate
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system

pytestmark = pytest.mark.ros

K = 60


def data(k0=0, n=K):
    """u, y of the bias scenario with a large h1 bias from sample 40 (alarms within K)."""
    traj = simulate(load_scenario("three_tank_bias_h1"), 2, n)
    u, y = traj.u[0], traj.y[0]
    y[40:] += [0.05, 0.0, 0.0]
    return u, y


def expected(u, y):
    system = load_system("three_tank")
    m = Monitor(system, load_gains("three_tank_thresholds", system))
    return [m.step(k, u[k], y[k]) for k in range(len(u))]


class Rig:
    """Monitor nodes, a driver and a collector on one executor."""

    def __init__(self, ctx, nodes, topics=("fd/residual", "fd/alarm"), driver_qos=None,
                 ns=""):
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from std_msgs.msg import Float64MultiArray

        from fd_monitor.nodes.qos import data_pub_qos

        self.nodes = list(nodes)
        self.col = Collector(ctx, [f"{ns}/{t}" for t in topics], diagnostics=True,
                             name=f"collector{ns.replace('/', '_')}")
        self.drv = Node(f"driver{ns.replace('/', '_')}", context=ctx)
        qos = driver_qos if driver_qos is not None else data_pub_qos()
        self.pub = {t: self.drv.create_publisher(Float64MultiArray, f"{ns}/plant/{t}", qos)
                    for t in ("u", "y")}
        self.ex = SingleThreadedExecutor(context=ctx)
        for n in [*self.nodes, self.col.node, self.drv]:
            self.ex.add_node(n)

    def matched(self, n=2, timeout=10.0):
        return spin_until(self.ex, lambda: all(p.get_subscription_count() >= n
                                               for p in self.pub.values()), timeout)

    def send(self, u, y, ks, batch=True):
        """Publish samples ``ks``, marked as a batch (unpaced test input whose every sample
        must be processed, however far behind the nodes fall) unless ``batch`` is False."""
        from fd_monitor.wire.conversions import to_msg

        for k in ks:
            self.pub["u"].publish(to_msg(("q1", "q2", "v13"), k, u[k], batch=batch))
            self.pub["y"].publish(to_msg(("h1", "h2", "h3"), k, y[k], batch=batch))

    def spin(self, cond, timeout=20.0):
        return spin_until(self.ex, cond, timeout)

    def close(self):
        self.ex.shutdown()
        for n in [*self.nodes, self.col.node, self.drv]:
            n.destroy_node()


def params(**kw):
    from rclpy.parameter import Parameter

    return [Parameter(k, value=v) for k, v in kw.items()]


def test_default_and_best_effort_publishers_feed_the_in_process_chain():
    """A reliable/volatile publisher (ROS default) and a best-effort one (sensor data) both
    reach the chain's four nodes in one process and give its alarms; the switch is reported on
    /diagnostics naming the topic and the policy; the estimator's fault stays visible after
    the input stops."""
    from rclpy.qos import qos_profile_sensor_data

    from fd_monitor.nodes.diagnostics import ERROR, STALE, WARN
    from fd_monitor.nodes.monitor import make_chain

    u, y = data()
    want = expected(u, y)
    with ros_context() as ctx:
        rig = Rig(ctx, make_chain(context=ctx, parameter_overrides=params(
            stale_timeout=0.5, diagnostics_period=0.2)))
        assert {n.get_name() for n in rig.nodes} == {"detector", "observer", "agei",
                                                     "bias_estimator"}
        assert rig.matched()
        rig.send(u, y, range(K))
        assert rig.spin(lambda: len(rig.col.msgs["/fd/alarm"]) >= K), \
            len(rig.col.msgs["/fd/alarm"])
        alarms = [d.values > 0.5 for d in rig.col.decoded("/fd/alarm")]
        np.testing.assert_array_equal(alarms, [o.alarm for o in want])
        # The fault found stays on /diagnostics, with its estimate, when the input stops.
        assert rig.spin(lambda: any(s.level == STALE for s in rig.col.statuses("observer: "
                                                                               "input")))

        def kept():
            st = rig.col.statuses("/bias_estimator: estimate")
            return st and st[-1].level == WARN and "input stopped" in st[-1].message and \
                {kv.key for kv in st[-1].values} >= {"sigma_hat", "stale"}
        assert rig.spin(kept, 10.0)
        rig.close()

    with ros_context() as ctx:
        rig = Rig(ctx, make_chain(context=ctx), driver_qos=qos_profile_sensor_data)

        def switched():
            return any("/plant/y: QoS incompatible" in s.message and "RELIABILITY" in s.message
                       for s in rig.col.statuses("/observer: ros graph"))
        assert rig.spin(switched, 15.0)
        assert rig.matched(2, 15.0)
        # Best effort may drop on a burst: send at a pace and look for the alarm on h1.
        for k in range(K):
            rig.send(u, y, [k])
            rig.spin(lambda: False, 0.02)
        assert rig.spin(lambda: any(s.level == ERROR for s in
                                    rig.col.statuses("/detector: residual h1")), 15.0)
        rig.close()


def test_two_namespaced_monitors_do_not_see_each_other():
    from fd_monitor.nodes.monitor import make_chain

    u, y = data()
    with ros_context() as ctx:
        one = make_chain(context=ctx, namespace="/robot1")
        two = make_chain(context=ctx, namespace="/robot2")
        rig1 = Rig(ctx, one, ns="/robot1")
        rig2 = Rig(ctx, two, ns="/robot2")
        for n in two:
            rig1.ex.add_node(n)
        rig1.ex.add_node(rig2.col.node)
        rig1.ex.add_node(rig2.drv)
        assert rig1.matched() and spin_until(rig1.ex, lambda: all(
            p.get_subscription_count() >= 2 for p in rig2.pub.values()), 10.0)
        rig1.send(u, y, range(K))
        assert rig1.spin(lambda: len(rig1.col.msgs["/robot1/fd/alarm"]) >= K)
        rig1.spin(lambda: False, 1.0)
        assert rig2.col.msgs["/robot2/fd/alarm"] == []
        names = {s.name for s in rig1.col.statuses()}
        assert "/robot1/detector: residual h1" in names
        assert "/robot2/detector: residual h1" in names
        assert not any(s.name.startswith("/detector") for s in rig1.col.statuses())
        robot2_inputs = rig1.col.statuses("/robot2/observer: input")
        assert robot2_inputs and all(s.message != "receiving" for s in robot2_inputs)
        rig1.ex.shutdown()
        for n in [*one, *two, rig1.col.node, rig1.drv, rig2.col.node, rig2.drv]:
            n.destroy_node()


def test_lifecycle_reset_and_restarted_stream():
    """autostart false waits; configure/activate/deactivate/cleanup; ~/reset; a second run
    of the same stamps after a pause is a new run with the same results as the first."""
    from lifecycle_msgs.msg import State
    from std_srvs.srv import Trigger

    from fd_monitor.nodes.monitor import make_chain

    u, y = data()
    with ros_context() as ctx:
        nodes = make_chain(context=ctx, parameter_overrides=params(autostart=False,
                                                                   restart_after=0.3))
        rig = Rig(ctx, nodes)
        obs = nodes[0]
        assert obs._state_machine.current_state[0] == State.PRIMARY_STATE_UNCONFIGURED
        for n in nodes:
            n.trigger_configure()
        assert obs._state_machine.current_state[0] == State.PRIMARY_STATE_INACTIVE
        assert rig.matched()
        rig.send(u, y, range(5))                         # inactive: dropped, counted
        assert rig.spin(lambda: obs.inactive_dropped >= 10)
        assert rig.col.msgs["/fd/alarm"] == []
        for n in nodes:
            n.trigger_activate()
        rig.send(u, y, range(K))
        assert rig.spin(lambda: len(rig.col.msgs["/fd/alarm"]) >= K)
        first = [d.values for d in rig.col.decoded("/fd/residual")]
        # The same stamps again (a second bag, a restarted driver): a new run, same results.
        rig.spin(lambda: False, 0.5)
        rig.send(u, y, range(K))
        assert rig.spin(lambda: len(rig.col.msgs["/fd/alarm"]) >= 2 * K), \
            len(rig.col.msgs["/fd/alarm"])
        second = [d.values for d in rig.col.decoded("/fd/residual")][K:]
        np.testing.assert_array_equal(second, first)
        assert obs.join.new_runs == 1
        assert rig.spin(lambda: any("new run: the stream restarted at stamp 0" in s.message
                                    + str([kv.value for kv in s.values])
                                    for s in rig.col.statuses("/observer: input"))), \
            [(s.message, [(kv.key, kv.value) for kv in s.values])
             for s in rig.col.statuses("/observer: input")][-3:]
        # ~/reset: the next sample starts a run at once.
        cli = rig.drv.create_client(Trigger, "/observer/reset")
        assert cli.wait_for_service(5.0)
        fut = cli.call_async(Trigger.Request())
        assert rig.spin(fut.done, 5.0) and fut.result().success
        assert obs.join.k_next is None
        for n in nodes:
            n.trigger_deactivate()
        assert not obs.active
        for n in nodes:
            n.trigger_cleanup()
        assert obs._state_machine.current_state[0] == State.PRIMARY_STATE_UNCONFIGURED
        rig.close()


def test_stray_stamp_does_not_blind_the_monitor():
    """One pair stamped 2**52 then good samples: the good samples are processed."""
    from fd_monitor.nodes.monitor import make_chain

    u, y = data()
    with ros_context() as ctx:
        nodes = make_chain(context=ctx)
        rig = Rig(ctx, nodes)
        assert rig.matched()
        rig.send(u, y, range(20))
        assert rig.spin(lambda: len(rig.col.msgs["/fd/alarm"]) >= 20)
        from fd_monitor.wire.conversions import to_msg

        rig.pub["u"].publish(to_msg(("q1", "q2", "v13"), 2**52, u[20]))
        rig.pub["y"].publish(to_msg(("h1", "h2", "h3"), 2**52, y[20]))
        rig.send(u, y, range(20, K))
        assert rig.spin(lambda: len(rig.col.msgs["/fd/alarm"]) >= K)
        assert [d.stamp for d in rig.col.decoded("/fd/alarm")][:K] == list(range(K))
        # a long status keeps its first clause; the reasons are in its values
        assert rig.spin(lambda: any("more than 100000 samples ahead" in status_text(s)
                                    for s in rig.col.statuses("/observer: input")))
        rig.close()


def test_runtime_parameters_and_gain_swap():
    from rclpy.parameter import Parameter

    from fd_monitor.nodes.diagnostics import WARN
    from fd_monitor.nodes.monitor import make_chain

    u, y = data()
    with ros_context() as ctx:
        nodes = make_chain(context=ctx)
        det = nodes[1]
        rig = Rig(ctx, nodes)
        assert rig.matched()
        res = det.set_parameters([Parameter("warn_share", value=0.0)])
        assert res[0].successful and det.params.warn_share == 0.0
        rig.send(u, y, range(10))                        # |r| > 0 x R: WARN everywhere
        assert rig.spin(lambda: any(s.level == WARN and "0 x threshold" in s.message
                                    for s in rig.col.statuses("/detector: residual h2")))
        assert det.set_parameters([Parameter("stale_timeout", value=5.0)])[0].successful
        refused = det.set_parameters([Parameter("system", value="pwa_cascade")])[0]
        assert not refused.successful and "read-only" in refused.reason
        bad = det.set_parameters([Parameter("gains", value="pwa_cascade_qb")])[0]
        assert not bad.successful and "still running" in bad.reason
        assert det.get_parameter("gains").value == "three_tank_thresholds"
        assert rig.spin(lambda: any("refused" in s.message
                                    for s in rig.col.statuses("/detector: ros graph")))
        rig.send(u, y, range(10, K))                    # keeps running the old gain file
        assert rig.spin(lambda: len(rig.col.msgs["/fd/alarm"]) >= K)
        good = det.set_parameters([Parameter("gains", value="three_tank_thresholds")])[0]
        assert good.successful
        rig.close()


def test_plain_y_without_u_is_reported_not_processed():
    from std_msgs.msg import Float64MultiArray

    from fd_monitor.nodes.diagnostics import WARN
    from fd_monitor.nodes.observer import ObserverNode

    with ros_context() as ctx:
        obs = ObserverNode(context=ctx)
        rig = Rig(ctx, [obs], topics=("fd/state_estimate",))
        assert rig.matched(1)
        m = Float64MultiArray()
        m.data = [0.4, 0.2, 0.3]
        rig.pub["y"].publish(m)
        assert rig.spin(lambda: any(
            s.level == WARN and "/plant/y sample 0: no /plant/u received before it" in s.message
            for s in rig.col.statuses("/observer: input")))
        assert obs.processed == 0 and rig.col.msgs["/fd/state_estimate"] == []
        rig.close()


def test_second_monitor_on_the_same_outputs_is_warned_about():
    from fd_monitor.nodes.detector import DetectorNode

    with ros_context() as ctx:
        a = DetectorNode(context=ctx, parameter_overrides=params(layout="chain"))
        b = DetectorNode(context=ctx, node_name="detector2",
                         parameter_overrides=params(layout="chain"))
        rig = Rig(ctx, [a, b])
        assert rig.spin(lambda: any("/fd/alarm: also published by /detector2" in s.message
                                    for s in rig.col.statuses("/detector: ros graph")), 15.0)
        rig.close()
