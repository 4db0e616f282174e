"""The fused monitor for any gain file (MonitorNode): hinf_sc and hminus_switched live give
what the offline runtime gives, bit for bit; outside the certified region it says so on
/diagnostics; a bad side signal is reported and the node goes on. Real DDS, bounded waits."""

from __future__ import annotations

import numpy as np
import pytest
from ros_util import Collector, ros_context, spin_until, status_text

pytestmark = pytest.mark.ros

OUT = ("/fd/residual", "/fd/threshold", "/fd/alarm", "/fd/state_estimate")


def _drive(bag, n, edit=None, params=(), expect=None, pause_at=()):
    """Publish the first n samples of a library bag (u, y and the side signals the runtime
    needs) into a MonitorNode; return (node, collector, decoded outputs, inputs)."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from std_msgs.msg import Float64MultiArray

    from fd_monitor.analysis.library import load_library
    from fd_monitor.core.methods import load_gains
    from fd_monitor.model.system import load_system
    from fd_monitor.nodes.monitor import MonitorNode
    from fd_monitor.nodes.qos import data_pub_qos
    from fd_monitor.wire.bag_reader import read_bag
    from fd_monitor.wire.bag_scanner import bag_topics
    from fd_monitor.wire.conversions import to_msg

    spec = load_library()[bag]
    gf0 = load_gains(spec.gains, verify=False)
    system = load_system(gf0.system_name)
    gf = load_gains(spec.gains, system)
    topics = ["/plant/u", "/plant/y", "/plant/rho", "/plant/mode"]
    b = read_bag(spec.folder, [t for t in topics if t in bag_topics(spec.folder)])
    data = {t: (a.labels, a.values[:n].copy()) for t, a in b.items() if t != "/plant/truth"}
    if edit is not None:
        edit(data)
    with ros_context() as ctx:
        node = MonitorNode(system=system, gains=gf, context=ctx, parameter_overrides=[
            Parameter("diagnostics_period", value=0.2), *params])
        col = Collector(ctx, list(OUT), diagnostics=True)
        drv = Node("driver", context=ctx)
        pub = {t: drv.create_publisher(Float64MultiArray, t, data_pub_qos()) for t in data}
        ex = SingleThreadedExecutor(context=ctx)
        for nd in (node, col.node, drv):
            ex.add_node(nd)
        assert spin_until(ex, lambda: all(p.get_subscription_count() >= 1
                                          for t, p in pub.items()
                                          if t in ("/plant/y", *node_side(node))), 10.0)
        for k in range(n):
            for t, (labels, vals) in data.items():
                pub[t].publish(to_msg(labels, k, vals[k], batch=True))
            ex.spin_once(timeout_sec=0.0)
            if k in pause_at:
                # the plant holds this state until /diagnostics has shown it: the node has
                # taken sample k, then published two diagnostics arrays
                assert spin_until(ex, lambda k=k: node.processed >= k + 1, 30.0), node.processed
                seen = len(col.diagnostics)
                assert spin_until(ex, lambda seen=seen: len(col.diagnostics) >= seen + 2, 10.0)
        want = n if expect is None else expect
        done = spin_until(ex, lambda: all(len(col.msgs[t]) >= want for t in OUT), 60.0)
        assert done, ({t: len(col.msgs[t]) for t in OUT}, node.processed)
        # what the last samples did is reported at the next diagnostics period: two more
        # arrays (on a loaded machine the run can end within one period)
        seen = len(col.diagnostics)
        assert spin_until(ex, lambda: len(col.diagnostics) >= seen + 2, 10.0)
        # raw values: a threshold is +inf while a bank settles (decode refuses non-finite)
        got = {t: (col.decoded(t) if t != "/fd/threshold" else None,
                   np.array([m.data[1:] for m in col.msgs[t]]),
                   [int(m.data[0]) for m in col.msgs[t]]) for t in OUT}
        statuses = col.statuses()
        ex.shutdown()
        for nd in (node, col.node, drv):
            nd.destroy_node()
    return system, gf, got, data, statuses


def node_side(node):
    return [f"/plant/{n}" for n in node.runtime.side_inputs]


def _offline(system, gf, data, n):
    from fd_monitor.core.methods import runtime_for

    rt = runtime_for(system, gf)
    side = {name: data[f"/plant/{name}"][1] for name in rt.side_inputs}
    u = data["/plant/u"][1] if "/plant/u" in data else np.zeros((n, 0))
    return rt, rt.run(np.arange(n), u, data["/plant/y"][1], side or None)


@pytest.mark.parametrize("bag, what", [
    ("three_tank_lpv_leaks_abrupt", "hinf_sc LPV, rho from the levels"),
    ("farhat_koenig_fault", "hminus_switched, mode from /plant/mode"),
])
def test_monitor_equals_the_offline_runtime(bag, what):
    n = 1200 if bag.startswith("three_tank") else 600
    system, gf, got, data, _ = _drive(bag, n)
    rt, ref = _offline(system, gf, data, n)
    assert got["/fd/residual"][2] == list(range(n))
    for topic, want in (("/fd/residual", ref.residual), ("/fd/threshold", ref.threshold),
                        ("/fd/alarm", ref.alarm.astype(float))):
        if got[topic][0] is not None:
            assert got[topic][0][0].labels == rt.channels
        np.testing.assert_array_equal(got[topic][1], want, err_msg=topic)
    est = got["/fd/state_estimate"][1]
    np.testing.assert_array_equal(est[:, 0], ref.mode)
    np.testing.assert_array_equal(est[:, 1:], ref.estimates["x_hat"].reshape(n, -1))
    if bag.startswith("three_tank"):
        assert ref.alarm[1003:].any() and not ref.alarm[:1000].any()   # the leak at 1000


def test_monitor_reports_a_mode_the_design_lacks_and_a_bad_side_signal():
    """/plant/mode = 7 (no such mode) from sample 200: WARN outside certified region naming
    the mode; a NaN mode at 400 is a bad message and a hole, and the node goes on."""
    def edit(data):
        modes = data["/plant/mode"][1]
        modes[200:260] = 7.0
        modes[400] = np.nan

    *_, got, _, statuses = _drive("farhat_koenig_fault", 600, edit, expect=599,
                                  pause_at=(230,))
    est = [s for s in statuses if s.name.endswith("monitor: estimate")]
    warn = [s for s in est if "outside certified region: mode above by" in status_text(s)]
    assert warn, [s.message for s in est][-5:]
    stamps = got["/fd/residual"][2]
    assert 400 not in stamps and stamps[-1] == 599 and len(stamps) == 599
    inp = [s for s in statuses if s.name.endswith("monitor: input")]
    assert any("/plant/mode stamp 400: value mode is nan" in status_text(s) for s in inp), \
        sorted({status_text(s) for s in inp})


def test_monitor_reads_the_parameters_the_node_would_see(tmp_path):
    """`monitor` decides which nodes to make before any exists, from the parameters the node
    would see: parameter overrides, a params file, the defaults."""
    from rclpy.parameter import Parameter

    from fd_monitor.nodes.monitor import peek_parameters

    names = ("system", "gains", "layout")
    params = tmp_path / "p.yaml"
    params.write_text("monitor:\n  ros__parameters:\n    system: pwa_cascade\n"
                      "    gains: pwa_cascade_qb\n    layout: chain\n")
    with ros_context() as ctx:
        assert peek_parameters("monitor", names, context=ctx) == {
            "system": "three_tank", "gains": "three_tank_thresholds", "layout": "fused"}
        assert peek_parameters("monitor", names, context=ctx, parameter_overrides=[
            Parameter("gains", value="farhat_koenig_hminus_switched")])["gains"] == \
            "farhat_koenig_hminus_switched"
    with ros_context(args=["--ros-args", "--params-file", str(params)]) as ctx:
        assert peek_parameters("monitor", names, context=ctx) == {
            "system": "pwa_cascade", "gains": "pwa_cascade_qb", "layout": "chain"}
