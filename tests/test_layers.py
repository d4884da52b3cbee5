"""The package's layers: every import points down, no module imports in a circle.

The order is written down once, here (top first); ``docs/development.md`` ("Layout") draws it.
A module may import modules of its own layer or of layers below it. Lazy imports
inside functions count too: they are imports all the same.
"""
import ast
import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent / "hdrcl"

#: Top to bottom. ``hdrcl`` itself (``__init__``, ``__main__``) sits above everything.
LAYERS = [
    ("cli", ["hdrcl.cli"]),
    ("api", ["hdrcl.api"]),
    ("shoot", ["hdrcl.shoot"]),
    ("report", ["hdrcl.report"]),
    ("core", ["hdrcl.core"]),
    ("cl", ["hdrcl.cl"]),
    ("io", ["hdrcl.io"]),
    ("base", ["hdrcl.errors", "hdrcl.version"]),
]
#: Modules of the package root that are entry points, above every layer.
TOP = {"hdrcl", "hdrcl.__main__"}


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules():
    return {_module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def _layer(mod: str):
    if mod in TOP:
        return -1
    for i, (_, prefixes) in enumerate(LAYERS):
        if any(mod == p or mod.startswith(p + ".") for p in prefixes):
            return i
    return None


def _imports(mod: str, path: Path, known) -> set:
    tree = ast.parse(path.read_text())
    pkg = mod if path.name == "__init__.py" else mod.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")
                base = base[: len(base) - (node.level - 1)]
                stem = ".".join(base + ([node.module] if node.module else []))
            else:
                stem = node.module or ""
            names = [stem] + [f"{stem}.{a.name}" for a in node.names]
        else:
            continue
        for n in names:
            # the longest known module that the name denotes
            while n and n not in known:
                n = n.rpartition(".")[0]
            if n and n != mod and n.startswith("hdrcl"):
                out.add(n)
    return out


def _graph():
    mods = _modules()
    return {m: _imports(m, p, mods) for m, p in mods.items()}


def test_every_module_has_a_layer():
    missing = [m for m in _modules() if _layer(m) is None]
    assert not missing, f"modules outside every layer of LAYERS: {missing}"


def test_imports_point_down():
    up = []
    for mod, deps in _graph().items():
        lm = _layer(mod)
        for d in deps:
            ld = _layer(d)
            if ld is None:
                continue
            if ld < lm:
                up.append(f"{mod} ({LAYERS[lm][0]}) imports {d} ({LAYERS[ld][0]})")
    assert not up, "imports pointing up a layer:\n" + "\n".join(sorted(up))


def test_no_import_circle():
    graph = _graph()
    state, stack, circles = {}, [], []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                circles.append(stack[stack.index(d):] + [d])
            elif d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not circles, "import circles:\n" + "\n".join(" -> ".join(c) for c in circles)


@pytest.mark.parametrize("limit", [600])
def test_no_long_module(limit):
    long = {m: n for m, p in _modules().items() if (n := len(p.read_text().splitlines())) > limit}
    assert not long, f"modules over {limit} lines: {long}"


def test_few_modules_at_the_root():
    root = [p.name for p in ROOT.glob("*.py")]
    assert len(root) <= 8, root


def test_layer_check_catches_an_upward_import(tmp_path, monkeypatch):
    """The checker itself: a core module importing the shoot layer is reported."""
    mods = {"hdrcl.core.x": tmp_path / "x.py", "hdrcl.shoot.y": tmp_path / "y.py"}
    mods["hdrcl.core.x"].write_text("def f():\n    from hdrcl.shoot.y import z\n")
    deps = _imports("hdrcl.core.x", mods["hdrcl.core.x"], mods)
    assert deps == {"hdrcl.shoot.y"}
    assert _layer("hdrcl.shoot.y") < _layer("hdrcl.core.x")


def test_package_docstrings():
    for pkg in ("cli", "shoot", "report", "core", "cl", "io"):
        doc = ast.get_docstring(ast.parse((ROOT / pkg / "__init__.py").read_text()))
        assert doc and "TODO" not in doc, pkg
    assert os.path.isfile(ROOT / "api.py")
