"""The documentation builds, its examples run, and the README stays a front page.

- ``doc/`` builds with Sphinx + MyST with warnings as errors (what rosdoc2 runs for a ROS
  package), into a temporary folder;
- every ``pycon`` block of every page under ``doc/`` runs as a doctest (the blocks of one
  page share one namespace, run from the repository's root, so ``bags/...`` resolves);
- the ``>>>`` examples in the package's docstrings run as doctests;
- README.md is at most 200 lines, and every relative link in it and in ``doc/`` points at a
  file that exists.
"""

from __future__ import annotations

import doctest
import importlib
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "doc"
PAGES = sorted(DOC.rglob("*.md"))
FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


def doctested_modules() -> list[str]:
    """The package's modules whose docstrings hold ``>>>`` examples (found, not listed, so a
    module that gains one is tested without an edit here)."""
    found = []
    for path in sorted((REPO / "fd_monitor").rglob("*.py")):
        if re.search(r"^\s*>>> ", path.read_text(), re.M):
            parts = path.relative_to(REPO).with_suffix("").parts
            found.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return found


@contextmanager
def in_repo() -> Iterator[None]:
    old = Path.cwd()
    os.chdir(REPO)
    try:
        yield
    finally:
        os.chdir(old)


def pycon_blocks(text: str) -> str:
    """The page with every line outside its ``pycon`` fenced blocks blanked (the fences
    too), so an example ends at its block's end and keeps its line number."""
    out, inside = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            inside = line.strip() == "```pycon"
            line = ""
        out.append(line if inside else "")
    return "\n".join(out) + "\n"


def test_sphinx_build_without_warnings(tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q",
                          "-b", "html", "-d", str(tmp_path / "doctrees"), str(DOC),
                          str(tmp_path / "html")],
                         cwd=REPO, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-4000:]
    html = tmp_path / "html"
    for page in PAGES:  # every page is reached from the index (glob toctrees)
        assert (html / page.relative_to(DOC).with_suffix(".html")).is_file(), page


@pytest.mark.parametrize("page", [p for p in PAGES if "```pycon" in p.read_text()],
                         ids=lambda p: str(p.relative_to(DOC)))
def test_page_examples_run(page: Path) -> None:
    text = pycon_blocks(page.read_text())
    test = doctest.DocTestParser().get_doctest(text, {}, str(page.relative_to(REPO)),
                                               str(page), 0)
    assert test.examples, f"{page}: no >>> example in its pycon blocks"
    runner = doctest.DocTestRunner(optionflags=FLAGS)
    with in_repo():
        runner.run(test)
    assert runner.failures == 0, f"{page}: {runner.failures} failing example(s) (see above)"


@pytest.mark.parametrize("name", doctested_modules())
def test_docstring_examples_run(name: str) -> None:
    module = importlib.import_module(name)
    with in_repo():
        result = doctest.testmod(module, optionflags=FLAGS, verbose=False)
    assert result.attempted > 0, f"{name}: no >>> example"
    assert result.failed == 0, f"{name}: {result.failed} failing example(s) (see above)"


def test_key_modules_have_examples() -> None:
    """The public API's modules keep their examples (the package, plants, gain files, the
    method registry, the simulator, bags)."""
    assert {"fd_monitor", "fd_monitor.model.system", "fd_monitor.model.gains",
            "fd_monitor.core.methods", "fd_monitor.core.simulator",
            "fd_monitor.wire.bag_reader", "fd_monitor.wire.bag_writer"
            } <= set(doctested_modules())


def test_readme_is_a_front_page() -> None:
    lines = (REPO / "README.md").read_text().splitlines()
    assert len(lines) <= 200, f"README.md has {len(lines)} lines (at most 200)"
    text = "\n".join(lines)
    # the two commands, exactly (.ci/run runs the second)
    assert "bash scripts/setup.sh && .venv/bin/python -m fd_monitor demo" in text
    assert "bash scripts/test.sh" in text


@pytest.mark.parametrize("page", [REPO / "README.md", *PAGES],
                         ids=lambda p: str(p.relative_to(REPO)))
def test_relative_links_resolve(page: Path) -> None:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    bad = []
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        if not (page.parent / target.split("#")[0]).exists():
            bad.append(target)
    assert not bad, f"{page}: links to missing files: {bad}"


def test_public_api_is_lazy_and_complete() -> None:
    """``import fd_monitor`` loads none of its layers (nor numpy); every name of ``__all__``
    resolves, and is the function of the module the API page names."""
    code = ("import sys, fd_monitor\n"
            "print(sorted(m for m in sys.modules if m.startswith(('numpy', 'fd_monitor.'))))\n"
            "print(all(getattr(fd_monitor, n) is not None for n in fd_monitor.__all__))\n"
            "from fd_monitor.wire.bag_reader import read_bag\n"
            "print(fd_monitor.read_bag is read_bag)\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True,
                         text=True, timeout=120)
    assert out.stdout.split("\n")[:3] == ["[]", "True", "True"], out.stdout + out.stderr


def test_gain_file_fields_page_names_every_key() -> None:
    """doc/reference/gain-file-fields.md names every top-level key and every ``results`` key
    of every shipped gain file (a key a designer starts writing gets documented)."""
    page = (DOC / "reference" / "gain-file-fields.md").read_text()
    missing = set()
    for path in sorted((REPO / "config" / "gains").glob("*.yaml")):
        doc = yaml.safe_load(path.read_text())
        for key in (*doc, *doc["results"]):
            if f"`{key}`" not in page:
                missing.add(f"{path.name}: {key}")
    assert not missing, sorted(missing)
