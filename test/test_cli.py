"""The command line: --help everywhere, one-line errors with status 2, JSON summaries."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from fd_monitor.commands.cli import SUBCOMMANDS


def fdm(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "fd_monitor", *args], capture_output=True,
                          text=True, timeout=120, cwd=cwd)


@pytest.mark.parametrize("sub", sorted(SUBCOMMANDS))
def test_every_subcommand_has_help(sub: str) -> None:
    out = fdm(sub, "--help")
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f"usage: fd_monitor {sub}")


def test_top_level_help_lists_subcommands() -> None:
    out = fdm("--help")
    assert out.returncode == 0
    for sub in SUBCOMMANDS:
        assert sub in out.stdout


@pytest.mark.parametrize(("args", "match"), [
    (("validate", "/nonexistent/plant.yaml"), "/nonexistent/plant.yaml: file not found"),
    (("validate", "no_such_plant"), "no_such_plant: neither a shipped plant nor a shipped "
                                    "scenario"),
    (("validate", "BADYAML"), "invalid YAML at line 2"),
    (("validate", "BADSCENARIO"), "faults[0].magnitude: expected a finite number"),
    (("validate", "three_tank", "--bogus"), "unrecognized arguments: --bogus"),
    (("no_such_subcommand",), "invalid choice: 'no_such_subcommand'"),
])
def test_bad_input_exits_2_with_one_line(tmp_path: Path, args: tuple[str, ...],
                                         match: str) -> None:
    (tmp_path / "bad.yaml").write_text("a: [b\n")
    (tmp_path / "bad_scenario.yaml").write_text(
        "system: pwa_cascade\nduration: 1.0\nfaults:\n"
        "  - {channel: b1_step, profile: abrupt, time: 0.5, magnitude: .nan}\n")
    args = tuple(str(tmp_path / "bad.yaml") if a == "BADYAML" else
                 str(tmp_path / "bad_scenario.yaml") if a == "BADSCENARIO" else a for a in args)
    out = fdm(*args)
    assert out.returncode == 2
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert "Traceback" not in out.stderr
    assert match in lines[-1]
    if args[0] == "validate" and not args[1].startswith("-"):
        assert len(lines) == 1, out.stderr


def test_validate_json() -> None:
    out = fdm("validate", "three_tank", "--json")
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout)
    assert doc["valid"] is True and doc["name"] == "three_tank"
    assert [m["name"] for m in doc["modes"]] == ["closed_dry", "closed_wet", "open_dry",
                                                 "open_wet"]
    assert len(doc["sha256"]) == 64


def test_validate_table() -> None:
    out = fdm("validate", "pwa_cascade")
    assert out.returncode == 0
    assert "valid plant pwa_cascade" in out.stdout
    assert re.search(r"safe_to_x2_high\s+autonomous\s+safe\s+x2_high", out.stdout)
