"""The simulator on LPV / uncertain plants (A_rho, B_rho) and on the switched Farhat & Koenig
plant: rho(t) from a profile or from the state (thesis eq. 7.19), an imposed switching
schedule, scenario fault channels, fault injection, and one-line errors for bad scenarios."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from fd_monitor.core.generalized_observer import simulate_switched
from fd_monitor.core.hinf_model import AffineModel
from fd_monitor.core.methods import load_gains
from fd_monitor.core.plant import rk4_step
from fd_monitor.core.simulator import simulate, truth_values
from fd_monitor.model.errors import ScenarioError
from fd_monitor.model.nonlinear import SCHEDULING_MAPS
from fd_monitor.model.paths import find_config_file
from fd_monitor.model.scenario import load_scenario, parse_scenario
from fd_monitor.model.system import load_system, parse_system
from fd_monitor.wire.topics import PLANT_TRUTH, side_topic

SCEN = Path(__file__).resolve().parent.parent / "config" / "scenarios"
SYS = Path(__file__).resolve().parent.parent / "config" / "systems"


def _scenario_doc(name: str) -> dict[str, Any]:
    return yaml.safe_load((SCEN / f"{name}.yaml").read_text())


def _model_of(system) -> AffineModel:
    m = system.modes[0]
    d = system.n_rho
    return AffineModel(m.A, m.A_rho, m.B, np.zeros((d, system.n, system.nu)), m.C,
                       np.array([p.min for p in system.lpv]),
                       np.array([p.max for p in system.lpv]))


def _reference_run(model: AffineModel, t: np.ndarray, u, rho) -> tuple[np.ndarray, np.ndarray]:
    """Reference: ``dx/dt = A(rho(t)) x + B(rho(t)) u_k`` per sample, u held, 10 RK4 substeps,
    written from the equation (x (K, n), y (K, p))."""
    x = np.zeros(model.n)
    xs = np.empty((t.size, model.n))
    for k in range(t.size):
        xs[k] = x
        uk = np.asarray(u(t[k]), dtype=float)
        x = rk4_step(lambda tt, xx, uk=uk: model.A(rho(tt)) @ xx + model.B(rho(tt)) @ uk,
                     float(t[k]), x, float(t[1] - t[0]), 10)
    return xs, xs @ model.C.T


@pytest.mark.parametrize("name", ["thesis_5_3_overlap", "thesis_6_5_overlap"])
def test_lpv_profile_run_equals_reference_integration(name):
    """rho(t) from profiles: the simulator integrates A(rho(t)) inside each sample (RK4, 10
    substeps) as the reference loop does; actuator faults held over the sample; truth
    rho.<name> = the profile at t_k."""
    doc = _scenario_doc(name)
    # 12 s (the reference loop is slow): a whole period of both inputs (7 s, 3 s) and of
    # rho (1 s; 6.5: 10 s and more than half of 20 s), f1 moved to 8 s, f2 (60 s) dropped
    doc["duration"] = 12.0
    doc["faults"] = [dict(doc["faults"][0], time=8.0)]
    kf = 800                                       # f1's onset sample
    sc = parse_scenario(doc, str(SCEN / f"{name}.yaml"))
    tr = simulate(sc)
    system = sc.system
    dt = system.sample_time
    t = np.arange(tr.k.size) * dt
    prof = sc.scheduling.profiles

    def u_applied(tt: float) -> np.ndarray:
        k = round(tt / dt)
        return np.array([p.value(tt) for p in sc.inputs]) + np.array([float(k >= kf), 0.0])

    def rho_of(tt: float) -> np.ndarray:
        return np.array([p.value(tt) for p in prof])

    x, y = _reference_run(_model_of(system), t, u_applied, rho_of)
    rho = np.array([rho_of(tt) for tt in t])
    np.testing.assert_allclose(tr.x[0], x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(tr.y[0], y, rtol=1e-12, atol=1e-12)
    assert PLANT_TRUTH.labels(sc)[-len(prof):] == tuple(f"rho.{p.name}" for p in system.lpv)
    np.testing.assert_array_equal(tr.rho[0], rho)
    if name == "thesis_5_3_overlap":
        np.testing.assert_allclose(tr.rho[0, :, 0], np.sin(2 * np.pi * t), atol=1e-12)
    else:
        np.testing.assert_allclose(tr.rho[0, :, 1], 0.4 * np.cos(0.3142 * t), atol=1e-4)
    lo = [p.min for p in system.lpv]
    hi = [p.max for p in system.lpv]
    assert (tr.rho[0] >= np.array(lo) - 1e-12).all() and (tr.rho[0] <= hi).all()
    # fault injection: f1 = 1 from sample 800 on, f2 never in 12 s
    np.testing.assert_array_equal(tr.faults[0, :, 0], (tr.k >= kf).astype(float))
    assert not tr.faults[0, :, 1].any()


def _quasi_lpv_three_tank():
    """The thesis' quasi-LPV model (7.13)-(7.21) of three_tank_lpv as an A_rho plant whose rho
    the scenario computes from the state by the map three_tank_sqrt (7.19)."""
    des = yaml.safe_load((SYS / "three_tank_lpv.design.yaml").read_text())["hinf_sc"]
    doc = {"format_version": 1, "name": "three_tank_quasi_lpv", "time": "continuous",
           "sample_time": 0.1, "states": ["h1", "h2", "h3"], "inputs": ["q1", "q2", "v13"],
           "outputs": ["h1", "h2", "h3"],
           "lpv": {"parameters": [{"name": f"rho{i + 1}", "min": 0.0, "max": 100.0,
                                   "measured": True} for i in range(3)]},
           "modes": {"closed": {"A": des["model"]["A0"], "A_rho": des["A_rho"],
                                "B": des["model"]["B0"], "C": np.eye(3).tolist()}},
           "initial": {"mode": "closed", "state": [0.5, 0.2, 0.35]}}
    return parse_system(doc, "<quasi-lpv>")


def test_lpv_rho_from_the_state_reproduces_the_nonlinear_three_tank():
    """rho = three_tank_sqrt(x) (thesis 7.19) evaluated on the true state inside each sample:
    the quasi-LPV plant A(rho(x)) x + B q is the nonlinear three-tank (flows S_n sqrt(2 g dh)),
    so both simulations agree (measured to 1e-13 m)."""
    inputs = {"q1": 1.2e-4, "q2": 0.4e-4, "v13": 0.0}
    sched = {"map": "three_tank_sqrt", "params": {"min_difference": 1.0e-3}}
    lpv = parse_scenario({"system": "three_tank_lpv", "duration": 100.0, "inputs": inputs,
                          "scheduling": sched}, "<lpv>", _quasi_lpv_three_tank())
    nl = parse_scenario({"system": "three_tank_lpv", "duration": 100.0, "inputs": inputs,
                         "scheduling": dict(sched, names=["rho1", "rho2", "rho3"])}, "<nl>")
    a, b = simulate(lpv), simulate(nl)
    assert np.abs(a.x[0, -1] - a.x[0, 0]).max() > 0.01           # the levels move
    np.testing.assert_allclose(a.x[0], b.x[0], atol=1e-10)   # measured 8e-14
    # truth rho is the map of the true state at t_k, in both
    want = np.array([SCHEDULING_MAPS["three_tank_sqrt"](x, {}) for x in b.x[0]])
    np.testing.assert_allclose(b.rho[0], want, rtol=1e-12)
    assert PLANT_TRUTH.labels(nl)[-3:] == ("rho.rho1", "rho.rho2", "rho.rho3")
    assert truth_values(b).shape == (1000, 1 + 3 + 3 + 3)


def test_switched_schedule_and_fault_channel_equal_simulate_switched():
    """Farhat & Koenig: the imposed schedule is the mode sequence; with the scenario's fault
    channel (the design file's E_f,i and F_f) the run equals generalized_observer's
    simulate_switched."""
    sc = load_scenario("bag_farhat_koenig_fault")
    system = sc.system
    des = yaml.safe_load((SYS / "farhat_koenig.design.yaml").read_text())
    fault = des["hminus_switched"]["fault"]
    ch = system.fault("f")
    # the added channel is the simulation's: the plant keeps its identity (the gain file's)
    assert system.sha256 == load_system("farhat_koenig").sha256
    assert load_gains("farhat_koenig_hminus_switched", system).certificate_status == "verified"
    for q, m in enumerate(system.modes):       # the scenario's numbers are the design file's
        np.testing.assert_array_equal(ch.direction(q, 3), np.ravel(fault["E_f"][m.name]))
    np.testing.assert_array_equal(ch.E, np.ravel(fault["F_f"]))
    tr = simulate(sc)
    t = tr.t
    want = np.zeros(t.size, dtype=int)
    for tk, name in yaml.safe_load((SCEN / "bag_farhat_koenig_fault.yaml").read_text())[
            "switching"]["schedule"]:
        want[t >= tk - 1e-9] = system.mode_index(name)
    np.testing.assert_array_equal(tr.mode[0], want)
    f = tr.faults[0]
    assert (f[t < 30.0] == 0).all() and (f[t >= 30.0] == 1.0).all()
    Ef = [np.asarray(fault["E_f"][m.name], float) for m in system.modes]
    Ff = [np.asarray(fault["F_f"], float)] * 2
    x, y = simulate_switched([m.A for m in system.modes], [m.B for m in system.modes],
                             [m.C for m in system.modes], Ef, Ff, want, system.initial_state,
                             f=f)
    np.testing.assert_allclose(tr.x[0], x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(tr.y[0], y, rtol=1e-12, atol=1e-12)


def test_without_schedule_the_plant_rule_holds():
    """No switching key: the plant file's rule (farhat_koenig has no guards: mode1 throughout);
    a schedule on a plant with guards overrides them."""
    doc = _scenario_doc("bag_farhat_koenig_fault")
    del doc["switching"]
    tr = simulate(parse_scenario(doc, str(SCEN / "x.yaml")))
    assert (tr.mode[0] == 0).all()
    doc = _scenario_doc("bag_three_tank_valve")
    doc["switching"] = {"schedule": [[0.0, "closed_dry"]]}
    guarded = simulate(parse_scenario(_scenario_doc("bag_three_tank_valve"),
                                      str(SCEN / "bag_three_tank_valve.yaml")))
    forced = simulate(parse_scenario(doc, str(SCEN / "bag_three_tank_valve.yaml")))
    assert len(set(guarded.mode[0])) > 1 and set(forced.mode[0]) == {0}


def test_random_switching_per_run_from_its_seed():
    """switching.random: dwell times within [min, max] (to a sample), the other mode at each
    switch, different sequences per seed, a run independent of its batch, and the run is the
    switched plant driven by its recorded mode sequence."""
    from fd_monitor.core.simulator import simulate_batch

    doc = _scenario_doc("bag_farhat_koenig_fault")
    doc["switching"] = {"random": {"min_dwell": 0.5, "max_dwell": 2.0}}
    sc = parse_scenario(doc, str(SCEN / "x.yaml"))
    tr = simulate_batch(sc, [1, 2])
    assert not np.array_equal(tr.mode[0], tr.mode[1])
    for q in tr.mode:
        edges = np.flatnonzero(np.diff(q)) + 1
        assert edges.size >= 30                       # 60 s / <= 2 s
        dwell = np.diff(np.r_[0, edges])
        assert dwell.min() >= 5 - 1 and dwell.max() <= 20 + 1, (dwell.min(), dwell.max())
    alone = simulate(sc, 2)
    np.testing.assert_array_equal(alone.mode[0], tr.mode[1])
    np.testing.assert_allclose(alone.y[0], tr.y[1], rtol=1e-12)   # BLAS: batch-size rounding
    system = sc.system
    ch = system.fault("f")
    x, y = simulate_switched([m.A for m in system.modes], [m.B for m in system.modes],
                             [m.C for m in system.modes],
                             [ch.direction(q, 3)[:, None] for q in range(2)],
                             [ch.E[:, None]] * 2, tr.mode[0], system.initial_state,
                             f=tr.faults[0])
    np.testing.assert_allclose(tr.x[0], x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(tr.y[0], y, rtol=1e-12, atol=1e-12)


def test_incipient_leak_on_the_lpv_three_tank():
    """Parameter fault (leak area) with the incipient profile of thesis eq. 1.4: the truth
    column follows delta (1 - exp(-alpha (t - t_f))) from the onset sample."""
    tr = simulate(load_scenario("bag_three_tank_lpv_incipient"))
    t = tr.t
    leak1 = tr.faults[0, :, 0]
    k0 = 1000
    assert not leak1[:k0 + 1].any()
    np.testing.assert_allclose(leak1[k0:], 1e-5 * (1 - np.exp(-0.05 * (t[k0:] - 100.0))),
                               rtol=1e-12, atol=1e-20)


BAD = [
    ("thesis_5_3_overlap", lambda d: d.pop("scheduling"),
     r"scheduling: expected rho\(t\) for the lpv parameters \['rho'\]"),
    ("thesis_5_3_overlap", lambda d: d.update(scheduling={"rho": {"constant": 1.5}}),
     r"scheduling\.rho: expected values inside the parameter box \[-1, 1\]"),
    ("thesis_6_5_overlap", lambda d: d["scheduling"].pop("rho2"),
     r"scheduling\.rho2: expected a profile for each lpv parameter"),
    ("thesis_5_3_overlap", lambda d: d.update(scheduling={"rho": {"saw": 1}}),
     r"scheduling\.rho: expected one of \{constant, steps, ramp, sine"),
    ("bag_three_tank_lpv_abrupt", lambda d: d["scheduling"].update(map="cube_root"),
     r"scheduling\.map: expected one of \['three_tank_sqrt'\]"),
    ("bag_three_tank_lpv_abrupt", lambda d: d["scheduling"].update(names=["a", "b"]),
     r"scheduling\.names: expected 3 parameter names"),
    ("thesis_5_3_overlap", lambda d: d.update(scheduling={"map": "three_tank_sqrt"}),
     r"scheduling\.names: expected 3 parameter names"),
    ("bag_farhat_koenig_fault", lambda d: d["switching"]["schedule"].append([59.0, "mode3"]),
     r"switching\.schedule\[23\]\[1\]: expected one of the modes \['mode1', 'mode2'\]"),
    ("bag_farhat_koenig_fault", lambda d: d["switching"]["schedule"].append([1.0, "mode1"]),
     r"switching\.schedule\[23\]\[0\]: expected times in increasing order"),
    ("bag_farhat_koenig_fault", lambda d: d.update(switching=[[0, "mode1"]]),
     r"switching: expected \{schedule: \[\[time, mode\], \.\.\.\]\} or \{random: "),
    ("bag_farhat_koenig_fault",
     lambda d: d.update(switching={"random": {"min_dwell": 0.05, "max_dwell": 1.0}}),
     r"switching\.random\.min_dwell: expected at least one sample \(0\.1 s\)"),
    ("bag_farhat_koenig_fault", lambda d: d["fault_channels"][0]["F"].update(mode1=[1.0]),
     r"fault_channels\[0\]\.F\.mode1: expected"),
    ("bag_farhat_koenig_fault", lambda d: d["fault_channels"][0].update(kind="leak"),
     r"fault_channels\[0\]\.kind: expected one of"),
]


@pytest.mark.parametrize(("name", "mutate", "match"), BAD)
def test_bad_scenario_is_one_line_naming_file_and_field(tmp_path, name, mutate, match):
    doc = _scenario_doc(name)
    mutate(doc)
    p = tmp_path / f"{name}.yaml"
    p.write_text(yaml.safe_dump(doc))
    with pytest.raises(ScenarioError) as ei:
        load_scenario(p)
    msg = str(ei.value)
    assert msg.startswith(f"{p}: ") and "\n" not in msg
    assert __import__("re").search(match, msg), msg


def test_simulate_cli_bad_scheduling_exits_2_with_one_line(tmp_path):
    doc = _scenario_doc("thesis_5_3_overlap")
    doc["scheduling"] = {"rho": {"sine": {"amplitude": 2.0, "period": 1.0}}}
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(doc))
    out = subprocess.run([sys.executable, "-m", "fd_monitor", "simulate", str(p), "-o",
                          str(tmp_path / "bag")], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert out.stderr.strip().count("\n") == 0
    assert out.stderr.startswith(f"fd_monitor: error: {p}: scheduling.rho: expected values "
                                 f"inside the parameter box [-1, 1] (the profile spans [-2, 2])")
    assert not (tmp_path / "bag").exists()


def test_simulate_cli_writes_rho_and_mode_to_the_truth(tmp_path):
    """`simulate` -> bag for an uncertain plant: rho and the mode on /plant/truth by label."""
    from fd_monitor.wire.bag_reader import read_bag

    out = subprocess.run([sys.executable, "-m", "fd_monitor", "simulate", "thesis_5_3_overlap",
                          "--duration", "2.0", "-o", str(tmp_path / "bag"), "--json"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    tr = read_bag(tmp_path / "bag", ["/plant/truth"])["/plant/truth"]
    assert len(tr) == 200
    np.testing.assert_allclose(tr.column("rho.rho"), np.sin(2 * np.pi * 0.01 * tr.stamps),
                               atol=1e-12)
    assert (tr.column("mode") == 0).all()
    assert find_config_file("thesis_5_3_overlap", "scenarios", ScenarioError).is_file()
    assert load_system("thesis_5_3").n_rho == 1


@pytest.mark.parametrize("scenario, topics", [
    ("thesis_6_5_overlap", {"/plant/rho": ("rho1", "rho2")}),     # measured parameters
    ("thesis_5_3_overlap", {}),                                     # uncertain: not measured
    ("bag_farhat_koenig_fault", {"/plant/mode": ("mode",)}),        # no guard decides it
    ("three_tank_nominal", {}),                                     # guards decide the mode
])
def test_measured_side_signals_are_what_a_monitor_may_measure(scenario, topics):
    """/plant/rho and /plant/mode (the runtimes' side signals) carry the true measured rho and
    the exogenous mode; nothing for an uncertain parameter or a guard-switched plant."""
    from fd_monitor.core.simulator import measured_signals

    sc = load_scenario(scenario)
    traj = simulate(sc, n_samples=300)
    got = {side_topic(n).absolute: v for n, v in measured_signals(traj).items()}
    assert {t: labels for t, (labels, _) in got.items()} == topics
    if "/plant/rho" in got:
        np.testing.assert_array_equal(got["/plant/rho"][1], traj.rho[0])
    if "/plant/mode" in got:
        np.testing.assert_array_equal(got["/plant/mode"][1][:, 0], traj.mode[0])
        assert len(set(traj.mode[0])) == 2                      # it does switch


def test_simulate_cli_writes_the_measured_mode_that_analyze_reads(tmp_path):
    """The switched plant's bag carries /plant/mode, and analyze runs the hminus_switched
    gain file on it (the side signal read from the bag)."""
    from fd_monitor.wire.bag_reader import read_bag

    out = subprocess.run([sys.executable, "-m", "fd_monitor", "simulate",
                          "bag_farhat_koenig_fault", "--duration", "20.0",
                          "-o", str(tmp_path / "bag"), "--json"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    b = read_bag(tmp_path / "bag", ["/plant/mode", "/plant/truth"])
    np.testing.assert_array_equal(b["/plant/mode"].column("mode"),
                                  b["/plant/truth"].column("mode"))
    out = subprocess.run([sys.executable, "-m", "fd_monitor", "analyze", str(tmp_path / "bag"),
                          "--gains", "farhat_koenig_hminus_switched", "--json"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    import json

    doc = json.loads(out.stdout)
    assert doc["method"] == "hminus_switched" and doc["samples"] == 200
