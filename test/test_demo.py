"""The demo end to end: five processes over DDS, a bag, the summary (--json parsed)."""

from __future__ import annotations

import json

import pytest
import yaml
from ros_util import REPO, run_cli

pytestmark = pytest.mark.ros


def check(doc, onset):
    assert doc["fault"] == {"channel": "bias_h1", "output": "h1", "time": onset,
                            "magnitude": 0.01}
    assert doc["detected_at"] is not None and doc["detected_at"] >= onset
    assert doc["alarm_channels"] == ["h1"]
    assert doc["isolated"] == ["h1"]
    assert abs(doc["bias_estimate"]["h1"] - 0.01) < 0.002
    assert doc["true_bias"]["h1"] == 0.01
    assert doc["lost"] == 0
    assert set(doc["samples"]) >= {"/plant/y", "/fd/alarm", "/fd/bias_estimate"}


def logs(folder, lines=8):
    """The last lines of every child's log (what a failed run in CI needs to be understood)."""
    return "".join(f"\n== {p.name}:\n" + "\n".join(p.read_text(errors="replace")
                                                   .splitlines()[-lines:])
                   for p in sorted(folder.glob("*.log")))


def test_demo_json_on_a_short_scenario(tmp_path):
    """The demo's scenario shortened to 80 s (bias at 40 s) to keep the suite fast."""
    doc = yaml.safe_load((REPO / "config/scenarios/three_tank_bias_h1.yaml").read_text())
    doc["duration"], doc["faults"][0]["time"] = 80.0, 40.0
    sc = tmp_path / "short.yaml"
    sc.write_text(yaml.safe_dump(doc))
    # --timeout: the demo's own wait, for a loaded machine (CI, a second test worker)
    r = run_cli(["demo", "--json", "--scenario", str(sc), "--output", str(tmp_path / "out"),
                 "--timeout", "170"], timeout=180)
    assert r.returncode == 0, r.stderr[-3000:] + logs(tmp_path / "out" / "logs")
    out = json.loads(r.stdout)
    check(out, 40.0)
    assert out["samples"]["/plant/y"] == 800
    assert (tmp_path / "out" / "bag" / "metadata.yaml").is_file()


@pytest.mark.slow
def test_demo_default_json(tmp_path):
    r = run_cli(["demo", "--json", "--output", str(tmp_path / "out"), "--timeout", "280"],
                timeout=300)
    assert r.returncode == 0, r.stderr[-3000:] + logs(tmp_path / "out" / "logs")
    check(json.loads(r.stdout), 200.0)


def test_demo_bad_arguments_are_one_line(tmp_path):
    for args, match in [(["demo", "--scenario", "nope"], "unknown scenario"),
                        (["demo", "--rate-factor", "-1"],
                         "argument --rate-factor: expected a finite number >= 0")]:
        r = run_cli(args, timeout=60)
        assert r.returncode == 2
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and match in lines[0], r.stderr


def test_demo_children_die_with_it(tmp_path):
    """A demo killed outright (SIGKILL, a CI timeout) leaves no node publishing into the
    domain: its children get SIGTERM from the kernel (PR_SET_PDEATHSIG)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from ros_util import fd_env

    p = subprocess.Popen([sys.executable, "-m", "fd_monitor", "demo", "--output",
                          str(tmp_path / "out")], cwd=REPO, env=fd_env(),
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def children() -> list[int]:
        out = subprocess.run(["pgrep", "-P", str(p.pid)], capture_output=True, text=True)
        return [int(x) for x in out.stdout.split()]

    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(children()) < 4 and p.poll() is None:
            time.sleep(0.2)  # polling the process table, bounded
        kids = children()
        assert len(kids) >= 4, kids
        print("demo children:", kids)
    finally:
        p.kill()
        p.wait(30)
    deadline = time.monotonic() + 30
    alive = kids
    while alive and time.monotonic() < deadline:
        alive = [k for k in kids if os.path.exists(f"/proc/{k}")
                 and open(f"/proc/{k}/stat").read().split()[2] != "Z"]
        time.sleep(0.2)  # polling the process table, bounded
    for k in alive:
        os.kill(k, signal.SIGKILL)
    assert not alive, f"demo children still running after the demo was killed: {alive}"
