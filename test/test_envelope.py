"""Declared operating envelope (issue 13): the interval bound of the remainder, the certified
region in the gain file, and the runtime saying where its guarantee holds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fd_monitor.commands.analyze import analyze_arrays
from fd_monitor.core.envelope import CertifiedRegion, describe_excess
from fd_monitor.core.methods import load_gains
from fd_monitor.core.plant import SampledPlant
from fd_monitor.core.simulator import simulate
from fd_monitor.design.envelope import jacobian_centre, remainder_bound
from fd_monitor.model.errors import SystemFileError
from fd_monitor.model.scenario import parse_scenario
from fd_monitor.model.system import load_system, parse_system
from fd_monitor.model.yaml_io import read_yaml

U_LO, U_HI = np.array([0.0, 0.0, 0.0]), np.array([1.5e-4, 1.5e-4, 1.0])


def _sampled_remainder(plant, q, A, lo, hi, v_bar, M, rng):
    x = rng.uniform(lo, hi, (M, 3))
    u = rng.uniform(U_LO, U_HI, (M, 3))
    v = np.where(rng.random((M, 1)) < 0.5, rng.choice([-1.0, 1.0], (M, 3)),
                 rng.uniform(-1, 1, (M, 3))) * v_bar
    qq = np.full(M, q)
    return np.abs(plant.step(qq, x + v, u) - plant.step(qq, x, u) - v @ A.T).max(axis=0)


@pytest.mark.parametrize("lo,hi", [((0.30, 0.10, 0.20), (0.36, 0.16, 0.26)),
                                   ((0.0, 0.0, 0.0), (0.7, 0.7, 0.7)),
                                   ((0.33, 0.33, 0.33), (0.37, 0.37, 0.37))])
def test_interval_bound_dominates_every_sample(lo, hi):
    """rho_bar (interval arithmetic) >= |f(x+v) - f(x) - A v| at 300k points, every mode,
    including boxes with equal levels (sqrt singular) and the upper pipe's height."""
    system = load_system("three_tank")
    plant = SampledPlant(system)
    v_bar = system.measurement_noise
    lo, hi = np.array(lo), np.array(hi)
    rng = np.random.default_rng(3)
    for q in range(len(system.modes)):
        A = jacobian_centre(system, plant, q, lo, hi, U_LO, U_HI, v_bar, 0.02, np.eye(3))
        bound, how = remainder_bound(system, plant, q, A, lo, hi, U_LO, U_HI, v_bar,
                                     box_width=0.02, samples=0, margin=0.0, rng=rng)
        assert how["method"] == "interval" and how["boxes"] >= 8
        seen = _sampled_remainder(plant, q, A, lo, hi, v_bar, 300000, rng)
        assert np.all(bound >= seen), (q, bound, seen)
        assert np.all(bound <= 20.0 * seen + 1e-6)   # and not uselessly loose


def test_linear_mode_remainder_is_exact_zero():
    system = load_system("pwa_cascade")
    plant = SampledPlant(system)
    n = system.n
    lo, hi = -np.ones(n), np.ones(n)
    A = jacobian_centre(system, plant, 0, lo, hi, -np.ones(system.nu), np.ones(system.nu),
                        np.ones(n) * 0.01, 0.1, np.eye(n))
    b, how = remainder_bound(system, plant, 0, A, lo, hi, -np.ones(system.nu),
                             np.ones(system.nu), np.ones(n) * 0.01, box_width=0.1, samples=10,
                             margin=0.0, rng=np.random.default_rng(0))
    assert how == {"method": "exact"} and np.all(b == 0.0)


def _with_envelope(env):
    data = read_yaml(Path(load_system("three_tank").source))
    data["envelope"] = env
    return parse_system(data, "tank.yaml")


def test_envelope_schema_and_identity():
    system = load_system("three_tank")
    assert system.envelope is not None
    np.testing.assert_array_equal(system.envelope.state_hi, np.full((4, 3), 0.7))
    # the envelope is not part of the plant's identity: gain files and bags stay valid
    data = read_yaml(Path(system.source))
    del data["envelope"]
    assert parse_system(data).sha256 == system.sha256
    narrowed = _with_envelope({"states": {"h1": [0, 0.7], "h2": [0, 0.7], "h3": [0, 0.7]},
                               "inputs": {"q1": [0, 1e-4], "q2": [0, 1e-4], "v13": [0, 1]},
                               "modes": {"closed_dry": {"states": {"h3": [0.0, 0.36]}}}})
    assert narrowed.envelope.state_hi[0, 2] == 0.36
    assert narrowed.envelope.state_hi[1, 2] == 0.7


@pytest.mark.parametrize("env,match", [
    ({"states": {"h1": [0, 1], "h2": [0, 1]}, "inputs": {}}, r"envelope\.states\.h3"),
    ({"states": {"h1": [1, 0], "h2": [0, 1], "h3": [0, 1]}}, r"envelope\.states\.h1: .*lo <= hi"),
    ({"states": {"h1": [0, 1], "h2": [0, 1], "h3": [0, 1], "h9": [0, 1]}},
     r"envelope\.states\.h9"),
    ({"states": {"h1": [0, 1], "h2": [0, 1], "h3": [0, 1]},
      "inputs": {"q1": [0, 1], "q2": [0, 1], "v13": [0, 1]}, "modes": {"nope": {}}},
     r"envelope\.modes\.nope"),
])
def test_envelope_errors_name_the_key(env, match):
    with pytest.raises(SystemFileError, match=match):
        _with_envelope(env)


def test_shipped_envelope_gain_file_states_how_bounds_were_obtained():
    system = load_system("three_tank")
    gf = load_gains("three_tank_envelope", system)
    env = gf.results["envelope"]
    assert env["source"] == "declared"
    assert [h["method"] for h in env["remainder"]] == ["interval"] * 4
    assert env["mismatch"]["method"] == "sampled" and env["mismatch"]["samples"] > 0
    region = CertifiedRegion.from_results(system, gf.results)
    assert region is not None
    np.testing.assert_array_equal(region.state_hi, system.envelope.state_hi)
    # the scenario design states the region it sampled (the bounding box of its design runs
    # widened by its tube) and says its bounds there are sampled
    sc = load_gains("three_tank_thresholds", system)
    assert sc.results["envelope"]["source"] == "scenarios"
    assert [h["method"] for h in sc.results["envelope"]["remainder"]] == ["sampled"] * 4
    assert CertifiedRegion.from_results(system, sc.results) is not None


def test_excess_is_signed_and_described():
    system = load_system("three_tank")
    region = CertifiedRegion.from_results(system,
                                          load_gains("three_tank_envelope", system).results)
    e = region.excess(0, np.array([0.75, 0.3, -0.01]), np.array([1e-4, 2e-4, 0.0]))
    np.testing.assert_allclose(e, [0.05, 0.0, -0.01, 0.0, 5e-5, 0.0], atol=1e-12)
    assert describe_excess(region.names, e) == "h1 above by 0.05, h3 below by 0.01, " \
                                               "q2 above by 5e-05"


def _run(ref, system):
    sc = parse_scenario({
        "name": "drive", "system": "three_tank", "duration": 150.0, "seed": 1,
        "inputs": {"q1": {"pi": {"output": "h1", "reference": {"steps": [[0.0, ref]]},
                                 "kp": 2e-3, "ki": 2e-5, "min": 0.0, "max": 1.5e-4}},
                   "q2": {"pi": {"output": "h2", "reference": {"steps": [[0.0, 0.2]]},
                                 "kp": 2e-3, "ki": 2e-5, "min": 0.0, "max": 1.5e-4}},
                   "v13": {"steps": [[0.0, 0.0]]}},
        "faults": [{"channel": "bias_h1", "profile": "abrupt", "time": 120.0,
                    "magnitude": 0.02}]}, system=system)
    return simulate(sc, 1)


@pytest.mark.parametrize("ref,outside", [(0.5, False), (0.78, True)])
def test_analyze_marks_alarms_outside_the_certified_region(ref, outside):
    """h1 driven to ~0.72 m (envelope: 0.7 m) -> the bias alarm is flagged; at 0.5 m not."""
    system = load_system("three_tank")
    tr = _run(ref, system)
    doc = analyze_arrays(system, load_gains("three_tank_envelope", system), tr.k, tr.u[0],
                         tr.y[0])
    assert doc["alarms"], "the 2 cm bias must raise an alarm either way"
    ep = doc["alarms"][0]
    assert ep["outside_certified_region"] is outside
    assert ("h1 above by" in ep["outside_detail"]) is outside


@pytest.mark.slow
def test_no_false_alarm_over_the_envelope_at_noise_bounds():
    """50 fault-free runs at set points spread over the declared envelope, noise and
    uncertainty at their bounds (``extreme``): the envelope design raises no alarm, and the
    runs stay inside its certified region (benchmarks/campaign_envelope.py: the full table)."""
    import importlib.util

    from fd_monitor.core.monitor import run_batch
    from fd_monitor.core.simulator import simulate_batch

    spec = importlib.util.spec_from_file_location(
        "campaign_envelope", Path(__file__).parents[1] / "benchmarks" / "campaign_envelope.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    system = load_system("three_tank")
    gf = load_gains("three_tank_envelope", system)
    region = CertifiedRegion.from_results(system, gf.results)
    for i in range(10):
        sc = mod.envelope_scenario(system, 40 + i, duration=200.0)
        assert sc.noise_distribution == "extreme"
        tr = simulate_batch(sc, [100 * i + j for j in range(5)])
        res = run_batch(system, gf, tr, keep=("x_hat", "mode"))
        assert not res.alarm.any(), f"false alarm at set point {i}"
        assert not np.any(region.excess(res.mode_hat, res.x_hat, tr.u))
