"""Alignment through the fusion (hdrcl.core.align.stream): the strip source an aligned
merge reads warps each strip as it is asked for, and gives the codes and masks the
whole-frame warp gives (align_bracket), bit for bit, on generated hand-held brackets."""
import numpy as np
import pytest

from hdrcl.core import synthetic as s


def _write(tmp_path, frames, prefix="m"):
    from hdrcl.io.ldr import write_ldr

    paths = []
    for k, f in enumerate(frames):
        p = tmp_path / f"{prefix}{k}.png"
        write_ldr(str(p), f)
        paths.append(str(p))
    return paths


@pytest.fixture(scope="module")
def moved_set():
    """Five generated exposures one stop apart, four moved by known similarities
    (rotations up to 1.5 degrees), one by a whole-pixel shift; odd sizes."""
    from moved import similarity, move
    from test_align import textured_radiance

    h, w = 233, 311
    rad = textured_radiance(h, w, seed=3)
    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
    times = s.stops(5, 1.0, centre=1.0 / float(np.median(rad)))
    tripod = s.bracket(rad, times, cam, noise=0.5, seed=4)
    mats = [similarity(1.5, 1.01, 6.0, -4.0, h, w), similarity(-0.7, 1.0, -3.3, 2.1, h, w), np.eye(3),
            np.array([[1.0, 0, 5.0], [0, 1.0, -3.0], [0, 0, 1.0]]), similarity(-1.2, 0.99, 4.0, 7.5, h, w)]
    moved = [f if k == 2 else move(f, m) for k, (f, m) in enumerate(zip(tripod, mats))]
    return moved, times, mats


def _whole(paths, times, valid, model, crop):
    """The old path: every frame decoded whole and warped (align_bracket)."""
    from hdrcl.core.align import handheld as HH
    from hdrcl.io.reader import BracketReader

    with BracketReader(paths) as reader:
        frames, _ = reader.read_all()
    return HH.align_bracket(frames, valid(frames), times, model=model, crop=crop, names=paths)


def _streamed(paths, times, model, crop, ignore=None):
    from hdrcl.core.align.stream import aligned_source
    from hdrcl.core.options import MergeOptions
    from hdrcl.core.sources import Inputs
    from hdrcl.io.frames import read_info

    inputs = Inputs(paths=paths, infos=[read_info(p) for p in paths], times=np.asarray(times, np.float64))
    opts = MergeOptions(align=True, crop=crop, align_model=model, ignore_color=ignore)
    return aligned_source(inputs, opts, find=lambda f: None)


@pytest.mark.parametrize("crop", [False, True])
@pytest.mark.parametrize("twin", [False, True])
def test_strips_equal_the_whole_frame_warp(tmp_path, moved_set, cl_device, monkeypatch, crop, twin):
    """Every strip of every frame (resampled, shifted by whole pixels, left as it is)
    equals the rows of align_bracket's warped frame, codes and masks, bit for bit: on
    the device (the same kernel per strip) and on the NumPy twin."""
    from hdrcl.core.align import stream as S

    moved, times, _ = moved_set
    paths = _write(tmp_path, moved)
    if twin:  # both paths on the NumPy twin (float64: it may differ from the kernel by a code)
        from hdrcl.core.align import handheld as HH

        monkeypatch.setattr(S.AlignedSource, "fit", _no_warper(S.AlignedSource.fit))
        monkeypatch.setattr(HH, "_warper", lambda aligner: None)
    monkeypatch.setattr(S, "CHUNK_PIXELS", 40 * 311)  # several chunks, bands that differ per chunk
    old = _whole(paths, times, lambda fr: [None] * len(fr), "auto", crop)
    src, rec = _streamed(paths, times, "auto", crop)
    try:
        assert rec.alignment == old.alignment and rec.crop == old.crop and rec.shifts == old.shifts
        assert [a["model"] for a in rec.alignment].count("shift") >= 1  # the whole-pixel path is taken
        assert (src.height, src.width) == old.frames[0].shape[:2]
        got = {}
        for y0, y1, frames, valid in src.strips(17):
            got[y0] = (frames, valid)
        assert sorted(got) == list(range(0, src.height, 17))
        for k, (f, v) in enumerate(zip(old.frames, old.valid)):
            codes = np.concatenate([got[y][0][k] for y in sorted(got)])
            np.testing.assert_array_equal(codes, f)
            if v is None:
                assert all(got[y][1][k] is None for y in got)
            else:
                np.testing.assert_array_equal(np.concatenate([got[y][1][k] for y in sorted(got)]), v)
        # The sampling grid and a patch, sliced out of the views, warp only those pixels.
        for k, f in enumerate(old.frames):
            np.testing.assert_array_equal(src.frames[k][::7, ::7], f[::7, ::7])
            np.testing.assert_array_equal(src.frames[k][30:41, 50:67], f[30:41, 50:67])
            np.testing.assert_array_equal(np.asarray(src.frames[k]), f)
    finally:
        src.close()


def _no_warper(fit):
    def wrapped(self, *a, **k):
        rec = fit(self, *a, **k)
        self.warper = None
        return rec

    return wrapped


def test_ignore_colour_and_fill_masked_as_before(tmp_path, moved_set, cl_device):
    """Pixels of the ignore colour are invalid and stay invalid through the warp, and a
    moved frame's black border fill is masked: the same masks as the whole-frame path."""
    from hdrcl.io.reader import ignore_color_mask

    moved, times, _ = moved_set
    frames = [f.copy() for f in moved]
    for f in frames:
        f[100:120, 140:170] = (0, 0, 255)
    frames[0][:, :9] = 0  # black fill at a moved frame's border
    paths = _write(tmp_path, frames, "i")
    old = _whole(paths, times, lambda fr: [~ignore_color_mask(f, (0, 0, 255)) for f in fr], "similarity", False)
    src, rec = _streamed(paths, times, "similarity", False, ignore=(0, 0, 255))
    try:
        assert rec.alignment == old.alignment
        strips = list(src.strips(64))
        for k, (f, v) in enumerate(zip(old.frames, old.valid)):
            np.testing.assert_array_equal(np.concatenate([st[2][k] for st in strips]), f)
            np.testing.assert_array_equal(np.concatenate([st[3][k] for st in strips]), v)
        assert not np.concatenate([st[3][2] for st in strips])[100:120, 140:170].any()
    finally:
        src.close()


def test_aligned_merge_holds_no_warped_frames(tmp_path, moved_set, cl_device, monkeypatch):
    """merge --align never warps a frame whole (no warp_one, no align_bracket), and its
    file has the same pixels as the merge of align_bracket's warped frames (the merge
    before the strip source: those frames held in an ArraySource)."""
    import hdrcl
    from hdrcl.core.align import handheld as HH
    from hdrcl.core.align import stream as S
    from hdrcl.core.align import warping
    from hdrcl.core.pipeline import ArraySource

    moved, times, _ = moved_set
    paths = _write(tmp_path, moved)
    old = _whole(paths, times, lambda fr: [None] * len(fr), "auto", True)
    streamed = S.aligned_source

    def held(inputs, options, find=None):  # the merge as it was: warped frames held whole
        src, rec = streamed(inputs, options, find)
        src.close()
        return ArraySource(old.frames, old.valid), rec

    with monkeypatch.context() as m:
        m.setattr(S, "aligned_source", held)
        hdrcl.merge_files(paths, str(tmp_path / "held.exr"), times=list(times), align=True, crop=True)

    def refuse(*a, **k):
        raise AssertionError("a frame was warped whole")

    monkeypatch.setattr(warping, "warp_one", refuse)
    monkeypatch.setattr(HH, "align_bracket", refuse)
    res = hdrcl.merge_files(paths, str(tmp_path / "a.exr"), times=list(times), align=True, crop=True)
    assert res.crop == old.crop and [a["matrix"] for a in res.alignment] == [a["matrix"] for a in old.alignment]
    from hdrcl.io.radiance import read_radiance

    (a, meta_a), (b, meta_b) = read_radiance(str(tmp_path / "a.exr")), read_radiance(str(tmp_path / "held.exr"))
    np.testing.assert_array_equal(a, b)  # the pixels, bit for bit
    assert meta_a["alignTransforms"] == meta_b["alignTransforms"]


def test_views_serve_after_close_and_act_as_arrays(tmp_path, moved_set, cl_device):
    """The frames as merged stay readable once the source is closed (a batch's quality
    report reads them after the merge), and a view used as an array warps it whole."""
    moved, times, _ = moved_set
    paths = _write(tmp_path, moved, "v")
    old = _whole(paths, times, lambda fr: [None] * len(fr), "auto", True)
    src, _ = _streamed(paths, times, "auto", True)
    frames, valid = src.frames, src.valid
    src.close()
    for k, (f, v) in enumerate(zip(old.frames, old.valid)):
        np.testing.assert_array_equal(np.asarray(frames[k]), f)
        np.testing.assert_array_equal(frames[k] >= 200, f >= 200)
        assert frames[k].astype(np.float32).sum() == f.astype(np.float32).sum()
        if v is not None:
            np.testing.assert_array_equal(valid[k] & True, v)
    kf, kv, grid = src.kept()
    assert not grid and all(np.array_equal(a, b) for a, b in zip(kf, old.frames))


def test_memory_rule_counts_an_aligned_set_without_warping_it(tmp_path, moved_set, cl_device, monkeypatch):
    """The batch's memory rule (overlap.held_bytes, on the main thread before each commit)
    counts an aligned set's decoded frames without warping them: its views' nbytes used to
    warp every frame whole (the whole frames then dropped, the frames counted twice)."""
    from types import SimpleNamespace

    from hdrcl.shoot.batch import overlap

    moved, times, _ = moved_set
    paths = _write(tmp_path, moved, "h")
    src, _ = _streamed(paths, times, "auto", True)
    calls = []
    monkeypatch.setattr(src, "region", lambda *a, **k: calls.append(a) or (_ for _ in ()).throw(
        AssertionError("a frame was warped to count its bytes")))
    run = SimpleNamespace(source=src, sinks={}, keep=None, tapped=None)
    try:
        cache = src.cache
        held = overlap.held_bytes(run)
        assert not calls
        assert held == (cache.frame_bytes * cache.nframes if cache.in_memory else 0)
    finally:
        src.close()


def test_views_copied_and_flipped_as_arrays_are(tmp_path, moved_set, cl_device):
    """np.array(view) is a copy (writing it left the view's whole frame changed for every
    later reader), and a slice with a negative step gives the flipped frame (it gave an
    empty array)."""
    moved, times, _ = moved_set
    paths = _write(tmp_path, moved, "c")
    src, _ = _streamed(paths, times, "auto", True)
    try:
        view = src.frames[0]
        whole = np.asarray(view).copy()
        scratch = np.array(view)
        scratch[...] = 0
        np.testing.assert_array_equal(np.asarray(view), whole)
        np.testing.assert_array_equal(view[::-1, ::-1], whole[::-1, ::-1])
        np.testing.assert_array_equal(view[5:1:-2], whole[5:1:-2])
    finally:
        src.close()
