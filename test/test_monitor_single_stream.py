"""The single-stream path of the diagnosis chain (Python floats, ``Monitor.step``) computes
the bits of the batch path (numpy, :class:`BatchMonitor` / :func:`run_batch`), every field of
every component, on the bundled three_tank scenarios (the ones the bundled bags are made from,
a guard crossing, a valve switching)."""

from __future__ import annotations

import numpy as np
import pytest

from fd_monitor.core.bias_estimator import matvec
from fd_monitor.core.filters import FilterBank, FilterSpec, FloatFilter
from fd_monitor.core.methods import load_gains
from fd_monitor.core.monitor import BatchMonitor, Monitor
from fd_monitor.core.simulator import simulate_batch
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system

SCENARIOS = ("bag_three_tank_nominal", "bag_three_tank_bias_h1", "bag_three_tank_bias_h2",
             "bag_three_tank_incipient_h3", "bag_three_tank_valve", "three_tank_guard_high")


@pytest.fixture(scope="module")
def system():
    return load_system("three_tank")


@pytest.fixture(scope="module")
def gains(system):
    return load_gains("three_tank_thresholds", system)


def _fields(o) -> dict[str, np.ndarray]:
    """Every field of a MonitorOutput, by the names of BatchMonitor.step."""
    ob, d, a, e = o.observer, o.detector, o.agei, o.estimator
    return {"mode": ob.mode, "x_hat": ob.x_hat, "y_tilde": ob.y_tilde,
            "residual": d.residual, "w": d.w, "threshold": d.threshold, "nominal": d.nominal,
            "alarm": d.alarm, "trigger": a.trigger, "override": a.override, "phase": a.phase,
            "row": a.row, "mode_uncertain": a.mode_uncertain, "sigma_hat": e.sigma_hat,
            "isolated": e.isolated, "active": e.active, "k_detect": e.k_detect}


@pytest.mark.parametrize("name, agei", [*((n, True) for n in SCENARIOS),
                                        ("three_tank_guard_high", False)])
def test_single_stream_equals_batch_bit_for_bit(system, gains, name, agei):
    sc = load_scenario(name)
    tr = simulate_batch(sc, [0, 1, 2])
    K = tr.y.shape[1]
    bm = BatchMonitor(system, gains, 3, agei=agei)
    mons = [Monitor(system, gains, agei=agei) for _ in range(3)]
    events = {"trigger": 0, "alarm": 0, "active": 0}
    for j in range(K):
        b = bm.step(int(tr.k[j]), tr.u[:, j], tr.y[:, j])
        for run, mon in enumerate(mons):
            # a list of floats for one run, an array for another: both paths of the input
            u = tr.u[run, j].tolist() if run == 1 else tr.u[run, j]
            o = mon.step(int(tr.k[j]), u, tr.y[run, j])
            for field, v in _fields(o).items():
                ref = b[field][run]
                assert np.asarray(v).dtype.kind == np.asarray(ref).dtype.kind, field
                assert np.array_equal(np.asarray(v), ref, equal_nan=True), \
                    (name, j, run, field, v, ref)
            events["trigger"] += o.agei.trigger >= 0
            events["alarm"] += bool(o.alarm.any())
            events["active"] += bool(o.estimator.active)
    # the comparison covered the paths that matter for each scenario
    if "bias" in name or "incipient" in name:
        assert events["alarm"] and events["active"]
    if name == "three_tank_guard_high" and agei:
        assert events["trigger"]


def test_single_stream_restart_equals_a_fresh_monitor(system, gains):
    """reset() forgets everything: the run after it is the run of a new Monitor."""
    tr = simulate_batch(load_scenario("bag_three_tank_bias_h1"), [4])
    mon = Monitor(system, gains)
    K = tr.y.shape[1]
    for j in range(K - 200):
        o = mon.step(j, tr.u[0, j], tr.y[0, j])
    assert o.estimator.active                    # past the detection: the estimator runs
    mon.reset()
    fresh = Monitor(system, gains)
    for j in range(K - 200, K):
        a, b = mon.step(j, tr.u[0, j], tr.y[0, j]), fresh.step(j, tr.u[0, j], tr.y[0, j])
        for (f, v), w in zip(_fields(a).items(), _fields(b).values()):
            assert np.array_equal(np.asarray(v), np.asarray(w), equal_nan=True), (j, f)


@pytest.mark.parametrize("spec", [FilterSpec(np.array([0.3, -1.7e-3, 2.5, 1e-9]),
                                             np.array([1.0])),
                                  FilterSpec(np.array([0.2, 0.1]), np.array([1.0, -0.5, 0.06]))])
def test_float_filter_equals_filterbank(spec):
    rng = np.random.default_rng(1)
    x = rng.standard_normal((300, 3)) * 10.0 ** rng.integers(-6, 6, (300, 3))
    fb, ff = FilterBank(spec, (1, 3)), FloatFilter(spec, 3)
    for row in x:
        assert fb.step(row[None])[0].tolist() == ff.step(row.tolist())


@pytest.mark.parametrize("m", range(1, 8))
def test_numpy_row_sums_of_up_to_7_terms_are_left_to_right(m):
    """What the estimator's float path relies on (bias_estimator.matvec)."""
    rng = np.random.default_rng(m)
    for _ in range(2000):
        M = rng.standard_normal((1, m)) * 10.0 ** rng.integers(-8, 8, (1, m))
        X = rng.standard_normal((1, m)) * 10.0 ** rng.integers(-8, 8, (1, m))
        p = (M[0] * X[0]).tolist()
        acc = p[0]
        for v in p[1:]:
            acc += v
        assert matvec(M, X)[0, 0] == acc


def test_outside_certified_region_equals_the_region_excess(system):
    """With a certified region (three_tank_envelope), ``outside`` is CertifiedRegion.excess."""
    g = load_gains("three_tank_envelope", system)
    tr = simulate_batch(load_scenario("three_tank_guard_high"), [0])
    mon = Monitor(system, g)
    region = mon.gains.region
    assert region is not None
    # then the levels and a pump above the box (0.7 m, 1.5e-4 m^3/s), still plausible
    u = np.concatenate([tr.u[0], np.tile([2e-4, 0.0, 0.0], (50, 1))])
    y = np.concatenate([tr.y[0], np.tile([0.75, 0.2, 0.3], (50, 1))])
    outside = 0
    for j in range(y.shape[0]):
        if j == tr.y.shape[0]:
            mon.reset()
        o = mon.step(j, u[j], y[j])
        ref = region.excess(o.mode, o.observer.x_hat, u[j])
        assert np.array_equal(o.outside, ref), j
        outside += bool(np.any(ref != 0.0))
    assert outside
