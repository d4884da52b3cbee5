"""``hdrcl scan``: the table, the JSON contract, manifests written and fed back, overrides."""
from __future__ import annotations

import json
import os
import shutil

import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.shoot.batch.manifest import load_manifest

try:
    import shootgen
except ImportError:  # tests/ made a package
    from tests import shootgen


@pytest.fixture(scope="module")
def shoot(tmp_path_factory):
    folder = tmp_path_factory.mktemp("shoot")
    truth = shootgen.make_shoot(folder)
    return str(folder), truth


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def names(files):
    return [os.path.basename(f) for f in files]


def test_json_groups_the_shoot_exactly(shoot):
    folder, truth = shoot
    res = run("scan", folder, "--json")
    assert res.exit_code == 0, res.output
    d = json.loads(res.stdout)
    assert [names(s["files"]) for s in d["sets"]] == truth["sets"]
    assert [s["index"] for s in d["sets"]] == list(range(len(truth["sets"])))
    for s, times in zip(d["sets"], truth["exposures"]):
        assert s["exposures"] == pytest.approx(times, rel=2e-3)
        assert isinstance(s["reason"], str) and s["reason"]
    unmerged = {tuple(names(u["files"])): u["reason"] for u in d["unmerged"]}
    assert unmerged[("IMG_0017.jpg",)] == "single frame"
    assert unmerged[("IMG_0016.jpg",)].startswith("corrupt")
    assert len(unmerged) == 2  # notes.txt is not an image and not listed


def test_table_is_readable(shoot):
    folder, truth = shoot
    res = run("scan", folder)
    assert res.exit_code == 0
    out = res.stdout
    assert out.splitlines()[0].split()[:3] == ["set", "frames", "first"]
    for s in truth["sets"]:
        assert s[0] in out
    assert "IMG_0016.jpg: corrupt" in out and "IMG_0017.jpg: single frame" in out
    assert f"{len(truth['sets'])} set(s)" in out


def test_manifest_written_edited_and_fed_back(shoot, tmp_path):
    folder, truth = shoot
    man = tmp_path / "manifest.json"
    res = run("scan", folder, "-o", man)
    assert res.exit_code == 0 and "wrote" in res.stdout
    d = json.loads(man.read_text())
    assert not os.path.isabs(d["sets"][0]["files"][0])  # relative: the folder can move
    assert [names(s.files) for s in load_manifest(man).sets] == truth["sets"]

    # By hand: split the 7-frame set into 3 + 4 frames, drop the exposures of another.
    seven = next(i for i, s in enumerate(d["sets"]) if len(s["files"]) == 7)
    s7 = d["sets"][seven]
    first = dict(s7, files=s7["files"][:3], exposures=s7["exposures"][:3])
    second = {"files": s7["files"][3:], "reason": "split by hand"}
    d["sets"][seven:seven + 1] = [first, second]
    del d["sets"][0]["exposures"]
    man.write_text(json.dumps(d))
    res = run("scan", man, "--json")
    assert res.exit_code == 0, res.output
    back = json.loads(res.stdout)
    sizes = [len(s["files"]) for s in back["sets"]]
    assert sizes.count(3) >= 7 and 4 in sizes and 7 not in sizes
    added = back["sets"][seven + 1]
    assert len(added["files"]) == 4 and added["reason"] == "split by hand"
    assert added["index"] == len(truth["sets"])  # numbered after the largest index
    assert back["sets"][0]["exposures"] == []  # from EXIF, at batch time

    # A set that cannot merge is reported, and scan says so in its exit code.
    d["sets"].append({"files": [os.path.join(folder, "IMG_0017.jpg")]})
    man.write_text(json.dumps(d))
    res = run("scan", man)
    assert res.exit_code == 1
    assert "cannot be merged: single frame" in res.stdout


def test_frames_per_set_and_gap_overrides(shoot):
    folder, truth = shoot
    d = json.loads(run("scan", folder, "--json", "--frames-per-set", "3").stdout)
    assert {len(s["files"]) for s in d["sets"]} <= {3}
    assert all(s["reason"] in ("frames-per-set 3", "end of files") or s["reason"].startswith("gap")
               for s in d["sets"])
    # A tiny gap splits the hand brackets (seconds between frames), not the bursts.
    d = json.loads(run("scan", folder, "--json", "--gap", "0.5").stdout)
    got = [names(s["files"]) for s in d["sets"]]
    assert truth["sets"][0] not in got
    assert ["IMG_0004.jpg", "IMG_0005.jpg", "IMG_0006.jpg", "IMG_0007.jpg", "IMG_0008.jpg"] in got


def test_recursive(shoot, tmp_path):
    folder, truth = shoot
    top = tmp_path / "card"
    sub = top / "DCIM" / "100CANON"
    shutil.copytree(folder, sub)
    # A card holds its photographs in subfolders only: scanned with them, and said so.
    res = run("scan", top, "--json")
    assert [names(s["files"]) for s in json.loads(res.stdout)["sets"]] == truth["sets"]
    assert "no photographs at its top" in res.stderr and "-r" in res.stderr
    d = json.loads(run("scan", top, "--json", "--recursive").stdout)
    assert [names(s["files"]) for s in d["sets"]] == truth["sets"]


@pytest.mark.parametrize("args, code", [
    (["scan", "{missing}"], 3),
    (["scan", "{bad_json}"], 3),
    (["scan", "{folder}", "--frames-per-set", "0"], 2),
    (["scan", "{folder}", "--gap", "-1"], 2),
    (["scan", "{manifest}", "--gap", "3"], 2),
])
def test_errors(shoot, tmp_path, args, code):
    folder, _ = shoot
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    man = tmp_path / "m.json"
    man.write_text(json.dumps({"sets": []}))
    paths = {"missing": tmp_path / "nope", "bad_json": bad, "folder": folder, "manifest": man}
    res = CliRunner().invoke(main, [a.format(**paths) for a in args])
    assert res.exit_code == code, res.output
    if code == 3:
        assert "hdrcl: error:" in res.stderr
