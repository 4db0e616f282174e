"""A burst of 50,000 samples must degrade to reported holes, then recover (issue 12).

Before: the entry node waited forever for feedback that the burst had pushed out of a
publisher's 1000-deep history ("waiting for feedback, not a hole"), buffering everything
after it; nothing more was ever processed. Now lost feedback is a restart after
``gap_timeout`` (downstream: ``restart_after``), so the chain recovers.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from ros_util import ros_context, spin_until
from test_nodes_graph import Rig

pytestmark = [pytest.mark.ros, pytest.mark.slow]

BURST = 50_000


def test_burst_of_50000_then_a_new_publisher_is_processed():
    from rclpy.node import Node
    from std_msgs.msg import Float64MultiArray

    from fd_monitor.nodes.common import data_pub_qos
    from fd_monitor.nodes.conversions import to_msg
    from fd_monitor.nodes.monitor import make_nodes

    u = np.array([1.0e-4, 1.0e-4, 0.0])
    y = np.array([0.4, 0.2, 0.3])
    with ros_context() as ctx:
        nodes = make_nodes(context=ctx)
        rig = Rig(ctx, nodes, topics=("fd/state_estimate",))
        obs = nodes[0]
        assert rig.matched()
        for k in range(BURST):                       # unpaced: the history overflows
            rig.pub["u"].publish(to_msg(("q1", "q2", "v13"), k, u))
            rig.pub["y"].publish(to_msg(("h1", "h2", "h3"), k, y))
        rig.spin(lambda: False, 5.0)
        after_burst = obs.processed
        # A new publisher (a restarted driver) continues the stamps; it must get through.
        drv2 = Node("driver2", context=ctx)
        pubs = {t: drv2.create_publisher(Float64MultiArray, f"/plant/{t}", data_pub_qos())
                for t in ("u", "y")}
        rig.ex.add_node(drv2)
        assert spin_until(rig.ex, lambda: all(p.get_subscription_count() >= 2
                                              for p in pubs.values()), 10.0)
        k0 = BURST + 10
        for k in range(k0, k0 + 200):
            pubs["u"].publish(to_msg(("q1", "q2", "v13"), k, u))
            pubs["y"].publish(to_msg(("h1", "h2", "h3"), k, y))
            rig.spin(lambda: False, 0.002)
        t0 = time.monotonic()
        got = lambda: sum(1 for m in rig.col.msgs["/fd/state_estimate"]  # noqa: E731
                          if m.data[0] >= k0)
        ok = rig.spin(lambda: got() >= 150, 60.0)
        print(f"burst: processed {after_burst} of {BURST} within 5 s, holes {obs.holes}; "
              f"new publisher: {got()} of 200 in {time.monotonic() - t0:.1f} s")
        assert ok, (after_burst, obs.holes, got())
        assert obs.holes > 0 or after_burst == BURST
        rig.close()
        drv2.destroy_node()
