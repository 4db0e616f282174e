"""QB runtime in the nodes: observer + detector processes equal the offline runner.

``bags/pwa_cascade_b1_step`` (the QB paper's Sec. VI plant, bias step on x3 at 25 s) is
replayed flat out into ``observer`` and ``detector`` run with the ``pwa_cascade_qb`` gain
file; the recorded alarms, signals and thresholds must equal
:func:`fd_monitor.analysis.offline.run_bag` sample for sample.
"""

from __future__ import annotations

import numpy as np
import pytest
from ros_util import REPO, Proc, replay_through

from fd_monitor.analysis.offline import run_bag
from fd_monitor.wire.bag_reader import read_bag

pytestmark = pytest.mark.ros

BAG = REPO / "bags/pwa_cascade_b1_step"
TOPICS = ["/fd/state_estimate", "/fd/residual", "/fd/threshold", "/fd/alarm"]
QB = ["--ros-args", "-p", "system:=pwa_cascade", "-p", "gains:=pwa_cascade_qb"]


def test_qb_observer_and_detector_equal_offline(tmp_path):
    off = run_bag(BAG, "pwa_cascade_qb")
    n = len(off.k)
    procs = [Proc(["run", x, *QB]) for x in ("observer", "detector")]
    until = [a for t in TOPICS for a in ("--until", f"{t}={n}")]
    rec = Proc(["record", *TOPICS, "-o", str(tmp_path / "rec"), *until])
    # pwa_cascade has no inputs: the QB observer subscribes to /plant/y only.
    replay_through(procs, rec, BAG, ["/plant/y"], wait_subscribers=1)
    got = read_bag(tmp_path / "rec", TOPICS)
    for t in TOPICS:
        np.testing.assert_array_equal(got[t].stamps, off.k, err_msg=t)
    assert got["/fd/alarm"].labels == off.channels
    np.testing.assert_array_equal(got["/fd/alarm"].values > 0.5, off.alarm)
    np.testing.assert_array_equal(got["/fd/residual"].values, off.signal)
    np.testing.assert_array_equal(got["/fd/threshold"].values, off.threshold)
    np.testing.assert_array_equal(got["/fd/state_estimate"].values[:, 0], off.mode_hat)
    assert off.alarm.any()                         # the bias step is detected


def test_qb_observer_warns_outside_a_stated_envelope(tmp_path):
    """Issue 13: a QB gain file that states a region (results.envelope) is checked at every
    sample by the observer node: WARN `outside certified region` naming the state and the
    excess on /diagnostics, as the qb runtime marks it offline."""
    import yaml
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from ros_util import Collector, ros_context, spin_until, status_text
    from std_msgs.msg import Float64MultiArray

    from fd_monitor.core.methods import load_gains
    from fd_monitor.model.gains import write_gain_doc
    from fd_monitor.model.system import load_system
    from fd_monitor.nodes.diagnostics import WARN
    from fd_monitor.nodes.observer import ObserverNode
    from fd_monitor.nodes.qos import data_pub_qos
    from fd_monitor.wire.conversions import to_msg

    system = load_system("pwa_cascade")
    doc = yaml.safe_load((REPO / "config/gains/pwa_cascade_qb.yaml").read_text())
    m = len(system.modes)
    # a (deliberately narrow) declared box: |x1| <= 0.005 (the run reaches 0.018), the rest
    # wide
    doc["results"]["envelope"] = {"source": "declared",
                                  "state_lo": [[-0.005, -1e3, -1e3, -1e3]] * m,
                                  "state_hi": [[0.005, 1e3, 1e3, 1e3]] * m,
                                  "input_lo": [[]] * m, "input_hi": [[]] * m}
    path = write_gain_doc(tmp_path / "qb_env.yaml", doc)
    gains = load_gains(path, system)
    y = read_bag(REPO / "bags/pwa_cascade_nominal", ["/plant/y"])["/plant/y"].values
    with ros_context() as ctx:
        obs = ObserverNode(system=system, gains=gains, context=ctx, parameter_overrides=[
            Parameter("diagnostics_period", value=0.2)])
        col = Collector(ctx, ["/fd/state_estimate"], diagnostics=True)
        drv = Node("driver", context=ctx)
        pub = drv.create_publisher(Float64MultiArray, "/plant/y", data_pub_qos())
        ex = SingleThreadedExecutor(context=ctx)
        for nd in (obs, col.node, drv):
            ex.add_node(nd)
        assert spin_until(ex, lambda: pub.get_subscription_count() >= 1, 10.0)

        def warned():
            return any(s.level == WARN and "outside certified region: x1 " in status_text(s)
                       for s in col.statuses("observer: estimate"))

        k = 0
        while k < len(y) and not warned():
            pub.publish(to_msg(system.outputs, k, y[k]))
            k += 1
            ex.spin_once(timeout_sec=0.01)
        assert spin_until(ex, warned, 5.0), [s.message for s in col.statuses("estimate")][-3:]
        st = [s for s in col.statuses("observer: estimate") if s.level == WARN][-1]
        vals = {kv.key: kv.value for kv in st.values}
        assert vals["outside_certified_region"].startswith("x1 ")
        for nd in (obs, col.node, drv):
            nd.destroy_node()
