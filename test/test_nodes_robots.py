"""Several robots' monitors in one process (``monitor`` with ``robots``), over real DDS.

One ``monitor`` process hosts robot1, robot2 and robot3 (``robots`` and one robot's own
section in a parameter file, as rcl reads it). Each robot gets its own input: a bias on h1
(robot1), on h2 (robot2, with a NaN and a wrong-length message mixed in), and robot1's data
on another gain file (robot3, its parameter section). Each robot's outputs must equal the
in-process ``Monitor`` on its own input and gain file, value for value on every topic; the
bad messages are reported on robot2's ``/diagnostics`` only; a lifecycle transition and a
reset of one robot leave the others running; SIGINT stops them all cleanly.
"""

from __future__ import annotations

import math
import signal
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from ros_util import FD_TOPICS, Collector, Proc, plain_msg, ros_context, spin_until, status_text

pytestmark = pytest.mark.ros

K = 60
ROBOTS = ("robot1", "robot2", "robot3")
#: robot3's own parameter section: another gain file and hardware_id
ROBOT3_GAINS, ROBOT3_HW = "three_tank_envelope", "arm3"
PARAMS = f"""\
/**:
  ros__parameters:
    robots: [{", ".join(ROBOTS)}]
    diagnostics_period: 0.2
    log_throttle: 0.0
/robot3/monitor:
  ros__parameters:
    gains: {ROBOT3_GAINS}
    hardware_id: {ROBOT3_HW}
"""


@dataclass
class Fleet:
    proc: Proc
    col: Collector
    ex: Any
    drv: Any
    pub: dict
    data: dict          # robot -> (u, y, Monitor outputs)

    def send(self, robot: str, ks: range) -> None:
        from fd_monitor.wire.conversions import to_msg

        u, y, _ = self.data[robot]
        for k in ks:
            self.pub[robot, "u"].publish(to_msg(("q1", "q2", "v13"), k, u[k % K]))
            self.pub[robot, "y"].publish(to_msg(("h1", "h2", "h3"), k, y[k % K]))

    def got(self, robot: str, topic: str) -> list:
        from fd_monitor.wire.conversions import decode

        t = f"/{robot}{topic}"
        return [decode(m, t, allow_nan=True) for m in self.col.msgs[t]]

    def call(self, srv_type: Any, name: str, request: Any) -> Any:
        cli = self.drv.create_client(srv_type, name)
        assert cli.wait_for_service(10.0), name
        fut = cli.call_async(request)
        assert spin_until(self.ex, fut.done, 10.0), name
        self.drv.destroy_client(cli)
        return fut.result()


def robot_data() -> dict:
    """robot -> (u, y, the in-process Monitor's outputs on its gain file)."""
    from fd_monitor.core.methods import load_gains
    from fd_monitor.core.monitor import Monitor
    from fd_monitor.core.simulator import simulate
    from fd_monitor.model.scenario import load_scenario
    from fd_monitor.model.system import load_system

    system = load_system("three_tank")
    traj = simulate(load_scenario("three_tank_bias_h1"), 2, K)
    u = traj.u[0]
    y1, y2 = traj.y[0].copy(), traj.y[0].copy()
    y1[40:] += [0.05, 0.0, 0.0]
    y2[40:] += [0.0, 0.05, 0.0]
    out = {}
    for robot, y, gains in (("robot1", y1, "three_tank_thresholds"),
                            ("robot2", y2, "three_tank_thresholds"),
                            ("robot3", y1, ROBOT3_GAINS)):
        m = Monitor(system, load_gains(gains, system))
        out[robot] = (u, y, [m.step(k, u[k], y[k]) for k in range(K)])
    return out


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """The three robots' process, driven with K samples each (robot2's bad messages at
    sample 5), every output received."""
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from std_msgs.msg import Float64MultiArray

    from fd_monitor.nodes.qos import data_pub_qos

    params = tmp_path_factory.mktemp("robots") / "robots.yaml"
    params.write_text(PARAMS)
    data = robot_data()
    with Proc(["run", "monitor", "--ros-args", "--params-file", str(params)]) as proc, \
            ros_context() as ctx:
        topics = [f"/{r}{t}" for r in ROBOTS for t in FD_TOPICS]
        col = Collector(ctx, topics, diagnostics=True, name="robots_collector")
        drv = Node("robots_driver", context=ctx)
        pub = {(r, t): drv.create_publisher(Float64MultiArray, f"/{r}/plant/{t}",
                                            data_pub_qos())
               for r in ROBOTS for t in ("u", "y")}
        ex = EventsExecutor(context=ctx)
        for n in (col.node, drv):
            ex.add_node(n)
        f = Fleet(proc, col, ex, drv, pub, data)
        assert spin_until(ex, lambda: all(p.get_subscription_count() >= 1
                                          for p in pub.values())
                          and all(col.node.count_publishers(t) >= 1 for t in topics),
                          60.0, [proc]), proc.output()[-3000:]
        for r in ROBOTS:
            if r == "robot2":
                f.send(r, range(5))
                y = data[r][1]
                pub[r, "y"].publish(plain_msg([y[5, 0], math.nan, y[5, 2]]))
                pub[r, "y"].publish(plain_msg(y[5, :2]))
                f.send(r, range(5, K))
            else:
                f.send(r, range(K))
        assert spin_until(ex, lambda: all(len(col.msgs[f"/{r}/fd/bias_estimate"]) >= K
                                          for r in ROBOTS), 30.0, [proc]), \
            {t: len(v) for t, v in col.msgs.items()}
        yield f
        ex.shutdown()
        for n in (col.node, drv):
            n.destroy_node()


def test_each_robot_outputs_equal_its_own_monitor(fleet):
    """Every topic of every robot equals the in-process Monitor on that robot's input and
    gain file (robot3: its own parameter section's), stamp for stamp and value for value;
    the three expectations differ, so a crossed stream or a shared parameter would fail."""
    from ros_util import expected_payloads

    exp = {r: expected_payloads(fleet.data[r][2]) for r in ROBOTS}
    # (AGEI never triggers here: thresholds, guard events and overrides are the gain
    # file's, the same for robot1 and robot2)
    for t in ("/fd/state_estimate", "/fd/residual", "/fd/alarm", "/fd/bias_estimate"):
        assert not np.array_equal(exp["robot1"][t], exp["robot2"][t]), t
    assert not np.array_equal(exp["robot1"]["/fd/threshold"], exp["robot3"]["/fd/threshold"])
    for r in ROBOTS:
        for t in FD_TOPICS:
            got = fleet.got(r, t)
            first = 1 if t in FD_TOPICS[4:] else 0      # feedback: stamped k + 1
            assert [d.stamp for d in got] == list(range(first, K + first)), (r, t)
            np.testing.assert_array_equal([d.values for d in got], exp[r][t],
                                          err_msg=f"{r} {t}")


def test_bad_input_is_reported_on_its_robot_only(fleet):
    """robot2's NaN and wrong-length messages: WARN on /robot2/monitor's input status (one
    line each, saying what and where); robot1's and robot3's statuses never mention them.
    Each
    robot's statuses carry its own hardware_id (robot3: from its parameter section)."""
    from fd_monitor.nodes.diagnostics import OK, WARN

    col = fleet.col
    checks = ["/robot2/plant/y: value h2 is nan",
              "/robot2/plant/y: wrong length: 2 values, expected 3"]

    def reported(text):
        return any(s.level == WARN and text in status_text(s)
                   for s in col.statuses("/robot2/monitor: input"))
    assert spin_until(fleet.ex, lambda: all(reported(c) for c in checks), 10.0), \
        [status_text(s) for s in col.statuses("/robot2/monitor: input")]
    for r in ("robot1", "robot3"):
        # (their levels are not asserted: a loaded machine may make a robot's input late, and
        # its input turns STALE stale_timeout after the data: statuses of their own)
        assert any(s.level == OK for s in col.statuses(f"/{r}/monitor: input"))
        texts = [status_text(s) for s in col.statuses(f"/{r}/")]
        assert not any("/robot2/" in t or " is nan" in t or "wrong length" in t
                       for t in texts), texts
    hw = {r: {s.hardware_id for s in col.statuses(f"/{r}/monitor: ")} for r in ROBOTS}
    assert hw == {"robot1": {"robot1/three_tank"}, "robot2": {"robot2/three_tank"},
                  "robot3": {ROBOT3_HW}}


def test_one_robots_lifecycle_and_reset_leave_the_others_running(fleet):
    """robot3 deactivated and robot1 reset through their own services: robot1's next sample
    starts a new run (restart flag), robot2 goes on undisturbed, robot3 drops its input and
    reads ``inactive``."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    from std_srvs.srv import Trigger

    req = ChangeState.Request()
    req.transition.id = Transition.TRANSITION_DEACTIVATE
    assert fleet.call(ChangeState, "/robot3/monitor/change_state", req).success
    assert fleet.call(Trigger, "/robot1/monitor/reset", Trigger.Request()).success
    for r in ROBOTS:
        fleet.send(r, range(K, K + 5))
    col = fleet.col
    assert spin_until(fleet.ex, lambda: all(len(col.msgs[f"/{r}/fd/state_estimate"]) >= K + 5
                                            for r in ("robot1", "robot2")), 20.0)

    def restarts(robot):
        return [d.stamp for d in fleet.got(robot, "/fd/state_estimate")
                if d.values[d.labels.index("restart")] > 0.5]
    assert restarts("robot1") == [0, K] and restarts("robot2") == [0]
    assert [d.stamp for d in fleet.got("robot2", "/fd/state_estimate")] == list(range(K + 5))
    assert len(col.msgs["/robot3/fd/state_estimate"]) == K
    assert spin_until(fleet.ex, lambda: any(
        "inactive" in s.message for s in col.statuses("/robot3/monitor: input")), 10.0)
    assert not any("inactive" in s.message for r in ("robot1", "robot2")
                   for s in col.statuses(f"/{r}/monitor: "))


def test_sigint_stops_every_robot_cleanly(fleet):
    """SIGINT: exit status 0, each robot's shutdown transition logged once, no traceback."""
    fleet.proc.signal(signal.SIGINT)
    assert fleet.proc.wait(20.0) == 0
    out = fleet.proc.output()
    assert "Traceback" not in out, out[-3000:]
    for r in ROBOTS:
        assert out.count(f"[{r}.monitor.lifecycle]: shut down (from ") \
            + out.count(f"[{r}.monitor]: shut down (from ") == 1, out[-3000:]


def test_robot_namespaces_and_the_namespace_rule():
    """``robots`` as a string array or one comma/blank-separated string, under the process's
    namespace; a name that is not a relative ROS namespace, or given twice, is refused in one
    line. ``-r __ns:=/NS`` is taken out of the ROS arguments (rcl would force every node into
    it); a value rcl would refuse is left for rcl to report."""
    from fd_monitor.model.errors import FdMonitorError
    from fd_monitor.nodes.robots import robot_namespaces
    from fd_monitor.nodes.ros_args import take_namespace

    assert robot_namespaces(None, ["r1", "arm/r2"]) == ["/r1", "/arm/r2"]
    assert robot_namespaces("/fleet/", "r1, r2 r3") == ["/fleet/r1", "/fleet/r2", "/fleet/r3"]
    assert robot_namespaces("/", []) == []
    for bad, match in ((["r1", "1r"], "'1r': expected a relative ROS namespace"),
                       (["/r1"], "'/r1': expected a relative"),
                       (["r1", "r1"], "'r1' is given twice"), (3, "expected robot names")):
        with pytest.raises(FdMonitorError, match=match) as exc:
            robot_namespaces(None, bad)
        assert "\n" not in str(exc.value)
    args = ["monitor", "--ros-args", "-r", "__ns:=/a", "-p", "x:=1", "-r", "__ns:=/fleet",
            "-r", "monitor:__ns:=/x"]
    assert take_namespace(args) == (["monitor", "--ros-args", "-p", "x:=1", "-r",
                                     "monitor:__ns:=/x"], "/fleet")
    assert take_namespace(["m", "--ros-args", "-r", "__ns:=rel"]) == (
        ["m", "--ros-args", "-r", "__ns:=rel"], None)
    assert take_namespace(["m", "-r", "__ns:=/a"]) == (["m", "-r", "__ns:=/a"], None)
