"""The package's layers run one way: each imports only the layers below it, and nothing cycles.

The layer order is written once, here (doc/development.md draws it). Every import of a
``fd_monitor`` module counts, at module level or inside a function, because a function-level
import is still a dependency the reader has to know about.
"""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "fd_monitor"

#: Bottom to top. A module may import its own layer and the ones listed before it.
LAYERS: tuple[str, ...] = ("model", "core", "wire", "analysis", "design", "nodes", "commands")


def module_name(path: Path) -> str:
    parts = path.relative_to(PKG.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer_of(module: str) -> int:
    parts = module.split(".")
    if len(parts) == 1 or parts[1] == "__main__":
        return len(LAYERS) - 1  # the package itself and `python -m fd_monitor`: the top
    assert parts[1] in LAYERS, f"{module}: not in any layer {LAYERS}"
    return LAYERS.index(parts[1])


def resolve(name: str) -> str:
    """The module ``name`` refers to: ``fd_monitor.core.qb.QBModel`` -> ``fd_monitor.core.qb``."""
    while name.count("."):
        p = PKG.parent / name.replace(".", "/")
        if p.with_suffix(".py").is_file() or (p / "__init__.py").is_file():
            return name
        name = name.rsplit(".", 1)[0]
    return name


def imports() -> dict[str, dict[str, int]]:
    """module -> {imported fd_monitor module: line of the first import}."""
    graph: dict[str, dict[str, int]] = {}
    for path in sorted(PKG.rglob("*.py")):
        mod = module_name(path)
        out = graph.setdefault(mod, {})
        pkg = mod if path.name == "__init__.py" else mod.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                                    + ([base] if base else []))
                names = [f"{base}.{a.name}" for a in node.names]
            for n in names:
                if n == "fd_monitor" or n.startswith("fd_monitor."):
                    target = resolve(n)
                    if target != mod:
                        out.setdefault(target, node.lineno)
    return graph


def test_every_import_points_down_or_sideways() -> None:
    up = [f"{m.replace('.', '/')}.py:{line}: {LAYERS[layer_of(m)]} imports {t} "
          f"({LAYERS[layer_of(t)]})"
          for m, deps in imports().items() for t, line in deps.items()
          if layer_of(t) > layer_of(m)]
    assert not up, "imports from a higher layer:\n" + "\n".join(up)


def test_no_import_cycles() -> None:
    graph = imports()
    cycles: list[list[str]] = []
    state: dict[str, int] = {}  # 1 on the stack, 2 done

    def visit(m: str, stack: list[str]) -> None:
        state[m] = 1
        for t in graph.get(m, {}):
            if state.get(t) == 1:
                cycles.append([*stack[stack.index(t):], t])
            elif t not in state:
                visit(t, [*stack, t])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_the_checker_sees_a_violation() -> None:
    """The rules can fail: core importing a node, and a two-module cycle, are caught."""
    assert layer_of("fd_monitor.nodes.monitor") > layer_of("fd_monitor.core.monitor")
    assert resolve("fd_monitor.core.runtime.RUNTIMES") == "fd_monitor.core.runtime"
    assert "fd_monitor.model.errors" in imports()["fd_monitor.core.runtime"]


def test_every_module_imports() -> None:
    """Every module of the package imports (an import of a name that moved fails here, not in
    a user's first ``design`` or node start). In a child process: a clean interpreter."""
    import subprocess
    import sys

    mods = sorted(m for m in imports() if not m.endswith("__main__"))  # __main__ runs
    code = ("import importlib, sys\nbad = []\n"
            f"for m in {mods!r}:\n"
            "    try:\n        importlib.import_module(m)\n"
            "    except Exception as e:\n        bad.append(f'{m}: {type(e).__name__}: {e}')\n"
            "print('\\n'.join(bad)); sys.exit(1 if bad else 0)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr


def test_long_modules_say_why() -> None:
    """Issue 22 item 7: a module of the package above 500 lines says why in its docstring
    ("Why one module of ~N lines: ...")."""
    big = {}
    for path in sorted(PKG.rglob("*.py")):
        text = path.read_text()
        n = len(text.splitlines())
        if n > 500 and "Why one module of" not in (ast.get_docstring(ast.parse(text)) or ""):
            big[str(path.relative_to(PKG))] = n
    assert not big, f"modules above 500 lines without a reason in their docstring: {big}"


def test_nodes_one_job_per_file() -> None:
    """nodes/ (issue 22 item 2): the chain nodes hold their reports (composition), each node
    class has one base; one composer of the in-process chain (monitor.py)."""
    mixed, composers = {}, []
    for path in sorted((PKG / "nodes").glob("*.py")):
        text = path.read_text()
        tree = ast.parse(text, str(path))
        for node in tree.body:
            if isinstance(node, ast.ClassDef) and len(node.bases) > 1:
                mixed[f"{path.name}:{node.name}"] = [ast.unparse(b) for b in node.bases]
            if isinstance(node, ast.FunctionDef) and node.name in ("make_chain", "make_nodes"):
                composers.append(f"{path.stem}.{node.name}")
    assert not mixed, f"classes with several bases (mixins?): {mixed}"
    assert composers == ["monitor.make_chain", "monitor.make_nodes"], composers
