"""The distributed chain (four node processes over DDS) equals the in-process Monitor.

A simulated bag is replayed flat out into observer, detector, agei and bias_estimator
(separate processes) and everything is recorded; the recorded residuals, thresholds, alarms,
state estimates and bias estimates must equal :class:`fd_monitor.core.monitor.Monitor` on the
same u, y, sample for sample, bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from ros_util import REPO, Proc, expected_payloads, replay_through

from fd_monitor.commands.simulate import simulate_to_bag
from fd_monitor.core.methods import load_gains
from fd_monitor.core.monitor import Monitor
from fd_monitor.model.system import load_system
from fd_monitor.wire.bag_reader import read_bag

pytestmark = pytest.mark.ros

K = 800  # 80 s; the bias on h1 starts at 40 s (sample 400): detection, estimation, isolation
ONSET = 400
FD_TOPICS = ["/fd/state_estimate", "/fd/residual", "/fd/threshold", "/fd/alarm",
             "/fd/guard_event", "/fd/threshold_override", "/fd/bias_estimate"]


def short_scenario(tmp_path):
    """The demo scenario, shortened to 80 s with the bias at 40 s (same plant and gains)."""
    doc = yaml.safe_load((REPO / "config/scenarios/three_tank_bias_h1.yaml").read_text())
    doc["duration"] = K * 0.1
    doc["faults"][0]["time"] = ONSET * 0.1
    path = tmp_path / "three_tank_bias_h1_short.yaml"
    path.write_text(yaml.safe_dump(doc))
    return str(path)


def offline(u, y):
    system = load_system("three_tank")
    m = Monitor(system, load_gains("three_tank_thresholds", system))
    return [m.step(k, u[k], y[k]) for k in range(len(u))]


@pytest.mark.parametrize("layout", ["four_processes", "monitor_nodes", "monitor_fused"])
def test_distributed_chain_equals_offline_monitor(tmp_path, layout):
    bag = tmp_path / "sim"
    simulate_to_bag(short_scenario(tmp_path), bag, seed=7)
    nodes = (["observer", "detector", "agei", "bias_estimator"] if layout == "four_processes"
             else ["monitor"])
    four = ["--ros-args", "-p", "layout:=nodes"] if layout == "monitor_nodes" else []
    procs = [Proc(["run", n, *four]) for n in nodes]
    until = [a for t in FD_TOPICS for a in ("--until", f"{t}={K}")]
    rec = Proc(["record", "/plant/u", "/plant/y", *FD_TOPICS, "-o", str(tmp_path / "rec"),
                *until])
    # /plant/u and /plant/y: observer, bias_estimator (fused: the monitor) and the recorder.
    replay_through(procs, rec, bag, ["/plant/u", "/plant/y"],
                   wait_subscribers=2 if layout == "monitor_fused" else 3, timeout=120)
    got = read_bag(tmp_path / "rec")
    u, y = got["/plant/u"].values, got["/plant/y"].values
    outs = offline(u, y)
    ks = np.arange(K)
    for t in FD_TOPICS:
        first = 1 if t in ("/fd/guard_event", "/fd/threshold_override",
                           "/fd/bias_estimate") else 0  # feedback: stamped k + 1
        np.testing.assert_array_equal(got[t].stamps, ks + first, err_msg=t)
    np.testing.assert_array_equal(got["/fd/state_estimate"].values[:, 1:4],
                                  [o.observer.x_hat for o in outs])
    np.testing.assert_array_equal(got["/fd/state_estimate"].values[:, 0],
                                  [o.mode for o in outs])
    np.testing.assert_array_equal(got["/fd/residual"].values[:, :3],
                                  [o.detector.residual for o in outs])
    np.testing.assert_array_equal(got["/fd/threshold"].values[:, :3],
                                  [o.detector.threshold for o in outs])
    alarm = np.array([o.alarm for o in outs])
    np.testing.assert_array_equal(got["/fd/alarm"].values > 0.5, alarm)
    np.testing.assert_array_equal(got["/fd/bias_estimate"].values[:, :3],
                                  [o.sigma_hat for o in outs])
    # Every value of every topic: the layouts of the chain nodes, the Monitor's bits.
    for t in FD_TOPICS:
        np.testing.assert_array_equal(got[t].values, expected_payloads(outs)[t], err_msg=t)
    # The scenario's fault is seen: an alarm after the onset, h1 isolated at the end.
    assert alarm[ONSET:].any() and not alarm[:ONSET].any()
    assert got["/fd/bias_estimate"].column("iso:h1")[-1] == 1.0
