"""Camera cards shot the way people shoot: grouped exactly, every decision with its reason.

Synthetic cards (``cardgen``: small JPEGs with real EXIF) per scenario and mixed on one
card; the exposure-ladder and scene signals on their own; exposure lists beside frames.
"""
from __future__ import annotations

import datetime as dt
import os

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.io.metadata import FrameInfo
from hdrcl.shoot.grouping.rules import group_frames
from hdrcl.shoot.grouping.ladder import ladder_of
from hdrcl.shoot.scan import scan_directory
from hdrcl.shoot.grouping.scene import GRID, Thumb, compare

try:
    import cardgen
except ImportError:  # tests/ made a package
    from tests import cardgen


def names(manifest):
    return [[os.path.basename(f) for f in s.files] for s in manifest.sets]


@pytest.fixture(scope="module", params=list(cardgen.SCENARIOS) + ["mixed"])
def card(request, tmp_path_factory):
    folder = tmp_path_factory.mktemp(request.param)
    return request.param, folder, cardgen.write_card(folder, request.param, seed=3)


def test_card_grouped_exactly_with_reasons(card):
    name, folder, truth = card
    m = scan_directory(folder)
    assert names(m) == truth["sets"], name
    assert sorted(os.path.basename(f) for u in m.unmerged for f in u.files) == sorted(truth["unmerged"])
    for s in m.sets:
        assert len(s.joins) == len(s.files) - 1 and all(s.joins), s
        assert s.reason
    if name == "manual_long_gaps":
        # 5-60 s between frames: the long gaps are bridged by the ladder and the scene.
        bridged = [j for s in m.sets for j in s.joins if "bridged" in j]
        assert bridged and all("same scene" in j and "ladder" in j for j in bridged)
        assert all(s.reason.startswith("gap ") or s.reason == "end of files" for s in m.sets)
    if name == "back_to_back":
        assert [s.reason for s in m.sets[:-1]] == ["gap 150.0 s", "gap 240.0 s"]
    if name == "exposure_comp":
        assert any("bias ladder" in j for s in m.sets for j in s.joins)


def test_card_headers_alone_still_split_the_sets(card):
    """Without the content signal the long gaps are bridged only up to 60 s by the
    ladder: the cards of sets that differ only in scene still come out right where the
    headers tell them apart."""
    name, folder, truth = card
    m = scan_directory(folder, content=False)
    if name in ("back_to_back", "subsecond", "aeb_orders", "auto_iso"):
        assert names(m) == truth["sets"]
    if name == "scene_only":  # the ladders continue each other: only the content splits them
        assert names(m) != truth["sets"]
    assert not any("same scene" in j for s in m.sets for j in s.joins)


def test_subsecond_ordering_is_by_subsec_not_name(tmp_path):
    truth = cardgen.write_card(tmp_path, "subsecond", seed=1)
    m = scan_directory(tmp_path)
    assert names(m) == truth["sets"]
    # The names are not in capture order: only SubSecTimeOriginal can have ordered them.
    assert any(s != sorted(s) for s in truth["sets"])


def test_scan_explain_shows_every_decision(tmp_path):
    cardgen.write_card(tmp_path, "manual_long_gaps", seed=0)
    res = CliRunner().invoke(main, ["scan", str(tmp_path), "--explain"])
    assert res.exit_code == 0, res.output
    assert "set 0 (9 frame(s)):" in res.output
    assert "IMG_0001.jpg: first frame" in res.output
    assert "bridged: exposure ladder, 1 EV steps, ascending, same scene" in res.output
    assert "ended: gap 180.0 s" in res.output


# ------------------------------------------------------------------------ ladders

T0 = dt.datetime(2025, 1, 1, 12, 0, 0)


def fi(t, iso=100.0, bias=None, mode=1, k=0):
    return FrameInfo(path=f"F{k}.jpg", width=32, height=24, nchannels=3, exposure_time=t, fnumber=8.0, iso=iso,
                     exposure_bias=bias, exposure_mode=mode, capture_time=T0 + dt.timedelta(seconds=30 * k))


@pytest.mark.parametrize("evs", [[0, -1, 1], [0, -2, 2, -4, 4], [-1, 0, 1], [0, -1, -2, 1, 2], [2, 1, 0, -1]])
def test_aeb_orders_are_ladders(evs):
    frames = [fi(1 / 100 * 2.0 ** e, bias=float(e), mode=2, k=i) for i, e in enumerate(evs)]
    lad = ladder_of(frames)
    assert lad is not None and lad.axis == "bias"
    assert lad.values == tuple(float(e - evs[0]) for e in evs)


def test_ladder_axes_and_refusals():
    manual = [fi(1 / 1000 * 2 ** k, k=k) for k in range(5)]
    assert ladder_of(manual).describe() == "exposure ladder, 1 EV steps, ascending"
    auto_iso = [fi(t, iso=i, mode=0, k=k) for k, (t, i) in enumerate([(1 / 60, 200), (1 / 60, 400), (1 / 30, 400)])]
    assert ladder_of(auto_iso).axis == "exposure" and ladder_of(auto_iso).step == 1.0
    assert ladder_of(manual[:2] + [fi(1 / 1000, k=9)]) is None  # a repeat
    assert ladder_of([fi(1 / 1000, k=0), fi(1 / 500, k=1), fi(1 / 60, k=2)]) is None  # uneven steps
    assert ladder_of([fi(1 / 1000, k=0), fi(1 / 500, k=1), fi(1 / 250, k=2), fi(1 / 2000, k=3)]) is None  # turns


def test_gap_bridge_needs_the_ladder_to_continue():
    # A stray frame 30 s before a clean ladder does not join it; the ladder's own 30 s
    # gaps are bridged.
    frames = [fi(1 / 100, k=0)] + [fi(1 / 250 * 4 ** j, k=j + 1) for j in range(3)]
    m = group_frames(frames)
    assert [s.files for s in m.sets] == [["F1.jpg", "F2.jpg", "F3.jpg"]]
    assert [u.files for u in m.unmerged] == [["F0.jpg"]]


# -------------------------------------------------------------------------- scene


def _thumb(rad, exposure, gamma=2.2):
    return Thumb(lum=np.clip(rad * exposure, 0, 1) ** (1 / gamma), exposure=exposure)


def test_scene_compare_same_and_changed():
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:GRID[0], 0:GRID[1]]
    a = 0.05 * np.exp(3 * x / GRID[1]) * (1 + 0.3 * np.sin(y))
    b = np.roll(rng.permutation(a.ravel()).reshape(a.shape), 3, axis=1)
    v = compare(_thumb(a, 1.0), _thumb(a, 2.0))
    assert v.kind == "same" and v.rho > 0.85 and abs(v.offset) < 0.2
    assert compare(_thumb(a, 1.0), _thumb(b, 2.0)).kind == "changed"
    # The same framing 6 stops brighter after normalising the exposure: another scene.
    assert compare(_thumb(a, 1.0), _thumb(a * 64, 1 / 64)).kind == "changed"
    assert compare(_thumb(a, 1.0), None).kind == "unknown"
    assert compare(_thumb(a, 1e-4), _thumb(a, 1.0)).kind == "unknown"  # nothing well exposed in both


# ---------------------------------------------------------------- exposure lists


def test_memorial_exposures_from_image_list(memorial):
    m = scan_directory(memorial)
    assert len(m.sets) == 1 and len(m.sets[0].files) == 16
    assert m.sets[0].exposures[0] == pytest.approx(32.0) and m.sets[0].exposures[-1] == pytest.approx(1 / 1024)


def test_uneven_hand_ladder_bridged_only_when_the_scene_matches(tmp_path):
    # 1/1000, 1/250, 1/125, 1/30: steps of 2, 1 and 2 stops, 20-40 s apart, one scene.
    shots = [cardgen.Shot([cardgen.Frame(time=t, gap=g) for t, g in
                           ((1 / 1000, 10.0), (1 / 250, 25.0), (1 / 125, 40.0), (1 / 30, 20.0))])]
    truth = cardgen.write_shots(tmp_path, shots, seed=2)
    assert names(scan_directory(tmp_path)) == truth["sets"]
    m = scan_directory(tmp_path, content=False)  # even steps required without the scene
    assert names(m) != truth["sets"]
    assert ladder_of([fi(t, k=k) for k, t in enumerate((1 / 1000, 1 / 250, 1 / 125, 1 / 30))], even=False).order \
        == "ascending, uneven"


def test_auto_brackets_without_bias_metered_a_third_apart_split():
    frames, k = [], 0
    for base in (1 / 100, 1 / 125, 1 / 160):
        for ev in (0, -1, 1):
            frames.append(fi(base * 2.0 ** ev, mode=2, k=k))
            k += 1
    for i, f in enumerate(frames):
        f.capture_time = T0 + dt.timedelta(seconds=0.3 * i)
    m = group_frames(frames)
    assert [len(s.files) for s in m.sets] == [3, 3, 3]
    assert m.sets[0].reason == "bracket pattern restarts (exposure off the set's steps)"


@pytest.mark.parametrize("name, frames", [("window_e995", 12), ("frobisher_001", 3)])
def test_real_brackets_are_one_set_and_the_scene_vouches(memorial, name, frames):
    # window_e995: a hand ladder 6-8 s apart whose JPEGs carry EXIF thumbnails (the
    # thumbnail path); frobisher_001: small JPEGs without one (decoded and reduced).
    folder = memorial.parent / name
    if not folder.is_dir():
        pytest.skip(f"{folder} not found")
    m = scan_directory(folder)
    assert [len(s.files) for s in m.sets] == [frames] and m.unmerged == []
    assert all("same scene" in j for j in m.sets[0].joins)


def test_raw_plus_jpeg_pairs_group_as_two_streams():
    frames = []
    for k, t in enumerate([1 / 500, 1 / 125, 1 / 30, 1 / 500, 1 / 125, 1 / 30]):
        when = T0 + dt.timedelta(seconds=2 * k + (60 if k >= 3 else 0))
        for ext in (".CR2", ".JPG"):
            frames.append(FrameInfo(path=f"IMG_{k:04d}{ext}", width=32, height=24, nchannels=3, exposure_time=t,
                                    fnumber=8.0, iso=100.0, exposure_mode=1, capture_time=when))
    m = group_frames(frames)
    got = sorted(tuple(s.files) for s in m.sets)
    want = sorted(tuple(f"IMG_{k:04d}{ext}" for k in ks) for ks in ((0, 1, 2), (3, 4, 5)) for ext in (".CR2", ".JPG"))
    assert got == want and m.unmerged == []
