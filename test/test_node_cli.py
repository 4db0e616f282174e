"""Node command lines: ``--params-file`` found from anywhere, bad files are one line and exit 2."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from ros_util import REPO, fd_env

from fd_monitor.model.errors import FdMonitorError
from fd_monitor.nodes.ros_args import find_params_file, resolve_params_files, shown_params_file

pytestmark = pytest.mark.ros

NOT_UTF8 = b"detector:\n  ros__parameters:\n    warn_share: 0.5 # \xff\xfe\n"


def run_node(args: list[str], cwd: Path, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fd_monitor", "run", *args], cwd=cwd,
                          env=fd_env(), capture_output=True, text=True, timeout=timeout)


def test_relative_params_file_is_looked_up_in_the_config_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert find_params_file("config/detector.yaml") == REPO / "config/detector.yaml"
    assert find_params_file("detector.yaml") == REPO / "config/detector.yaml"
    # --help shows a path that works from here: the shipped file, not config/... of cwd.
    assert shown_params_file("detector") == str(REPO / "config/detector.yaml")
    (tmp_path / "config").mkdir()
    (tmp_path / "config/detector.yaml").write_text("detector:\n  ros__parameters: {}\n")
    # A file of the user's own, where the path says, wins over the shipped one.
    assert find_params_file("config/detector.yaml") == Path("config/detector.yaml")
    assert shown_params_file("detector") == "config/detector.yaml"
    args = ["x", "--ros-args", "-p", "a:=1", "--params-file", "plant_sim.yaml", "--",
            "--params-file", "not_ros"]
    assert resolve_params_files(args) == [*args[:5], str(REPO / "config/plant_sim.yaml"),
                                          "--", "--params-file", "not_ros"]
    with pytest.raises(FdMonitorError, match=r"--params-file no\.yaml: file not found \(looked "
                                             r"in .*config"):
        find_params_file("no.yaml")


def test_params_file_as_help_prints_it_works_from_another_directory(tmp_path):
    out = run_node(["plant_sim", "--help"], tmp_path)
    assert out.returncode == 0
    shown = str(REPO / "config/plant_sim.yaml")
    assert f"--params-file {shown}" in out.stdout
    # topics as the node resolves them: relative (a namespace moves them), /diagnostics not
    assert re.search(r"^  plant/y +measurements", out.stdout, re.M), out.stdout
    assert "/plant/" not in out.stdout
    assert re.search(r"^  /diagnostics ", out.stdout, re.M)
    out = run_node(["plant_sim", "--ros-args", "--params-file", "config/plant_sim.yaml",
                    "-p", "rate_factor:=0.0", "-p", "duration:=0.5"], tmp_path)
    assert out.returncode == 0, out.stderr
    assert "published 5 samples" in out.stderr


@pytest.mark.parametrize("case, node, match", [
    ("missing", "detector", r"--params-file .*missing\.yaml: file not found \(looked in"),
    ("not_utf8", "detector", r"params\.yaml: not UTF-8 text \(byte 0xff at offset"),
    ("bad_yaml", "detector", r"params\.yaml: invalid YAML at line 2"),
    ("a_list", "detector", r"params\.yaml: not a ROS 2 parameter file: expected a mapping"),
    ("bad_value", "detector", r"bad ROS arguments: .*Sequence should be of same type"),
    ("gains_not_utf8", "detector", r"gains\.yaml: not UTF-8 text"),
    ("system_not_utf8", "observer", r"plant\.yaml: not UTF-8 text"),
    ("scenario_not_utf8", "plant_sim", r"scenario\.yaml: not UTF-8 text"),
])
def test_bad_params_file_or_file_parameter_is_one_line_exit_2(tmp_path, case, node, match):
    files = {"not_utf8": NOT_UTF8, "bad_yaml": b"detector: [\n",
             "a_list": b"- 1\n- 2\n",
             "bad_value": b"detector:\n  ros__parameters:\n    warn_share: [1, 'a']\n"}
    if case in files:
        (tmp_path / "params.yaml").write_bytes(files[case])
        ros = ["--params-file", "params.yaml"]
    elif case == "missing":
        ros = ["--params-file", "missing.yaml"]
    else:
        param, name = {"gains_not_utf8": ("gains", "gains.yaml"),
                       "system_not_utf8": ("system", "plant.yaml"),
                       "scenario_not_utf8": ("scenario", "scenario.yaml")}[case]
        (tmp_path / name).write_bytes(b"name: \xff\xfe\n")
        ros = ["-p", f"{param}:={tmp_path / name}"]
    out = run_node([node, "--ros-args", *ros], tmp_path)
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr
    errors = [ln for ln in out.stderr.splitlines() if ln.startswith(f"{node}: error: ")]
    assert len(errors) == 1, out.stderr
    assert re.search(match, errors[0]), errors[0]
