"""Grouping by what people do (issue 27): the patterns real cards still split, and folders.

Runs are joined whenever the scene matches and no exposure repeats, whatever their order
or step size: a compact's third-stop ladder 9-81 s apart, a last step of a third of a
stop, a ladder shot 1, 2, 1/2 s then on down, a first frame at 1/1250 s before 1/125 ..
1/1000 s, a moon ladder 1/4 -> 1/250 s then 1/2 -> 8 s; phones in auto mode whose 0.25-0.5
EV compensation steps repeat a (shutter, ISO) pair; dark frames on a sensor's pedestal.
Generated cards (``cardgen.PEOPLE``) over seeds 0-9, then each rule on constructed
headers. A folder whose exposure list names its frames is one set; frames of different
folders join only in one camera's stream.
"""
from __future__ import annotations

import datetime as dt
import json
import os

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.io.metadata import FrameInfo
from hdrcl.shoot.grouping import scene as scene_mod
from hdrcl.shoot.grouping.rules import group_frames
from hdrcl.shoot.grouping.ladder import MAX_STEP
from hdrcl.shoot.scan import scan_directory
from hdrcl.shoot.grouping.scene import GRID, Thumb, Verdict, compare

try:
    import cardgen
    from test_grouping_missed import Card, files, scene_signal
except ImportError:  # tests/ made a package
    from tests import cardgen
    from tests.test_grouping_missed import Card, files, scene_signal


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


# The PEOPLE cards, seeds 0-9, are grouped exactly in tests/test_grouping_missed.py (one test for every card).


@pytest.mark.parametrize("name, words", [
    ("compact_thirds", ["bridged: exposure ladder, 0.32 EV steps, ascending, same scene"]),
    ("moon", ["ladder turns back (1/250 -> 1/2 s), gap ", "any order, same scene"]),
    ("phone_comp_steps", ["repeats the settings of the frame before (", "with a new compensation (",
                          "): kept as a duplicate"]),
    ("stray_first", ["set 0 (5 frame(s)):"]),
    ("dark_pedestal", ["set 0 (9 frame(s)):"]),
])
def test_explain_names_the_decisions(tmp_path, name, words):
    cardgen.write_card(tmp_path, name, seed=0)
    res = run("scan", tmp_path, "--explain")
    assert res.exit_code == 0, res.output
    for w in words:
        assert w in res.output, (w, res.output)
    assert "not merged:" not in res.output


# --------------------------------------------------------------- constructed headers

T0 = dt.datetime(2025, 1, 1, 12, 0, 0)


def test_repeated_setting_with_a_new_monotonic_compensation_is_a_duplicate():
    c = Card()
    evs = (-1.0, -0.5, 0.0, 0.5, 1.0)
    ts = (1 / 500, 1 / 250, 1 / 250, 1 / 125, 1 / 60)  # -0.5 and 0 EV metered alike
    a = [c.add(t, bias=ev, mode=0) for t, ev in zip(ts, evs)]
    m = group_frames(c.frames, compare=scene_signal)
    assert files(m) == [a]
    assert "with a new compensation (0 EV): kept as a duplicate" in m.sets[0].joins[1]
    # The compensation walking back with the setting repeated: a new set, as before.
    c = Card()
    a = [c.add(t, bias=ev, mode=0) for t, ev in ((1 / 500, -1.0), (1 / 250, -0.5))]
    b = [c.add(t, bias=ev, mode=0) for t, ev in ((1 / 250, -1.0), (1 / 125, 0.0))]
    m = group_frames(c.frames, compare=scene_signal)
    assert files(m) == [a, b]
    # The same compensation and setting: a repeat (kept as a duplicate of the frame before).
    c = Card()
    a = [c.add(t, bias=ev, mode=0) for t, ev in ((1 / 500, -1.0), (1 / 250, 0.0), (1 / 250, 0.0), (1 / 125, 1.0))]
    assert files(group_frames(c.frames, compare=scene_signal)) == [a]


def test_a_turning_ladder_joins_when_the_scene_matches_and_nothing_repeats():
    c = Card()
    a = [c.add(t) for t in (1 / 4, 1 / 8, 1 / 15, 1 / 30, 1 / 60, 1 / 125, 1 / 250, 1 / 2, 1, 2, 4, 8)]
    m = group_frames(c.frames, compare=scene_signal)
    assert files(m) == [a]
    assert m.sets[0].joins[6].startswith("ladder turns back (1/250 -> 1/2 s), gap 2.0 s bridged")
    # Without the scene the turn still ends the set; on another scene too.
    assert [len(f) for f in files(group_frames(c.frames))] == [7, 5]
    for f in c.frames[7:]:
        f.scene = 1
    m = group_frames(c.frames, compare=scene_signal)
    assert [len(f) for f in files(m)] == [7, 5] and m.sets[0].reason == "exposure ladder restarts"


def test_any_order_and_step_but_no_repeat():
    c = Card()
    a = [c.add(t, gap=g) for t, g in ((1 / 1250, 2.0), (1 / 125, 20.0), (1 / 250, 30.0), (1 / 500, 9.0),
                                        (1 / 1000, 40.0))]
    assert files(group_frames(c.frames, compare=scene_signal)) == [a]
    # A repeat of an earlier exposure (the ladder shot again) still starts a new set; where
    # the cut could fall on either side of a frame, the set shot first keeps it.
    c = Card()
    a = [c.add(t, gap=20.0) for t in (1 / 1000, 1 / 500, 1 / 250)]
    b = [c.add(t, gap=20.0) for t in (1 / 500, 1 / 1000)]
    assert files(group_frames(c.frames, compare=scene_signal)) == [a, b]
    c = Card()
    a = [c.add(t, gap=3.0) for t in (1 / 1000, 1 / 500, 1 / 250)]
    b = [c.add(t, gap=3.0) for t in (1 / 500, 1 / 1000)]
    m = group_frames(c.frames, compare=scene_signal)
    assert files(m) == [a, b] and m.sets[0].reason == "exposure repeats frame 2 of the set"


def dark_signal(a, b):
    """As ``scene_signal``, but a frame tagged ``scene=None`` shows too little to compare."""
    if a.scene is None or b.scene is None:
        return Verdict("unknown", pixels=5)
    return scene_signal(a, b)


@pytest.mark.parametrize("gap, joined", [(70.0, True), (200.0, False)])
def test_the_darkest_frames_of_a_night_ladder_join_as_it_goes_on(gap, joined):
    """The last frames of a hand ladder over minutes show too little to compare: the
    ladder going on one way at its own pace (not after a pause) vouches for them."""
    c = Card()
    ts = [30.0, 8.0, 2.0, 0.5, 1 / 8, 1 / 30, 1 / 125]
    gaps = [9.0, 40.0, 81.0, 25.0, 60.0, 33.0]
    a = [c.add(t, gap=g) for t, g in zip(ts, [0.0] + gaps)]
    d = [c.add(t, gap=g, scene=None) for t, g in ((1 / 500, gap), (1 / 2000, 50.0))]
    m = group_frames(c.frames, compare=dark_signal)
    assert files(m) == ([a + d] if joined else [a, d])
    if joined:
        assert m.sets[0].joins[6].endswith("scene not comparable, the ladder the scene vouched for goes on one way")
    # A frame that walks back is no continuation.
    c = Card()
    a = [c.add(t, gap=g) for t, g in zip(ts, [0.0] + gaps)]
    d = [c.add(t, gap=g, scene=None) for t, g in ((1 / 60, 70.0), (1 / 250, 50.0))]
    assert files(group_frames(c.frames, compare=dark_signal)) == [a, d]


@pytest.mark.parametrize("verdict, joined", [(Verdict("unknown", pixels=5), True),
                                              (Verdict("unknown", rho=0.47, offset=-0.8, pixels=629), False)])
def test_a_doubtful_match_bridges_nothing(verdict, joined):
    """An even ladder 40 s apart is bridged when the thumbnails show too little to
    compare, not when they were compared over most of the frame and matched neither
    well nor badly (two views)."""
    c = Card()
    a = [c.add(t, gap=3.0) for t in (1 / 125, 1 / 60, 1 / 30)]
    b = [c.add(t, gap=40.0 if k == 0 else 3.0) for k, t in enumerate((1 / 15, 1 / 8, 1 / 4))]
    m = group_frames(c.frames, compare=lambda x, y: verdict if (x.path in a) != (y.path in a) else
                     Verdict("same", rho=0.95, offset=0.0, pixels=500))
    assert files(m) == ([a + b] if joined else [a, b])
    assert verdict.doubtful is not joined


def fi(t, mode=1, bias=None, k=0):
    return FrameInfo(path=f"F{k}.jpg", width=32, height=24, nchannels=3, exposure_time=t, fnumber=8.0, iso=100.0,
                     exposure_bias=bias, exposure_mode=mode, capture_time=T0 + dt.timedelta(seconds=30 * k))


def test_distinct_of():
    from hdrcl.shoot.grouping.ladder import distinct_of

    lad = distinct_of([fi(1 / 1000 * 2 ** (k / 3), k=k) for k in range(6)])
    assert lad is not None and lad.order == "ascending" and lad.step == pytest.approx(0.33, abs=0.02)
    assert distinct_of([fi(t, k=k) for k, t in enumerate((1, 2, 0.5, 0.25))]).order == "any order"
    assert distinct_of([fi(t, k=k) for k, t in enumerate((1 / 15, 1 / 13))]) is not None  # nominal thirds: 0.21 stops
    assert distinct_of([fi(t, k=k) for k, t in enumerate((1 / 100, 1 / 250, 1 / 105))]) is None  # a repeat
    hole = 2.0 ** (MAX_STEP + 0.5)
    assert distinct_of([fi(1 / 1000, k=0), fi(1 / 1000 * hole, k=1)]) is None  # no frame overlaps the next
    # Auto exposure without compensation: a third of a stop is the metering's drift.
    assert distinct_of([fi(t, mode=0, k=k) for k, t in enumerate((1 / 100, 1 / 125))]) is None
    # Compensation steps of 0.25 EV are a ladder in the bias.
    assert distinct_of([fi(1 / 100, mode=0, bias=b, k=k) for k, b in enumerate((0, 0.25, 0.5))]).axis == "bias"


# ------------------------------------------------------------------------ pedestal


def test_dark_frames_on_a_pedestal_are_not_a_changed_scene(monkeypatch):
    """Two dark frames of one scene, black at 15 codes with noise: the pedestal and its
    noise are no exposure. With the old fixed floor (0.04) the noise decides: "changed"."""
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:GRID[0], 0:GRID[1]]
    rad = 0.02 * np.exp(3 * x / GRID[1]) * (1 + 0.4 * np.sin(y * 0.7) * np.cos(x * 0.5))

    def dark(exposure):
        code = 15 / 255 + (240 / 255) * np.clip(rad * exposure, 0, 1) ** (1 / 2.2)
        return Thumb(lum=code + rng.normal(0, 0.6 / 255, GRID), exposure=exposure)

    a, b = dark(1 / 128), dark(1 / 64)
    assert compare(a, b).kind != "changed"
    monkeypatch.setattr(scene_mod, "floor", lambda t: scene_mod._LO)
    assert compare(a, b).kind == "changed"


def test_the_floor_rises_only_to_a_pedestal():
    lum = np.full(GRID, 0.3)
    assert scene_mod.floor(Thumb(lum=lum, exposure=1.0)) < 0.3  # a bright frame: every cell counts
    lum[0, 0] = 0.0
    assert scene_mod.floor(Thumb(lum=lum, exposure=1.0)) == pytest.approx(scene_mod._LO)


# ------------------------------------------------------------------------- folders


def test_folder_per_set_views_are_two_sets(tmp_path):
    """Two overlapping views of one scene, one folder each, converted PNGs with one
    conversion stamp and an image_list.txt each: two sets, each its folder's frames in
    the list's order; no frame of one folder joins the other."""
    truth = cardgen.write_folder_views(tmp_path)
    m = scan_directory(tmp_path, recursive=True)
    assert [[os.path.relpath(f, tmp_path) for f in s.files] for s in m.sets] == truth["sets"]
    assert m.unmerged == []
    assert all(j == "listed in image_list.txt" for s in m.sets for j in s.joins)
    assert [s.reason for s in m.sets] == ["end of the frames image_list.txt lists"] * 2
    res = run("scan", tmp_path, "-r", "--explain")
    assert res.exit_code == 0 and "gap -" not in res.output and "2 set(s)" in res.output, res.output


def test_folder_per_set_views_tiff_and_list_order(tmp_path):
    # The second folder's ladder goes on where the first one's ends (in name order too).
    truth = cardgen.write_folder_views(tmp_path, times=[[1 / 250, 1 / 60, 1 / 125], [1 / 30, 1 / 15, 1 / 8]],
                                       fmt="tif", shift=2)
    m = scan_directory(tmp_path, recursive=True)
    assert [[os.path.relpath(f, tmp_path) for f in s.files] for s in m.sets] == truth["sets"]
    assert m.sets[0].exposures == pytest.approx([1 / 250, 1 / 60, 1 / 125])


LADDER = [1 / 1000 * 2 ** k for k in range(8)]


def _batch_views(tmp_path, times):
    # Views 2 px apart: the scene test calls them one; only the folders tell them apart.
    truth = cardgen.write_folder_views(tmp_path / "shoot", times=times, shift=2)
    res = run("batch", tmp_path / "shoot", "-r", "-o", tmp_path / "hdr", "--no-preview", "--json")
    assert res.exit_code == 0, res.output
    return truth, json.loads(res.stdout)


def test_folder_per_set_views_batch_two_outputs(tmp_path):
    """``batch -r`` writes one output per folder, each of its folder's frames, even where
    the second view's ladder goes on from the first's."""
    truth, report = _batch_views(tmp_path, [LADDER[:4], LADDER[4:]])
    assert [os.path.basename(s["output"]) for s in report["sets"]] == ["set1.exr", "set2.exr"]
    assert [[os.path.relpath(f, tmp_path / "shoot") for f in s["files"]] for s in report["sets"]] == truth["sets"]


@pytest.mark.parametrize("times", [
    pytest.param(LADDER[:6], id="same-ladder"),
    pytest.param([LADDER[:4], LADDER[4:]], id="ladder-going-on"),
])
def test_folder_per_set_views_batch_on_one_scale(tmp_path, times):
    """The two views' outputs agree where they overlap (within 0.05 stops)."""
    import OpenImageIO as oiio

    truth, report = _batch_views(tmp_path, times)
    a, b = (oiio.ImageBuf(s["output"]).get_pixels(oiio.FLOAT)[:, :, :3].mean(axis=2) for s in report["sets"])
    s = truth["shift"]
    d = np.log2(b[:, :a.shape[1] - s]) - np.log2(a[:, s:])
    # Where both views measured the pixel: some frame of each holds it in the curve's body
    # (a pixel clipped in every frame of one view has only a bound there, not a value).
    def measured(files):
        codes = [oiio.ImageBuf(str(tmp_path / "shoot" / f)).get_pixels(oiio.FLOAT)[:, :, :3] * 255 for f in files]
        return np.any([((c > 25) & (c < 230)).all(axis=2) for c in codes], axis=0)

    both = measured(truth["sets"][1])[:, :a.shape[1] - s] & measured(truth["sets"][0])[:, s:]
    assert both.mean() > 0.2
    assert abs(float(np.median(d[both]))) <= 0.05 and float(np.sqrt(np.mean(d[both] ** 2))) <= 0.05


def test_frames_without_a_camera_never_join_across_folders():
    # One ladder going on from folder a/ to folder b/, capture times but no camera.
    c = Card()
    a = [c.add(t, folder="a", make=None, model=None) for t in (1 / 1000, 1 / 500, 1 / 250)]
    b = [c.add(t, folder="b", make=None, model=None) for t in (1 / 125, 1 / 60, 1 / 30)]
    assert files(group_frames(c.frames, compare=scene_signal)) == [a, b]
    # One camera's stream (a card's folder rollover, 100CANON -> 101CANON): one set.
    c = Card()
    a = [c.add(t, folder="100CANON") for t in (1 / 1000, 1 / 500, 1 / 250)]
    b = [c.add(t, folder="101CANON") for t in (1 / 125, 1 / 60, 1 / 30)]
    assert files(group_frames(c.frames, compare=scene_signal)) == [a + b]
    # A camera but no capture times: each folder apart.
    for f in c.frames:
        f.capture_time = None
    assert files(group_frames(c.frames, compare=scene_signal)) == [a, b]


# ------------------------------------------------------------------ issue 29 items


@pytest.mark.parametrize("command", [["scan"], ["batch", "--dry-run", "-o", "OUT/"]])
def test_a_trailing_slash_leaves_nothing_out(tmp_path, command):
    cardgen.write_card(tmp_path / "shoot", "back_to_back", seed=0)
    args = [a.replace("OUT", str(tmp_path / "hdr")) for a in command]
    res = run(args[0], str(tmp_path / "shoot") + "/", *args[1:])
    assert res.exit_code == 0, res.output
    assert "left out" not in res.output and "add -r" not in res.output, res.output
    # With photographs below, the line counts them (and only them).
    cardgen.write_card(tmp_path / "shoot" / "day2", "scene_only", seed=0)
    res = run(args[0], str(tmp_path / "shoot") + "/", *args[1:])
    assert "9 photographs in subfolders (day2) are left out; add -r" in res.output, res.output


def test_gaps_are_never_negative():
    # Capture times in whole seconds: the next frame's start lies inside a 2 s exposure.
    c = Card()
    a = [c.add(t, gap=g) for t, g in ((1 / 8, 2.0), (2.0, 2.0), (1 / 2, -1.5))]
    m = group_frames(c.frames)
    assert files(m) == [a] and min(m.sets[0].gaps) >= 0 and not any("gap -" in j for j in m.sets[0].joins)


@pytest.mark.parametrize("command", [["scan"], ["batch", "-o", "OUT"]])
def test_negative_time_in_an_image_list_names_the_list_line_and_time(tmp_path, command):
    truth = cardgen.write_folder_views(tmp_path / "shoot", times=[1 / 60, 1 / 15, 1 / 4])
    lst = tmp_path / "shoot" / "set1" / "image_list.txt"
    lines = lst.read_text().splitlines()
    fields = lines[2].split()
    fields[1] = "-2"
    lines[2] = " ".join(fields)
    lst.write_text("\n".join(lines) + "\n")
    args = [a.replace("OUT", str(tmp_path / "hdr")) for a in command]
    res = run(args[0], tmp_path / "shoot" / "set1", *args[1:])
    assert res.exit_code == 3, res.output
    err = res.stderr.strip().splitlines()
    assert err == [f"hdrcl: error: {lst} line 3: {os.path.basename(truth['sets'][0][1])}: exposure time -2 s "
                   "is not a positive time"], err
    assert not (tmp_path / "hdr").exists()
