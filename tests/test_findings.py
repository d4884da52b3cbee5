"""Findings reach the result: a check's finding makes a batch set "check" (not "done"), named in
the progress line, the summary and ``report.json``; a rerun that skips the set keeps them."""
from __future__ import annotations

import json
import os

import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.core import stages
from hdrcl.core.findings import CHECK, NOTE, Finding, causes, needs_check

try:
    from test_batch import make_clean_shoot
except ImportError:  # tests/ made a package
    from tests.test_batch import make_clean_shoot


def test_finding_round_trip_and_severity():
    f = Finding("agreement", "a.jpg: frames disagree", file="a.jpg", figure=3.14159)
    assert Finding.from_dict(f.to_dict()) == Finding("agreement", "a.jpg: frames disagree", file="a.jpg",
                                                     figure=3.1416)
    assert needs_check([f]) and not needs_check([Finding("exposure", "fixed", severity=NOTE)])
    assert causes([f, f, Finding("x", "n", severity=NOTE)]) == ["a.jpg: frames disagree"]
    with pytest.raises(ValueError):
        Finding("x", "y", severity="bad")


@pytest.fixture
def flagging(monkeypatch):
    """Every merge finds a 'check' finding naming its first frame (and a 'note')."""
    measure = stages.measure

    def flagged(run):
        measure(run)
        name = os.path.basename(run.inputs.paths[0])
        run.find(Finding("test", f"{name}: planted finding", severity=CHECK, file=name, figure=1.5))
        run.find(Finding("test", f"{name}: planted note", severity=NOTE, file=name))

    monkeypatch.setattr(stages, "measure", flagged)


def test_batch_marks_check_names_it_and_keeps_it_on_rerun(tmp_path, flagging, cl_device):
    shoot, out = tmp_path / "shoot", tmp_path / "out"
    make_clean_shoot(str(shoot), sets=2)
    r = CliRunner().invoke(main, ["batch", str(shoot), "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "2 to check" in r.stdout and "check: set 0" in r.stdout and "planted finding" in r.stdout
    assert "planted finding" in r.stderr  # the progress line and the engine's warning
    rep = json.load(open(out / "report.json"))
    assert rep["summary"]["check"] == 2 and rep["summary"]["done"] == 0
    for s in rep["sets"]:
        assert s["status"] == "check"
        assert [f["severity"] for f in s["findings"]] == ["check", "note"]
        assert any("planted finding" in w for w in s["warnings"])
    # A rerun skips both outputs and keeps what the merging run found.
    r = CliRunner().invoke(main, ["batch", str(shoot), "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "2 up to date" in r.stdout and "check: set 1" in r.stdout
    rep = json.load(open(out / "report.json"))
    assert [s["status"] for s in rep["sets"]] == ["skipped", "skipped"]
    assert all(s["findings"] and s["findings"][0]["message"].endswith("planted finding") for s in rep["sets"])
    assert rep["summary"]["check"] == 2  # still to check, though up to date
    # Without the old report.json, the EXRs say what their merge found.
    os.remove(out / "report.json")
    r = CliRunner().invoke(main, ["batch", str(shoot), "-o", str(out)])
    assert r.exit_code == 0 and "2 to check" in r.stdout, r.output
    rep = json.load(open(out / "report.json"))
    assert rep["summary"]["check"] == 2
    assert all(any(f["message"].endswith("planted finding") for f in s["findings"]) for s in rep["sets"])


def test_merge_prints_findings_once(tmp_path, flagging, cl_device):
    shoot = tmp_path / "shoot"
    make_clean_shoot(str(shoot), sets=1)
    frames = sorted(str(p) for p in shoot.rglob("*.jpg"))
    r = CliRunner().invoke(main, ["merge", *frames, "-o", str(tmp_path / "m.exr")])
    assert r.exit_code == 0, r.output
    assert r.stderr.count("planted finding") == 1
