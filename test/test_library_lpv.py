"""The library bags of the hinf_sc and hminus_switched gain files, checked independently of
`analyze` (which does not run these methods in this version): regeneration (values within
rounding),
sample counts, truth columns (rho, mode, faults at their onsets), noise within the plant's
bounds, and expected.yaml against the method's core runtime and the truth."""

from __future__ import annotations

import numpy as np
import pytest
from bag_compare import assert_bags_close

from fd_monitor.analysis.expectations import check_expected, core_summary
from fd_monitor.analysis.generate import generate_bag
from fd_monitor.analysis.library import load_expected, load_library
from fd_monitor.analysis.summary import read_bag_truth, truth_facts
from fd_monitor.core.methods import load_gains
from fd_monitor.model.nonlinear import SCHEDULING_MAPS
from fd_monitor.model.scenario import load_scenario
from fd_monitor.wire.bag_reader import read_bag

LIB = load_library()
NEW = ["three_tank_lpv_leaks_abrupt", "three_tank_lpv_leaks_incipient", "f16xl_overlap",
       "farhat_koenig_fault", "thesis_5_3_overlap", "thesis_6_5_overlap", "thesis_4_7_overlap"]
#: fault -> onset sample (first non-zero truth sample), from the scenarios
ONSETS = {"three_tank_lpv_leaks_abrupt": {"leak1": 1000, "leak2": 1500, "leak3": 2000},
          "three_tank_lpv_leaks_incipient": {"leak1": 1001, "leak2": 1501, "leak3": 2001},
          "f16xl_overlap": {"f_delta": 500, "f_wg": 1200, "f_theta": 2000},
          "farhat_koenig_fault": {"f": 300},
          "thesis_5_3_overlap": {"f1": 700, "f2": 1200},
          "thesis_6_5_overlap": {"f1": 700, "f2": 1200},
          "thesis_4_7_overlap": {"f1": 700, "f2": 1200}}


def test_library_holds_the_new_bags_with_their_methods():
    methods = {n: load_gains(LIB[n].gains, verify=False).method for n in NEW}
    assert methods == {"three_tank_lpv_leaks_abrupt": "hinf_sc",
                       "three_tank_lpv_leaks_incipient": "hinf_sc",
                       "f16xl_overlap": "hinf_sc", "farhat_koenig_fault": "hminus_switched",
                       "thesis_5_3_overlap": "hinf_sc", "thesis_6_5_overlap": "hinf_sc",
                       "thesis_4_7_overlap": "hinf_sc"}


@pytest.mark.parametrize("name", NEW)
def test_bag_regenerates_within_rounding(tmp_path, name):
    """The library's spec regenerates the shipped bag: metadata (counts, topics, times) byte
    for byte, messages by decoded values within bag_compare.SIM_RTOL (another machine's
    rounding; see there)."""
    spec = LIB[name]
    out = generate_bag(spec, tmp_path / name)
    assert (out / "metadata.yaml").read_bytes() == (spec.folder / "metadata.yaml").read_bytes()
    assert_bags_close(out, spec.folder)
    assert (spec.folder / f"{name}.mcap").stat().st_size < 600_000


@pytest.mark.parametrize("name", NEW)
def test_sample_counts_and_truth_faults_at_their_onsets(name):
    spec = LIB[name]
    sc = load_scenario(spec.scenario)
    b = read_bag(spec.folder)
    K = round(spec.duration / sc.system.sample_time)
    for t in ("/plant/u", "/plant/y", "/plant/truth"):
        assert len(b[t]) == K, t
        np.testing.assert_array_equal(b[t].stamps, np.arange(K))
    facts = truth_facts(read_bag_truth(spec.folder), sc.system)
    assert {f: v["onset_sample"] for f, v in facts["faults"].items()} == ONSETS[name]
    tr = b["/plant/truth"]
    for ev in sc.faults:
        ch = sc.system.faults[ev.channel].name
        col = tr.column(f"f.{ch}")
        k0 = round(ev.time / sc.system.sample_time)
        assert not col[:k0].any()
        np.testing.assert_allclose(col[k0:], ev.beta(tr.stamps[k0:] * sc.system.sample_time,
                                                     sc.system.sample_time))


@pytest.mark.parametrize("name", ["three_tank_lpv_leaks_abrupt",
                                  "three_tank_lpv_leaks_incipient"])
def test_three_tank_truth_carries_rho_of_eq_7_19_and_noise_within_bounds(name):
    spec = LIB[name]
    sc = load_scenario(spec.scenario)
    b = read_bag(spec.folder)
    tr, y = b["/plant/truth"], b["/plant/y"]
    x = np.column_stack([tr.column(f"x.{s}") for s in sc.system.states])
    rho = np.column_stack([tr.column(f"rho.rho{i}") for i in (1, 2, 3)])
    want = np.array([SCHEDULING_MAPS["three_tank_sqrt"](xi, {"min_difference": 1e-3})
                     for xi in x])
    # the bag's rho was computed where the bag was made: a few correctly rounded operations
    # (difference, sqrt, division) on the same x, so equal to a few ulps on any machine
    np.testing.assert_allclose(rho, want, rtol=1e-14, atol=0)
    assert 1.5 < rho.min() and rho.max() < 4.0     # inside the design box (7.19 data)
    v = y.values - x                               # C = I, no sensor fault: y - x = noise
    bound = sc.system.measurement_noise
    assert (np.abs(v) <= bound).all()
    assert (np.abs(v).max(axis=0) > 0.9 * bound).all()   # uniform over the whole bound


def test_f16xl_truth_is_noise_free_with_the_sensor_bias():
    spec = LIB["f16xl_overlap"]
    b = read_bag(spec.folder)
    tr, y = b["/plant/truth"], b["/plant/y"]
    x = np.column_stack([tr.column(f"x.{s}") for s in ("x_u", "x_w", "x_q", "x_theta")])
    want = x.copy()
    want[:, 3] += tr.column("f.f_theta")          # y_theta += f_theta (sensor bias)
    np.testing.assert_array_equal(y.values, want)  # the plant file bounds no noise: none


def test_farhat_koenig_truth_mode_follows_the_schedule():
    spec = LIB["farhat_koenig_fault"]
    sc = load_scenario(spec.scenario)
    tr = read_bag(spec.folder, ["/plant/truth"])["/plant/truth"]
    t = tr.stamps * sc.system.sample_time
    want = np.zeros(len(tr))
    assert sc.switching is not None
    for tk, q in sc.switching:
        want[t >= tk - 1e-9] = q
    np.testing.assert_array_equal(tr.column("mode"), want)
    assert len(set(want)) == 2


@pytest.mark.parametrize("name", NEW)
def test_expected_agrees_with_the_core_runtime_and_the_truth(name):
    """expected.yaml: fault onset, isolated faults and modes are the truth; first alarms (the
    core runtime's) after the onset; and the runtime reproduces them today."""
    spec = LIB[name]
    exp = load_expected(spec.expected_file)
    assert exp["fault_onset_sample"] == min(ONSETS[name].values())
    summary = core_summary(spec)
    assert check_expected(exp, summary) == []
    if name != "farhat_koenig_fault":
        assert sorted(exp["isolated"]) == sorted(ONSETS[name])
        for f, a in exp["alarms"].items():
            assert ONSETS[name][f] <= a["first_sample"] <= ONSETS[name][f] + 60
    else:                                          # one detecting channel, no isolation
        assert "isolated" not in exp
        assert exp["alarms"] == {"r_norm": {"first_sample": ONSETS[name]["f"],
                                            "tolerance": 10}}


@pytest.mark.parametrize("name, measured", [("thesis_5_3_overlap", False),
                                            ("thesis_6_5_overlap", True)])
def test_thesis_bags_carry_rho_measured_only_for_the_lpv_plant(name, measured):
    """5.3: rho is uncertain (truth only); 6.5: rho is measured, on /plant/rho as on the
    truth; both noise free (y = C x exactly)."""
    spec = LIB[name]
    sc = load_scenario(spec.scenario)
    b = read_bag(spec.folder)
    tr, y = b["/plant/truth"], b["/plant/y"]
    names = [p.name for p in sc.system.lpv]
    rho = np.column_stack([tr.column(f"rho.{n}") for n in names])
    assert ("/plant/rho" in b) == measured
    if measured:
        np.testing.assert_array_equal(b["/plant/rho"].values, rho)
    assert np.abs(rho).max() <= 1.0 + 1e-12 and np.abs(rho).max() > 0.99
    x = np.column_stack([tr.column(f"x.{s}") for s in sc.system.states])
    np.testing.assert_allclose(y.values, x @ sc.system.modes[0].C.T, rtol=0, atol=1e-12)
