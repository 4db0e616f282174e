"""StampJoin's decisions (pure, time passed in): order, feedback, holes, restarts.

The entry role must reproduce :func:`fd_monitor.offline.run_bag`: valid samples in stamp
order, a restart (feedback at initial values) at the first valid sample after a hole, a
rejected message makes its stamp lost at once, a missing one is lost once a later stamp has
been complete for ``gap_timeout`` s, out-of-order stamps within the timeout are processed in
order, duplicates keep the first.
"""

from __future__ import annotations

from fd_monitor.nodes.conversions import readable_stamp, to_msg
from fd_monitor.nodes.join import StampJoin

FB0 = "fb0"


def entry(gap_timeout=1.0):
    return StampJoin(["u", "y"], {"fb": FB0}, gap_timeout=gap_timeout)


def feed(j, k, now=0.0, names=("u", "y")):
    for n in names:
        assert j.put(n, k, f"{n}{k}", now) is None


def release(j, now=0.0):
    return [(s.k, s.restart, s.hole, s.inputs.get("fb")) for s in j.ready(now)]


def test_entry_in_order_with_feedback():
    j = entry()
    feed(j, 0)
    assert release(j) == [(0, True, None, FB0)]        # first sample: initial feedback
    feed(j, 1)
    assert release(j) == []                            # waits for feedback, not a hole
    j.put("fb", 1, "fb1")
    assert release(j, 100.0) == [(1, False, None, "fb1")]


def test_entry_rejected_stamp_is_a_hole_at_once():
    j = entry()
    feed(j, 0)
    release(j)
    j.put("fb", 1, "fb1")
    j.put("u", 1, "u1")
    j.reject(1)                                        # y_1 was NaN
    assert release(j) == []                            # nothing complete after it yet
    j.reject(2)
    feed(j, 3, now=5.0)
    j.put("fb", 2, "late")                             # feedback for a skipped sample
    assert release(j, 5.0) == [(3, True, (1, 2), FB0)]
    assert j.put("fb", 2, "later") is None             # silently dropped
    assert "hole" in j.put("y", 2, "y2")               # a late required message is reported


def test_entry_missing_stamp_needs_the_timeout():
    j = entry(gap_timeout=1.0)
    feed(j, 0)
    release(j)
    feed(j, 5, now=10.0)                               # 1..4 never came
    assert release(j, 10.5) == []
    assert release(j, 11.0) == [(5, True, (1, 4), FB0)]


def test_entry_out_of_order_within_the_timeout_is_processed_in_order():
    j = entry()
    feed(j, 0)
    release(j)
    j.put("u", 1, "u1")
    feed(j, 2, now=1.0)                                # y_2 before y_1
    assert release(j, 1.5) == []
    j.put("y", 1, "y1")
    j.put("fb", 1, "fb1")
    assert [s[0] for s in release(j, 1.6)] == [1]
    j.put("fb", 2, "fb2")
    assert release(j, 1.7) == [(2, False, None, "fb2")]


def test_entry_duplicate_keeps_the_first():
    j = entry()
    feed(j, 0)
    assert "duplicate" in j.put("y", 0, "again")
    s = next(j.ready())
    assert s.inputs["y"] == "y0"


def test_downstream_follows_the_sequence_and_its_restarts():
    j = StampJoin(["est", "r"], {"fb": FB0}, sequence="est")
    for k in (0, 1):
        j.put("est", k, f"e{k}", restart=k == 0)
        j.put("r", k, f"r{k}")
    assert [s[:2] for s in release(j)] == [(0, True)]
    j.put("fb", 1, "fb1")
    j.put("est", 4, "e4", restart=True)                # the entry node skipped 2, 3
    j.put("r", 4, "r4")
    j.put("fb", 2, "dead")                             # from sample 1: alive until 4 runs
    assert release(j) == [(1, False, None, "fb1"), (4, True, (2, 3), FB0)]
    assert j.put("fb", 3, "late") is None              # a dead stamp: silently dropped
    assert j.pending == {}


def test_downstream_waits_for_feedback_of_an_alive_sample():
    j = StampJoin(["est"], {"fb": FB0}, sequence="est")
    j.put("est", 0, "e0", restart=True)
    release(j)
    j.put("est", 1, "e1")
    j.put("est", 3, "e3", restart=True)
    assert release(j) == []                            # 1 is alive: wait for its feedback
    j.put("fb", 1, "fb1")
    assert [s[:3] for s in release(j)] == [(1, False, None), (3, True, (2, 2))]


def test_readable_stamp():
    m = to_msg(("a", "b"), 7, [1.0, 2.0])
    assert readable_stamp(m) == 7
    m.data = [7.0, float("nan")]
    assert readable_stamp(m) == 7
    m.data = [float("nan"), 1.0]
    assert readable_stamp(m) is None
    m.layout.data_offset = 0
    assert readable_stamp(m) is None
