"""How good is an identified model (issue 20): quality, excitation, auto, bounds, halves,
physical parameters.

The closed-loop plant: two coupled velocities ``w1, w2`` driven by torques ``tau1, tau2``
(``x+ = A x + B u + w``, ``y = x + v``, v uniform within 5 mm/s... in its units, w within 2e-3)
under a digital controller that reads the same measurements the bag records: ``tau1`` is a PI
loop tracking random set points (excited), ``tau2 = -2 w2`` a P loop holding ``w2`` at zero
(excited only through feedback), plus an optional dither on ``tau2`` (uniform, held 2 samples).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm

from fd_monitor.analysis.identify import Dataset, identify
from fd_monitor.analysis.identify_quality import NOISE_FACTOR, physical_parameters
from fd_monitor.commands.cli import main as cli_main
from fd_monitor.core.identify import (
    AffineModel,
    eigen_intervals,
    hac_covariance,
    hf_noise_std,
    nrmse_fit,
    pe_order,
    physical_joint,
    physical_velocity,
    simulate,
)
from fd_monitor.wire.adapters import parse_adapter
from fd_monitor.wire.bag_reader import arrays_from
from fd_monitor.wire.bag_writer import write_bag

A_TRUE = np.array([[0.96, 0.03], [-0.02, 0.93]])
B_TRUE = np.array([[0.08, 0.02], [0.01, 0.06]])
TS = 0.01
V_BAR, W_BAR = 0.005, 0.002
FAST = {"max_window": 0.3}           # the uncertainty bound's windows: 30 samples suffice here


def closed_loop(seed: int, K: int, dither: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """u (K, 2), y (K, 2) of the closed-loop plant (module doc)."""
    rng = np.random.default_rng(seed)
    r1 = np.repeat(rng.uniform(-1, 1, K // 200 + 1), 200)[:K]
    d = np.repeat(rng.uniform(-dither, dither, K // 2 + 1), 2)[:K]
    v = rng.uniform(-V_BAR, V_BAR, (K, 2))
    w = rng.uniform(-W_BAR, W_BAR, (K, 2))
    x, i1 = np.zeros(2), 0.0
    Y, U = np.empty((K, 2)), np.empty((K, 2))
    for k in range(K):
        y = x + v[k]
        e1 = r1[k] - y[0]
        i1 += 0.2 * e1
        u = np.array([e1 + i1, -2.0 * y[1] + d[k]])
        Y[k], U[k] = y, u
        x = A_TRUE @ x + B_TRUE @ u + w[k]
    return U, Y


def dataset(seed: int, K: int, dither: float = 0.0) -> Dataset:
    U, Y = closed_loop(seed, K, dither)
    return Dataset(f"cl{seed}", ("tau1", "tau2"), ("w1", "w2"), np.arange(K), U, Y, TS)


def bag(path: Path, seed: int, K: int, dither: float = 0.0) -> Path:
    U, Y = closed_loop(seed, K, dither)
    k = np.arange(K)
    ns = np.rint(k * TS * 1e9).astype(np.int64)
    return write_bag(path, [arrays_from("/plant/u", ("tau1", "tau2"), k, U, ns),
                            arrays_from("/plant/y", ("w1", "w2"), k, Y, ns)])


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    d = tmp_path_factory.mktemp("quality")
    return {"fit": bag(d / "fit", 1, 3000), "held": bag(d / "held", 2, 1000),
            "fit_d": bag(d / "fit_d", 1, 3000, 0.3), "held_d": bag(d / "held_d", 2, 1000, 0.3)}


def _cli(capsys, *argv: str) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = cli_main(["identify", *argv])
    out = capsys.readouterr()
    return rc, out.out, out.err


# ---------------------------------------------------------------- numerics (core)

def test_nrmse_fit_is_matlab_compare():
    y = np.linspace(0.0, 1.0, 50)[:, None]
    assert nrmse_fit(y, y)[0] == pytest.approx(100.0)
    assert nrmse_fit(y, np.full_like(y, y.mean()))[0] == pytest.approx(0.0)
    assert nrmse_fit(y, y + 0.1 * (y - y.mean()))[0] == pytest.approx(90.0)


def test_simulate_runs_the_model_free_from_x0():
    M = AffineModel(np.array([[0.5]]), np.array([[1.0]]), np.array([0.1]), "affine", 3)
    X = simulate([M], np.zeros(3, dtype=int), np.ones((3, 1)), np.array([2.0]))
    np.testing.assert_allclose(X[:, 0], [2.0, 2.1, 2.15, 2.175])


def test_pe_order_of_a_constant_a_sine_and_white_noise():
    k = np.arange(2000)
    assert pe_order(np.full(2000, 3.0), 6) == 0
    assert pe_order(np.sin(0.3 * k), 6) == 2          # a sinusoid excites order 2
    assert pe_order(np.random.default_rng(0).normal(size=2000), 6) == 6


def test_hac_standard_errors_match_the_spread_over_repeated_fits():
    """Least squares of y_k+1 on y_k with measured noise (MA(1) errors): the sandwich
    standard error is within 20 % of the standard deviation of the estimate over 200 runs."""
    rng = np.random.default_rng(5)
    est, se = [], []
    for _ in range(200):
        N = 400
        u = rng.normal(size=N)
        x = np.zeros(N + 1)
        for k in range(N):
            x[k + 1] = 0.8 * x[k] + u[k] + 0.05 * rng.normal()
        y = x + 0.05 * rng.normal(size=N + 1)
        Th = np.column_stack([y[:-1], u])
        xi = np.linalg.lstsq(Th, y[1:, None], rcond=None)[0]
        cov = hac_covariance(Th, y[1:, None] - Th @ xi)
        est.append(xi[1, 0])
        se.append(np.sqrt(cov[1, 1]))
    assert np.mean(se) == pytest.approx(np.std(est), rel=0.2)


def test_eigen_intervals_of_a_diagonal_matrix_are_its_entries_standard_errors():
    A = np.diag([0.9, 0.5])
    cov = np.diag([1e-4, 0.0, 0.0, 4e-4])          # var(A00), var(A11)
    e = eigen_intervals(A, cov)
    order = np.argsort(e["eig"].real)
    np.testing.assert_allclose(e["se_real"][order], [0.02, 0.01], rtol=1e-9)
    assert e["z"] == pytest.approx(2.2414, abs=1e-3)    # Bonferroni: 2 statements at 95 %


def test_hf_noise_std_recovers_white_measurement_noise():
    rng = np.random.default_rng(3)
    A = np.array([[0.9, 0.1], [0.0, 0.8]])
    N = 20000
    v = rng.uniform(-0.01, 0.01, (N + 1, 2))
    eta = 1e-3 * np.sin(np.arange(N) / 200.0)[:, None]       # slow modelling error: removed
    E = v[1:] - v[:-1] @ A.T + eta
    np.testing.assert_allclose(hf_noise_std(E, A), 0.01 / np.sqrt(3), rtol=0.03)


def test_physical_parameters_of_a_joint_and_of_a_velocity_round_trip():
    J, b, k, tau0 = 0.05, 0.2, 1.5, 0.3
    Ac = np.array([[0.0, 1.0], [-k / J, -b / J]])
    Bc = np.array([[0.0, 0.0], [1.0 / J, -1.0 / J]])       # torque and the constant torque
    M = expm(np.block([[Ac, Bc], [np.zeros((2, 4))]]) * TS)
    p = physical_joint(M[:2, :2], M[:2, 2], M[:2, 3] * tau0, TS)
    assert p["inertia"] == pytest.approx(J, rel=1e-9)
    assert p["damping"] == pytest.approx(b, rel=1e-9)
    assert p["stiffness"] == pytest.approx(k, rel=1e-9)
    assert p["constant_torque"] == pytest.approx(tau0, rel=1e-9)
    a = np.exp(-b * TS / J)
    beta = (1 - a) / b
    v = physical_velocity(a, beta, -beta * tau0, TS)
    assert (v["inertia"], v["damping"], v["constant_torque"]) == pytest.approx((J, b, tau0))
    assert physical_velocity(1.01, beta, 0.0, TS) == {}       # not a damped joint


# ---------------------------------------------------------------- closed loop, excitation

def test_an_input_excited_only_through_feedback_is_named_and_strict_refuses(bags, tmp_path,
                                                                            capsys):
    out = tmp_path / "cl.yaml"
    args = [str(bags["fit"]), "--holdout", str(bags["held"]), "--model", "linear",
            "--estimator", "iv", "--max-window", "0.3", "-o", str(out)]
    rc, stdout, err = _cli(capsys, *args)
    assert rc == 0
    warns = [ln for ln in err.splitlines() if ln.startswith("WARNING: input")]
    assert len(warns) == 1 and warns[0].startswith("WARNING: input tau2 is weakly excited")
    assert "gain is not determined" in warns[0] and "add a dither to tau2" in warns[0]
    assert "tau2" in stdout and "WEAK" in stdout        # the excitation table
    assert "rank 3 of 4" in stdout                      # tau2 = -2 w2: one dependent column
    out.unlink()
    rc, stdout, err = _cli(capsys, *args, "--strict")
    assert rc == 2 and not out.exists()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fd_monitor: error: --strict: input tau2")


def test_with_a_dither_the_gain_is_within_10_percent(bags, tmp_path, capsys):
    rc, stdout, err = _cli(capsys, str(bags["fit_d"]), "--holdout", str(bags["held_d"]),
                           "--model", "linear", "--estimator", "iv", "--max-window", "0.3",
                           "-o", str(tmp_path / "d.yaml"), "--json", "--strict")
    assert rc == 0, err
    s = json.loads(stdout)
    B = np.asarray(s["quality"]["coefficients"][0]["B"])
    assert abs(B[1, 1] - B_TRUE[1, 1]) <= 0.1 * B_TRUE[1, 1]     # tau2 -> w2
    exc = {e["input"]: e for e in s["quality"]["excitation"]}
    assert not exc["tau2"]["weak"] and exc["tau2"]["gain_rel_se"] < 0.1
    assert exc["tau2"]["own_share"] > 0.5                     # the dither is its own part
    assert s["closed_loop"]["inputs"]                         # P loop: it reacts to the noise
    assert s["warnings"] == []


def test_eigenvalue_intervals_contain_the_true_ones_in_9_of_10_seeds():
    """Closed loop with a dither, instrumental variables: the stated joint 95 % intervals of
    the eigenvalues (real and imaginary parts) contain the true pair 0.945 +- 0.0194j in at
    least 9 of 10 seeds, and are narrow (half-width below 0.01) so that this says something."""
    true = np.linalg.eigvals(A_TRUE)
    hits = 0
    for seed in range(10):
        res = identify([dataset(100 + seed, 2000, 0.3)], [dataset(200 + seed, 400, 0.3)],
                       name="cl", model="linear", estimator="iv", **FAST)
        eig = res.summary["quality"]["coefficients"][0]["eigenvalues"]
        ok = True
        for lam in true:
            e = min(eig, key=lambda e: abs(complex(e["real"], e["imag"]) - lam))
            lo, hi = e["interval_real"]
            ilo, ihi = e["interval_imag"]
            assert hi - lo < 0.02 and ihi - ilo < 0.02
            ok &= bool(lo <= lam.real <= hi and ilo <= lam.imag <= ihi)
        hits += ok
    assert hits >= 9


def test_auto_compares_estimators_by_held_out_simulation_and_skips_ls_in_closed_loop(bags):
    from fd_monitor.analysis.identify import identify_bags

    res = identify_bags([bags["fit_d"]], holdout=[bags["held_d"]], name="cl", **FAST)
    s = res.summary
    cands = s["candidates"]
    assert {(c["model"], c["estimator"]) for c in cands} >= {
        ("linear", "ls"), ("affine", "ls"), ("linear", "iv"), ("affine", "iv"),
        ("sparse", "iv"), ("affine", "n4sid")}
    assert all(len(c["simulation_fit"]) == 2 for c in cands)
    chosen = [c for c in cands if c["chosen"]]
    assert len(chosen) == 1 and chosen[0]["estimator"] != "ls"     # closed loop: ls not chosen
    eligible = [c for c in cands if c["estimator"] != "ls"]
    assert chosen[0]["simulation_error"] <= min(c["simulation_error"] for c in eligible) + 1e-9
    assert s["estimator"] == chosen[0]["estimator"] and s["model"] == chosen[0]["model"]
    q = s["quality"]
    assert min(q["simulation"]["fit_percent"]) > 80.0
    assert q["halves"]["stable"] and len(q["halves"]["fit_first"]) == 2
    assert q["bounds"][0]["bound"] == "measurement_noise"
    assert q["bounds"][0]["samples"] == s["validation_samples"]


# ---------------------------------------------------------------- honest bounds

def test_a_datasheet_noise_bound_is_stated_as_assumed_and_checked():
    fit, held = [dataset(1, 2000, 0.3)], [dataset(2, 400, 0.3)]
    ok = identify(fit, held, name="cl", model="linear", estimator="iv",
                  stated_noise=[V_BAR], **FAST)
    s = ok.summary
    np.testing.assert_array_equal(ok.system.measurement_noise, [V_BAR, V_BAR])
    assert s["measurement_noise"]["assumed"] and "assumed" in s["quality"]["bounds"][0]["how"]
    assert s["warnings"] == []
    # the multi-step simulation the --plot draws beside the one-step prediction
    sim = ok.validation["simulation"]
    assert sim["simulated"].shape == sim["measured"].shape == (399, 2)
    sigma = np.asarray(s["quality"]["noise_std_hf"])
    np.testing.assert_allclose(sigma, V_BAR / np.sqrt(3), rtol=0.1)   # uniform noise's std
    low = identify(fit, held, name="cl", model="linear", estimator="iv",
                   stated_noise=[0.4 * V_BAR], **FAST)
    warns = [w for w in low.summary["warnings"] if "noise bound" in w]
    assert len(warns) == 2 and warns[0].startswith("output w1: the stated (--noise-bound)")
    assert not any(n["ok"] for n in low.summary["quality"]["noise_check"])
    assert NOISE_FACTOR * sigma.max() > 0.4 * V_BAR


# ---------------------------------------------------------------- physical parameters

def test_joint_position_and_velocity_give_inertia_damping_and_stiffness():
    """A joint ``J dv/dt = tau - b v - k p`` sampled at 100 Hz, open loop, read through an
    adapter that names the joint's position and velocity: within 2 %."""
    J, b, k = 0.05, 0.2, 1.5
    Ac = np.array([[0.0, 1.0], [-k / J, -b / J]])
    M = expm(np.block([[Ac, np.array([[0.0], [1.0 / J]])], [np.zeros((1, 3))]]) * TS)
    Ad, Bd = M[:2, :2], M[:2, 2:]
    rng = np.random.default_rng(9)

    def run(seed_off: int) -> Dataset:
        K = 3000
        u = np.repeat(rng.uniform(-0.5, 0.5, K // 5 + 1), 5)[:K, None]
        x, X = np.zeros(2), np.empty((K, 2))
        for i in range(K):
            X[i] = x
            x = Ad @ x + Bd @ u[i]
        return Dataset(f"j{seed_off}", ("effort",), ("pos", "vel"), np.arange(K), u,
                       X + rng.uniform(-1e-4, 1e-4, (K, 2)), TS)

    res = identify([run(0)], [run(1)], name="joint", model="linear", estimator="iv", **FAST)
    adapter = parse_adapter({"format_version": 1, "inputs": [
        {"channel": "effort", "topic": "/cmd", "type": "std_msgs/msg/Float64MultiArray",
         "index": 0}], "outputs": [
        {"channel": "pos", "topic": "/joint_states", "type": "sensor_msgs/msg/JointState",
         "joint": "elbow", "field": "position"},
        {"channel": "vel", "topic": "/joint_states", "type": "sensor_msgs/msg/JointState",
         "joint": "elbow", "field": "velocity"}]})
    (p,) = physical_parameters(adapter, res.models, ["nominal"], ("effort",), ("pos", "vel"),
                               TS)
    assert p["joint"] == "elbow" and p["states"] == ["pos", "vel"]
    assert p["inertia"] == pytest.approx(J, rel=0.02)
    assert p["damping"] == pytest.approx(b, rel=0.02)
    assert p["stiffness"] == pytest.approx(k, rel=0.02)
    assert p["kinematic"] == pytest.approx(1.0, rel=0.02)
