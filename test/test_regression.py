"""Regression suite: every library bag analysed offline matches its expected.yaml.

Every bag goes through ``analyze``'s offline run
(:func:`fd_monitor.analysis.expectations.analyze_summary`
calls :func:`fd_monitor.analysis.offline.run_bag`: the gain file's runtime from the registry of
:mod:`fd_monitor.core.runtime`, whatever its method). A test shows that a threshold 20 %
higher in the gain file makes the suite fail.
"""

from __future__ import annotations

import subprocess
import sys

import pytest
import yaml

from fd_monitor.analysis.expectations import analyze_summary, check_expected
from fd_monitor.analysis.library import load_expected, load_library
from fd_monitor.commands.analyze import analyze_bag
from fd_monitor.core.methods import load_gains
from fd_monitor.model.errors import GainFileError
from fd_monitor.model.gains import write_gain_doc
from fd_monitor.model.paths import find_config_file

LIB = load_library()
ANALYZED_BAGS = [b.name for b in LIB.bags]


def test_every_method_of_the_library_is_analyzed():
    """The library holds a bag of every runtime's method, and every bag is analysed."""
    methods = {load_gains(b.gains, verify=False).method for b in LIB.bags}
    assert methods == {"thresholds", "qb", "hinf_sc", "hminus_switched"}
    assert len(ANALYZED_BAGS) >= 12


@pytest.mark.parametrize("name", ANALYZED_BAGS)
def test_bag_matches_expected(name):
    spec = LIB[name]
    summary = analyze_summary(spec.folder, spec.gains, transient=spec.transient)
    assert check_expected(load_expected(spec.expected_file), summary) == []


@pytest.mark.parametrize("name", ["three_tank_bias_h1", "three_tank_nominal"])
def test_library_summary_is_analyze(name):
    """On a clean bag the regression summary is exactly `analyze`'s (the CLI function)."""
    spec = LIB[name]
    doc = analyze_bag(str(spec.folder), spec.gains)
    s = analyze_summary(spec.folder, spec.gains)
    first = {}
    for a in doc["alarms"]:
        first.setdefault(a["channel"], a["first_sample"])
    assert {a["channel"]: a["first_sample"] for a in s["alarms"]} == first
    assert s["isolated"] == doc["isolated"]
    assert s["bias_estimate"] == doc["bias_estimate"]
    assert s["samples"] == doc["samples"]
    to = [t["to"] for t in doc["transitions_estimated"]]
    assert s["modes"][1:] == to


def _scaled_gains(tmp_path, factor):
    """The shipped three_tank gain file with every threshold term multiplied by ``factor``.

    The threshold in force is ``max_q noise_l1 + H_p_bar[eta_bar + remainder_bar]``
    (:mod:`fd_monitor.core.thresholds`), so scaling those (and r_bar, r_bar_star, which the
    certificate compares with them) scales R_k by exactly ``factor``.
    """
    src = find_config_file("three_tank_thresholds", "gains", GainFileError)
    doc = yaml.safe_load(src.read_text())
    res = doc["results"]
    for key in ("noise_l1", "eta_bar", "remainder_bar", "r_bar"):
        res[key] = [[v * factor for v in row] for row in res[key]]
    for row in res["agei"]["rows"]:
        row["r_bar_star"] = [v * factor for v in row["r_bar_star"]]
    out = tmp_path / f"three_tank_thresholds_x{factor}.yaml"
    write_gain_doc(out, doc)  # as a designer would write it (a hand edit is refused)
    return out


def test_suite_fails_with_thresholds_20_percent_higher(tmp_path):
    """Thresholds x1.2 still pass the certificate but change a detection: the suite fails."""
    from fd_monitor.model.system import load_system

    gains = _scaled_gains(tmp_path, 1.2)
    assert load_gains(gains, load_system("three_tank")).certificate_status == "verified"
    failures = {}
    for spec in LIB.bags:
        if spec.gains != "three_tank_thresholds":
            continue
        fails = check_expected(load_expected(spec.expected_file),
                               analyze_summary(spec.folder, str(gains)))
        if fails:
            failures[spec.name] = fails
    assert failures, "no expectation noticed thresholds 20 % higher"
    assert "three_tank_incipient_h3" in failures


def test_thresholds_20_percent_lower_are_refused(tmp_path):
    """Thresholds x0.8 fall below the recomputed noise bound: the certificate refuses them."""
    from fd_monitor.model.system import load_system

    gains = _scaled_gains(tmp_path, 0.8)
    with pytest.raises(GainFileError, match="certificate does not hold"):
        load_gains(gains, load_system("three_tank"))


def test_analyze_cli_on_a_library_bag():
    spec = LIB["three_tank_bias_h2"]
    out = subprocess.run([sys.executable, "-m", "fd_monitor", "analyze", str(spec.folder),
                          "--gains", spec.gains, "--json"], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    doc = yaml.safe_load(out.stdout)
    assert doc["isolated"] == ["h2"]
    assert doc["alarms"][0]["channel"] == "h2"
