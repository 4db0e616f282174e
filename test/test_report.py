"""Bag and campaign reports: figures written and readable, summary.md, CLI errors."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from fd_monitor.analysis.library import load_library
from fd_monitor.analysis.report import bag_report, campaign_report
from fd_monitor.wire.bag_reader import arrays_from
from fd_monitor.wire.bag_writer import write_bag

LIB = load_library()


def _png(path):
    import matplotlib.image as mpimg

    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 300 and img.shape[1] > 600, img.shape
    return img


def test_qb_bag_report(tmp_path):
    spec = LIB["pwa_cascade_b1_step"]
    res = bag_report(spec.folder, tmp_path)
    assert set(res["figures"]) == {"residuals", "modes", "bias", "qb_bound"}
    for p in res["figures"].values():
        _png(p)
    md = (tmp_path / "summary.md").read_text()
    assert "All expectations hold." in md
    first = res["summary"]["alarms"][0]
    assert first["channel"] == "b1"
    assert f"| b1 | {first['first_sample']} | {first['first_sample'] * 0.01:.2f} | yes |" in md
    for name in ("residuals.png", "modes.png", "bias.png", "qb_bound.png"):
        assert f"]({name})" in md
    assert res["expected_failures"] == []


def test_thresholds_bag_report_with_bad_input(tmp_path):
    spec = LIB["three_tank_bad_input"]
    res = bag_report(spec.folder, tmp_path, spec.gains)
    assert set(res["figures"]) == {"residuals", "modes", "bias"}
    for p in res["figures"].values():
        _png(p)
    md = (tmp_path / "summary.md").read_text()
    assert "non_finite: [300, 301]" in md and "restarts at samples: [750]" in md
    assert "bridged holes (memory kept) at samples: [302, 451]" in md
    assert res["summary"]["alarms"] == []


def test_report_flags_failed_expectations(tmp_path):
    """With another bag's expectations the report says FAILED (the check is real)."""
    res = bag_report(LIB["three_tank_bias_h2"].folder, tmp_path,
                     expected=LIB["three_tank_bias_h1"].expected_file)
    assert res["expected_failures"]
    assert "**FAILED:**" in (tmp_path / "summary.md").read_text()


def test_campaign_report(tmp_path):
    from fd_monitor.analysis.evaluate import CampaignRow
    from fd_monitor.model.scenario import load_scenario

    scs = [load_scenario("bag_three_tank_nominal"), load_scenario("bag_three_tank_bias_h1"),
           load_scenario("bag_three_tank_bias_h2"), load_scenario("bag_three_tank_incipient_h3")]
    rows = [CampaignRow(scs[0].name, "thresholds", None, 20, 0.0),
            CampaignRow(scs[1].name, "thresholds", None, 20, 0.05, 1.0, 0.1, 0.1, 0.3, 100.0),
            CampaignRow(scs[2].name, "thresholds", None, 20, 0.0, 0.9, 0.4, 0.2, 1.5, 100.0),
            # same magnitude as bias_h1 (0.03): ties must not break the plot
            CampaignRow(scs[3].name, "thresholds", None, 20, 0.0, 1.0, 2.0, 1.9, 4.0, 80.0)]
    res = campaign_report(rows, scs, tmp_path, gains="three_tank_thresholds")
    assert set(res["figures"]) == {"detection", "false_alarms"}
    for p in res["figures"].values():
        _png(p)
    md = (tmp_path / "summary.md").read_text()
    assert "| bag_three_tank_bias_h2 | 0.025 | thresholds | - | 20 | 0.0 | 90.0 |" in md


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "fd_monitor", "report", *args],
                          capture_output=True, text=True, timeout=300)


def test_cli_report_writes_and_prints(tmp_path):
    out = _cli(str(LIB["pwa_cascade_nominal"].folder), "-o", str(tmp_path / "r"), "--json")
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "r" / "summary.md").is_file()
    assert '"expected": "ok"' in out.stdout


@pytest.mark.parametrize("case", ["missing_bag", "missing_topic", "unknown_gains"])
def test_cli_errors_are_one_line(tmp_path, case):
    bag = str(LIB["three_tank_bad_input"].folder)
    args = [bag, "-o", str(tmp_path / "r")]
    if case == "missing_bag":
        args[0] = str(tmp_path / "nobag")
        want = "no such bag"
    elif case == "missing_topic":
        b = tmp_path / "only_u"
        write_bag(b, [arrays_from("/plant/u", ("q1", "q2", "v13"), [0, 1], np.zeros((2, 3)),
                                  [0, 100_000_000])])
        args = [str(b), "--gains", "three_tank_thresholds", "-o", str(tmp_path / "r")]
        want = "/plant/y"
    else:
        args += ["--gains", "no_such_gains"]
        want = "unknown gain file"
    out = _cli(*args)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fd_monitor: error:"), out.stderr
    assert want in lines[0]


def test_report_console_script_help():
    out = subprocess.run([sys.executable, "-c",
                          "import sys; from fd_monitor.commands.report import main; "
                          "sys.argv = ['report', '--help']; sys.exit(main())"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "usage" in out.stdout.lower()
