"""--deghost: a moving object leaves no double image; a static scene has no ghosts."""
import numpy as np
import pytest

from hdrcl.core import synthetic as s
from hdrcl.core.fusion import fuse_frames
from hdrcl.core.solve import recover_response

POS = [40 + 40 * k for k in range(5)]


@pytest.fixture(scope="module")
def moving():
    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
    rad = s.radiance_field(240, 321, decades=3.5, seed=3)
    times = s.stops(5, 1.5, centre=1.0 / float(np.median(rad)))
    frames = []
    for k, t in enumerate(times):
        scene = rad.copy()
        scene[100:130, POS[k]:POS[k] + 30] = np.median(rad) * 8  # a bright object moving right
        frames.append(s.bracket(scene, [t], cam, noise=0.5, seed=k)[0])
    return rad, times, frames, cam


def _ratio(radiance, rad, k):
    x = POS[k]
    return float(radiance[105:125, x + 5:x + 25].mean() / rad[105:125, x + 5:x + 25].mean())


def test_calibration_is_robust_to_the_moving_object(moving):
    rad, times, frames, cam = moving
    resp = recover_response(frames, times)
    z = np.arange(10, 246)
    for c in range(3):
        d = resp.tables()[c, z] - cam.g(z, c)
        assert np.max(np.abs(d - d.mean())) < 0.05


def test_no_double_image(moving, cl_device):
    rad, times, frames, _ = moving
    resp = recover_response(frames, times)
    plain = fuse_frames(frames, times, resp)
    clean = fuse_frames(frames, times, resp, deghost=True)
    # without: the object shows, faded, at other frames' positions
    # (at one of them the shortest frame reads mid-grey where the next reads black: the
    # noise-floor rule of issue 17 drops that contradicting frame, so >= 1, not >= 2)
    assert sum(_ratio(plain.radiance, rad, k) > 1.5 for k in range(5)) >= 1
    # with: only at the reference (middle exposure) position; background elsewhere
    for k in range(5):
        r = _ratio(clean.radiance, rad, k)
        assert (r > 4) if k == 2 else (abs(r - 1) < 0.1), (k, r)
    assert 0.03 < clean.ghost_mask.mean() < 0.08
    assert clean.counts["ghost"] == int(clean.ghost_mask.sum())


def test_static_scene_has_no_ghosts(scene, cl_device):
    resp = recover_response(scene["frames"], scene["times"])
    res = fuse_frames(scene["frames"], scene["times"], resp, deghost=True)
    assert res.ghost_mask.mean() < 0.002


def test_streaming_deghost_matches_in_memory(moving, cl_device):
    from hdrcl.core.pipeline import ArraySink, ArraySource, stream_merge

    rad, times, frames, _ = moving
    resp = recover_response(frames, times)
    whole = fuse_frames(frames, times, resp, deghost=True)
    sink = ArraySink(*frames[0].shape)
    mask = np.zeros(frames[0].shape[:2], bool)
    counts, _ = stream_merge(ArraySource(frames, [None] * 5), times, resp, sink, deghost=True, ghost_mask=mask)
    # strips are dilated separately, so only rows at strip seams may differ
    assert (mask != whole.ghost_mask).mean() < 0.002
    assert abs(counts["ghost"] - whole.counts["ghost"]) <= 0.02 * whole.counts["ghost"]


def test_strip_seams_grow_like_the_whole_image(monkeypatch, cl_device):
    """A ghost straddling a strip seam grows across it exactly as in one piece."""
    import hdrcl.cl.processing as proc
    import hdrcl.core.pipeline as pl
    from hdrcl.cl.backend import _processors
    from hdrcl.core.pipeline import ArraySink, ArraySource, stream_merge

    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
    rad = s.radiance_field(64, 64, decades=2.0, seed=5)
    times = s.stops(3, 1.5, centre=1.0 / float(np.median(rad)))
    frames = []
    for k, t in enumerate(times):
        scene = rad.copy()
        if k == 2:
            scene[29:32, 20:30] *= 20  # only in the longest frame, across the seam at row 32
        frames.append(s.bracket(scene, [t], cam, noise=0.3, seed=k)[0])
    resp = recover_response(frames, times, samples=300)
    whole = fuse_frames(frames, times, resp, deghost=True)
    monkeypatch.setattr(proc, "STRIP_PIXELS", 64 * 32)
    monkeypatch.setattr(pl, "NUMPY_STRIP_PIXELS", 64 * 32)
    _processors.clear()
    mask = np.zeros((64, 64), bool)
    sink = ArraySink(64, 64, 3)
    stream_merge(ArraySource(frames, [None] * 3), times, resp, sink, deghost=True, ghost_mask=mask)
    _processors.clear()
    np.testing.assert_array_equal(mask, whole.ghost_mask)
    assert mask[32:34].any()  # the growth did cross the seam
    np.testing.assert_allclose(sink.array, whole.radiance, rtol=2e-5)


def _night(toe, shoulder):
    """The night scene of scripts/deghost_bench.py and a response wrong in the toe and
    shoulder as calibrated curves are (ln units at code 10 and at the top)."""
    from hdrcl.core.response import Response, knot_positions

    sc = s.night_scene(360, 480, seed=1)
    z = np.arange(256.0)
    err = toe * np.clip((60 - z) / 50, 0, 1) ** 2 + shoulder * np.clip((z - 180) / 75, 0, 1) ** 2
    g = np.stack([sc.camera.g(np.clip(z, 0.5, 254.5), c) for c in range(3)]) + err
    return sc, Response(bits=8, g=g, knots=knot_positions(8))


@pytest.mark.parametrize("toe,shoulder", [(-0.3, 0.4), (0.3, -0.4)])
def test_deghost_leaves_no_darker_blotches(toe, shoulder, cl_device):
    """Issue 32 item 6: ghost pixels took the reference frame's raw estimate, in its toe
    where the curve is wrong, with a hard edge: blotches darker than both the truth and
    the plain merge. Corrected by the learnt bias of the code read and blended over the
    grown rings, none is more than 20 % darker (before: 15 and 0 pixels), and the moving leaves are
    still caught."""
    sc, resp = _night(toe, shoulder)
    plain = fuse_frames(sc.frames, sc.times, resp).radiance
    res = fuse_frames(sc.frames, sc.times, resp, deghost=True)
    truth = sc.truth[len(sc.frames) // 2]
    assert res.ghost_mask.mean() > 0.001
    darker = (res.radiance < 0.8 * np.minimum(truth, plain)).any(axis=2)
    assert darker.sum() == 0, int(darker.sum())
    assert np.isfinite(res.radiance).all()


def test_feathered_edge_and_read_bias(cl_device):
    """The grown rings blend the two values (1/3, 2/3, then 1 inward); a bool mask is
    replaced whole, and the estimate is corrected by ``read_bias``."""
    from hdrcl.core import deghost as dg

    mask = np.zeros((15, 15), bool)
    mask[7, 7] = True
    grown = dg.feather(__import__("scipy").ndimage.binary_dilation(mask, iterations=dg.GROW))
    assert grown[7, 7] == 1 and abs(grown[7, 5] - 1 / 3) < 1e-6 and abs(grown[7, 6] - 2 / 3) < 1e-6
    assert grown[7, 4] == 0
    tables = np.tile(np.log(np.arange(1, 257.0))[None], (1, 1))
    frames = [np.full((1, 2, 1), 100, np.uint8)]
    model = dg.GhostModel(bias=np.zeros((1, 1, dg.BINS)), spread=np.ones((1, 1, dg.BINS)),
                          read_bias=np.full((1, 1, dg.BINS), 0.5))
    rad = np.full((1, 2, 1), 50.0, np.float32)
    dg.replace(rad, frames, [0.0], tables, np.array([[1.0, 0.5]], np.float32), None, 0, model)
    want = np.log(101.0) - 0.5
    np.testing.assert_allclose(np.log(rad[0, :, 0]), [want, 0.5 * want + 0.5 * np.log(50.0)], rtol=1e-5)


def test_ghost_kernel_matches_twin(cl_device):
    """``ghost_raw`` (kernels/fusion.cl) marks the pixels its NumPy twin
    (:func:`hdrcl.core.deghost.departures`) marks, with invalid pixels, on an odd size."""
    from hdrcl.cl.backend import get_processor
    from hdrcl.core import deghost as dg
    from hdrcl.core import reference
    from hdrcl.core.pipeline import fusion_tables

    sc, resp = _night(-0.3, 0.4)
    frames = [f[:151, :227] for f in sc.frames]
    valid = [None, np.arange(151 * 227).reshape(151, 227) % 7 != 0, None, None, None]
    lt = np.log(sc.times)
    tables, wts = fusion_tables(resp, np.uint8, 3)
    model = dg.learn(frames, lt, tables, wts, valid)
    fused = reference.fuse(frames, lt, tables, wts, valid)[0].astype(np.float32)
    twin = dg.departures(frames, lt, tables, valid, fused, model)
    knl = get_processor("fusion").ghost_departures(frames, valid, fused, dg.ghost_tables(lt, tables, model))
    assert twin.sum() > 50
    assert (twin != knl).sum() <= 2  # float32 against float64 at the threshold
