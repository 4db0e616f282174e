"""The fused ``monitor`` node: the chain's outputs from one join and one Monitor.step per
sample; bad input is reported on /diagnostics and changes nothing; ``layout: chain`` gives
the four nodes; a gain-file swap and a qb gain file are handled like the chain nodes do.

A driver node publishes *plain* Float64MultiArrays on /plant/u and /plant/y (stamped on
arrival) with bad messages mixed in; the node's outputs on every topic must equal the
in-process Monitor on the good samples, value for value.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from ros_util import FD_TOPICS as TOPICS
from ros_util import (
    Collector,
    biased_h1_run,
    expected_payloads,
    plain_msg,
    ros_context,
    spin_until,
    status_text,
)

pytestmark = pytest.mark.ros

K = 60


def test_fused_monitor_bad_input_reported_outputs_equal_monitor():
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from std_msgs.msg import Float64MultiArray

    from fd_monitor.nodes.diagnostics import ERROR, WARN
    from fd_monitor.nodes.monitor import MonitorNode, make_nodes
    from fd_monitor.nodes.qos import data_pub_qos

    _, u, y, want = biased_h1_run(K)  # a large bias on h1 from sample 40: alarms in the run

    with ros_context() as ctx:
        overrides = [Parameter("stale_timeout", value=0.5),
                     Parameter("diagnostics_period", value=0.2)]
        nodes = make_nodes(context=ctx, parameter_overrides=overrides)
        assert len(nodes) == 1 and isinstance(nodes[0], MonitorNode)
        col = Collector(ctx, TOPICS, diagnostics=True)
        drv = Node("driver", context=ctx)
        pub = {t: drv.create_publisher(Float64MultiArray, t, data_pub_qos())
               for t in ("/plant/u", "/plant/y")}
        ex = EventsExecutor(context=ctx)            # what `monitor` runs on
        for n in [*nodes, col.node, drv]:
            ex.add_node(n)
        assert spin_until(ex, lambda: all(p.get_subscription_count() >= 1
                                          for p in pub.values())
                          and all(col.node.count_publishers(t) >= 1 for t in TOPICS), 10.0)
        for k in range(K):
            if k == 5:
                pub["/plant/y"].publish(plain_msg([y[k, 0], math.nan, y[k, 2]]))  # NaN
                pub["/plant/y"].publish(plain_msg(y[k, :2]))                      # wrong length
                pub["/plant/u"].publish(plain_msg([math.inf, 0.0, 0.0]))          # Inf
            pub["/plant/u"].publish(plain_msg(u[k]))
            ex.spin_once(timeout_sec=0.0)
            pub["/plant/y"].publish(plain_msg(y[k]))
            ex.spin_once(timeout_sec=0.0)
        assert spin_until(ex, lambda: len(col.msgs["/fd/bias_estimate"]) >= K, 30.0), \
            {t: len(v) for t, v in col.msgs.items()}

        from fd_monitor.wire.conversions import decode

        exp = expected_payloads(want)
        for t in TOPICS:
            got = [decode(msg, t, allow_nan=True) for msg in col.msgs[t]]
            first = 1 if t in TOPICS[4:] else 0          # feedback: stamped k + 1
            assert [d.stamp for d in got] == list(range(first, K + first)), t
            np.testing.assert_array_equal([d.values for d in got], exp[t], err_msg=t)
        assert any(o.alarm.any() for o in want)

        def reported(text, level=WARN):
            return any(s.level == level and text in status_text(s)
                       for s in col.statuses("/monitor: input"))

        checks = ["/plant/y: value h2 is nan", "/plant/y: wrong length: 2 values, expected 3",
                  "/plant/u: value q1 is inf"]
        assert spin_until(ex, lambda: all(reported(c) for c in checks), 10.0), \
            [c for c in checks if not reported(c)]
        # per-channel residual status (ERROR on alarm), AGEI tracker and bias estimate
        assert spin_until(ex, lambda: any(s.level == ERROR for s in
                                          col.statuses("/monitor: residual h1")), 10.0)
        names = {s.name for s in col.statuses("/monitor")}
        assert {"/monitor: estimate", "/monitor: tracker", "/monitor: bias estimate",
                "/monitor: residual h2", "/monitor: ros graph"} <= names
        st = col.statuses("/monitor: bias estimate")[-1]
        assert st.level == WARN and ("estimating" in st.message or "bias on" in st.message)
        ex.shutdown()
        for n in [*nodes, col.node, drv]:
            n.destroy_node()


def test_layout_nodes_gives_the_four_nodes_and_a_bad_layout_is_refused(capfd):
    """``layout: nodes`` makes the chain's four nodes; its old name ``chain`` makes the same
    four with ONE deprecation warning naming ``nodes``; an unknown layout is refused."""
    from rclpy.parameter import Parameter

    from fd_monitor.model.errors import FdMonitorError
    from fd_monitor.nodes.monitor import make_nodes

    with ros_context() as ctx:
        for layout in ("nodes", "chain"):
            capfd.readouterr()
            nodes = make_nodes(context=ctx, parameter_overrides=[Parameter("layout",
                                                                           value=layout)])
            assert [n.get_name() for n in nodes] == ["observer", "detector", "agei",
                                                     "bias_estimator"]
            for n in nodes:
                n.destroy_node()
            err = capfd.readouterr().err
            assert err.count("is deprecated") == (layout == "chain"), err
            if layout == "chain":
                assert "parameter layout: 'chain' is deprecated: use 'nodes'" in err
        with pytest.raises(FdMonitorError, match="parameter layout: 'star'"):
            make_nodes(context=ctx, parameter_overrides=[Parameter("layout", value="star")])


def test_detector_is_one_node_and_its_old_layouts_say_so(capfd, monkeypatch):
    """The detector executable is the detector node alone: ``layout: chain`` (what it was)
    is accepted with ONE deprecation warning; without an observer it says once that it
    needs one and that ``monitor`` is the whole chain; ``standalone`` (the whole chain, now
    ``monitor``'s) is refused in one line naming ``monitor -p layout:=nodes``."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from fd_monitor.model.errors import FdMonitorError
    from fd_monitor.nodes import detector
    from fd_monitor.nodes.detector import DetectorNode

    monkeypatch.setattr(detector, "ENTRY_HINT", 0.2)   # s (5 s in a real process)
    with ros_context() as ctx:
        capfd.readouterr()
        det = DetectorNode(context=ctx, parameter_overrides=[Parameter("layout",
                                                                       value="chain")])
        assert det.active
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(det)
        seen: list[str] = []

        def hinted() -> bool:
            seen.append(capfd.readouterr().err)
            return "no publisher of /fd/state_estimate" in "".join(seen)
        assert spin_until(ex, hinted, 10.0)
        ex.shutdown()
        det.destroy_node()
        err = "".join(seen) + capfd.readouterr().err
        assert err.count("is deprecated") == 1 and "layout: 'chain' is deprecated" in err
        assert err.count("no publisher of /fd/state_estimate") == 1 and "run `monitor`" in err
        with pytest.raises(FdMonitorError) as exc:
            DetectorNode(context=ctx, parameter_overrides=[Parameter("layout",
                                                                     value="standalone")])
        line = str(exc.value)
        assert "\n" not in line and "'standalone' was removed" in line
        assert "monitor -p layout:=nodes" in line


def test_other_methods_run_in_the_one_fused_node():
    """A qb gain file (any method) runs in the same fused MonitorNode, with the registry's
    runtime (test_nodes_runtime.py checks its outputs against the offline run), also with
    layout:=nodes (the four-node chain is the thresholds method's)."""
    from rclpy.parameter import Parameter

    from fd_monitor.nodes.monitor import MonitorNode, make_nodes
    from fd_monitor.wire.topics import RUNTIME_OUTPUTS

    with ros_context() as ctx:
        for layout in ("fused", "nodes"):
            nodes = make_nodes(context=ctx, parameter_overrides=[
                Parameter("system", value="pwa_cascade"),
                Parameter("gains", value="pwa_cascade_qb"), Parameter("layout", value=layout)])
            assert [type(n) for n in nodes] == [MonitorNode]
            assert nodes[0].get_name() == "monitor" and nodes[0].runtime.method == "qb"
            assert nodes[0].outputs == RUNTIME_OUTPUTS
            for n in nodes:
                n.destroy_node()
