"""The frames' agreement check (hdrcl.core.agreement): a shifted frame and a moving subject
are found in every merge, named with the figure and what to try; static sets stay quiet."""
import glob
import os

import numpy as np
import pytest

from hdrcl.core import synthetic as s
from hdrcl.core.agreement import GHOST_PERCENT, SHIFT_PX, measure_agreement

CAM = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))


def _scene(h, w, seed=1):
    """The synthetic field with sharp-edged blocks (13 px, so that the edges fall at every
    phase of a coarser grid): a scene has edges, a pure gradient does not show a shift."""
    rad = s.radiance_field(h, w, decades=4.0, seed=seed)
    rng = np.random.default_rng(seed)
    b = 13
    blocks = rng.uniform(0.4, 1.6, (-(-h // b), -(-w // b)))
    return rad * np.kron(blocks, np.ones((b, b)))[:h, :w, None]


def _frames(rads, times, noise=1.0):
    return [s.bracket(r, [t], CAM, noise=noise, seed=10 + i)[0] for i, (r, t) in enumerate(zip(rads, times))]


def _tables(levels=256):
    z = np.arange(levels, dtype=np.float64)
    z[0], z[-1] = 0.5, levels - 1.5
    return np.stack([CAM.g(z, c) for c in range(3)])


def _measure(rads, times, stride=1, noise=1.0):
    frames = [f[::stride, ::stride] for f in _frames(rads, times, noise)]
    return measure_agreement(frames, None, times, _tables(), stride)


@pytest.fixture(scope="module")
def synth():
    rad = _scene(240, 320)
    return rad, s.stops(5, 2.0, centre=1.0 / float(np.median(rad)))


def _moved(ag):
    return [p for p in ag.pairs if p.moved]


def _ghosts(ag):
    return [p for p in ag.pairs if p.ghost_percent >= GHOST_PERCENT and not p.moved]


@pytest.mark.parametrize("noise", [0.5, 2.0])
def test_static_noisy_set_agrees(synth, noise):
    rad, times = synth
    ag = _measure([rad] * 5, times, noise=noise)
    assert len(ag.pairs) == 4
    assert not _moved(ag) and not _ghosts(ag)
    assert max(p.shift_px for p in ag.pairs) < 0.5
    assert max(p.ghost_percent for p in ag.pairs) < 0.3


@pytest.mark.parametrize("dy,dx", [(3, 0), (0, -3), (2, 2)])
def test_frame_shifted_3px_is_found(synth, dy, dx):
    rad, times = synth
    rads = [rad] * 5
    rads[2] = np.roll(rad, (dy, dx), axis=(0, 1))
    ag = _measure(rads, times)
    moved = _moved(ag)
    assert {(p.short, p.long) for p in moved} == {(1, 2), (2, 3)}
    for p in moved:
        assert abs(p.shift_px - np.hypot(dy, dx)) < 0.5
    from hdrcl.core.agreement import findings

    (f,) = findings(ag, [f"f{i}.png" for i in range(5)])
    assert f.check == "agreement" and f.severity == "check" and f.file == "f2.png"
    assert "try --align" in f.message and abs(f.figure - np.hypot(dy, dx)) < 0.5
    import re

    x, y = (float(v) for v in re.search(r"lies x ([-+.\d]+), y ([-+.\d]+) px off", f.message).groups())
    assert abs(x - dx) < 0.5 and abs(y - dy) < 0.5  # the named frame's own offset


def test_shift_found_on_a_coarse_grid():
    """A 3 px shift measured on every 3rd row and column (a 5 MP frame's sampling grid)."""
    rad = _scene(600, 800, seed=3)
    times = s.stops(3, 2.0, centre=1.0 / float(np.median(rad)))
    ag = _measure([rad, np.roll(rad, 3, axis=1), rad], times, stride=3)
    assert _moved(ag) and all(2.0 < p.shift_px < 4.5 for p in ag.pairs)
    static = _measure([rad] * 3, times, stride=3)
    assert all(p.shift_px < SHIFT_PX for p in static.pairs)


def test_moving_object_in_two_frames_is_a_ghost(synth):
    rad, times = synth
    h, w = rad.shape[:2]
    side = int(np.sqrt(0.05 * h * w))
    a, b = rad.copy(), rad.copy()
    a[40:40 + side, 60:60 + side] = np.median(rad) * 8
    b[100:100 + side, 170:170 + side] = np.median(rad) * 0.1
    ag = _measure([rad, a, rad, b, rad], times)
    assert not _moved(ag)
    worst = max(p.ghost_percent for p in ag.pairs)
    assert 2.5 < worst < 12
    from hdrcl.core.agreement import findings

    (f,) = findings(ag, [f"f{i}.png" for i in range(5)])
    assert f.severity == "check" and "try --deghost" in f.message and "% of the picture" in f.message
    (g,) = findings(ag, [f"f{i}.png" for i in range(5)], deghost=True)
    assert g.severity == "note"


def test_bright_object_in_one_frame_is_named(synth):
    """A bright object in the middle frame only (clipped there): found through the clipped
    code's bound, and the frame named, not its exposure."""
    rad, times = synth
    h, w = rad.shape[:2]
    side = int(np.sqrt(0.05 * h * w))
    o = rad.copy()
    o[50:50 + side, 60:60 + side] = np.median(rad) * 64
    ag = _measure([rad, rad, o, rad, rad], times)
    from hdrcl.core.agreement import findings

    names = [f"f{i}.png" for i in range(5)]
    assert max(p.ghost_percent for p in ag.pairs) > 2.5
    (f,) = findings(ag, names)
    assert "f2.png" in f.message and "try --deghost" in f.message
    (f,) = findings(ag, names, notes=["f2.png: exposure measured +6.0 stops from its label"])
    assert f.file == "f2.png" and "not its exposure" in f.message


def test_merge_reports_the_finding(synth, tmp_path, write_frames, cl_device):
    """Through the engine (hdrcl merge's path): on the result, in its warnings, once."""
    from hdrcl.core.merge import merge_files

    rad, times = synth
    rads = [rad] * 5
    rads[3] = np.roll(rad, 3, axis=0)
    paths = write_frames(tmp_path / "in", _frames(rads, times))
    res = merge_files(paths, str(tmp_path / "out.exr"), times=list(times))
    found = [f for f in res.findings if f.check == "agreement"]
    assert len(found) == 1 and found[0].file == "f3.png" and "--align" in found[0].message
    assert found[0].message in res.warnings
    quiet = merge_files(write_frames(tmp_path / "static", _frames([rad] * 5, times)), str(tmp_path / "s.exr"),
                        times=list(times))
    assert not [f for f in quiet.findings if f.check == "agreement"]


def test_merge_bracket_carries_findings(synth):
    import hdrcl
    from hdrcl.core.bracket import Bracket

    rad, times = synth
    h, w = rad.shape[:2]
    o = rad.copy()
    o[30:90, 40:110] = np.median(rad) * 3
    frames = _frames([rad, o, rad, rad, rad], times)
    res = hdrcl.merge_bracket(Bracket(frames=frames, times=np.asarray(times), valid=[None] * 5))
    assert [f.check for f in res.findings] == ["agreement"] and "--deghost" in res.findings[0].message


def _shared(name):
    """A set of the shared data beside the repo (conftest's), or under HDRCL_DATA (a
    worktree elsewhere); skipped only when missing."""
    from pathlib import Path

    from conftest import MEMORIAL

    for root in (MEMORIAL.parent, Path(os.environ.get("HDRCL_DATA", MEMORIAL.parent))):
        if (root / name).is_dir():
            return root / name
    pytest.skip(f"{name} not found in {MEMORIAL.parent} (or HDRCL_DATA)")


@pytest.fixture(scope="module")
def memorial_set():
    return _shared("memorial")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["frobisher_001", "window_e995"])
def test_static_camera_sets_raise_nothing(name, tmp_path, cl_device):
    from hdrcl.core.merge import merge_files

    paths = sorted(str(p) for p in _shared(name).iterdir() if p.suffix.lower() == ".jpg")
    res = merge_files(paths, str(tmp_path / "out.exr"))
    assert not [f.message for f in res.findings if f.check == "agreement"]


def _memorial_grid(memorial):
    import hdrcl
    from hdrcl.core.calibrate import calibrate

    br = hdrcl.load_bracket(sorted(glob.glob(str(memorial / "memorial*.png"))),
                            times_file=memorial / "image_list.txt", ignore_color=(0, 0, 255))
    resp = calibrate(br)
    return br, resp


def test_memorial_agrees_and_a_shifted_frame_does_not(memorial_set):
    """The tripod Memorial set (film frames 0.5-0.8 px apart) raises nothing; one frame
    moved by 3 px is found and named."""
    br, resp = _memorial_grid(memorial_set)
    times = np.asarray(br.times)
    tables = resp.table_for(3)
    ag = measure_agreement(br.frames, br.valid, times, tables, 1)
    assert len(ag.pairs) == 15
    assert not _moved(ag) and not _ghosts(ag)
    frames = list(br.frames)
    valid = list(br.valid)
    k = int(np.argsort(times)[8])
    frames[k] = np.roll(frames[k], 3, axis=1)
    valid[k] = None if valid[k] is None else np.roll(valid[k], 3, axis=1)
    moved = _moved(measure_agreement(frames, valid, times, tables, 1))
    assert moved and all(k in (p.short, p.long) for p in moved)
    assert all(2.0 < p.shift_px < 4.0 for p in moved)


def test_batch_set_with_a_moved_frame_needs_a_check(tmp_path, cl_device):
    """Through hdrcl batch: the set whose middle frame moved 3 px is 'check' with the
    agreement finding in report.json; the static set beside it is 'done'."""
    import datetime as dt

    from click.testing import CliRunner

    from hdrcl.cli import main
    from hdrcl.io.ldr import write_photo

    folder = tmp_path / "shoot"
    folder.mkdir()
    rad = _scene(240, 320, seed=4) * 40.0
    times = [1 / 500, 1 / 125, 1 / 30, 1 / 8]
    when, n = dt.datetime(2024, 6, 1, 9, 0, 0), 0
    for moved in (False, True):
        rads = [rad] * 4
        if moved:
            rads[2] = np.roll(rad, 3, axis=1)
        for k, (r, t) in enumerate(zip(rads, times)):
            n += 1
            frame = s.bracket(r, [t], CAM, noise=0.5, seed=n)[0]
            write_photo(str(folder / f"IMG_{n:04d}.jpg"), frame,
                        {"ExposureTime": float(t), "FNumber": 8.0, "Exif:PhotographicSensitivity": 100,
                         "Exif:ExposureMode": 1, "Make": "Canon", "Model": "Canon EOS R6",
                         "Exif:DateTimeOriginal": when.strftime("%Y:%m:%d %H:%M:%S")})
            when += dt.timedelta(seconds=2)
        when += dt.timedelta(seconds=60)
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["batch", str(folder), "-o", str(out)])
    assert r.exit_code == 0, r.output
    import json

    sets = json.loads((out / "report.json").read_text())["sets"]
    assert [x["status"] for x in sets] == ["done", "check"]
    (f,) = [f for f in sets[1]["findings"] if f["check"] == "agreement"]
    assert f["file"] == "IMG_0007.jpg" and f["severity"] == "check" and "--align" in f["message"]
    assert not [f for f in sets[0].get("findings", []) if f["check"] == "agreement"]
