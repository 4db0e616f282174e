"""The locked environment (issue 23): requirements.lock pins, with hashes, everything setup.py
asks for and everything the code imports; the project's .venv holds exactly the lock.

The lock is made by ``bash scripts/lock.sh`` (``uv pip compile --generate-hashes``) and
installed by ``bash scripts/setup.sh``; requirements.txt, setup.py and package.xml keep loose
ranges for ROS 2 workspaces (test_packaging.py compares those)."""

from __future__ import annotations

import ast
import importlib.metadata as md
import importlib.util
import re
import sys
from pathlib import Path

import pytest
from test_packaging import _setup_kwargs

REPO = Path(__file__).resolve().parent.parent
#: Folders whose Python files are scanned for imports (the package, its tests, benchmarks and
#: scripts all run in the locked venv).
SCANNED = ("fd_monitor", "test", "benchmarks", "scripts")


def _lockcheck():
    spec = importlib.util.spec_from_file_location("lockcheck", REPO / "scripts" / "lockcheck.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


LC = _lockcheck()
LOCK = LC.read_lock()


def imported_modules(files: list[Path]) -> dict[str, str]:
    """Top-level module -> first ``file:line`` importing it (absolute imports, anywhere in
    the file: a function-level import needs its package as much as a module-level one)."""
    out: dict[str, str] = {}
    for f in files:
        tree = ast.parse(f.read_text(encoding="utf-8"), str(f))
        for node in ast.walk(tree):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            for n in names:
                rel = f.relative_to(REPO) if f.is_relative_to(REPO) else f
                out.setdefault(n.split(".")[0], f"{rel}:{node.lineno}")
    return out


def unlocked_imports(files: list[Path], locked: set[str]) -> list[str]:
    """The third-party modules ``files`` import that no locked distribution provides.

    Modules map to distributions through the installed metadata
    (``importlib.metadata.packages_distributions``: ``yaml`` -> PyYAML, ``rclpy`` ->
    ros-rclpy); the standard library and the project's own modules are skipped."""
    local = {p.stem for d in SCANNED for p in (REPO / d).rglob("*.py")} | set(SCANNED) | {
        "setup", "__future__"}
    # the vendored ROS 2 launch packages (third_party/, not on the registry; their sources
    # are in the repository, put on the path by scripts/third_party.py)
    local |= {p.parent.name for p in (REPO / "third_party").glob("*/*/*/__init__.py")}
    dists = md.packages_distributions()
    bad = []
    for mod, where in sorted(imported_modules(files).items()):
        if mod in sys.stdlib_module_names or mod in local:
            continue
        provided = {LC.normalize(d) for d in dists.get(mod, [])}
        if not provided:
            bad.append(f"{where}: imports {mod}, which no installed distribution provides")
        elif not provided & locked:
            bad.append(f"{where}: imports {mod} from {sorted(provided)}, not in "
                       f"requirements.lock (add it to setup.py, then bash scripts/lock.sh)")
    return bad


def test_every_third_party_import_is_locked():
    files = [p for d in SCANNED for p in sorted((REPO / d).rglob("*.py"))]
    assert len(files) > 100
    assert unlocked_imports(files, set(LOCK)) == []


def test_an_unlocked_import_is_named(tmp_path):
    """The check above can fail: a module whose distribution the lock lacks, and one that
    nothing installed provides, are both named with their file and line."""
    f = tmp_path / "m.py"
    f.write_text("import os\nimport numpy as np\n\n\ndef g():\n    from yaml import safe_load\n"
                 "    import no_such_module_anywhere\n")
    bad = unlocked_imports([f], set(LOCK) - {"pyyaml"})
    assert len(bad) == 2, bad
    assert re.search(r"m\.py:6: imports yaml from \['pyyaml'\], not in requirements\.lock",
                     bad[1]), bad
    assert "m.py:7: imports no_such_module_anywhere" in bad[0]


def test_lock_pins_everything_setup_py_asks_for_with_hashes():
    """Every requirement of setup.py (runtime, `ros`, `dev`) is pinned; every pin is exact and
    hashed; the lock says which command made it."""
    kw = _setup_kwargs()
    wanted = [*kw["install_requires"], *kw["extras_require"]["ros"],
              *kw["extras_require"]["dev"]]
    names = {LC.normalize(re.split(r"[<>=!~;\[ ]", w)[0]) for w in wanted}
    missing = sorted(names - set(LOCK))
    assert missing == [], f"not in requirements.lock (run bash scripts/lock.sh): {missing}"
    for tool in ("pip", "uv", "pytest", "hypothesis", "ruff", "mypy", "colcon-core",
                 "ros-jazzy-rclpy", "ros-rclpy", "numpy", "cvxpy", "clarabel"):
        assert tool in LOCK, tool
    for name, pins in LOCK.items():
        for version, _marker, hashes in pins:
            assert re.fullmatch(r"[0-9][0-9A-Za-z.+!-]*", version), (name, version)
            assert hashes and all(re.fullmatch(r"[0-9a-f]{64}", h) for h in hashes), name
    head = (REPO / "requirements.lock").read_text(encoding="utf-8").splitlines()[:3]
    assert any("bash scripts/lock.sh" in ln for ln in head), head
    # the loose files stay loose: a ROS workspace resolves them with its own pins
    req = (REPO / "requirements.txt").read_text().splitlines()
    assert not [ln for ln in req if "==" in ln], "requirements.txt stays unpinned"


@pytest.mark.skipif(Path(sys.prefix).resolve() != (REPO / ".venv").resolve(),
                    reason="runs in the project's .venv (scripts/setup.sh) only")
def test_the_venv_holds_exactly_the_lock():
    problems, _extras = LC.differences()
    assert problems == [], "re-run bash scripts/setup.sh:\n" + "\n".join(problems)
