"""Plant simulator properties: exact ZOH, guard timing, bounds, fault onset, determinism."""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from scipy.integrate import solve_ivp

from fd_monitor.core.plant import SampledPlant
from fd_monitor.core.simulator import PlantSimulator, simulate, simulate_batch
from fd_monitor.model.errors import ScenarioError
from fd_monitor.model.scenario import load_scenario, parse_scenario
from fd_monitor.model.system import load_system


def test_zoh_equals_fine_integration_of_every_linear_mode() -> None:
    """Exact ZOH (Van Loan) vs. RK45 at rtol 1e-11 with u, w and the affine term held:
    agreement to 1e-9 (absolute, states of order 1)."""
    system = load_system("pwa_cascade")
    plant = SampledPlant(system)
    rng = np.random.default_rng(0)
    for qi, mode in enumerate(system.modes):
        assert mode.A is not None
        x0 = rng.uniform(-1, 1, system.n)
        w = rng.uniform(-1, 1, system.nw)

        def rhs(_t: float, x: np.ndarray, A: np.ndarray = mode.A,
                D: np.ndarray = mode.D, w: np.ndarray = w) -> np.ndarray:
            return A @ x + D @ w

        ref = solve_ivp(rhs, (0.0, system.sample_time), x0, rtol=1e-11, atol=1e-13).y[:, -1]
        got = plant.step(np.array([qi]), x0[None], np.zeros((1, 0)), w[None])[0]
        np.testing.assert_allclose(got, ref, atol=1e-9)


def test_zoh_with_inputs_and_offset(tmp_path: Path) -> None:
    doc = {"name": "lin", "sample_time": 0.5, "states": ["a", "b"], "inputs": ["u"],
           "outputs": ["y"], "modes": {"m": {"A": [[-0.3, 2.0], [-2.0, -0.3]],
                                              "B": [[0.0], [1.0]], "C": [[1.0, 0.0]],
                                              "offset": [0.5, -0.2]}},
           "initial": {"mode": "m", "state": [1.0, 0.0]}}
    p = tmp_path / "lin.yaml"
    p.write_text(yaml.safe_dump(doc))
    system = load_system(p)
    m = system.modes[0]
    assert m.A is not None
    u = 0.7
    ref = solve_ivp(lambda _t, x: m.A @ x + m.B[:, 0] * u + m.offset, (0, 0.5), [1.0, 0.0],
                    rtol=1e-11, atol=1e-13).y[:, -1]
    got = SampledPlant(system).step(np.array([0]), np.array([[1.0, 0.0]]), np.array([[u]]))[0]
    np.testing.assert_allclose(got, ref, atol=1e-9)


def test_autonomous_guard_fires_at_the_first_sample_its_condition_holds() -> None:
    """For every k >= 1 the mode is the target of the guard of mode_{k-1} enabled by x_k,
    or unchanged when none is (eq. 15 through the plant's guards)."""
    sc = load_scenario("pwa_cascade_b1_step")
    tr = simulate(sc, n_samples=6000)
    system = sc.system
    x, q = tr.x[0], tr.mode[0]
    changes = 0
    for k in range(1, x.shape[0]):
        enabled = [g for g in system.guards_from(int(q[k - 1]), "autonomous")
                   if g.enabled(x[k], np.zeros(0))]
        expected = enabled[0].target if enabled else q[k - 1]
        assert q[k] == expected, f"sample {k}"
        changes += q[k] != q[k - 1]
    assert changes >= 2  # x2 decays into the safe mode; the bias step drives x1 up


def test_controlled_guard_takes_effect_the_sample_after_the_input() -> None:
    sc = load_scenario("three_tank_bias_h1")
    tr = simulate(sc, n_samples=3300)
    v13 = tr.u[0, :, 2]
    first_open = int(np.argmax(v13 >= 0.5))
    assert first_open == 3200  # steps profile: v13 = 1 from t = 320 s
    names = sc.system.mode_names
    assert names[tr.mode[0, first_open]].startswith("closed")
    assert names[tr.mode[0, first_open + 1]].startswith("open")


def test_three_tank_demo_scenario_crosses_the_autonomous_guard_both_ways() -> None:
    sc = load_scenario("three_tank_bias_h1")
    tr = simulate(sc)
    names = [sc.system.mode_names[i] for i in tr.mode[0]]
    pairs = {(a, b) for a, b in itertools.pairwise(names) if a != b}
    assert ("closed_dry", "closed_wet") in pairs and ("closed_wet", "closed_dry") in pairs


def test_noise_and_uncertainty_never_exceed_their_bounds() -> None:
    """three_tank (C = I, E = 0): v = y - x - sigma; eta = x_{k+1} - f(q_k, x_k, u_k)."""
    sc = load_scenario("three_tank_bias_h1")
    system = sc.system
    plant = SampledPlant(system)
    for dist in ("uniform", "extreme"):
        sc_d = parse_scenario({**yaml.safe_load(Path(sc.source).read_text()),
                               "noise": {"distribution": dist},
                               "uncertainty": {"distribution": dist}}, sc.source)
        tr = simulate_batch(sc_d, [1, 2, 3], n_samples=2500)
        sigma = np.zeros_like(tr.y)
        for i, f in enumerate(system.faults):
            if f.kind == "sensor_bias":
                sigma[..., f.index] += tr.faults[..., i]
        v = tr.y - tr.x - sigma
        vbar = system.measurement_noise
        assert np.all(np.abs(v) <= vbar * (1 + 1e-12))
        if dist == "extreme":
            np.testing.assert_allclose(np.abs(v), np.broadcast_to(vbar, v.shape), rtol=1e-12)
        for k in range(tr.mode.shape[1] - 1):
            pred = plant.step(tr.mode[:, k], tr.x[:, k], tr.u[:, k])
            eta = tr.x[:, k + 1] - pred
            bound = np.array([system.modes[q].uncertainty for q in tr.mode[:, k]])
            assert np.all(np.abs(eta) <= bound * (1 + 1e-9) + 1e-15), f"sample {k}"


def test_disturbance_within_bounds_pwa() -> None:
    """pwa_cascade: y - C x = E w with E = 0.01 [I 0], so |y - C x| <= 0.01."""
    tr = simulate(load_scenario("pwa_cascade_nominal"), n_samples=3000)
    assert np.all(np.abs(tr.y[0] - tr.x[0][:, :2]) <= 0.01 * (1 + 1e-12))
    assert np.max(np.abs(tr.y[0] - tr.x[0][:, :2])) > 0.009  # the noise is really there


def test_abrupt_fault_appears_exactly_at_its_sample() -> None:
    """Heracleous et al. eq. (4): sigma = 0 for k < K0, the magnitude from K0 = 2000 on."""
    sc = load_scenario("three_tank_bias_h1")
    tr = simulate(sc)
    ch = [f.name for f in sc.system.faults].index("bias_h1")
    f = tr.faults[0, :, ch]
    assert np.all(f[:2000] == 0.0) and np.all(f[2000:] == 0.01)
    v = tr.y[0, :, 0] - tr.x[0, :, 0]
    assert np.max(np.abs(v[:2000])) <= 1e-3 < np.min(v[2000:])


def test_incipient_fault_follows_thesis_eq_1_4(tmp_path: Path) -> None:
    doc = {"system": "three_tank", "duration": 50.0,
           "inputs": {"q1": 5e-5, "q2": 2e-5, "v13": 0.0},
           "faults": [{"channel": "bias_h2", "profile": "incipient", "time": 10.0,
                       "magnitude": 0.02, "rate": 0.2}]}
    sc = parse_scenario(doc, str(tmp_path / "s.yaml"))
    tr = simulate(sc)
    t = tr.t
    expected = np.where(t >= 10.0, 0.02 * (1 - np.exp(-0.2 * (t - 10.0))), 0.0)
    ch = [f.name for f in sc.system.faults].index("bias_h2")
    np.testing.assert_allclose(tr.faults[0, :, ch], expected, atol=1e-15)


def test_state_jump_and_relative_actuator_faults(tmp_path: Path) -> None:
    tr = simulate(load_scenario("pwa_cascade_b1_step"))
    b1 = tr.x[0, :, 2]
    assert np.all(b1[:5000] == 0.0) and np.all(b1[5000:] == 0.5)  # constant bias state

    doc = {"system": "three_tank", "duration": 20.0,
           "inputs": {"q1": 1e-4, "q2": 0.0, "v13": 0.0},
           "noise": {"scale": 0.0}, "uncertainty": {"scale": 0.0},
           "faults": [{"channel": "pump1", "profile": "abrupt", "time": 10.0,
                       "magnitude": 1.0, "relative": True}]}
    faulty = simulate(parse_scenario(doc, str(tmp_path / "a.yaml")))
    nominal = simulate(parse_scenario({**doc, "faults": []}, str(tmp_path / "b.yaml")))
    # pump1 dead from t = 10 s: h1 keeps rising nominally, stops gaining from the pump after.
    np.testing.assert_array_equal(faulty.x[0, :101], nominal.x[0, :101])
    assert faulty.x[0, -1, 0] < nominal.x[0, -1, 0] - 1e-3
    np.testing.assert_array_equal(faulty.u, nominal.u)  # the published u is the command


def test_deterministic_per_seed_and_independent_of_batch() -> None:
    sc = load_scenario("three_tank_bias_h1")
    a = simulate(sc, seed=3, n_samples=700)
    b = simulate(sc, seed=3, n_samples=700)
    c = simulate(sc, seed=4, n_samples=700)
    batch = simulate_batch(sc, [9, 3], n_samples=700)
    np.testing.assert_array_equal(a.y, b.y)
    assert not np.array_equal(a.y, c.y)
    np.testing.assert_array_equal(a.y[0], batch.y[1])
    np.testing.assert_array_equal(a.x[0], batch.x[1])


def test_step_api_matches_batch() -> None:
    sc = load_scenario("pwa_cascade_b1_step")
    sim = PlantSimulator(sc)
    ys = np.array([sim.step().y[0] for _ in range(300)])
    np.testing.assert_array_equal(ys, simulate(sc, n_samples=300).y[0])


BAD_SCENARIOS: list[Any] = [
    ({"system": "three_tank", "duration": 10.0}, r"inputs\.q1: expected a profile for every"),
    ({"system": "nope", "duration": 10.0}, r"system: nope: unknown plant"),
    ({"system": "pwa_cascade", "duration": -1.0}, r"duration: expected a number > 0"),
    ({"system": "pwa_cascade", "duration": 1.0,
      "faults": [{"channel": "x", "profile": "abrupt", "time": 0, "magnitude": 1}]},
     r"faults\[0\]\.channel: expected a fault channel of plant 'pwa_cascade'"),
    ({"system": "pwa_cascade", "duration": 1.0,
      "faults": [{"channel": "b1_step", "profile": "incipient", "time": 0, "magnitude": 1}]},
     r"faults\[0\]\.rate: expected the decay rate"),
    ({"system": "pwa_cascade", "duration": 1.0, "noise": {"distribution": "gauss"}},
     r"noise\.distribution: expected one of \['uniform', 'extreme'\]"),
]


@pytest.mark.parametrize(("doc", "match"), BAD_SCENARIOS)
def test_bad_scenarios(tmp_path: Path, doc: Any, match: str) -> None:
    with pytest.raises(ScenarioError, match=match):
        parse_scenario(doc, str(tmp_path / "s.yaml"))


def test_three_tank_scalar_path_is_bit_identical_to_the_vectorised_one() -> None:
    """A single stream takes a float fast path; it must give the batch path's exact bits."""
    from fd_monitor.model.nonlinear import get_model

    mdl = get_model("three_tank")
    system = load_system("three_tank")
    rng = np.random.default_rng(5)
    X = rng.uniform(0.0, 0.7, (400, 3))
    X[:5] = [[0.35, 0.2, 0.35], [0.4, 0.4, 0.4], [0.0, 0.0, 0.0], [0.5, 0.1, 0.36],
             [0.3, 0.2, 0.3]]  # equal levels, empty tanks, the pipe edge
    U = np.column_stack([rng.uniform(-1e-5, 1.5e-4, 400), rng.uniform(0, 1e-4, 400),
                         rng.integers(0, 2, 400)])
    for mode in system.modes:
        batch = mdl.step(X, U, mode.params, 0.1)
        for i in range(X.shape[0]):
            single = mdl.step(X[i:i + 1], U[i:i + 1], mode.params, 0.1)
            assert single.shape == (1, 3)
            np.testing.assert_array_equal(single[0], batch[i])
            np.testing.assert_array_equal(mdl.step(X[i], U[i], mode.params, 0.1), batch[i])
