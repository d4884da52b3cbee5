"""Bracket-set grouping: logic on constructed headers, manifests, and a generated shoot."""
from __future__ import annotations

import datetime as dt
import json
import os
import random

import pytest

from hdrcl.errors import InputError, UsageError
from hdrcl.io.metadata import FrameInfo
from hdrcl.shoot.grouping.rules import format_exposure, group_frames, unmergeable_reason
from hdrcl.shoot.batch.manifest import (
    BracketSet,
    Manifest,
    Unmerged,
    load_manifest,
    save_manifest,
)
from hdrcl.shoot.scan import format_table, scan_directory

try:
    import shootgen
except ImportError:  # tests/ made a package
    from tests import shootgen

T0 = dt.datetime(2024, 6, 1, 12, 0, 0)
CAM_A = dict(make="Canon", model="Canon EOS R6", serial="111", lens="RF24-105mm",
             focal_length=24.0)
CAM_B = dict(make="NIKON CORPORATION", model="NIKON Z 6", serial="222",
             lens="NIKKOR Z 24-70mm", focal_length=35.0)


class Shoot:
    """Builds FrameInfo lists on a timeline: each frame starts ``gap`` seconds after
    the end of the previous one's exposure."""

    def __init__(self):
        self.frames = []
        self.clock = T0
        self.n = 0

    def shot(self, t, gap=0.5, *, fnumber=8.0, iso=100.0, bias=0.0, mode=1, name=None,
             cam=CAM_A, size=(48, 32), **kw):
        if self.frames:
            self.clock += dt.timedelta(seconds=gap)
        self.n += 1
        fields = dict(cam)
        fields.update(kw)
        f = FrameInfo(path=name or f"IMG_{self.n:04d}.jpg", width=size[0], height=size[1],
                      nchannels=3, exposure_time=t, fnumber=fnumber, iso=iso,
                      exposure_bias=bias, exposure_mode=mode, capture_time=self.clock,
                      **fields)
        self.frames.append(f)
        self.clock += dt.timedelta(seconds=t)
        return f

    def ladder(self, times, gap=0.5, first_gap=None, **kw):
        out = []
        for i, t in enumerate(times):
            g = gap if i else (first_gap if first_gap is not None else gap)
            out.append(self.shot(t, g, **kw).path)
        return out

    def aeb(self, base, evs, gap=0.2, first_gap=None, record_bias=True, **kw):
        out = []
        for i, ev in enumerate(evs):
            g = gap if i else (first_gap if first_gap is not None else gap)
            bias = float(ev) if record_bias else None
            out.append(self.shot(base * 2.0 ** ev, g, bias=bias, mode=2, **kw).path)
        return out


def files(manifest):
    return [s.files for s in manifest.sets]


def reasons(manifest):
    return [s.reason for s in manifest.sets]


# --------------------------------------------------------------------- basic rules


def test_hand_brackets_split_by_gap_and_sizes_differ():
    sh = Shoot()
    a = sh.ladder([1 / 250, 1 / 60, 1 / 15], gap=3.0)
    b = sh.ladder([1 / 1000, 1 / 500, 1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15],
                  gap=2.0, first_gap=40.0)
    c = sh.ladder([1 / 30, 1 / 8, 1 / 2, 2, 8], gap=1.0, first_gap=25.0)
    m = group_frames(sh.frames)
    assert files(m) == [a, b, c]
    assert reasons(m) == ["gap 40.0 s", "gap 25.0 s", "end of files"]
    assert m.unmerged == []
    assert [s.index for s in m.sets] == [0, 1, 2]
    assert m.sets[0].exposures == pytest.approx([1 / 250, 1 / 60, 1 / 15])
    assert m.sets[0].camera == "Canon EOS R6" and m.sets[0].fnumber == 8.0
    assert m.sets[0].start == "2024-06-01T12:00:00.000"
    assert m.sets[1].gaps == pytest.approx([2.0] * 6)


def test_gap_is_measured_from_end_of_exposure():
    # 30 s exposures, 1 s apart end to start: start-to-start is 31 s, still one set.
    sh = Shoot()
    a = sh.ladder([2, 8, 30], gap=1.0)
    m = group_frames(sh.frames)
    assert files(m) == [a]
    assert m.sets[0].gaps == pytest.approx([1.0, 1.0])


def test_long_exposure_noise_reduction_allowance():
    # A 15 s exposure followed by a 15 s dark frame: the 15.5 s gap stays within the set
    # by default, and --gap makes the limit exact.
    sh = Shoot()
    a = sh.ladder([1, 4, 15, 60], gap=0.5)
    sh.frames[3].capture_time += dt.timedelta(seconds=15)
    assert files(group_frames(sh.frames)) == [a]
    m = group_frames(sh.frames, gap=10)
    assert files(m) == [a[:3]]
    assert m.sets[0].reason == "gap 15.5 s"
    assert m.unmerged[0].files == a[3:] and m.unmerged[0].reason == "single frame"


def test_back_to_back_hand_sets_closer_than_longest_exposure():
    # Second set starts 0.5 s after the first ends; the first's longest exposure is 4 s.
    sh = Shoot()
    a = sh.ladder([4, 1, 1 / 4], gap=0.5)
    b = sh.ladder([4, 1, 1 / 4], gap=0.5)
    c = sh.ladder([4, 1, 1 / 4, 1 / 15], gap=0.5)
    m = group_frames(sh.frames)
    assert files(m) == [a, b, c]
    assert reasons(m) == ["exposure repeats first frame"] * 2 + ["end of files"]


def test_repeat_of_any_exposure_in_set_splits():
    # Reversed second ladder: its first frame repeats the first set's last exposure.
    sh = Shoot()
    a = sh.ladder([1 / 60, 1 / 15, 1 / 4], gap=0.3)
    b = sh.ladder([1 / 4, 1 / 15, 1 / 60], gap=0.3)
    m = group_frames(sh.frames)
    assert files(m) == [a, b]
    assert m.sets[0].reason == "exposure repeats frame 3 of the set"


@pytest.mark.parametrize("evs", [
    [0, -2, 2],
    [-2, 0, 2],
    [0, -1, 1, -2, 2],
    [0, -1, -2, 1, 2],  # monotonic for three frames, then turns: still one set
    [-3, -2, -1, 0, 1, 2, 3],
    [0, -1, 1, -2, 2, -3, 3],
])
def test_auto_bracket_orders_back_to_back(evs):
    # Three auto brackets in a burst, metered differently each time, so no exposure
    # time repeats: the exposure-bias ladder restarting splits them.
    sh = Shoot()
    a = sh.aeb(1 / 100, evs)
    b = sh.aeb(1 / 80 * 1.07, evs)
    c = sh.aeb(1 / 30, evs, gap=0.2, fnumber=8.0)
    m = group_frames(sh.frames)
    assert files(m) == [a, b, c]
    assert m.sets[0].reason.startswith("exposure")
    assert m.sets[0].ev == [float(e) for e in evs]


def test_auto_bracket_without_bias_field_is_not_a_ladder_restart():
    # Some bodies record ExposureMode 2 but no bias: the order 0,-1,-2,+1,+2 turns back
    # after three monotonic frames and must still be one set.
    sh = Shoot()
    a = sh.aeb(1 / 125, [0, -1, -2, 1, 2], record_bias=False)
    m = group_frames(sh.frames)
    assert files(m) == [a]


def test_auto_bracket_same_metering_back_to_back():
    sh = Shoot()
    a = sh.aeb(1.0, [0, -2, 2])
    b = sh.aeb(1.0, [0, -2, 2], first_gap=0.3)
    m = group_frames(sh.frames)
    assert files(m) == [a, b]
    assert m.sets[0].reason == "exposure repeats first frame"


def test_hand_ladder_restarts_with_new_metering():
    # Monotonic hand ladders, no repeated time, no gap: the ladder turning back splits.
    sh = Shoot()
    a = sh.ladder([1 / 1000, 1 / 250, 1 / 60, 1 / 15], gap=1.0)
    b = sh.ladder([1 / 500, 1 / 125, 1 / 30], gap=1.0)
    m = group_frames(sh.frames)
    assert files(m) == [a, b]
    assert m.sets[0].reason == "exposure ladder restarts"


def test_exposure_mode_change_splits():
    sh = Shoot()
    a = sh.ladder([1 / 125, 1 / 30, 1 / 8], gap=1.0, mode=1)
    b = sh.aeb(1 / 250, [0, -1, 1], first_gap=1.0)
    m = group_frames(sh.frames)
    assert files(m) == [a, b]
    assert m.sets[0].reason == "exposure mode changed (manual -> auto bracket)"


def test_unsorted_input_is_sorted_by_time_then_name():
    sh = Shoot()
    a = sh.ladder([1 / 250, 1 / 60, 1 / 15], gap=2.0)
    b = sh.ladder([1 / 250, 1 / 60, 1 / 15], gap=2.0, first_gap=30)
    # Two frames with the same capture second: the name decides.
    sh.frames[1].capture_time = sh.frames[0].capture_time
    frames = list(sh.frames)
    random.Random(1).shuffle(frames)
    assert files(group_frames(frames)) == [a, b]


def test_frames_without_capture_time_go_last_and_group_by_pattern():
    sh = Shoot()
    a = sh.ladder([1 / 250, 1 / 60, 1 / 15])
    untimed = [FrameInfo(path=f"z/{n}.png", width=48, height=32, nchannels=3,
                         exposure_time=t, **CAM_A)
               for n, t in zip("bacdef", [1 / 60, 1 / 250, 1 / 15, 1 / 250, 1 / 60, 1 / 15])]
    m = group_frames(untimed + sh.frames)
    assert files(m) == [a, ["z/a.png", "z/b.png", "z/c.png"], ["z/d.png", "z/e.png", "z/f.png"]]
    assert m.sets[1].gaps == [None, None] and m.sets[1].start is None


# -------------------------------------------------------------- cameras, lenses, size


def test_two_cameras_interleaved_are_separate_streams():
    sh = Shoot()
    a1 = sh.shot(1 / 250, cam=CAM_A).path
    b1 = sh.shot(1 / 100, cam=CAM_B, mode=2).path
    a2 = sh.shot(1 / 60, cam=CAM_A).path
    b2 = sh.shot(1 / 200, cam=CAM_B, mode=2, bias=-1.0).path
    a3 = sh.shot(1 / 15, cam=CAM_A).path
    b3 = sh.shot(1 / 50, cam=CAM_B, mode=2, bias=1.0).path
    m = group_frames(sh.frames)
    assert files(m) == [[a1, a2, a3], [b1, b2, b3]]
    assert m.sets[1].camera == "NIKON Z 6" and m.sets[1].serial == "222"


def test_same_model_different_serial_is_another_camera():
    sh = Shoot()
    a = sh.ladder([1 / 250, 1 / 60, 1 / 15], gap=1.0)
    b = sh.ladder([1 / 500, 1 / 125, 1 / 30], gap=1.0, serial="999")
    assert files(group_frames(sh.frames)) == [a, b]


@pytest.mark.parametrize("change, why", [
    (dict(lens="EF 50mm f/1.8"), "lens changed (RF24-105mm -> EF 50mm f/1.8)"),
    (dict(focal_length=50.0), "focal length changed (24 -> 50 mm)"),
    (dict(size=(32, 48)), "image size changed (48x32 -> 32x48)"),
])
def test_lens_focal_length_size_changes_split(change, why):
    sh = Shoot()
    a = sh.ladder([1 / 250, 1 / 60, 1 / 15], gap=1.0)
    b = sh.ladder([1 / 500, 1 / 125, 1 / 30], gap=1.0, **change)
    m = group_frames(sh.frames)
    assert files(m) == [a, b]
    assert m.sets[0].reason == why


def test_aperture_change_in_time_ladder_splits():
    sh = Shoot()
    a = sh.ladder([1 / 250, 1 / 60, 1 / 15], gap=1.0, fnumber=8.0)
    b = sh.ladder([1 / 500, 1 / 60, 1 / 8], gap=1.0, fnumber=4.0)
    m = group_frames(sh.frames)
    assert files(m) == [a, b]
    assert m.sets[0].reason == "aperture changed (f/8 -> f/4)"


# ------------------------------------------------------------------- unmerged groups


def test_single_frames_are_unmerged():
    sh = Shoot()
    s1 = sh.shot(1 / 100).path
    a = sh.ladder([1 / 250, 1 / 60, 1 / 15], gap=1.0, first_gap=30)
    s2 = sh.shot(1 / 100, gap=30).path
    m = group_frames(sh.frames)
    assert files(m) == [a]
    assert [(u.files, u.reason) for u in m.unmerged] == [([s1], "single frame"),
                                                         ([s2], "single frame")]


def test_burst_at_one_exposure_is_one_unmerged_group():
    sh = Shoot()
    burst = sh.ladder([1 / 125] * 4, gap=0.1)
    a = sh.ladder([1 / 125, 1 / 30, 1 / 8], gap=1.0, first_gap=1.0)
    m = group_frames(sh.frames)
    assert files(m) == [a]
    assert len(m.unmerged) == 1
    assert m.unmerged[0].files == burst
    assert m.unmerged[0].reason.startswith("all frames share one exposure (1/125 s, f/8)")


def test_aperture_bracketing_is_flagged():
    sh = Shoot()
    frames = sh.ladder([1 / 125] * 3, gap=0.3, fnumber=8.0)
    sh.frames[1].fnumber, sh.frames[2].fnumber = 4.0, 16.0
    m = group_frames(sh.frames)
    assert m.sets == []
    assert [u.files for u in m.unmerged] == [frames]
    assert m.unmerged[0].reason == "aperture bracketing (f/4 .. f/16 at 1/125 s)"


def test_iso_only_ladder_at_one_shutter_time_is_a_set():
    # A phone in pro mode at 1/125 s stepping ISO 100, 400, 1600: t * ISO is the ladder
    # (issue 19), and the merge's effective exposures step by it.
    from hdrcl.io.metadata import relative_exposures
    from hdrcl.io.exposure_lists import Exposure

    sh = Shoot()
    a = sh.ladder([1 / 125] * 3, gap=0.3)
    sh.frames[1].iso, sh.frames[2].iso = 400.0, 1600.0
    m = group_frames(sh.frames)
    assert files(m) == [a] and m.unmerged == []
    assert m.sets[0].iso == [100.0, 400.0, 1600.0]
    rel = relative_exposures([Exposure(time=t, fnumber=8.0, iso=i) for t, i in zip(m.sets[0].exposures, m.sets[0].iso)])
    assert rel / rel[0] == pytest.approx([1.0, 4.0, 16.0])
    # One time and one ISO is still no ladder.
    sh = Shoot()
    sh.ladder([1 / 125] * 3, gap=0.3)
    assert group_frames(sh.frames).unmerged[0].reason.startswith("all frames share one exposure (1/125 s")


def test_missing_exposure_time_is_flagged():
    sh = Shoot()
    sh.ladder([1 / 250, 1 / 60, 1 / 15], gap=1.0)
    sh.frames[1].exposure_time = None
    m = group_frames(sh.frames)
    assert m.sets == []
    assert m.unmerged[0].reason == "no exposure time (IMG_0002.jpg)"


def test_unmergeable_reason_mixed_cameras():
    sh = Shoot()
    sh.shot(1 / 250)
    sh.shot(1 / 60, cam=CAM_B)
    assert unmergeable_reason(sh.frames) == \
        "mixed cameras (Canon EOS R6 #111, NIKON Z 6 #222)"
    assert unmergeable_reason(sh.frames[:1]) == "single frame"


# ------------------------------------------------------------------------- overrides


def test_frames_per_set_override():
    # Exposures repeat inside each chunk and the gaps are large: the override wins.
    sh = Shoot()
    names = sh.ladder([1 / 60, 1 / 60, 1 / 15, 1 / 4, 1 / 4, 1, 1 / 8, 1 / 2], gap=20)
    m = group_frames(sh.frames, frames_per_set=3)
    assert files(m) == [names[0:3], names[3:6], names[6:8]]
    assert reasons(m) == ["frames-per-set 3", "frames-per-set 3", "end of files"]
    assert m.unmerged == []
    m = group_frames(sh.frames[:6], frames_per_set=3)
    assert reasons(m) == ["frames-per-set 3", "end of files"]
    m = group_frames(sh.frames, frames_per_set=4)
    assert files(m) == [names[0:4], names[4:8]]
    assert reasons(m) == ["frames-per-set 4", "end of files"]


def test_frames_per_set_short_last_set_and_flags():
    sh = Shoot()
    names = sh.ladder([1 / 60, 1 / 15, 1 / 4, 1, 4], gap=1)
    sh.shot(1 / 30, cam=CAM_B)
    sh.shot(1 / 8)
    m = group_frames(sh.frames, frames_per_set=3)
    assert files(m) == [names[0:3]]
    assert m.unmerged[0].files == names[3:5] + ["IMG_0006.jpg"]
    assert m.unmerged[0].reason.startswith("mixed cameras")
    assert m.unmerged[1].files == ["IMG_0007.jpg"]
    assert m.unmerged[1].reason == "single frame"


def test_frames_per_set_with_gap():
    sh = Shoot()
    a = sh.ladder([1 / 60, 1 / 15], gap=1)
    b = sh.ladder([1 / 60, 1 / 15, 1 / 4], gap=1, first_gap=50)
    m = group_frames(sh.frames, frames_per_set=3, gap=10)
    assert files(m) == [a, b]
    assert reasons(m) == ["gap 50.0 s", "end of files"]


def test_gap_override():
    # Slow hand bracketing, 20 s between frames: the default bridges the gaps (one clean
    # ladder), --gap 10 makes the limit exact, --gap 30 keeps the set.
    sh = Shoot()
    a = sh.ladder([1 / 250, 1 / 60, 1 / 15], gap=20)
    m = group_frames(sh.frames)
    assert files(m) == [a]
    assert m.sets[0].joins == ["gap 20.0 s bridged: exposure ladder, 2.1 EV steps, ascending, scene not compared",
                               "gap 20.0 s bridged: exposure ladder, 2.1 EV steps, ascending, scene not compared"]
    m = group_frames(sh.frames, gap=10)
    assert m.sets == [] and len(m.unmerged) == 3
    assert [u.ended for u in m.unmerged] == ["gap 20.0 s", "gap 20.0 s", "end of files"]
    m = group_frames(sh.frames, gap=30)
    assert files(m) == [a]
    # A tight gap splits a burst.
    m = group_frames(sh.frames, gap=5)
    assert m.sets == []


@pytest.mark.parametrize("kw", [dict(frames_per_set=0), dict(frames_per_set=2.5),
                                dict(gap=-1), dict(gap=float("nan"))])
def test_bad_overrides(kw):
    with pytest.raises(UsageError):
        group_frames([], **kw)


def test_empty_input():
    m = group_frames([])
    assert m.sets == [] and m.unmerged == []
    assert "0 set(s)" in format_table(m)


# ------------------------------------------------------------------------ manifests


def _manifest():
    sh = Shoot()
    sh.ladder([1 / 250, 1 / 60, 1 / 15], gap=1.0)
    sh.aeb(1 / 100, [0, -2, 2], first_gap=30)
    sh.shot(1 / 100, gap=30)
    return group_frames(sh.frames)


def test_manifest_json_shape_and_round_trip():
    m = _manifest()
    d = json.loads(m.to_json())
    assert set(d) >= {"sets", "unmerged"}
    s0 = d["sets"][0]
    assert {"index", "files", "exposures", "reason"} <= set(s0)
    assert s0["index"] == 0 and s0["files"] == ["IMG_0001.jpg", "IMG_0002.jpg", "IMG_0003.jpg"]
    assert all(isinstance(t, float) for t in s0["exposures"])
    assert d["sets"][1]["ev"] == [0.0, -2.0, 2.0]
    assert d["unmerged"] == [{"files": ["IMG_0007.jpg"], "reason": "single frame", "ended": "end of files"}]
    assert Manifest.from_dict(d) == m


def test_save_and_load_resolve_relative_paths(tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    for n in ("a.jpg", "b.jpg", "c.jpg", "d.jpg"):
        (photos / n).write_bytes(b"x")
    m = Manifest(sets=[BracketSet(index=0, files=[str(photos / "a.jpg"), str(photos / "b.jpg")],
                                  exposures=[0.01, 0.04], reason="gap 30.0 s")],
                 unmerged=[Unmerged(files=[str(photos / "d.jpg")], reason="single frame")],
                 root=str(photos))
    out = tmp_path / "manifest.json"
    save_manifest(m, out)
    d = json.loads(out.read_text())
    assert d["sets"][0]["files"] == [os.path.join("photos", "a.jpg"),
                                     os.path.join("photos", "b.jpg")]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["manifest.json", "photos"]
    back = load_manifest(out)
    assert back == m
    # Hand edit: add a set without index or exposures, relative to the manifest folder.
    d["sets"].append({"files": ["photos/c.jpg", "photos/d.jpg"]})
    d["unmerged"] = []
    out.write_text(json.dumps(d))
    back = load_manifest(out)
    assert back.sets[1].index == 1 and back.sets[1].exposures == []
    assert back.sets[1].files == [str(photos / "c.jpg"), str(photos / "d.jpg")]
    assert back.sets[1].reason == "manifest"


def test_load_manifest_keeps_indices_and_unknown_keys(tmp_path):
    for n in "abcdef":
        (tmp_path / f"{n}.jpg").write_bytes(b"x")
    d = {"sets": [{"index": 5, "files": ["a.jpg", "b.jpg"], "note": "keep me"},
                  {"files": ["c.jpg", "d.jpg"]},
                  {"index": 2, "files": ["e.jpg", "f.jpg"]}]}
    p = tmp_path / "m.json"
    p.write_text(json.dumps(d))
    m = load_manifest(p)
    assert [s.index for s in m.sets] == [5, 6, 2]
    assert m.sets[0].extra == {"note": "keep me"}
    assert m.sets[0].to_dict()["note"] == "keep me"


@pytest.mark.parametrize("doc, message", [
    ('{"sets": [{"files": ["a.jpg"]}, {"files": ["b.jpg"]}, {"index": 2}]}',
     "sets[2] has no 'files'"),
    ("[1, 2]", "expected a JSON object with 'sets'"),
    ('{"unmerged": []}', "no 'sets' list"),
    ('{"sets": {}}', "'sets' is not a list"),
    ('{"sets": [{"files": []}]}', "sets[0].files is empty"),
    ('{"sets": [{"files": ["a.jpg", 3]}]}', "sets[0].files[1] is not a file name"),
    ('{"sets": [{"files": ["a.jpg", "b.jpg"], "exposures": [0.1]}]}',
     "sets[0].exposures has 1 values for 2 files"),
    ('{"sets": [{"files": ["a.jpg"], "exposures": [-1]}]}',
     "sets[0].exposures[0] is not a positive number"),
    ('{"sets": [{"files": ["a.jpg"], "index": "x"}]}', "sets[0].index is not"),
    ('{"sets": [{"files": ["a.jpg"], "index": 1}, {"files": ["b.jpg"], "index": 1}]}',
     "sets[1].index 1 is also the index of sets[0]"),
    ('{"sets": [{"files": ["a.jpg"]}, {"files": ["a.jpg"]}]}', "is also in sets[0]"),
    ('{"sets": [], "unmerged": [{"reason": "x"}]}', "unmerged[0] has no 'files'"),
    ('{"sets": [', "not valid JSON (line 1"),
])
def test_load_manifest_errors_name_file_and_problem(tmp_path, monkeypatch, doc, message):
    monkeypatch.chdir(tmp_path)
    for n in ("a.jpg", "b.jpg"):
        (tmp_path / n).write_bytes(b"x")
    (tmp_path / "manifest.json").write_text(doc)
    with pytest.raises(InputError) as err:
        load_manifest("manifest.json")
    assert str(err.value).startswith("manifest.json: ")
    assert message in str(err.value)


def test_load_manifest_missing_files(tmp_path):
    p = tmp_path / "m.json"
    p.write_text('{"sets": [{"files": ["nope.jpg"]}]}')
    with pytest.raises(InputError, match="no such file"):
        load_manifest(p)
    assert load_manifest(p, check_files=False).sets[0].files == [str(tmp_path / "nope.jpg")]
    with pytest.raises(InputError, match="no such manifest file"):
        load_manifest(tmp_path / "missing.json")


def test_save_manifest_replaces_atomically(tmp_path):
    p = tmp_path / "m.json"
    p.write_text("old")
    save_manifest(_manifest(), p)
    assert json.loads(p.read_text())["sets"][0]["index"] == 0
    assert sorted(x.name for x in tmp_path.iterdir()) == ["m.json"]  # no temp left


# --------------------------------------------------------------------------- display


def test_format_exposure():
    assert [format_exposure(t) for t in (1 / 60, 0.25, 1.0, 2.5, 30, 0.4, None)] == \
        ["1/60", "1/4", "1", "2.5", "30", "0.4", "?"]


def test_format_table():
    text = format_table(_manifest())
    lines = text.splitlines()
    assert lines[0].split() == ["set", "frames", "first", "file", "exposures", "EV",
                                "ended", "by"]
    assert "IMG_0001.jpg" in lines[1] and "1/250 .. 1/15 s" in lines[1]
    assert "gap 30.0 s" in lines[1]
    assert "0,-2,+2" in lines[2]
    assert "IMG_0007.jpg: single frame" in text
    assert "2 set(s)" in text


# ----------------------------------------------------------------- generated shoot


@pytest.fixture(scope="module")
def shoot(tmp_path_factory):
    pytest.importorskip("OpenImageIO")
    folder = tmp_path_factory.mktemp("shoot")
    return str(folder), shootgen.make_shoot(folder, seed=0)


def test_shootgen_exif_survives_jpeg(shoot):
    import OpenImageIO as oiio

    folder, truth = shoot
    inp = oiio.ImageInput.open(os.path.join(folder, "IMG_0019.jpg"))
    spec = inp.spec()
    inp.close()
    for name in shootgen.EXIF_ATTRIBUTES:
        assert spec.getattribute(name) is not None, name
    assert spec.getattribute("ExposureTime") == pytest.approx(1.0)
    assert spec.getattribute("Exif:ExposureBiasValue") == pytest.approx(0.0)
    assert spec.getattribute("Exif:ExposureMode") == 2


def test_scan_groups_generated_shoot_exactly(shoot):
    pytest.importorskip("hdrcl.io")
    folder, truth = shoot
    m = scan_directory(folder)
    got = [[os.path.basename(f) for f in s.files] for s in m.sets]
    assert got == truth["sets"]
    for s, want in zip(m.sets, truth["exposures"]):
        assert s.exposures == pytest.approx(want, rel=1e-3)
    got_unmerged = [([os.path.basename(f) for f in u.files], u.reason) for u in m.unmerged]
    assert [g[0] for g in got_unmerged] == [u["files"] for u in truth["unmerged"]]
    for (names, reason), want in zip(got_unmerged, truth["unmerged"]):
        assert reason.startswith(want["kind"]), (names, reason)
    # The back-to-back pairs were split by the pattern, not by the gap.
    by_first = {os.path.basename(s.files[0]): s.reason for s in m.sets}
    assert by_first["IMG_0018.jpg"] == "exposure bias repeats (-2 EV)"
    assert by_first["IMG_0024.jpg"] == "exposure repeats first frame"
    assert m.root == folder
    # JSON for machines, table for people.
    d = json.loads(m.to_json())
    assert len(d["sets"]) == len(truth["sets"]) and len(d["unmerged"]) == 2
    assert "corrupt: " in format_table(m)


def test_scan_recursive_and_extensions(shoot, tmp_path):
    pytest.importorskip("hdrcl.io")
    import shutil

    folder, truth = shoot
    # Split the first set across two subfolders (a file-number rollover) and hide one.
    (tmp_path / "100CANON").mkdir()
    (tmp_path / "101CANON").mkdir()
    (tmp_path / ".thumbs").mkdir()
    shutil.copy(os.path.join(folder, "IMG_0001.jpg"), tmp_path / "100CANON" / "IMG_9999.JPG")
    shutil.copy(os.path.join(folder, "IMG_0002.jpg"), tmp_path / "101CANON" / "IMG_0001.jpeg")
    shutil.copy(os.path.join(folder, "IMG_0003.jpg"), tmp_path / "101CANON" / "IMG_0002.jpg")
    shutil.copy(os.path.join(folder, "IMG_0004.jpg"), tmp_path / ".thumbs" / "x.jpg")
    shutil.copy(os.path.join(folder, "IMG_0005.jpg"), tmp_path / "101CANON" / "._IMG.jpg")
    m = scan_directory(tmp_path, recursive=True)
    assert [[os.path.relpath(f, tmp_path) for f in s.files] for s in m.sets] == [[
        os.path.join("100CANON", "IMG_9999.JPG"), os.path.join("101CANON", "IMG_0001.jpeg"),
        os.path.join("101CANON", "IMG_0002.jpg")]]
    assert m.unmerged == []
    m = scan_directory(tmp_path, recursive=True, extensions=("JPG",))
    assert [[os.path.basename(f) for f in s.files] for s in m.sets] == [
        ["IMG_9999.JPG", "IMG_0002.jpg"]]


def test_scan_overrides_on_shoot(shoot):
    pytest.importorskip("hdrcl.io")
    folder, truth = shoot
    m = scan_directory(folder, frames_per_set=3)
    assert all(len(s.files) == 3 for s in m.sets)
    assert all(s.reason in ("frames-per-set 3", "end of files") for s in m.sets)


def test_scan_missing_folder(tmp_path):
    with pytest.raises(InputError, match="no such folder"):
        scan_directory(tmp_path / "nope")
