"""Issue 32: a frame that does not belong is said. A frame of another view (or mirrored)
inside a continuous ladder no longer cuts it in two; a duplicated file is merged once; a
frame tagged with another camera inside a ladder it fits is named. Each is left out of
the set and the set carries a finding naming the file (the batch: status "check" or a
note in report.json)."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

try:
    import cardgen
except ImportError:  # tests/ made a package
    from tests import cardgen

from hdrcl.shoot.batch.manifest import BracketSet, set_findings
from hdrcl.shoot.scan import scan_directory

LADDER = [1 / 1000, 1 / 500, 1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15]
VICTIM = 3  # the middle frame (1/125 s)


def _shots():
    return [cardgen.Shot(cardgen._ladder(LADDER, gaps=[2.0] * (len(LADDER) - 1)), label="ladder"),
            cardgen.Shot(cardgen._ladder([1 / 1000, 1 / 250, 1 / 60], gaps=[2.0, 2.0], first_gap=100.0),
                         label="other")]


def _card(folder, seed=0):
    return cardgen.write_shots(folder, _shots(), seed=seed)


def _rewrite(path, pixels=None, **attrs):
    """The JPEG at ``path`` written again with its EXIF, ``pixels`` and ``attrs`` changed."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(os.fspath(path))
    spec = oiio.ImageSpec(inp.spec())
    old = inp.read_image(0, 0, 0, spec.nchannels, "uint8")
    inp.close()
    for k, v in attrs.items():
        spec.attribute(k, v)
    out = oiio.ImageOutput.create(os.fspath(path))
    assert out.open(os.fspath(path), spec)
    assert out.write_image(np.ascontiguousarray(old if pixels is None else pixels(old)))
    out.close()


def _foreign(folder, truth):
    """The victim replaced by the same frame of another card (another scene, same EXIF)."""
    other = os.path.join(folder, "_other")
    _card(other, seed=5)
    name = truth["sets"][0][VICTIM]
    shutil.copyfile(os.path.join(other, name), os.path.join(folder, name))
    shutil.rmtree(other)
    return name


def _mirrored(folder, truth):
    name = truth["sets"][0][VICTIM]
    _rewrite(os.path.join(folder, name), pixels=lambda a: a[:, ::-1])
    return name


def _names(files):
    return [os.path.basename(f) for f in files]


@pytest.mark.parametrize("fault", [_foreign, _mirrored])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_foreign_frame_does_not_cut_the_ladder(tmp_path, fault, seed):
    truth = _card(tmp_path, seed)
    victim = fault(tmp_path, truth)
    m = scan_directory(tmp_path)
    assert [_names(s.files) for s in m.sets] == [[f for f in truth["sets"][0] if f != victim], truth["sets"][1]]
    assert [(_names(u.files), u.reason.split(":")[0]) for u in m.unmerged] == [([victim], "left out of a set")]
    (f,) = set_findings(m.sets[0])
    assert (f["check"], f["severity"], f["file"]) == ("frames", "check", victim)
    assert f["message"].startswith(f"{victim}: does not match the scene of the other frames (match ")
    assert f["figure"] < 0.45
    assert set_findings(m.sets[1]) == []


def test_clean_ladder_has_no_finding(tmp_path):
    truth = _card(tmp_path)
    m = scan_directory(tmp_path)
    assert [_names(s.files) for s in m.sets] == truth["sets"]
    assert m.unmerged == [] and all(set_findings(s) == [] for s in m.sets)


def test_stray_frame_before_a_ladder_stays_a_single_frame(tmp_path):
    """A frame of another view before the ladder (a test shot) is no foreign frame *inside*
    a run: nothing is joined, nothing said of the set."""
    shots = [cardgen.Shot([cardgen.Frame(time=1 / 60, gap=100.0)], merge=False, label="stray"), *_shots()]
    truth = cardgen.write_shots(tmp_path, shots)
    m = scan_directory(tmp_path)
    assert [_names(s.files) for s in m.sets] == truth["sets"]
    assert all(set_findings(s) == [] for s in m.sets)


def test_duplicated_file_is_merged_once(tmp_path):
    truth = _card(tmp_path)
    name = truth["sets"][0][VICTIM]
    copy = name.replace(".jpg", "_copy.jpg")
    shutil.copy2(tmp_path / name, tmp_path / copy)
    m = scan_directory(tmp_path)
    assert [_names(s.files) for s in m.sets] == truth["sets"]
    assert [(_names(u.files), u.reason) for u in m.unmerged] == [([copy], f"duplicate of {name} (the same bytes)")]
    (f,) = set_findings(m.sets[0])
    assert (f["check"], f["severity"], f["file"]) == ("frames", "note", copy)
    assert name in f["message"] and copy in f["message"]


def test_the_same_files_in_two_folders_are_two_sets(tmp_path, write_frames):
    """Folders of one set each (frames without EXIF, a list each) holding the same frames
    (a set copied, its list changed) are two whole sets: a copy in another folder is no
    duplicate (it took 4 frames out of one set)."""
    from hdrcl.core import synthetic

    times = [1 / 250, 1 / 60, 1 / 15, 1 / 4]
    frames = synthetic.bracket(synthetic.radiance_field(24, 32, decades=3.0, seed=2), times, synthetic.Camera())
    for d, k in (("a", [1, 1, 1, 1]), ("b", [1, 4, 1, 4])):  # b's list: two times wrong, two the same
        paths = write_frames(tmp_path / d, frames)
        (tmp_path / d / "image_list.txt").write_text("".join(f"{os.path.basename(p)} {t * f}\n"
                                                            for p, t, f in zip(paths, times, k)))
    m = scan_directory(tmp_path, recursive=True)
    assert [len(s.files) for s in m.sets] == [4, 4]
    assert not [u for u in m.unmerged if u.reason.startswith("duplicate")]
    assert not any(set_findings(s) for s in m.sets)


def test_re_encoded_copy_is_a_duplicate(tmp_path):
    """Same capture time, settings and pixels, other bytes (a copy saved again)."""
    truth = _card(tmp_path)
    name = truth["sets"][0][VICTIM]
    copy = name.replace(".jpg", "_copy.jpg")
    shutil.copy2(tmp_path / name, tmp_path / copy)
    _rewrite(tmp_path / copy, ImageDescription="saved again")
    assert (tmp_path / copy).read_bytes() != (tmp_path / name).read_bytes()
    m = scan_directory(tmp_path)
    assert [_names(s.files) for s in m.sets] == truth["sets"]
    assert [_names(u.files) for u in m.unmerged] == [[copy]]
    assert "the same capture time, settings and pixels" in m.unmerged[0].reason


def test_repeat_shot_is_no_duplicate(tmp_path):
    """The shutter pressed twice at one setting (its own capture time and noise) stays in
    the set as before (pass 2 of the splitting), nothing left out."""
    frames = cardgen._ladder([1 / 500, 1 / 125, 1 / 125, 1 / 30, 1 / 8], gaps=[2.0] * 4)
    truth = cardgen.write_shots(tmp_path, [cardgen.Shot(frames)])
    m = scan_directory(tmp_path)
    assert [_names(s.files) for s in m.sets] == truth["sets"]
    assert m.unmerged == [] and set_findings(m.sets[0]) == []


def test_frame_of_another_camera_inside_a_ladder_is_named(tmp_path):
    truth = _card(tmp_path)
    victim = truth["sets"][0][VICTIM]
    _rewrite(tmp_path / victim, Make="Canon", Model="Canon EOS 5D Mark II")
    m = scan_directory(tmp_path)
    assert [_names(s.files) for s in m.sets] == [[f for f in truth["sets"][0] if f != victim], truth["sets"][1]]
    assert [_names(u.files) for u in m.unmerged] == [[victim]]
    assert m.unmerged[0].reason.startswith("other camera (Canon EOS 5D Mark II #3051234) inside a set of NIKON D750 #")
    (f,) = set_findings(m.sets[0])
    assert (f["check"], f["severity"], f["file"]) == ("frames", "check", victim)
    assert "Canon EOS 5D Mark II" in f["message"] and f["figure"] >= 0.6


def test_second_photographer_is_not_flagged(tmp_path):
    """Another camera's own bracket shot in the middle of a ladder: its own set, no finding."""
    frames = cardgen._ladder(LADDER, gaps=[2.0] * (len(LADDER) - 1))
    b = dict(cardgen.PHONE)
    for fr in frames[2:5]:
        fr.camera = b
    truth = cardgen.write_shots(tmp_path, [cardgen.Shot(frames)])
    m = scan_directory(tmp_path)
    assert len(m.sets) == 2 and all(set_findings(s) == [] for s in m.sets), truth
    assert not any("other camera" in u.reason for u in m.unmerged)


def test_hand_edited_findings_are_filtered():
    s = BracketSet(index=0, files=["a"], exposures=[1.0], reason="x",
                   extra={"findings": ["text", {"message": ""}, {"check": "frames", "message": "a: odd"}]})
    assert set_findings(s) == [{"check": "frames", "message": "a: odd"}]
    assert set_findings(BracketSet(index=0, files=["a"], exposures=[1.0], reason="x", extra={"findings": 3})) == []


def _batch(folder, out, *options):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    r = subprocess.run([sys.executable, "-m", "hdrcl", "batch", str(folder), "-o", str(out), *options],
                       capture_output=True, text=True, env=env, timeout=300)
    return r, json.loads((out / "report.json").read_text())


@pytest.mark.parametrize("fault", ["foreign", "duplicate"])
def test_batch_carries_the_scan_finding(tmp_path, cl_device, fault):
    truth = _card(tmp_path / "in")
    if fault == "foreign":
        victim = _foreign(tmp_path / "in", truth)
    else:
        name = truth["sets"][0][VICTIM]
        victim = name.replace(".jpg", "_copy.jpg")
        shutil.copy2(tmp_path / "in" / name, tmp_path / "in" / victim)
    r, rep = _batch(tmp_path / "in", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    first = rep["sets"][0]
    assert [s["status"] for s in rep["sets"]] == (["check", "done"] if fault == "foreign" else ["done", "done"])
    assert [f["file"] for f in first["findings"]] == [victim]
    assert any(victim in w for w in first["warnings"])
    if fault == "foreign":
        assert f"check: set 0 ({truth['sets'][0][0]}): {victim}: does not match the scene" in r.stdout
    raw = [ln for ln in r.stderr.splitlines() if not ln.startswith("hdrcl:")]
    assert raw == [], r.stderr


def test_findings_survive_the_manifest_file(tmp_path):
    """``hdrcl scan -o manifest.json`` then ``batch --manifest``: the set keeps what the scan found."""
    from hdrcl.shoot.batch.manifest import load_manifest, save_manifest

    truth = _card(tmp_path / "in")
    victim = _foreign(tmp_path / "in", truth)
    m = scan_directory(tmp_path / "in")
    save_manifest(m, tmp_path / "m.json")
    back = load_manifest(tmp_path / "m.json")
    assert set_findings(back.sets[0]) == set_findings(m.sets[0]) and set_findings(back.sets[0])[0]["file"] == victim
