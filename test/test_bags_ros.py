"""Bags through ROS: simulate -> replay -> record, and plant_sim -> record, give equal arrays."""

from __future__ import annotations

import json
import signal

import numpy as np
import pytest
from ros_util import Proc, run_cli

from fd_monitor.bags import bag_topics, read_bag
from fd_monitor.commands.simulate import simulate_to_bag

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
                      "-p", "keep_going:=true", "-p", "min_subscribers_y:=2"]) as sim:
            # Both the recorder and the collector are matched before sample 0; stop the
            # recorder with SIGINT mid-stream.
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
        (["replay", str(sim_bag), "--rate", "-1"], "--rate -1.0: expected >= 0"),
        (["record", "/x", "-o", str(tmp_path / "r")], "unknown type of /x"),
        (["record", "/plant/y", "-o", str(sim_bag)], "already exists"),
        (["record", "/plant/y", "-o", str(tmp_path / "r2"), "--until", "/plant/u=3"],
         "not a recorded topic"),
    ]:
        r = run_cli(args, timeout=60)
        assert r.returncode == 2, (args, r.stdout, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and match in lines[0], (args, r.stderr)
