"""The observer node says on /diagnostics when the plant leaves the certified region
(issue 13): real nodes over DDS, bounded waits."""

from __future__ import annotations

import time

import pytest
from ros_util import Collector, ros_context, spin_until, status_text

pytestmark = pytest.mark.ros


def test_observer_warns_outside_certified_region():
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from std_msgs.msg import Float64MultiArray

    from fd_monitor.model.system import load_system
    from fd_monitor.nodes.diagnostics import OK, WARN
    from fd_monitor.nodes.observer import ObserverNode
    from fd_monitor.nodes.qos import data_pub_qos
    from fd_monitor.wire.conversions import to_msg

    system = load_system("three_tank")
    with ros_context() as ctx:
        # The observer alone (open loop: no feedback publisher). In the whole chain the bias
        # estimator attributes the level step to a sensor bias and pulls x^ back inside
        # within a few samples: whether /diagnostics catches that short excursion is timing.
        nodes = [ObserverNode(context=ctx, parameter_overrides=[
            Parameter("gains", value="three_tank_envelope"),
            Parameter("diagnostics_period", value=0.2)])]
        col = Collector(ctx, ["/fd/state_estimate"], diagnostics=True)
        drv = Node("driver", context=ctx)
        pub = {t: drv.create_publisher(Float64MultiArray, t, data_pub_qos())
               for t in ("/plant/u", "/plant/y")}
        ex = SingleThreadedExecutor(context=ctx)
        for n in (*nodes, col.node, drv):
            ex.add_node(n)
        assert spin_until(ex, lambda: pub["/plant/y"].get_subscription_count() >= 1, 10.0)

        def estimate(level, text):
            return any(s.level == level and text in status_text(s)
                       for s in col.statuses("observer: estimate"))

        k = 0

        def feed(y, until, timeout=10.0):
            # stamped samples, one per spin, until the status shows up (bounded)
            nonlocal k
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline and not until():
                pub["/plant/u"].publish(to_msg(system.inputs, k, [5e-5, 5e-5, 0.0]))
                pub["/plant/y"].publish(to_msg(system.outputs, k, y))
                k += 1
                ex.spin_once(timeout_sec=0.05)
            return until()

        # inside the envelope (levels <= 0.7 m): OK
        assert feed([0.40, 0.20, 0.30], lambda: estimate(OK, "mode closed_dry"))
        assert not estimate(WARN, "outside certified region")
        # h1 at 0.8 m: WARN naming the variable and the excess
        assert feed([0.80, 0.20, 0.30],
                    lambda: estimate(WARN, "outside certified region: h1 above by")), \
            [s.message for s in col.statuses("observer: estimate")][-3:]
        st = [s for s in col.statuses("observer: estimate") if s.level == WARN][-1]
        vals = {kv.key: kv.value for kv in st.values}
        assert vals["outside_certified_region"].startswith("h1 above by 0.0")
        for n in nodes:
            n.destroy_node()
        col.node.destroy_node()
        drv.destroy_node()
