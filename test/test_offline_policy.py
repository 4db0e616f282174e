"""Offline reading runs the nodes' input policy (issue 10 item 2): one policy, not two.

A synthetic three_tank bag holds every kind of bad ordering at once: a duplicate, an
out-of-order pair within ``gap_timeout``, a hole, a message delayed beyond ``gap_timeout``,
a stray stamp far ahead, and a source that restarts its stamps (a new run). The offline
reader (:func:`fd_monitor.analysis.offline.read_streams`, record log time as ``now``) must
take exactly the decisions a live entry node takes: the reference below drives
:class:`~fd_monitor.wire.join.StampJoin` as the node's subscription callback and gap timer
do (put at arrival, release after it and on a 10 ms timer), independently of
:class:`~fd_monitor.wire.stream.InputStream`.
"""

from __future__ import annotations

import numpy as np
import pytest

from fd_monitor.analysis.offline import read_streams, run_bag
from fd_monitor.core.methods import load_gains
from fd_monitor.core.simulator import simulate
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system
from fd_monitor.wire.bag_writer import write_messages
from fd_monitor.wire.join import StampJoin
from fd_monitor.wire.stream import (
    GAP_TIMEOUT,
    MAX_GAP,
    RESTART_AFTER,
    STAMP_HORIZON,
    TopicOrder,
)
from fd_monitor.wire.topics import PLANT_U, PLANT_Y

TS = 0.1                     # three_tank's sample time, s
STRAY = 2**40                # a stamp far beyond the horizon


@pytest.fixture(scope="module")
def plant():
    sys_ = load_system("three_tank")
    return sys_, load_gains("three_tank_thresholds", sys_), simulate(
        load_scenario("three_tank_nominal"), 1, 120)


def _timeline(tr) -> list[tuple[float, str, int, np.ndarray]]:
    """(log time s, topic, stamp, values) in record order."""
    u, y = PLANT_U.absolute, PLANT_Y.absolute
    out: list[tuple[float, str, int, np.ndarray]] = []

    def sample(t: float, k: int, src: int | None = None) -> None:
        j = k if src is None else src
        out.extend([(t, u, k, tr.u[0, j]), (t, y, k, tr.y[0, j])])

    for k in range(80):
        t = k * TS
        if 20 <= k <= 24:
            continue                                   # a hole: no message at all
        if k == 10:
            out.append((t, u, 10, tr.u[0, 10]))        # y10 comes after y11 (within 1 s)
            continue
        if k == 11:
            sample(t, 11)
            out.append((t, y, 10, tr.y[0, 10]))
            continue
        if k == 40:
            out.append((t, u, 40, tr.u[0, 40]))        # y40 comes 1.8 s late: a hole
            continue
        sample(t, k)
        if k == 5:
            out.append((t, y, 5, tr.y[0, 5]))          # recorded twice
        if k == 58:
            out.append((t, y, 40, tr.y[0, 40]))        # the late y40
        if k == 60:
            out.append((t, y, STRAY, tr.y[0, 60]))     # a stray stamp
    for j in range(30):                                # the source restarts at stamp 0
        if j == 28:                                    # u only: 29 waits for the bag's end
            out.append((8.0 + j * TS, u, 28, tr.u[0, 28]))
            continue
        sample(8.0 + j * TS, j)
    return out


def _bag(tmp_path, sys_, timeline) -> str:
    labels = {PLANT_U.absolute: sys_.inputs, PLANT_Y.absolute: sys_.outputs}
    return str(write_messages(tmp_path / "policy", [
        (topic, round(t * 1e9), k, labels[topic], v) for t, topic, k, v in timeline]))


def _node_reference(timeline) -> list[tuple]:
    """The decisions of a live entry node: callback put + release, a 10 ms gap timer."""
    join = StampJoin(["u", "y"], gap_timeout=GAP_TIMEOUT, horizon=STAMP_HORIZON,
                     restart_after=RESTART_AFTER, max_gap=MAX_GAP)
    orders = {t: TopicOrder(t) for t in (PLANT_U.absolute, PLANT_Y.absolute)}
    name = {PLANT_U.absolute: "u", PLANT_Y.absolute: "y"}
    out: list[tuple] = []

    def drain(now: float) -> None:
        out.extend((s.k, s.restart, s.bridge, s.hole, s.new_run is not None)
                   for s in join.ready(now))

    clock = 0.0
    for t, topic, k, v in [*timeline, (timeline[-1][0] + 5.0, None, 0, None)]:
        while clock + 0.01 < t:                        # the timer between two messages
            clock += 0.01
            if join.pending or join.held:
                drain(clock)
        clock = t
        if topic is None:
            break
        _line, duplicate = orders[topic].check(k)
        if duplicate:
            continue
        if join.put(name[topic], k, v, t) is None:
            drain(t)
    return out


def test_offline_takes_the_live_nodes_decisions(plant, tmp_path):
    sys_, _g, tr = plant
    timeline = _timeline(tr)
    bag = _bag(tmp_path, sys_, timeline)
    seen: list[tuple] = []

    def step(s) -> bool:
        seen.append((s.k, s.restart, s.bridge, s.hole, s.new_run is not None))
        return True

    got, rep = read_streams(bag, sys_, step=step)
    assert seen == _node_reference(timeline)
    ks = [s[0] for s in seen]
    assert ks == [*range(20), *range(25, 40), *range(41, 80), *range(28), 29]
    # what the reader reports: the live node's log, by kind
    kinds = rep.by_kind()
    assert kinds["duplicate"] == [5]
    # y10 after y11; y40 after y58; y61 after the stray; u0 and y0 of the new run
    assert kinds["out_of_order"] == [0, 0, 10, 40, 61]
    assert kinds["missing"] == [[20, 24], [28, 28], [40, 40]]
    assert kinds["late"] == [40]                       # y40 came after its hole was declared
    assert kinds["held"] == [0, STRAY]                 # the stray, the new run's first
    # holes of at most MAX_GAP samples are bridged; the new run restarts
    assert MAX_GAP >= 5
    assert rep.restarts == [0]
    assert rep.bridges == [25, 41, 29]                 # 29: decided at the end (now = inf)
    assert [s for s in seen if s[1] or s[2]] == [
        (0, True, False, None, False), (25, False, True, (20, 24), False),
        (41, False, True, (40, 40), False), (0, True, False, None, True),
        (29, False, True, (28, 28), False)]
    # the values joined are the messages' (the new run's stamp 0 replays sample 0)
    assert got.k.tolist() == ks                        # released order, both runs
    np.testing.assert_array_equal(got.y[ks.index(10)], tr.y[0, 10])
    np.testing.assert_array_equal(got.u[ks.index(79)], tr.u[0, 79])


def test_out_of_order_within_the_timeout_is_not_a_hole(plant, tmp_path):
    """A stamp that comes gap_timeout - 0.2 s late is joined in order (no restart)."""
    sys_, _g, tr = plant
    u, y = PLANT_U.absolute, PLANT_Y.absolute
    late = GAP_TIMEOUT - 0.2
    tl = [m for k in range(30) for m in ((k * TS, u, k, tr.u[0, k]), (k * TS, y, k, tr.y[0, k]))
          if not (m[1] == y and m[2] == 12)]
    tl.append((12 * TS + late, y, 12, tr.y[0, 12]))
    tl.sort(key=lambda m: m[0])
    got, rep = read_streams(_bag(tmp_path, sys_, tl), sys_)
    assert got.k.tolist() == list(range(30)) and rep.restarts == []
    assert rep.by_kind() == {"out_of_order": [12]}


def test_a_bag_read_twice_gives_the_same_run(plant, tmp_path):
    """The same stream recorded twice in one bag (a source restarted, a bag replayed again):
    two runs, the second a new run with fresh state, bit-identical to the first; and
    reading the bag again gives the same result."""
    sys_, g, tr = plant
    u, y = PLANT_U.absolute, PLANT_Y.absolute
    K = 100
    once = [m for k in range(K) for m in ((k * TS, u, k, tr.u[0, k]), (k * TS, y, k, tr.y[0, k]))]
    twice = once + [(t + K * TS, topic, k, v) for t, topic, k, v in once]
    bag = _bag(tmp_path, sys_, twice)
    a, b = run_bag(bag, g, system=sys_), run_bag(bag, g, system=sys_)
    for f in ("k", "signal", "threshold", "alarm", "mode_hat"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    assert a.inputs.errors == b.inputs.errors and a.inputs.restarts == b.inputs.restarts
    np.testing.assert_array_equal(a.k, [*range(K), *range(K)])
    np.testing.assert_array_equal(a.signal[:K], a.signal[K:])     # fresh state at the new run
    np.testing.assert_array_equal(a.estimate["h1"][:K], a.estimate["h1"][K:])
    assert a.inputs.restarts == [0]
    assert a.inputs.by_kind() == {"out_of_order": [0, 0], "held": [0]}


def test_a_refused_sample_then_a_gap_is_a_reported_hole(plant, tmp_path):
    """An implausible y at 50 (refused by the runtime), then no message for 51..53: the
    stream goes on at 51, so 51..53 are a reported hole and 54 bridges the 4 lost samples
    (50..53, within MAX_GAP)."""
    sys_, g, tr = plant
    u, y = PLANT_U.absolute, PLANT_Y.absolute
    bad = tr.y[0, 50].copy()
    bad[0] = 1e300
    tl = [m for k in range(80) if not 51 <= k <= 53
          for m in ((k * TS, u, k, tr.u[0, k]), (k * TS, y, k, bad if k == 50 else tr.y[0, k]))]
    run = run_bag(_bag(tmp_path, sys_, tl), g, system=sys_)
    assert run.inputs.by_kind() == {"implausible": [50], "missing": [[51, 53]]}
    assert run.inputs.restarts == [] and run.inputs.bridges == [54]
    assert list(run.k) == [*range(50), *range(54, 80)]


@pytest.mark.ros
def test_monitor_fed_at_the_recorded_pace_matches_offline(plant, tmp_path):
    """The live spec: the synthetic bag replayed at its recorded pace (``--rate 1``) into
    the ``monitor`` process gives the samples, residuals and reports of the offline read.
    (Flat out, time is compressed: a message 1.5 s late in the bag is not late live.)"""
    from ros_util import Proc, replay_through
    from test_regression_live import logged_input_errors

    from fd_monitor.wire.bag_reader import read_bag

    sys_, g, tr = plant
    bag = _bag(tmp_path, sys_, _timeline(tr))
    offline = run_bag(bag, g, system=sys_)
    n = len(offline.k)
    # max_lag 0: equality with offline needs every sample (a real-time stream on a loaded
    # machine may put the node more than max_lag behind, and it would shed)
    mon = Proc(["run", "monitor", "--ros-args", "-p", "log_throttle:=0.0", "-p", "max_lag:=0.0"])
    rec = Proc(["record", "/fd/residual", "-o", str(tmp_path / "rec"),
                "--until", f"/fd/residual={n}"])
    replay_through([mon], rec, bag, ["/plant/u", "/plant/y"], wait_subscribers=1, rate=1.0)
    res = read_bag(tmp_path / "rec", ["/fd/residual"])["/fd/residual"]
    np.testing.assert_array_equal(res.stamps, offline.k)
    np.testing.assert_array_equal(res.values[:, :sys_.ny], offline.signal)
    live = logged_input_errors(mon.output())
    want = offline.inputs.by_kind()
    assert {k: live.get(k) for k in ("duplicate", "out_of_order", "missing")} == \
        {k: want.get(k) for k in ("duplicate", "out_of_order", "missing")}
