"""The one validation toolkit (fd_monitor.model.validate.Checker) and the files that use it:
plant files, scenarios, design files and the bag library give one-line errors naming the
file, the key path and what was expected, each as its own error class."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from fd_monitor.analysis.library import LibraryError, load_expected, load_library
from fd_monitor.design._lmi_common import design_checker
from fd_monitor.model.errors import DesignError, ScenarioError, SystemFileError
from fd_monitor.model.scenario import parse_scenario
from fd_monitor.model.system import parse_system, plant_checker
from fd_monitor.model.validate import Checker, Got


class BadError(ValueError):
    pass


def test_fail_names_file_section_key_and_what_was_found() -> None:
    ck = Checker("f.yaml", BadError, "sec")
    with pytest.raises(BadError, match=r"^f\.yaml: sec\.a\.b: expected a thing, got 'x'$"):
        ck.fail("a.b", "a thing", "x")
    with pytest.raises(BadError, match=r"^f\.yaml: sec: expected a mapping$"):
        ck.fail("", "a mapping", show=False)
    with pytest.raises(BadError, match=r"^f\.yaml: k: expected n, got 3 rows$"):
        Checker("f.yaml", BadError).fail("k", "n", Got("3 rows"))


def test_what_was_found_is_clipped_unless_asked_not_to() -> None:
    long = list(range(100))
    with pytest.raises(BadError) as info:
        Checker("f", BadError).fail("k", "x", long)
    assert str(info.value).endswith("...") and len(str(info.value).split("got ")[1]) == 60
    with pytest.raises(BadError) as info:
        Checker("f", BadError, clip=None).fail("k", "x", long)
    assert str(info.value).endswith(repr(long))


@pytest.mark.parametrize(("kwargs", "value", "message"), [
    ({}, "1", "expected a finite number, got '1'"),
    ({}, True, "expected a finite number, got True"),
    ({}, math.nan, "expected a finite number, got nan"),
    ({"positive": True}, 0, "expected a number > 0, got 0"),
    ({"negative": True}, 0.0, "expected a number < 0, got 0.0"),
    ({"nonneg": True}, -1, "expected a number >= 0, got -1"),
])
def test_number(kwargs: dict[str, bool], value: object, message: str) -> None:
    pattern = "^f: k: " + re.escape(message) + "$"
    with pytest.raises(BadError, match=pattern):
        Checker("f", BadError).number("k", value, **kwargs)
    assert Checker("f", BadError).number("k", 2) == 2.0


def test_plant_numbers_are_bounded_and_say_so() -> None:
    ck = plant_checker("p.yaml")
    with pytest.raises(SystemFileError, match=r"p\.yaml: k: expected a number, got 'x'"):
        ck.number("k", "x")
    with pytest.raises(SystemFileError, match=r"expected a number of magnitude <= 1e\+15"):
        ck.number("k", 1e16)
    with pytest.raises(SystemFileError, match=r"expected a number >= 0 \(a bound cannot be "
                       r"negative\), got -1"):
        ck.number("k", -1, nonneg=True)


def test_matrix_and_vector_shapes() -> None:
    ck = Checker("f", BadError)
    np.testing.assert_array_equal(ck.matrix("m", [[1, 2], [3, 4]], (2, 2)), [[1, 2], [3, 4]])
    assert ck.matrix("m", None, (3, 0)).shape == (3, 0)
    assert ck.matrix("m", [[1, 2, 3]], (None, 3)).shape == (1, 3)
    with pytest.raises(BadError, match=r"^f: m: expected a 2x2 matrix, got 1 rows of length 2$"):
        ck.matrix("m", [[1, 2]], (2, 2))
    with pytest.raises(BadError, match=r"^f: m: expected a rx3 matrix, got 2 rows of length 2, 3$"):
        ck.matrix("m", [[1, 2], [1, 2, 3]], (None, 3))
    with pytest.raises(BadError, match=r"^f: m: expected a rxc matrix \(a list of rows\), "
                       r"got \[\]$"):
        ck.matrix("m", [], (None, None))
    with pytest.raises(BadError, match=r"^f: m\[0\]\[1\]: expected a finite number, got 'a'$"):
        ck.matrix("m", [[1, "a"]], (1, 2))
    with pytest.raises(BadError, match=r"^f: v: expected a list of 2 numbers, got 3 numbers$"):
        ck.vector("v", [1, 2, 3], 2)
    with pytest.raises(BadError, match=r"^f: v\[1\]: expected a number >= 0, got -1$"):
        ck.vector("v", [1, -1], None, nonneg=True)


def test_keys_names_integers_booleans() -> None:
    ck = Checker("f", BadError, "s")
    with pytest.raises(BadError, match=r"^f: s\.m\.z: expected one of the keys \['a'\] \(unknown "
                       r"key\)$"):
        ck.mapping("m", {"a": 1, "z": 2}, {"a"})
    with pytest.raises(BadError, match=r"^f: s\.m\.b: expected a value \(missing key\)$"):
        ck.require("m", {"a": 1}, ("a", "b"))
    with pytest.raises(BadError, match=r"^f: s\.n: expected unique names, got \['x'\]$"):
        ck.names("n", ["x", "y", "x"])
    with pytest.raises(BadError, match=r"^f: s\.n\[0\]: expected a name of letters, digits"):
        ck.names("n", ["1x"])
    with pytest.raises(BadError, match=r"^f: s\.i: expected an integer >= 1, got 0$"):
        ck.integer("i", 0, 1)
    with pytest.raises(BadError, match=r"^f: s\.i: expected an integer >= 0, got True$"):
        ck.integer("i", True)
    with pytest.raises(BadError, match=r"^f: s\.b: expected true or false, got 'yes'$"):
        ck.boolean("b", "yes")


def test_every_file_kind_uses_the_toolkit_with_its_own_error(tmp_path: Path) -> None:
    """Plant, scenario, design section and library: same message shape, own error class."""
    with pytest.raises(SystemFileError, match=r"^p\.yaml: sample_time: expected a number > 0"):
        parse_system({"name": "p", "sample_time": -1}, "p.yaml")
    with pytest.raises(ScenarioError, match=r"^s\.yaml: duration: expected a number > 0, "
                       r"got -1"):
        parse_scenario({"system": "pwa_cascade", "duration": -1}, "s.yaml")
    with pytest.raises(DesignError, match=r"^d\.yaml: hinf_sc\.weights\.a: expected a number "
                       r"> 0, got 0"):
        design_checker("d.yaml", "hinf_sc").number("weights.a", 0, positive=True)
    lib = tmp_path / "library.yaml"
    lib.write_text(yaml.safe_dump({"format_version": 1, "bags": [
        {"name": "b", "scenario": "x", "seed": -2, "duration": 1.0, "gains": "g"}]}))
    with pytest.raises(LibraryError, match=rf"^{lib}: bags\[0\]\.seed: expected an integer "
                       r">= 0, got -2$"):
        load_library(lib)
    exp = tmp_path / "expected.yaml"
    exp.write_text(yaml.safe_dump({"alarms": {"h1": {"first_sample": 3}}}))
    with pytest.raises(LibraryError, match=rf"^{exp}: alarms\.h1: expected "
                       r"\{first_sample, tolerance\}, got \{'first_sample': 3\}$"):
        load_expected(exp)
