"""One runtime contract and one registry for every gain-file method (issue 10 items 1-2,
issue 13 item 2): the registry covers every shipped gain file, step == run == run_batch,
unknown methods fail in one line, and ``analyze``/``report`` run ``hinf_sc`` and
``hminus_switched`` bags (a fault injected: alarm after the onset, none before), with alarm
episodes outside the certified region marked."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from fd_monitor.analysis.evaluate import get_runner
from fd_monitor.commands.analyze import analyze_arrays, analyze_bag
from fd_monitor.core.generalized_observer import simulate_switched
from fd_monitor.core.methods import RUNTIMES, load_gains, runtime_class, runtime_for
from fd_monitor.core.runtime import HinfScRuntime, HminusSwitchedRuntime
from fd_monitor.core.simulator import simulate
from fd_monitor.model.errors import BagError, GainFileError, MessageError
from fd_monitor.model.gains import save_gains
from fd_monitor.model.scenario import load_scenario, parse_scenario
from fd_monitor.model.system import load_system
from fd_monitor.wire.bag_reader import arrays_from
from fd_monitor.wire.bag_writer import write_bag

GAINS_DIR = Path(__file__).resolve().parents[1] / "config" / "gains"
GAIN_FILES = sorted(p.stem for p in GAINS_DIR.glob("*.yaml"))
K = 60


def _loaded(name: str):
    raw = load_gains(name, verify=False)
    system = load_system(raw.system_name)
    return system, load_gains(name, system)


def _fk_fault():
    """Farhat & Koenig fault channel (E_f per mode, F_f) of the design file."""
    path = Path(__file__).resolve().parents[1] / "config" / "systems" / \
        "farhat_koenig.design.yaml"
    doc = yaml.safe_load(path.read_text())["hminus_switched"]["fault"]
    return ([np.asarray(doc["E_f"][m], float) for m in ("mode1", "mode2")],
            np.asarray(doc["F_f"], float))


def _stream(system, gf, n_samples=K, seed=0):
    """(u (K, nu), y (K, ny), side) of a short fault-free run of the gain file's plant."""
    rng = np.random.default_rng(seed)
    side: dict[str, np.ndarray] = {}
    if gf.method in ("thresholds", "qb", "hinf_sc"):
        # the thesis banks' scenarios inject their first fault at 30 s, after these samples;
        # the identified motor runs on data of the true one it was identified from
        sc = {"dc_motor_identified": "dc_motor_nominal"}.get(system.name) or {
            "thresholds": "three_tank_nominal", "qb": "pwa_cascade_nominal"}.get(
            gf.method, "three_tank_lpv_nominal" if system.name == "three_tank_lpv"
            else f"{system.name}_overlap")
        tr = simulate(load_scenario(sc), seed, n_samples)
        if "rho" in runtime_for(system, gf).side_inputs:
            side["rho"] = tr.rho[0]
        return tr.u[0], tr.y[0], side
    modes = rng.integers(0, 2, n_samples)
    Ef, Ff = _fk_fault()
    A = [m.A for m in system.modes]
    C = [m.C for m in system.modes]
    B = [m.B for m in system.modes]
    _x, y = simulate_switched(A, B, C, Ef, [Ff, Ff], modes, system.initial_state)
    side["mode"] = modes.astype(float)
    return np.zeros((n_samples, 0)), y, side


@pytest.mark.parametrize("name", GAIN_FILES)
def test_registry_runs_every_shipped_gain_file(name):
    """Every gain file's method has a runtime; one step gives the named outputs."""
    system, gf = _loaded(name)
    rt = runtime_for(system, gf)
    assert type(rt) is RUNTIMES[gf.method] and rt.method == gf.method
    assert set(rt.side_inputs) <= set(rt.SIDE_SIGNALS)
    u, y, side = _stream(system, gf, 3)
    o = rt.step(0, u[0], y[0], {n: v[0] for n, v in side.items()} or None)
    m = len(rt.channels)
    assert m >= 1 and len(rt.units) == m
    assert o.residual.shape == o.threshold.shape == o.alarm.shape == (m,)
    assert o.alarm.dtype == bool and np.all(o.threshold > 0)
    assert (o.outside is None) == (not rt.region_names)
    if o.outside is not None:
        assert o.outside.shape == (len(rt.region_names),)
    assert isinstance(o.mode, int) and 0 <= o.mode < len(system.modes)


@pytest.mark.parametrize("name", GAIN_FILES)
def test_step_equals_run_equals_batch(name):
    """Sample by sample == the whole-stream form (bit-identical) == the Monte Carlo form
    (bit-identical, except qb's vectorised batch: 1e-12 relative)."""
    system, gf = _loaded(name)
    u, y, side = _stream(system, gf)
    rt = runtime_for(system, gf)
    steps = [rt.step(k, u[k], y[k], {n: v[k] for n, v in side.items()} or None)
             for k in range(K)]
    rt.reset()
    tr = rt.run(np.arange(K), u, y, side or None)
    np.testing.assert_array_equal(tr.residual, [o.residual for o in steps])
    np.testing.assert_array_equal(tr.threshold, [o.threshold for o in steps])
    np.testing.assert_array_equal(tr.alarm, [o.alarm for o in steps])
    np.testing.assert_array_equal(tr.mode, [o.mode for o in steps])
    if rt.region_names:
        np.testing.assert_array_equal(tr.outside, [o.outside for o in steps])
    u2, y2, side2 = _stream(system, gf, seed=1)
    traj = SimpleNamespace(k=np.arange(K), u=np.stack([u, u2]), y=np.stack([y, y2]),
                           **{n: np.stack([side[n], side2[n]]) for n in side})
    res = get_runner(gf.method)(system, gf, traj)
    assert res.channels == rt.channels
    tol = {"rtol": 1e-12, "atol": 1e-15} if gf.method == "qb" else {"rtol": 0, "atol": 0}
    np.testing.assert_allclose(res.residual[0], tr.residual, **tol)
    np.testing.assert_array_equal(res.alarm[0], tr.alarm)
    rt.reset()
    tr2 = rt.run(np.arange(K), u2, y2, side2 or None)
    np.testing.assert_allclose(res.residual[1], tr2.residual, **tol)


def test_unknown_method_is_one_line():
    with pytest.raises(GainFileError) as ei:
        runtime_for(load_system("three_tank"), SimpleNamespace(method="kalman_bank"))
    msg = str(ei.value)
    assert "\n" not in msg
    assert msg == ("method 'kalman_bank': no runtime for it; known methods: hinf_sc, "
                   "hminus_switched, qb, thresholds")
    with pytest.raises(GainFileError, match="no runtime"):
        runtime_class("nope")
    system, gf = _loaded("three_tank_lpv_hinf_sc")
    with pytest.raises(GainFileError, match=r"no option agei \(options: discretisation\)"):
        runtime_for(system, gf, agei=False)


def test_missing_side_signal_is_refused():
    system, gf = _loaded("farhat_koenig_hminus_switched")
    rt = runtime_for(system, gf)
    assert rt.side_inputs == ("mode",)
    with pytest.raises(MessageError, match="sample 4: side signal 'mode' missing"):
        rt.step(4, [], [0.1, 0.2])
    system, gf = _loaded("thesis_6_5_hinf_sc")
    with pytest.raises(MessageError, match="side signal 'rho' missing"):
        runtime_for(system, gf).step(0, [0.0, 0.0], [0.0, 0.0])


def test_hminus_mode_from_an_input_channel_and_outside_mode():
    """A plant input named ``mode`` is the switching signal (same residuals as the side
    signal); a mode the design does not have is reported in ``outside`` and the last valid
    mode is kept."""
    from fd_monitor.model.system import parse_system, read_yaml

    system, gf = _loaded("farhat_koenig_hminus_switched")
    u, y, side = _stream(system, gf)
    doc = dict(read_yaml(Path(__file__).resolve().parents[1] / "config" / "systems" /
                         "farhat_koenig.yaml"))
    doc["inputs"] = ["mode"]            # the switching signal as an input channel
    with_input = parse_system(doc, "<fk with a mode input>")
    rt_in = HminusSwitchedRuntime(with_input, gf)
    assert rt_in.mode_source == "input" and rt_in.side_inputs == ()
    a = rt_in.run(np.arange(K), side["mode"][:, None], y)
    b = runtime_for(system, gf).run(np.arange(K), u, y, side)
    np.testing.assert_array_equal(a.residual, b.residual)
    np.testing.assert_array_equal(a.mode, side["mode"].astype(int))
    rt = HminusSwitchedRuntime(system, gf)
    o = rt.step(0, [], [0.1, 0.2], {"mode": 1})
    assert o.mode == 1 and o.outside.tolist() == [0.0]
    o = rt.step(1, [], [0.1, 0.2], {"mode": 3})
    assert o.mode == 1 and o.outside.tolist() == [2.0]
    assert runtime_for(system, gf).run(np.arange(3), np.zeros((3, 0)), y[:3],
                                       {"mode": [0, 0.5, 1]}).outside[:, 0].tolist() == \
        [0.0, 0.5, 0.0]


# --------------------------------------------------------------------------------------
# analyze / report on bags


def _onset_ok(doc, onsets):
    """Every alarm episode starts at or after its channel's fault onset; each channel alarms."""
    first = {}
    for ep in doc["alarms"]:
        assert ep["first_sample"] >= onsets[ep["channel"]], ep
        first.setdefault(ep["channel"], ep["first_sample"])
    assert set(first) == set(onsets)
    return first


def test_analyze_and_report_hinf_sc_bag(tmp_path):
    """Thesis 7.2 three-tank leak bank (LPV, rho from the levels): leaks at 100, 150, 200 s
    detected after their onsets, none before; every sample inside the design box here."""
    from fd_monitor.analysis.report import bag_report
    from fd_monitor.commands.simulate import simulate_to_bag

    bag = tmp_path / "lpv"
    simulate_to_bag("three_tank_lpv_abrupt", bag)
    doc = analyze_bag(str(bag), "three_tank_lpv_hinf_sc")
    assert doc["method"] == "hinf_sc"
    first = _onset_ok(doc, {"leak1": 1000, "leak2": 1500, "leak3": 2000})
    assert first["leak1"] < 1000 + 50                  # within 5 s
    assert doc["isolated"] == ["leak1", "leak2", "leak3"]
    assert all(ep["outside_certified_region"] is False for ep in doc["alarms"])
    rep = bag_report(bag, tmp_path / "rep", gains="three_tank_lpv_hinf_sc")
    assert set(rep["figures"]) == {"residuals", "modes"}
    md = Path(rep["summary_md"]).read_text()
    assert "method `hinf_sc`" in md and "| leak1 | 10" in md


def test_lpv_run_outside_its_design_range_is_marked(tmp_path):
    """h2 driven to 0.5 m: rho3 = 1/sqrt(h2) = 1.41 < rho_min 1.5; the leak alarm is raised and
    its episode marked outside the certified region (rho3 below), as are the false alarms the
    bank raises off its design range."""
    system = load_system("three_tank_lpv")
    gf = load_gains("three_tank_lpv_hinf_sc", system)
    pi = {"kp": 5e-3, "ki": 4e-4, "min": 0.0, "max": 1.5e-4}
    sc = parse_scenario({
        "name": "off_design", "system": "three_tank_lpv", "duration": 200.0, "seed": 0,
        "inputs": {"q1": {"pi": {"output": "h1", "reference": {"constant": 0.7}, **pi}},
                   "q2": {"pi": {"output": "h2", "reference": {"constant": 0.5}, **pi}},
                   "v13": 0.0},
        "faults": [{"channel": "leak1", "profile": "abrupt", "time": 150.0,
                    "magnitude": 1e-5}]}, system=system)
    tr = simulate(sc, 0)
    doc = analyze_arrays(system, gf, tr.k, tr.u[0], tr.y[0])
    eps = [e for e in doc["alarms"] if e["channel"] == "leak1" and e["first_sample"] >= 1500]
    assert eps and eps[0]["outside_certified_region"] is True
    # off design the bank also raises alarms of the healthy tanks: all of them marked
    assert all(e["outside_certified_region"] for e in doc["alarms"])
    assert "rho3 below by" in eps[0]["outside_detail"]
    rt = runtime_for(system, gf)
    o = rt.run(tr.k, tr.u[0], tr.y[0])
    assert np.all(o.outside[-100:, 2] < -0.05)          # 1/sqrt(0.5) - 1.5 = -0.086
    nominal = simulate(load_scenario("three_tank_lpv_nominal"), 0, 1500)
    rt.reset()
    assert not rt.run(nominal.k, nominal.u[0], nominal.y[0]).outside[600:].any()


def _fk_bag(tmp_path, with_mode=True):
    """Farhat & Koenig switched plant, random switching, step fault f = 1 from sample 300,
    bounded output noise; bag with /plant/y, /plant/mode (the measured switching signal)
    and /plant/truth."""
    system = load_system("farhat_koenig")
    rng = np.random.default_rng(3)
    Kf = 600
    modes = (rng.random(Kf) < 0.5).astype(int)
    f = np.zeros((Kf, 1))
    f[300:] = 1.0
    Ef, Ff = _fk_fault()
    x, y = simulate_switched([m.A for m in system.modes], [m.B for m in system.modes],
                             [m.C for m in system.modes], Ef, [Ff, Ff], modes,
                             system.initial_state, f=f)
    y = y + rng.uniform(-1e-3, 1e-3, y.shape)
    k = np.arange(Kf)
    ns = np.rint(k * system.sample_time * 1e9).astype(np.int64)
    topics = [arrays_from("/plant/y", system.outputs, k, y, ns),
              arrays_from("/plant/truth", ("mode", *(f"x.{s}" for s in system.states)), k,
                          np.column_stack([modes, x]), ns)]
    if with_mode:
        topics.append(arrays_from("/plant/mode", ("mode",), k, modes[:, None].astype(float),
                                  ns))
    bag = write_bag(tmp_path / ("fk" if with_mode else "fk_nomode"), topics)
    return system, bag, k, y, modes


def _fk_gains_with_threshold(tmp_path, system, k, y, modes):
    """The shipped gain file with the threshold of this noisy bag (1.5 x max ||r|| of its
    fault-free part after 5 s; the shipped threshold is for the paper's noise-free plant),
    written by the gain-file writer where the runtime reads it (observers.hminus)."""
    gf = load_gains("farhat_koenig_hminus_switched", system)
    rt = runtime_for(system, gf)
    r = rt.run(k[:300], np.zeros((300, 0)), y[:300], {"mode": modes[:300]}).residual
    obs = dict(gf.results["observers"])
    obs["hminus"] = dict(obs["hminus"], threshold=1.5 * float(r[50:].max()))
    res = dict(gf.results, observers=obs,
               threshold_method={"method": "monte_carlo", "runs": 1, "settle_s": 5.0,
                                 "margin": 1.5})
    path = save_gains(tmp_path / "fk_gains.yaml", gf.method, system, gf.parameters, res,
                      gf.certificate, gf.solver)
    return str(path)


def test_analyze_and_report_hminus_switched_bag(tmp_path):
    """Switched plant, mode from /plant/mode: the step fault at sample 300 is detected after
    its onset and never before; every mode is a design mode (inside)."""
    from fd_monitor.analysis.report import bag_report

    system, bag, k, y, modes = _fk_bag(tmp_path)
    gains = _fk_gains_with_threshold(tmp_path, system, k, y, modes)
    doc = analyze_bag(str(bag), gains)
    assert doc["method"] == "hminus_switched" and doc["samples"] == 600
    first = _onset_ok(doc, {"r_norm": 300})
    assert first["r_norm"] < 300 + 20
    assert all(ep["outside_certified_region"] is False for ep in doc["alarms"])
    assert doc["mode_agreement"] == 1.0                 # the measured mode is the true one
    rep = bag_report(bag, tmp_path / "rep", gains=gains)
    assert Path(rep["figures"]["residuals"]).stat().st_size > 0
    # without /plant/mode the runtime cannot run: one line naming the topic
    _s, bag2, *_ = _fk_bag(tmp_path, with_mode=False)
    with pytest.raises(BagError, match=r"no topic /plant/mode in the bag"):
        analyze_bag(str(bag2), gains)


def test_hinf_sc_rho_side_signal_from_bag_and_outside(tmp_path):
    """Thesis 6.5 (LPV, no scheduling map): rho read from /plant/rho; the printed
    rho2(t) = cos(0.3142 t) (6.85) leaves the design box [-0.4, 0.4]: outside is marked."""
    from fd_monitor.analysis.offline import run_bag

    system, gf = _loaded("thesis_6_5_hinf_sc")
    Kr = 400
    tr = simulate(load_scenario("thesis_6_5_overlap"), 0, Kr)
    u, y = tr.u[0], tr.y[0]
    t = tr.t
    # the measured rho2 the bag carries is the printed cos(0.3142 t), outside [-0.4, 0.4]
    rho = np.column_stack([0.5 * np.sin(t), np.cos(0.3142 * t)])
    k = np.arange(Kr)
    ns = np.rint(t * 1e9).astype(np.int64)
    bag = write_bag(tmp_path / "t65", [arrays_from("/plant/u", system.inputs, k, u, ns),
                                      arrays_from("/plant/y", system.outputs, k, y, ns),
                                      arrays_from("/plant/rho", ("rho1", "rho2"), k, rho,
                                                  ns)])
    run = run_bag(bag, gf, system=system)
    assert run.region_names == ("rho1", "rho2") and len(run.k) == Kr
    np.testing.assert_allclose(run.outside[:, 1], rho[:, 1] - np.clip(rho[:, 1], -0.4, 0.4))
    assert not run.outside[:, 0].any() and run.outside[0, 1] == pytest.approx(0.6)
    np.testing.assert_allclose(run.traces["rho"][:, 1], np.clip(rho[:, 1], -0.4, 0.4))
    ref = HinfScRuntime(system, gf).run(k, u, y, {"rho": rho})
    np.testing.assert_array_equal(run.signal, ref.residual)


def test_evaluate_runs_an_hinf_sc_campaign():
    """``evaluate`` takes every method: the thesis 7.2 bank over fault-free and abrupt-leak
    runs (2 seeds each): no false alarm after the 60 s start-up, every leak detected."""
    from fd_monitor.analysis.evaluate import run_campaign

    system = load_system("three_tank_lpv")
    gf = load_gains("three_tank_lpv_hinf_sc", system)
    rows = run_campaign(gf, [load_scenario("three_tank_lpv_nominal"),
                             load_scenario("three_tank_lpv_abrupt")], 2, transient=60.0,
                        progress=False)
    nominal, abrupt = rows
    assert nominal.variant == "hinf_sc" and nominal.false_alarm_rate == 0.0
    assert abrupt.false_alarm_rate == 0.0 and abrupt.detection_rate == 1.0
    assert abrupt.delay_max_s is not None and abrupt.delay_max_s < 2.0


def test_regression_library_takes_an_hinf_sc_bag(tmp_path):
    """A library bag with an ``hinf_sc`` gain file: generated, its expectations proposed from
    one analysis and the truth, honest (check_truth: no alarm before the onsets, the leaking
    tanks isolated) and met (check_expected)."""
    from fd_monitor.analysis.expectations import (
        analyze_summary,
        check_expected,
        check_truth,
        propose_expected,
    )
    from fd_monitor.analysis.generate import generate_bag
    from fd_monitor.analysis.library import load_library

    (tmp_path / "library.yaml").write_text(yaml.safe_dump({"format_version": 1, "bags": [
        {"name": "lpv_leaks", "scenario": "three_tank_lpv_abrupt", "seed": 2,
         "duration": 300.0, "gains": "three_tank_lpv_hinf_sc", "transient": 60.0,
         "description": "leaks at 100, 150, 200 s"}]}))
    spec = load_library(tmp_path / "library.yaml")["lpv_leaks"]
    generate_bag(spec)
    system = load_system("three_tank_lpv")
    summary = analyze_summary(spec.folder, spec.gains, transient=spec.transient)
    assert summary["channels"] == ["leak1", "leak2", "leak3"]
    doc = propose_expected(spec, summary, system)
    assert set(doc["alarms"]) == {"leak1", "leak2", "leak3"} and doc["no_alarm"] == []
    assert doc["isolated"] == ["leak1", "leak2", "leak3"] and doc["bias_estimate"] == {}
    assert check_truth(spec, doc, system) == []
    assert check_expected(doc, summary) == []


def test_hminus_mode_from_the_plants_guards():
    """A switched plant whose plant file has guards: the runtime follows them on its estimate
    (no side signal needed) and, once the observer has converged, uses the true mode."""
    from fd_monitor.core.plant import SampledPlant
    from fd_monitor.model.system import parse_system, read_yaml

    _s, gf = _loaded("farhat_koenig_hminus_switched")
    doc = dict(read_yaml(Path(__file__).resolve().parents[1] / "config" / "systems" /
                         "farhat_koenig.yaml"))
    doc["guards"] = [
        {"from": "mode1", "to": "mode2", "kind": "autonomous",
         "when": [{"var": "x1", "op": ">", "value": 0.0}]},
        {"from": "mode2", "to": "mode1", "kind": "autonomous",
         "when": [{"var": "x1", "op": "<=", "value": 0.0}]}]
    doc["initial"] = {"mode": "mode1", "state": [-1.0, 2.0, 3.0]}
    system = parse_system(doc, "<fk with guards>")
    plant = SampledPlant(system)
    Kg = 300
    x, q = np.array([[-1.0, 2.0, 3.0]]), np.array([0])
    xs, qs = np.empty((Kg, 3)), np.empty(Kg, int)
    for k in range(Kg):
        xs[k], qs[k] = x[0], q[0]
        # a slow forced oscillation of x1 around 0 so the guards fire repeatedly
        x = plant.step(q, x, np.zeros((1, 0))) + np.array([[0.3 * np.sin(0.1 * k), 0, 0]])
        q = plant.next_mode(q, x, np.zeros((1, 0)), "autonomous")
    assert np.count_nonzero(np.diff(qs)) >= 6          # the guards fire repeatedly
    rt = HminusSwitchedRuntime(system, gf)
    assert rt.mode_source == "guards" and rt.side_inputs == ()
    y = xs @ system.modes[0].C.T
    tr = rt.run(np.arange(Kg), np.zeros((Kg, 0)), y)
    assert np.mean(tr.mode[100:] == qs[100:]) > 0.9


def test_analyze_reads_the_bag_once(monkeypatch):
    """`analyze` opens and reads a bag once (topics, labels, inputs, truth from one pass)."""
    import fd_monitor.analysis.reader as reader

    calls = []
    real = reader.read_raw

    def counting(*a, **kw):
        calls.append(a[0])
        return real(*a, **kw)

    monkeypatch.setattr(reader, "read_raw", counting)    # the contract reader analyze runs
    bag = Path(__file__).resolve().parents[1] / "bags" / "three_tank_bias_h1"
    doc = analyze_bag(str(bag), "three_tank_thresholds")
    assert doc["isolated"] == ["h1"] and doc["transitions_true"] is not None
    assert len(calls) == 1


@pytest.mark.parametrize("name", GAIN_FILES)
def test_invalid_sample_is_a_message_error_and_changes_nothing(name):
    """Every runtime refuses a NaN and a hole without reset() with a MessageError naming the
    sample, and its state is unchanged (the next valid sample gives the same output)."""
    system, gf = _loaded(name)
    u, y, side = _stream(system, gf, 3)
    sd = [{n: v[k] for n, v in side.items()} or None for k in range(3)]
    rt = runtime_for(system, gf)
    rt.step(0, u[0], y[0], sd[0])
    bad = y[1].copy()
    bad[0] = np.nan
    with pytest.raises(MessageError, match="sample 1"):
        rt.step(1, u[1], bad, sd[1])
    with pytest.raises(MessageError, match="consecutive"):
        rt.step(2, u[2], y[2], sd[2])
    a = rt.step(1, u[1], y[1], sd[1])
    ref = runtime_for(system, gf)
    ref.step(0, u[0], y[0], sd[0])
    b = ref.step(1, u[1], y[1], sd[1])
    np.testing.assert_array_equal(a.residual, b.residual)


def test_evaluate_flags_checked_against_the_runtimes_batch_options():
    """``evaluate --estimator`` / ``--state-bound`` on a method without them: one line."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "fd_monitor", "evaluate",
                          "three_tank_lpv_hinf_sc", "-s", "three_tank_lpv_nominal", "--runs",
                          "1", "--state-bound", "rho_max"], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 2
    assert out.stderr.strip() == ("fd_monitor: error: --state-bound: method 'hinf_sc' has no "
                                  "state_bound option (its batch options: discretisation)")
    assert "estimator" in RUNTIMES["qb"].batch_options()
    assert "estimator" not in RUNTIMES["thresholds"].batch_options()
