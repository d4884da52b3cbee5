"""Alignment of hand-held brackets: kernels equal their twins, known shifts come back.

Scenes are synthetic with known truth: a textured radiance field on a canvas larger
than the frames, bracketed through a known camera; each frame is a window of its
exposure cut at a known offset, so shifted-in borders hold real content, not
wrap-around. Sizes are odd (bitmap rows end mid-word).
"""
import logging

import numpy as np
import pytest

from hdrcl.core.align import mtb as A
from hdrcl.core import synthetic as s
from hdrcl.errors import HdrclError

H, W = 301, 457
MARGIN = 44


def _value_noise(rng, h, w, cell):
    """Bilinear interpolation of a random grid: structure at scale ``cell`` pixels."""
    g = rng.normal(0.0, 1.0, (h // cell + 2, w // cell + 2))
    y, x = np.arange(h) / cell, np.arange(w) / cell
    y0, x0 = y.astype(int), x.astype(int)
    fy, fx = (y - y0)[:, None], (x - x0)[None, :]
    top = g[y0][:, x0] * (1 - fx) + g[y0][:, x0 + 1] * fx
    bot = g[y0 + 1][:, x0] * (1 - fx) + g[y0 + 1][:, x0 + 1] * fx
    return top * (1 - fy) + bot * fy


def textured_radiance(h, w, seed=0):
    """radiance_field (the dynamic range) times texture at several scales and
    rectangles with hard edges: something to align on at every pyramid level."""
    rng = np.random.default_rng(seed)
    log10 = np.zeros((h, w))
    for cell, amp in ((64, 0.45), (24, 0.3), (9, 0.2)):
        log10 += amp * _value_noise(rng, h, w, cell)
    for _ in range(h * w // 2500):
        y, x = rng.integers(0, h), rng.integers(0, w)
        rh, rw = rng.integers(6, 70, 2)
        log10[y:y + rh, x:x + rw] += rng.uniform(-0.8, 0.8)
    return s.radiance_field(h, w, decades=2.0, seed=seed) * (10.0 ** log10)[..., None]


def shifted_bracket(shifts, bits=8, step=1.5, seed=0, h=H, w=W, channels=3):
    """Frames ``j`` with ``frame_j(y + dy, x + dx) = exposure_j(y, x)`` of the reference
    window, and the exposures of the reference window (the aligned truth)."""
    rad = textured_radiance(h + 2 * MARGIN, w + 2 * MARGIN, seed)[..., :channels]
    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8)[:channels], bits=bits)
    times = s.stops(len(shifts), step, centre=1.0 / float(np.median(rad)))
    canvas = s.bracket(rad, times, cam, noise=0.5, seed=seed + 1)
    m = MARGIN
    frames = [c[m - dy:m - dy + h, m - dx:m - dx + w] for c, (dy, dx) in zip(canvas, shifts)]
    truth = [c[m:m + h, m:m + w] for c in canvas]
    return frames, truth


def random_shifts(n, seed, reach=40):
    rng = np.random.default_rng(seed)
    shifts = [tuple(int(v) for v in rng.integers(-reach, reach + 1, 2)) for _ in range(n)]
    shifts[n // 2] = (0, 0)
    return shifts


def within_one(est, truth):
    return all(abs(a - c) <= 1 and abs(b - d) <= 1 for (a, b), (c, d) in zip(est, truth))


# ------------------------------------------------------------------ kernel == twin


@pytest.mark.parametrize("bits,channels", [(8, 3), (16, 3), (8, 1)])
def test_kernels_equal_twins_on_odd_sizes(cl_device, monkeypatch, bits, channels):
    import hdrcl.cl.align as cla

    monkeypatch.setattr(cla, "_MAX_GROUPS", 2)  # several words per work item: the grid-stride loop
    proc = cla.AlignProcessor(ctx=cl_device, strip_pixels=700)  # several strips, a ragged last one
    twin = A.NumpyAligner()
    frames, _ = shifted_bracket([(3, -5), (0, 0)], bits=bits, h=61, w=97, channels=channels)
    levels = 4
    tol = A._tolerance(4, frames[0].dtype)
    gps = [proc.grey_pyramid(f, levels, slot) for f, slot in zip(frames, ("frame", "ref"))]
    gts = [twin.grey_pyramid(f, levels) for f in frames]
    for gp, gt in zip(gps, gts):
        assert gp.shapes == gt.shapes == [(61, 97), (30, 48), (15, 24), (7, 12)]
        for a, b in zip(gp.host, gt.host):
            np.testing.assert_array_equal(a, b)
    for q in (A.QMEDIAN, A.QONE // 10, A.QONE):
        thr = [[A.level_threshold(g, q) for g in gt.host] for gt in gts]
        bms = [proc.bitmaps(gp, t, tol) for gp, t in zip(gps, thr)]
        bts = [twin.bitmaps(gt, t, tol) for gt, t in zip(gts, thr)]
        for k in range(levels):
            for bm, bt in zip(bms, bts):
                tb, eb = proc.read_bitmaps(bm, k)
                np.testing.assert_array_equal(tb, bt.tb[k])
                np.testing.assert_array_equal(eb, bt.eb[k])
            for cy, cx in [(0, 0), (3, -5), (-2, 33), (31, -64), (-60, 0), (200, 200)]:
                got = proc.costs(bms[1], bms[0], k, cy, cx)
                want = twin.costs(bts[1], bts[0], k, cy, cx)
                np.testing.assert_array_equal(got, want, err_msg=f"q={q} level={k} centre=({cy},{cx})")
    # the true shift costs least at full size, and far more than nothing is compared
    thr = [[A.level_threshold(g) for g in gt.host] for gt in gts]
    bm_r, bm_f = proc.bitmaps(gps[1], thr[1], tol), proc.bitmaps(gps[0], thr[0], tol)
    c = proc.costs(bm_r, bm_f, 0, 3, -5)
    assert c.argmin() == 4 and c.min() < 0.3 * c.max()


def test_fetch_of_whole_word_shifts(cl_device):
    """dx a multiple of 32 takes the kernel's no-shift branch (x << 32 is x in OpenCL)."""
    from hdrcl.cl.align import AlignProcessor

    rng = np.random.default_rng(7)
    grey = rng.integers(0, 256, (9, 101)).astype(np.uint8)
    proc, twin = AlignProcessor(ctx=cl_device), A.NumpyAligner()
    gp, gt = proc.grey_pyramid(grey, 1), twin.grey_pyramid(grey, 1)
    t = [A.level_threshold(gt.host[0])]
    bm, bt = proc.bitmaps(gp, t, 4), twin.bitmaps(gt, t, 4)
    for cx in (-63, -32, -31, 0, 1, 31, 32, 33, 64, 97):
        np.testing.assert_array_equal(proc.costs(bm, bm, 0, 0, cx), twin.costs(bt, bt, 0, 0, cx))


# ---------------------------------------------------------------- known shifts


@pytest.mark.parametrize("bits,n,step,seed", [(8, 5, 1.5, 0), (16, 5, 1.5, 1), (8, 7, 2.0, 2)])
def test_known_shifts_recovered_within_one_pixel(cl_device, bits, n, step, seed):
    shifts = random_shifts(n, seed=100 + seed)
    shifts[0] = (40, -40)  # the corners of the required range
    shifts[-1] = (-40, 40)
    frames, _ = shifted_bracket(shifts, bits=bits, step=step, seed=seed)
    est = A.estimate_shifts(frames)
    assert est[n // 2] == (0, 0)
    assert within_one(est, shifts), f"estimated {est}, true {shifts}"


def test_twin_path_gives_the_same_shifts(cl_device, monkeypatch):
    shifts = random_shifts(5, seed=11)
    frames, _ = shifted_bracket(shifts, seed=3)
    est_cl = A.estimate_shifts(frames)
    monkeypatch.setenv("HDRCL_OPENCL", "0")
    monkeypatch.delenv("HDRCL_REQUIRE_OPENCL", raising=False)
    assert isinstance(A.get_aligner(), A.NumpyAligner)
    est_np = A.estimate_shifts(frames)
    assert est_np == est_cl
    assert within_one(est_np, shifts)


def test_twin_path_alone(monkeypatch):
    """The NumPy fallback aligns by itself (runs without any OpenCL device)."""
    monkeypatch.setenv("HDRCL_OPENCL", "0")
    monkeypatch.delenv("HDRCL_REQUIRE_OPENCL", raising=False)
    shifts = [(-17, 29), (0, 0), (38, -3)]
    frames, _ = shifted_bracket(shifts, seed=4, step=2.0)
    assert within_one(A.estimate_shifts(frames), shifts)


def test_static_bracket_has_zero_shifts(cl_device):
    frames, _ = shifted_bracket([(0, 0)] * 5, seed=5)
    assert A.estimate_shifts(frames) == [(0, 0)] * 5
    # featureless frames: every cost is 0 and the tie rule keeps the estimate at 0
    flat = [np.full((33, 65, 3), v, np.uint8) for v in (10, 100, 200)]
    assert A.estimate_shifts(flat, levels=2) == [(0, 0)] * 3


def test_reference_and_levels(cl_device):
    shifts = [(5, -7), (12, 3), (-9, 20)]
    frames, _ = shifted_bracket(shifts, seed=6, step=1.0)
    est = A.estimate_shifts(frames, reference=0, levels=3)  # a wide coarse search instead
    rel = [(dy - 5, dx + 7) for dy, dx in shifts]
    assert est[0] == (0, 0) and within_one(est, rel)


def test_search_reach_is_at_least_63_pixels():
    for levels in range(1, 9):
        r = A.coarse_radius(levels)
        assert (r + 1) * 2 ** (levels - 1) - 1 >= 63
    assert A.coarse_radius(6) == 1  # Ward's search for the default levels
    assert A.default_levels(4000, 6000) == 6 and A.default_levels(H, W) == 5
    assert A.default_levels(20, 20) == 1


def test_shared_percentile():
    # both well exposed at the median: Ward's median
    assert A.shared_percentile((0.1, 0.9), (0.3, 0.95)) == A.QMEDIAN
    # a dark frame: the lowest percentile at which it is above its noise floor, and a bit
    q = A.shared_percentile((0.05, 0.97), (0.8, 1.0))
    assert 0.8 < q / A.QONE < 0.9
    assert 0 <= A.shared_percentile((0.9, 1.0), (0.0, 0.1)) <= A.QONE


# ------------------------------------------------------------------ apply_shifts


def test_apply_shifts_masks_exactly_the_uncovered_borders():
    h, w = 31, 47
    frames = [np.arange(h * w * 3, dtype=np.uint16).reshape(h, w, 3) + 100 * j for j in range(3)]
    shifts = [(3, -5), (0, 0), (-7, 2)]
    out, valid, crop = A.apply_shifts(frames, shifts)
    assert valid[1] is None and out[1] is frames[1]
    yy, xx = np.mgrid[0:h, 0:w]
    for f, o, v, (dy, dx) in zip(frames, out, valid, shifts):
        assert o.dtype == f.dtype and o.shape == f.shape
        if v is None:
            continue
        inside = (yy + dy >= 0) & (yy + dy < h) & (xx + dx >= 0) & (xx + dx < w)
        np.testing.assert_array_equal(v, inside)
        np.testing.assert_array_equal(o[inside], f[yy[inside] + dy, xx[inside] + dx])
        assert not o[~inside].any()  # no wrap-around
    assert crop == (7, h - 3, 5, w - 2)
    y0, y1, x0, x1 = crop
    for v in valid:
        assert v is None or v[y0:y1, x0:x1].all()

    # given masks travel with their frames
    given = [np.ones((h, w), bool) for _ in frames]
    given[0][10, 10] = False
    given[1][0, 0] = False
    _, valid2, _ = A.apply_shifts(frames, shifts, given)
    assert not valid2[0][10 - 3, 10 + 5] and valid2[0].sum() == valid[0].sum() - 1
    assert not valid2[1][0, 0]


def test_align_restores_the_reference_geometry(cl_device, caplog):
    shifts = random_shifts(5, seed=21)
    frames, truth = shifted_bracket(shifts, bits=16, seed=7)
    with caplog.at_level(logging.INFO, logger="hdrcl.core.align.mtb"):
        res = A.align(frames)
    assert isinstance(res, A.AlignResult) and res.reference == 2
    assert res.shifts == shifts  # texture this sharp: exact
    for j, (f, t, v) in enumerate(zip(res.frames, truth, res.valid)):
        m = np.ones(f.shape[:2], bool) if v is None else v
        np.testing.assert_array_equal(f[m], t[m])
        assert f.dtype == np.uint16
    y0, y1, x0, x1 = res.crop
    dys, dxs = [d for d, _ in shifts], [d for _, d in shifts]
    assert (y0, y1, x0, x1) == (max(0, -min(dys)), H - max(0, max(dys)), max(0, -min(dxs)), W - max(0, max(dxs)))
    logged = [r.getMessage() for r in caplog.records if "shift" in r.getMessage()]
    assert len(logged) == 4 and all("dy=" in m and "dx=" in m for m in logged)


# -------------------------------------------------------------------------- errors


def test_input_errors():
    a = np.zeros((31, 47, 3), np.uint8)
    with pytest.raises(ValueError, match="same size"):
        A.estimate_shifts([a, np.zeros((31, 45, 3), np.uint8)])
    with pytest.raises(ValueError, match="one depth"):
        A.estimate_shifts([a, a.astype(np.uint16)])
    with pytest.raises(ValueError, match="out of range"):
        A.estimate_shifts([a, a], reference=2)
    with pytest.raises(ValueError, match="too many"):
        A.estimate_shifts([a, a], levels=6)
    with pytest.raises(ValueError, match="shifts for"):
        A.apply_shifts([a, a], [(0, 0)])


def test_opencl_off_and_required_contradict(monkeypatch):
    monkeypatch.setenv("HDRCL_OPENCL", "0")
    monkeypatch.setenv("HDRCL_REQUIRE_OPENCL", "1")
    with pytest.raises(HdrclError, match="contradicts"):
        A.get_aligner()


# ------------------------------------------- hand-held: similarity and homography


@pytest.fixture(scope="module")
def memorial_handheld(memorial):
    """Exposures 1 stop apart of one real Memorial frame (so the scene is registered
    exactly), moved by known similarities: rotations up to 2 degrees, shifts up to 40
    px, scales up to 2 % (the first and last frames at the extremes)."""
    import imageio.v3 as iio

    from moved import handheld_set

    base = iio.imread(memorial / "memorial0066.png")[..., :3]
    stops = [-2, -1, 0, 1, 2]
    tripod, moved, mats = handheld_set(base, stops, seed=5)
    valid = [~np.all(f == (0, 0, 255), axis=2) for f in moved]
    return tripod, moved, mats, valid, np.exp2(stops)


@pytest.mark.parametrize("model", ["auto", "similarity", "homography"])
def test_handheld_motion_recovered_at_the_corners(cl_device, memorial_handheld, model):
    from hdrcl.core.align import handheld as HH
    from hdrcl.core.align import warp as W

    _, moved, mats, valid, times = memorial_handheld
    h, w = moved[0].shape[:2]
    res = HH.align_bracket(moved, valid, times, model=model, names=[f"m{k}.png" for k in range(5)])
    errs = [W.corner_distance(np.asarray(a["matrix"]), m, h, w) for a, m in zip(res.alignment, mats)]
    assert max(errs) < 0.3, errs
    assert res.alignment[2]["model"] == "reference"
    if model == "auto":  # rotated and scaled: a translation is not enough
        assert all(a["model"] in ("similarity", "homography") for k, a in enumerate(res.alignment) if k != 2)
    a0 = res.alignment[0]
    assert abs(a0["rotation_deg"] - 2.0) < 0.05 and abs(a0["scale"] - 1.02) < 0.002
    assert all(a["residual_px"] is not None and a["residual_px"] < 0.5 for a in res.alignment)


def test_check_model():
    from hdrcl.core.align.handheld import check_model
    from hdrcl.errors import UsageError

    assert check_model("Similarity") == "similarity" and check_model(None) == "auto"
    with pytest.raises(UsageError, match="affine"):
        check_model("affine")


@pytest.mark.parametrize("folder,pattern", [("frobisher_001", "*.jpg"), ("window_e995", "*.jpg")])
def test_real_tripod_sets_find_no_motion(cl_device, memorial, folder, pattern):
    """Real tripod brackets: auto finds no rotation or scale, no frame moved more than
    a fraction of a pixel, and a set that moved less than STATIC_PX stays untouched."""
    import hdrcl
    from hdrcl.core.align import handheld as HH
    from hdrcl.core.align import warp as W

    paths = sorted((memorial.parent / folder).glob(pattern))
    br = hdrcl.load_bracket(paths)
    res = HH.align_bracket(br.frames, br.valid, br.times, names=paths)
    h, w = br.frames[0].shape[:2]
    motion = [W.corner_distance(np.asarray(a["matrix"]), np.eye(3), h, w) for a in res.alignment]
    assert all(a["model"] in ("none", "shift", "reference") for a in res.alignment), res.alignment
    assert max(motion) < 0.6, motion
    # the model finds no motion: the frames are merged as they are
    assert all(a["model"] in ("none", "reference") for a in res.alignment), res.alignment
    assert all(f is g for f, g in zip(res.frames, br.frames))


def test_handheld_numpy_path_matches_opencl(cl_device, memorial_handheld, monkeypatch):
    """Without OpenCL the same matrices come out (the estimation runs on the host from
    grey pyramids the twins make equal) and the twin's warp agrees with the kernel's."""
    from hdrcl.core.align import handheld as HH

    _, moved, _, valid, times = memorial_handheld
    a = HH.align_bracket(moved, valid, times, model="similarity")
    monkeypatch.setenv("HDRCL_OPENCL", "0")
    monkeypatch.delenv("HDRCL_REQUIRE_OPENCL", raising=False)
    assert isinstance(A.get_aligner(), A.NumpyAligner)
    b = HH.align_bracket(moved, valid, times, model="similarity")
    for ra, rb in zip(a.alignment, b.alignment):
        np.testing.assert_allclose(ra["matrix"], rb["matrix"], atol=1e-9)
    for fa, fb, va, vb in zip(a.frames, b.frames, a.valid, b.valid):
        va = np.ones(fa.shape[:2], bool) if va is None else va
        vb = np.ones(fb.shape[:2], bool) if vb is None else vb
        assert np.mean(va != vb) < 1e-3
        d = np.abs(fa.astype(int) - fb.astype(int))[va & vb].max(axis=1)
        # float32 coordinates: a source coordinate within a float32 rounding of the snap
        # distance from an integer snaps in one and not the other, which changes the taps
        # that contribute (and with them the clip rule and the no-ringing range): a few pixels
        assert np.mean(d > 1) < 1e-4 and np.mean(d > 0) < 0.01


def test_frame_with_nothing_to_measure_takes_its_neighbours_motion(cl_device, memorial_bracket, caplog):
    """A frame that records nothing but its pedestal (Memorial's 1/1024 s frame, its few
    window pixels replaced by the sensor's noise): nothing to register, so it is not
    refused but takes its neighbour's motion, with a warning. (The real 1/1024 s frame is
    measured: its windows, block-matched, confirm the fit.)"""
    from hdrcl.core.align import handheld as HH

    br = memorial_bracket
    darkest = int(np.argmin(br.times))
    frames = list(br.frames)
    rng = np.random.default_rng(0)
    frames[darkest] = np.clip(np.round(15 + rng.normal(0, 1, frames[darkest].shape)), 0, 255).astype(np.uint8)
    with caplog.at_level(logging.WARNING, logger="hdrcl.core.align.handheld"):
        res = HH.align_bracket(frames, br.valid, br.times, names=br.paths, model="similarity")
    rec = res.alignment[darkest]
    assert rec["model"] == "inherited" and rec["residual_px"] is None
    neighbour = [a for a in res.alignment if a["file"] == rec["against"]][0]
    assert rec["matrix"] == neighbour["matrix"]
    assert any(rec["file"] in r.getMessage() and "too few" in r.getMessage() for r in caplog.records)
    assert sum(a["model"] == "inherited" for a in res.alignment) == 1


def test_inplace_reuses_frames_and_changes_nothing(cl_device, memorial_handheld):
    """``inplace`` warps into the memory of frames already replaced (no fresh pages):
    the same frames and masks come out as without it, and the arrays given are reused."""
    from hdrcl.core.align import handheld as HH

    _, moved, _, valid, times = memorial_handheld
    a = HH.align_bracket(moved, valid, times, model="similarity")
    frames, masks = [f.copy() for f in moved], list(valid)
    given = list(frames)  # identities only: their contents are overwritten
    b = HH.align_bracket(frames, masks, times, model="similarity", inplace=True)
    assert b.frames is frames and b.valid is masks  # replaced in the lists given
    for f, g, u, v in zip(a.frames, b.frames, a.valid, b.valid):
        np.testing.assert_array_equal(f, g)
        np.testing.assert_array_equal(u, v)
    # the reference as it was, and at least one warp written into a replaced frame
    assert sum(any(np.shares_memory(f, g) for g in given) for f in frames) >= 2
