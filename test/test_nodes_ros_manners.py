"""Issue 21 over real DDS: derived node names, one reset for the chain, lifecycle managers,
/diagnostics as diagnostic_aggregator reads it, WARNs that clear, the fault verdict.

In-process nodes share one executor with a driver and a collector; one test starts two
renamed ``detector`` processes (what launch_ros' ``Node(name=...)`` starts).
"""

from __future__ import annotations

import signal

import numpy as np
import pytest
from ros_util import Collector, Proc, ros_context, spin_until

pytestmark = pytest.mark.ros

U_LABELS, Y_LABELS = ("q1", "q2", "v13"), ("h1", "h2", "h3")


def bias_data(n: int, size: float, at: int = 40):
    """u, y of three_tank_bias_h1 (seed 2), n samples, ``size`` m added to y_h1 from ``at``."""
    from fd_monitor.core.simulator import simulate
    from fd_monitor.model.scenario import load_scenario

    traj = simulate(load_scenario("three_tank_bias_h1"), 2, n)
    u, y = traj.u[0], traj.y[0]
    y[at:] += [size, 0.0, 0.0]
    return u, y


def params(**kw):
    from rclpy.parameter import Parameter

    return [Parameter(k, value=v) for k, v in kw.items()]


class Bench:
    """Nodes, a driver per namespace and a collector on one executor."""

    def __init__(self, ctx, nodes, topics=(), namespaces=("",), driver_qos=None):
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from std_msgs.msg import Float64MultiArray

        from fd_monitor.nodes.qos import data_pub_qos

        self.nodes = list(nodes)
        self.col = Collector(ctx, list(topics), diagnostics=True, name="manners_collector")
        self.drv = Node("manners_driver", context=ctx)
        qos = driver_qos if driver_qos is not None else data_pub_qos()
        self.pub = {(ns, t): self.drv.create_publisher(Float64MultiArray, f"{ns}/plant/{t}",
                                                       qos)
                    for ns in namespaces for t in ("u", "y")}
        self.ex = SingleThreadedExecutor(context=ctx)
        for n in [*self.nodes, self.col.node, self.drv]:
            self.ex.add_node(n)

    def matched(self, n=1, timeout=10.0):
        return self.spin(lambda: all(p.get_subscription_count() >= n
                                     for p in self.pub.values()), timeout)

    def send(self, u, y, ks, ns=""):
        from fd_monitor.wire.conversions import to_msg

        for k in ks:
            self.pub[(ns, "u")].publish(to_msg(U_LABELS, k, u[k], batch=True))
            self.pub[(ns, "y")].publish(to_msg(Y_LABELS, k, y[k], batch=True))

    def spin(self, cond, timeout=20.0):
        return spin_until(self.ex, cond, timeout)

    def call(self, srv_type, name, request, timeout=10.0):
        cli = self.drv.create_client(srv_type, name)
        assert cli.wait_for_service(timeout), name
        fut = cli.call_async(request)
        assert self.spin(fut.done, timeout), name
        self.drv.destroy_client(cli)
        return fut.result()

    def latest(self, prefix):
        """The latest status of every channel of the node ``prefix`` (``/ns/node: ``)."""
        out = {}
        for s in self.col.statuses(prefix):
            out[s.name] = s
        return out

    def close(self):
        self.ex.shutdown()
        for n in [*self.nodes, self.col.node, self.drv]:
            n.destroy_node()


def aggregate(statuses) -> int:
    """The level diagnostic_aggregator gives a group of statuses (GenericAnalyzerBase::report,
    ros/diagnostics, branch ros2-jazzy, no timeout): the highest level; STALE if every status
    is STALE; ERROR if some are STALE and some are not."""
    levels = [int.from_bytes(s.level, "little") for s in statuses]
    stale = 3
    if all(lv == stale for lv in levels):
        return stale
    top = max(levels)
    return 2 if top == stale else top


def test_aggregator_reads_an_idle_an_active_an_alarmed_and_a_stopped_monitor():
    """Two fused monitors (namespaces /a and /b): idle OK 'waiting for input'; active OK;
    /b alarmed ERROR; /a stopped after healthy input: STALE as a whole (not ERROR).
    hardware_id: <namespace>/<plant>, or the parameter."""
    from fd_monitor.nodes.diagnostics import OK, STALE
    from fd_monitor.nodes.monitor import MonitorNode

    OKi, ERRi, STALEi = 0, 2, 3
    u, y = bias_data(60, 0.05)
    with ros_context() as ctx:
        common = dict(stale_timeout=0.3, diagnostics_period=0.1)
        a = MonitorNode(context=ctx, namespace="/a", parameter_overrides=params(**common))
        b = MonitorNode(context=ctx, namespace="/b",
                        parameter_overrides=params(hardware_id="tank_b", **common))
        bench = Bench(ctx, [a, b], namespaces=("/a", "/b"))
        names = {f"/a/monitor: {c}" for c in ("input", "ros graph", "estimate", "residual h1",
                                              "residual h2", "residual h3", "tracker",
                                              "bias estimate", "fault")}

        def group(ns):
            return list(bench.latest(f"/{ns}/monitor: ").values())

        # idle: every status OK "waiting for input" (or the graph's OK)
        assert bench.spin(lambda: {s.name for s in group("a")} >= names and
                          {s.name for s in group("b")}), [s.name for s in group("a")]
        idle = group("a")
        assert aggregate(idle) == OKi and all(s.level == OK for s in idle)
        assert {s.message for s in idle if "graph" not in s.name} <= {
            "waiting for input", "active: waiting for /a/plant/u, /a/plant/y"}
        assert {s.hardware_id for s in idle} == {"a/three_tank"}
        assert {s.hardware_id for s in group("b")} == {"tank_b"}
        # active, healthy (before the bias) on /a; alarmed on /b
        assert bench.matched()
        bench.send(u, y, range(35), "/a")
        bench.send(u, y, range(60), "/b")
        assert bench.spin(lambda: a.processed >= 35 and b.processed >= 60)
        assert bench.spin(lambda: aggregate(group("a")) == OKi and any(
            s.message == "receiving" for s in group("a")))
        assert bench.spin(lambda: aggregate(group("b")) == ERRi)
        # /a stopped: every status STALE, the group STALE (not the ERROR of a mixed group)
        assert bench.spin(lambda: aggregate(group("a")) == STALEi, 5.0), \
            [(s.name, s.level, s.message) for s in group("a")]
        assert all(s.level == STALE for s in group("a"))
        # /b stopped after it found a fault: the fault is kept (marked stale) beside STALE
        # statuses, which the aggregator reads as ERROR
        def b_stopped():
            st = {s.name: s for s in group("b")}
            return st["/b/monitor: input"].level == STALE and any(
                kv.key == "stale" for kv in st["/b/monitor: fault"].values)
        assert bench.spin(b_stopped, 5.0)
        assert aggregate(group("b")) == ERRi
        bench.close()


def test_detector_reset_resets_the_whole_chain_and_the_verdict():
    """/detector/reset (not the observer's) starts a new run of the whole chain: the bias
    estimator leaves its latched state and the fault verdict clears; fd/fault is latched
    (a subscriber that comes later gets the verdict in force)."""
    from rclpy.node import Node
    from std_msgs.msg import Float64MultiArray
    from std_srvs.srv import Trigger

    from fd_monitor.nodes.diagnostics import ERROR, OK
    from fd_monitor.nodes.fault import fault_qos
    from fd_monitor.nodes.monitor import make_chain
    from fd_monitor.wire.conversions import decode

    u, y = bias_data(80, 0.05)
    with ros_context() as ctx:
        # no hole or new run declared on a loaded machine: only the reset restarts the run
        nodes = make_chain(context=ctx, parameter_overrides=params(gap_timeout=30.0,
                                                                   restart_after=30.0))
        obs = next(n for n in nodes if n.get_name() == "observer")
        bench = Bench(ctx, nodes, topics=["/fd/bias_estimate", "/fd/fault"])
        assert bench.matched(2)
        bench.send(u, y, range(60))
        assert bench.spin(lambda: len(bench.col.msgs["/fd/bias_estimate"]) >= 60)
        before = {m.stamp: m for m in bench.col.decoded("/fd/bias_estimate")}
        i_active = list(before[60].labels).index("active")
        assert before[60].values[i_active] == 1.0                       # estimating
        assert obs.join.restarts == 0 and obs.join.new_runs == 0
        assert bench.spin(lambda: any(d.values[0] > 0.5
                                      for d in bench.col.decoded("/fd/fault")))
        assert bench.spin(lambda: any(s.level == ERROR and s.message.startswith("fault on h1")
                                      for s in bench.col.statuses("/bias_estimator: fault")))
        # a late subscriber gets the verdict in force (transient local)
        late_msgs: list = []
        late = Node("late_subscriber", context=ctx)
        late.create_subscription(Float64MultiArray, "/fd/fault", late_msgs.append, fault_qos())
        bench.ex.add_node(late)
        assert bench.spin(lambda: bool(late_msgs), 10.0)
        d = decode(late_msgs[-1], "/fd/fault")
        assert d.values[0] == 1.0 and d.labels[0] == "fault:h1"
        res = bench.call(Trigger, "/detector/reset", Trigger.Request())
        assert res.success and "entry" in res.message
        assert bench.spin(lambda: obs.join.k_next is None, 5.0)
        bench.send(u, y, range(60, 70))                  # continues the stamps: a new run
        assert bench.spin(lambda: len(bench.col.msgs["/fd/bias_estimate"]) >= 70)
        after = [m for m in bench.col.decoded("/fd/bias_estimate") if m.stamp > 60]
        assert all(m.values[i_active] == 0.0 for m in after)          # not latched any more
        assert bench.spin(lambda: decode(bench.col.msgs["/fd/fault"][-1],
                                         "/fd/fault").values[0] == 0.0)
        assert bench.spin(lambda: bench.col.statuses("/bias_estimator: fault")[-1].level == OK)
        bench.ex.remove_node(late)
        late.destroy_node()
        bench.close()


def test_lifecycle_manager_takes_over_inactive_status_and_warns_that_clear():
    """A lifecycle manager's configure + activate on an autostarted node succeed (hand-over);
    deactivated, every status reads 'inactive' and never STALE; a refused gains set is a
    WARN that a valid set clears; a best-effort publisher's switch is handled (OK); a long
    message goes out short with the full text in 'detail'."""
    from lifecycle_msgs.msg import State, Transition
    from lifecycle_msgs.srv import ChangeState, GetState
    from rclpy.parameter import Parameter
    from rclpy.qos import qos_profile_sensor_data

    from fd_monitor.nodes.diagnostics import MAX_MESSAGE, OK, STALE, WARN
    from fd_monitor.nodes.monitor import MonitorNode

    with ros_context() as ctx:
        mon = MonitorNode(context=ctx, parameter_overrides=params(stale_timeout=0.2,
                                                                  diagnostics_period=0.1))
        bench = Bench(ctx, [mon], driver_qos=qos_profile_sensor_data)
        # best-effort driver: WARN on the incompatibility, then OK once switched
        graph = "/monitor: ros graph"
        assert bench.spin(lambda: any(s.level == WARN and "RELIABILITY" in s.message
                                      for s in bench.col.statuses(graph)))
        assert bench.spin(lambda: bench.col.statuses(graph)[-1].level == OK and any(
            kv.key == "best_effort_inputs" for kv in bench.col.statuses(graph)[-1].values))
        # a refused gain file: WARN (message short, the full reason in detail), cleared by a
        # valid one
        bad = mon.set_parameters([Parameter("gains", value="pwa_cascade_qb")])[0]
        assert not bad.successful and len(bad.reason) > MAX_MESSAGE
        assert bench.spin(lambda: bench.col.statuses(graph)[-1].level == WARN)
        st = bench.col.statuses(graph)[-1]
        detail = {kv.key: kv.value for kv in st.values}
        assert len(st.message) <= MAX_MESSAGE and detail["detail"] == bad.reason
        good = mon.set_parameters([Parameter("gains", value="three_tank_thresholds")])[0]
        assert good.successful
        assert bench.spin(lambda: bench.col.statuses(graph)[-1].level == OK)
        # nav2's lifecycle_manager: configure, check inactive; activate, check active
        for tid, want in ((Transition.TRANSITION_CONFIGURE, State.PRIMARY_STATE_INACTIVE),
                          (Transition.TRANSITION_ACTIVATE, State.PRIMARY_STATE_ACTIVE),
                          (Transition.TRANSITION_DEACTIVATE, State.PRIMARY_STATE_INACTIVE)):
            req = ChangeState.Request()
            req.transition.id = tid
            assert bench.call(ChangeState, "/monitor/change_state", req).success, tid
            got = bench.call(GetState, "/monitor/get_state", GetState.Request())
            assert got.current_state.id == want
        # inactive: every status says so, and stays OK past the stale timeout
        n0 = len(bench.col.diagnostics)
        assert bench.spin(lambda: len(bench.col.diagnostics) >= n0 + 8, 10.0)
        recent = [s for arr in bench.col.diagnostics[n0 + 2:] for s in arr.status
                  if s.name.startswith("/monitor: ")]
        assert recent and all(s.level == OK and "inactive" in s.message for s in recent)
        assert not any(s.level == STALE for s in recent)
        bench.close()


def test_renamed_chains_coexist_and_log_their_shutdown(tmp_path):
    """Two ``monitor -p layout:=nodes`` processes (the chain's four nodes) renamed as
    launch_ros does (-r __node:=det1 / det2): eight distinct nodes in one domain, no rcl
    'Publisher already registered'; SIGINT: each node logs its shutdown transition. A
    lifecycle manager takes the autostarted det1_detector over."""
    from lifecycle_msgs.msg import State, Transition
    from lifecycle_msgs.srv import ChangeState, GetState
    from rclpy.node import Node

    with ros_context() as ctx, \
            Proc(["run", "monitor", "--ros-args", "-r", "__node:=det1",
                  "-p", "layout:=nodes"]) as p1, \
            Proc(["run", "monitor", "--ros-args", "-r", "__node:=det2",
                  "-p", "layout:=nodes", "-p", "autostart:=false"]) as p2:
        probe = Node("names_probe", context=ctx)
        want = {f"{d}{s}" for d in ("det1", "det2")
                for s in ("_detector", "_observer", "_agei", "_bias_estimator")}

        def names():
            return {n for n, _ in probe.get_node_names_and_namespaces()}
        from rclpy.executors import SingleThreadedExecutor

        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(probe)
        assert spin_until(ex, lambda: want <= names(), 60.0, [p1, p2]), \
            (names(), p1.output()[-2000:], p2.output()[-2000:])
        listed = [n for n, _ in probe.get_node_names_and_namespaces() if n in want]
        assert sorted(listed) == sorted(want)                   # each name once
        assert spin_until(ex, lambda: "[det1_observer]: active: waiting for" in p1.output(),
                          30.0, [p1])
        # a lifecycle manager takes det1 over (rclpy's EventsExecutor in that process)
        for tid, want in ((Transition.TRANSITION_CONFIGURE, State.PRIMARY_STATE_INACTIVE),
                          (Transition.TRANSITION_ACTIVATE, State.PRIMARY_STATE_ACTIVE)):
            req = ChangeState.Request()
            req.transition.id = tid
            assert call(ex, probe, ChangeState, "/det1_detector/change_state", req).success, tid
            got = call(ex, probe, GetState, "/det1_detector/get_state", GetState.Request())
            assert got.current_state.id == want
        assert "[det1_detector]: lifecycle manager: configure asked" in p1.output()
        for p in (p1, p2):
            p.signal(signal.SIGINT)
            assert p.wait(30.0) == 0, p.output()[-3000:]
        for p, d, state in ((p1, "det1", "active"), (p2, "det2", "unconfigured")):
            out = p.output()
            assert "Publisher already registered" not in out, out[-3000:]
            assert "Failed to publish log message to rosout" not in out, out[-3000:]
            for node in (f"{d}_detector", f"{d}_observer", f"{d}_bias_estimator"):
                assert f"[{node}.lifecycle]: shut down (from {state})" in out, out[-3000:]
        ex.shutdown()
        probe.destroy_node()


def call(ex, node, srv_type, name, request, timeout=15.0):
    """Call a service of another process from ``node`` spun by ``ex``."""
    cli = node.create_client(srv_type, name)
    assert cli.wait_for_service(timeout), name
    fut = cli.call_async(request)
    assert spin_until(ex, fut.done, timeout), name
    node.destroy_client(cli)
    return fut.result()


def test_monitor_chain_takes_its_names_from_the_given_name():
    from fd_monitor.nodes.monitor import make_nodes

    with ros_context() as ctx:
        nodes = make_nodes(context=ctx, node_name="m1",
                           parameter_overrides=params(layout="nodes"))
        assert [n.get_name() for n in nodes] == ["m1_observer", "m1_detector", "m1_agei",
                                                 "m1_bias_estimator"]
        fused = make_nodes(context=ctx, node_name="m2")
        assert [n.get_name() for n in fused] == ["m2"]
        for n in [*nodes, *fused]:
            n.destroy_node()


def test_fused_monitor_publishes_the_2cm_verdict_until_reset():
    """The +2 cm h1 bias through the fused monitor: fd/fault is set at the third alarm and
    is still set at the end although the alarm stopped; the 'fault' status is ERROR; the
    values published equal the core verdict's (fd_monitor.core.verdict)."""
    from std_srvs.srv import Trigger

    from fd_monitor.core.methods import load_gains
    from fd_monitor.core.monitor import Monitor
    from fd_monitor.core.thresholds import as_gains
    from fd_monitor.core.verdict import FaultVerdict, VerdictRule
    from fd_monitor.model.system import load_system
    from fd_monitor.nodes.diagnostics import ERROR
    from fd_monitor.nodes.monitor import MonitorNode

    n = 300
    u, y = bias_data(n, 0.02)
    system = load_system("three_tank")
    gains = load_gains("three_tank_thresholds", system)
    m = Monitor(system, gains)
    v = FaultVerdict(3, VerdictRule(3, 10, 50), as_gains(system, gains).isolation_threshold)
    want = []
    alarms = []
    for k in range(n):
        o = m.step(k, u[k], y[k])
        alarms.append(bool(o.alarm[0]))
        x = v.step(k, o.alarm, o.estimator.sigma_hat, o.estimator.isolated)
        if x.changed:
            want.append((k, np.concatenate([x.fault, x.isolated, x.estimate, x.since])))
    with ros_context() as ctx:
        mon = MonitorNode(context=ctx)
        bench = Bench(ctx, [mon], topics=["/fd/fault", "/fd/alarm"])
        assert bench.matched()
        bench.send(u, y, range(n))
        assert bench.spin(lambda: len(bench.col.msgs["/fd/alarm"]) >= n)
        assert bench.spin(lambda: len(bench.col.msgs["/fd/fault"]) >= len(want))
        got = [(d.stamp, d.values) for d in bench.col.decoded("/fd/fault")]
        assert [k for k, _ in got] == [k for k, _ in want]
        np.testing.assert_array_equal(np.array([g for _, g in got]),
                                      np.array([w for _, w in want]))
        assert not any(alarms[-100:]) and got[-1][1][0] == 1.0    # alarm gone, fault kept
        assert bench.spin(lambda: any(s.level == ERROR and "h1 (since sample 42" in s.message
                                      for s in bench.col.statuses("/monitor: fault")))
        # ~/reset of the monitor: the next sample starts a new run without the fault
        assert bench.call(Trigger, "/monitor/reset", Trigger.Request()).success
        bench.send(u, y, range(5))
        assert bench.spin(lambda: bench.col.decoded("/fd/fault")[-1].values[0] == 0.0)
        bench.close()
