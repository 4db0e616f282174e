"""The one hold rule (fd_monitor/wire/hold.py): the value in force at t is the latest at or
before t, while at most max_age old; the nodes' plain-input pairing and the time base's grid
both use it (pure: no ROS)."""

from __future__ import annotations

import pytest

from fd_monitor.wire.hold import HeldPairing, ZeroOrderHold
from fd_monitor.wire.timebase import Gap, GridSample, GridSampler


def test_zero_order_hold_latest_at_or_before() -> None:
    h = ZeroOrderHold()
    assert h.at(5) is None
    h.put(10, "a")
    h.put(20, "b")
    assert h.at(9) is None
    assert h.at(10) == (10, "a") and h.at(19) == (10, "a") and h.at(25) == (20, "b")
    h.put(15, "late")                      # arrives after a newer one: in force from 15 to 20
    assert h.at(17) == (15, "late") and h.at(21) == (20, "b")
    h.put(20, "again")                     # a tie: the value put last wins
    assert h.at(20) == (20, "again")
    h.forget_before(18)                    # keeps the one in force at 18
    assert len(h) == 3 and h.at(18) == (15, "late")
    assert h.newer_than(19) and not h.newer_than(20)


def test_zero_order_hold_max_age_and_depth() -> None:
    h = ZeroOrderHold(max_age=2, depth=1)
    h.put(3, 1.0)
    h.put(1, 0.0)                          # older than the held one: not held
    assert len(h) == 1 and h.at(4) == (3, 1.0)
    assert not h.too_old(3, 5) and h.too_old(3, 6)


def test_held_pairing_waits_for_a_later_held_value_or_the_wait() -> None:
    p = HeldPairing(["u"], wait=0.1)
    p.hold("u", 100, "u100")
    p.sample(150, 0.0, "y150")
    # no u after 150 yet: it may still come (published before y, delivered after)
    assert list(p.pairs()) == [] and p.waiting == 1
    p.hold("u", 140, "u140")
    p.hold("u", 200, "u200")
    assert list(p.pairs()) == [("y150", {"u": "u140"}, [])]
    p.sample(250, 1.0, "y250")
    assert list(p.pairs(now=1.05)) == []               # within the wait
    assert list(p.pairs(now=1.2)) == [("y250", {"u": "u200"}, [])]
    p.sample(50, 2.0, "y50")                          # before every u kept: none held
    assert list(p.pairs(now=3.0)) == [("y50", {}, ["u"])]
    p.clear()
    assert p.waiting == 0 and len(p.holds["u"]) == 0


def test_held_pairing_without_held_inputs_pairs_at_once() -> None:
    p = HeldPairing([])
    p.sample(1, 0.0, "y")
    assert not p and list(p.pairs()) == [("y", {}, [])]


@pytest.mark.parametrize("max_hold, want", [(0.03, "held"), (0.01, "stale")])
def test_grid_holds_by_the_same_rule(max_hold: float, want: str) -> None:
    """A slower input on the grid: held while at most max_hold old, else a gap (stale)."""
    ts = 0.01
    g = GridSampler({"y": ("y",), "u": ("u",)}, "y", ts, {"y": True, "u": True},
                    {"u": max_hold}, wait=0.05)
    ns = round(ts * 1e9)
    for k in range(20):
        g.put("y", k * ns, k * ns, {"y": float(k)})
        if k % 3 == 0:                              # u every third sample
            g.put("u", k * ns, k * ns, {"u": 10.0 * k})
    events = g.ready(final=True)
    samples = {e.k: e for e in events if isinstance(e, GridSample)}
    gaps = [e for e in events if isinstance(e, Gap)]
    if want == "held":
        assert not gaps
        s = next(s for s in samples.values() if s.held)
        assert s.held == ("u",) and s.values["u"] == 10.0 * (s.k - s.k % 3)
    else:
        assert gaps and all(g.reason == "stale" and g.channel == "u" for g in gaps)
