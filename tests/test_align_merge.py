"""hdrcl merge --align: hand-held brackets end to end through the CLI."""
import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.core import synthetic as s

SHIFTS = [(7, -12), (-25, 31), (0, 0), (40, -40)]  # the middle exposure (index 2) is the reference


@pytest.fixture()
def handheld(tmp_path):
    from test_align import (
        textured_radiance,  # texture at several scales: something to align on
    )

    from hdrcl.io.writers import write_ldr

    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
    big = textured_radiance(300, 400, seed=21)
    times = s.stops(4, 1.5, centre=1.0 / float(np.median(big)))
    paths = []
    for k, ((dy, dx), t) in enumerate(zip(SHIFTS, times)):
        view = big[60 + dy:240 + dy, 60 + dx:340 + dx]  # the camera moved: frame(y+dy, x+dx) = ref(y, x)
        p = tmp_path / f"h{k}.png"
        write_ldr(str(p), s.bracket(view, [t], cam, noise=0.5, seed=k)[0])
        paths.append(str(p))
    return paths, times, tmp_path


def test_merge_align_recovers_shifts_and_crops(handheld, cl_device):
    paths, times, d = handheld
    tt = ",".join(repr(float(t)) for t in times)
    r = CliRunner().invoke(main, ["merge", *paths, "--times", tt, "-o", str(d / "a.exr"), "--align", "--crop"])
    assert r.exit_code == 0, r.output
    line = [ln for ln in r.output.splitlines() if "aligned:" in ln][0]
    from hdrcl.io.radiance import read_radiance

    rad, meta = read_radiance(str(d / "a.exr"))
    got = [tuple(v) for v in __import__("json").loads(meta["alignShifts"])] if isinstance(meta["alignShifts"], str) \
        else [tuple(v) for v in meta["alignShifts"]]
    ref = SHIFTS[2]  # the middle exposure (index 2 of 4, by time order) is the reference
    want = [(ref[0] - dy, ref[1] - dx) for dy, dx in SHIFTS]  # frame(y+dy, x+dx) = reference(y, x)
    for g, w in zip(got, want):
        assert abs(g[0] - w[0]) <= 1 and abs(g[1] - w[1]) <= 1, (got, want, line)
    assert rad.shape[0] < 180 and rad.shape[1] < 280  # cropped to the common area
    assert np.all(np.isfinite(rad)) and rad.min() > 0


def test_crop_needs_align(handheld):
    paths, times, d = handheld
    r = CliRunner().invoke(main, ["merge", *paths, "--times", "1,2,4,8", "-o", str(d / "b.exr"), "--crop"])
    assert r.exit_code == 2 and "--align" in r.output


def test_align_masks_reach_the_kernel(handheld, monkeypatch, cl_device):
    """Pixels an aligned frame no longer covers are masked on the OpenCL path too:
    the OpenCL and NumPy merges agree."""
    import hdrcl

    paths, times, d = handheld
    a = hdrcl.merge_files(paths, d / "cl.exr", times=list(times), align=True, dtype="float", keep_radiance=True,
                          fit_exposures="off")
    monkeypatch.setenv("HDRCL_OPENCL", "0")
    monkeypatch.delenv("HDRCL_REQUIRE_OPENCL", raising=False)
    b = hdrcl.merge_files(paths, d / "np.exr", times=list(times), align=True, dtype="float", keep_radiance=True,
                          fit_exposures="off", response=a.response)
    np.testing.assert_allclose(a.radiance, b.radiance, rtol=2e-5)


def test_align_masks_decide_the_clipping_rule(tmp_path, monkeypatch, cl_device):
    """A border an aligned frame lost, where every other frame is clipped: with its mask
    honoured the pixel is 'clipped high'; read as a real black sample it would turn
    'clipped low'. OpenCL and NumPy must agree."""
    from test_align import textured_radiance

    import hdrcl
    from hdrcl.io.writers import write_ldr

    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
    big = textured_radiance(200, 260, seed=4)
    big[:, :40] *= 1e4  # a window blown out in every exposure
    times = s.stops(3, 2.0, centre=1.0 / float(np.median(big)))
    shifts = [(0, 6), (0, 0), (0, 0)]  # the shortest frame moved: its left edge is lost
    paths = []
    for k, ((dy, dx), t) in enumerate(zip(shifts, times)):
        view = big[30 + dy:170 + dy, 30 + dx:230 + dx]
        p = tmp_path / f"c{k}.png"
        write_ldr(str(p), s.bracket(view, [t], cam, noise=0.5, seed=k)[0])
        paths.append(str(p))
    a = hdrcl.merge_files(paths, tmp_path / "cl.exr", times=list(times), align=True, dtype="float",
                          keep_radiance=True, fit_exposures="off")
    assert a.shifts[0] == (0, -6)
    monkeypatch.setenv("HDRCL_OPENCL", "0")
    monkeypatch.delenv("HDRCL_REQUIRE_OPENCL", raising=False)
    b = hdrcl.merge_files(paths, tmp_path / "np.exr", times=list(times), align=True, dtype="float",
                          keep_radiance=True, fit_exposures="off", response=a.response)
    np.testing.assert_allclose(a.radiance, b.radiance, rtol=2e-5)
    assert a.radiance[:, :6].min() > np.median(a.radiance)  # the lost border stays bright


def test_report_measures_the_aligned_cropped_frames(handheld, tmp_path, cl_device):
    import hdrcl
    from hdrcl.report.merge_report import write_quality_report

    paths, times, d = handheld
    res = hdrcl.merge_files(paths, d / "r.exr", times=list(times), align=True, crop=True, thumbnail=64)
    fig, entry = write_quality_report(res, tmp_path / "rep", loo=False)
    assert fig.coverage.shape == res.shape[:2]
    assert (tmp_path / "rep" / "index.html").is_file()
