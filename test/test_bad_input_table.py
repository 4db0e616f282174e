"""Every bad file and argument of issue 12 gets one line ``fd_monitor: error: ...`` and exit 2.

One table: each row builds its input in tmp_path, runs the command line in process
(``fd_monitor.commands.cli.main``) and expects status 2, a single stderr line starting
``fd_monitor`` and containing the row's fragment, and no traceback. The interrupted
``replay`` (130/143) is a separate test: it needs a real process and a signal.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fd_monitor.commands.cli import main as cli_main
from fd_monitor.model.paths import find_config_file

REPO = Path(__file__).resolve().parent.parent
PLANT = find_config_file("three_tank", "systems", FileNotFoundError).read_text()
PWA = find_config_file("pwa_cascade", "systems", FileNotFoundError).read_text()
SCEN = find_config_file("three_tank_nominal", "scenarios", FileNotFoundError).read_text()
GAINS = find_config_file("three_tank_thresholds", "gains", FileNotFoundError).read_text()
BAG = str(REPO / "bags" / "three_tank_nominal")


def _write(tmp: Path, name: str, text: str | bytes) -> str:
    p = tmp / name
    if isinstance(text, bytes):
        p.write_bytes(text)
    else:
        p.write_text(text)
    return str(p)


def _plant(tmp: Path, old: str, new: str, base: str = PLANT) -> str:
    assert old in base, old
    return _write(tmp, "plant.yaml", base.replace(old, new, 1))


def _scenario(tmp: Path, extra: str = "", old: str = "", new: str = "") -> str:
    text = SCEN.replace("system: three_tank", f"system: {REPO}/config/systems/three_tank.yaml")
    if old:
        assert old in text, old
        text = text.replace(old, new, 1)
    return _write(tmp, "scen.yaml", text + extra)


def _gains(tmp: Path, old: str, new: str) -> str:
    assert old in GAINS, old
    return _write(tmp, "gains.yaml", GAINS.replace(old, new, 1))


def _big_plant(tmp: Path, n: int) -> str:
    names = ", ".join(f"x{i}" for i in range(n))
    eye = "\n".join("    - [" + ", ".join("-1.0" if i == j else "0.0" for j in range(n)) + "]"
                    for i in range(n))
    return _write(tmp, "big.yaml", f"name: big\nsample_time: 0.1\nstates: [{names}]\n"
                  f"outputs: [{names}]\nmodes:\n  m:\n    A:\n{eye}\n    C:\n{eye}\n"
                  f"initial: {{mode: m, state: [{', '.join(['0.0'] * n)}]}}\n")


def _alias_bomb(tmp: Path) -> str:
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for i in range(1, 10):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]")
    return _write(tmp, "plant.yaml", PLANT.replace(
        "format_version: 1", "format_version: 1\nx-bombs:\n" + "\n".join(
            "  " + ln for ln in lines), 1).replace("description: >-", "description_: >-", 1)
        + "description: *a9\n")


def _file_here(tmp: Path) -> str:
    return _write(tmp, "afile", "x")


ROWS = [
    # (id, argv builder, expected fragment)
    ("plant-not-utf8", lambda t: ["validate", _write(t, "p.yaml", b"name: \xff\xfe\n")],
     "not UTF-8 text"),
    ("gains-not-utf8", lambda t: ["analyze", BAG, "--gains",
                                  _write(t, "g.yaml", b"method: \xff\n")], "not UTF-8 text"),
    ("scenario-not-utf8", lambda t: ["validate", "--scenario",
                                     _write(t, "s.yaml", b"system: \xc3\x28\n")],
     "not UTF-8 text"),
    # 100 levels: libyaml accepts it, the project's own limit (64) refuses it
    ("deep-nesting", lambda t: ["validate", _write(t, "p.yaml", "a: " + "[" * 100
                                                   + "]" * 100 + "\n")],
     "p.yaml: line 1: YAML nested deeper than 64 levels (refused)"),
    # 20,000 levels: whichever refuses first, as one line naming the file -- the project's
    # check, or the parser's own limit (libyaml >= 0.2.5 stops at 1,000 levels, PyYAML 6.0.4
    # with its bundled libyaml says "exceeded maximum nesting depth")
    ("deep-nesting-20000", lambda t: ["validate", _write(t, "p.yaml", "a: " + "[" * 20000
                                                         + "]" * 20000 + "\n")],
     re.compile(r"p\.yaml: (line 1: YAML nested deeper than 64 levels \(refused\)|invalid "
                r"YAML at line 1, column \d+: exceeded maximum nesting depth)")),
    ("gains-results-list", lambda t: ["analyze", BAG, "--gains",
                                      _gains(t, "results:", "results: [1, 2]\nresults_:")],
     "results: expected a mapping"),
    ("fault-parameter-list", lambda t: ["validate", _plant(
        t, "parameter: leak_area_1}", "parameter: [leak_area_1]}")],
     "faults[5].parameter: expected the name of a model parameter"),
    ("tank-area-zero", lambda t: ["validate", _plant(t, "tank_area: 0.0154", "tank_area: 0")],
     "params.tank_area: expected a value in (0, 1000]"),
    ("tank-area-negative", lambda t: ["validate", _plant(t, "tank_area: 0.0154",
                                                         "tank_area: -0.0154")],
     "params.tank_area: expected a value in (0, 1000]"),
    ("sample-time-tiny", lambda t: ["validate", _plant(t, "sample_time: 0.1",
                                                       "sample_time: 1e-300")],
     "sample_time: expected a sample time in [1e-06, 1e+06] s"),
    ("duration-huge", lambda t: ["validate", "--scenario", _scenario(
        t, old="duration: 400.0", new="duration: 1e12")], "would need"),
    ("cli-duration-nan", lambda t: ["simulate", "three_tank_nominal", "-o", str(t / "b"),
                                    "--duration", "nan"],
     "argument --duration: expected a finite number > 0, got 'nan'"),
    ("cli-duration-inf", lambda t: ["simulate", "three_tank_nominal", "-o", str(t / "b"),
                                    "--duration", "inf"],
     "argument --duration: expected a finite number > 0, got 'inf'"),
    ("qb-500-states", lambda t: ["design", "qb", _big_plant(t, 500), "-o", str(t / "g.yaml")],
     "a QB design of 500 states: would need 126 GB of memory"),
    ("report-onto-file", lambda t: ["report", BAG, "-o", _file_here(t)],
     "exists and is not a folder"),
    ("report-unwritable", lambda t: ["report", BAG, "-o", _file_here(t) + "/sub"],
     "cannot write there"),
    ("report-no-overwrite", lambda t: ["report", BAG, "-o", str(Path(_file_here(t)).parent)],
     "folder is not empty (would overwrite; use --force)"),
    ("evaluate-report-onto-file", lambda t: ["evaluate", "three_tank_thresholds", "-s",
                                             "three_tank_nominal", "--report", _file_here(t)],
     "--report"),
    ("design-o-unwritable", lambda t: ["design", "qb", "pwa_cascade", "-o",
                                       _file_here(t) + "/g.yaml"], "cannot write there"),
    ("design-o-folder", lambda t: ["design", "qb", "pwa_cascade", "-o", str(t)],
     "is a folder"),
    ("design-o-no-overwrite", lambda t: ["design", "qb", "pwa_cascade", "-o", _file_here(t)],
     "exists (would overwrite; use --force)"),
    ("evaluate-chunk-0", lambda t: ["evaluate", "three_tank_thresholds", "-s",
                                    "three_tank_nominal", "--chunk", "0"],
     "argument --chunk: expected an integer in [1, 1000000], got '0'"),
    ("evaluate-seed0-negative", lambda t: ["evaluate", "three_tank_thresholds", "-s",
                                           "three_tank_nominal", "--seed0", "-1"],
     "argument --seed0: expected an integer >= 0, got '-1'"),
    ("A-1e308", lambda t: ["validate", _plant(t, "A: [[-0.5, 0.0, 1.0, 0.0]",
                                              "A: [[1.0e+308, 0.0, 1.0, 0.0]", PWA)],
     "expected a number of magnitude <= 1e+15"),
    ("bounds-1e308", lambda t: ["validate", _plant(t, "measurement_noise: [0.001, 0.001, 0.001]",
                                                   "measurement_noise: [1e308, 0.001, 0.001]")],
     "bounds.measurement_noise[0]: expected a number of magnitude"),
    ("fault-after-end", lambda t: ["validate", "--scenario", _scenario(
        t, "faults:\n  - {channel: bias_h1, profile: abrupt, time: 500.0, magnitude: 0.01}\n")],
     "faults[0].time: expected a time inside the run"),
    ("relative-string", lambda t: ["validate", "--scenario", _scenario(
        t, "faults:\n  - {channel: pump1, profile: abrupt, time: 10.0, magnitude: 0.3, "
        "relative: 'false'}\n")], "faults[0].relative: expected true or false, got 'false'"),
    ("duplicate-key", lambda t: ["validate", _plant(t, "sample_time: 0.1",
                                                    "sample_time: 0.1\nsample_time: 0.2")],
     "duplicate key 'sample_time'"),
    ("format-version-true", lambda t: ["validate", _plant(t, "format_version: 1",
                                                          "format_version: true")],
     "format_version: expected one of (1,), got True"),
    ("gains-format-version-true", lambda t: ["analyze", BAG, "--gains", _gains(
        t, "format_version: 1", "format_version: true")], "format_version: expected 1"),
    ("alias-bomb", lambda t: ["validate", _alias_bomb(t)], "alias bomb"),
]


@pytest.mark.parametrize("build,fragment", [r[1:] for r in ROWS], ids=[r[0] for r in ROWS])
def test_bad_input_one_line_exit_2(tmp_path, capsys, build, fragment):
    argv = build(tmp_path)
    try:
        code = cli_main(argv)
    except SystemExit as exc:                            # argparse usage errors
        code = exc.code
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("fd_monitor"), err
    if isinstance(fragment, re.Pattern):
        assert fragment.search(lines[0]), lines[0]
    else:
        assert fragment in lines[0], lines[0]
    assert "Traceback" not in err


def test_force_allows_overwrite_checks_pass(tmp_path):
    from fd_monitor.model.errors import FdMonitorError
    from fd_monitor.model.paths import check_output

    f = Path(_file_here(tmp_path))
    assert check_output(f, "-o", FdMonitorError, folder=False, force=True) == f
    assert check_output(tmp_path, "-o", FdMonitorError, folder=True, force=True) == tmp_path
    with pytest.raises(FdMonitorError, match="use --force"):
        check_output(tmp_path, "-o", FdMonitorError, folder=True, force=False)


def test_merge_keys_and_anchors_still_load():
    # The shipped three_tank uses `&base` / `<<: *base`: explicit keys override merged ones.
    from fd_monitor.model.system import load_system

    s = load_system("three_tank")
    assert s.modes[1].params["upper_area"] == 2.5e-5 and s.modes[0].params["upper_area"] == 0


@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_interrupted_replay_exits_non_zero(tmp_path, sig, code):
    env = dict(os.environ, ROS_LOG_DIR=str(tmp_path / "log"))
    p = subprocess.Popen([sys.executable, "-m", "fd_monitor", "replay", BAG, "--rate", "0.2"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        # Wait (bounded) until it runs: rclpy is up once it logs or has published.
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and p.poll() is None:
            if _has_node(p.pid):
                break
            time.sleep(0.1)
        time.sleep(1.0)
        p.send_signal(sig)
        _out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == code, err
    assert re.search(rf"replay interrupted by {sig.name}", err)


def _has_node(pid: int) -> bool:
    """The replay process has opened its DDS sockets (rclpy initialised)."""
    try:
        return any("socket" in os.readlink(f"/proc/{pid}/fd/{fd}")
                   for fd in os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return False
