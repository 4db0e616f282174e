"""Bags through ROS: simulate -> replay -> record, and plant_sim -> record, give equal arrays."""

from __future__ import annotations

import json
import signal

import numpy as np
import pytest
from ros_util import Proc, run_cli

from fd_monitor.commands.simulate import simulate_to_bag
from fd_monitor.wire.bag_reader import read_bag
from fd_monitor.wire.bag_scanner import bag_topics

pytestmark = pytest.mark.ros

TOPICS = ["/plant/u", "/plant/y", "/plant/truth"]
K = 400


def assert_same_arrays(a, b, topics=TOPICS):
    for t in topics:
        assert a[t].labels == b[t].labels, t
        np.testing.assert_array_equal(a[t].stamps, b[t].stamps, err_msg=t)
        np.testing.assert_array_equal(a[t].values, b[t].values, err_msg=t)


@pytest.fixture(scope="module")
def sim_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("rosbags") / "sim"
    simulate_to_bag("three_tank_bias_h1", path, seed=5, duration=K * 0.1)
    return path


def record_args(out, n=K):
    return ["record", *TOPICS, "-o", str(out), "--json",
            *[a for t in TOPICS for a in ("--until", f"{t}={n}")]]


def test_replay_then_record_gives_identical_arrays(sim_bag, tmp_path):
    with Proc(record_args(tmp_path / "rec")) as rec:
        rep = run_cli(["replay", str(sim_bag), "--rate", "0", "--wait-subscribers", "1",
                       "--json"], timeout=120)
        assert rep.returncode == 0, rep.stderr
        assert json.loads(rep.stdout)["published"] == 3 * K
        assert rec.wait(60) == 0, rec.output()
        assert json.loads(rec.output()[rec.output().index("{"):])["messages"] == \
            {t: K for t in TOPICS}
    assert_same_arrays(read_bag(sim_bag), read_bag(tmp_path / "rec"))


def test_plant_sim_recorded_equals_simulate(sim_bag, tmp_path):
    with Proc(record_args(tmp_path / "rec")) as rec:
        sim = run_cli(["run", "plant_sim", "--ros-args", "-p", "rate_factor:=0.0",
                       "-p", "seed:=5", "-p", f"duration:={K * 0.1}",
                       "-p", "min_subscribers_u:=1", "-p", "min_subscribers_y:=1",
                       "-p", "min_subscribers_truth:=1"], timeout=120)
        assert sim.returncode == 0, sim.stderr
        assert rec.wait(60) == 0, rec.output()
    assert_same_arrays(read_bag(sim_bag), read_bag(tmp_path / "rec"))


def test_record_stops_on_sigint_with_a_readable_bag(tmp_path):
    from rclpy.executors import SingleThreadedExecutor
    from ros_util import Collector, ros_context, spin_until

    with ros_context() as ctx:
        col = Collector(ctx, ["/plant/y"])
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(col.node)
        with Proc(["record", "/plant/y", "-o", str(tmp_path / "rec")]) as rec, \
                Proc(["run", "plant_sim", "--ros-args", "-p", "rate_factor:=100.0",
                      "-p", "keep_going:=true", "-p", "min_subscribers_y:=2",
                      "-p", "start_delay:=0.5"]) as sim:
            # Both the recorder and the collector are matched before sample 0 (both ways:
            # start_delay); stop the recorder with SIGINT mid-stream.
            assert spin_until(ex, lambda: len(col.msgs["/plant/y"]) >= 30, 30.0, [rec, sim])
            rec.signal(signal.SIGINT)
            assert rec.wait(20) == 0, rec.output()
        ex.shutdown()
        col.node.destroy_node()
    topics = bag_topics(tmp_path / "rec")
    y = read_bag(tmp_path / "rec", ["/plant/y"])["/plant/y"]
    assert topics["/plant/y"][1] == len(y) >= 1
    np.testing.assert_array_equal(y.stamps, np.arange(len(y)))


def test_replay_and_record_errors_are_one_line(tmp_path, sim_bag):
    for args, match in [
        (["replay", str(tmp_path / "missing")], "no such bag"),
        (["replay", str(sim_bag), "--topics", "/fd/alarm"], "no topic /fd/alarm"),
        (["replay", str(sim_bag), "--rate", "-1"],
         "argument --rate: expected a finite number >= 0"),
        (["record", "/x", "-o", str(tmp_path / "r")], "unknown type of /x"),
        (["record", "/plant/y", "-o", str(sim_bag)], "already exists"),
        (["record", "/plant/y", "-o", str(tmp_path / "r2"), "--until", "/plant/u=3"],
         "not a recorded topic"),
    ]:
        r = run_cli(args, timeout=60)
        assert r.returncode == 2, (args, r.stdout, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and match in lines[0], (args, r.stderr)


def test_record_killed_with_sigkill_loses_at_most_the_last_second(tmp_path):
    """Issue 12: `record` SIGKILLed during a steady 100 Hz /plant/y (after >= 5 s). The bag
    (no metadata.yaml, no footer) reads, holds every sample from the first on, and its last
    message arrived at most 1 s before the kill; `bag recover` turns it into a complete bag
    with the same messages."""
    import time

    from fd_monitor.wire.bag_scanner import BagDamageWarning, read_raw

    rate = 100.0          # plant_sim at rate_factor 10: 10 x 10 Hz
    bag = tmp_path / "rec"
    with Proc(["record", "/plant/y", "-o", str(bag)]) as rec, \
            Proc(["run", "plant_sim", "--ros-args", "-p", "rate_factor:=10.0",
                  "-p", "keep_going:=true", "-p", "min_subscribers_y:=1"]) as sim:
        # Bounded wait on the bag itself (read while being written): 5 s of samples.
        deadline = time.monotonic() + 60.0
        n = 0
        while n < 5 * rate and time.monotonic() < deadline:
            assert rec.p.poll() is None and sim.p.poll() is None, rec.output() + sim.output()
            time.sleep(0.2)
            if bag.is_dir() and any(bag.glob("*.mcap")):
                n = sum(1 for _ in read_raw(bag, damage=[]))
        assert n >= 5 * rate, rec.output()
        killed_ns = time.time_ns()
        rec.signal(signal.SIGKILL)
        assert rec.wait(20) == -signal.SIGKILL
    assert not (bag / "metadata.yaml").exists()
    damage: list = []
    got = [t for _, _, t, _ in read_raw(bag, damage=damage)]
    assert [str(d) for d in damage if "did not close" not in str(d)] == []
    with pytest.warns(BagDamageWarning, match="did not close"):
        y = read_bag(bag, ["/plant/y"])["/plant/y"]
    assert len(got) == len(y) >= 5 * rate
    np.testing.assert_array_equal(y.stamps, np.arange(len(y)))   # nothing lost before
    gap = (killed_ns - int(y.receive_ns[-1])) * 1e-9
    steady = (int(y.receive_ns[-1]) - int(y.receive_ns[0])) * 1e-9 / (len(y) - 1)
    assert steady < 1.5 / rate, f"publication not steady: {steady * 1e3:.1f} ms per sample"
    assert gap <= 1.0, f"the last {gap:.2f} s before the kill are missing"
    out = run_cli(["bag", "recover", str(bag), "--json"])
    assert out.returncode == 0, out.stderr
    fixed = read_bag(tmp_path / "rec_recovered", ["/plant/y"])["/plant/y"]
    np.testing.assert_array_equal(fixed.values, y.values)
    assert (tmp_path / "rec_recovered" / "metadata.yaml").is_file()
    print(f"SIGKILL after {len(y)} samples in the bag; last one {gap:.2f} s before the kill")


def test_record_meets_a_best_effort_driver(tmp_path):
    """A driver publishing best effort (sensor-data QoS): `record` switches that topic's
    subscription to best effort (one log line) and records its messages in order."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data
    from ros_util import ros_context, spin_until
    from std_msgs.msg import Float64MultiArray

    from fd_monitor.nodes.bag_nodes import RecorderNode
    from fd_monitor.wire.bag_writer import BagWriter
    from fd_monitor.wire.conversions import to_msg

    out = tmp_path / "be"
    with ros_context() as ctx, BagWriter(out) as writer:
        rec = RecorderNode(writer, {"/plant/y": "std_msgs/msg/Float64MultiArray"},
                           context=ctx)
        drv = Node("best_effort_driver", context=ctx)
        pub = drv.create_publisher(Float64MultiArray, "/plant/y", qos_profile_sensor_data)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(rec)
        ex.add_node(drv)
        assert spin_until(ex, lambda: not rec.inputs["/plant/y"].reliable, 15.0)
        assert spin_until(ex, lambda: pub.get_subscription_count() >= 1, 15.0)
        k = 0
        while writer.counts.get("/plant/y", 0) < 20 and k < 2000:   # best effort: keep sending
            pub.publish(to_msg(("h1", "h2", "h3"), k, [0.1, 0.2, 0.3]))
            ex.spin_once(timeout_sec=0.01)
            k += 1
        assert writer.counts.get("/plant/y", 0) >= 20, k
        ex.shutdown()
        rec.destroy_node()
        drv.destroy_node()
    got = read_bag(out, ["/plant/y"])["/plant/y"]
    assert len(got) >= 20 and list(got.stamps) == sorted(got.stamps)
