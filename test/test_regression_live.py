"""Regression suite through the live nodes: replay library bags into the running monitor.

The live subset of ``bags/library.yaml`` (``live: true``) is replayed flat out (lossless) into
the ``monitor`` process (the four chain nodes on one executor) and into the five-process
pipeline (observer, detector, agei, bias_estimator and replay), the outputs are recorded, and
the same ``expected.yaml`` is checked on what the nodes published: alarms, modes, bias
estimates, restarts (the ``restart`` channel of ``/fd/state_estimate``) and the input errors
the observer reported in its log. The residuals must also equal the offline runner's
(:func:`fd_monitor.analysis.offline.run_bag`) sample for sample: bad input is handled the same way.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from ros_util import Proc, replay_through

from fd_monitor.analysis.expectations import check_expected
from fd_monitor.analysis.library import load_expected, load_library
from fd_monitor.analysis.offline import run_bag, stamp_runs
from fd_monitor.analysis.summary import recorded_outputs, summarize
from fd_monitor.wire.bag_reader import read_bag

pytestmark = pytest.mark.ros

LIB = load_library()
LIVE = [b.name for b in LIB.bags if b.live]
TOPICS = ["/fd/alarm", "/fd/state_estimate", "/fd/bias_estimate", "/fd/residual"]
BAD = "three_tank_bad_input"


def logged_input_errors(log: str) -> dict[str, list]:
    """kind -> stamps, from the entry node's log lines (observer, or the fused monitor: the
    kinds of ``read_inputs``)."""
    out: dict[str, list] = {}
    rejected: set[int] = set()
    holes: list[int] = []
    for line in log.splitlines():
        if "[observer]" not in line and "[monitor]" not in line:
            continue
        if m := re.search(r"/plant/[uy] stamp (\d+): (value \S+ is (nan|inf)|wrong length)",
                          line):
            kind = "non_finite" if m.group(3) else "wrong_length"
            out.setdefault(kind, []).append(int(m.group(1)))
            rejected.add(int(m.group(1)))
        elif m := re.search(r"/plant/[uy] stamp (\d+): duplicate", line):
            out.setdefault("duplicate", []).append(int(m.group(1)))
        elif m := re.search(r"/plant/[uy] stamp (\d+) after stamp \d+: out of order", line):
            out.setdefault("out_of_order", []).append(int(m.group(1)))
        elif m := re.search(r"hole: no valid sample for stamps? (\d+)(?:\.\.(\d+))?", line):
            a = int(m.group(1))
            holes += range(a, int(m.group(2) or a) + 1)
    missing = [list(r) for r in stamp_runs(sorted(set(holes) - rejected))]
    if missing:
        out["missing"] = missing
    return {k: sorted(v) for k, v in out.items()}


CASES = [(LIVE[0], "monitor"), (BAD, "monitor"), (BAD, "five_processes")]


@pytest.mark.parametrize(("name", "layout"), CASES)
def test_live_nodes_match_expected(tmp_path, name, layout):
    from fd_monitor.model.system import load_system

    spec = LIB[name]
    assert spec.live
    assert spec.gains == "three_tank_thresholds"   # the nodes' default gain file
    system = load_system("three_tank")
    offline = run_bag(spec.folder, spec.gains, system=system)
    n = len(offline.k)                             # valid samples
    nodes = ["monitor"] if layout == "monitor" else ["observer", "detector", "agei",
                                                     "bias_estimator"]
    # Every bad-input line logged (not throttled): the log is compared with the offline
    # reader's errors; the detector runs alone beside the other processes.
    procs = [Proc(["run", x, "--ros-args", "-p", "log_throttle:=0.0"]) for x in nodes]
    until = [a for t in TOPICS for a in ("--until", f"{t}={n}")]
    rec = Proc(["record", *TOPICS, "-o", str(tmp_path / "rec"), *until])
    # /plant/u and /plant/y subscribers: the observer and the bias estimator (the fused
    # monitor: itself).
    replay_through(procs, rec, spec.folder, ["/plant/u", "/plant/y"],
                   wait_subscribers=1 if layout == "monitor" else 2)
    # what the nodes published, summarised as the offline run is
    s = summarize(recorded_outputs(read_bag(tmp_path / "rec", TOPICS), system))
    s["input_errors"] = logged_input_errors("".join(p.output() for p in procs))
    assert s["samples"] == n                       # no valid sample lost
    assert check_expected(load_expected(spec.expected_file), s) == []
    res = read_bag(tmp_path / "rec", ["/fd/residual"])["/fd/residual"]
    np.testing.assert_array_equal(res.stamps, offline.k)
    np.testing.assert_array_equal(res.values[:, :system.ny], offline.signal)


GENERIC = [b.name for b in LIB.bags if b.live and b.gains != "three_tank_thresholds"]


def test_live_subset_has_every_method():
    from fd_monitor.core.methods import load_gains

    methods = {load_gains(LIB[n].gains, verify=False).method for n in LIVE}
    assert methods >= {"thresholds", "hinf_sc", "hminus_switched"}, methods


def _monitor_outputs(tmp_path, bag, gains, system, gf, n):
    """``bag``'s /plant topics (and side signals) replayed flat out into a `monitor` process
    on ``gains``; its residual, threshold and alarm topics as recorded (``n`` samples)."""
    from fd_monitor.core.methods import runtime_for

    side = [f"/plant/{s}" for s in runtime_for(system, gf).side_inputs]
    topics = ["/fd/residual", "/fd/threshold", "/fd/alarm"]
    procs = [Proc(["run", "monitor", "--ros-args", "-p", f"system:={system.name}",
                   "-p", f"gains:={gains}"])]
    until = [a for t in topics for a in ("--until", f"{t}={n}")]
    rec = Proc(["record", *topics, "-o", str(tmp_path / "rec"), *until])
    replay_through(procs, rec, bag, [*(["/plant/u"] if system.nu else []), "/plant/y", *side],
                   wait_subscribers=1)
    return read_bag(tmp_path / "rec", topics)


@pytest.mark.parametrize("name", GENERIC)
def test_live_monitor_runs_any_gain_file_like_analyze(tmp_path, name):
    """The `monitor` process on an hinf_sc / hminus_switched gain file (the fused
    MonitorNode) publishes exactly what `analyze` computes offline: every residual, threshold
    and alarm of every channel, sample for sample; the bag's expectations hold offline
    (test_regression.py), so they hold live."""
    from fd_monitor.core.methods import load_gains
    from fd_monitor.model.system import load_system

    spec = LIB[name]
    system = load_system(load_gains(spec.gains, verify=False).system_name)
    gf = load_gains(spec.gains, system)
    offline = run_bag(spec.folder, spec.gains, system=system)
    got = _monitor_outputs(tmp_path, spec.folder, spec.gains, system, gf, len(offline.k))
    for topic, want in (("/fd/residual", offline.signal), ("/fd/threshold", offline.threshold),
                        ("/fd/alarm", offline.alarm.astype(float))):
        assert got[topic].labels == offline.channels, topic
        np.testing.assert_array_equal(got[topic].stamps, offline.k, err_msg=topic)
        np.testing.assert_array_equal(got[topic].values, want, err_msg=topic)


#: A one-sample and a 10-sample hole in three_tank_bias_h1, after h1 is isolated (1217).
HOLES = [(1300, 1300), (1600, 1609)]


@pytest.mark.parametrize("layout", ["monitor", "five_processes"])
def test_live_bridges_keep_the_isolation(tmp_path, layout):
    """A hole is not amnesia, over DDS (issue 19 item 2): three_tank_bias_h1 (+0.03 m on h1,
    isolated from sample 1217) replayed with a one-sample hole at 1300 and a 10-sample hole
    at 1600..1609 into the fused monitor and into the five-process chain. Both holes are
    bridged (no restart): h1 stays isolated through them with its estimate, nothing else is
    isolated, and every residual and bias estimate equals the offline run's."""
    from test_bridge import _holed_bag

    from fd_monitor.model.system import load_system

    spec = LIB["three_tank_bias_h1"]
    system = load_system("three_tank")
    bag = _holed_bag(spec.folder, tmp_path / "holes", HOLES)
    offline = run_bag(bag, spec.gains, system=system)
    assert offline.inputs.bridges == [1301, 1610] and offline.inputs.restarts == []
    n = len(offline.k)
    nodes = ["monitor"] if layout == "monitor" else ["observer", "detector", "agei",
                                                     "bias_estimator"]
    procs = [Proc(["run", x, "--ros-args", "-p", "log_throttle:=0.0"]) for x in nodes]
    until = [a for t in TOPICS for a in ("--until", f"{t}={n}")]
    rec = Proc(["record", *TOPICS, "-o", str(tmp_path / "rec"), *until])
    replay_through(procs, rec, bag, ["/plant/u", "/plant/y"],
                   wait_subscribers=1 if layout == "monitor" else 2)
    got = read_bag(tmp_path / "rec", TOPICS)
    st, be = got["/fd/state_estimate"], got["/fd/bias_estimate"]
    np.testing.assert_array_equal(st.stamps, offline.k)
    assert st.stamps[st.column("restart") > 0.5].tolist() == [0]
    assert st.stamps[st.column("bridge") > 0.5].tolist() == [1301, 1610]
    # bias estimates are stamped k + 1 (the sample they are used at)
    np.testing.assert_array_equal(be.stamps, offline.k + 1)
    np.testing.assert_array_equal(be.column("h1"), offline.estimate["h1"])
    iso = be.column("iso:h1") > 0.5
    after = be.stamps > 1217
    assert iso[after].all() and np.all(be.column("h1")[after] > 0.02)
    assert not (be.column("iso:h2") > 0.5).any() and not (be.column("iso:h3") > 0.5).any()
    res = got["/fd/residual"]
    np.testing.assert_array_equal(res.values[:, :system.ny], offline.signal)
    log = "".join(p.output() for p in procs)
    assert "bridged at 1301" in log and "bridged at 1610" in log
    assert "isolated nothing" not in log


@pytest.mark.parametrize("name", ["thesis_6_5_overlap", "farhat_koenig_fault"])
def test_live_monitor_bridges_registry_runtimes_like_analyze(tmp_path, name):
    """The fused monitor on an hinf_sc bank with measured rho (/plant/rho) and on the
    switched generalized observer (/plant/mode), replayed with a one-sample and a 10-sample
    hole on every /plant topic: both bridged, and every residual, threshold (armed again
    settle_s after the 10-sample hole where the gain file has a settling time: Farhat &
    Koenig) and alarm equals analyze's, sample for sample."""
    from test_bridge import _holed_bag

    from fd_monitor.core.methods import load_gains
    from fd_monitor.model.system import load_system

    spec = LIB[name]
    system = load_system(load_gains(spec.gains, verify=False).system_name)
    gf = load_gains(spec.gains, system)
    k_end = int(read_bag(spec.folder, ["/plant/y"])["/plant/y"].stamps[-1])
    holes = [(k_end // 2, k_end // 2), (3 * k_end // 4, 3 * k_end // 4 + 9)]
    bag = _holed_bag(spec.folder, tmp_path / "holes", holes)
    offline = run_bag(bag, spec.gains, system=system)
    assert offline.inputs.bridges == [b + 1 for _a, b in holes]
    got = _monitor_outputs(tmp_path, bag, spec.gains, system, gf, len(offline.k))
    for topic, want in (("/fd/residual", offline.signal), ("/fd/threshold", offline.threshold),
                        ("/fd/alarm", offline.alarm.astype(float))):
        np.testing.assert_array_equal(got[topic].stamps, offline.k, err_msg=topic)
        np.testing.assert_array_equal(got[topic].values, want, err_msg=topic)
