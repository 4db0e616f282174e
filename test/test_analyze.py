"""``python -m fd_monitor analyze BAG --gains GAINS``: offline diagnosis of a bag."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from fd_monitor.commands.analyze import analyze_arrays, analyze_bag
from fd_monitor.commands.cli import main as cli_main
from fd_monitor.core.methods import load_gains
from fd_monitor.core.simulator import simulate
from fd_monitor.model.errors import BagError, GainFileError, MessageError
from fd_monitor.model.gains import write_gain_doc
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system

REPO = Path(__file__).resolve().parent.parent
GAINS = REPO / "config" / "gains" / "three_tank_thresholds.yaml"

bags = pytest.importorskip("fd_monitor.wire.bag_writer")
bag_reader = pytest.importorskip("fd_monitor.wire.bag_reader")


@pytest.fixture(scope="module")
def bias_bag(tmp_path_factory):
    """three_tank_bias_h1 (1 cm bias on h1 at 200 s), cut to 260 s."""
    from fd_monitor.commands.simulate import simulate_to_bag

    path = tmp_path_factory.mktemp("bags") / "bias_h1"
    simulate_to_bag("three_tank_bias_h1", path, seed=3, duration=260.0)
    return path


def test_analyze_bag_json(bias_bag, capsys):
    assert cli_main(["analyze", str(bias_bag), "--gains", str(GAINS), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert {"alarms", "isolated", "bias_estimate"} <= set(doc)
    first = doc["alarms"][0]
    assert first["channel"] == "h1" and first["first_sample"] == 2000
    assert first["time"] == pytest.approx(200.0)
    assert doc["isolated"] == ["h1"]
    assert doc["bias_estimate"]["h1"] == pytest.approx(0.01, abs=1.5e-3)
    assert doc["transitions_true"] and doc["transitions_estimated"]
    assert doc["mode_agreement"] > 0.8


def test_analyze_table_output(bias_bag, capsys):
    assert cli_main(["analyze", str(bias_bag), "--gains", str(GAINS)]) == 0
    out = capsys.readouterr().out
    assert "first detection: sample 2000" in out
    assert "mode transitions" in out and "sensor biases" in out


def test_missing_topic(tmp_path, capsys):
    sys_ = load_system("three_tank")
    tr = simulate(load_scenario("three_tank_nominal"), 1, 50)
    ns = tr.k * 100_000_000
    path = bags.write_bag(tmp_path / "no_u", [
        bag_reader.arrays_from("/plant/y", sys_.outputs, tr.k, tr.y[0], ns)])
    with pytest.raises(BagError, match="topic /plant/u missing"):
        analyze_bag(str(path), str(GAINS))
    assert cli_main(["analyze", str(path), "--gains", str(GAINS)]) == 2
    assert "fd_monitor: error:" in capsys.readouterr().err


def test_wrong_gains_for_the_bag(tmp_path):
    """A bag of another plant (pwa_cascade) analysed with three_tank gains is refused."""
    from fd_monitor.commands.simulate import simulate_to_bag

    path = tmp_path / "pwa"
    simulate_to_bag("pwa_cascade_nominal", path, duration=0.5)
    with pytest.raises(BagError, match="wrong gain file"):
        analyze_bag(str(path), str(GAINS))


def test_gain_file_of_another_plant_version_is_refused(bias_bag, tmp_path):
    doc = yaml.safe_load(GAINS.read_text())
    doc["system"]["sha256"] = "0" * 64
    p = tmp_path / "other.yaml"
    p.write_text(yaml.safe_dump(doc))  # a hand edit: the digest names it
    with pytest.raises(GainFileError, match=r"system\.sha256 changed"):
        analyze_bag(str(bias_bag), str(p))
    write_gain_doc(p, doc)
    with pytest.raises(GainFileError, match="designed for"):
        analyze_bag(str(bias_bag), str(p))
    doc["system"]["sha256"] = load_system("three_tank").sha256
    doc["method"] = "qb"  # a QB design cannot exist for this nonlinear plant
    write_gain_doc(p, doc)
    with pytest.raises(GainFileError, match=r"certificate does not hold: .*nonlinear"):
        analyze_bag(str(bias_bag), str(p))
    doc["method"] = "hinf_sc"   # analyze runs every method, but this is no hinf_sc bank
    write_gain_doc(p, doc)
    with pytest.raises(GainFileError, match=r"malformed results or certificate: KeyError"):
        analyze_bag(str(bias_bag), str(p))


def test_analyze_arrays_reports_bad_sample():
    sys_ = load_system("three_tank")
    g = load_gains(GAINS, sys_)
    tr = simulate(load_scenario("three_tank_nominal"), 1, 30)
    y = tr.y[0].copy()
    y[17, 1] = np.nan
    with pytest.raises(MessageError, match=r"sample 17.*non-finite"):
        analyze_arrays(sys_, g, tr.k, tr.u[0], y)
    doc = analyze_arrays(sys_, g, tr.k, tr.u[0], tr.y[0], tr.mode[0])
    assert doc["alarms"] == [] and doc["isolated"] == [] and doc["mode_agreement"] == 1.0


def test_analyze_loads_no_scipy_rosbags_rclpy_cvxpy_or_matplotlib(repo):
    """`analyze` on a bundled three_tank bag with the thresholds gain file runs without
    scipy (imported where a linear mode is discretised), the rosbags type store (its
    Float64MultiArrays are read by conversions.parse_cdr), rclpy, cvxpy or matplotlib: the
    import budget behind its start-up time (benchmarks/bench_replay.py) cannot regress
    silently."""
    import subprocess
    import sys

    code = ("import json, sys\n"
            "from fd_monitor.commands.cli import main\n"
            "rc = main(['analyze', 'bags/three_tank_bias_h1', '--gains', "
            "'three_tank_thresholds', '--json'])\n"
            "heavy = ('scipy', 'rosbags', 'rclpy', 'cvxpy', 'matplotlib')\n"
            "print(json.dumps({'rc': rc, 'loaded': sorted({m.split('.')[0] for m in "
            "sys.modules if m.split('.')[0] in heavy})}))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=repo, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    doc, _, budget = out.stdout.rstrip("\n").rpartition("\n")   # analyze's JSON, then ours
    result, imports = json.loads(doc), json.loads(budget)
    assert imports == {"rc": 0, "loaded": []}
    assert result["detection"]["sample"] == 1000 and result["isolated"] == ["h1"]
