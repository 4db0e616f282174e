"""Plausibility limits (issue 12 item 2): implausible samples never reach the runtime state.

y = 1e300 is finite, so it passed every NaN/Inf check and ruined sigma-hat for good. Now it
is refused where samples enter the runtime (core/plausibility.py), reported like a NaN
message, and the good samples after it are processed normally, with no alarm.
"""

from __future__ import annotations

import numpy as np
import pytest

from fd_monitor.analysis.offline import InputReport, run_bag, run_thresholds
from fd_monitor.analysis.summary import summarize_run
from fd_monitor.core.methods import load_gains
from fd_monitor.core.monitor import Monitor
from fd_monitor.core.plausibility import PREDICTION_FACTOR, Plausibility
from fd_monitor.core.simulator import simulate
from fd_monitor.model.errors import MessageError
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system
from fd_monitor.wire.join import StampJoin

K = 600  # 60 s of three_tank_nominal


@pytest.fixture(scope="module")
def plant():
    sys_ = load_system("three_tank")
    return sys_, load_gains("three_tank_thresholds", sys_), simulate(
        load_scenario("three_tank_nominal"), 1, K)


def test_core_step_refuses_1e300_and_keeps_its_state(plant):
    sys_, g, tr = plant
    u, y = tr.u[0], tr.y[0]
    clean, hit = Monitor(sys_, g), Monitor(sys_, g)
    for k in range(K):
        if k == 300:
            with pytest.raises(MessageError, match=r"y at sample 300: h2 = 1e\+300 outside "
                                                   r"the physical range.*implausible"):
                hit.step(k, u[k], [y[k, 0], 1e300, y[k, 2]])
        a, b = clean.step(k, u[k], y[k]), hit.step(k, u[k], y[k])
        # Nothing of the refused sample reached any state: bit-identical to a clean run.
        assert np.array_equal(a.detector.residual, b.detector.residual)
        assert np.array_equal(a.sigma_hat, b.sigma_hat)
    assert not b.alarm.any() and np.all(np.abs(b.sigma_hat) < 1e-3)


def test_input_outside_limits_refused(plant):
    sys_, g, tr = plant
    mon = Monitor(sys_, g)
    with pytest.raises(MessageError, match=r"u at sample 0: q1 = 5\.0 outside .*implausible"):
        mon.step(0, [5.0, 0.0, 0.0], tr.y[0, 0])


def test_offline_run_reports_it_and_recovers_without_alarm(plant):
    sys_, g, tr = plant
    us = {k: tr.u[0, k] for k in range(K)}
    ys = {k: tr.y[0, k].copy() for k in range(K)}
    ys[300] = np.array([1e300, ys[300][1], ys[300][2]])
    rep = InputReport()
    out = run_thresholds(sys_, g, list(range(K)), us, ys, rep)
    assert [(e["kind"], e["sample"]) for e in rep.errors] == [("implausible", 300)]
    assert rep.restarts == [] and rep.bridges == [301]   # one lost sample: bridged
    assert 300 not in out["k"] and len(out["k"]) == K - 1
    assert not out["alarm"].any()                       # later good samples: no alarm
    assert max(np.max(np.abs(v)) for v in out["estimate"].values()) < 1e-3


def test_flipped_bit_in_a_bag_is_an_input_error(plant, tmp_path):
    from fd_monitor.wire.bag_reader import arrays_from
    from fd_monitor.wire.bag_writer import write_bag

    sys_, _g, tr = plant
    y = tr.y[0].copy()
    y[250, 0] = 3.5e307                                  # one flipped exponent bit
    ns = tr.k * 100_000_000
    bag = write_bag(tmp_path / "flip", [
        arrays_from("/plant/u", sys_.inputs, tr.k, tr.u[0], ns),
        arrays_from("/plant/y", sys_.outputs, tr.k, y, ns)])
    s = summarize_run(run_bag(bag, "three_tank_thresholds", system=sys_))
    assert s["input_errors"] == {"implausible": [250]}
    assert s["alarms"] == [] and s["restarts"] == [] and s["bridges"] == [251]
    assert s["samples"] == K - 1


def test_prediction_test_factor_on_the_noise_bound():
    sys_ = load_system("three_tank")
    p = Plausibility(sys_, factor=10.0)                  # 10 x 1 mm
    pred = np.array([0.4, 0.2, 0.3])
    p.check(0, np.zeros(3), pred + 0.0099, pred)
    with pytest.raises(MessageError, match=r"h1 = .* away from its prediction.*implausible"):
        p.check(0, np.zeros(3), pred + np.array([0.0101, 0, 0]), pred)
    # The stated factor: 1000 noise bounds (1 m for three_tank), far beyond the 1 cm faults.
    assert PREDICTION_FACTOR == 1000.0
    assert np.all(Plausibility(sys_).tolerance == 1.0)


def test_plant_without_limits_still_refuses_absurd_magnitudes():
    sys_ = load_system("pwa_cascade")                    # no limits, zero noise bound
    p = Plausibility(sys_)
    p.check(0, np.zeros(sys_.nu), [1e3, -1e3], [0.0, 0.0])
    with pytest.raises(MessageError, match="implausible"):
        p.check(0, np.zeros(sys_.nu), [0.0, 1e300])


def test_join_lost_sample_restarts_at_the_next():
    j = StampJoin(["y"], {"fb": 0.0})
    j.put("y", 0, 1.0)
    assert [s.k for s in j.ready()] == [0]
    j.put("y", 1, 2.0)
    j.put("fb", 1, 9.0)
    (s1,) = list(j.ready())
    j.lost(s1.k)                                         # the core refused sample 1
    j.put("y", 2, 3.0)                                   # no feedback for 2: a restart
    (s2,) = list(j.ready())
    assert (s2.k, s2.restart, s2.inputs["fb"]) == (2, True, 0.0)
