"""The "Using it from a ROS 2 workspace" block (doc/tutorial/ros-workspace.md), run literally
in a fresh workspace.

The block (marked ``<!-- workspace:commands``) is run by bash in a temporary ``$HOME`` with
these stand-ins, and nothing else changed:

- ``git clone <this repository> DIR``: a clean copy of the committed tree (``git archive
  HEAD``) extracted into DIR;
- ``rosdep install ...``: skipped; the "ROS 2 installation" is a Python environment
  (``venv`` of the base interpreter) holding symlinks to every package of the project venv
  (the ROS 2 wheels, numpy, ..., what ``requirements.txt`` names) except fd_monitor itself;
- ``python3 -m pip install -r FILE``: checks that every requirement of FILE is installed;
- ``ros2 run fd_monitor EXE ARGS``: ``<ws>/install/fd_monitor/lib/fd_monitor/EXE ARGS``,
  which is what ``ros2 run`` executes (there is no ros2 CLI here).

PYTHONPATH starts empty; before ``source install/setup.bash`` fd_monitor cannot be imported,
after it it comes from ``install/``. The test waits (bounded) for an alarm on ``/fd/alarm``.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from ros_util import REPO, Collector, ros_context, spin_until

pytestmark = [pytest.mark.ros, pytest.mark.slow]

MARK = "<!-- workspace:commands"


def workspace_block() -> list[str]:
    """The command lines of the marked bash block of the tutorial page."""
    text = (REPO / "doc" / "tutorial" / "ros-workspace.md").read_text()
    after = text[text.index(MARK):]
    m = re.search(r"```bash\n(.*?)```", after, re.S)
    assert m is not None, "no ```bash block after the workspace:commands mark"
    return [ln for ln in m.group(1).splitlines() if ln.strip()]


def ros_env(tmp_path: Path) -> Path:
    """A venv with the project venv's packages but not fd_monitor (the "ROS 2 install")."""
    venv = Path(sys.prefix)
    env = tmp_path / "rosenv"
    base = getattr(sys, "_base_executable", sys.executable)
    subprocess.run([base, "-m", "venv", "--without-pip", str(env)], check=True)
    py = f"python{sys.version_info.major}.{sys.version_info.minor}"
    site, own_site = env / "lib" / py / "site-packages", venv / "lib" / py / "site-packages"
    for e in own_site.iterdir():
        if e.name.startswith(("fd_monitor", "__editable__")) or e.name == "__pycache__":
            continue
        (site / e.name).symlink_to(e)
    # The ROS 2 wheels' shared libraries and ament index live in <prefix>/lib and /share.
    for sub in ("lib", "share"):
        (env / sub).mkdir(exist_ok=True)
        for e in (venv / sub).iterdir():
            if not (env / sub / e.name).exists():
                (env / sub / e.name).symlink_to(e)
    colcon = env / "bin" / "colcon"
    colcon.write_text(f"#!{env / 'bin' / 'python'}\nimport sys\n"
                      "from colcon_core.command import main\nsys.exit(main())\n")
    colcon.chmod(0o755)
    return env


def script(lines: list[str], repo_head: str, ws_install: Path) -> str:
    """The page's lines with the stand-ins of the module docstring."""
    out = ["set -e"]
    seen = set()
    for ln in lines:
        if "git clone" in ln:
            ln = re.sub(r"git clone <[^>]*> (\S+)",
                        rf"git -C {REPO} archive {repo_head} --prefix=\1/ | tar -x", ln)
            seen.add("clone")
        elif ln.startswith("rosdep install"):
            ln = ": rosdep stands in: the ROS 2 environment is given"
            seen.add("rosdep")
        elif ln.startswith("python3 -m pip install -r"):
            req = ln.split()[5]
            ln = (f"python3 -c \"import importlib.metadata as m, sys; "
                  f"[m.version(r.strip()) for r in open('{req}') "
                  f"if r.strip() and not r.startswith('#')]\"")
            seen.add("pip")
        elif "ros2 run fd_monitor" in ln:
            ln = re.sub(r"ros2 run fd_monitor (\w+)",
                        rf"{ws_install}/fd_monitor/lib/fd_monitor/\1", ln)
            seen.add("run")
        elif ln.startswith("source install/setup.bash"):
            # The imported fd_monitor: none before, install/'s after.
            ln = ("! python3 -c 'import fd_monitor' 2>/dev/null\n" + ln +
                  "\npython3 -c 'import fd_monitor; print(\"fd_monitor from\", "
                  "fd_monitor.__file__)'")
            seen.add("source")
        out.append(ln)
    assert seen == {"clone", "rosdep", "pip", "run", "source"}, seen
    return "\n".join(out) + "\n"


def test_workspace_commands_work_literally(tmp_path: Path) -> None:
    lines = workspace_block()
    assert any(ln.startswith("colcon build") for ln in lines)
    exes = [m.group(1) for ln in lines for m in re.finditer(r"ros2 run fd_monitor (\w+)", ln)]
    assert exes, "the block runs no fd_monitor executable"
    home = tmp_path / "home"
    home.mkdir()
    ws = home / "ws"
    env_dir = ros_env(tmp_path)
    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], check=True,
                          capture_output=True, text=True).stdout.strip()
    text = script(lines, head, ws / "install")
    env = {"HOME": str(home), "PATH": f"{env_dir / 'bin'}{os.pathsep}/usr/bin{os.pathsep}/bin",
           "LANG": "C.UTF-8", "PYTHONUNBUFFERED": "1"}
    for var in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "RMW_IMPLEMENTATION",
                "ROS_LOG_DIR", "FASTDDS_BUILTIN_TRANSPORTS"):
        if var in os.environ:
            env[var] = os.environ[var]
    log = tmp_path / "session.log"
    with ros_context() as ctx, open(log, "w") as out:
        from rclpy.executors import SingleThreadedExecutor

        col = Collector(ctx, ["/fd/alarm"], diagnostics=True)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(col.node)
        proc = subprocess.Popen(["bash", "-c", text], cwd=home, env=env, stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)

        def alarm_on_h1() -> bool:
            return any(d.values[d.labels.index("h1")] == 1.0
                       for d in col.decoded("/fd/alarm"))

        class _P:  # spin_until stops early when the session fails
            p = proc

        try:
            ok = spin_until(ex, alarm_on_h1, 150.0, [_P()])  # type: ignore[list-item]
        finally:
            for sig in (signal.SIGINT, signal.SIGKILL):
                if proc.poll() is None:
                    os.killpg(proc.pid, sig)
                    try:
                        proc.wait(15)
                    except subprocess.TimeoutExpired:
                        pass
            # Children that outlived bash (the background plant_sim).
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            ex.shutdown()
            col.node.destroy_node()
    session = log.read_text()
    assert ok, f"no alarm on h1 (exit {proc.returncode}):\n{session[-4000:]}"
    assert f"fd_monitor from {ws}/install/fd_monitor/lib/" in session, session[-2000:]
    assert "Traceback" not in session, session[-4000:]
    assert (ws / "install/fd_monitor/share/fd_monitor/bags/library.yaml").is_file()
    for exe in exes:
        # The executables ran with the "ROS 2 install"'s Python, not the project venv's.
        first = (ws / "install/fd_monitor/lib/fd_monitor" / exe).read_text().splitlines()[0]
        assert first == f"#!{env_dir / 'bin' / 'python'}", first
