"""The chain nodes in one process: bad input is reported and changes nothing; STALE; start-up.

A driver node publishes *plain* Float64MultiArrays on /plant/u and /plant/y (no stamp, no
labels: stamped on arrival) with bad messages mixed in; the four nodes' outputs must equal
the in-process Monitor on the good samples, and each bad message must show up on
/diagnostics with its reason.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from ros_util import Collector, Proc, biased_h1_run, plain_msg, ros_context, spin_until, status_text

pytestmark = pytest.mark.ros

K = 60


def test_bad_messages_are_reported_and_change_nothing():
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from std_msgs.msg import Float64MultiArray

    from fd_monitor.nodes.diagnostics import ERROR, STALE, WARN
    from fd_monitor.nodes.monitor import make_chain
    from fd_monitor.nodes.qos import data_pub_qos
    from fd_monitor.wire.conversions import to_msg

    _, u, y, want = biased_h1_run(K)  # a large bias on h1 from sample 40: alarms in the run

    with ros_context() as ctx:
        overrides = [Parameter("stale_timeout", value=0.5),
                     Parameter("diagnostics_period", value=0.2)]
        nodes = make_chain(context=ctx, parameter_overrides=overrides)
        col = Collector(ctx, ["/fd/residual", "/fd/alarm", "/fd/bias_estimate",
                              "/fd/state_estimate"], diagnostics=True)
        drv = Node("driver", context=ctx)
        pub = {t: drv.create_publisher(Float64MultiArray, t, data_pub_qos())
               for t in ("/plant/u", "/plant/y", "/fd/state_estimate", "/fd/alarm")}
        # the nodes' executor (run_node): callbacks in arrival order, which pairs plain u, y
        ex = EventsExecutor(context=ctx)
        for n in [*nodes, col.node, drv]:
            ex.add_node(n)
        assert spin_until(ex, lambda: pub["/plant/y"].get_subscription_count() >= 2, 10.0)
        for k in range(K):
            if k == 5:
                pub["/plant/y"].publish(plain_msg([y[k, 0], math.nan, y[k, 2]]))  # NaN
                pub["/plant/y"].publish(plain_msg(y[k, :2]))                      # wrong length
                pub["/plant/u"].publish(plain_msg([math.inf, 0.0, 0.0]))          # Inf
            if k == 8:
                # Stamped, but one value short: refused by detector, agei, bias_estimator.
                pub["/fd/state_estimate"].publish(to_msg(
                    ("mode", "h1", "h2", "h3", "y~h1", "y~h2"), 9, [0.0] * 6))
                pub["/fd/alarm"].publish(plain_msg([0.0, 0.0, 0.0]))  # no stamp: required here
            pub["/plant/u"].publish(plain_msg(u[k]))
            pub["/plant/y"].publish(plain_msg(y[k]))
        assert spin_until(ex, lambda: len(col.msgs["/fd/bias_estimate"]) >= K, 30.0), \
            {t: len(v) for t, v in col.msgs.items()}

        est = [d for d in col.decoded("/fd/state_estimate") if d.values.size == 9]
        np.testing.assert_array_equal([d.values[1:4] for d in est],
                                      [o.observer.x_hat for o in want])
        res = col.decoded("/fd/residual")
        assert [d.stamp for d in res] == list(range(K))
        np.testing.assert_array_equal([d.values[:3] for d in res],
                                      [o.detector.residual for o in want])
        alarms = [d for d in col.decoded("/fd/alarm") if d.stamp is not None]  # not ours
        np.testing.assert_array_equal([d.values > 0.5 for d in alarms],
                                      [o.alarm for o in want])
        np.testing.assert_array_equal([d.values[:3] for d in col.decoded("/fd/bias_estimate")],
                                      [o.sigma_hat for o in want])
        assert any(o.alarm.any() for o in want)

        def reported(node, text, level=WARN):
            return any(s.level == level and text in status_text(s)
                       for s in col.statuses(f"{node}: input"))

        checks = [("observer", "/plant/y: value h2 is nan"),
                  ("observer", "/plant/y: wrong length: 2 values, expected 3"),
                  ("observer", "/plant/u: value q1 is inf"),
                  ("bias_estimator", "/plant/u: value q1 is inf"),
                  ("detector", "/fd/state_estimate stamp 9: wrong length: 6 values"),
                  ("agei", "/fd/state_estimate stamp 9: wrong length"),
                  ("bias_estimator", "/fd/alarm: missing stamp")]
        ok = spin_until(ex, lambda: all(reported(*c) for c in checks), 10.0)
        if not ok:
            print("\n".join(f"{s.name} {s.level} {s.message}" for s in col.statuses("input")))
        assert ok, [c for c in checks if not reported(*c)]
        assert True, \
            [c for c in checks if not reported(*c)]
        # The detector reports per output channel: ERROR on alarm (h1), then STALE once the
        # input stops for stale_timeout.
        assert spin_until(ex, lambda: any(s.level == ERROR and "residual h1" in s.name
                                          for s in col.statuses("detector")), 10.0)
        st = [s for s in col.statuses("detector: residual h1")][-1]
        keys = {kv.key for kv in st.values}
        assert {"residual", "threshold", "margin", "mode", "sigma_hat", "gain_file",
                "certificate"} <= keys
        assert spin_until(ex, lambda: any(s.level == STALE
                                          for s in col.statuses("detector: residual h2")),
                          10.0)
        ex.shutdown()
        for n in [*nodes, col.node, drv]:
            n.destroy_node()


@pytest.mark.parametrize("node, ros_args, match", [
    ("detector", ["-p", "gains:=pwa_cascade_qb"], "designed for another plant"),
    ("observer", ["-p", "gains:=/nonexistent/g.yaml"], "file not found"),
    ("agei", ["-p", "stale_timeout:=1"], "parameter stale_timeout"),
    ("agei", ["-p", "system:=pwa_cascade", "-p", "gains:=pwa_cascade_qb"],
     "method 'qb': agei runs thresholds gain files only"),
    ("bias_estimator", ["-p", "system:=pwa_cascade", "-p", "gains:=pwa_cascade_qb"],
     "method 'qb': bias_estimator runs thresholds gain files only"),
])
def test_bad_start_is_one_line_and_nonzero(node, ros_args, match):
    with Proc(["run", node, "--ros-args", *ros_args]) as proc:
        assert proc.wait(60) == 2
        errors = [ln for ln in proc.output().splitlines() if "error" in ln.lower()]
        assert len(errors) == 1 and match in errors[0], proc.output()
        assert "Traceback" not in proc.output()
