"""Installation layout: pip (prefix install) and colcon both install what `ros2 run` needs.

`ros2 run fd_monitor <exe>` looks for `<prefix>/lib/fd_monitor/<exe>` of a package listed in
the ament index (`<prefix>/share/ament_index/resource_index/packages/fd_monitor`). There is
no `ros2` CLI on this machine, so these tests check the installed files and run the
launchers directly, as `ros2 run` would.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from fd_monitor.executables import EXECUTABLES

pytestmark = pytest.mark.slow


def _check_layout(prefix: Path) -> None:
    assert (prefix / "share/ament_index/resource_index/packages/fd_monitor").is_file()
    assert (prefix / "share/fd_monitor/package.xml").is_file()
    for plant in ("three_tank", "pwa_cascade"):
        assert (prefix / f"share/fd_monitor/config/systems/{plant}.yaml").is_file()
    for exe in EXECUTABLES:
        launcher = prefix / "lib/fd_monitor" / exe
        assert launcher.is_file(), exe
        assert os.access(launcher, os.X_OK), f"{launcher} is not executable"


def _env(prefix: Path, site: Path | None) -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["AMENT_PREFIX_PATH"] = str(prefix)
    env.pop("FD_MONITOR_CONFIG", None)
    if site is not None:
        env["PYTHONPATH"] = str(site)
    return env


def _run_launchers(prefix: Path, env: dict[str, str], cwd: Path) -> None:
    """Every launcher answers --help; the CLI one finds the installed config via the prefix."""
    for exe in EXECUTABLES:
        out = subprocess.run([str(prefix / "lib/fd_monitor" / exe), "--help"], env=env,
                             cwd=cwd, capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, f"{exe} --help: {out.stderr[-800:]}"
        assert "usage" in out.stdout.lower(), exe
    out = subprocess.run([str(prefix / "lib/fd_monitor/fd_monitor"), "validate", "three_tank"],
                         env=env, cwd=cwd, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert str(prefix / "share/fd_monitor/config/systems/three_tank.yaml") in out.stdout


def test_pip_install_layout_and_launchers(repo: Path, tmp_path: Path) -> None:
    prefix = tmp_path / "prefix"
    build = tmp_path / "src"
    shutil.copytree(repo, build, ignore=shutil.ignore_patterns(
        ".venv", ".git", "build", "install", "log", "*.egg-info", "__pycache__", "bags"))
    # --ignore-installed: without it pip uninstalls the venv's own (editable) fd_monitor.
    out = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps",
                          "--no-build-isolation", "--ignore-installed", "--prefix", str(prefix),
                          str(build)],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    _check_layout(prefix)
    site = next(prefix.glob("lib/python3*/site-packages"))
    _run_launchers(prefix, _env(prefix, site), tmp_path)


def test_colcon_build_installs_an_ament_python_package(repo: Path, tmp_path: Path) -> None:
    colcon = Path(sys.executable).parent / "colcon"
    if not colcon.exists():
        pytest.fail("colcon is not installed in the test environment (scripts/setup.sh "
                    "installs colcon-core, colcon-ros, colcon-python-setup-py)")
    src = tmp_path / "ws/src/fd_monitor"
    shutil.copytree(repo, src, ignore=shutil.ignore_patterns(
        ".venv", ".git", "build", "install", "log", "*.egg-info", "__pycache__", "bags"))
    ws = tmp_path / "ws"
    out = subprocess.run([str(colcon), "build", "--base-paths", "src"], cwd=ws,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    assert "Finished <<< fd_monitor" in out.stdout
    prefix = ws / "install/fd_monitor"
    _check_layout(prefix)
    site = next(prefix.glob("lib/python3*/site-packages"))
    _run_launchers(prefix, _env(prefix, site), tmp_path)
