"""The warp kernel against its NumPy twin (float32 against float64), the twin against
known truth, and the crop box every warped frame covers."""
import numpy as np
import pytest

from hdrcl.core.align import warp as W

from moved import similarity


def _matrices(h, w):
    return {
        "integer shift": W.translation(3, -5),
        "sub-pixel shift": W.translation(0.37, -12.81),
        "similarity": similarity(2.0, 1.02, 17.3, -31.6, h, w),
        "homography": np.array([[1.01, 0.02, 3.3], [-0.015, 0.99, -2.2], [2e-4, -1.5e-4, 1.0]]),
        "horizon": np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -0.02, 1.0]]),  # s <= 0 below row 50
        "far away": similarity(90.0, 3.0, 5000.0, 0.0, h, w),
    }


@pytest.mark.parametrize("dtype,channels", [(np.uint8, 3), (np.uint16, 3), (np.uint8, 1), (np.uint16, 4)])
def test_kernel_equals_twin(cl_device, dtype, channels):
    from hdrcl.cl.warp import WarpProcessor

    rng = np.random.default_rng(1)
    h, w = 83, 131  # odd sizes
    top = np.iinfo(dtype).max
    frame = (rng.random((h, w, channels)) * top).astype(dtype)
    valid = rng.random((h, w)) > 0.02
    proc = WarpProcessor(ctx=cl_device)
    for name, m in _matrices(h, w).items():
        for v in (None, valid):
            got, gok, gcov = proc.warp(frame, m, v, strip_pixels=w * 9)  # several strips, a ragged last
            want = np.empty_like(frame)
            wok = np.empty((h, w), bool)
            wcov = np.empty((h, w), bool)
            for y0 in range(0, h, 20):
                want[y0:y0 + 20], wok[y0:y0 + 20], wcov[y0:y0 + 20] = W.warp_rows(frame, m, y0, min(h, y0 + 20), v)
            # masks: equal but for coordinates float32 puts on the other side of a border
            assert np.mean(gok != wok) < 2e-3 and np.mean(gcov != wcov) < 2e-3, name
            both = gcov & wcov
            d = np.abs(got.astype(np.int64) - want.astype(np.int64))[both]
            # float32: coordinates good to about 1e-5 px and sums of 16 taps to 1e-6 of
            # full scale; on noise that jumps full scale from pixel to pixel that is a code
            # rounded the other way now and then (16-bit: a few codes), never more
            tol = 1 + int(np.ceil(3e-5 * top))
            flips = 0.01 if dtype == np.uint8 else 0.15
            assert d.max(initial=0) <= tol and np.count_nonzero(d) <= flips * d.size, (name, d.max(initial=0))
            if name == "far away":
                assert not gcov.any() and not wcov.any()
            assert not got[~gcov].any()  # uncovered: 0
            if name == "integer shift":
                np.testing.assert_array_equal(got, want)
                np.testing.assert_array_equal(gok, wok)
            if name in ("similarity", "homography"):
                assert 0.5 < wcov.mean() < 1.0  # something was both kept and lost


def test_twin_reproduces_smooth_fields_exactly():
    """Keys' cubic reproduces quadratics: a warped quadratic ramp is the ramp at the
    source coordinates (to the rounding of the codes)."""
    h, w = 60, 90
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)

    def field(x, y):
        return 300.0 + 40.0 * x + 25.0 * y + 0.1 * x * x - 0.05 * x * y

    frame = np.round(field(xx, yy)).astype(np.uint16)[..., None]
    m = similarity(1.5, 1.01, 2.4, -3.7, h, w)
    out, ok = W.warp_frame(frame, m)
    sx, sy, _ = W.source_coords(m, yy, xx)
    truth = field(sx, sy)
    err = np.abs(out[..., 0].astype(np.float64) - truth)[ok]
    assert ok.mean() > 0.8 and err.max() < 1.5  # 0.5 (codes of the input) + 0.5 (of the output) + slack


def test_valid_masks_are_warped_conservatively():
    h, w = 40, 50
    frame = np.full((h, w, 3), 100, np.uint8)
    valid = np.ones((h, w), bool)
    valid[20, 25] = False
    _, ok = W.warp_frame(frame, W.translation(0.5, 0.5), valid)
    # out(y, x) reads rows y-1+0.5 .. : the 4x4 taps around (y + 0.5, x + 0.5)
    bad = np.argwhere(~ok[2:-3, 2:-3]) + 2
    assert {tuple(p) for p in bad} == {(y, x) for y in range(18, 22) for x in range(23, 27)}
    _, ok = W.warp_frame(frame, W.translation(1, 2), valid)  # whole pixels: exactly one pixel lost inside
    assert not ok[19, 23] and ok[1:-2, :-3].sum() == ok[1:-2, :-3].size - 1


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_crop_box_is_covered_and_maximal(seed):
    rng = np.random.default_rng(seed)
    h, w = 71, 97
    mats = [np.eye(3)] + [similarity(rng.uniform(-3, 3), 1 + rng.uniform(-0.03, 0.03), rng.uniform(-6, 6),
                                     rng.uniform(-6, 6), h, w) for _ in range(3)] + [W.translation(2, -3)]
    y0, y1, x0, x1 = W.crop_box((h, w), mats)
    frame = np.zeros((h, w, 1), np.uint8)
    cover = np.ones((h, w), bool)
    for m in mats:
        cover &= W.warp_frame(frame, m)[1]
    assert y1 > y0 and x1 > x0 and cover[y0:y1, x0:x1].all()
    for box in ((y0 - 1, y1, x0, x1), (y0, y1 + 1, x0, x1), (y0, y1, x0 - 1, x1), (y0, y1, x0, x1 + 1)):
        a, b, c, d = box
        if a < 0 or c < 0 or b > h or d > w:
            continue
        assert not cover[a:b, c:d].all()  # no side can grow


def test_crop_box_of_whole_pixel_shifts_is_exact():
    from hdrcl.core.align.mtb import crop_box as shift_box

    shifts = [(3, -5), (0, 0), (-7, 2)]
    assert W.crop_box((31, 47), [W.translation(dy, dx) for dy, dx in shifts]) == shift_box((31, 47), shifts)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_a_clipped_tap_makes_the_warped_channel_clipped(cl_device, dtype):
    """A lamp clipped in a long exposure, moved half a pixel: a channel blended from a
    clipped code (at or above fusion's clip level) comes out clipped, not as a made-up
    mid-range value fusion would trust; kernel and twin alike."""
    from hdrcl.cl.warp import WarpProcessor
    from hdrcl.core.weights import clip_levels

    top = int(np.iinfo(dtype).max)
    lo, hi = clip_levels(top + 1)
    frame = np.full((24, 32, 3), top // 2, dtype)
    frame[:, 16:, 0] = top           # red clipped from x = 16
    frame[:, 16:, 1] = hi            # green exactly at the clip level
    frame[:, 16:, 2] = hi - 1        # blue just below it: interpolated as usual
    m = W.translation(0.0, 0.5)      # reference x samples frame x + 0.5
    twin, ok_t = W.warp_frame(frame, m, clip_hi=hi)
    codes, ok_k, _ = WarpProcessor(ctx=cl_device).warp(frame, m, clip_hi=hi)
    np.testing.assert_array_equal(codes, twin)
    np.testing.assert_array_equal(ok_k, ok_t)
    row = twin[12, 8:24]
    # columns whose taps (x - 1 .. x + 2 around x + 0.5) reach x = 16 are clipped in red and green
    assert (row[6:, 0] == top).all() and (row[6:, 1] == top).all()
    assert (row[:6, 0] < hi).all()
    plain, _ = W.warp_frame(frame, m)  # without the rule: values between the two sides
    np.testing.assert_array_equal(twin[..., 2], plain[..., 2])  # blue: no tap clipped, interpolated
    assert plain[12, 8 + 7, 0] < hi


# ------------------------------------------------ no ringing, no fill blended in


@pytest.mark.parametrize("path", ["twin", "kernel"])
def test_a_hard_edge_does_not_ring(path, request):
    """A step from 20 to 240 moved by half a pixel: Keys' cubic alone overshoots both
    sides (by about 7 % of the step); each channel is held between its smallest and
    largest contributing tap, so no code leaves [20, 240] (the speckles of issue 27)."""
    h, w = 24, 40
    frame = np.full((h, w, 3), 20, np.uint8)
    frame[:, 20:] = 240
    frame[:, 20:, 2] = 120  # another step in another channel
    m = W.translation(0.3, 0.5)
    if path == "kernel":
        from hdrcl.cl.warp import WarpProcessor

        out, ok, _ = WarpProcessor(ctx=request.getfixturevalue("cl_device")).warp(frame, m, clip_hi=250)
    else:
        out, ok = W.warp_frame(frame, m, clip_hi=250)
    o = out[ok]
    assert o[:, :2].min() >= 20 and o[:, :2].max() <= 240
    assert o[:, 2].min() >= 20 and o[:, 2].max() <= 120
    assert len(np.unique(o[:, 0])) > 2  # still interpolated across the edge


def test_black_fill_is_masked_not_blended(cl_device):
    """A frame whose corner a rotation filled with black: warped again, no valid pixel
    is a blend of the fill (dark edges of odd colour), and fill inside the picture (a
    black object not touching the border) stays data."""
    from hdrcl.core.align.handheld import warp_one

    h, w = 60, 80
    frame = np.full((h, w, 3), (180, 140, 90), np.uint8)
    yy, xx = np.mgrid[0:h, 0:w]
    frame[(xx + yy) < 20] = 0  # the filled corner
    frame[30:34, 40:44] = 0  # a black object
    fill = W.border_fill(frame)
    assert fill[0, 0] and not fill[31, 41] and fill.sum() == ((xx + yy) < 20).sum()
    out, ok = warp_one(frame, W.translation(0.4, 0.6), None, None)
    near_fill = ok & ((xx + yy) < 26)
    assert near_fill.any() and out[near_fill].min() >= 90  # nothing darkened by the fill
    assert ok[31, 41]  # the object is data
