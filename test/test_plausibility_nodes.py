"""Plausibility limits in the live chain: y = 1e300 is refused by the observer node, reported
on /diagnostics, and the chain bridges the lost sample at the next one with no alarm (issue 12
item 2; issue 19: a hole is not amnesia)."""

from __future__ import annotations

import numpy as np
import pytest
from ros_util import Collector, plain_msg, ros_context, spin_until, status_text

from fd_monitor.core.simulator import simulate
from fd_monitor.model.scenario import load_scenario

pytestmark = pytest.mark.ros

K = 60
BAD = 30


def test_live_chain_refuses_1e300_and_recovers():
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from std_msgs.msg import Float64MultiArray

    from fd_monitor.nodes.diagnostics import WARN
    from fd_monitor.nodes.monitor import make_chain
    from fd_monitor.nodes.qos import data_pub_qos

    traj = simulate(load_scenario("three_tank_nominal"), 1, K)
    u, y = traj.u[0], traj.y[0].copy()
    y[BAD, 1] = 1e300

    with ros_context() as ctx:
        nodes = make_chain(context=ctx,
                           parameter_overrides=[Parameter("diagnostics_period", value=0.2)])
        col = Collector(ctx, ["/fd/alarm", "/fd/bias_estimate", "/fd/state_estimate"],
                        diagnostics=True)
        drv = Node("driver", context=ctx)
        pub = {t: drv.create_publisher(Float64MultiArray, t, data_pub_qos())
               for t in ("/plant/u", "/plant/y")}
        ex = SingleThreadedExecutor(context=ctx)
        for n in [*nodes, col.node, drv]:
            ex.add_node(n)
        assert spin_until(ex, lambda: pub["/plant/y"].get_subscription_count() >= 2, 10.0)
        for k in range(K):
            pub["/plant/u"].publish(plain_msg(u[k]))
            pub["/plant/y"].publish(plain_msg(y[k]))
        assert spin_until(ex, lambda: len(col.msgs["/fd/bias_estimate"]) >= K - 1, 30.0), \
            {t: len(v) for t, v in col.msgs.items()}

        est = col.decoded("/fd/state_estimate")
        assert [d.stamp for d in est] == [k for k in range(K) if k != BAD]
        restart = {d.stamp for d in est if d.values[-2] > 0.5}    # fields ..., restart, bridge
        bridge = {d.stamp for d in est if d.values[-1] > 0.5}
        assert restart == {0} and bridge == {BAD + 1}   # a hole at BAD: bridged after it
        sig = np.array([d.values[:3] for d in col.decoded("/fd/bias_estimate")])
        assert np.all(np.abs(sig) < 1e-3)               # 1e300 never reached the estimator
        assert not any(np.any(d.values > 0.5) for d in col.decoded("/fd/alarm"))
        assert spin_until(ex, lambda: any(
            s.level == WARN and f"y at sample {BAD}: h2 = 1e+300" in status_text(s)
            and "implausible" in status_text(s) for s in col.statuses("observer: input")), 10.0)
        # the bridge is reported and counted on /diagnostics
        assert spin_until(ex, lambda: any(
            f"bridged at {BAD + 1} after 1 refused sample(s)" in status_text(s)
            and {kv.key: kv.value for kv in s.values}.get("bridged") == "1"
            for s in col.statuses("observer: input")), 10.0)
        ex.shutdown()
        for n in [*nodes, col.node, drv]:
            n.destroy_node()
