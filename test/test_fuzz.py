"""Property-based fuzzing (issue 12 item 6, issue 26 item 6): malformed input gets an fd_monitor
error, or works.

Targets: the plant, scenario and gain-file readers (generated YAML: random text and bytes,
and valid shipped files with one value replaced by a random YAML value or a key removed),
message decoding (:func:`fd_monitor.wire.conversions.decode` on generated messages) and
the offline reader (:func:`fd_monitor.analysis.offline.run_bag` on generated bags: stamps, values,
labels, and bytes of a valid bag flipped or cut); and (issue 26) the library, ``expected.yaml``,
adapter, ROS parameter and design files, a bag's ``metadata.yaml``, identify's reader on
generated streams, ``bag check`` on corrupted bytes, and every numeric option of the CLI. The
property of each: the call returns a result or raises
:class:`~fd_monitor.model.errors.FdMonitorError` — never another exception.

The suite runs a bounded, derandomised number of examples per target (fast, same examples
every run); ``benchmarks/fuzz_inputs.py`` runs many more with a random seed and prints the
count and the crashes.
"""

from __future__ import annotations

import copy
import functools
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fd_monitor.model.errors import FdMonitorError
from fd_monitor.model.paths import find_config_file
from fd_monitor.model.system import load_system, parse_system
from fd_monitor.model.yaml_io import parse_yaml_text

#: Examples per target in the test suite (the benchmark runs more).
SUITE_EXAMPLES = 40

_SYSTEM = load_system("three_tank")
_PWA = load_system("pwa_cascade")


@functools.cache
def _gain_file() -> Any:
    from fd_monitor.core.methods import load_gains

    return load_gains("three_tank_thresholds", _SYSTEM)


def _text(kind: str, name: str) -> str:
    return find_config_file(name, kind, FileNotFoundError).read_text()


BASE = {
    "plant": yaml.safe_load(_text("systems", "three_tank")),
    "plant_pwa": yaml.safe_load(_text("systems", "pwa_cascade")),
    "scenario": yaml.safe_load(_text("scenarios", "three_tank_bias_h1")),
    "gains": yaml.safe_load(_text("gains", "pwa_cascade_qb")),
}

# -- strategies -------------------------------------------------------------------------------

_scalars = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-10**30, max_value=10**30),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=20),
    st.sampled_from([0, -1, 1e308, -1e308, 1e-300, "nan", "true", "three_tank", "h1", ""]))
_values = st.recursive(_scalars, lambda c: st.one_of(
    st.lists(c, max_size=5), st.dictionaries(st.text(max_size=8), c, max_size=4)),
    max_leaves=20)


def _paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    """Every key path of a parsed YAML document (mappings and lists)."""
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += _paths(v, (*prefix, i))
    return out


@st.composite
def mutated(draw: Any, base: Any) -> str:
    """YAML text of ``base`` with one to three values replaced by random ones or deleted."""
    doc = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in _paths(doc) if p]
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        if draw(st.booleans()) and isinstance(parent, dict):
            del parent[path[-1]]
        else:
            parent[path[-1]] = draw(_values)
    return yaml.safe_dump(doc, sort_keys=False, allow_unicode=True)


def yaml_inputs(base: Any) -> st.SearchStrategy:
    """Text or bytes: mutated valid files, random text, random bytes, YAML fragments."""
    return st.one_of(
        mutated(base), st.text(max_size=200), st.binary(max_size=200),
        st.builds(lambda v: yaml.safe_dump(v), _values),
        st.sampled_from(["a: &x [*x]", "[" * 100, "{a: 1, a: 2}", "- !!python/object:os.system",
                         "a: !!binary xyz", "\ufeffname: x", "? [1]\n: 2", "a: *nope"]))


@st.composite
def messages(draw: Any) -> Any:
    """Float64MultiArray-like objects (duck-typed, as decode accepts from rclpy and rosbags)."""
    vals = draw(st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=8))
    dims = draw(st.lists(st.builds(
        SimpleNamespace, label=st.one_of(st.just("h1,h2,h3"), st.text(max_size=12)),
        size=st.integers(-2, 10), stride=st.integers(-2, 10)), max_size=2))
    return SimpleNamespace(data=vals, layout=SimpleNamespace(
        dim=dims, data_offset=draw(st.integers(-3, 5))))


# -- targets: each takes one generated input and returns or raises -----------------------------

def _parse_plant(raw: Any) -> Any:
    return parse_system(parse_yaml_text(raw, "<fuzz>"), "<fuzz>")


def _parse_scenario(raw: Any) -> Any:
    from fd_monitor.model.errors import ScenarioError
    from fd_monitor.model.scenario import parse_scenario

    return parse_scenario(parse_yaml_text(raw, "<fuzz>", ScenarioError), "<fuzz>", _SYSTEM)


def _load_gains(raw: Any) -> Any:
    from fd_monitor.core.methods import load_gains

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "g.yaml"
        p.write_bytes(raw if isinstance(raw, bytes) else raw.encode("utf-8", "surrogatepass"))
        return load_gains(p, _PWA)


def _decode(msg: Any) -> Any:
    from fd_monitor.wire.conversions import decode

    return decode(msg, "/plant/y", labels=("h1", "h2", "h3"), require_stamp=False)


@st.composite
def bag_streams(draw: Any) -> dict[str, Any]:
    """A short (u, y) stream of three_tank with generated stamps and values."""
    n = draw(st.integers(1, 12))
    stamps = draw(st.lists(st.integers(0, 2**53 - 1) | st.integers(0, 15), min_size=n,
                           max_size=n))
    good = st.floats(0.0, 0.6)
    vals = st.one_of(good, st.floats(allow_nan=True, allow_infinity=True),
                     st.sampled_from([1e300, 3.5e307, -1e308, 0.0]))
    y = [[draw(vals) for _ in range(3)] for _ in range(n)]
    u = [[draw(st.one_of(st.just(1e-4), vals)) for _ in range(3)] for _ in range(n)]
    return {"stamps": stamps, "y": y, "u": u}


def _run_stream(doc: dict[str, Any]) -> Any:
    from fd_monitor.analysis.offline import run_bag
    from fd_monitor.wire.bag_reader import arrays_from
    from fd_monitor.wire.bag_writer import write_bag

    s = _SYSTEM
    ns = np.arange(len(doc["stamps"])) * 100_000_000
    with tempfile.TemporaryDirectory() as d:
        bag = write_bag(Path(d) / "b", [
            arrays_from("/plant/u", s.inputs, doc["stamps"], doc["u"], ns),
            arrays_from("/plant/y", s.outputs, doc["stamps"], doc["y"], ns)])
        return run_bag(bag, _gain_file(), system=s)


_VALID_BAG = Path(__file__).resolve().parent.parent / "bags" / "three_tank_bad_input"


@st.composite
def bag_bytes(draw: Any) -> tuple[list[tuple[int, int]], int | None]:
    """Byte flips (offset fraction in 1e-6, xor mask) and an optional cut of a valid bag."""
    flips = draw(st.lists(st.tuples(st.integers(0, 10**6 - 1), st.integers(1, 255)),
                          max_size=4))
    cut = draw(st.none() | st.integers(0, 10**6 - 1))
    return flips, cut


def _read_corrupted(spec: tuple[list[tuple[int, int]], int | None]) -> Any:
    from fd_monitor.analysis.offline import run_bag

    flips, cut = spec
    with tempfile.TemporaryDirectory() as d:
        bag = Path(d) / "b"
        shutil.copytree(_VALID_BAG, bag)
        mcap = next(bag.glob("*.mcap"))
        data = bytearray(mcap.read_bytes())
        for frac, mask in flips:
            data[frac * len(data) // 10**6] ^= mask
        if cut is not None:
            data = data[:cut * len(data) // 10**6]
        mcap.write_bytes(bytes(data))
        return run_bag(bag, _gain_file(), system=_SYSTEM)


# -- issue 26 item 6: every command and file kind ------------------------------------------------

_REPO = Path(__file__).resolve().parent.parent
BASE.update({
    "library": yaml.safe_load((_REPO / "bags" / "library.yaml").read_text()),
    "expected": yaml.safe_load((_REPO / "bags" / "three_tank_bias_h1" / "expected.yaml")
                               .read_text()),
    "adapter": yaml.safe_load(_text("adapters", "dc_motor")),
    "params": yaml.safe_load((_REPO / "config" / "detector.yaml").read_text()),
    "design": yaml.safe_load((_REPO / "config" / "systems" / "thesis_4_7.design.yaml")
                             .read_text()),
    "metadata": yaml.safe_load((_VALID_BAG / "metadata.yaml").read_text()),
})


def _in_file(raw: Any, name: str, folder: str = "f") -> tuple[Any, Path]:
    """A temporary folder holding ``raw`` as ``<folder>/<name>`` (bytes or text)."""
    d = tempfile.TemporaryDirectory()
    p = Path(d.name) / folder / name
    p.parent.mkdir()
    p.write_bytes(raw if isinstance(raw, bytes) else raw.encode("utf-8", "surrogatepass"))
    return d, p


def _load_library(raw: Any) -> Any:
    from fd_monitor.analysis.library import load_library

    d, p = _in_file(raw, "library.yaml")
    with d:
        return load_library(p)


def _load_expected(raw: Any) -> Any:
    from fd_monitor.analysis.library import load_expected

    d, p = _in_file(raw, "expected.yaml", "three_tank_bias_h1")
    with d:
        return load_expected(p)


def _load_adapter(raw: Any) -> Any:
    from fd_monitor.wire.adapters import AdapterError, parse_adapter

    return parse_adapter(parse_yaml_text(raw, "<fuzz>", AdapterError), "<fuzz>")


def _load_params(raw: Any) -> Any:
    from fd_monitor.nodes.ros_args import find_params_file

    d, p = _in_file(raw, "detector.yaml")
    with d:
        return find_params_file(str(p))


@functools.cache
def _thesis_47() -> Any:
    return load_system("thesis_4_7")


def _load_design(raw: Any) -> Any:
    from fd_monitor.design._lmi_common import load_design_section
    from fd_monitor.design.hinf_spec import parse_spec

    d, p = _in_file(raw, "p.design.yaml")
    with d:
        section, origin, sha = load_design_section(_thesis_47(), "hinf_sc", p)
        return parse_spec(_thesis_47(), section, origin, sha)


def _bag_metadata(raw: Any) -> Any:
    """A valid bag whose metadata.yaml is replaced: every reader's integrity check."""
    from fd_monitor.analysis.integrity import bag_integrity

    with tempfile.TemporaryDirectory() as d:
        bag = Path(d) / "b"
        shutil.copytree(_VALID_BAG, bag)
        (bag / "metadata.yaml").write_bytes(raw if isinstance(raw, bytes)
                                            else raw.encode("utf-8", "surrogatepass"))
        return bag_integrity(bag, warn=False)


def _identify_stream(doc: dict[str, Any]) -> Any:
    """identify's reader (:func:`~fd_monitor.analysis.integrity.read_joined`) on generated
    stamps and values."""
    from fd_monitor.analysis.integrity import read_joined
    from fd_monitor.wire.bag_reader import arrays_from
    from fd_monitor.wire.bag_writer import write_bag

    s = _SYSTEM
    ns = np.arange(len(doc["stamps"])) * 100_000_000
    with tempfile.TemporaryDirectory() as d:
        bag = write_bag(Path(d) / "b", [
            arrays_from("/plant/u", s.inputs, doc["stamps"], doc["u"], ns),
            arrays_from("/plant/y", s.outputs, doc["stamps"], doc["y"], ns)])
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return read_joined(bag, "/plant/u", "/plant/y")


def _check_corrupted(spec: tuple[list[tuple[int, int]], int | None]) -> Any:
    """``bag check``'s reading (:func:`~fd_monitor.analysis.integrity.bag_integrity`) of a
    valid bag with bytes flipped or cut."""
    from fd_monitor.analysis.integrity import bag_integrity

    flips, cut = spec
    with tempfile.TemporaryDirectory() as d:
        bag = Path(d) / "b"
        shutil.copytree(_VALID_BAG, bag)
        mcap = next(bag.glob("*.mcap"))
        data = bytearray(mcap.read_bytes())
        for frac, mask in flips:
            data[frac * len(data) // 10**6] ^= mask
        if cut is not None:
            data = data[:cut * len(data) // 10**6]
        mcap.write_bytes(bytes(data))
        return bag_integrity(bag, warn=False)


#: (command argv prefix, option) of every numeric option the CLI takes.
CLI_NUMBERS = [
    (["design", "qb", "pwa_cascade"], o) for o in ("--beta", "--margin")] + [
    (["design", "thresholds", "three_tank"], o) for o in (
        "--seeds", "--tube", "--mc-samples", "--mc-margin", "--mc-seed", "--length", "--pole",
        "--max-window", "--delta", "--gamma", "--lambda", "--alpha", "--box-width",
        "--m-sigma")] + [
    (["evaluate", "g", "-s", "s"], o) for o in ("--runs", "--seed0", "--chunk", "--transient",
                                                "--q-fault")] + [
    (["identify", "b", "-o", "p"], o) for o in ("--split", "--sample-time", "--margin",
                                               "--max-window", "--sparsity", "--max-radius")] + [
    (["replay", "b"], o) for o in ("--rate", "--wait-subscribers", "--wait-timeout",
                                   "--remap")] + [
    (["simulate", "s", "-o", "o"], o) for o in ("--seed", "--duration")] + [
    (["report", "b", "-o", "o"], "--transient"), (["validate", "p"], "--sample-time"),
    (["record", "-o", "o"], "--messages"), (["record", "-o", "o"], "--duration")]


@st.composite
def cli_numbers(draw: Any) -> list[str]:
    """argv: one numeric option of one command with a generated value."""
    prefix, opt = draw(st.sampled_from(CLI_NUMBERS))
    value = draw(st.one_of(
        st.sampled_from(["nan", "inf", "-inf", "1e12", str(2**80), "-3", "0", "0.5", "1e308",
                         "2.5", "", " ", "1_0", "0x10", "a:=b", "bad", "-0"]),
        st.floats(allow_nan=True, allow_infinity=True).map(repr),
        st.integers(-10**25, 10**25).map(str), st.text(max_size=8)))
    return [*prefix, opt, value]


def _parse_cli(argv: list[str]) -> Any:
    """Parse only (nothing runs): a value the option accepts, or one line and status 2."""
    import contextlib
    import io
    import math

    from fd_monitor.commands.cli import build_parser

    err = io.StringIO()
    parser = build_parser(argv)
    try:
        with contextlib.redirect_stderr(err):
            ns = parser.parse_args(argv)
    except SystemExit as exc:
        lines = err.getvalue().strip().splitlines()
        assert exc.code == 2 and len(lines) == 1 and ": error: " in lines[0], err.getvalue()
        raise FdMonitorError(lines[0]) from None
    for v in vars(ns).values():                    # what a command gets is always finite
        if isinstance(v, float):
            assert math.isfinite(v), (argv, v)
    return ns


#: name -> (strategy, target).
TARGETS: dict[str, tuple[st.SearchStrategy, Callable[[Any], Any]]] = {
    "plant": (yaml_inputs(BASE["plant"]), _parse_plant),
    "plant_linear": (yaml_inputs(BASE["plant_pwa"]), _parse_plant),
    "scenario": (yaml_inputs(BASE["scenario"]), _parse_scenario),
    "gains": (yaml_inputs(BASE["gains"]), _load_gains),
    "decode": (messages(), _decode),
    "offline_stream": (bag_streams(), _run_stream),
    "offline_bag_bytes": (bag_bytes(), _read_corrupted),
    "library": (yaml_inputs(BASE["library"]), _load_library),
    "expected": (yaml_inputs(BASE["expected"]), _load_expected),
    "adapter": (yaml_inputs(BASE["adapter"]), _load_adapter),
    "params": (yaml_inputs(BASE["params"]), _load_params),
    "design_file": (yaml_inputs(BASE["design"]), _load_design),
    "bag_metadata": (yaml_inputs(BASE["metadata"]), _bag_metadata),
    "identify_stream": (bag_streams(), _identify_stream),
    "bag_check_bytes": (bag_bytes(), _check_corrupted),
    "cli_numbers": (cli_numbers(), _parse_cli),
}
#: Examples per target in the suite where one is slow (a bag per example); default
#: SUITE_EXAMPLES. The benchmark runs ``--examples`` of every target.
SUITE_EXAMPLES_OF = {"bag_metadata": 10, "identify_stream": 15, "bag_check_bytes": 10,
                     "design_file": 15, "params": 20, "library": 8, "expected": 20,
                     "cli_numbers": 30}


def outcome(target: Callable[[Any], Any], value: Any) -> str:
    """``"ok"``, ``"error"`` (an FdMonitorError: the expected refusal) — anything else raises."""
    try:
        target(value)
    except FdMonitorError as exc:
        msg = str(exc)
        assert msg and len(msg.splitlines()) == 1, f"not a one-line message: {msg!r}"
        return "error"
    return "ok"


@pytest.mark.parametrize("name", list(TARGETS))
def test_fuzz_target(name):
    strategy, target = TARGETS[name]
    seen: dict[str, int] = {}

    examples = SUITE_EXAMPLES_OF.get(name, SUITE_EXAMPLES)

    @settings(max_examples=examples, derandomize=True, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(strategy)
    def prop(value: Any) -> None:
        r = outcome(target, value)
        seen[r] = seen.get(r, 0) + 1

    prop()
    assert sum(seen.values()) >= examples // 2
