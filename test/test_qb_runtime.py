"""QB runtime: hybrid observer (13), detector (eq. 8, 11 and the tighter bounds), batch runner."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from fd_monitor.core.kalman import kalman_gains
from fd_monitor.core.methods import load_gains
from fd_monitor.core.qb import QBDetector, QBObserver, run_batch
from fd_monitor.core.simulator import simulate_batch
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system


@pytest.fixture(scope="module")
def pwa():
    return load_system("pwa_cascade")


@pytest.fixture(scope="module")
def gains(pwa, repo):
    return load_gains(repo / "config" / "gains" / "pwa_cascade_qb.yaml", pwa)


@pytest.fixture(scope="module")
def nominal_runs():
    return simulate_batch(load_scenario("pwa_cascade_nominal"), range(100), n_samples=6000)


def test_step_api_matches_batch(pwa, gains):
    traj = simulate_batch(load_scenario("pwa_cascade_b1_step"), [3], n_samples=5200)
    res = run_batch(pwa, gains, traj)
    obs, det = QBObserver(pwa, gains), QBDetector(pwa, gains)
    assert det.channels == res.channels
    for k in range(traj.y.shape[1]):
        m, x = obs.step(k, traj.u[0, k], traj.y[0, k])
        assert m == res.mode_hat[0, k]
        np.testing.assert_allclose(x, res.x_hat[0, k], rtol=1e-10, atol=1e-12)
        a = det.step(x, obs.residual(m, x, traj.y[0, k]), m)
        assert np.array_equal(a, res.alarm[0, k])
    with pytest.raises(ValueError, match="consecutive"):
        obs.step(k + 2, traj.u[0, k], traj.y[0, k])
    with pytest.raises(ValueError, match="y"):
        QBObserver(pwa, gains).step(0, [], [np.nan, 0.0])


def test_tighter_bounds_never_exceed_rho_max(gains):
    comp = gains.results["component_bound"]
    assert np.all(comp <= gains.results["rho_max"])
    assert np.all(gains.results["output_bound"] <= gains.results["r_max"][:, None])


def test_fault_free_errors_stay_in_the_ellipsoid(pwa, gains, nominal_runs):
    """After the transient (eq. 5) e'Pe <= 1, so the per-component bounds |e_j| <=
    sqrt((P^-1)_jj) and the per-output residual bounds are never crossed (100 runs x 40 s)."""
    res = run_batch(pwa, gains, nominal_runs)
    k0 = 2000  # 20 s transient
    e = nominal_runs.x[:, k0:] - res.x_hat[:, k0:]
    V = np.einsum("nki,ij,nkj->nk", e, gains.results["P"], e)
    assert V.max() <= 1.0
    assert np.all(np.abs(e) <= gains.results["component_bound"])
    assert not res.alarm[:, k0:].any()  # every channel at rho = 1 (guaranteed bounds)
    # ...and the estimated mode is the true one except near the guard crossings
    assert (res.mode_hat[:, k0:] == nominal_runs.mode[:, k0:]).mean() > 0.99


def test_bias_step_detected(pwa, gains):
    """Sec. VI: a bias step of 0.5 on x3 at t = 50 s is detected on channel b1 (rho = 1)."""
    traj = simulate_batch(load_scenario("pwa_cascade_b1_step"), range(20))
    res = run_batch(pwa, gains, traj)
    j = res.channels.index("b1")
    k_on = 5000
    assert not res.alarm[:, 2000:k_on].any()
    first = np.argmax(res.alarm[:, k_on:, j], axis=1)
    assert res.alarm[:, k_on:, j].any(axis=1).all()
    delay = first * pwa.sample_time
    assert np.all(delay < 5.0)


def test_rho_scales_thresholds(pwa, gains, nominal_runs):
    r1 = run_batch(pwa, gains, nominal_runs, rho=1.0, state_bound="rho_max")
    r2 = run_batch(pwa, gains, nominal_runs, rho=0.01, state_bound="rho_max")
    assert np.array_equal(r2.alarm, r2.residual > 0.01 * r1.threshold)
    assert r2.alarm[:, 2000:, 0].any()  # Table II: 0.01 rho_max is inside the noise


def test_kalman_baseline_is_stable(pwa):
    kd = kalman_gains(pwa)
    Phi, _ = kd.matrices
    assert np.all(np.abs(np.linalg.eigvals(Phi)).max(axis=1) < 1)
    assert np.all(np.linalg.eigvalsh(kd.X) > -1e-12)


def test_core_is_pure(python, repo):
    code = ("import sys, fd_monitor.core.qb, fd_monitor.core.kalman, fd_monitor.core.batch;"
            "print('cvxpy' in sys.modules, 'rclpy' in sys.modules)")
    out = subprocess.run([python, "-c", code], capture_output=True, text=True, cwd=repo)
    assert out.stdout.split() == ["False", "False"], out.stderr
