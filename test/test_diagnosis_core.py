"""Sensor-bias diagnosis chain (Heracleous et al.): filters, thresholds, monitor, campaigns.

Uses the shipped gain file ``config/gains/three_tank_thresholds.yaml`` (written by
``python -m fd_monitor design thresholds three_tank``).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from fd_monitor.core.bias_estimator import project
from fd_monitor.core.filters import (
    FilterBank,
    first_order,
    impulse_response,
    moving_average,
    settling_length,
)
from fd_monitor.core.monitor import Monitor, run_batch, validate_sample
from fd_monitor.core.simulator import simulate, simulate_batch
from fd_monitor.core.thresholds import DiagnosisGains, as_gains, noise_l1_bound
from fd_monitor.model.errors import GainFileError, MessageError
from fd_monitor.model.gains import load_gains, write_gain_doc
from fd_monitor.model.scenario import FaultEvent, load_scenario
from fd_monitor.model.system import load_system
from fd_monitor.wire.topics import STATE_ESTIMATE

REPO = Path(__file__).resolve().parent.parent
GAINS = REPO / "config" / "gains" / "three_tank_thresholds.yaml"


@pytest.fixture(scope="module")
def system():
    return load_system("three_tank")


@pytest.fixture(scope="module")
def gains(system):
    return load_gains(GAINS, system)


def _bias_scenario(sensor: str, mag: float, t: float, duration: float | None = None):
    sc = load_scenario("three_tank_nominal")
    ch = [f.name for f in sc.system.faults].index(f"bias_{sensor}")
    sc = replace(sc, faults=(FaultEvent(ch, "abrupt", t, mag),))
    if duration is not None:
        sc = replace(sc, duration=duration)
    return sc


# ---------------------------------------------------------------- filters (eq. 8-9)

def test_moving_average_impulse_and_settling():
    spec = moving_average(5)
    h = impulse_response(spec, 8)
    np.testing.assert_allclose(h, [0.2] * 5 + [0.0] * 3, atol=1e-15)
    assert settling_length(spec) == 5
    assert spec.spectral_radius() == 0.0


def test_first_order_filter_is_stable_and_unit_dc():
    spec = first_order(0.9)
    assert spec.spectral_radius() == pytest.approx(0.9)
    h = impulse_response(spec, settling_length(spec, 1e-12) + 1)
    assert h.sum() == pytest.approx(1.0, abs=1e-10)


def test_filterbank_matches_convolution_and_is_batch_independent():
    rng = np.random.default_rng(0)
    spec = first_order(0.7)
    x = rng.normal(size=(4, 50, 2))
    fb = FilterBank(spec, (4, 2))
    out = np.array([fb.step(x[:, k]) for k in range(50)]).transpose(1, 0, 2)
    # steady-state initial condition: equivalent to prepending x_0 forever
    h = impulse_response(spec, 400)
    pre = np.concatenate([np.repeat(x[:, :1], 350, axis=1), x], axis=1)
    ref = np.stack([np.convolve(pre[i, :, c], h)[350:400] for i in range(4) for c in range(2)]
                   ).reshape(4, 2, 50).transpose(0, 2, 1)
    np.testing.assert_allclose(out, ref, atol=1e-12)
    single = FilterBank(spec, (1, 2))
    out1 = np.array([single.step(x[2:3, k]) for k in range(50)])[:, 0]
    assert np.array_equal(out1, out[2])  # bit-identical whatever the batch size


# ---------------------------------------------------------------- threshold derivation

def test_noise_l1_bound_is_attained_and_never_exceeded():
    """The combined bound (derivation of eq. 16-19 in design/thresholds.py) is exact."""
    rng = np.random.default_rng(1)
    h = impulse_response(moving_average(6), 6)
    A = np.array([[0.99, 0.01], [0.02, 0.97]])
    v_bar = np.array([1e-3, 2e-3])
    bound = noise_l1_bound(h, A, v_bar)
    T = 60

    def residual(v):  # r = H[e], e_k = v_k - A v_{k-1}
        e = v.copy()
        e[1:] -= v[:-1] @ A.T
        return np.array([np.convolve(e[:, i], h)[:T] for i in range(2)]).T

    for _ in range(200):
        v = rng.uniform(-1, 1, (T, 2)) * v_bar
        assert np.all(np.abs(residual(v)) <= bound + 1e-15)
    # worst case for output 0 at sample T-1: v_{l,k-m} = v_bar_l sign(coefficient)
    hh = np.concatenate([h, [0.0]])
    hp = np.concatenate([[0.0], h])
    v = np.zeros((T, 2))
    for l in range(2):
        coef = (hh if l == 0 else 0.0) - A[0, l] * hp
        for m, c in enumerate(coef):
            v[T - 1 - m, l] = v_bar[l] * np.sign(c)
    assert residual(v)[T - 1, 0] == pytest.approx(bound[0], rel=1e-12)
    # and it is far below bounding v_F and Delta-f separately (2 ||h||_1 v_bar)
    assert bound[0] < 0.5 * 2 * np.abs(h).sum() * v_bar[0]


def test_shipped_gain_file_is_certified_and_consistent(system, gains):
    assert gains.certificate_status == "verified"
    g = as_gains(system, gains)
    assert isinstance(g, DiagnosisGains)
    res = gains.results
    # combined thresholds are much tighter than eq. 19 term by term
    assert np.all(g.r_bar * 4 < res["r_bar_separate"])
    # one AGEI row per autonomous guard; r_bar* >= r_bar (eq. 22)
    auto = [i for i, gd in enumerate(system.guards) if gd.kind == "autonomous"]
    assert sorted(r.guard for r in g.agei_rows) == auto
    for r in g.agei_rows:
        assert np.all(r.r_bar_star >= g.r_bar[r.enabling_mode] - 1e-15)
    assert np.all(np.abs(np.linalg.eigvals(g.Lambda)) < 1)
    assert np.all(np.linalg.eigvalsh(g.Gamma) > 0)


@pytest.mark.parametrize("edit, match", [
    (lambda d: d["results"]["r_bar"][0].__setitem__(0, 1e-6), "r_bar"),
    (lambda d: d["results"]["r_bar"][1].__setitem__(2, 1.2 * d["results"]["r_bar"][1][2]),
     r"r_bar\[closed_wet\] differs from .* r_bar is derived"),
    (lambda d: d["results"]["estimator"].__setitem__("Gamma", [[0.02, 0, 0], [0, -0.01, 0],
                                                               [0, 0, 0.02]]),
     "Gamma is not positive definite"),
    (lambda d: d["results"]["estimator"].__setitem__("Lambda", [[1.5, 0, 0], [0, 0.0, 0],
                                                                [0, 0, 0.0]]),
     "Lambda is not Schur"),
    (lambda d: d["results"]["noise_l1"][1].__setitem__(2, 1e-9), "noise_l1"),
    (lambda d: d["results"]["impulse"]["h_p_bar"].__setitem__(3, 0.0), "h_p_bar"),
    (lambda d: d["results"]["agei"]["rows"].pop(0), "one row per autonomous guard"),
])
def test_tampered_gain_file_is_refused(system, tmp_path, edit, match):
    doc = yaml.safe_load(GAINS.read_text())
    edit(doc)
    p = tmp_path / "bad.yaml"
    write_gain_doc(p, doc)  # re-digested: the re-derived checks must still refuse it
    with pytest.raises(GainFileError, match=match):
        load_gains(p, system)


def test_projection_keeps_estimate_in_ball():
    """Eq. 26: on the boundary, an outward update is projected onto the tangent plane."""
    G = np.diag([0.02, 0.03, 0.01])
    sigma = np.array([[0.06, 0.08, 0.0]])  # |sigma| = 0.1 = M
    step = np.array([[0.01, 0.02, -0.01]]) @ G
    p = project(sigma, step, G, 0.1)
    assert float(sigma[0] @ p[0]) == pytest.approx(0.0, abs=1e-18)
    inward = -step
    np.testing.assert_array_equal(project(sigma, inward, G, 0.1), inward)


# ---------------------------------------------------------------- monitor contract

def test_monitor_equals_run_batch_bit_for_bit(system, gains):
    sc = _bias_scenario("h1", 0.005, 20.0, duration=60.0)
    tr = simulate_batch(sc, [3, 4, 5])
    res = run_batch(system, gains, tr)
    for run in (0, 2):
        mon = Monitor(system, gains)
        outs = [mon.step(int(k), tr.u[run, j], tr.y[run, j]) for j, k in enumerate(tr.k)]
        assert np.array_equal(np.array([o.detector.residual for o in outs]),
                              res.residual[run])
        assert np.array_equal(np.array([o.detector.alarm for o in outs]), res.alarm[run])
        assert np.array_equal(np.array([o.estimator.sigma_hat for o in outs]),
                              res.extra["sigma_hat"][run])
        assert np.array_equal(np.array([o.mode for o in outs]), res.mode_hat[run])
    assert res.extra["k_detect"].tolist() == [200, 200, 200]


def test_components_composed_by_hand_equal_monitor(system, gains):
    """The five-process pipeline: each component fed the previous sample's feedback."""
    from fd_monitor.core.agei import Agei
    from fd_monitor.core.bias_estimator import BiasEstimator
    from fd_monitor.core.detector import ResidualDetector
    from fd_monitor.core.hybrid_observer import HybridObserver

    g = as_gains(system, gains)
    tr = simulate(_bias_scenario("h2", 0.004, 10.0, duration=30.0), 7)
    obs, det = HybridObserver(system), ResidualDetector(system, g)
    ag, est = Agei(system, g), BiasEstimator(system, g)
    mon = Monitor(system, gains)
    sigma, trig, ov = np.zeros(3), -1, np.full(3, np.nan)
    for j, k in enumerate(tr.k):
        u, y = tr.u[0, j], tr.y[0, j]
        o = obs.step(int(k), u, y, sigma, trig)
        d = det.step(int(k), o.y_tilde, o.x_hat, o.mode, ov)
        a = ag.step(int(k), o.mode, d.w, d.residual, d.nominal)
        e = est.step(int(k), u, y, o.mode, d.alarm, a.mode_uncertain)
        sigma, trig, ov = e.sigma_hat, a.trigger, a.override
        m = mon.step(int(k), u, y)
        assert np.array_equal(m.detector.residual, d.residual)
        assert np.array_equal(m.estimator.sigma_hat, e.sigma_hat)
        assert m.agei.trigger == a.trigger
    lay = STATE_ESTIMATE.layout(system)
    vals = lay.encode(m.observer.payload(), restart=False, bridge=False)
    assert len(lay.labels) == vals.size == 1 + 3 + 3 + 2
    assert vals[lay.index["x_hat"]].tolist() == m.observer.x_hat.tolist()


@pytest.mark.parametrize("u, y, match", [
    ([0.0, 0.0, 0.0], [0.4, np.nan, 0.3], "non-finite"),
    ([0.0, np.inf, 0.0], [0.4, 0.2, 0.3], "non-finite"),
    ([0.0, 0.0, 0.0], [0.4, 0.2], "expected 3 values"),
    ([0.0, 0.0], [0.4, 0.2, 0.3], "expected 3 values"),
    ([0.0, 0.0, 0.0], "abc", "expected 3"),
])
def test_invalid_sample_is_rejected_without_state_change(system, gains, u, y, match):
    tr = simulate(load_scenario("three_tank_nominal"), 2, 40)
    ref, mon = Monitor(system, gains), Monitor(system, gains)
    for j in range(40):
        if j == 20:
            with pytest.raises(MessageError, match=match):
                mon.step(j, u, y)
        a = ref.step(j, tr.u[0, j], tr.y[0, j])
        b = mon.step(j, tr.u[0, j], tr.y[0, j])
        assert np.array_equal(a.detector.residual, b.detector.residual)
        assert np.array_equal(a.observer.x_hat, b.observer.x_hat)


def test_non_consecutive_sample_index_is_rejected(system, gains):
    mon = Monitor(system, gains)
    mon.step(5, [0, 0, 0], [0.4, 0.2, 0.3])
    with pytest.raises(MessageError, match="expected 6"):
        mon.step(7, [0, 0, 0], [0.4, 0.2, 0.3])
    with pytest.raises(MessageError, match="integer"):
        validate_sample(system, 1.5, [0, 0, 0], [0, 0, 0])
    mon.step(6, [0, 0, 0], [0.4, 0.2, 0.3])  # still usable


# ---------------------------------------------------------------- Monte Carlo (small)

def test_fault_free_guard_crossings_no_false_alarm_and_ablation(system, gains):
    """30 fault-free runs crossing h3 = 0.35 m both ways: no false alarm with AGEI;
    without AGEI (observer never executes autonomous transitions) false alarms appear after
    the upward crossing."""
    tr = simulate_batch(load_scenario("three_tank_nominal"), range(100, 130))
    assert np.all(np.sum(np.diff(tr.mode, axis=1) != 0, axis=1) >= 3)
    res = run_batch(system, gains, tr, keep=("mode",))
    assert not res.alarm.any()
    hi = simulate_batch(load_scenario("three_tank_guard_high"), range(100, 120))
    on = run_batch(system, gains, hi, keep=())
    off = run_batch(system, gains, hi, agei=False, keep=())
    assert not on.alarm.any()
    first_up = np.argmax(hi.mode == 1, axis=1)
    off_any = off.alarm.any(axis=2)
    assert off_any.any(axis=1).sum() >= 18
    first_fa = np.argmax(off_any, axis=1)
    assert np.all(first_fa[off_any.any(axis=1)] > first_up[off_any.any(axis=1)])


@pytest.mark.parametrize("sensor", ["h1", "h3"])
def test_bias_detected_isolated_and_estimated(system, gains, sensor):
    """5 mm bias at 200 s, 20 runs: detected within the filter window, the faulty sensor alone
    isolated; at 400 s |sigma^ - sigma| < 1.5 mm (1.5 v_bar, the tolerance of
    doc/theory/thresholds.md) and
    healthy |sigma^_j| below the isolation threshold (the isolation rule's guarantee)."""
    i = system.outputs.index(sensor)
    tr = simulate_batch(_bias_scenario(sensor, 0.005, 200.0), range(200, 220))
    res = run_batch(system, gains, tr, keep=("sigma_hat", "isolated"))
    K0 = 2000
    assert not res.alarm[:, :K0].any()
    kd = res.extra["k_detect"]
    assert np.all((kd >= K0) & (kd < K0 + gains.results["hold_steps"]))
    want = np.zeros(3, bool)
    want[i] = True
    assert np.all(res.extra["isolated"][:, -1] == want)
    sig = res.extra["sigma_hat"][:, -1]
    assert np.all(np.abs(sig[:, i] - 0.005) < 1.5e-3)
    zeta = np.delete(as_gains(system, gains).isolation_threshold, i)
    assert np.all(np.abs(np.delete(sig, i, axis=1)) < zeta)
