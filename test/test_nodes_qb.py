"""QB runtime in the nodes: observer + detector processes equal the offline runner.

``bags/pwa_cascade_b1_step`` (the QB paper's Sec. VI plant, bias step on x3 at 25 s) is
replayed flat out into ``observer`` and ``detector`` run with the ``pwa_cascade_qb`` gain
file; the recorded alarms, signals and thresholds must equal
:func:`fd_monitor.offline.run_bag` sample for sample.
"""

from __future__ import annotations

import numpy as np
import pytest
from ros_util import REPO, Proc, replay_through

from fd_monitor.bags import read_bag
from fd_monitor.offline import run_bag

pytestmark = pytest.mark.ros

BAG = REPO / "bags/pwa_cascade_b1_step"
TOPICS = ["/fd/state_estimate", "/fd/residual", "/fd/threshold", "/fd/alarm"]
QB = ["--ros-args", "-p", "system:=pwa_cascade", "-p", "gains:=pwa_cascade_qb"]


def test_qb_observer_and_detector_equal_offline(tmp_path):
    off = run_bag(BAG, "pwa_cascade_qb")
    n = len(off.k)
    procs = [Proc(["run", x, *QB, *(["-p", "layout:=chain"] if x == "detector" else [])])
             for x in ("observer", "detector")]
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
