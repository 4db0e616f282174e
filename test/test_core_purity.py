"""The core is pure: importing fd_monitor.core (every module) leaves rclpy and cvxpy out."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def test_core_imports_neither_rclpy_nor_cvxpy(repo: Path) -> None:
    mods = sorted(p.stem for p in (repo / "fd_monitor/core").glob("*.py") if p.stem != "__init__")
    code = (
        "import importlib, sys\n"
        f"for m in {mods!r}: importlib.import_module('fd_monitor.core.' + m)\n"
        "import fd_monitor.model.system, fd_monitor.model.scenario, fd_monitor.model.gains\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'cvxpy'))\n"
        "print(len(sys.modules)); assert not bad, bad\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=repo, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert mods, "no core modules found"


def test_cvxpy_only_in_designers(repo: Path) -> None:
    offenders = [str(p.relative_to(repo)) for p in (repo / "fd_monitor").rglob("*.py")
                 if "design" not in p.relative_to(repo / "fd_monitor").parts[0]
                 and ("import cvxpy" in p.read_text() or "from cvxpy" in p.read_text())]
    assert offenders == []


def test_rclpy_only_in_nodes_or_lazily(repo: Path) -> None:
    """rclpy is imported at module level only under fd_monitor/nodes/."""
    offenders = []
    for p in (repo / "fd_monitor").rglob("*.py"):
        if p.relative_to(repo / "fd_monitor").parts[0] == "nodes":
            continue
        for line in p.read_text().splitlines():
            if line.startswith(("import rclpy", "from rclpy")):
                offenders.append(str(p.relative_to(repo)))
    assert offenders == []
