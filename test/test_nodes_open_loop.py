"""An observer without the nodes that feed it back runs open loop at full rate (issue 12's
CI hang: a feedback pair not yet matched cost one ``gap_timeout`` per sample). Real nodes over
DDS, bounded waits."""

from __future__ import annotations

import numpy as np
import pytest
from ros_util import Collector, ros_context, spin_until

pytestmark = pytest.mark.ros


def test_observer_alone_runs_every_sample_without_waiting_for_feedback():
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from std_msgs.msg import Float64MultiArray

    from fd_monitor.core.hybrid_observer import NO_TRIGGER, HybridObserver
    from fd_monitor.core.methods import load_gains
    from fd_monitor.core.monitor import Monitor
    from fd_monitor.model.system import load_system
    from fd_monitor.nodes.observer import ObserverNode
    from fd_monitor.nodes.qos import data_pub_qos
    from fd_monitor.wire.conversions import to_msg

    system = load_system("three_tank")
    gains = load_gains("three_tank_thresholds", system)
    n = 300
    with ros_context() as ctx:
        obs = ObserverNode(context=ctx, parameter_overrides=[
            Parameter("gains", value="three_tank_thresholds")])
        col = Collector(ctx, ["/fd/state_estimate"])
        drv = Node("driver", context=ctx)
        pub = {t: drv.create_publisher(Float64MultiArray, t, data_pub_qos())
               for t in ("/plant/u", "/plant/y")}
        ex = SingleThreadedExecutor(context=ctx)
        for nd in (obs, col.node, drv):
            ex.add_node(nd)
        assert spin_until(ex, lambda: pub["/plant/y"].get_subscription_count() >= 1, 10.0)
        u, y = [5e-5, 5e-5, 0.0], [0.40, 0.20, 0.30]
        for k in range(n):
            pub["/plant/u"].publish(to_msg(system.inputs, k, u, batch=True))
            pub["/plant/y"].publish(to_msg(system.outputs, k, y, batch=True))
            ex.spin_once(timeout_sec=0.0)

        def count():
            return len(col.msgs["/fd/state_estimate"])

        # with a wait of gap_timeout (1 s) per sample this would take 300 s
        assert spin_until(ex, lambda: count() >= n, 30.0), count()
        assert obs.holes == 0 and obs.processed == n
        # open loop = the core observer fed sigma^ = 0 and no trigger at every sample
        ref = HybridObserver(system, region=Monitor(system, gains).gains.region)
        got = col.decoded("/fd/state_estimate")
        assert [d.stamp for d in got] == list(range(n))
        for k, d in enumerate(got):
            out = ref.step(k, np.array(u), np.array(y), np.zeros(3), NO_TRIGGER)
            assert np.array_equal(d.values[1:1 + system.n], np.ravel(out.x_hat)), k
        for nd in (obs, col.node, drv):
            nd.destroy_node()
