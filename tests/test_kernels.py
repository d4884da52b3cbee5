"""OpenCL kernels held to their NumPy twins (float32 tolerance), and both to the truth."""
import numpy as np
import pytest

from hdrcl.core import reference as ref
from hdrcl.core import synthetic as s
from hdrcl.core.solve import recover_response
from hdrcl.core.weights import weight_table

RTOL = 2e-5  # float32 arithmetic over a few dozen terms, then exp


def _odd_bracket(bits=8, h=31, w=47, channels=3, seed=0):
    cam = s.Camera(a=1.0, x0=(1.0, 1.3, 0.7)[:channels], bits=bits)
    rad = s.radiance_field(h, w, decades=5.0, channels=channels, seed=seed)
    times = s.stops(5, 2.0, centre=1.0 / float(np.median(rad)))
    return cam, rad, times, s.bracket(rad, times, cam, noise=0.7, seed=seed + 1)


def _tables(cam, channels, bits):
    levels = 1 << bits
    z = np.arange(levels, dtype=np.float64)
    z = np.clip(z, 0.5, levels - 1.5)  # g is infinite at the ends of a logistic camera
    return np.stack([cam.g(z, c) for c in range(channels)])


@pytest.mark.parametrize("bits,channels", [(8, 3), (8, 1), (16, 3)])
def test_fusion_kernel_matches_twin_on_odd_sizes(cl_device, bits, channels):
    from hdrcl.cl.fusion import FusionProcessor

    cam, rad, times, frames = _odd_bracket(bits=bits, channels=channels)
    tables = _tables(cam, channels, bits)
    w = weight_table(1 << bits)
    rng = np.random.default_rng(3)
    valid = [rng.random(frames[0].shape[:2]) > 0.1 for _ in frames]
    valid[2][:3, :5] = False
    for v in valid:
        v[0, 0] = False  # one pixel valid nowhere
    proc = FusionProcessor(ctx=cl_device, strip_pixels=200)  # several strips, ragged last one
    got, counts = proc.fuse(frames, np.log(times), tables, w, valid)
    want, wcounts = ref.fuse(frames, np.log(times), tables, w, valid)
    assert got.dtype == np.float32 and got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=0)
    assert counts == wcounts
    assert counts["no_data"] == channels
    assert np.all(np.isfinite(got))


@pytest.mark.parametrize("w,strip", [(3, 3), (5, 5), (9, 18)])  # strips of 3, 5 and 18 pixels
def test_fusion_kernel_ragged_strip_ends(cl_device, w, strip):
    """Strips whose pixel count is not a multiple of 4 (or below 4): the last pixels go
    through fuse_tail, and must equal the twin like the rest."""
    from hdrcl.cl.fusion import FusionProcessor

    cam, rad, times, frames = _odd_bracket(h=7, w=w, seed=4)
    tables = _tables(cam, 3, 8)
    wt = weight_table(256)
    valid = [np.random.default_rng(k).random(frames[0].shape[:2]) > 0.2 for k in range(len(frames))]
    proc = FusionProcessor(ctx=cl_device, strip_pixels=strip)
    for vv in (None, valid):
        got, counts = proc.fuse(frames, np.log(times), tables, wt, vv)
        want, wcounts = ref.fuse(frames, np.log(times), tables, wt, vv)
        np.testing.assert_allclose(got, want, rtol=RTOL, atol=0)
        assert counts == wcounts


def test_zero_weight_rule(cl_device):
    """Clipped high everywhere -> shortest frame at the top code; black -> longest at 0."""
    from hdrcl.cl.fusion import FusionProcessor

    cam = s.Camera(a=1.0, x0=(1.0,))
    tables = _tables(cam, 1, 8)
    w = weight_table(256)
    times = np.array([0.01, 0.1, 1.0])
    f = [np.full((3, 5, 1), 128, np.uint8) for _ in times]
    for fr in f:
        fr[0, :, 0] = 255
        fr[1, :, 0] = 0
    want, counts = ref.fuse(f, np.log(times), tables, w)
    got, gcounts = FusionProcessor(ctx=cl_device).fuse(f, np.log(times), tables, w)
    np.testing.assert_allclose(got, want, rtol=RTOL)
    assert counts == gcounts == {"clipped_high": 5, "clipped_low": 5, "no_data": 0}
    np.testing.assert_allclose(want[0, :, 0], np.exp(tables[0, 255] - np.log(0.01)))
    np.testing.assert_allclose(want[1, :, 0], np.exp(tables[0, 0] - np.log(1.0)))
    assert np.all(got > 0) and np.all(np.isfinite(got))


@pytest.mark.parametrize("out_bits", [8, 16])
def test_exposure_kernel_matches_twin(cl_device, out_bits):
    from hdrcl.cl.exposure import ExposureProcessor

    cam, rad, times, frames = _odd_bracket()
    tables = _tables(cam, 3, 8)
    tables[1, 100:104] = tables[1, 100]  # a plateau: inversion must not divide by zero
    r = rad.astype(np.float32)
    r[0, 0, 0] = 0.0
    r[0, 1, 0] = np.nan
    r[0, 2, 0] = np.inf
    r[0, 3, 0] = -1.0
    proc = ExposureProcessor(ctx=cl_device, strip_pixels=300)
    got = proc.expose(r, ref.monotone_tables(tables), float(np.log(times[2])), out_bits)
    want = ref.expose(r, tables, float(np.log(times[2])), out_bits)
    assert got.dtype == want.dtype
    diff = np.abs(got.astype(np.int64) - want.astype(np.int64))
    assert diff.max() <= 1  # float32 vs float64 at a rounding boundary
    # float32 log/interpolation puts z within ~1e-4 levels of float64; at 16-bit output
    # that is scaled by 257 before rounding, so more values sit near a boundary
    assert (diff > 0).mean() < (1e-3 if out_bits == 8 else 1e-2)
    assert got[0, 0, 0] == 0 and got[0, 1, 0] == 0 and got[0, 3, 0] == 0
    assert got[0, 2, 0] == (1 << out_bits) - 1


def test_expose_inverts_the_camera():
    """Twin against the truth: rendering true radiance through the true curve gives the photo."""
    cam, rad, times, _ = _odd_bracket()
    clean = s.bracket(rad, times, cam, noise=0.0, seed=0)
    tables = _tables(cam, 3, 8)
    for t, photo in zip(times, clean):
        img = ref.expose(rad, tables, float(np.log(t)))
        inner = (photo > 2) & (photo < 253)
        assert np.abs(img.astype(int) - photo.astype(int))[inner].max() <= 1


def test_fusion_recovers_true_radiance(scene):
    """Twin against the truth with a recovered curve: median error < 2 % on well-exposed pixels."""
    resp = recover_response(scene["frames"], scene["times"])
    order = np.argsort(scene["times"])
    rad, counts = ref.fuse([scene["frames"][i] for i in order], np.log(scene["times"][order]),
                           resp.tables(), weight_table(256))
    truth = scene["radiance"]
    well = np.zeros(truth.shape, bool)
    for f in scene["frames"]:
        well |= (f >= 26) & (f <= 230)
    for c in range(3):
        ratio = rad[..., c][well[..., c]] / truth[..., c][well[..., c]]
        err = np.median(np.abs(ratio / np.median(ratio) - 1))
        assert err < 0.02
    assert counts["no_data"] == 0


def test_opencl_merge_of_synthetic_scene_matches_truth(cl_device, scene):
    import hdrcl

    rad = hdrcl.merge(scene["frames"], scene["times"])
    truth = scene["radiance"]
    ratio = rad / truth
    k = np.median(ratio, axis=(0, 1))
    assert np.median(np.abs(ratio / k - 1)) < 0.02


def test_kernel_matches_twin_on_memorial(cl_device, memorial_bracket):
    from hdrcl.cl.fusion import FusionProcessor

    br = memorial_bracket
    resp = recover_response(br.frames, br.times, valid=br.valid_all, samples=500)
    order = np.argsort(br.times)
    frames = [br.frames[i] for i in order]
    valid = [br.valid[i] for i in order]
    w = weight_table(256)
    got, gc = FusionProcessor(ctx=cl_device).fuse(frames, np.log(br.times[order]), resp.tables(), w, valid)
    want, wc = ref.fuse(frames, np.log(br.times[order]), resp.tables(), w, valid)
    np.testing.assert_allclose(got, want, rtol=RTOL)
    assert gc == wc
    # the paper: the Memorial map spans more than five orders of magnitude
    lum = got.mean(axis=2)
    lo, hi = np.percentile(lum[lum > 0], [0.1, 99.9])
    assert hi / lo > 1e4


# --- issue 17: clipping consistent across exposures (rule: hdrcl.core.reference.fuse) -----

def _messy_bracket(bits, nch, nframes, h=23, w=37, seed=0):
    """Every case of the clipping rule: clipped and black runs, codes at and around the
    noise floor and the clip level, frames out of order (flicker, motion: codes anywhere),
    invalid samples, a pixel valid nowhere."""
    rng = np.random.default_rng(seed)
    cam = s.Camera(a=1.0, x0=(1.0, 1.3, 0.7)[:nch], bits=bits)
    rad = s.radiance_field(h, w, decades=6.0, channels=nch, seed=seed)
    times = s.stops(nframes, 1.0 if nframes > 8 else 2.0, centre=1.0 / float(np.median(rad)))
    frames = s.bracket(rad, times, cam, noise=1.5, seed=seed + 1)
    top = (1 << bits) - 1
    zc = int(round(250 * top / 255))
    lo = top - zc
    edges = np.array([0, 1, lo - 1, lo, lo + 1, zc - 1, zc, zc + 1, top - 1, top])
    for f in frames:
        m = rng.random(f.shape) < 0.08
        f[m] = rng.choice(edges, int(m.sum()))
        m = rng.random(f.shape) < 0.03
        f[m] = rng.integers(0, top + 1, int(m.sum()))
    valid = [rng.random((h, w)) > 0.1 for _ in frames]
    for v in valid:
        v[0, 1] = False
    return frames, np.log(times), _tables(cam, nch, bits), valid


@pytest.mark.parametrize("bits,nch,nframes", [(8, 3, 2), (8, 3, 5), (8, 1, 3), (16, 3, 4), (8, 3, 12),
                                              (8, 3, 13), (8, 3, 16), (8, 3, 17), (16, 1, 14), (8, 1, 20)])
def test_fusion_kernel_matches_twin_on_clipped_brackets(cl_device, bits, nch, nframes):
    """Up to 12 frames the fast path tests clip order by bit patterns, up to 16 by counts
    and index sums, beyond that it walks per sample; values out of order go to fuse_fix:
    every path equals the twin, clip mask included."""
    from hdrcl.cl.fusion import FusionProcessor

    frames, log_t, tables, valid = _messy_bracket(bits, nch, nframes)
    w = weight_table(1 << bits, "gaussian")
    proc = FusionProcessor(ctx=cl_device, strip_pixels=300)  # several strips, ragged ends
    for vv in (None, valid):
        mask_k = np.full(frames[0].shape[:2], 7, np.uint8)
        mask_t = np.full(frames[0].shape[:2], 7, np.uint8)
        got, gc = proc.fuse(frames, log_t, tables, w, vv, clip_mask=mask_k)
        want, wc = ref.fuse(frames, log_t, tables, w, vv, clip_mask=mask_t)
        np.testing.assert_allclose(got, want, rtol=RTOL, atol=0)
        assert gc == wc
        np.testing.assert_array_equal(mask_k, mask_t)
        assert wc["clipped_high"] > 0 and wc["clipped_low"] > 0
        assert (mask_t & 1).any() and (mask_t & 2).any() and mask_t.max() <= 3
        assert np.all(np.isfinite(got))


def test_fusion_clip_levels(cl_device):
    """Codes 5 / 250 (8-bit) and 1285 / 64250 (16-bit) are the floor and the clip: a
    shortest frame reading 249 is measured, 250 is a bound; a longest frame reading 6 is
    measured, 5 is a bound -- the same in kernel and twin."""
    from hdrcl.cl.fusion import FusionProcessor, clip_codes
    from hdrcl.core.weights import clip_levels

    for levels in (256, 1024, 65536):
        assert clip_codes(levels) == clip_levels(levels)
    for bits in (8, 16):
        levels = 1 << bits
        lo, hi = clip_levels(levels)
        cam = s.Camera(a=1.0, x0=(1.0,), bits=bits)
        tables = _tables(cam, 1, bits)
        dt = np.uint8 if bits == 8 else np.uint16
        times = np.array([0.01, 0.1, 1.0])
        mid = levels // 2
        short = np.array([hi - 1, hi, hi + 1, levels - 1, mid, mid, mid, mid], dt)
        long_ = np.array([levels - 1] * 4 + [lo - 1, lo, lo + 1, mid], dt)
        f = [short.reshape(1, 8, 1), np.full((1, 8, 1), 0, dt), long_.reshape(1, 8, 1)]
        f[1][0, :4, 0] = levels - 1
        f[1][0, 4:, 0] = np.array([0, 0, 0, mid])
        w = weight_table(levels)
        want, wc = ref.fuse(f, np.log(times), tables, w)
        got, gc = FusionProcessor(ctx=cl_device).fuse(f, np.log(times), tables, w)
        np.testing.assert_allclose(got, want, rtol=RTOL)
        assert gc == wc == {"clipped_high": 3, "clipped_low": 2, "no_data": 0}
        np.testing.assert_allclose(want[0, 0, 0], np.exp(tables[0, hi - 1] - np.log(0.01)))  # measured
        np.testing.assert_allclose(want[0, 1:4, 0], np.exp(tables[0, [hi, hi + 1, levels - 1]] - np.log(0.01)))
        np.testing.assert_allclose(want[0, 4:6, 0], np.exp(tables[0, [lo - 1, lo]] - np.log(1.0)))
        np.testing.assert_allclose(want[0, 6, 0], np.exp(tables[0, lo + 1] - np.log(1.0)))  # measured


def test_fusion_strip_api_with_and_without_clip_mask(cl_device):
    from hdrcl.cl.fusion import FusionProcessor

    frames, log_t, tables, _ = _messy_bracket(8, 3, 4, h=5, w=9)
    plan = FusionProcessor(ctx=cl_device).plan(len(frames), 9, 3, np.uint8, log_t, tables, weight_table(256), False)
    out = np.empty((5, 9, 3), np.float32)
    plan.fuse_strip(frames, None, out)  # the signature before issue 17
    out2 = np.empty((5, 9, 3), np.float32)
    mask = np.full((5, 9), 9, np.uint8)
    plan.fuse_strip(frames, None, out2, clip_mask=mask)
    np.testing.assert_array_equal(out, out2)
    tmask = np.zeros((5, 9), np.uint8)
    want, _ = ref.fuse(frames, log_t, tables, weight_table(256), clip_mask=tmask)
    np.testing.assert_allclose(out, want, rtol=RTOL)
    np.testing.assert_array_equal(mask, tmask)
    # a strip with nothing to fix still clears the mask
    calm = [np.full((5, 9, 3), 128, np.uint8) for _ in frames]
    plan.fuse_strip(calm, None, out, clip_mask=mask)
    assert not mask.any()


def test_fusion_twin_keeps_highlight_hue():
    """A channel clipped in every frame is not darker than the pixel's measured channels,
    and a pixel clipped in every channel is neutral (hdrcl.core.reference.fuse)."""
    cam = s.Camera(a=1.0, x0=(1.0, 1.3, 0.7))
    tables = _tables(cam, 3, 8)
    times = np.array([0.01, 0.1])
    f = [np.array([[[255, 120, 60], [255, 254, 252]]], np.uint8), np.array([[[255, 250, 200], [255, 255, 255]]], np.uint8)]
    out, counts = ref.fuse(f, np.log(times), tables, weight_table(256))
    assert counts["clipped_high"] == 4
    g_meas = np.exp(tables[1, 120] - np.log(0.01))
    assert out[0, 0, 0] == pytest.approx(max(np.exp(tables[0, 255] - np.log(0.01)), g_meas, out[0, 0, 2]))
    assert out[0, 0, 0] >= out[0, 0, 1] >= out[0, 0, 2]
    bounds = np.exp(tables[[0, 1, 2], [255, 254, 252]] - np.log(0.01))
    np.testing.assert_allclose(out[0, 1], bounds.max())


@pytest.mark.parametrize("shift", [0, 1, 37, 127])
def test_fusion_in_place_at_any_address(cl_device, shift):
    """Frames, output and clip mask at addresses that are not aligned (the kernels use
    the host's memory in place, from the aligned address below each strip): equal to
    the twin, and nothing written outside the output and the mask."""
    from hdrcl.cl.fusion import FusionProcessor

    frames, log_t, tables, _ = _messy_bracket(8, 3, 6, h=29, w=41, seed=5)
    h, w, c = frames[0].shape
    n = h * w * c

    def at(k, a):  # a copy of `a` that starts k bytes after a 128-byte boundary
        raw = np.zeros(a.nbytes + 512, np.uint8)
        start = (-raw.ctypes.data) % 128 + k
        v = raw[start:start + a.nbytes].view(a.dtype).reshape(a.shape)
        v[...] = a
        return v

    moved = [at((shift + 13 * j) % 128, f) for j, f in enumerate(frames)]
    out_raw = np.full(n + 64, 7.0, np.float32)
    out = out_raw[shift % 32:shift % 32 + n].reshape(h, w, c)
    mask_raw = np.full(h * w + 256, 9, np.uint8)
    mask = mask_raw[shift:shift + h * w].reshape(h, w)
    w8 = weight_table(256, "gaussian")
    proc = FusionProcessor(ctx=cl_device, strip_pixels=7 * w + 3)  # strips start at odd rows
    got, gc = proc.fuse(moved, log_t, tables, w8, out=out, clip_mask=mask)
    tmask = np.zeros((h, w), np.uint8)
    want, wc = ref.fuse(frames, log_t, tables, w8, clip_mask=tmask)
    assert got is out
    np.testing.assert_allclose(out, want, rtol=RTOL, atol=0)
    assert gc == wc
    np.testing.assert_array_equal(mask, tmask)
    assert (out_raw[:shift % 32] == 7.0).all() and (out_raw[shift % 32 + n:] == 7.0).all()
    assert (mask_raw[:shift] == 9).all() and (mask_raw[shift + h * w:] == 9).all()


def test_fusion_every_pixel_to_fix(cl_device):
    """A strip where every pixel goes to fuse_fix (codes in random order across the
    frames): the list of pixels to fix holds them all, and the result is the twin's."""
    from hdrcl.cl.fusion import FusionProcessor

    rng = np.random.default_rng(11)
    frames = [rng.choice(np.array([0, 3, 128, 252, 255], np.uint8), (40, 50, 3)) for _ in range(5)]
    frames[0][...] = 255  # the shortest frame clipped, longer ones in range: out of order everywhere
    log_t = np.log(np.array([0.01, 0.02, 0.04, 0.08, 0.16]))
    cam = s.Camera(a=1.0, x0=(1.0, 1.3, 0.7))
    tables = _tables(cam, 3, 8)
    w8 = weight_table(256)
    mask_k = np.zeros((40, 50), np.uint8)
    mask_t = np.zeros((40, 50), np.uint8)
    got, gc = FusionProcessor(ctx=cl_device).fuse(frames, log_t, tables, w8, clip_mask=mask_k)
    want, wc = ref.fuse(frames, log_t, tables, w8, clip_mask=mask_t)
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=0)
    assert gc == wc and wc["clipped_high"] == 40 * 50 * 3
    np.testing.assert_array_equal(mask_k, mask_t)


def test_profile_kernel_on_a_bracket_that_is_all_fix_up(cl_device):
    """profile_kernel's fix list was npix bytes for npix ints and never emptied between
    repeats: an all-black bracket (every pixel on the list) crashed the process."""
    from hdrcl.cl.backend import get_processor
    from hdrcl.cl.fusion import profile_kernel
    from hdrcl.core.weights import weight_table

    proc = get_processor("fusion")
    frames = [np.zeros((300, 400, 3), np.uint8)] * 3
    z = np.arange(256, dtype=np.float64)
    tables = np.stack([np.log(np.maximum(z, 0.5) / 128.0)] * 3)
    seconds = profile_kernel(proc, frames, np.log([0.25, 1.0, 4.0]), tables, weight_table(256), repeats=3)
    assert np.isfinite(seconds) and seconds > 0
