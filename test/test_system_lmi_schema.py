"""Plant-file additions for the LMI designers: per-mode / output process-fault directions,
``switching``, ``lpv`` with ``A_rho`` / ``B_rho`` (fd_monitor.model.system)."""

from __future__ import annotations

import numpy as np
import pytest

from fd_monitor.core.plant import SampledPlant
from fd_monitor.core.simulator import simulate
from fd_monitor.model.errors import SystemFileError
from fd_monitor.model.scenario import parse_scenario
from fd_monitor.model.system import load_system, parse_system


def _doc(**extra):
    d = {"name": "t", "time": "discrete", "sample_time": 0.1, "states": ["a", "b"],
         "inputs": ["u"], "outputs": ["y1", "y2"],
         "modes": {"m1": {"A": [[0.5, 0.0], [0.0, 0.5]], "B": [[1.0], [0.0]],
                          "C": [[1.0, 0.0], [0.0, 1.0]]},
                   "m2": {"A": [[0.5, 0.0], [0.0, 0.5]], "B": [[1.0], [0.0]],
                          "C": [[1.0, 0.0], [0.0, 1.0]]}},
         "initial": {"mode": "m1", "state": [0.0, 0.0]}}
    d.update(extra)
    return d


def test_existing_plants_keep_their_sha():
    """The canonical form of a file without the new keys is unchanged: a digest recorded
    before the additions (thesis_4_7, its shipped gain file holds it) still matches."""
    import yaml

    s = load_system("thesis_4_7")
    from fd_monitor.model.paths import repo_root

    root = repo_root()
    assert root is not None
    g = yaml.safe_load((root / "config/gains/thesis_4_7_hinf_sc.yaml").read_text())
    assert g["system"]["sha256"] == s.sha256
    assert s.switching == "guards" and s.lpv == ()
    assert "switching" not in s.canonical and "lpv" not in s.canonical


def test_process_fault_per_mode_and_output_direction():
    s = parse_system(_doc(faults=[{"name": "f", "kind": "process",
                                   "F": {"m2": [0.0, 1.0]}, "E": [0.0, 2.0]}]))
    f = s.faults[0]
    assert f.F is None and f.E is not None
    np.testing.assert_array_equal(f.direction(0, 2), [0.0, 0.0])
    np.testing.assert_array_equal(f.direction(1, 2), [0.0, 1.0])
    plant = SampledPlant(s)
    np.testing.assert_array_equal(plant.modes[0].Fd, [[0.0], [0.0]])
    np.testing.assert_array_equal(plant.modes[1].Fd, [[0.0], [1.0]])
    # the simulator applies the mode's F to the state and E f to the output
    s2 = parse_system(_doc(faults=[{"name": "f", "kind": "process",
                                    "F": {"m1": [0.0, 1.0]}, "E": [0.0, 2.0]}]))
    sc = parse_scenario({"name": "x", "system": "t", "duration": 0.5, "inputs": {"u": 0.0},
                         "faults": [{"channel": "f", "profile": "abrupt", "time": 0.0,
                                     "magnitude": 1.0}]}, "<x>", s2)
    tr = simulate(sc)
    # x_b: 0 -> 1 -> 1.5 -> ...; y2 = x_b + 2 f
    np.testing.assert_allclose(tr.x[0, :3, 1], [0.0, 1.0, 1.5])
    np.testing.assert_allclose(tr.y[0, :3, 1], [2.0, 3.0, 3.5])
    np.testing.assert_allclose(tr.y[0, :3, 0], 0.0)


def test_switching_and_lpv_parse_and_enter_the_sha():
    base = parse_system(_doc())
    arb = parse_system(_doc(switching="arbitrary"))
    assert arb.switching == "arbitrary" and arb.sha256 != base.sha256
    doc = _doc(lpv={"parameters": [{"name": "rho", "min": -1.0, "max": 1.0,
                                    "measured": True}]})
    doc["modes"]["m1"]["A_rho"] = [[[0.0, 1.0], [-1.0, 0.0]]]
    doc["modes"]["m1"]["B_rho"] = [[[0.0], [1.0]]]
    s = parse_system(doc)
    assert s.n_rho == 1 and s.lpv[0].measured and s.lpv[0].max == 1.0
    np.testing.assert_array_equal(s.modes[0].A_of(np.array([0.5])), [[0.5, 0.5], [-0.5, 0.5]])
    assert s.modes[1].A_rho is None
    assert s.sha256 != base.sha256
    plant = SampledPlant(s)                 # simulated with rho (test_simulator_lpv.py)
    assert plant.lpv_modes == (True, False)
    with pytest.raises(ValueError, match=r"mode 'm1': parameter-dependent .*give rho"):
        plant.step(np.array([0]), np.zeros((1, 2)), np.zeros((1, 1)))


@pytest.mark.parametrize("mut, match", [
    (lambda d: d.update(switching="sometimes"),
     r"<f>: switching: expected 'guards' .* or 'arbitrary'"),
    (lambda d: d.update(lpv={"parameters": []}), r"<f>: lpv.parameters: expected a non-empty"),
    (lambda d: d.update(lpv={"parameters": [{"name": "r", "min": 1, "max": 0,
                                             "measured": True}]}),
     r"<f>: lpv.parameters\[0\].max: expected a number >= min"),
    (lambda d: d.update(lpv={"parameters": [{"name": "r", "min": 0, "max": 1}]}),
     r"<f>: lpv.parameters\[0\].measured: expected a value \(missing key\)"),
    (lambda d: d.update(lpv={"parameters": [{"name": "r", "min": 0, "max": 1,
                                             "measured": "yes"}]}),
     r"<f>: lpv.parameters\[0\].measured: expected true"),
    (lambda d: d["modes"]["m1"].update(A_rho=[[[0, 0], [0, 0]]]),
     r"<f>: modes.m1.A_rho: expected no affine parts without a top-level 'lpv"),
    (lambda d: (d.update(lpv={"parameters": [{"name": "r", "min": 0, "max": 1,
                                              "measured": False}]}),
                d["modes"]["m1"].update(A_rho=[[[0, 0], [0, 0]], [[0, 0], [0, 0]]])),
     r"<f>: modes.m1.A_rho: expected a list of 1 2x2 matrices .*, got 2 entries"),
    (lambda d: (d.update(lpv={"parameters": [{"name": "r", "min": 0, "max": 1,
                                              "measured": False}]}),
                d["modes"]["m1"].update(B_rho=[[[0, 0], [0, 0]]])),
     r"<f>: modes.m1.B_rho\[0\]: expected a 2x1 matrix"),
    (lambda d: d.update(faults=[{"name": "f", "kind": "process", "F": {"m3": [0, 1]}}]),
     r"<f>: faults\[0\].F.m3: expected one of the modes \['m1', 'm2'\]"),
    (lambda d: d.update(faults=[{"name": "f", "kind": "process", "F": {"m1": [0]}}]),
     r"<f>: faults\[0\].F.m1: expected a list of 2 numbers"),
    (lambda d: d.update(faults=[{"name": "f", "kind": "process", "F": [0, 1], "E": [1]}]),
     r"<f>: faults\[0\].E: expected a list of 2 numbers"),
    (lambda d: d.update(faults=[{"name": "f", "kind": "actuator", "input": "u", "E": [1, 0]}]),
     r"<f>: faults\[0\].E: expected one of the keys"),
])
def test_bad_input_names_file_key_and_expectation(mut, match):
    d = _doc()
    mut(d)
    with pytest.raises(SystemFileError, match=match):
        parse_system(d, "<f>")


def test_design_files_are_not_listed_as_plants():
    with pytest.raises(SystemFileError) as ei:
        load_system("no_such_plant")
    msg = str(ei.value)
    assert "thesis_4_7" in msg and ".design" not in msg
