"""Issue 17: a given or pooled response checks exposures but did not correct them.

Real DSLR sets have frames labelled a stop apart that are not (some identical); merged
with a response calibrated on a correct set of the same camera they were about a stop
RMS from the camera curve's map. With the curve known there is no exponential
ambiguity: the pixels tell every exposure ratio, the metadata only the scale
(:func:`hdrcl.core.exposure.known.estimate_exposures`).
"""
import numpy as np
import pytest

import hdrcl
from hdrcl.core import synthetic as s
from hdrcl.core.exposure.fit import fit_exposures
from hdrcl.core.exposure.known import KnownCurveFit, estimate_exposures
from hdrcl.core.exposure.verdict import untrusted_metadata
from hdrcl.core.fusion import fuse_frames
from hdrcl.core.response import Response, knot_positions
from hdrcl.errors import UsageError

CAM = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
NAMES = [f"f{k}.png" for k in range(7)]


def true_response(cam=CAM, channels=3):
    """The camera's own curve, g(mid) = 0 per channel, at the knots of its depth."""
    knots = knot_positions(cam.bits)
    top = cam.levels - 1
    z = np.clip(knots, 0.5, top - 0.5)
    mid = np.argmin(np.abs(knots - cam.levels / 2))
    g = np.stack([cam.g(z, c) for c in range(channels)])
    return Response(bits=cam.bits, g=g - g[:, mid:mid + 1], knots=knots,
                    channels=("R", "G", "B") if channels == 3 else ("Y",))


def radiance_error(radiance, truth, frames):
    """Largest over channels of the median relative error, over pixels some frame
    measures well, after each channel's free scale."""
    top = np.iinfo(frames[0].dtype).max
    ok = np.zeros(truth.shape, bool)
    for f in frames:
        ok |= (f > 25 * top / 255) & (f < 230 * top / 255)
    err = 0.0
    for c in range(truth.shape[2]):
        r = radiance[..., c][ok[..., c]] / truth[..., c][ok[..., c]]
        err = max(err, float(np.median(np.abs(r / np.median(r) - 1))))
    return err


def exposure_error(used, truth):
    """Largest |log2(used / truth)| after the free global scale (stops)."""
    e = np.log2(np.asarray(used) / np.asarray(truth))
    return float(np.abs(e - np.median(e)).max())


@pytest.fixture(scope="module")
def field():
    rad = s.radiance_field(90, 120, decades=4.0, seed=11)
    return rad, 1.0 / float(np.median(rad))


@pytest.fixture(scope="module")
def wrong_ladder(field):
    """Seven frames a stop apart by their labels; in truth f5 is f4 again (identical
    pixels: the shutter limit) and f2 is 1.3 stops shorter than labelled."""
    rad, c = field
    labelled = s.stops(7, 1.0, centre=c)
    truth = labelled.copy()
    truth[5] = truth[4]
    truth[2] = labelled[2] * 2.0 ** -1.3
    frames = s.bracket(rad, truth, CAM, noise=0.5, seed=12)
    frames[5] = frames[4].copy()
    return frames, labelled, truth


def test_wrong_labels_with_the_true_curve_are_corrected(field, wrong_ladder):
    rad, _ = field
    frames, labelled, truth = wrong_ladder
    resp = true_response()
    before = radiance_error(fuse_frames(frames, labelled, resp).radiance, rad, frames)
    assert before > 0.03  # the failure: the right curve, the metadata taken at its word
    assert exposure_error(labelled, truth) > 1.0
    fit = estimate_exposures(frames, labelled, resp, names=NAMES)
    assert isinstance(fit, KnownCurveFit)
    assert list(np.flatnonzero(fit.flagged)) == [2, 5]
    assert list(np.flatnonzero(~fit.trusted)) == [2, 5] and fit.measured.all()
    np.testing.assert_allclose(fit.stops[[2, 5]], [-1.3, -1.0], atol=0.05)
    assert exposure_error(fit.used, truth) < 0.05
    assert exposure_error(fit.fitted, truth) < 0.05
    np.testing.assert_array_equal(fit.used[~fit.flagged], labelled[~fit.flagged])  # the rest kept exactly
    after = radiance_error(fuse_frames(frames, fit.used, resp).radiance, rad, frames)
    assert after < 0.02 and after < before / 4
    assert fit.same == [(4, 5)]
    text = " | ".join(fit.notes)
    assert "f2.png: metadata says" in text and "(-1.30 stops); the measured exposure is used" in text
    assert "f5.png: metadata says" in text and "(-1.00 stops)" in text
    assert "f4.png and f5.png are at the same exposure" in text
    assert not any(n.startswith(("f0.png", "f1.png", "f3.png", "f6.png")) for n in fit.notes)
    assert "5 frames" in fit.scale_note


def test_a_curve_calibrated_on_another_correct_set_corrects_them(field, wrong_ladder):
    """The issue's setting: the response hdrcl calibrates itself on a correct set of the
    same camera (as --response, or a batch's pooled response)."""
    rad, _ = field
    frames, labelled, truth = wrong_ladder
    other = s.radiance_field(90, 120, decades=4.0, seed=3)
    t_other = s.stops(7, 1.0, centre=1.0 / float(np.median(other)))
    resp = hdrcl.calibrate(s.bracket(other, t_other, CAM, noise=0.5, seed=1), t_other)
    fit = estimate_exposures(frames, labelled, resp, names=NAMES)
    assert list(np.flatnonzero(fit.flagged)) == [2, 5]
    assert exposure_error(fit.used, truth) < 0.05
    assert radiance_error(fuse_frames(frames, fit.used, resp).radiance, rad, frames) < 0.02


def test_a_curve_that_does_not_quite_fit_keeps_right_metadata(field, wrong_ladder):
    """A curve of another slope (picture style, adaptive tone curve) measures every
    ratio raised to one power. Moving the ends of a right ladder to it would bend the
    map: the metadata is kept and the stretch is said; wrong frames are still corrected,
    onto the metadata's spacing."""
    rad, c = field
    times = s.stops(9, 2.0, centre=c)
    frames = s.bracket(rad, times, CAM, noise=0.5, seed=13)
    flatter = true_response(s.Camera(a=1.0, x0=CAM.x0))
    fit = estimate_exposures(frames, times, flatter)
    assert fit.stretch == pytest.approx(1.1, abs=0.02) and fit.trusted.all() and not fit.flagged.any()
    np.testing.assert_array_equal(fit.used, times)
    assert len(fit.notes) == 1 and "1.10x as far apart" in fit.notes[0] and "metadata is kept" in fit.notes[0]
    assert radiance_error(fuse_frames(frames, fit.used, flatter).radiance, rad, frames) < 0.02
    frames, labelled, truth = wrong_ladder
    fit = estimate_exposures(frames, labelled, true_response(s.Camera(a=1.25, x0=CAM.x0)), names=NAMES)
    assert list(np.flatnonzero(fit.flagged)) == [2, 5] and fit.stretch == pytest.approx(0.88, abs=0.02)
    assert exposure_error(fit.used, truth) < 0.05


def test_correct_ladder_is_left_exactly_as_labelled(field):
    rad, c = field
    times = s.stops(7, 1.0, centre=c)
    frames = s.bracket(rad, times, CAM, noise=0.8, seed=3)
    for labels in (times, times * 2.0 ** np.array([0.034, -0.03, 0.02, -0.04, 0.03, 0.0, -0.02])):
        fit = estimate_exposures(frames, labels, true_response(), names=NAMES)
        assert fit.notes == [] and fit.same == []
        assert not fit.flagged.any() and fit.trusted.all() and fit.measured.all()
        np.testing.assert_array_equal(fit.used, labels)
        assert np.abs(np.log2(fit.fitted / times)).max() < 0.05
    # EXIF-like rounding: 1/64 s written 1/60, 1/128 written 1/125 ...
    exact = 2.0 ** -np.arange(4.0, 11.0)[::-1]
    exif = np.array([1 / 1000, 1 / 500, 1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15])
    frames = s.bracket(rad, exact * c / np.median(exact), CAM, noise=0.5, seed=4)
    fit = estimate_exposures(frames, exif, true_response())
    assert fit.notes == [] and not fit.flagged.any()
    np.testing.assert_array_equal(fit.used, exif)


def test_sixteen_bit_frames():
    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8), bits=16)
    rad = s.radiance_field(60, 80, decades=4.0, seed=5)
    labelled = s.stops(5, 1.0, centre=1.0 / float(np.median(rad)))
    truth = labelled.copy()
    truth[3] *= 2.0  # labelled a stop shorter than it was
    frames = s.bracket(rad, truth, cam, noise=0.5, seed=6)
    assert frames[0].dtype == np.uint16
    fit = estimate_exposures(frames, labelled, true_response(cam))
    assert list(np.flatnonzero(fit.flagged)) == [3]
    assert fit.stops[3] == pytest.approx(1.0, abs=0.05)
    assert exposure_error(fit.used, truth) < 0.05
    assert fit.notes[0].startswith("image 3: metadata says")
    with pytest.raises(UsageError, match="16-bit"):
        estimate_exposures(frames, labelled, true_response())


def test_grey_frames():
    cam = s.Camera(a=1.1, x0=(1.0,))
    rad = s.radiance_field(60, 80, decades=4.0, channels=1, seed=7)
    labelled = s.stops(5, 1.0, centre=1.0 / float(np.median(rad)))
    truth = labelled.copy()
    truth[1] = truth[0]  # identical to its neighbour, labelled a stop apart
    frames = s.bracket(rad, truth, cam, noise=0.5, seed=8)
    grey = true_response(cam, channels=1)
    for fr in (frames, [f[..., 0] for f in frames]):  # (H, W, 1) and (H, W)
        fit = estimate_exposures(fr, labelled, grey)
        assert list(np.flatnonzero(fit.flagged)) == [1] and fit.same == [(0, 1)]
        assert exposure_error(fit.used, truth) < 0.05
    after = radiance_error(fuse_frames(frames, fit.used, grey).radiance, rad, frames)
    before = radiance_error(fuse_frames(frames, labelled, grey).radiance, rad, frames)
    assert after < 0.02 < before


def test_masks_are_honoured(field):
    """Most of f3 is something else (a passer-by two stops brighter); the mask says so.
    A frame masked almost entirely keeps its metadata, and the notes say why."""
    rad, c = field
    times = s.stops(7, 1.0, centre=c)
    frames = s.bracket(rad, times, CAM, noise=0.5, seed=9)
    brighter = s.bracket(rad, times[3:4] * 4.0, CAM, noise=0.5, seed=10)[0]
    moved = [f.copy() for f in frames]
    valid = [None] * 7
    valid[3] = np.zeros(frames[3].shape[:2], bool)
    valid[3][:, :30] = True
    moved[3][~valid[3]] = brighter[~valid[3]]
    resp = true_response()
    unmasked = estimate_exposures(moved, times, resp, names=NAMES)
    assert unmasked.flagged[3]  # the failure without the mask
    fit = estimate_exposures(moved, times, resp, valid=valid, names=NAMES)
    assert not fit.flagged.any() and fit.notes == []
    np.testing.assert_array_equal(fit.used, times)
    # f3 labelled wrong as well: measured on its valid pixels only.
    wrong = times.copy()
    wrong[3] *= 2.0
    fit = estimate_exposures(moved, wrong, resp, valid=valid, names=NAMES)
    assert list(np.flatnonzero(fit.flagged)) == [3] and exposure_error(fit.used, times) < 0.05
    # A shared mask, and a frame with too few usable pixels.
    shared = np.ones(frames[0].shape[:2], bool)
    shared[:, -10:] = False
    assert not estimate_exposures(frames, times, resp, valid=shared).flagged.any()
    valid[3] = np.zeros_like(valid[3])
    valid[3][:5, :5] = True
    fit = estimate_exposures(moved, wrong, resp, valid=valid, names=NAMES)
    assert not fit.measured[3] and not fit.flagged.any() and fit.used[3] == wrong[3]
    # an end frame with nothing measurable contradicts nothing: said at -v only (issue 34: a
    # phone batch printed one such warning per frame)
    assert not any("too few pixels" in n for n in fit.notes)


def test_few_frames_take_the_median_scale(field):
    """Three frames, one wrong: the calibrating path cannot tell which (no three agree);
    with the curve known the median offset can. Two frames a stop apart by their labels
    but identical are put at one exposure."""
    rad, c = field
    truth = c * np.array([0.5, 1.0, 2.0])
    frames = s.bracket(rad, truth, CAM, noise=0.5, seed=5)
    labelled = truth * np.array([1.0, 1.0, 2.0])
    fit = estimate_exposures(frames, labelled, true_response())
    assert not fit.trusted.any() and list(np.flatnonzero(fit.flagged)) == [2]
    assert exposure_error(fit.used, truth) < 0.05
    assert any("no three frames agree" in n for n in fit.notes)
    two = [frames[1], frames[1].copy()]
    fit = estimate_exposures(two, c * np.array([1.0, 2.0]), true_response(), names=["a.png", "b.png"])
    assert list(np.flatnonzero(fit.flagged)) == [1] and fit.used[0] == c
    assert fit.used[1] == pytest.approx(c, rel=0.01)
    assert fit.same == [(0, 1)] and any(n.startswith("a.png and b.png are at the same exposure") for n in fit.notes)


def test_untrusted_metadata_names_the_frames(field):
    rad, c = field
    # No three frames agree (the calibrating path keeps the metadata).
    truth = c * np.array([0.5, 1.0, 2.0])
    frames = s.bracket(rad, truth, CAM, noise=0.5, seed=5)
    labelled = truth * np.array([1.0, 1.0, 2.0])
    names = ["a.png", "b.png", "c.png"]
    resp = hdrcl.calibrate(frames, labelled, warn=False)
    fit = fit_exposures(frames, labelled)
    msg = untrusted_metadata(resp, fit, names)
    assert msg.startswith("the exposure metadata of this set cannot be trusted: "
                          "no three of its 3 frames (a.png, b.png, c.png) agree")
    assert "--response" in msg
    # A stretched curve: frames a stop apart labelled two stops apart.
    truth = s.stops(6, 1.0, centre=c)
    frames = s.bracket(rad, truth, CAM, noise=0.5, seed=6)
    resp = hdrcl.calibrate(frames, s.stops(6, 2.0, centre=c), warn=False)
    msg = untrusted_metadata(resp)
    assert "stretch the response" in msg and "image 0, image 1" in msg and "image 5" in msg
    msg = untrusted_metadata(resp, names=[f"d{k}.jpg" for k in range(6)])
    assert "d0.jpg" in msg and "d5.jpg" in msg
    # A good set: nothing to say.
    good = hdrcl.calibrate(frames, truth)
    assert untrusted_metadata(good, fit_exposures(frames, truth)) is None
    assert untrusted_metadata(good) is None


def test_merge_with_a_response_corrects_wrong_labels_end_to_end(tmp_path, field, wrong_ladder, cl_device, write_frames):
    """``merge --response`` with wrong labels: the frames the pixels contradict are
    measured through the curve (one decode feeds both), said per frame, and the radiance
    follows the truth; ``--fit-exposures off`` keeps the labels and only warns."""
    from hdrcl.core.merge import merge_files

    rad, _ = field
    frames, labelled, truth = wrong_ladder
    paths = write_frames(tmp_path / "set", frames, names=NAMES)
    res = merge_files(paths, tmp_path / "m.exr", times=list(labelled), response=true_response(),
                      keep_radiance=True)
    assert exposure_error(res.times, truth) < 0.05
    assert radiance_error(res.radiance, rad, frames) < 0.02
    assert any("f2.png" in w and "the pixels say" in w for w in res.warnings)
    off = merge_files(paths, tmp_path / "off.exr", times=list(labelled), response=true_response(),
                      keep_radiance=True, fit_exposures="off")
    np.testing.assert_array_equal(off.times, labelled)
    assert radiance_error(off.radiance, rad, frames) > 0.03
    assert any("f2.png" in w for w in off.warnings)  # the check still warns


def test_batch_corrects_wrong_labels_with_the_pooled_response(tmp_path, field, cl_device):
    """A batch set whose labels are wrong is merged with its camera's pooled response and
    corrected through it; report.json says which frame, and the exposures used."""
    import datetime as dt
    import json

    from click.testing import CliRunner

    from hdrcl.cli import main
    from hdrcl.io.ldr import write_photo

    rad, c = field
    when = dt.datetime(2024, 6, 1, 9, 0, 0)
    labelled = s.stops(5, 1.0, centre=c)
    for k in range(3):  # three sets of one camera: the last one's f2 is 1.3 stops off
        truth = labelled.copy()
        if k == 2:
            truth[2] = labelled[2] * 2.0 ** -1.3
        frames = s.bracket(rad * (1.0 + 0.3 * k), truth, CAM, noise=0.5, seed=20 + k)
        sub = tmp_path / "shoot" / f"set{k}"
        sub.mkdir(parents=True)
        # the last set at f/4: a quarter of the time gives the same exposure; its times are
        # equivalents on the shoot's f/8 in the batch, its messages quote what was recorded
        fnumber = 4.0 if k == 2 else 8.0
        for j, (f, t) in enumerate(zip(frames, labelled)):
            write_photo(str(sub / f"IMG_{k}{j}.jpg"), f,
                        {"ExposureTime": float(t) * (fnumber / 8.0) ** 2, "FNumber": fnumber,
                         "Exif:PhotographicSensitivity": 100,
                         "Make": "Canon", "Model": "EOS R6", "Exif:ExposureMode": 1,
                         "Exif:DateTimeOriginal": when.strftime("%Y:%m:%d %H:%M:%S")})
            when += dt.timedelta(seconds=2)
        when += dt.timedelta(minutes=5)
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["batch", str(tmp_path / "shoot"), "-r", "-o", str(out), "--no-preview"])
    assert res.exit_code == 0, res.output
    rep = json.loads((out / "report.json").read_text())
    sets = sorted(rep["sets"], key=lambda e: e["index"])
    assert not any("the pixels say" in w for e in sets[:2] for w in e["warnings"])
    assert any("IMG_22.jpg" in w and "the pixels say" in w for w in sets[2]["warnings"])
    from hdrcl.io.metadata import format_time

    said = f"metadata says {format_time(float(labelled[2]) / 4)} f/4 ISO 100 but the pixels say"
    assert any(said in w for w in sets[2]["warnings"]), sets[2]["warnings"]
    from hdrcl.io.radiance import read_metadata

    meta = read_metadata(sets[2]["output"])
    used = json.loads(meta["exposures"]) if isinstance(meta["exposures"], str) else meta["exposures"]
    ratio = used[2] / used[1]
    assert abs(np.log2(ratio) - np.log2(labelled[2] / labelled[1]) + 1.3) < 0.05
