"""Issue 26 (bad input, round three), items 1-6: every offline, CLI and file case of the issue.

Each case runs the command line in process (``fd_monitor.commands.cli.main``) on an input
built in ``tmp_path`` and asserts the contract: one line ``... error: ...`` naming the
problem and exit status 2, or the correct result with its ``integrity`` record. A few run
as real processes to show "one line, exit 2, no traceback" end to end.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from fd_monitor.commands.cli import main as cli_main
from fd_monitor.model.paths import find_config_file
from fd_monitor.wire.bag_reader import arrays_from, read_bag
from fd_monitor.wire.bag_writer import write_bag

REPO = Path(__file__).resolve().parent.parent
NOMINAL = REPO / "bags" / "three_tank_nominal"
GAINS = "three_tank_thresholds"
U, Y = "/plant/u", "/plant/y"
N = 300                                   # samples of the short bags (30 s of three_tank)


@pytest.fixture(scope="module")
def nominal():
    """The first N samples of the shipped nominal bag: labels, stamps, values, times."""
    a = read_bag(NOMINAL, [U, Y])
    return {t: (a[t].labels, a[t].stamps[:N].copy(), a[t].values[:N].copy(),
                a[t].receive_ns[:N].copy()) for t in (U, Y)}


@pytest.fixture(scope="module")
def short(nominal, tmp_path_factory):
    """The nominal bag's first N samples, written once (with metadata.yaml)."""
    return _bag(tmp_path_factory.mktemp("short") / "three_tank_nominal", nominal)


@pytest.fixture(scope="module")
def short_bad(nominal, tmp_path_factory):
    """N samples with bad input: NaN at k = 10, no message for k = 100..109, /plant/y of
    k = 200 twice."""
    from fd_monitor.wire.bag_writer import write_messages

    (lu, _su, vu, tu), (ly, _s, vy, _t) = nominal[U], nominal[Y]
    msgs = []
    for k in range(N):
        if 100 <= k < 110:
            continue
        y = vy[k].copy()
        if k == 10:
            y[1] = np.nan
        msgs += [(U, tu[k], k, lu, vu[k]), (Y, tu[k], k, ly, y)]
        if k == 200:
            msgs.append((Y, tu[k], k, ly, y))
    return write_messages(tmp_path_factory.mktemp("bad") / "bad", msgs)


def _bag(path: Path, base, u=None, y=None, stamps=None, labels=None) -> Path:
    """A three_tank bag of N samples from ``base``, with u, y, stamps or labels replaced."""
    (lu, su, vu, tu), (ly, _sy, vy, ty) = base[U], base[Y]
    s = stamps if stamps is not None else su
    lu, ly = labels if labels is not None else (lu, ly)
    return write_bag(path, [arrays_from(U, lu, s, vu if u is None else u, tu),
                            arrays_from(Y, ly, s, vy if y is None else y, ty)])


def _run(capsys, argv):
    code = cli_main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _one_line(capsys, argv, fragment):
    code, _out, err = _run(capsys, argv)
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and re.match(r"^[\w ]+: error: ", lines[0]), err
    assert "Traceback" not in err
    if isinstance(fragment, re.Pattern):
        assert fragment.search(lines[0]), lines[0]
    else:
        assert fragment in lines[0], lines[0]
    return lines[0]


# -- item 1: every sample refused, integrity record, --strict -----------------------------------

REFUSED = [
    ("y-5-everywhere", lambda b: {"y": np.full_like(b[Y][2], 5.0)}, "implausible"),
    ("u-1e308", lambda b: {"u": np.full_like(b[U][2], 1e308)}, "implausible"),
    ("u-y-swapped", lambda b: {"u": b[Y][2], "y": b[U][2],
                               "labels": (b[Y][0], b[U][0])}, "has channels"),
]


@pytest.mark.parametrize("cmd", ["analyze", "report"])
@pytest.mark.parametrize("make,fragment", [r[1:] for r in REFUSED], ids=[r[0] for r in REFUSED])
def test_every_sample_refused_is_one_line(tmp_path, capsys, nominal, cmd, make, fragment):
    bag = _bag(tmp_path / "b", nominal, **make(nominal))
    argv = [cmd, bag, "--gains", GAINS] + (["-o", tmp_path / "r"] if cmd == "report" else [])
    line = _one_line(capsys, argv, fragment)
    assert "IndexError" not in line


def test_integrity_record_and_strict(tmp_path, capsys, short_bad):
    bag = short_bad
    code, out, _ = _run(capsys, ["analyze", bag, "--gains", GAINS, "--json"])
    doc = json.loads(out)["integrity"]
    assert code == 0 and doc["clean"] is False
    assert doc["refused_samples"] == {"non_finite": 1}
    assert doc["samples_skipped"] == {"missing": 10, "non_finite": 1}
    assert doc["lost_samples"] == 11 and doc["samples_present"] == N
    assert doc["dropped_messages"] == {"duplicate": 1}
    assert doc["skipped_chunks"] == 0 and doc["metadata"] == []
    # --strict: the same JSON, then one line and status 2
    code, out, err = _run(capsys, ["analyze", bag, "--gains", GAINS, "--json", "--strict"])
    assert code == 2 and json.loads(out)["integrity"] == doc
    assert err.count("\n") == 1 and f"input not used whole (--strict): 11 of {N}" in err
    # the same record from report, bag check and replay's pre-check
    code, out, _ = _run(capsys, ["report", bag, "--gains", GAINS, "-o", tmp_path / "r",
                                 "--json"])
    assert code == 0 and json.loads(out)["integrity"] == doc
    code, out, _ = _run(capsys, ["bag", "check", bag, "--json"])
    got = json.loads(out)["integrity"]
    assert code == 0 and {k: got[k] for k in ("refused_samples", "samples_skipped",
                                             "dropped_messages")} == \
        {k: doc[k] for k in ("refused_samples", "samples_skipped", "dropped_messages")}
    _one_line(capsys, ["replay", bag, "--strict"], "input not used whole (--strict)")


def test_clean_bag_is_clean(capsys, short):
    code, out, err = _run(capsys, ["analyze", short, "--gains", GAINS, "--json", "--strict"])
    assert code == 0 and err == ""
    doc = json.loads(out)["integrity"]
    assert doc["clean"] is True and doc["lost_samples"] == 0 and doc["unchecked_chunks"] == 0


def _flip_chunk(folder: Path) -> None:
    mcap = next(folder.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    data[len(data) // 3] ^= 0x40                     # inside a zstd chunk
    mcap.write_bytes(bytes(data))


def test_damaged_chunk_is_in_the_json(tmp_path, capsys, nominal):
    from fd_monitor.wire.bag_writer import BagWriter

    bag = tmp_path / "b"
    with BagWriter(bag, chunk_bytes=4096) as w:          # ~20 chunks: one can be lost
        for k in range(N):
            for t in (U, Y):
                labels, _s, v, ns = nominal[t]
                w.write_array(t, k, labels, v[k], int(ns[k]))
    _flip_chunk(bag)
    code, out, err = _run(capsys, ["analyze", bag, "--gains", GAINS, "--json"])
    doc = json.loads(out)["integrity"]
    assert code == 0 and doc["skipped_chunks"] == 1 and doc["clean"] is False
    assert doc["lost_samples"] > 0 and "CRC mismatch" in err
    assert _run(capsys, ["analyze", bag, "--gains", GAINS, "--strict"])[0] == 2


# -- item 1: metadata.yaml must agree with the MCAP it names ------------------------------------

def _edit_meta(bag: Path, f) -> None:
    p = bag / "metadata.yaml"
    doc = yaml.safe_load(p.read_text())
    f(doc["rosbag2_bagfile_information"])
    p.write_text(yaml.safe_dump(doc))


def _count_wrong(info):
    info["topics_with_message_count"][0]["message_count"] += 7


def _type_wrong(info):
    info["topics_with_message_count"][0]["topic_metadata"]["type"] = "std_msgs/msg/String"


META = [
    ("count", _count_wrong, f"metadata.yaml says {N + 7} messages, the .mcap has {N}"),
    ("type", _type_wrong, "metadata.yaml says type std_msgs/msg/String"),
    ("removed", None, "no metadata.yaml"),
]


@pytest.mark.parametrize("edit,fragment", [m[1:] for m in META], ids=[m[0] for m in META])
def test_metadata_disagreeing_is_said(tmp_path, capsys, short, edit, fragment):
    bag = tmp_path / "b"
    shutil.copytree(short, bag)
    if edit is None:
        (bag / "metadata.yaml").unlink()
    else:
        _edit_meta(bag, edit)
    code, out, _ = _run(capsys, ["bag", "check", bag])
    assert code == 1 and fragment in out
    code, out, err = _run(capsys, ["analyze", bag, "--gains", GAINS, "--json"])
    assert code == 0 and fragment in err
    assert any(fragment in m for m in json.loads(out)["integrity"]["metadata"])
    assert _run(capsys, ["analyze", bag, "--gains", GAINS, "--strict"])[0] == 2


@pytest.mark.parametrize("cmd", ["analyze", "report", "identify", "replay", "bag"])
def test_metadata_naming_another_bags_mcap(tmp_path, capsys, cmd):
    other = tmp_path / "other"
    shutil.copytree(REPO / "bags" / "three_tank_bias_h1", other)
    bag = tmp_path / "three_tank_nominal"
    shutil.copytree(NOMINAL, bag)
    _edit_meta(bag, lambda i: i.update(relative_file_paths=["../other/three_tank_bias_h1.mcap"]))
    argv = {"analyze": ["analyze", bag, "--gains", GAINS],
            "report": ["report", bag, "--gains", GAINS, "-o", tmp_path / "r"],
            "identify": ["identify", bag, "-o", tmp_path / "p.yaml"],
            "replay": ["replay", bag],
            "bag": ["bag", "check", bag]}[cmd]
    _one_line(capsys, argv, "not a file of this bag folder")


def test_garbage_appended_is_damage(tmp_path, capsys, short):
    bag = tmp_path / "b"
    shutil.copytree(short, bag)
    with open(bag / "three_tank_nominal.mcap", "ab") as f:
        f.write(os.urandom(5000))
    code, out, _ = _run(capsys, ["bag", "check", bag])
    assert code == 1 and "does not end with an MCAP footer" in out


# -- item 1: identify gets analyze's input checks ----------------------------------------------

@pytest.fixture(scope="module")
def linear():
    """A one-input, one-output linear plant's record (identify fits it in well under 1 s)."""
    rng = np.random.default_rng(3)
    K = 400
    u = np.repeat(rng.uniform(-1, 1, K // 20), 20).reshape(-1, 1)
    y = np.zeros((K, 1))
    for k in range(K - 1):
        y[k + 1] = 0.9 * y[k] + 0.5 * u[k] + rng.uniform(-1e-3, 1e-3)
    return u, y


def _lin_bag(path, linear, stamps=None, u=None, y=None, y_labels=("y1",), extra=None):
    u0, y0 = linear
    ks = np.arange(len(u0)) if stamps is None else np.asarray(stamps)
    ns = np.arange(len(u0)) * 100_000_000
    arrays = [arrays_from(U, ("u1",), ks, u0 if u is None else u, ns),
              arrays_from(Y, y_labels, ks, y0 if y is None else y, ns)]
    return write_bag(path, arrays + (extra or []))


def _with_y(linear, rows, value):
    y = linear[1].copy()
    y[rows] = value
    return y


IDENTIFY = [
    # (id, bag builder, what the integrity record must show)
    ("stamps-2^52", lambda p, lin: _lin_bag(p, lin, stamps=np.r_[np.arange(399), 2**52]),
     "held"),
    ("stamps-back", lambda p, lin: _lin_bag(p, lin, stamps=np.r_[np.arange(200),
                                                                 np.arange(150, 350)]),
     "out_of_order"),
    ("stamps-restart", lambda p, lin: _lin_bag(p, lin, stamps=np.r_[np.arange(200),
                                                                    np.arange(200)]),
     "out_of_order"),
    ("duplicates", lambda p, lin: _lin_bag(p, lin, stamps=np.r_[np.arange(200),
                                                                np.arange(100, 300)]),
     "out_of_order"),
    ("y-out-of-limits", lambda p, lin: _lin_bag(p, lin, y=_with_y(lin, slice(10, 20), 1e300)),
     "implausible"),
    ("garbage", None, "skipped_chunks"),
    ("metadata-removed", None, "metadata"),
]


@pytest.mark.parametrize("make,shows", [r[1:] for r in IDENTIFY], ids=[r[0] for r in IDENTIFY])
def test_identify_says_what_it_did_not_use(tmp_path, capsys, linear, make, shows):
    bag = tmp_path / "b"
    if make is None:
        _lin_bag(bag, linear)
        if shows == "metadata":
            (bag / "metadata.yaml").unlink()
        else:
            with open(bag / "b.mcap", "ab") as f:
                f.write(os.urandom(5000))
    else:
        make(bag, linear)
    out = tmp_path / "p.yaml"
    code, js, err = _run(capsys, ["identify", bag, "-o", out, "--model", "linear", "--json"])
    assert code == 0, err
    doc = json.loads(js)["integrity"][str(bag)]
    assert doc["clean"] is False and "warning" in err
    assert shows in json.dumps(doc), doc
    out.unlink()
    _one_line(capsys, ["identify", bag, "-o", out, "--model", "linear", "--strict"],
              re.compile(r"(input not used whole \(--strict\)|does not end)"))
    assert not out.exists()


@pytest.mark.parametrize("labels,kind", [(("y2",), "malformed"), (("y1", "y2"), "wrong_length")],
                         ids=["labels-changed", "channel-count"])
def test_identify_refuses_labels_changing_mid_bag(tmp_path, capsys, linear, labels, kind):
    from fd_monitor.wire.bag_writer import write_messages

    u, y = linear
    msgs = []
    for k in range(len(u)):
        late = k >= 300
        msgs.append((U, k * 100_000_000, k, ("u1",), u[k]))
        msgs.append((Y, k * 100_000_000, k, labels if late else ("y1",),
                     np.r_[y[k], 0.0][:len(labels)] if late else y[k]))
    bag = write_messages(tmp_path / "b", msgs)
    code, js, err = _run(capsys, ["identify", bag, "-o", tmp_path / "p.yaml", "--json"])
    assert code == 0, err
    assert json.loads(js)["integrity"][str(bag)]["refused_samples"] == {kind: 100}


@pytest.mark.parametrize("value", [1e300, -1e300])
def test_identify_on_1e300_is_a_quick_clean_error(tmp_path, capsys, linear, value):
    bag = _lin_bag(tmp_path / "b", linear, y=np.full_like(linear[1], value))
    line = _one_line(capsys, ["identify", bag, "-o", tmp_path / "p.yaml"],
                     "no usable (u, y) sample")
    assert "implausible 400" in line


# -- item 2 and 3: bounds and numbers -------------------------------------------------------------

def _design_file(tmp: Path, num) -> Path:
    src = find_config_file("thesis_4_7", "systems", FileNotFoundError)
    plant = tmp / "p.yaml"
    shutil.copy(src, plant)
    design = yaml.safe_load(src.with_name("thesis_4_7.design.yaml").read_text())
    design["hinf_sc"]["lambda_grid"] = {"start": -10.0, "stop": -0.1, "num": num}
    (tmp / "p.design.yaml").write_text(yaml.safe_dump(design))
    return plant


def _lib(tmp: Path, **changes) -> Path:
    text = (REPO / "bags" / "library.yaml").read_text()
    doc = yaml.safe_load(text)
    entry = dict(doc["bags"][0], **changes)
    p = tmp / "library.yaml"
    p.write_text(yaml.safe_dump({"format_version": 1, "bags": [entry]}))
    return p


def _scen(tmp: Path, magnitude=0.01, step=None) -> Path:
    src = find_config_file("three_tank_bias_h1", "scenarios", FileNotFoundError)
    doc = yaml.safe_load(src.read_text())
    doc["system"] = str(find_config_file("three_tank", "systems", FileNotFoundError))
    doc["faults"][0]["magnitude"] = magnitude
    if step is not None:
        doc["inputs"]["v13"] = {"steps": [[0, 0.0], [10, step]]}
    p = tmp / "s.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


def _expected(tmp: Path, **changes) -> Path:
    bag = tmp / "three_tank_nominal"
    shutil.copytree(NOMINAL, bag)
    doc = yaml.safe_load((bag / "expected.yaml").read_text())
    doc.update(changes)
    (bag / "expected.yaml").write_text(yaml.safe_dump(doc))
    return bag


NUMBERS = [
    # (id, argv builder, fragment)
    ("qb-margin-nan", lambda t: ["design", "qb", "pwa_cascade", "--margin", "nan"],
     "argument --margin: expected a finite number >= 0, got 'nan'"),
    ("thresholds-tube-nan", lambda t: ["design", "thresholds", "three_tank", "--tube", "nan"],
     "argument --tube: expected a finite number >= 0, got 'nan'"),
    ("mc-samples-0", lambda t: ["design", "thresholds", "three_tank", "--mc-samples", "0"],
     "argument --mc-samples: expected an integer in [1, 10000000], got '0'"),
    ("length-minus-3", lambda t: ["design", "thresholds", "three_tank", "--length", "-3"],
     "argument --length: expected an integer in [1, 1000000], got '-3'"),
    ("replay-remap-bad", lambda t: ["replay", NOMINAL, "--remap", "bad"],
     "argument --remap: expected FROM:=TO with two topic names, got 'bad'"),
    ("replay-rate-nan", lambda t: ["replay", NOMINAL, "--rate", "nan"],
     "argument --rate: expected a finite number >= 0, got 'nan'"),
    ("simulate-seed-2^80", lambda t: ["simulate", "three_tank_nominal", "-o", t / "b",
                                      "--seed", str(2**80)], "argument --seed: expected an "
                                                             "integer >= 0"),
    ("evaluate-runs-1e12", lambda t: ["evaluate", GAINS, "-s", "three_tank_nominal", "--runs",
                                      "1e12"], "argument -n/--runs: expected an integer in [1, "
                                               "1000000], got '1e12'"),
    ("evaluate-runs-10^12", lambda t: ["evaluate", GAINS, "-s", "three_tank_nominal", "--runs",
                                       str(10**12)], "argument -n/--runs: expected an integer"),
    ("report-transient-inf", lambda t: ["report", NOMINAL, "-o", t / "r", "--transient", "inf"],
     "argument --transient: expected a finite number >= 0, got 'inf'"),
    ("identify-split-1", lambda t: ["identify", NOMINAL, "-o", t / "p.yaml", "--split", "1"],
     "argument --split: expected a finite number > 0 and < 1, got '1'"),
    ("hinf-grid-num-fraction", lambda t: ["design", "hinf_sc", "thesis_4_7", "--grid", "-10",
                                          "-1", "2.5"], "--grid NUM 2.5: expected an integer"),
    ("lambda-grid-1e9", lambda t: ["design", "hinf_sc", _design_file(t, 10**9)],
     "lambda_grid.num: expected an integer in [1, 1000] (MAX_GRID_POINTS"),
    ("library-duration-1e12", lambda t: ["simulate", "--library", _lib(t, duration=1e12)],
     re.compile(r"bag three_tank_nominal: duration 1e\+12 s .* would need .* of memory")),
    ("library-duration-inf", lambda t: ["simulate", "--library", _lib(t, duration=".inf")],
     "expected a finite duration > 0 in s"),
    ("scenario-magnitude-1e308", lambda t: ["validate", "--scenario", _scen(t, 1e308)],
     "faults[0].magnitude: expected a magnitude of at most 1.1"),
    ("scenario-step-1e308", lambda t: ["validate", "--scenario", _scen(t, step=1e308)],
     "inputs.v13: expected values inside the limits of input v13 [-0.5, 1.5]"),
    ("expected-tolerance-nan", lambda t: ["report", _expected(
        t, bias_estimate={"h1": {"value": 0.0, "tolerance": float("nan")}}), "-o", t / "r"],
     "bias_estimate.h1.tolerance: expected a finite number >= 0"),
    ("expected-other-bag", lambda t: ["report", _expected(t, bag="three_tank_bias_h1"),
                                      "-o", t / "r"],
     "bag: expected the name of its bag folder 'three_tank_nominal'"),
    ("plant-100MB", lambda t: ["validate", _sparse(t / "big.yaml", 100 * 2**20)],
     "over the limit of 16.8 MB for a YAML file (MAX_FILE_BYTES"),
    ("gains-100MB", lambda t: ["analyze", NOMINAL, "--gains", _sparse(t / "g.yaml", 10**8)],
     "MAX_FILE_BYTES"),
]


def _sparse(p: Path, size: int) -> Path:
    with open(p, "wb") as f:
        f.truncate(size)
    return p


@pytest.mark.parametrize("build,fragment", [r[1:] for r in NUMBERS], ids=[r[0] for r in NUMBERS])
def test_numbers_and_bounds_one_line(tmp_path, capsys, build, fragment):
    _one_line(capsys, build(tmp_path), fragment)


# -- item 4: unknown keys, YAML tags, BOM/CRLF/comments, folders and FIFOs ------------------------

def _lib_text(tmp: Path, f) -> Path:
    p = _lib(tmp)
    p.write_text(f(p.read_text()))
    return p


FILES = [
    ("library-binary", lambda t: ["simulate", "--library", _lib_text(
        t, lambda s: s.replace("description:", "x: !!binary aGVsbG8=\n  description:"))],
     "YAML tag !!binary (refused"),
    ("library-unknown-top-key", lambda t: ["simulate", "--library", _lib_text(
        t, lambda s: s + "extra_key: 1\n")], "extra_key: expected one of ['bags', "),
    ("library-unknown-gains", lambda t: ["simulate", "--library", _lib(t, gains="nope_gains")],
     "bags[0].gains: expected a gain file (nope_gains: unknown gain file"),
    ("plant-python-tag", lambda t: ["validate", _write(t / "p.yaml",
                                                       "name: !!python/name:os.system x\n")],
     "YAML tag !!python/name:os.system"),
    ("plant-folder", lambda t: ["validate", t], "is a folder"),
    ("gains-folder", lambda t: ["analyze", NOMINAL, "--gains", t], "is a folder"),
    ("plant-fifo", lambda t: ["validate", _fifo(t / "p.yaml")], "is a FIFO (named pipe)"),
    ("library-folder", lambda t: ["simulate", "--library", t], "is a folder"),
]


def _write(p: Path, text: str) -> Path:
    p.write_text(text)
    return p


def _fifo(p: Path) -> Path:
    os.mkfifo(p)
    return p


@pytest.mark.parametrize("build,fragment", [r[1:] for r in FILES], ids=[r[0] for r in FILES])
def test_files_one_line(tmp_path, capsys, build, fragment):
    _one_line(capsys, build(tmp_path), fragment)


@pytest.mark.parametrize("variant", ["bom", "crlf", "comment"])
def test_meaning_independent_of_bom_crlf_comments(tmp_path, variant):
    from fd_monitor.analysis.generate import bag_messages
    from fd_monitor.analysis.library import load_library
    from fd_monitor.model.system import load_system

    base = _lib(tmp_path, duration=2.0)
    text = base.read_text()
    other = tmp_path / "v" / "library.yaml"
    other.parent.mkdir()
    raw = {"bom": "\ufeff" + text, "crlf": text.replace("\n", "\r\n"),
           "comment": "# " + "c" * 20000 + "\n" + text.replace("bags:", "# why\nbags:  # b")
           }[variant]
    other.write_bytes(raw.encode())
    a, b = load_library(base).bags[0], load_library(other).bags[0]
    assert (a.scenario, a.seed, a.duration, a.gains, a.corruptions) == \
        (b.scenario, b.seed, b.duration, b.gains, b.corruptions)
    ma, mb = bag_messages(a)[0], bag_messages(b)[0]          # the bag that would be written
    assert [(m.topic, m.stamp, m.values.tobytes()) for m in ma] == \
        [(m.topic, m.stamp, m.values.tobytes()) for m in mb]
    plant = find_config_file("three_tank", "systems", FileNotFoundError).read_text()
    p = tmp_path / "p.yaml"
    p.write_bytes({"bom": "\ufeff" + plant, "crlf": plant.replace("\n", "\r\n"),
                   "comment": "# " + "c" * 20000 + "\n" + plant}[variant].encode())
    assert load_system(p).sha256 == load_system("three_tank").sha256


def test_params_key_outside_ros_parameters(tmp_path):
    from fd_monitor.model.errors import FdMonitorError
    from fd_monitor.nodes.ros_args import find_params_file

    p = tmp_path / "d.yaml"
    p.write_text("detector:\n  ros__parameters:\n    warn_share: 0.5\n  stray: 1\n")
    with pytest.raises(FdMonitorError, match=r"detector\.stray: not inside ros__parameters"):
        find_params_file(str(p))
    with pytest.raises(FdMonitorError, match="is a folder"):
        find_params_file(str(tmp_path))


@pytest.mark.ros
def test_node_warns_once_on_undeclared_and_refuses_bad_choice(capfd):
    import rclpy
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from fd_monitor.model.errors import FdMonitorError
    from fd_monitor.nodes.params import Param, declare_parameters

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        params = (Param("layout", "standalone", "where", choices=("standalone", "chain")),)
        node = Node("n26", context=ctx, parameter_overrides=[
            Parameter("layuot", value="chain"), Parameter("warn_shrae", value=0.5)])
        declare_parameters(node, params)
        err = capfd.readouterr().err
        assert err.count("does not declare") == 1 and "layuot, warn_shrae" in err
        node.destroy_node()
        node = Node("n26b", context=ctx, parameter_overrides=[
            Parameter("layout", value="weird")])
        with pytest.raises(FdMonitorError, match="parameter layout: 'weird': expected one of "
                                                 "standalone, chain"):
            declare_parameters(node, params)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


# -- item 5: CRC 0 is "not computed" -------------------------------------------------------

def test_rosbags_bag_without_crcs_is_not_damaged(tmp_path, capsys):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from fd_monitor.wire.bag_writer import serialize_array

    ts = get_typestore(Stores.ROS2_JAZZY)
    bag = tmp_path / "rb"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        cu = w.add_connection(U, "std_msgs/msg/Float64MultiArray", typestore=ts)
        cy = w.add_connection(Y, "std_msgs/msg/Float64MultiArray", typestore=ts)
        for k in range(200):
            w.write(cu, k * 100_000_000, serialize_array(("q1", "q2", "v13"), k,
                                                         [1e-4, 1e-4, 0.0]))
            w.write(cy, k * 100_000_000, serialize_array(("h1", "h2", "h3"), k,
                                                         [0.4, 0.2, 0.3]))
    code, out, err = _run(capsys, ["bag", "check", bag])
    assert code == 0 and err == ""
    assert out.count("carry no CRC") == 1 and "0 damage(s)" in out
    code, out, err = _run(capsys, ["analyze", bag, "--gains", GAINS, "--json", "--strict"])
    assert code == 0 and err == ""
    doc = json.loads(out)["integrity"]
    assert doc["unchecked_chunks"] >= 1 and doc["clean"] is True


# -- "one line, exit 2, no traceback" as real processes -------------------------------------------

@pytest.mark.parametrize("argv,fragment", [
    (["simulate", "three_tank_nominal", "-o", "x", "--seed", str(2**80)], "argument --seed"),
    (["evaluate", GAINS, "-s", "three_tank_nominal", "--runs", "1e12"], "argument -n/--runs"),
    (["analyze", "BAG", "--gains", GAINS], "no usable sample: every one was refused"),
], ids=["seed-2^80", "runs-1e12", "all-refused"])
def test_subprocess_one_line_exit_2(tmp_path, nominal, argv, fragment):
    if "BAG" in argv:
        argv = [str(_bag(tmp_path / "b", nominal, y=np.full_like(nominal[Y][2], 5.0)))
                if a == "BAG" else a for a in argv]
    p = subprocess.run([sys.executable, "-m", "fd_monitor", *argv], capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 2, p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and fragment in p.stderr
    assert "Traceback" not in p.stderr and "RuntimeWarning" not in p.stderr


def _as_from_a_shell() -> None:
    """In the child before exec: SIGINT at its default and not blocked, as a shell starts a
    command. A test process's own signal state (an rclpy context's handler, a thread's
    mask, a disposition a library left) must not reach the command under test: with SIGINT
    inherited as ignored, the child never sees the Ctrl-C."""
    import signal

    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_evaluate_stops_cleanly_on_ctrl_c(tmp_path):
    import signal

    src = find_config_file("three_tank_nominal", "scenarios", FileNotFoundError)
    doc = yaml.safe_load(src.read_text())
    doc.update(duration=5.0, system=str(find_config_file("three_tank", "systems",
                                                          FileNotFoundError)))
    scen = tmp_path / "short.yaml"              # 50 samples a run: the bar comes at once
    scen.write_text(yaml.safe_dump(doc))
    p = subprocess.Popen([sys.executable, "-m", "fd_monitor", "evaluate", GAINS, "-s",
                          str(scen), "--runs", "1000000", "--chunk", "1",
                          "--workers", "0"],             # the in-process campaign
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         preexec_fn=_as_from_a_shell)
    try:
        assert p.stderr is not None
        seen = b""
        while b"evaluate [" not in seen:        # the progress bar: the campaign runs
            ch = p.stderr.read(1)
            assert ch, "evaluate ended before its progress bar"
            seen += ch
        p.send_signal(signal.SIGINT)
        _out, rest = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    err = (seen + rest).decode()
    assert p.returncode == 130, err
    assert err.rstrip().splitlines()[-1] == ("fd_monitor: interrupted (Ctrl-C): evaluate "
                                             "stopped, nothing more written")
    assert "Traceback" not in err


def _label_bag(path: Path, nominal, label_of) -> Path:
    from fd_monitor.wire.bag_writer import write_messages

    (lu, _s, vu, tu), (ly, _s2, vy, _t) = nominal[U], nominal[Y]
    msgs = []
    for k in range(100):
        msgs += [(U, tu[k], k, lu, vu[k]), (Y, tu[k], k, label_of(k, ly), vy[k])]
    return write_messages(path, msgs)


def test_long_labels_are_refused_short(tmp_path, capsys, nominal):
    # 100 kB label strings on 20 messages: refused as malformed, each with a short line
    long = ("h" * 100_000, "h2", "h3")
    bag = _label_bag(tmp_path / "b", nominal, lambda k, ly: long if 40 <= k < 60 else ly)
    code, out, _ = _run(capsys, ["analyze", bag, "--gains", GAINS, "--json"])
    doc = json.loads(out)
    assert code == 0 and doc["integrity"]["refused_samples"] == {"malformed": 20}
    assert max(len(e["message"]) for e in doc["input_errors"]) < 300


def test_too_many_distinct_labels_is_one_line(tmp_path, capsys, nominal):
    bag = _label_bag(tmp_path / "b", nominal, lambda k, ly: (f"a{k}", "b", "c"))
    _one_line(capsys, ["analyze", bag, "--gains", GAINS],
              re.compile(r"(has channels|more than 64 distinct channel label strings)"))
    _one_line(capsys, ["bag", "check", bag, "--strict"],
              "more than 64 distinct channel label strings (limit MAX_DISTINCT_LABELS")
