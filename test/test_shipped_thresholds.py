"""Thresholds of the thesis 5.3 / 6.5 banks and of the Farhat & Koenig observer (issue 10):
each gain file's threshold comes from its design file (provenance re-computed here), a
fault-free run raises no alarm after the settling time, and the faults of the papers'
simulations alarm on the right channel within a stated delay (the runtime of
:func:`fd_monitor.core.methods.runtime_for` on simulated runs, as nodes and ``analyze`` run it).

Delays measured on these runs: thesis 5.3 r1 0.01 s after f1 (30 s), r2 0.03 s after f2
(60 s); thesis 6.5 0.01 s for both; Farhat & Koenig the fault sample itself (300).

Last, thesis 5.3, 6.5, 7.1 and Farhat & Koenig go through ``simulate`` -> bag -> ``analyze``
-> ``report`` with the CLI, as the other plants do."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from bag_compare import assert_bags_close

pytest.importorskip("cvxpy")

from fd_monitor.analysis.library import load_expected, load_library
from fd_monitor.core.methods import load_gains, runtime_for
from fd_monitor.core.simulator import simulate, simulate_batch
from fd_monitor.design import hinf_sc, hminus_switched
from fd_monitor.design._lmi_common import load_design_section
from fd_monitor.design.hinf_thresholds import bound_thresholds
from fd_monitor.model.errors import DesignError
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system

LIB = load_library()
#: stated detection delays (s): the first alarm of the faulty generator is at most this late
DELAY_S = 0.1


def _run(system, gf, tr, i=0):
    """The gain file's runtime on run i of a trajectory, side signals from the truth (rho
    for an LPV bank without a scheduling map, the mode for a switched plant)."""
    rt = runtime_for(system, gf)
    side = {}
    if "rho" in rt.side_inputs:
        side["rho"] = tr.rho[i]
    if "mode" in rt.side_inputs:
        side["mode"] = tr.mode[i]
    return rt.run(np.arange(tr.y.shape[1]), tr.u[i], tr.y[i], side or None)


# --------------------------------------------------------------------------------------
# provenance: the shipped thresholds are what the design files give


def test_thesis_6_5_thresholds_are_the_bound_4_17_of_its_design_file():
    s = load_system("thesis_6_5")
    gf = load_gains("thesis_6_5_hinf_sc", s)
    tm = gf.results["threshold_method"]
    assert tm == {"method": "bound", "levels": {"nuisance": 1.0}, "margin": 3.0}
    sec, _origin, _sha = load_design_section(s, "hinf_sc")
    assert dict(sec["thresholds"]) == {"method": "bound", "levels": {"nuisance": 1.0},
                                       "margin": 3.0}
    J = np.asarray(gf.results["thresholds"])
    np.testing.assert_allclose(J, bound_thresholds(gf.results, {"nuisance": 1.0}, 3.0),
                               rtol=1e-12)
    # J_i = 3 gamma_i: the nuisance fault at level 1 is the only unknown input (rho measured)
    g = [np.sqrt(x["gamma2"]["nuisance"]) for x in gf.results["generators"]]
    np.testing.assert_allclose(J, 3.0 * np.asarray(g), rtol=1e-12)


@pytest.mark.parametrize("name, method", [
    ("thesis_5_3", "hinf_sc"),
    pytest.param("farhat_koenig", "hminus_switched", marks=pytest.mark.slow)])  # ~20 s
def test_monte_carlo_thresholds_are_reproduced_from_the_design_file(name, method,
                                                                   shipped_design):
    """Re-designing from the design file gives the shipped thresholds, within what the SDP
    solver's accuracy lets another machine differ (the Monte Carlo runs are seeded: the same
    noise everywhere; only the gains and bounds move).

    J_i = margin (max ||r_i|| of the fault-free runs + gamma_i x level): gamma_i and the gains
    are Clarabel's answers, correct to its stopping tolerances (1e-8 on gap and feasibility);
    thesis 5.3's gamma_1 (~7.6e-6) lies near that resolution. Another machine's rounding can
    make the solver stop an iteration earlier or later, so the answers may differ by up to
    the defaults' distance to the optimum, measured here by re-solving with the tolerances at
    1e-10: J_1 moves by 7.6e-3, J_2 by 4.7e-6 (relative; two machines differed by 5.4e-4 on
    J_1, issue 23). The tolerance is twice that (both sides carry it): 2e-2 and 1e-5. A
    changed margin, level, settling time or scenario moves them by far more. Farhat &
    Koenig's thresholds (Monte Carlo maxima over 200 runs of the H-minus observer) move with
    its gains as thesis 5.3's J_2 does: 1e-5 too."""
    s = load_system(name)
    gf = load_gains(f"{name}_{method}", s)
    out = shipped_design(name, method)         # design(s, the design file's section)
    assert out["results"]["threshold_method"] == gf.results["threshold_method"]
    assert gf.results["threshold_method"]["method"] == "monte_carlo"
    if method == "hinf_sc":
        got, want = out["results"]["thresholds"], gf.results["thresholds"]
    else:
        got = [o["threshold"] for o in out["results"]["observers"].values()]
        want = [o["threshold"] for o in gf.results["observers"].values()]
    rtols = [2e-2, 1e-5] if name == "thesis_5_3" else [1e-5] * len(want)
    for i, (g, w, rtol) in enumerate(zip(got, want, rtols, strict=True)):
        np.testing.assert_allclose(g, w, rtol=rtol, err_msg=f"threshold {i + 1}")
    assert np.all(np.isfinite(want)) and np.all(np.asarray(want) > 0)


def test_thesis_5_3_threshold_is_monte_carlo_plus_the_nuisance_bound():
    """J_i = margin (max ||r_i|| of the fault-free run after 5 s + gamma_i x 1): the
    uncertainty term dominates r2 (~0.011 x 1.5), the nuisance bound r1 (r1's fault-free
    residual is ~1e-10: the uncertainty does not reach it, 5.65 F_a1 = 0)."""
    s = load_system("thesis_5_3")
    gf = load_gains("thesis_5_3_hinf_sc", s)
    tm = gf.results["threshold_method"]
    assert tm["settle_s"] == 5.0 and tm["margin"] == 1.5 and tm["levels"] == {"nuisance": 1.0}
    tr = simulate(load_scenario(tm["scenario"]))
    assert not tr.faults.any()
    r = _run(s, gf, tr).residual
    k0 = round(tm["settle_s"] / s.sample_time)
    g = np.array([np.sqrt(x["gamma2"]["nuisance"]) for x in gf.results["generators"]])
    np.testing.assert_allclose(gf.results["thresholds"], 1.5 * (r[k0:].max(axis=0) + g),
                               rtol=1e-9)
    J = np.asarray(gf.results["thresholds"])
    assert J[1] > 0.01                         # the uncertainty's residual on r2
    assert J[0] < 1e-4                         # r1: the nuisance bound, far below the fault


# --------------------------------------------------------------------------------------
# fault free: no alarm after the settling time; faults: the right channel, in time


@pytest.mark.parametrize("name", ["thesis_5_3", "thesis_6_5"])
def test_thesis_banks_fault_free_no_alarm_and_overlapping_faults_isolated(name, scenario_run):
    s = load_system(name)
    gf = load_gains(f"{name}_hinf_sc", s)
    sc = load_scenario(f"{name}_overlap")
    f1, f2 = sc.faults
    # fault free (the scenario without its faults): no alarm once armed
    tr = simulate(replace(sc, faults=()))
    ff = _run(s, gf, tr)
    assert np.isfinite(ff.threshold[-1]).all()
    assert not ff.alarm.any()
    # both faults (thesis Fig. 5.5 / 6.4): r1 from f1 at 30 s, r2 from f2 at 60 s, isolated
    tr = scenario_run(f"{name}_overlap")         # simulate(sc)
    out = _run(s, gf, tr)
    t = tr.t
    first = [t[np.flatnonzero(out.alarm[:, j])[0]] for j in range(2)]
    assert f1.time < first[0] <= f1.time + DELAY_S
    assert f2.time < first[1] <= f2.time + DELAY_S
    assert out.alarm[t >= first[0], 0].all()   # r1 stays up (f1 persists, f2 does not mask)
    assert out.alarm[t >= first[1], 1].all()
    # f2 alone: r2 alarms, r1 never (the nuisance bound in J_1 keeps the isolation)
    tr = simulate(replace(sc, faults=(f2,)))
    only2 = _run(s, gf, tr)
    assert not only2.alarm[:, 0].any()
    k2 = np.flatnonzero(only2.alarm[:, 1])[0]
    assert f2.time < tr.t[k2] <= f2.time + DELAY_S


def test_farhat_koenig_fault_free_random_switching_no_alarm_after_settling():
    """Fifty runs the threshold design did not see (seeds 1000-1049; it used 100-299):
    random switching, no alarm once armed (25 s after the start). (`evaluate` on 2,000
    such runs, seeds 1000-2999: 0 false alarms; see doc/theory/hinf.md.)"""
    s = load_system("farhat_koenig")
    gf = load_gains("farhat_koenig_hminus_switched", s)
    sc = load_scenario("farhat_koenig_nominal")
    tm = gf.results["threshold_method"]
    assert tm["scenario"] == sc.name and sc.seed == 100 and tm["runs"] == 200
    assert tm["settle_s"] == 25.0
    tr = simulate_batch(sc, list(range(1000, 1050)))
    for i in range(50):
        out = _run(s, gf, tr, i)
        assert not out.alarm.any(), i
        assert np.isinf(out.threshold[:250]).all()          # not armed during settling
        assert np.isfinite(out.threshold[250:]).all()


def test_farhat_koenig_fault_alarms_at_its_onset():
    """The library bag's scenario: f = 1 from 30 s (sample 300) alarms at once and stays."""
    s = load_system("farhat_koenig")
    gf = load_gains("farhat_koenig_hminus_switched", s)
    tr = simulate(load_scenario("bag_farhat_koenig_fault"))
    out = _run(s, gf, tr)
    a = np.flatnonzero(out.alarm[:, 0])
    assert a[0] == 300 and a.size == tr.y.shape[1] - 300
    # the stability-only observer has its own threshold (design stability)
    st = runtime_for(s, gf, design="stability")
    thr = gf.results["observers"]["stability"]["threshold"]
    assert st.observer.threshold == thr != gf.results["observers"]["hminus"]["threshold"]


def test_hminus_threshold_section_errors_are_one_line():
    s = load_system("farhat_koenig")
    sec, origin, sha = load_design_section(s, "hminus_switched")
    bad = dict(sec, threshold={"method": "bound"})
    with pytest.raises(DesignError, match=r"hminus_switched\.threshold\.method: expected "
                                          r"none or monte_carlo"):
        hminus_switched.design(s, bad, origin, sha)
    bad = dict(sec, threshold={"method": "monte_carlo", "scenario": "bag_farhat_koenig_fault"})
    with pytest.raises(DesignError, match=r"threshold\.scenario: expected a fault-free"):
        hminus_switched.design(s, bad, origin, sha)
    bad = dict(sec, threshold={"method": "monte_carlo", "scenario": "farhat_koenig_nominal",
                               "settle": 100.0})
    with pytest.raises(DesignError, match=r"threshold\.settle: expected less than"):
        hminus_switched.design(s, bad, origin, sha)


def test_hinf_monte_carlo_threshold_refuses_a_faulty_scenario():
    """Monte Carlo thresholds come from fault-free runs (hinf_sc and hminus_switched share
    the check: design/hinf_thresholds.fault_free_scenario)."""
    s = load_system("thesis_5_3")
    sec, origin, sha = load_design_section(s, "hinf_sc")
    bad = dict(sec, thresholds=dict(sec["thresholds"], scenario="bag_thesis_5_3_overlap"))
    with pytest.raises(DesignError, match=r"hinf_sc\.thresholds\.scenario: expected a "
                                          r"fault-free scenario"):
        hinf_sc.design(s, bad, origin, sha)


# --------------------------------------------------------------------------------------
# simulate -> bag -> analyze -> report, as for the other plants (issue 10, item 5)


def _cli(*args):
    out = subprocess.run([sys.executable, "-m", "fd_monitor", *args], capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


@pytest.mark.parametrize("name", ["thesis_5_3_overlap", "thesis_6_5_overlap", "f16xl_overlap",
                                  "farhat_koenig_fault"])
def test_thesis_and_switched_plants_through_simulate_analyze_report(tmp_path, name):
    """Thesis 5.3, 6.5, 7.1 (F16XL) and Farhat & Koenig with the commands a user runs:
    `simulate` writes the library bag (values within rounding), `analyze` alarms on every
    faulty channel after its onset, `report` writes its figures and finds the library's
    expectations hold."""
    spec = LIB[name]
    bag = tmp_path / name                # expected.yaml names its bag folder
    doc = _cli("simulate", spec.scenario, "--seed", str(spec.seed), "--duration",
               str(spec.duration), "-o", str(bag), "--json")
    assert doc["samples"] == round(spec.duration / doc["sample_time"])
    # the library bag's messages, within rounding (made on another machine: bag_compare)
    assert_bags_close(bag / f"{name}.mcap", spec.folder / f"{name}.mcap")
    exp = load_expected(spec.expected_file)
    an = _cli("analyze", str(bag), "--gains", spec.gains, "--json")
    first = {}
    for ep in an["alarms"]:
        first.setdefault(ep["channel"], ep["first_sample"])
    assert sorted(first) == sorted(exp["alarms"])
    for ch, a in exp["alarms"].items():
        assert exp["fault_onset_sample"] <= first[ch] <= a["first_sample"] + a["tolerance"]
    shutil.copy(spec.expected_file, bag / "expected.yaml")
    rep = _cli("report", str(bag), "-o", str(tmp_path / "rep"), "--json")
    assert rep["expected"] == "ok"
    assert {"residuals", "modes"} <= set(rep["figures"])
    for p in rep["figures"].values():
        assert Path(p).stat().st_size > 10_000
    assert "All expectations hold." in (tmp_path / "rep" / "summary.md").read_text()


def test_design_cli_prints_the_thresholds_and_their_method(tmp_path):
    doc = _cli("design", "hinf_sc", "thesis_6_5", "-o", str(tmp_path / "g.yaml"), "--json")
    assert doc["threshold_method"] == {"method": "bound", "levels": {"nuisance": 1.0},
                                       "margin": 3.0}
    shipped = load_gains("thesis_6_5_hinf_sc", load_system("thesis_6_5"))
    # J_i = 3 gamma_i from the SDP (see test_monte_carlo_thresholds_are_reproduced_...):
    # re-solved with Clarabel's tolerances at 1e-10 instead of 1e-8, J_1 moves by 1.4e-4 and
    # J_2 by 8.1e-2 (its SDP stops with gamma_2^2 18 % above the optimum): twice that
    for i, (g, w, rtol) in enumerate(zip(doc["thresholds"], shipped.results["thresholds"],
                                         [3e-4, 0.17], strict=True)):
        np.testing.assert_allclose(g, w, rtol=rtol, err_msg=f"threshold {i + 1}")
    out = subprocess.run([sys.executable, "-m", "fd_monitor", "design", "hinf_sc", "thesis_6_5",
                          "-o", str(tmp_path / "g2.yaml")], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert "threshold (bound)" in out.stdout
    assert f"{doc['thresholds'][0]:.4g}" in out.stdout      # this machine's design, printed
