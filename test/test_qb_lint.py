"""ruff and mypy on the QB / evaluation files (the style gate of CONVENTIONS.md)."""

from __future__ import annotations

import subprocess

FILES = ["fd_monitor/core/qb.py", "fd_monitor/core/kalman.py", "fd_monitor/core/batch.py",
         "fd_monitor/design/qb.py", "fd_monitor/evaluate.py", "fd_monitor/commands/evaluate.py",
         "test/test_qb_design.py", "test/test_qb_runtime.py", "test/test_evaluate.py",
         "test/test_qb_lint.py", "benchmarks/bench_qb_design.py"]
CORE = ["fd_monitor/core/qb.py", "fd_monitor/core/kalman.py", "fd_monitor/core/batch.py"]


def test_ruff(python, repo):
    out = subprocess.run([python, "-m", "ruff", "check", *FILES], capture_output=True,
                         text=True, cwd=repo)
    assert out.returncode == 0, out.stdout + out.stderr


def test_mypy_core(python, repo):
    # Errors in modules owned elsewhere (imported, e.g. system.py) are not this test's concern.
    out = subprocess.run([python, "-m", "mypy", "--follow-imports=silent", *CORE],
                         capture_output=True, text=True, cwd=repo)
    assert out.returncode == 0, out.stdout + out.stderr
