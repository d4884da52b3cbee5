"""The benchmark scripts depend on each other one way only (issue 33, item 6).

``scripts/bench.py`` starts ``scripts/shoot_bench.py`` (``--shoot``) and
``shoot_bench.py`` imported ``bench`` for its launcher: a circle. The shared helpers now
live in ``scripts/benchlib.py``, which needs no other script. An edge here is an import of
a sibling script or a sibling's file name (``"x.py"``) in the code, i.e. a script started
as a process.
"""
import ast
from pathlib import Path

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def script_edges() -> dict:
    """{script: {sibling scripts it imports or starts}} for every ``scripts/*.py``."""
    names = {p.stem for p in SCRIPTS.glob("*.py")}
    edges = {}
    for p in sorted(SCRIPTS.glob("*.py")):
        tree = ast.parse(p.read_text(encoding="utf-8"))
        doc = ast.get_docstring(tree, clean=False)
        deps = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                deps.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                deps.add(node.module.split(".")[0])
            elif isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value != doc \
                    and node.value.endswith(".py"):
                deps.add(node.value[:-3])
        edges[p.stem] = {d for d in deps & names if d != p.stem}
    return edges


def circles(edges: dict) -> list:
    """Every cycle's nodes found by depth-first search (empty when there is none)."""
    found, state = [], {}

    def visit(n, path):
        state[n] = "open"
        for m in sorted(edges.get(n, ())):
            if state.get(m) == "open":
                found.append(path[path.index(m):] + [m])
            elif m not in state:
                visit(m, path + [m])
        state[n] = "done"

    for n in sorted(edges):
        if n not in state:
            visit(n, [n])
    return found


def test_circles_finds_a_circle():
    assert circles({"bench": {"shoot_bench"}, "shoot_bench": {"bench"}}) == [["bench", "shoot_bench", "bench"]]
    assert circles({"bench": {"benchlib"}, "shoot_bench": {"benchlib"}, "benchlib": set()}) == []


def test_benchmark_scripts_form_no_circle():
    edges = script_edges()
    assert "shoot_bench" in edges["bench"]  # bench.py --shoot starts it
    assert "benchlib" in edges["bench"] and "benchlib" in edges["shoot_bench"]
    assert edges["benchlib"] == set()
    assert circles(edges) == [], circles(edges)


def test_benchmark_parts_import_no_benchmark():
    """bench.py and shoot_bench.py are split along their parts (issue 33, item 6): the
    generated inputs, the in-process workers and the reports are modules that import or
    start no benchmark script, only the shared helpers and each other."""
    edges = script_edges()
    parts = {"benchbrackets", "benchworkers", "benchreport", "benchshoots", "benchshootreport"}
    assert parts <= set(edges), parts - set(edges)
    for name in parts:
        assert edges[name] <= {"benchlib", "benchbrackets"}, (name, edges[name])
    assert {"benchbrackets", "benchworkers", "benchreport"} <= edges["bench"]
    assert {"benchshoots", "benchshootreport"} <= edges["shoot_bench"]
    assert "bench" not in edges["fusion_bench"] and "bench" not in edges["encode_bench"]
    assert "shoot_bench" not in edges["report_bench"]


def test_startup_bench_import_times_by_package():
    """startup_bench.py --imports: the import costs of a command, per module and per package."""
    import os
    import sys

    sys.path.insert(0, str(SCRIPTS))
    try:
        import startup_bench as sb
    finally:
        sys.path.remove(str(SCRIPTS))
    cmd = [sys.executable, "-c", "import json, email.mime.text"]
    rows = sb.import_times(cmd, dict(os.environ))
    names = {name for _, _, _, name in rows}
    assert {"json", "email.mime.text"} <= names, names
    assert all(own >= 0 and cum >= own for own, cum, _, _ in rows)
    pkgs = dict((pkg, us) for us, pkg in sb.import_packages(cmd, dict(os.environ), n=50))
    assert pkgs.get("email", 0) > 0 and "json" in pkgs
