"""The fast paths of the runtimes equal their references (issue 25).

* ``hinf_sc``: :meth:`ResidualBank.step` (precomputed maps; LPV: the Taylor polynomial of
  the discretisation in rho, :class:`~fd_monitor.core.residual_bank.DiscretisationPolynomial`)
  against :meth:`ResidualBank.step_reference` (re-discretised at every sample), on every
  library bag of a ``hinf_sc`` gain file -- one bag per shipped ``hinf_sc`` gain file; an
  LPV bag over its first LPV_SAMPLES, past its first fault's alarm -- and
  through the registry's runtime on a synthetic stream of every shipped ``hinf_sc`` file.
  Not bit for bit: the fast path sums ``[Ad - Ld C, Bd, Ld] [x^; u; y]`` in one product
  (another summation order) and, for an LPV bank, takes the maps from a polynomial whose
  entries are within ``table_bound`` (< TABLE_TOL = 1e-12) of the exact discretisation.
  Stated tolerance: ``|r_fast - r_ref| <= RTOL * (threshold or max |r|)`` with
  RTOL = 1e-9; the alarms agree wherever the reference's residual is farther than that
  from its threshold.
* ``qb``: the runtime's single stream on Python floats (QBObserver.step1) against its numpy
  path within 1e-12, same modes and alarms; the guards of one run on Python floats
  (:meth:`SampledPlant.next_mode1`) equal the batch comparisons
  (:meth:`SampledPlant.next_mode`) bit for bit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_monitor_single_stream import _fields as monitor_fields

from fd_monitor.analysis.library import load_library
from fd_monitor.core.methods import load_gains, runtime_for
from fd_monitor.core.plant import SampledPlant
from fd_monitor.core.residual_bank import TABLE_TOL, ResidualBank
from fd_monitor.core.runtime import HinfScRuntime
from fd_monitor.model.system import load_system
from fd_monitor.wire.bag_reader import read_bag
from fd_monitor.wire.topics import PLANT_U, PLANT_Y, side_topic

#: Relative tolerance of a fast residual (see the module docstring).
RTOL = 1e-9
#: Samples of an LPV bag run on both paths (its first fault starts at 1000, or 700).
LPV_SAMPLES = 1400

LIB = load_library()
HINF_BAGS = sorted(s.name for s in LIB.bags
                   if load_gains(s.gains, verify=False).method == "hinf_sc")
HINF_FILES = ["f16xl_hinf_sc", "thesis_4_7_hinf_sc", "thesis_5_3_hinf_sc",
              "thesis_6_5_hinf_sc", "three_tank_lpv_hinf_sc"]


def _loaded(name: str):
    raw = load_gains(name, verify=False)
    system = load_system(raw.system_name)
    return system, load_gains(name, system)


def test_every_shipped_hinf_file_has_a_library_bag_and_the_fast_path():
    files = {Path(load_gains(LIB[n].gains, verify=False).path).stem for n in HINF_BAGS}
    assert files == set(HINF_FILES)
    for name in HINF_FILES:
        system, gf = _loaded(name)
        bank = ResidualBank(system, gf)
        assert bank.fast, f"{name}: {bank.fallback}"
        if bank.kind == "lpv":
            assert 0.0 < bank.table_bound <= TABLE_TOL and bank.table_degree >= 1


@pytest.mark.parametrize("name", HINF_BAGS)
def test_fast_bank_equals_reference_on_library_bag(name):
    spec = LIB[name]
    system, gf = _loaded(Path(load_gains(spec.gains, verify=False).path).stem)
    t_u, t_y = PLANT_U.absolute, PLANT_Y.absolute
    b = read_bag(spec.folder, [t_u, t_y])
    u, y = b[t_u].values, b[t_y].values
    fast, ref = ResidualBank(system, gf), ResidualBank(system, gf, fast=False)
    rho = None
    if fast.kind == "lpv" and not fast.model.scheduling:
        t_rho = side_topic("rho").absolute
        rho = read_bag(spec.folder, [t_rho])[t_rho].values
    if fast.kind == "lpv":
        # the reference re-discretises at every sample (~1 ms): the first LPV_SAMPLES, past
        # the first fault's onset and alarm
        u, y = u[:LPV_SAMPLES], y[:LPV_SAMPLES]
        rho = None if rho is None else rho[:LPV_SAMPLES]
    x0 = np.linalg.pinv(fast.model.C) @ y[0]
    fast.reset(x0)
    ref.reset(x0)
    r_fast, r_ref = fast.run(u, y, rho), ref.run(u, y, rho)
    thr = fast.thresholds
    scale = np.where(np.isfinite(thr), thr, np.abs(r_ref).max(axis=0))
    worst = (np.abs(r_fast - r_ref) / scale).max()
    assert worst <= RTOL, f"largest difference {worst:.2e} of the threshold"
    np.testing.assert_allclose(fast.xhat, ref.xhat, rtol=0, atol=RTOL * np.abs(ref.xhat).max())
    clear = np.abs(r_ref - thr) > RTOL * scale
    assert np.array_equal((r_fast > thr)[clear], (r_ref > thr)[clear])
    assert (r_ref > thr).any(), "the bag's faults alarm (the comparison covers alarms)"


@pytest.mark.parametrize("name", HINF_FILES)
def test_fast_runtime_equals_reference_on_synthetic_stream(name):
    """The registry's runtime (validation, settling, rho clipped and its excess) on both
    paths: same thresholds, alarms, outside and x^ within RTOL."""
    system, gf = _loaded(name)
    fast, ref = HinfScRuntime(system, gf), HinfScRuntime(system, gf, fast=False)
    rng = np.random.default_rng(7)
    K = 300
    lo, hi = system.output_limits[:, 0], system.output_limits[:, 1]
    mid = np.where(np.isfinite(lo + hi), 0.5 * (lo + hi), 0.0)
    y = mid + 1e-3 * rng.standard_normal((K, system.ny))
    u = np.zeros((K, system.nu))
    side = None
    if fast.side_inputs:
        m = fast.bank.model
        # a sweep across the box and 10 % beyond it on both sides (clipped, ``outside``)
        s = np.linspace(-0.1, 1.1, K)[:, None]
        side = {"rho": m.rho_min + s * (m.rho_max - m.rho_min)}
    k = np.arange(K)
    a, b = fast.run(k, u, y, side), ref.run(k, u, y, side)
    assert np.array_equal(a.threshold, b.threshold)
    scale = max(np.abs(b.residual).max(), 1e-12)
    assert np.abs(a.residual - b.residual).max() <= RTOL * scale
    assert np.array_equal(a.alarm, b.alarm)
    if b.outside is not None:
        assert np.array_equal(a.outside, b.outside)
        if side is not None:
            assert (b.outside != 0).any()
    np.testing.assert_allclose(a.estimates["x_hat"], b.estimates["x_hat"], rtol=0,
                               atol=RTOL * max(np.abs(b.estimates["x_hat"]).max(), 1.0))


@pytest.mark.parametrize("plant", ["pwa_cascade", "three_tank"])
def test_guards_of_one_run_equal_the_batch_comparisons(plant):
    system = load_system(plant)
    sp = SampledPlant(system)
    rng = np.random.default_rng(3)
    # values on and around every guard's thresholds (ties included)
    vals = sorted({float(c.value) for g in system.guards for c in g.conditions})
    pool = np.array(vals + [v + d for v in vals for d in (-1e-12, 1e-12, -1.0, 1.0)])
    N = 400
    x = rng.choice(pool, (N, system.n))
    u = rng.choice(pool, (N, system.nu)) if system.nu else np.zeros((N, 0))
    q = rng.integers(0, len(system.modes), N)
    for kind in ("controlled", "autonomous"):
        batch = sp.next_mode(q, x, u, kind)
        one = [sp.next_mode1(int(q[i]), x[i].tolist(), u[i].tolist(), kind) for i in range(N)]
        assert one == batch.tolist()


@pytest.mark.parametrize("name", ["pwa_cascade_b1_step", "pwa_cascade_sampled_b1_step"])
def test_qb_floats_equal_the_numpy_path(name):
    """QBRuntime.step on Python floats (QBObserver.step1, the signals summed left to right)
    against its numpy path (QBObserver.step, QBDetector.signals) on a library bag of each
    shipped qb gain file: the same modes and alarms, signals within 1e-12 of their size
    (the matrix-vector products round differently in the last bit: the tolerance
    test_runtime.py states for the vectorised QB batch)."""
    spec = LIB[name]
    system, gf = _loaded(Path(load_gains(spec.gains, verify=False).path).stem)
    b = read_bag(spec.folder, [PLANT_U.absolute, PLANT_Y.absolute])
    u, y = b[PLANT_U.absolute].values, b[PLANT_Y.absolute].values
    k = np.arange(len(y))
    rt = runtime_for(system, gf)
    assert rt._floats
    fast = rt.run(k, u, y)
    rt.reset()
    rt._floats = False
    ref = rt.run(k, u, y)
    assert np.array_equal(fast.mode, ref.mode)
    assert np.abs(fast.residual - ref.residual).max() <= 1e-12 * np.abs(ref.residual).max()
    assert np.array_equal(fast.alarm, ref.alarm) and ref.alarm.any()


# --------------------------------------------------------------------------------------
# thresholds: Monitor.step (the single stream on Python floats: the three_tank RK4 compiled
# per mode, scalar linear modes on floats, the certified box and the controlled guards
# precomputed per mode, outputs with lazy arrays) against BatchMonitor (the numpy batch
# path, the reference), bit for bit.

THRESHOLD_FILES = ["dc_motor_identified_thresholds", "three_tank_envelope",
                   "three_tank_thresholds"]
#: three_tank_bad_input is left out: read_bag refuses its corrupted records (wrong length),
#: and its other samples are those of three_tank_thresholds' bias bags (covered).
THRESHOLD_BAGS = sorted(s.name for s in LIB.bags
                        if load_gains(s.gains, verify=False).method == "thresholds"
                        and s.name != "three_tank_bad_input")
#: Samples of a thresholds bag compared (the batch path costs 0.3-2 ms per sample): past the
#: first alarm and the estimator's start (sample 812-1000) in FAULT_BAGS (one per gain
#: file whose bag faults early enough); the others' first 400 (dc_motor_bias_velocity's
#: fault starts at 2500, beyond what the batch path runs here in a second or two; its
#: estimator's scalar linear steps are compared below).
FAULT_BAGS = {"three_tank_bias_h1", "three_tank_incipient_h3", "three_tank_envelope_bias_h1"}
THRESHOLD_SAMPLES = 400


def test_every_shipped_thresholds_file_has_a_library_bag():
    files = {Path(load_gains(LIB[n].gains, verify=False).path).stem for n in THRESHOLD_BAGS}
    assert files | {"three_tank_thresholds"} == set(THRESHOLD_FILES) == {
        p.stem for p in (Path(__file__).parents[1] / "config" / "gains").glob("*.yaml")
        if load_gains(p, verify=False).method == "thresholds"}


@pytest.mark.parametrize("name", THRESHOLD_BAGS)
def test_monitor_single_stream_equals_batch_on_library_bag(name):
    """Every output of Monitor.step equals BatchMonitor's (one run) bit for bit (NaN where
    NaN), dtype kinds included, up to the bag's first refused sample (three_tank_bad_input:
    a NaN the batch path does not take) or THRESHOLD_SAMPLES; the x^ box excess equals the
    reference formula's bits. The reference runs the stream twice in one batch (N = 2): with
    N = 1 and one output, FilterBank's taps are one contiguous axis and numpy sums them
    pairwise, not slice by slice (dc_motor_identified's 200-tap filter: the last bit
    differs; a property of the batch path with N = 1, not of the single stream)."""
    from fd_monitor.core.monitor import BatchMonitor, Monitor
    from fd_monitor.model.errors import MessageError

    spec = LIB[name]
    system, gf = _loaded(Path(load_gains(spec.gains, verify=False).path).stem)
    b = read_bag(spec.folder, [PLANT_U.absolute, PLANT_Y.absolute])
    u, y = b[PLANT_U.absolute].values, b[PLANT_Y.absolute].values
    mon, bm = Monitor(system, gf), BatchMonitor(system, gf, 2)
    box = mon.observer._box
    seen = {"alarm": False, "active": False}
    # dc_motor: 250 samples (past its 200-tap filter's window; its batch path costs ~4 ms
    # per sample)
    K = min(len(y), 1100 if name in FAULT_BAGS else 250 if name.startswith("dc_motor")
            else THRESHOLD_SAMPLES)
    for k in range(K):
        try:
            o = mon.step(k, u[k], y[k])
        except MessageError:
            break
        ref = bm.step(k, np.stack([u[k], u[k]]), np.stack([y[k], y[k]]))
        for field, v in monitor_fields(o).items():
            r = ref[field][0]
            assert np.asarray(v).dtype.kind == np.asarray(r).dtype.kind, (k, field)
            assert np.array_equal(v, r, equal_nan=np.asarray(r).dtype.kind == "f"), (k, field)
        if box:
            lo, hi = box[o.mode]
            z = list(o.observer.x_hat) + u[k].tolist()
            assert o.outside.tolist() == [v - min(max(v, a), c) for v, a, c in zip(z, lo, hi)]
        seen["alarm"] |= bool(o.alarm.any())
        seen["active"] |= bool(o.estimator.active)
    assert k > 100, "the comparison covers the bag"
    if name in FAULT_BAGS:
        assert seen["alarm"] and seen["active"], seen


def test_three_tank_compiled_step_equals_the_float_step_bit_for_bit():
    """The per-mode compiled RK4 (``compile_floats``) against ``step_floats`` on every mode
    of every shipped plant of the three_tank model: the same bits, signs of zero included,
    on random levels with exact zeros, ties (h1 == h3, h3 at h_upper) and negative inputs."""
    import math
    import random

    from fd_monitor.core.hybrid_observer import ModeDynamics
    from fd_monitor.model.nonlinear import get_model

    model = get_model("three_tank")
    rng = random.Random(5)
    for plant in ("three_tank", "three_tank_lpv"):
        system = load_system(plant)
        md = ModeDynamics(system)
        params = md._mode_params or [
            {**model.defaults, **{k: float(v) for k, v in m.params.items()}}
            for m in system.modes if m.model == "three_tank"]
        for p in params:
            step = model.compile_floats(p, system.sample_time)
            for _ in range(1500):
                x = [rng.choice([rng.uniform(-0.1, 0.8), 0.0, -0.0, p.get("h_upper", 0.35)])
                     for _ in range(3)]
                if rng.random() < 0.1:
                    x[2] = x[0]
                u = [rng.choice([rng.uniform(-1e-4, 1e-4), 0.0, -0.0]) for _ in range(2)]
                a = model.step_floats(x, [*u, 0.0], p, system.sample_time)
                b = step(x, [*u, 0.0])
                assert [(v, math.copysign(1.0, v)) for v in a] == \
                    [(v, math.copysign(1.0, v)) for v in b], (plant, x, u)


def test_box_excess_and_scalar_linear_steps_equal_their_references():
    """excess_map == [v - min(max(v, lo), hi)] (NaN, infinities, signed zeros); the scalar
    linear modes on floats == SampledPlant.step (dc_motor_identified)."""
    import math

    from fd_monitor.core.hybrid_observer import ModeDynamics, excess_map

    lo, hi = [-math.inf, 0.0, -1.0, 0.5], [1.0, math.inf, 1.0, 0.5]
    f = excess_map(lo, hi)
    pool = [0.3, -2.0, 2.0, 0.0, -0.0, 1.0, -1.0, 0.5, math.nan, math.inf, -math.inf]
    rng = np.random.default_rng(2)
    for z in rng.choice(pool, (2000, 4)).tolist():
        ref = [v - min(max(v, a), b) for v, a, b in zip(z, lo, hi)]
        got = f(z)
        assert [repr(v) for v in got] == [repr(v) for v in ref], z
    system = load_system("dc_motor_identified")
    md = ModeDynamics(system)
    assert md._steps1, "dc_motor_identified: scalar linear modes on floats"
    x = rng.uniform(-5.0, 5.0, (3000, 1))
    u = rng.uniform(-1.0, 1.0, (3000, 1))
    q = np.zeros(3000, dtype=int)
    batch = md.plant.step(q, x, u)
    one = [md.step1(0, x[i].tolist(), u[i].tolist()) for i in range(3000)]
    assert np.array_equal(np.array(one), batch)


def test_monitor_list_entry_and_projection_equal_batch_bit_for_bit():
    """Monitor.step fed lists of Python floats (its fast entry: no per-value check) and with
    a bias bound M_sigma small enough that the projection (eq. 26) acts after detection: every
    output equals BatchMonitor's bit for bit. With the shipped M_sigma (0.1) |sigma^| reaches
    0.025 on this bag; with 0.01 it is held near the ball's surface (the projection's
    tangent step leaves it slightly outside, far below 0.025)."""
    import dataclasses

    from fd_monitor.core.monitor import BatchMonitor, Monitor
    from fd_monitor.core.thresholds import as_gains

    system, gf = _loaded("three_tank_thresholds")
    g = dataclasses.replace(as_gains(system, gf), M_sigma=0.01)
    b = read_bag(LIB["three_tank_bias_h1"].folder, [PLANT_U.absolute, PLANT_Y.absolute])
    u, y = b[PLANT_U.absolute].values, b[PLANT_Y.absolute].values
    mon, bm = Monitor(system, g), BatchMonitor(system, g, 2)
    norms = []
    for k in range(1100):
        o = mon.step(k, u[k].tolist(), y[k].tolist())
        ref = bm.step(k, np.stack([u[k], u[k]]), np.stack([y[k], y[k]]))
        for field, v in monitor_fields(o).items():
            r = ref[field][0]
            assert np.asarray(v).dtype.kind == np.asarray(r).dtype.kind, (k, field)
            assert np.array_equal(v, r, equal_nan=np.asarray(r).dtype.kind == "f"), (k, field)
        norms.append(float(np.linalg.norm(o.sigma_hat)))
    assert 0.01 <= max(norms) < 0.0125, max(norms)
