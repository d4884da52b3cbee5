"""A merge is a plan, executed in one place (issue 33 item 1): the frozen plan
(hdrcl.core.plan), the one stage order (hdrcl.core.executor), the run split at the commit,
and the batch's set on the same metadata as ``hdrcl merge``."""
from __future__ import annotations

import dataclasses
import os
import re

import numpy as np
import pytest

try:
    from test_batch import make_clean_shoot
    from test_engine import _bracket
except ImportError:  # tests/ made a package
    from tests.test_batch import make_clean_shoot
    from tests.test_engine import _bracket

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

ORDER = ["open_frames", "load", "sample", "respond", "measure", "agreement", "scale", "fuse", "commit"]


@pytest.fixture
def calls(monkeypatch):
    """Every stage function, recording its name when called."""
    from hdrcl.core import fusestage, stages

    seen = []
    for module, name in [(stages, n) for n in ORDER[:7]] + [(fusestage, "fuse"), (fusestage, "commit")]:
        real = getattr(module, name)

        def spy(run, _real=real, _name=name):
            seen.append(_name)
            return _real(run)

        monkeypatch.setattr(module, name, spy)
    return seen


def _plan(paths, times, output, **extras):
    from hdrcl.core.options import MergeOptions
    from hdrcl.core.plan import Extras, plan_merge
    from hdrcl.core.sources import Inputs, response_source

    return plan_merge(Inputs.open(paths, times), MergeOptions(), response_source(None), output,
                      extras=Extras(**extras))


def test_a_file_merge_runs_the_stages_in_one_order_and_leaves_its_plan_as_it_was(tmp_path, calls, cl_device):
    from hdrcl.core.executor import execute
    from hdrcl.core.plan import STREAMED

    paths, times = _bracket(str(tmp_path / "in"), "f", 31, 47)
    plan = _plan(paths, times, str(tmp_path / "out.exr"), keep_radiance=True)
    before = repr(plan)
    res = execute(plan)
    assert calls == ORDER
    assert plan.frames == STREAMED and plan.response.kind == "own"
    assert repr(plan) == before  # the run's findings live on the run state, not on the plan
    with pytest.raises(dataclasses.FrozenInstanceError):
        plan.output = "x.exr"
    assert os.path.isfile(res.output) and res.radiance.shape == (31, 47, 3)
    assert np.isfinite(res.radiance).all()
    assert set(res.seconds) == {"open", "calibrate", "fuse_and_write"} and "fuse" in res.stages


def test_an_array_merge_runs_through_the_same_executor(tmp_path, calls):
    import hdrcl
    from hdrcl.core.bracket import load_bracket

    paths, times = _bracket(str(tmp_path / "in"), "f", 31, 47)
    res = hdrcl.merge_bracket(load_bracket(paths, times))
    assert calls == ORDER  # commit has nothing to move: no file
    assert res.output is None and res.radiance.shape == (31, 47, 3) and set(res.seconds) == {"calibrate", "fuse"}


def test_the_run_splits_at_the_commit(tmp_path, cl_device):
    """start() fuses with the writer open and nothing at the output; finish() commits;
    abort() leaves nothing (a batch writes its preview in between)."""
    from hdrcl.core.executor import abort, finish, start

    paths, times = _bracket(str(tmp_path / "in"), "f", 31, 47)
    out = tmp_path / "out.exr"
    run = start(_plan(paths, times, str(out), save_response=str(tmp_path / "r.json")))
    assert run.writer is not None and run.counts and not out.exists() and not (tmp_path / "r.json").exists()
    res = finish(run)
    assert out.is_file() and (tmp_path / "r.json").is_file() and res.counts == run.counts
    out2 = tmp_path / "out2.exr"
    run = start(_plan(paths, times, str(out2), save_response=str(tmp_path / "r2.json")))
    abort(run)
    assert sorted(os.listdir(tmp_path)) == ["in", "out.exr", "r.json"]  # no temporary file left either


def test_only_the_executor_calls_the_stages():
    """The stage order is written in one module: no other module calls a stage function."""
    stage_call = re.compile(r"\b(stages|fusestage)\.(open_frames|load|sample|respond|measure|agreement|scale|fuse|"
                            r"fuse_to_array|commit)\(")
    found = []
    for dp, _, fs in os.walk(os.path.join(ROOT, "hdrcl")):
        for f in fs:
            if f.endswith(".py") and f != "executor.py":
                text = open(os.path.join(dp, f), encoding="utf-8").read()
                found += [f"{f}: {m.group(0)}" for m in stage_call.finditer(text)]
    assert found == []
    assert not os.path.exists(os.path.join(ROOT, "hdrcl", "core", "engine.py"))
    assert not os.path.exists(os.path.join(ROOT, "hdrcl", "core", "inmemory.py"))


def test_a_batch_set_gets_the_metadata_a_merge_gets(tmp_path, cl_device):
    """One metadata for every plan: a batch's EXR says its colour space and units as
    ``hdrcl merge``'s does (it said neither), besides its digest and exposure reference."""
    from click.testing import CliRunner

    from hdrcl.cli import main
    from hdrcl.io.radiance import read_metadata

    shoot, out = tmp_path / "shoot", tmp_path / "out"
    make_clean_shoot(str(shoot), sets=1)
    r = CliRunner().invoke(main, ["batch", str(shoot), "-o", str(out)])
    assert r.exit_code == 0, r.output
    exr = [f for f in os.listdir(out) if f.endswith(".exr")]
    assert len(exr) == 1
    meta = read_metadata(str(out / exr[0]))
    assert meta.get("colorspace") == "rec709" and meta.get("units") == "relative"
    assert meta.get("inputHash") and meta.get("exposureRef")


def test_leave_one_out_runs_the_plan_without_frame_k(monkeypatch, caplog):
    """The report's leave-one-out is the bracket's plan less one frame, run by the executor
    as a measuring device: no checks of the user's frames, nothing logged, the figure as
    the frame rendered from the others."""
    from hdrcl.core import executor, synthetic
    from hdrcl.core.bracket import Bracket
    from hdrcl.report import leaveoneout as q

    plans = []
    real = executor.prepare
    monkeypatch.setattr(executor, "prepare", lambda plan: plans.append(plan) or real(plan))
    cam = synthetic.Camera(a=1.1, x0=(1.0, 1.15, 0.85))
    rad = synthetic.radiance_field(31, 47, decades=3.0, seed=3) * 60.0
    times = np.array([1 / 1000, 1 / 250, 1 / 60, 1 / 15, 1 / 4])
    frames = synthetic.bracket(rad, times, cam, seed=1)
    frames[2] = np.roll(frames[2], 5, axis=1)  # a moved frame: the user's merge would say so, the measure not
    caplog.set_level("WARNING")
    rows = q.leave_one_out_all(Bracket(frames=frames, times=times, valid=[None] * 5), fit_exposures="off")
    assert [r.index for r in rows] == [1, 2, 3] and len(plans) == 3
    assert all(p.checks is False and len(p.bracket.frames) == 4 for p in plans)
    assert [float(p.inputs.times[1]) for p in plans] == [1 / 60, 1 / 250, 1 / 250]
    assert all(np.isfinite(r.rmse) and r.pixels > 0 for r in rows)
    assert rows[1].rmse > 2 * max(rows[0].rmse, rows[2].rmse)  # the moved frame renders worst
    assert not [r for r in caplog.records if r.levelname == "WARNING"]
