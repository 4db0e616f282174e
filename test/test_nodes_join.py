"""StampJoin's decisions (pure, time passed in): order, feedback, holes, restarts.

The entry role is the input policy of the nodes and of offline reading
(:func:`fd_monitor.analysis.offline.run_bag`, test/test_offline_policy.py): valid samples in stamp
order, a restart (feedback at initial values) at the first valid sample after a hole, a
rejected message makes its stamp lost at once, a missing one is lost once a later stamp has
been complete for ``gap_timeout`` s, out-of-order stamps within the timeout are processed in
order, duplicates keep the first.
"""

from __future__ import annotations

import pytest

from fd_monitor.wire.conversions import readable_stamp, to_msg
from fd_monitor.wire.join import StampJoin

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


def test_entry_stamp_beyond_the_horizon_is_held_and_forgotten_in_a_live_stream():
    j = StampJoin(["u", "y"], gap_timeout=1.0, horizon=1000, restart_after=1.0)
    feed(j, 0)
    release(j)
    note = j.put("u", 2**52, "u", 0.1)
    assert "more than 1000 samples ahead" in note and "held" in note
    assert j.put("y", 2**52, "y", 0.1) is None           # reported once per episode
    for k in range(1, 20):
        feed(j, k, now=0.1 + k)                            # the stream goes on
        assert [s[0] for s in release(j, 0.1 + k)] == [k]
    assert j.held == {}                                    # forgotten at the next progress
    assert release(j, 100.0) == []                         # never a new run


def test_entry_source_restarting_at_zero_is_a_new_run():
    j = StampJoin(["u", "y"], gap_timeout=1.0, horizon=1000, restart_after=1.0)
    for k in range(500):
        feed(j, k, now=k * 0.001)
        release(j, k * 0.001)
    assert "below the stream (next is 500)" in j.put("u", 0, "u0", 1.0)
    assert j.put("y", 0, "y0", 1.0) is None
    feed(j, 1, now=1.1)
    assert release(j, 1.2) == []                           # the old stream may go on
    out = list(j.ready(1.6))                               # stalled 1.1 s: a new run
    assert [(s.k, s.restart, s.new_run) for s in out] == [(0, True, (500, 4)),
                                                          (1, False, None)]
    feed(j, 2, now=1.7)                                     # and it goes on
    assert [s[0] for s in release(j, 1.7)] == [2]


def test_entry_stray_stamp_then_pause_then_good_samples():
    """The 2**52 pair adopted after a pause; the good samples after it are a new run again."""
    j = StampJoin(["u", "y"], gap_timeout=1.0, horizon=1000, restart_after=1.0)
    feed(j, 0)
    release(j)
    for n in ("u", "y"):
        j.put(n, 2**52, n, 0.5)
    assert [s[0] for s in release(j, 2.0)] == [2**52]       # the stream stopped: adopted
    for k in range(1, 6):
        for n in ("u", "y"):
            j.put(n, k, n, 3.0)
    assert [(s[0], s[1]) for s in release(j, 3.0)] == [(1, True), (2, False), (3, False),
                                                       (4, False), (5, False)]


def test_downstream_restart_below_the_stream_adopts_held_inputs():
    j = StampJoin(["est", "r"], sequence="est")
    for k in range(10):
        j.put("est", k, f"e{k}", restart=k == 0)
        j.put("r", k, f"r{k}")
    assert [s[0] for s in release(j)] == list(range(10))
    assert j.put("r", 0, "new r0") is None                  # a new run's input, early
    j.put("est", 0, "new e0", restart=True)
    out = list(j.ready())
    assert [(s.k, s.restart, s.inputs["r"]) for s in out] == [(0, True, "new r0")]
    assert out[0].new_run == (10, 2)


def test_reset_forgets_everything():
    j = entry()
    feed(j, 0)
    release(j)
    j.reset()
    assert j.k_next is None and j.pending == {}
    feed(j, 0)
    assert release(j) == [(0, True, None, FB0)]


def test_lost_feedback_goes_on_without_it_then_the_restarted_source_rejoins():
    """fb_1 did not come (its source was killed, or a burst overflowed its publisher's
    history): without a timeout the join would wait for it forever. After gap_timeout s
    sample 1 goes on with fb's initial value and no restart (the run's memory is kept);
    fb is not waited for again -- a killed source stays matched until its DDS lease ends,
    and waiting gap_timeout s per sample was a crawl no restarted source could catch up
    with -- until a message of it arrives, even for a sample already processed (issue 26:
    a restarted bias_estimator rejoins the running chain)."""
    j = entry(gap_timeout=1.0)
    feed(j, 0)
    release(j)
    feed(j, 1, now=0.5)
    feed(j, 2, now=0.5)
    assert release(j, 0.9) == []                        # fb_1 may still come
    out = list(j.ready(1.0))          # due gap_timeout s after sample 0 was released
    assert [(s.k, s.restart, s.feedback_lost, s.inputs["fb"]) for s in out] == [
        (1, False, True, FB0), (2, False, False, FB0)]
    assert j.lost_feedback == {"fb"} and j.feedback_losses == 1 and j.restarts == 0
    feed(j, 3, now=2.1)
    assert release(j, 2.1) == [(3, False, None, FB0)]   # not waited for
    j.put("fb", 3, "late fb3", 2.2)                     # the restarted source's first one
    assert j.lost_feedback == set() and j.resumed == ["fb"]
    feed(j, 4, now=2.2)
    assert release(j, 2.3) == []                        # waited for again
    j.put("fb", 4, "fb4", 2.3)
    assert release(j, 2.3) == [(4, False, None, "fb4")]


def test_lost_feedback_with_a_later_one_here_is_one_sample_only():
    """Only fb_1 was lost (fb_2 is already here): 1 goes on without it, fb stays awaited."""
    j = entry(gap_timeout=1.0)
    feed(j, 0)
    release(j)
    feed(j, 1, now=1.0)
    feed(j, 2, now=1.0)
    j.put("fb", 2, "fb2", 1.0)
    assert release(j, 2.0) == [(1, False, None, FB0), (2, False, None, "fb2")]
    assert j.lost_feedback == set()


def test_downstream_lost_feedback_goes_on_after_restart_after():
    """Downstream, the feedback for a sample is due restart_after s after the previous one
    was released, however late the sample's own est came (the entry node may have waited
    for a dead peer already)."""
    j = StampJoin(["est"], {"fb": FB0}, sequence="est", restart_after=1.0)
    j.put("est", 0, "e0", 0.0, restart=True)
    release(j)
    j.put("est", 1, "e1", 0.5)
    assert release(j, 0.9) == []
    assert [(s.k, s.restart, s.feedback_lost) for s in j.ready(1.0)] == [(1, False, True)]
    j.put("est", 2, "e2", 2.0)
    assert release(j, 2.0) == [(2, False, None, FB0)]   # not waited for until fb comes
    j.put("fb", 2, "fb2 late", 2.1)
    j.put("est", 3, "e3", 2.1)
    assert release(j, 2.2) == []
    j.put("fb", 3, "fb3", 2.2)
    assert release(j, 2.2) == [(3, False, None, "fb3")]


def test_entry_behind_by_more_than_max_lag_sheds_to_the_newest_sample():
    """A node that cannot keep up (the next sample waits behind a backlog for more than
    max_lag s) skips to the newest complete sample: the skipped stamps are a hole (a restart
    beyond max_gap, a bridge within), counted in ``shed``; nothing stalls (issue 26: the
    in-process chain took 84 s to drain 10 s of 10 kHz input)."""
    j = StampJoin(["u", "y"], {"fb": FB0}, gap_timeout=0.5, max_lag=2.0, max_gap=3)
    feed(j, 0)
    assert release(j) == [(0, True, None, FB0)]
    for k in range(1, 50):
        feed(j, k, now=0.01 * k)
    j.put("fb", 1, "fb1", 0.5)
    assert release(j, 0.5) == [(1, False, None, "fb1")]   # in lock step, behind
    j.put("fb", 2, "fb2", 2.5)
    out = list(j.ready(2.5))                            # 2 complete at 0.02: 2.48 s ago
    assert [(s.k, s.restart, s.hole, s.shed) for s in out] == [(49, True, (2, 48), 47)]
    assert (j.shed, j.shed_episodes) == (47, 1)
    # a short skip is bridged with the feedback in force
    for k in range(50, 53):
        feed(j, k, now=2.6)
    j.put("fb", 50, "fb50", 2.6)
    assert release(j, 2.6) == [(50, False, None, "fb50")]
    out = list(j.ready(5.0))
    assert [(s.k, s.bridge, s.hole, s.shed, s.inputs["fb"]) for s in out] == [
        (52, True, (51, 51), 1, FB0)]


def test_downstream_behind_by_more_than_max_lag_restarts_at_the_newest_sample():
    """A downstream node behind its entry node (est_k waiting, complete, for more than
    max_lag s) skips to the newest complete est and restarts there."""
    j = StampJoin(["est"], {"fb": FB0}, sequence="est", restart_after=1.0, max_lag=1.0)
    j.put("est", 0, "e0", 0.0, restart=True)
    assert release(j) == [(0, True, None, FB0)]
    for k in range(1, 30):
        j.put("est", k, f"e{k}", 0.01 * k)
    j.put("fb", 1, "fb1", 0.5)
    assert release(j, 0.5) == [(1, False, None, "fb1")]
    out = list(j.ready(1.1))                            # est_2 complete at 0.02
    assert [(s.k, s.restart, s.hole, s.shed) for s in out] == [(29, True, (2, 28), 27)]
    j.put("est", 30, "e30", 1.2)
    j.put("fb", 30, "fb30", 1.2)
    assert release(j, 1.2) == [(30, False, None, "fb30")]


def lagging_entry(spacing: float, n: int = 60) -> StampJoin:
    """An entry join (Ts 0.1 s, max_lag 2 s, batch_pace 2) whose samples 1..n arrived
    ``spacing`` s apart while it waited for the feedback of sample 1 (the chain in lock step
    behind a backlog)."""
    j = StampJoin(["u", "y"], {"fb": FB0}, gap_timeout=0.5, max_lag=2.0, sample_time=0.1,
                  batch_pace=2.0)
    feed(j, 0)
    assert release(j) == [(0, True, None, FB0)]
    for k in range(1, n + 1):
        feed(j, k, now=spacing * k)
    return j


def test_a_backlog_that_came_faster_than_real_time_is_a_batch_and_never_shed():
    """Issue 26 item 0 without losing a flat-out replay's samples: 60 samples 0.01 s apart
    (10 x real time at Ts 0.1 s) wait 3 s behind a feedback: more than max_lag behind, but a
    batch (their stamps span 6 s of plant time, they came within 0.6 s): every one is
    processed in order, also once the source has stopped (the end of a replay)."""
    j = lagging_entry(0.01)
    j.put("fb", 1, "fb1", 3.0)
    assert release(j, 3.0) == [(1, False, None, "fb1")]
    for k in range(2, 61):
        j.put("fb", k, f"fb{k}", 3.0 + k)
        assert release(j, 3.0 + k) == [(k, False, None, f"fb{k}")]
    assert (j.shed, j.shed_episodes) == (0, 0) and j.batch_waits > 0
    assert j.pace_waits == j.batch_waits                # by pace: the opt-in rule


def test_a_backlog_that_came_at_real_time_is_shed_and_batch_pace_0_sheds_any():
    """The same wait on a live stream (samples 0.1 s apart: real time) sheds to the newest
    sample; so does a batch with ``batch_pace`` 0 (nothing is a batch: what a user sets for
    a simulation far faster than real time where latency matters)."""
    j = lagging_entry(0.1)
    j.put("fb", 1, "fb1", 6.05)                 # sample 1 complete at 0.1: 5.95 s ago
    out = [(s.k, s.restart, s.hole, s.shed) for s in j.ready(6.05)]
    assert out == [(60, True, (1, 59), 59)]
    j = lagging_entry(0.01)
    j.batch_pace = 0.0
    j.put("fb", 1, "fb1", 3.0)
    out = [(s.k, s.restart, s.hole, s.shed) for s in j.ready(3.0)]
    assert out == [(60, True, (1, 59), 59)]
    assert j.batch_waits == 0


def test_a_batch_that_turns_into_a_live_stream_is_shed_once_the_live_part_dominates():
    """30 samples at once (a burst: 3 s of plant time), then real time (10 Hz), into a node
    that processes 2 samples a second: more than max_lag behind from t = 2 s, the backlog is
    a batch while its stamps span more than twice its arrival time, then it is shed (a burst
    after a stall delays a shed by about its own length)."""
    j = StampJoin(["u", "y"], {"fb": FB0}, gap_timeout=0.5, max_lag=2.0, sample_time=0.1,
                  batch_pace=2.0)
    feed(j, 0)
    release(j)
    for k in range(1, 31):
        feed(j, k, now=0.0)                     # the burst
    shed_at = None
    for i in range(1, 60):
        t = 0.1 * i
        feed(j, 30 + i, now=t)
        if i % 5 == 0:                          # the node's pace: 2 samples a second
            j.put("fb", j.k_next, "fb", t)
        out = [(t, s.k, s.shed) for s in j.ready(t) if s.shed]
        if out:
            shed_at = out[0]
            break
    # lagging > 2 s; shed when (newest - k) * 0.1 <= 2 t, newest = 30 + 10 t, k ~ 1 + 2 t:
    # 2.9 + 0.8 t <= 2 t, t >= 2.42 (batch_pace 0 would have shed at 2.1)
    assert shed_at is not None and 2.4 <= shed_at[0] <= 2.6 and shed_at[1] == 30 + i, shed_at


def test_downstream_batch_is_not_shed():
    """A downstream node behind a fast entry node (est 0.01 s apart, Ts 0.1 s) processes
    every est however late; the same backlog at real time is shed."""
    for spacing, expected in ((0.01, [(1, 0)]), (0.1, [(29, 28)])):
        j = StampJoin(["est"], {"fb": FB0}, sequence="est", restart_after=1.0, max_lag=1.0,
                      sample_time=0.1, batch_pace=2.0)
        j.put("est", 0, "e0", 0.0, restart=True)
        release(j)
        for k in range(1, 30):
            j.put("est", k, f"e{k}", spacing * k)
        j.put("fb", 1, "fb1", 4.0)
        out = [(s.k, s.shed) for s in j.ready(4.0)]
        assert out == expected, (spacing, out)


def test_max_lag_is_at_least_the_feedback_timeout_and_offline_never_sheds():
    assert StampJoin(["u"], {"fb": 0}, gap_timeout=1.0, max_lag=0.1).max_lag == 1.0
    assert StampJoin(["est"], sequence="est", restart_after=2.0, max_lag=1.0).max_lag == 2.0
    assert StampJoin(["u"], gap_timeout=1.0).max_lag is None


def test_downstream_skips_a_stamp_whose_inputs_were_published_before_it_subscribed():
    """A downstream node that subscribed after the source started (a robot driver already
    publishing, the in-process chain's bias estimator created last) gets est_0 but never
    u_0: once a later sequence stamp has every input, 0 is dead and the node restarts there
    instead of waiting for u_0 forever."""
    j = StampJoin(["u", "est"], {"fb": FB0}, sequence="est")
    j.put("est", 0, "e0", restart=True)
    j.put("u", 1, "u1")
    assert release(j) == []                            # 1 has no est yet: 0 may still come
    j.put("est", 1, "e1", restart=True)
    assert release(j) == [(1, True, None, FB0)]
    assert j.pending == {}
    j.put("u", 2, "u2")
    j.put("est", 2, "e2")
    j.put("fb", 2, "fb2")
    assert release(j) == [(2, False, None, "fb2")]
    # later in the stream: u_3 lost on the way, 4 complete -> a hole at 3, restart at 4
    j.put("est", 3, "e3")
    j.put("fb", 3, "fb3")
    j.put("u", 4, "u4")
    j.put("est", 4, "e4")
    assert release(j) == [(4, True, (3, 3), FB0)]


def test_feedback_without_a_publisher_is_not_waited_for():
    """An observer without its bias estimator (or before its publisher matched) runs open
    loop: feedback at its initial value, no restart, no wait; once a publisher is matched it
    waits for the feedback again."""
    there = {"fb": False}
    j = StampJoin(["u", "y"], {"fb": FB0}, gap_timeout=1.0,
                  feedback_source=lambda n: there[n])
    feed(j, 0)
    feed(j, 1)
    feed(j, 2)
    assert release(j) == [(0, True, None, FB0), (1, False, None, FB0), (2, False, None, FB0)]
    there["fb"] = True
    feed(j, 3)
    assert release(j, 0.5) == []                       # a source exists: wait for fb_3
    j.put("fb", 3, "fb3")
    assert release(j, 0.5) == [(3, False, None, "fb3")]
    j.reset()
    assert j.feedback_source is not None               # kept across a reset


def test_downstream_feedback_without_a_publisher_is_not_waited_for():
    j = StampJoin(["est"], {"fb": FB0}, sequence="est", feedback_source=lambda n: False)
    j.put("est", 0, "e0", restart=True)
    j.put("est", 1, "e1")
    assert release(j) == [(0, True, None, FB0), (1, False, None, FB0)]


def test_entry_refused_sample_keeps_the_stream_at_the_next_stamp():
    """After :meth:`StampJoin.lost` (the core refused sample 1) the stream goes on at 2: a 2
    that comes after 3 within the timeout is still joined (a restart, no feedback awaited),
    and a 2 that never comes is a reported hole -- not skipped silently."""
    j = entry()
    feed(j, 0)
    release(j)
    feed(j, 1)
    j.put("fb", 1, "fb1")
    (s1,) = release(j)
    j.lost(s1[0])
    feed(j, 3, now=0.1)                                # 3 before 2
    assert release(j, 0.1) == []                       # 2 is awaited, not skipped
    feed(j, 2, now=0.2)
    j.put("fb", 3, "fb3")
    assert release(j, 0.2) == [(2, True, None, FB0), (3, False, None, "fb3")]
    j.lost(3)
    feed(j, 5, now=1.0)                                # 4 never comes
    assert release(j, 1.5) == []
    assert release(j, 2.0) == [(5, True, (4, 4), FB0)]


def test_join_notes_carry_their_kind():
    j = StampJoin(["u", "y"], gap_timeout=1.0, horizon=10)
    feed(j, 0)
    list(j.ready())
    j.put("u", 1, "u1")
    assert j.put("u", 1, "again").kind == "duplicate"
    assert j.put("u", 50, "stray").kind == "held"
    feed(j, 3, now=0.0)
    list(j.ready(5.0))                                 # 1..2: a hole
    assert j.put("y", 2, "late").kind == "late"
    j = StampJoin(["u", "y"], max_pending=3)
    for k in range(3):
        assert j.put("u", k, "u") is None
    note = j.put("u", 3, "u")                          # a 4th incomplete stamp: 0 dropped
    assert (note.kind, note.stamp) == ("dropped", 0)


# -- a hole is not amnesia (issue 19 item 2): bridges --------------------------------------


def bridged(j, now=0.0):
    return [(s.k, s.restart, s.bridge, s.gap, s.hole, s.inputs.get("fb")) for s in j.ready(now)]


def test_entry_short_hole_is_bridged_with_the_feedback_in_force():
    """A hole of at most max_gap stamps: the next sample is a bridge (no restart), with the
    feedback stamped at the hole's first stamp (what the last processed sample decided);
    a longer one restarts with the initial feedback."""
    j = StampJoin(["u", "y"], {"fb": FB0}, gap_timeout=1.0, max_gap=3)
    feed(j, 0)
    assert bridged(j) == [(0, True, False, 0, None, FB0)]
    j.put("fb", 1, "fb1")                              # decided at 0, for 1
    j.reject(1)
    j.reject(2)
    feed(j, 3)
    assert bridged(j) == [(3, False, True, 2, (1, 2), "fb1")]
    assert j.put("fb", 2, "late") is None              # inside the hole: dropped
    j.put("fb", 4, "fb4")
    for k in (4, 5, 6, 7):
        j.reject(k)
    feed(j, 8)                                         # 4 lost stamps > max_gap
    assert bridged(j) == [(8, True, False, 4, (4, 7), FB0)]
    assert (j.bridges, j.restarts) == (1, 1)


def test_entry_bridge_waits_for_the_feedback_of_the_last_sample():
    """The hole is decided before the feedback of the last processed sample arrived: the
    bridge waits for it (it is on its way), and after gap_timeout bridges without it (its
    initial value, feedback_lost), as for any feedback."""
    j = StampJoin(["u", "y"], {"fb": FB0}, gap_timeout=1.0, max_gap=3)
    feed(j, 0)
    bridged(j)
    j.reject(1)
    feed(j, 2, now=0.1)
    assert bridged(j, 0.2) == []                       # fb for 1 not here yet
    j.put("fb", 1, "fb1")
    assert bridged(j, 0.3) == [(2, False, True, 1, (1, 1), "fb1")]
    j.reject(3)
    feed(j, 4, now=1.0)
    assert bridged(j, 1.2) == []                       # 2 was released at 0.3
    out = list(j.ready(1.3))
    assert [(s.k, s.restart, s.bridge, s.feedback_lost, s.inputs["fb"]) for s in out] == [
        (4, False, True, True, FB0)]


def test_entry_refused_samples_are_bridged_with_the_feedback_carried():
    """Samples the core refused (lost) count in the gap; the sample after them bridges with
    the feedback that was in force for the refused one (no new feedback comes for a refused
    sample) and does not wait; refused samples and a hole together beyond max_gap restart.
    A refused restart sample makes the next one a restart again."""
    j = StampJoin(["u", "y"], {"fb": FB0}, gap_timeout=1.0, max_gap=2)
    feed(j, 0)
    bridged(j)
    j.put("fb", 1, "fb1")
    feed(j, 1)
    (s1,) = bridged(j)
    j.lost(s1[0])                                      # 1 refused by the core
    feed(j, 2)
    assert bridged(j) == [(2, False, True, 1, None, "fb1")]
    j.lost(2)                                          # refused again: the gap grows
    j.reject(3)
    feed(j, 4)
    assert bridged(j) == [(4, True, False, 3, (3, 3), FB0)]   # 2 refused + 1 lost > 2
    j.lost(4)                                          # a refused restart
    feed(j, 5)
    assert [s[:3] for s in bridged(j)] == [(5, True, False)]


def test_downstream_bridges_where_the_entry_bridged():
    """Downstream: a sequence stamp flagged bridge after skipped stamps is a bridge with the
    feedback stamped at the first skipped one; unflagged skips restart."""
    j = StampJoin(["est", "r"], {"fb": FB0}, sequence="est")
    j.put("est", 0, "e0", restart=True)
    j.put("r", 0, "r0")
    assert [s[:3] for s in bridged(j)] == [(0, True, False)]
    j.put("fb", 1, "fb1")                              # decided at 0, for 1
    j.put("est", 3, "e3", bridge=True)                 # the entry lost 1, 2
    j.put("r", 3, "r3")
    assert bridged(j) == [(3, False, True, 2, (1, 2), "fb1")]
    j.put("fb", 4, "fb4")
    j.put("est", 6, "e6")                              # skipped without a flag: restart
    j.put("r", 6, "r6")
    assert [s[:3] for s in bridged(j)] == [(6, True, False)]


def marked_lagging_entry(batch: bool, n: int = 60) -> StampJoin:
    """An entry join with the defaults of the nodes (max_lag 2 s, batch_pace 0) whose
    samples 1..n came 0.01 s apart (10 x real time at Ts 0.1 s), with the batch mark or
    without, while it waited for the feedback of sample 1."""
    j = StampJoin(["u", "y"], {"fb": FB0}, gap_timeout=0.5, max_lag=2.0, sample_time=0.1)
    feed(j, 0)
    assert release(j) == [(0, True, None, FB0)]
    for k in range(1, n + 1):
        for name in ("u", "y"):
            assert j.put(name, k, f"{name}{k}", 0.01 * k, batch=batch) is None
    return j


def test_a_marked_backlog_is_a_batch_and_an_unmarked_one_is_shed_whatever_its_pace():
    """Issue 26 item 0, by default: the same fast backlog (10 x real time) 3 s behind is
    processed completely when its messages carry the batch mark -- to its last sample after
    the source stopped (the end of a replay) -- and shed when they do not (a flood cannot
    be told from a flat-out replay by its pace); the released samples say they are a batch
    (the node marks what it publishes for them)."""
    j = marked_lagging_entry(True)
    j.put("fb", 1, "fb1", 3.0)
    out = list(j.ready(3.0))
    assert [(s.k, s.shed, s.batch) for s in out] == [(1, 0, True)]
    for k in range(2, 61):
        j.put("fb", k, f"fb{k}", 3.0 + k)
        assert [(s.k, s.shed, s.batch) for s in j.ready(3.0 + k)] == [(k, 0, True)]
    assert (j.shed, j.shed_episodes, j.pace_waits) == (0, 0, 0) and j.batch_waits >= 59
    j = marked_lagging_entry(False)
    j.put("fb", 1, "fb1", 3.0)
    out = list(j.ready(3.0))
    assert [(s.k, s.restart, s.hole, s.shed, s.batch) for s in out] == [
        (60, True, (1, 59), 59, False)]
    assert j.batch_waits == 0


def test_a_shed_stops_before_a_marked_batch_that_follows_a_live_backlog():
    """Unmarked samples 1..30 then marked 31..60 behind a feedback wait: the live part is
    skipped up to the batch, the batch processed completely."""
    j = StampJoin(["u", "y"], {"fb": FB0}, gap_timeout=0.5, max_lag=2.0)
    feed(j, 0)
    release(j)
    for k in range(1, 61):
        for name in ("u", "y"):
            j.put(name, k, f"{name}{k}", 0.01 * k, batch=k > 30)
    j.put("fb", 1, "fb1", 3.0)
    assert [(s.k, s.hole, s.shed, s.batch) for s in j.ready(3.0)] == [(31, (1, 30), 30, True)]
    for k in range(32, 61):
        j.put("fb", k, f"fb{k}", 3.0 + k)
        assert [(s.k, s.shed) for s in j.ready(3.0 + k)] == [(k, 0)]


def flood_held_in_dds(batch: bool, n: int = 5000) -> tuple[StampJoin, list, float]:
    """A downstream node (the standalone detector: no feedback publisher) taking a flood
    held in DDS: est k received at 0.1 ms x k (10 kHz), taken one at a time; a sample
    costs 1 ms to process, a skipped message 20 us. Returns the join, the released
    samples and the time the node had taken the last one."""
    j = StampJoin(["est"], {"fb": FB0}, sequence="est", restart_after=1.0, max_lag=2.0,
                  feedback_source=lambda name: False)
    out, t = [], 0.0
    for k in range(n):
        rx = 1e-4 * k
        t = max(t, rx)
        j.put("est", k, f"e{k}", t, restart=k == 0, batch=batch, arrived=rx)
        got = list(j.ready(t))
        out += got
        t += 1e-3 if got else 2e-5
    return j, out, t


def test_a_flood_held_in_dds_is_shed_in_one_episode_and_good_input_after_it_is_processed():
    """The backlog of a node that processes each sample in the callback that took it (the
    standalone detector, the fused monitor) stays in DDS, where the join cannot see it: the
    lag counts from each message's DDS reception time. Unmarked: processed while less than
    max_lag s old (stamps 0 .. ~2,200 in order), then skipped as taken, in one episode, to
    the end of the flood; a real-time sample after it is processed at once, restarting,
    and reports the skip. Marked: every sample processed, in order, nothing shed."""
    j, out, t = flood_held_in_dds(False)
    ks = [s.k for s in out]
    assert ks == list(range(len(ks))) and 2000 < len(ks) < 2400, len(ks)
    assert j.shed == 5000 - len(ks) and j.shed_episodes == 1
    j.put("est", 5000, "e5000", t + 0.1, arrived=t + 0.1)
    s, = j.ready(t + 0.1)
    assert (s.k, s.restart, s.hole, s.shed) == (5000, True, (len(ks), 4999), 5000 - len(ks))
    j, out, t = flood_held_in_dds(True)
    assert [s.k for s in out] == list(range(5000)) and all(s.batch for s in out)
    assert (j.shed, j.shed_episodes) == (0, 0) and t > 5.0


def test_a_node_that_cannot_even_take_the_flood_processes_one_sample_per_max_lag():
    """A source faster than the node takes messages (it never catches up): the skip ends
    after max_lag s of skipping with the sample in hand, so the node is never blind for
    longer than that."""
    j = StampJoin(["est"], {"fb": FB0}, sequence="est", restart_after=1.0, max_lag=2.0,
                  feedback_source=lambda name: False)
    j.put("est", 0, "e0", 0.0, restart=True)
    assert len(list(j.ready(0.0))) == 1
    done = []
    for k in range(1, 3001):
        t = 2.5 + 0.002 * k                    # taken every 2 ms, each received 2.5 s ago
        j.put("est", k, f"e{k}", t, arrived=t - 2.5)
        done += [(s.k, round(t, 3), s.shed) for s in j.ready(t)]
    assert [d[0] for d in done] == [1001, 2002] and done[0][2] == 1000, done


def test_sent_time_sees_a_queue_whatever_the_publishers_clock():
    """The lag counts from publication, on the node's clock: a publisher whose clock is 100 s
    ahead (another machine) gives the same publication times as one on ours; a message that
    waited 3 s (in the publisher's history or the DDS reader) is 3 s old when taken; the
    clock offset estimate follows a drift of up to 1 ms per s."""
    from fd_monitor.wire.stream import SentTime

    for skew in (0.0, 100.0, -100.0):
        st = SentTime()
        # (source on the publisher's clock, received and taken on ours): 1 ms transport
        assert st.sent(10.0 + skew, 10.001, now=5.002, now_wall=10.002) == pytest.approx(5.001)
        # published at 11.0, taken 3 s later (it waited): 3 s old (within the drift
        # allowance of 1 ms per s since the last message)
        assert st.sent(11.0 + skew, 14.0, now=9.0, now_wall=14.0) == pytest.approx(6.0,
                                                                                  abs=0.006)
        # drift: the publisher's clock 0.5 ms/s slower for 100 s; a message that did not
        # wait is still about as fresh as the transport makes it
        got = st.sent(111.0 + skew - 0.05, 111.001, now=106.001, now_wall=111.001)
        assert 106.001 - got <= 0.001 + 1e-9
    # never later than now
    assert SentTime().sent(20.0, 10.0, now=1.0, now_wall=10.0) == 1.0


def optional_rows(j, now):
    return [(s.k, s.restart, s.bridge, s.feedback_lost, s.inputs["g"]) for s in j.ready(now)]


def test_an_optional_input_is_its_own_stamps_or_none_never_a_substitute():
    """An optional input (the bias estimator's AGEI decision at k: the node has its own AGEI)
    is waited for like a required one while its publisher is there; unlike feedback it is
    not replaced at a restart or a bridge (the sample gets its own stamp's message)."""
    there = {"g": True}
    j = StampJoin(["est"], {"fb": FB0}, sequence="est", restart_after=1.0,
                  feedback_source=lambda n: there[n], optional=["g"])
    j.put("est", 0, "e0", 0.0, restart=True)
    assert optional_rows(j, 0.5) == []                 # waited for, at a restart too
    j.put("g", 0, "g0", 0.5)
    assert optional_rows(j, 0.5) == [(0, True, False, False, "g0")]
    j.put("fb", 1, "fb1", 0.6)
    j.put("est", 3, "e3", 0.6, bridge=True)            # the entry lost 1, 2
    assert optional_rows(j, 0.7) == []
    j.put("g", 3, "g3", 0.7)
    assert optional_rows(j, 0.7) == [(3, False, True, False, "g3")]
    there["g"] = False                                 # no publisher: not waited for
    j.put("fb", 4, "fb4", 0.8)
    j.put("est", 4, "e4", 0.8)
    assert optional_rows(j, 0.8) == [(4, False, False, False, None)]
    assert j.lost_feedback == set() and j.feedback_losses == 0
    with pytest.raises(ValueError, match="downstream role only"):
        StampJoin(["u", "y"], optional=["g"])


def test_a_lost_optional_input_is_none_until_its_publisher_is_back():
    """Its publisher killed (still matched until its lease ends): the sample is released
    with None after restart_after s, as lost feedback is, and the input is not waited for
    until a message of it arrives. The restarted publisher's first message is for a later
    stamp: the stamps before it get None at once (in order per topic, theirs will not come),
    no wait, no restart; from then on it is waited for again."""
    j = StampJoin(["est"], sequence="est", restart_after=1.0, optional=["g"])
    j.put("est", 0, "e0", 0.0, restart=True)
    j.put("g", 0, "g0", 0.0)
    assert optional_rows(j, 0.0) == [(0, True, False, False, "g0")]
    j.put("est", 1, "e1", 0.1)
    assert optional_rows(j, 0.9) == []
    assert optional_rows(j, 1.0) == [(1, False, False, True, None)]
    assert j.lost_feedback == {"g"} and j.last_lost == ("g",) and j.feedback_losses == 1
    j.put("est", 2, "e2", 1.1)
    j.put("est", 3, "e3", 1.1)
    assert optional_rows(j, 1.1) == [(2, False, False, False, None),
                                     (3, False, False, False, None)]
    j.put("est", 4, "e4", 1.2)
    j.put("est", 5, "e5", 1.2)
    j.put("g", 5, "g5", 1.3)                           # the restarted publisher's first
    assert j.lost_feedback == set() and j.resumed == ["g"]
    assert optional_rows(j, 1.3) == [(4, False, False, False, None),
                                     (5, False, False, False, "g5")]
    j.put("est", 6, "e6", 1.4)
    assert optional_rows(j, 1.4) == []                 # waited for again
    j.put("g", 6, "g6", 1.5)
    assert optional_rows(j, 1.5) == [(6, False, False, False, "g6")]
    assert j.restarts == 0 and j.feedback_losses == 1
