"""Each option declared once (issue 33 item 2): the merge options are the fields of
``MergeOptions`` (help, spelling, kind and range from the option table), ``merge`` and
``batch`` take every one of them with the same help, nothing lists the fields by hand,
no click flag is declared twice, the options are checked once per merge, and the command
line's imports are plain (the layer test sees them)."""
import ast
import collections
import dataclasses
import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.core.options import MergeOptions

ROOT = Path(__file__).resolve().parent.parent / "hdrcl"
FIELDS = [f.name for f in dataclasses.fields(MergeOptions)]


def _params(command: str) -> dict:
    """The click options of ``command`` by parameter name."""
    ctx = main.make_context("hdrcl", [command, "--help"], resilient_parsing=True)
    cmd = main.get_command(ctx, command)
    return {p.name: p for p in cmd.params}


def _help(command: str) -> str:
    res = CliRunner().invoke(main, [command, "--help"], terminal_width=200)
    assert res.exit_code == 0, res.output
    return res.output


@pytest.mark.parametrize("name", FIELDS)
def test_every_merge_option_is_in_merge_and_batch_with_one_help(name):
    merge, batch = _params("merge"), _params("batch")
    flag = "--" + name.replace("_", "-")
    assert name in merge and name in batch, f"{flag}: not an option of both merge and batch"
    assert merge[name].opts == batch[name].opts == [flag]
    assert merge[name].help and merge[name].help == batch[name].help
    field = next(f for f in dataclasses.fields(MergeOptions) if f.name == name)
    assert merge[name].default == batch[name].default == field.default
    for command in ("merge", "batch"):
        assert flag in _help(command)


def test_calibrate_takes_the_solve_options_from_the_same_declaration():
    cal, merge = _params("calibrate"), _params("merge")
    solve = [f.name for f in dataclasses.fields(MergeOptions) if f.metadata["solve"]]
    assert set(solve) == {"weight", "ignore_color", "samples", "smoothness", "seed", "fit_exposures",
                          "exposure_tolerance"}
    assert all(cal[n].help == merge[n].help for n in solve)
    assert not set(FIELDS) - set(solve) & set(cal)


# ------------------------------------------------- option_lists: hand lists, flags twice
def _py(folder):
    return sorted(Path(folder).rglob("*.py"))


def _names_in(node, fields):
    got = set()
    for n in ast.walk(node):
        if isinstance(n, ast.keyword) and n.arg in fields:
            got.add(n.arg)
        elif isinstance(n, ast.Constant) and isinstance(n.value, str) and n.value in fields:
            got.add(n.value)
        elif isinstance(n, ast.arg) and n.arg in fields:
            got.add(n.arg)
    return got


def hand_lists(root: Path, least: int = 8) -> list:
    """Functions outside ``MergeOptions`` naming at least ``least`` of its fields (as
    keywords, string constants or parameters): a hand-kept list of the options (the rule of
    ../shared/tools/option_lists.py)."""
    fields = set(FIELDS)
    home = root / "core" / "options.py"
    cls = next(n for n in ast.walk(ast.parse(home.read_text())) if isinstance(n, ast.ClassDef)
               and n.name == "MergeOptions")
    out = []
    for path in _py(root):
        for n in ast.walk(ast.parse(path.read_text())):
            if not isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            if path == home and cls.lineno <= n.lineno <= cls.end_lineno:
                continue
            inner = [c for c in ast.walk(n) if c is not n and isinstance(c, (ast.FunctionDef, ast.AsyncFunctionDef))]
            got = _names_in(n, fields) - set().union(set(), *[_names_in(c, fields) for c in inner])
            if len(got) >= least:
                out.append(f"{path.relative_to(root.parent)}:{n.lineno} {n.name} ({len(got)})")
    return out


def flags_declared_twice(root: Path) -> list:
    import re

    flags = collections.Counter()
    for path in _py(root / "cli"):
        for m in re.finditer(r'click\.option\(\s*"(--[a-z0-9-]+)"', path.read_text()):
            flags[m.group(1)] += 1
    return sorted(f for f, c in flags.items() if c > 1)


def test_no_hand_list_of_the_options_and_no_flag_declared_twice():
    # core/engine.py's fusion spec is the engine's own (issue 33 item 1 replaces it)
    assert [p for p in hand_lists(ROOT) if not p.startswith("hdrcl/core/engine.py")] == []
    assert flags_declared_twice(ROOT) == []


def test_the_checks_catch_a_hand_list_and_a_second_flag(tmp_path):
    pkg = tmp_path / "hdrcl"
    (pkg / "core").mkdir(parents=True)
    (pkg / "cli").mkdir()
    (pkg / "core" / "options.py").write_text((ROOT / "core" / "options.py").read_text())
    (pkg / "core" / "x.py").write_text("def f(o):\n    return dict(" + ", ".join(f"{n}=o.{n}" for n in FIELDS[:9])
                                       + ")\n")
    (pkg / "cli" / "a.py").write_text('import click\nA = click.option("--json", is_flag=True)\n')
    (pkg / "cli" / "b.py").write_text('import click\nB = click.option(\n    "--json", is_flag=True)\n')
    assert hand_lists(pkg) == ["hdrcl/core/x.py:1 f (9)"]
    assert flags_declared_twice(pkg) == ["--json"]


TOOL = ROOT.parent.parent.parent / "shared" / "tools" / "option_lists.py"


@pytest.mark.skipif(not TOOL.exists(), reason="../shared/tools/option_lists.py is not beside this checkout")
def test_option_lists_tool_agrees():
    out = subprocess.run([sys.executable, str(TOOL), str(ROOT.parent)], capture_output=True, text=True, timeout=120)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["flags_declared_twice"] == 0
    assert [p for p in got["places"] if not p.startswith("hdrcl/core/engine.py")] == []


# ------------------------------------------------------------ one object, checked once
def test_batch_options_hold_one_merge_options():
    from hdrcl.shoot.batch.jobs import BatchOptions

    names = {f.name for f in dataclasses.fields(BatchOptions)}
    assert "merge" in names and not names & set(FIELDS)  # contained, not copied
    b = BatchOptions(dtype="float", preview=False, align=True, align_model="shift")
    assert b.merge == MergeOptions(dtype="float", align=True, align_model="shift")
    assert (b.dtype, b.align_model, b.preview) == ("float", "shift", False)  # read as its own
    assert pickle.loads(pickle.dumps(b)) == b  # workers and Dask receive it
    with pytest.raises(TypeError):
        BatchOptions(no_such_option=1)
    with pytest.raises(AttributeError):
        b.no_such_option  # noqa: B018
    # the digest: the declared identity of each option, unchanged for plain merges
    assert BatchOptions().output_params() == {"weight": "gaussian", "ignore_color": None, "dtype": "auto",
                                              "compression": "piz"}
    assert BatchOptions(colorspace="ACEScg", align_model="shift").output_params()["colorspace"] == "acescg"
    assert "align_model" not in BatchOptions(align_model="shift").output_params()  # only with --align


def _bracket(tmp_path, write_frames, scene):
    return write_frames(tmp_path / "frames", scene["frames"][1:6:2]), scene["times"][1:6:2]


def test_a_merge_checks_its_options_once(tmp_path, monkeypatch, write_frames, scene, cl_device):
    import hdrcl.core.params as params

    calls = []
    check_options = params.check_options

    def counting(*args, **kw):
        if "ghost_reference" in kw:  # the merge options (not the solve's or the deliverables')
            calls.append(kw)
        return check_options(*args, **kw)

    monkeypatch.setattr(params, "check_options", counting)
    paths, times = _bracket(tmp_path, write_frames, scene)
    res = CliRunner().invoke(main, ["merge", *paths, "-o", str(tmp_path / "m.exr"), "--times",
                                    ",".join(repr(float(t)) for t in times), "--deghost", "--ghost-reference", "1"])
    assert res.exit_code == 0, res.output
    assert len(calls) == 1
    res = CliRunner().invoke(main, ["merge", *paths, "-o", str(tmp_path / "n.exr"), "--deghost",
                                    "--ghost-reference", "3"])
    assert res.exit_code == 2 and "--ghost-reference: frame 3 does not exist (0..2)" in res.output


def test_merge_bracket_takes_the_options_object_or_its_fields(scene):
    from hdrcl.core.bracket import Bracket
    from hdrcl.core.merge import merge_bracket
    from hdrcl.errors import UsageError

    frames = list(scene["frames"][1:6:2])
    br = Bracket(frames=frames, times=np.asarray(scene["times"][1:6:2]), valid=[None] * 3)
    a = merge_bracket(br, options=MergeOptions(weight="hat", seed=3), device=None)
    b = merge_bracket(br, weight="hat", seed=3)
    np.testing.assert_array_equal(a.radiance, b.radiance)
    with pytest.raises(UsageError, match="frame 5 does not exist"):
        merge_bracket(br, deghost=True, ghost_reference=5)
    with pytest.raises(TypeError):
        merge_bracket(br, no_such_option=1)


def test_batch_takes_the_merge_options_it_lacked(tmp_path, cl_device):
    """--absolute (and --reference-patch, the ghost tuning) reach batch from merge's own
    declaration: a shoot in approximate cd/m^2, recorded in each output's digest."""
    shoot, out = tmp_path / "shoot", tmp_path / "out"
    assert CliRunner().invoke(main, ["sample-shoot", str(shoot), "--size", "64x48"]).exit_code == 0
    res = CliRunner().invoke(main, ["batch", str(shoot), "-o", str(out), "--absolute", "--no-preview"])
    assert res.exit_code == 0, res.output
    rep = json.loads((out / "report.json").read_text())
    assert [s["status"] for s in rep["sets"]] == ["done"] * 3
    import OpenImageIO as oiio

    spec = oiio.ImageSpec()
    inp = oiio.ImageInput.open(rep["sets"][0]["output"])
    spec, _ = inp.spec(), inp.close()
    assert "cd/m2" in str(spec.getattribute("hdrcl:units"))


# ------------------------------------------------------------------ plain imports, start-up
def test_the_cli_support_module_imports_plainly():
    src = (ROOT / "api" / "support.py").read_text()
    assert "importlib" not in src and "__getattr__" not in src
    sys.path.insert(0, str(ROOT.parent / "tests"))
    from test_layers import _graph

    graph = _graph()
    assert {"hdrcl.core.merge", "hdrcl.core.calibrate", "hdrcl.io.atomic"} <= graph["hdrcl.api.support"]
    assert "hdrcl.report.merge_report" in graph["hdrcl.api.reports"]


def test_help_loads_neither_the_engine_nor_the_support_module():
    code = ("import sys\nfrom click.testing import CliRunner\nfrom hdrcl.cli import main\n"
            "r = CliRunner().invoke(main, ['merge', '--help'])\nassert r.exit_code == 0, r.output\n"
            "print(sorted(m for m in ('hdrcl.api.support', 'hdrcl.core.merge', 'hdrcl.io.frames') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "PYTHONPATH": str(ROOT.parent)})
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[]"
