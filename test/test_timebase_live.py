"""The one time base live: a ros2_control-like robot bag that fd_monitor did not write
(JointState stamps jittered by 0.4 Ts, the effort controller answering 1-3 ms after each
measurement with a header-less Float64MultiArray, 1 message in 200 lost on each topic)
replayed at its recorded pace into `monitor -p adapter:=dc_motor` over real DDS gives the
samples and residuals of `analyze --adapter` on the same bag, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from test_timebase import CMD, GAINS, JS, PLANT, robot_bag

from fd_monitor.analysis.offline import run_bag
from fd_monitor.model.system import load_system

pytestmark = pytest.mark.ros


def test_jittered_lossy_robot_bag_live_equals_offline(tmp_path):
    from ros_util import Proc, replay_through

    from fd_monitor.wire.bag_reader import read_bag

    bag = tmp_path / "robot"
    robot_bag(bag, 1200, jitter=0.4, y_lost=1 / 200, u_lost=1 / 200, seed=5)
    offline = run_bag(bag, GAINS, system=load_system(PLANT), adapter="dc_motor")
    counts = offline.inputs.sample_counts()
    assert counts["skipped"].get("stale", 0) > 0          # the bag has gaps
    n = len(offline.k)
    assert counts["used"] == n
    mon = Proc(["run", "monitor", "--ros-args", "-p", f"system:={PLANT}", "-p",
                f"gains:={GAINS}", "-p", "adapter:=dc_motor", "-p", "log_throttle:=0.0",
                # equality with offline needs every sample: a real-time stream on a loaded
                # machine may put the node more than max_lag behind, and it would shed
                "-p", "max_lag:=0.0"])
    rec = Proc(["record", "/fd/residual", "-o", str(tmp_path / "rec"),
                "--until", f"/fd/residual={n}"])
    replay_through([mon], rec, bag, [JS, CMD], wait_subscribers=1, rate=1.0)
    res = read_bag(tmp_path / "rec", ["/fd/residual"])["/fd/residual"]
    np.testing.assert_array_equal(res.stamps, offline.k)
    np.testing.assert_array_equal(res.values[:, :offline.signal.shape[1]], offline.signal)
