"""Quality figures (hdrcl.quality.measure) on synthetic scenes with known truth."""
import json

import numpy as np
import pytest

from hdrcl.core import synthetic as s
from hdrcl.core.bracket import Bracket, load_bracket
from hdrcl.core.merge import merge_bracket
from hdrcl.report.quality import (
    NO_DATA,
    QualityFigures,
    decimate,
    dynamic_range_stops,
    measure,
)

CAM = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))


def exposure_at(code: float, cam: s.Camera = CAM) -> np.ndarray:
    """Per channel, the exposure X at which ``cam`` reads ``code`` (before rounding)."""
    f = code / (cam.levels - 1)
    return np.array([x0 * (1.0 / f - 1.0) ** (-1.0 / cam.a) for x0 in cam.x0])


@pytest.fixture(scope="module")
def clean(scene):
    """The conftest scene (4.5 decades, 7 frames 2 stops apart), merged: nothing clipped."""
    br = load_bracket(scene["frames"], scene["times"])
    return br, merge_bracket(br)


def test_unclipped_scene(clean, scene):
    br, res = clean
    fig = measure(br, res.response, res.radiance, loo=False)
    # The same percentiles of the true luminance; the scene spans 4.5 decades end to end.
    truth = dynamic_range_stops(scene["radiance"])
    assert truth < 4.5 * np.log2(10.0)
    assert fig.dynamic_range_stops == pytest.approx(truth, abs=0.3)
    assert not fig.dynamic_range_is_lower_bound
    assert fig.clipped_high_fraction == fig.clipped_low_fraction == 0.0
    assert fig.extra_ev_high == fig.extra_ev_low == 0.0
    h, w = scene["radiance"].shape[:2]
    assert fig.coverage.shape == (h, w) and fig.coverage.dtype == np.uint8
    assert fig.coverage.min() >= 1 and fig.coverage.max() <= 7
    assert sum(fig.coverage_histogram) == fig.valid_pixels == h * w
    assert [e["nominal"] for e in fig.exposures] == pytest.approx(list(scene["times"]))
    assert fig.loo == [] and fig.loo_rmse is None


def test_leave_one_out_small_on_clean_set(clean):
    br, res = clean
    fig = measure(br, res.response, res.radiance, loo_max_pixels=6000)
    assert fig.loo_stride == 2  # 120 x 160 = 19200 pixels -> every 2nd row and column
    assert len(fig.loo) == 5  # the interior frames
    assert all(r.pixels > 1000 for r in fig.loo)
    assert fig.loo_rmse < 1.5  # 8-bit levels; noise is 0.5 levels


def test_decimate():
    frames = [np.zeros((31, 47, 3), np.uint8), np.ones((31, 47, 3), np.uint8)]
    valid = [np.ones((31, 47), bool), None]
    br = Bracket(frames=frames, times=np.array([1.0, 2.0]), valid=valid)
    assert decimate(br, 31 * 47) == (br, 1)
    sub, k = decimate(br, 400)
    assert k == 2 and sub.frames[0].shape == (16, 24, 3) and sub.valid[0].shape == (16, 24)
    assert sub.valid[1] is None and list(sub.times) == [1.0, 2.0]


@pytest.mark.parametrize("bits", [8, 16])
def test_clipped_scene(bits):
    """A bright block clipped in every frame and a dark block black in every frame.

    The fractions are the blocks' areas exactly. The extra exposures are bounds: a
    frame must be at least that much shorter (longer) than the bracket to read the
    blocks in the working range, whatever their true radiance -- so the bound is the
    same for a block 1 or 4 stops beyond the clip point, and the truth, known here, is
    always beyond it. It is also no larger than the true camera's own shoulder (toe):
    the distance from code 245 (10) to the clip point.
    """
    cam = s.Camera(a=CAM.a, x0=CAM.x0, bits=bits)
    zmax = cam.levels - 1
    top, bot = 245.5 * zmax / 255, 9.5 * zmax / 255  # read at most 245 / at least 10
    h, w = 61, 83
    base = s.radiance_field(h, w, decades=2.5, seed=3)
    times = s.stops(5, 2.0, centre=1.0 / float(np.median(base)))
    ts, tl = times.min(), times.max()
    clip_high = exposure_at(zmax - 0.5, cam).max()  # reads Zmax at or above (no noise)
    clip_low = exposure_at(0.5, cam).min()  # reads 0 below
    assert base.max() * ts < exposure_at(top, cam).min() and base.min() * tl > exposure_at(bot, cam).max()
    bright, dark = (slice(5, 25), slice(10, 40)), (slice(40, 55), slice(50, 75))
    area_b, area_d = 20 * 30, 15 * 25
    bounds = {}
    for beyond in (1.0, 4.0):
        rad = base.copy()
        rad[bright] = clip_high * 2.0 ** beyond / ts
        rad[dark] = clip_low / 2.0 ** beyond / tl
        frames = s.bracket(rad, times, cam, noise=0.0)
        br = load_bracket(frames, times)
        res = merge_bracket(br)
        fig = measure(br, res.response, res.radiance, loo=False)

        assert fig.clipped_high_pixels == area_b and fig.clipped_high_fraction == area_b / (h * w)
        assert fig.clipped_low_pixels == area_d and fig.clipped_low_fraction == area_d / (h * w)
        assert (fig.coverage[bright] == 0).all() and (fig.coverage[dark] == 0).all()
        assert (np.count_nonzero(fig.coverage == 0)) == area_b + area_d
        assert fig.coverage_histogram[0] == area_b + area_d
        assert fig.dynamic_range_is_lower_bound

        # Truth: the change a new frame needs for the block to read in the working range.
        need_high = np.log2(exposure_at(top, cam) / (rad[bright][0, 0] * ts)).min()
        need_low = np.log2(exposure_at(bot, cam) / (rad[dark][0, 0] * tl)).max()
        assert need_high < -beyond and need_low > beyond
        assert need_high <= fig.extra_ev_high < -1.0
        assert 1.0 < fig.extra_ev_low <= need_low
        shoulder = np.log2(exposure_at(top, cam) / exposure_at(zmax - 0.5, cam)).min()
        toe = np.log2(exposure_at(bot, cam) / exposure_at(0.5, cam)).max()
        assert shoulder <= fig.extra_ev_high and fig.extra_ev_low <= toe
        bounds[beyond] = (fig.extra_ev_high, fig.extra_ev_low)
    assert bounds[1.0] == pytest.approx(bounds[4.0], abs=1e-6)


def test_invalid_pixels_and_json(scene):
    frames, times = scene["frames"][:4], scene["times"][:4]
    h, w = frames[0].shape[:2]
    hole = np.ones((h, w), bool)
    hole[:10, :20] = False  # invalid in every frame
    valid = [hole.copy() for _ in frames]
    valid[0][50:60, :] = False  # the shortest frame misses a strip: longer frames stand in
    br = load_bracket(frames, times, valid=valid)
    res = merge_bracket(br)
    fig = measure(br, res.response, res.radiance, loo=False)
    assert fig.valid_pixels == h * w - 200
    assert (fig.coverage[:10, :20] == NO_DATA).all() and (fig.coverage[10:] != NO_DATA).all()
    assert sum(fig.coverage_histogram) == fig.valid_pixels
    # This 4-frame subset (-6..0 stops) leaves the darkest part of the scene black.
    assert fig.clipped_low_fraction > 0 and fig.extra_ev_low > 0

    d = json.loads(json.dumps(fig.to_dict(), allow_nan=False))
    back = QualityFigures.from_dict(d)
    assert back.to_dict() == d and back.coverage is None


def test_clipping_counts_the_clip_levels(clean):
    """A block that reads 252 in every frame is clipped (JPEG highlights clip anywhere in
    250..255), and one at 3 is black: the report counts what fusion counts, by
    :func:`hdrcl.core.weights.clip_levels`, not only 0 and 255."""
    from hdrcl.core.weights import clip_levels

    br, res = clean
    lo, hi = clip_levels(256)
    frames = [f.copy() for f in br.frames]
    bright, dark = (slice(5, 25), slice(10, 40)), (slice(60, 75), slice(100, 125))
    for f in frames:
        f[bright] = hi + 2  # inside the clip band, not the top code
        f[dark] = lo - 2
    assert 0 < lo - 2 and hi + 2 < 255
    edited = Bracket(frames=frames, times=br.times, valid=br.valid)
    fig = measure(edited, res.response, None, loo=False)
    area_b, area_d = 20 * 30, 15 * 25
    assert fig.clipped_high_pixels == area_b and fig.clipped_low_pixels == area_d
    assert (fig.coverage[bright] == 0).all() and (fig.coverage[dark] == 0).all()
    assert fig.coverage_histogram[0] == area_b + area_d
    # Fusion's own count of the pixel-channels it had to bound agrees.
    fused = merge_bracket(edited, res.response)
    assert fused.counts["clipped_high"] == 3 * area_b and fused.counts["clipped_low"] == 3 * area_d


def test_a_later_frame_after_a_clip_is_no_evidence(clean):
    """Once a shorter frame clips, a longer one reading mid-range (a moving light) is not a
    measurement, as in fusion: coverage counts the frames fusion really uses."""
    br, res = clean
    order = np.argsort(br.times)
    frames = [f.copy() for f in br.frames]
    frames[order[0]][:4, :4] = 254  # the shortest frame clips
    for j in order[1:]:
        frames[j][:4, :4] = 120  # ... the longer ones read mid-range
    fig = measure(Bracket(frames=frames, times=br.times, valid=br.valid), res.response, None, loo=False)
    assert (fig.coverage[:4, :4] == 0).all() and fig.clipped_high_pixels == 16


# ------------------------------------------------------------------ verdicts


@pytest.mark.parametrize("key", ["loo", "clipped", "coverage"])
def test_verdict_boundaries(key):
    """Each limit belongs to the better verdict; just above it, the worse one."""
    from hdrcl.report.verdicts import FAIL, PASS, THRESHOLDS, WARN, grade

    t = {t.key: t for t in THRESHOLDS}[key]
    assert 0 < t.warn_above < t.fail_above
    assert grade(key, 0.0) == PASS
    assert grade(key, t.warn_above) == PASS
    assert grade(key, np.nextafter(t.warn_above, np.inf)) == WARN
    assert grade(key, t.fail_above) == WARN
    assert grade(key, np.nextafter(t.fail_above, np.inf)) == FAIL
    assert grade(key, None) is None and grade(key, float("nan")) is None


def test_verdicts_of_figures(clean):
    """The figures' verdicts follow the table: a clean set passes; the same figures with
    the clipping pushed just past each limit warn, then fail."""
    from hdrcl.report.verdicts import THRESHOLDS, grade_figures, thin_coverage_percent, worst

    br, res = clean
    fig = measure(br, res.response, res.radiance, loo_max_pixels=6000)
    assert set(grade_figures(fig).values()) == {"pass"} and worst(grade_figures(fig).values()) == "pass"
    limit = {t.key: t for t in THRESHOLDS}["clipped"]
    fig.clipped_high_fraction = np.nextafter(limit.warn_above, np.inf) / 100.0
    fig.clipped_low_fraction = np.nextafter(limit.fail_above, np.inf) / 100.0
    g = grade_figures(fig)
    assert g["Clipped high"] == "warn" and g["Clipped low"] == "fail" and worst(g.values()) == "fail"
    # Thin coverage: pixels measured by at most one frame, from the histogram.
    fig.coverage_histogram = [1, 3] + [0] * (len(fig.coverage_histogram) - 3) + [fig.valid_pixels - 4]
    assert thin_coverage_percent(fig) == pytest.approx(400.0 / fig.valid_pixels)
    fig.loo_rmse = None
    assert grade_figures(fig)["Leave-one-out RMSE"] is None
    assert worst([None, None]) is None
