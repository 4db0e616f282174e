"""Linters are part of the suite: ruff on everything, mypy on the whole package (mypy.ini:
every function typed, ``disallow_untyped_defs``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def test_ruff_clean(repo: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "ruff", "check", "."], cwd=repo,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]


def test_mypy_clean(repo: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "mypy", "--config-file", "mypy.ini"],
                         cwd=repo, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]
