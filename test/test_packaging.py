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

from fd_monitor.commands.executables import EXECUTABLES

REPO = Path(__file__).resolve().parent.parent

#: PyPI name -> rosdep key, for the setup.py dependencies that have one.
ROSDEP_KEYS = {"setuptools": "python3-setuptools", "numpy": "python3-numpy",
               "scipy": "python3-scipy", "pyyaml": "python3-yaml",
               "matplotlib": "python3-matplotlib"}


def _setup_kwargs() -> dict:
    """The keywords setup.py passes to ``setuptools.setup`` (run without installing)."""
    import runpy

    import setuptools

    seen: dict = {}
    real = setuptools.setup
    setuptools.setup = lambda **kw: seen.update(kw)  # type: ignore[assignment]
    try:
        runpy.run_path(str(REPO / "setup.py"), run_name="__main__")
    finally:
        setuptools.setup = real
    return seen


def test_package_xml_setup_py_and_requirements_agree() -> None:
    """Every runtime dependency is declared for rosdep (package.xml) or pip
    (requirements.txt), and setup.py installs exactly the same set."""
    import xml.etree.ElementTree as ET

    kw = _setup_kwargs()
    exec_depends = {e.text for e in ET.parse(REPO / "package.xml").getroot()
                    .iter("exec_depend")}
    requirements = [ln.strip() for ln in (REPO / "requirements.txt").read_text().splitlines()
                    if ln.strip() and not ln.startswith("#")]
    from_setup_ros = {w.removeprefix("ros-jazzy-").replace("-", "_")
                      for w in kw["extras_require"]["ros"]}
    pip_only = [d for d in kw["install_requires"] if d not in ROSDEP_KEYS]
    from_setup_rosdep = {ROSDEP_KEYS[d] for d in kw["install_requires"] if d in ROSDEP_KEYS}
    assert exec_depends == from_setup_ros | from_setup_rosdep
    assert pip_only == requirements
    # The ROS packages the code imports are all declared.
    for pkg in ("rclpy", "std_msgs", "diagnostic_msgs", "rcl_interfaces"):
        assert pkg in exec_depends, pkg


pytestmark = pytest.mark.slow


def _check_layout(prefix: Path) -> None:
    assert (prefix / "share/ament_index/resource_index/packages/fd_monitor").is_file()
    assert (prefix / "share/fd_monitor/package.xml").is_file()
    for plant in ("three_tank", "pwa_cascade"):
        assert (prefix / f"share/fd_monitor/config/systems/{plant}.yaml").is_file()
    share = prefix / "share/fd_monitor"
    assert (share / "requirements.txt").is_file()
    # Every params file and every bag of the library, in the same layout as the checkout.
    for params in sorted((REPO / "config").glob("*.yaml")):
        assert (share / "config" / params.name).is_file(), params.name
    bags = [p.relative_to(REPO) for p in (REPO / "bags").rglob("*") if p.is_file()]
    assert any(p.suffix == ".mcap" for p in bags)
    for rel in bags:
        assert (share / rel).is_file(), rel
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
        ".venv", ".git", "build", "install", "log", "*.egg-info", "__pycache__"))
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
        ".venv", ".git", "build", "install", "log", "*.egg-info", "__pycache__"))
    ws = tmp_path / "ws"
    out = subprocess.run([str(colcon), "build", "--base-paths", "src"], cwd=ws,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    assert "Finished <<< fd_monitor" in out.stdout
    prefix = ws / "install/fd_monitor"
    _check_layout(prefix)
    site = next(prefix.glob("lib/python3*/site-packages"))
    _run_launchers(prefix, _env(prefix, site), tmp_path)
