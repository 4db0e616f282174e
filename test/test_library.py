"""The bag library: spec, reproducible bags, honest expectations (checked against the truth)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from bag_compare import SIM_RTOL, assert_bags_close

from fd_monitor.analysis.expectations import check_expected, check_truth
from fd_monitor.analysis.generate import generate_bag
from fd_monitor.analysis.library import LibraryError, load_expected, load_library
from fd_monitor.analysis.offline import read_inputs
from fd_monitor.model.scenario import load_scenario
from fd_monitor.wire.bag_reader import read_bag
from fd_monitor.wire.bag_scanner import read_raw

LIB = load_library()


def _system(spec):
    """The system that wrote the bag's truth: the scenario's (its plant plus the fault
    channels a scenario may add, e.g. Farhat & Koenig's f)."""
    return load_scenario(spec.scenario).system


def test_library_lists_the_required_bags():
    names = set(LIB.names)
    assert {"three_tank_nominal", "three_tank_bias_h1", "three_tank_bias_h2",
            "three_tank_incipient_h3", "three_tank_valve", "three_tank_bad_input",
            "pwa_cascade_nominal", "pwa_cascade_b1_step"} <= names
    kinds = {c.kind for b in LIB.bags for c in b.corruptions}
    assert kinds == {"nan", "wrong_length", "gap", "duplicate", "out_of_order"}


def test_every_shipped_gain_file_has_a_bag():
    """Issue 23: each gain file of config/gains/ is exercised by at least one library bag (so
    the regression suite runs every shipped gain file through `analyze`)."""

    gains = Path(__file__).resolve().parent.parent / "config" / "gains"
    shipped = {p.stem for p in gains.glob("*.yaml")}
    assert shipped <= {Path(b.gains).stem for b in LIB.bags}, \
        sorted(shipped - {Path(b.gains).stem for b in LIB.bags})


def test_library_is_small():
    total = sum(f.stat().st_size for b in LIB.bags for f in b.folder.iterdir())
    # 5.9 MB with a bag for every shipped gain file (17 bags, each below 0.6 MB); the
    # three_tank_envelope bag adds ~0.3 MB
    assert total < 6_500_000, f"bag library is {total / 1e6:.2f} MB (limit 6.5 MB)"
    assert all(f.stat().st_size < 600_000 for b in LIB.bags for f in b.folder.iterdir())


@pytest.mark.parametrize("name", LIB.names)
def test_expectations_agree_with_truth(name):
    """No alarm expected before the onset, the faulty channel isolated, true biases/modes."""
    spec = LIB[name]
    assert (spec.folder / "metadata.yaml").is_file()
    exp = load_expected(spec.expected_file)
    assert check_truth(spec, exp, _system(spec)) == []
    # only the detect-only method (one channel ||r||, no isolation) leaves `isolated` out
    assert ("isolated" in exp) != (spec.gains == "farhat_koenig_hminus_switched")


def test_bags_regenerate_within_rounding(tmp_path):
    """Same spec (scenario, seed, duration, corruptions) -> the shipped bag: metadata byte for
    byte, every record (the corrupted ones too: NaN, wrong length, gap, duplicate, order) at
    its place with its layout and stamp, values within bag_compare.SIM_RTOL (the shipped bag
    was simulated on another machine; see there)."""
    spec = LIB["three_tank_bad_input"]
    out = generate_bag(spec, tmp_path / "again")
    assert (out / "metadata.yaml").read_bytes() == (spec.folder / "metadata.yaml").read_bytes()
    assert_bags_close(out, spec.folder)


def test_bag_comparison_tells_rounding_from_a_change(tmp_path):
    """bag_compare.assert_bags_close, used on every regenerated bag, passes a copy whose
    values moved by rounding (1e-13 of the scale) and fails on a change of 1e-6 of it, on a
    moved stamp and on a changed label."""
    from dataclasses import replace

    from fd_monitor.wire.bag_writer import write_bag

    spec = LIB["three_tank_valve"]
    src = read_bag(spec.folder)
    order = ["/plant/u", "/plant/y", "/plant/truth"]
    assert sorted(src) == sorted(order)

    def copy(name, topic=None, **change):
        arrays = [replace(src[t], **change) if t == topic else src[t] for t in order]
        return write_bag(tmp_path / name, arrays)

    assert_bags_close(copy("same"), spec.folder)
    y = src["/plant/y"].values
    bump = np.zeros_like(y)
    bump[700, 1] = np.abs(y).max()
    assert_bags_close(copy("rounding", "/plant/y", values=y + 1e-13 * bump), spec.folder)
    with pytest.raises(AssertionError, match=r"record \d+ \(/plant/y\): \|got - want\|"):
        assert_bags_close(copy("change", "/plant/y", values=y + 1e-6 * bump), spec.folder)
    st = src["/plant/y"].stamps.copy()
    st[700] += 1
    with pytest.raises(AssertionError, match="stamp differs"):
        assert_bags_close(copy("stamp", "/plant/y", stamps=st), spec.folder)
    labels = ("h1", "h2", "h3x")
    assert src["/plant/y"].labels != labels and len(src["/plant/y"].labels) == 3
    with pytest.raises(AssertionError, match="layout differs"):
        assert_bags_close(copy("label", "/plant/y", labels=labels), spec.folder)


def test_regenerated_arrays_equal_the_simulator(tmp_path):
    """A library bag holds exactly what `simulate` writes for its scenario and seed."""
    from fd_monitor.commands.simulate import simulate_to_bag

    spec = LIB["three_tank_valve"]
    simulate_to_bag(spec.scenario, tmp_path / "sim", seed=spec.seed, duration=spec.duration)
    a, b = read_bag(spec.folder), read_bag(tmp_path / "sim")
    for t in ("/plant/u", "/plant/y", "/plant/truth"):
        assert a[t].labels == b[t].labels
        np.testing.assert_array_equal(a[t].stamps, b[t].stamps)
        # simulated here vs on the machine that shipped it: rounding only (SIM_RTOL)
        np.testing.assert_allclose(b[t].values, a[t].values, rtol=0,
                                   atol=SIM_RTOL * np.abs(a[t].values).max())


def test_bad_input_bag_holds_its_corruptions():
    spec = LIB["three_tank_bad_input"]
    system = _system(spec)
    n_y = sum(1 for _ in read_raw(spec.folder, ["/plant/y"]))
    assert n_y == 1500 - 50 + 1       # the gap removes 50 messages, the duplicate adds one
    s, rep = read_inputs(spec.folder, system)
    ys, us = set(s.k.tolist()), set(s.k.tolist())
    kinds = rep.by_kind()
    assert kinds["non_finite"] == [300, 301]
    assert kinds["wrong_length"] == [450]
    assert kinds["duplicate"] == [900]
    assert kinds["out_of_order"] == [1100]
    assert kinds["missing"] == [[700, 749]]
    assert 1100 in ys and 1101 in ys and 300 not in ys and 700 not in us


def test_spec_errors_name_file_and_key(tmp_path):
    p = tmp_path / "library.yaml"
    p.write_text("bags:\n  - {name: a, scenario: x, seed: 1, duration: 1.0, gains: g,\n"
                 "     corruptions: [{kind: scramble, samples: [1]}]}\n")
    with pytest.raises(LibraryError, match=r"bags\[0\]\.corruptions\[0\]\.kind"):
        load_library(p)
    p.write_text("bags:\n  - {name: a, scenario: x, seed: -1, duration: 1.0, gains: g}\n")
    with pytest.raises(LibraryError, match=r"bags\[0\]\.seed: expected an integer >= 0"):
        load_library(p)
    with pytest.raises(LibraryError, match="not found"):
        load_library(tmp_path / "nope.yaml")
    p.write_text("bags:\n  - {name: a, scenario: x, seed: 1, duration: 1.0, gains: g}\n")
    with pytest.raises(LibraryError, match=r"bags\[0\]\.gains: expected a gain file \(g: "
                                           r"unknown gain file"):
        load_library(p)


def test_check_expected_reports_each_kind_of_failure():
    exp = {"fault_onset_sample": 100, "alarms": {"h1": {"first_sample": 100, "tolerance": 5}},
           "no_alarm": ["h2"], "isolated": ["h1"],
           "bias_estimate": {"h1": {"value": 0.03, "tolerance": 0.003}},
           "modes": ["a", "b"], "input_errors": {"non_finite": [3]}, "restarts": [4]}
    good = {"alarms": [{"channel": "h1", "first_sample": 103}], "isolated": ["h1"],
            "bias_estimate": {"h1": 0.031}, "modes": ["a", "b"],
            "input_errors": {"non_finite": [3]}, "restarts": [4]}
    assert check_expected(exp, good) == []
    bad = {"alarms": [{"channel": "h1", "first_sample": 120},
                      {"channel": "h2", "first_sample": 50}],
           "isolated": [], "bias_estimate": {"h1": 0.02}, "modes": ["a"],
           "input_errors": {"non_finite": [3], "duplicate": [7]}, "restarts": []}
    fails = check_expected(exp, bad)
    text = "\n".join(fails)
    for part in ("before the fault onset", "alarms.h1", "no_alarm: channel h2", "isolated",
                 "bias_estimate.h1", "modes", "input_errors.duplicate", "restarts"):
        assert part in text, part


def test_mode_min_dwell_drops_chatter_only():
    from fd_monitor.analysis.summary import settled_modes

    segs = [["q2", 0, 1], ["q0", 1, 2000], ["q1", 2001, 2], ["q0", 2003, 3],
            ["q1", 2006, 500]]
    assert settled_modes(segs, 20) == ["q2", "q0", "q1"]
    assert settled_modes(segs, 1) == ["q2", "q0", "q1", "q0", "q1"]
