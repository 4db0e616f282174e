"""Plant descriptions: the shipped plants load, malformed files give one precise error each."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from fd_monitor.model.errors import SystemFileError
from fd_monitor.model.system import load_system

MINIMAL: dict[str, Any] = {
    "format_version": 1,
    "name": "tiny",
    "time": "continuous",
    "sample_time": 0.1,
    "states": ["x1", "x2"],
    "inputs": ["u1"],
    "outputs": ["y1"],
    "disturbances": ["w1"],
    "bounds": {"disturbance": [1.0], "measurement_noise": [0.01]},
    "shared": {"C": [[1.0, 0.0]], "B": [[0.0], [1.0]]},
    "modes": {
        "a": {"A": [[0.0, 1.0], [-1.0, -1.0]], "D": [[0.1], [0.0]]},
        "b": {"A": [[0.0, 1.0], [-2.0, -1.0]], "uncertainty": [0.001, 0.001]},
    },
    "guards": [
        {"from": "a", "to": "b", "kind": "autonomous", "when": [{"var": "x1", "op": ">",
                                                                  "value": 1.0}]},
        {"from": "b", "to": "a", "kind": "controlled", "when": [{"var": "u1", "op": "<",
                                                                  "value": 0.0}]},
    ],
    "faults": [{"name": "bias_y1", "kind": "sensor_bias", "output": "y1"}],
    "initial": {"mode": "a", "state": [0.0, 0.0]},
}


def write(tmp_path: Path, doc: Any, name: str = "plant.yaml") -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(doc) if not isinstance(doc, str) else doc)
    return p


def mutated(path: tuple[Any, ...], value: Any = None, delete: bool = False) -> dict[str, Any]:
    doc = copy.deepcopy(MINIMAL)
    node = doc
    for k in path[:-1]:
        node = node[k]
    if delete:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return doc


def test_minimal_plant_loads(tmp_path: Path) -> None:
    s = load_system(write(tmp_path, MINIMAL))
    assert (s.n, s.nu, s.ny, s.nw) == (2, 1, 1, 1)
    assert s.mode_names == ("a", "b")
    assert s.guards[0].name == "a->b" and s.guards[0].kind == "autonomous"
    np.testing.assert_array_equal(s.modes[1].B, [[0.0], [1.0]])  # from shared
    np.testing.assert_array_equal(s.modes[0].uncertainty, [0.0, 0.0])  # default


@pytest.mark.parametrize("name", ["pwa_cascade", "three_tank"])
def test_shipped_plants_load(name: str) -> None:
    s = load_system(name)
    assert s.name == name
    assert len(s.sha256) == 64


def test_pwa_cascade_is_the_papers_example() -> None:
    """QB paper Sec. VI: three modes, C = [I 0], E = 0.01 [I 0], guards F(x) of eq. (15)."""
    s = load_system("pwa_cascade")
    assert len(s.modes) == 3 and s.n == 4 and s.ny == 2
    assert [m.A[0, 0] for m in s.modes if m.A is not None] == [-0.5, -0.5, -1.0]
    assert [m.A[1, 1] for m in s.modes if m.A is not None] == [-0.5, -1.0, -0.5]
    for m in s.modes:
        np.testing.assert_array_equal(m.C, np.eye(2, 4))
        np.testing.assert_array_equal(m.E, 0.01 * np.eye(2, 4))
    assert all(c.value == 0.4 for g in s.guards for c in g.conditions)
    np.testing.assert_array_equal(s.disturbance_bound, np.ones(4))


def test_identity_is_canonical(tmp_path: Path) -> None:
    """Key order, comments and the description do not change the plant's SHA-256; values do."""
    a = load_system(write(tmp_path, MINIMAL, "a.yaml"))
    reordered = dict(reversed(list(copy.deepcopy(MINIMAL).items())))
    reordered["description"] = "same plant, other words"
    b = load_system(write(tmp_path, "# comment\n" + yaml.safe_dump(reordered), "b.yaml"))
    assert a.sha256 == b.sha256
    c = load_system(write(tmp_path, mutated(("sample_time",), 0.2), "c.yaml"))
    assert c.sha256 != a.sha256


def test_units_come_from_the_plant_file(tmp_path: Path) -> None:
    """``units`` names each channel's unit ("-" where not given); it is not part of the
    plant's identity, and a runtime labels its channels with it, whatever the plant's name."""
    from fd_monitor.core.methods import load_gains, runtime_for

    a = load_system(write(tmp_path, MINIMAL, "a.yaml"))
    assert a.state_units == ("-", "-") and a.input_units == ("-",) and a.output_units == ("-",)
    b = load_system(write(tmp_path, mutated(("units",), {"states": {"x1": "m"},
                                                         "outputs": {"y1": "m/s"}}), "b.yaml"))
    assert b.state_units == ("m", "-") and b.output_units == ("m/s",)
    assert b.sha256 == a.sha256

    tanks = load_system("three_tank")
    assert tanks.output_units == ("m", "m", "m")
    gains = load_gains("three_tank_thresholds", tanks)
    assert runtime_for(tanks, gains).units == ("m", "m", "m")
    doc = yaml.safe_load(Path(tanks.source).read_text())
    del doc["units"]
    bare = load_system(write(tmp_path, doc, "three_tank.yaml"))
    assert bare.name == "three_tank" and bare.sha256 == tanks.sha256
    assert runtime_for(bare, gains).units == ("-", "-", "-")


# (mutation, message fragment that must appear); every message also names the file.
MALFORMED = [
    pytest.param(mutated(("sample_time",), delete=True), r"sample_time: expected .*missing key",
                 id="missing-key"),
    pytest.param(mutated(("modes", "a", "A"), [[0.0, 1.0]]),
                 r"modes\.a\.A: expected a 2x2 matrix, got 1 rows of length 2",
                 id="wrong-matrix-shape"),
    pytest.param(mutated(("modes", "b", "A"), [[0.0, 1.0], [float("nan"), -1.0]]),
                 r"modes\.b\.A\[1\]\[0\]: expected a finite number", id="nan-in-matrix"),
    pytest.param(mutated(("bounds", "measurement_noise"), [-0.01]),
                 r"bounds\.measurement_noise\[0\]: expected a number >= 0", id="negative-bound"),
    pytest.param(mutated(("guards", 0, "to"), "c"),
                 r"guards\[0\]\.to: expected one of the modes \['a', 'b'\] \(unknown mode\)",
                 id="unknown-mode-in-guard"),
    pytest.param(mutated(("guards", 0, "when", 0, "var"), "u1"),
                 r"guards\[0\]\.when\[0\]\.var: expected a state of a autonomous guard",
                 id="autonomous-guard-on-input"),
    pytest.param(mutated(("guards", 1, "when", 0, "op"), "=>"),
                 r"guards\[1\]\.when\[0\]\.op: expected one of", id="bad-operator"),
    pytest.param(mutated(("sample_time",), -0.1), r"sample_time: expected a number > 0",
                 id="non-positive-sample-time"),
    pytest.param(mutated(("initial", "mode"), "z"), r"initial\.mode: expected one of the modes",
                 id="unknown-initial-mode"),
    pytest.param(mutated(("initial", "state"), [0.0]),
                 r"initial\.state: expected a list of 2 numbers, got 1 numbers",
                 id="wrong-initial-state-length"),
    pytest.param(mutated(("modes", "a", "dynamics"), "nonlinear"),
                 r"modes\.a\.A: expected no 'A' in a nonlinear mode", id="A-in-nonlinear-mode"),
    pytest.param(mutated(("modes", "a", "Bogus"), 1),
                 r"modes\.a\.Bogus: expected one of the keys .* \(unknown key\)",
                 id="unknown-key"),
    pytest.param(mutated(("faults", 0, "output"), "y9"),
                 r"faults\[0\]\.output: expected one of \['y1'\]", id="fault-unknown-output"),
    pytest.param(mutated(("states",), ["x1", "x1"]), r"states: expected unique names",
                 id="duplicate-state"),
    pytest.param(mutated(("shared",), delete=True),
                 r"modes\.a\.C: expected a 1x2 matrix \(missing key", id="missing-C"),
    pytest.param(mutated(("format_version",), 7), r"format_version: expected one of \(1,\)",
                 id="unsupported-version"),
    pytest.param(mutated(("modes",), {"a": {"dynamics": "nonlinear", "model": "nope"}}),
                 r"modes\.a\.model: expected a known nonlinear model: \[.*three_tank",
                 id="unknown-model"),
    pytest.param(mutated(("units",), {"outputs": {"y9": "m"}}),
                 r"units\.outputs\.y9: expected one of the keys \['y1'\] \(unknown key\)",
                 id="unit-of-unknown-output"),
    pytest.param(mutated(("units",), {"states": {"x1": 3}}),
                 r"units\.states\.x1: expected a unit \(a non-empty string such as 'm'\), "
                 r"got 3", id="unit-not-a-string"),
    pytest.param(mutated(("units",), {"speeds": {}}),
                 r"units\.speeds: expected one of the keys \['inputs', 'outputs', 'states'\]",
                 id="unit-unknown-group"),
]


@pytest.mark.parametrize(("doc", "match"), MALFORMED)
def test_malformed_plant_names_file_key_and_expectation(tmp_path: Path, doc: Any,
                                                          match: str) -> None:
    path = write(tmp_path, doc)
    with pytest.raises(SystemFileError, match=match) as info:
        load_system(path)
    msg = str(info.value)
    assert msg.startswith(str(path) + ": ")
    assert "\n" not in msg


def test_not_yaml_and_not_a_mapping(tmp_path: Path) -> None:
    with pytest.raises(SystemFileError, match=r"invalid YAML at line 2"):
        load_system(write(tmp_path, "name: [\n"))
    with pytest.raises(SystemFileError, match=r"\(top level\): expected a mapping"):
        load_system(write(tmp_path, "- 1\n- 2\n"))


def test_missing_file_and_unknown_name(tmp_path: Path) -> None:
    with pytest.raises(SystemFileError, match=r"nope\.yaml: file not found"):
        load_system(tmp_path / "nope.yaml")
    with pytest.raises(SystemFileError, match=r"no_such_plant: unknown plant \(shipped: .*"
                                              r"three_tank"):
        load_system("no_such_plant")


def test_nonlinear_model_parameters_are_checked(tmp_path: Path) -> None:
    doc = yaml.safe_load((Path(__file__).parent.parent / "config/systems/three_tank.yaml")
                         .read_text())
    doc["modes"]["closed_dry"]["params"] = {"tank_area": 0.0154}
    with pytest.raises(SystemFileError, match=r"modes\.closed_dry\.params\.pipe_area: expected "
                                              r"a number \(missing parameter\)"):
        load_system(write(tmp_path, doc))
    doc["modes"]["closed_dry"]["params"] = {"tank_aera": 0.0154}
    with pytest.raises(SystemFileError, match=r"params\.tank_aera: expected a parameter of "
                                              r"model 'three_tank'"):
        load_system(write(tmp_path, doc))
