"""Absolute scale, white balance, motion blur (issue 5)."""
import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.core import radiometry as rm
from hdrcl.core import synthetic as s
from hdrcl.errors import UsageError


@pytest.fixture()
def files(tmp_path):
    from hdrcl.io.ldr import write_photo

    cam = s.Camera(a=1.1, x0=(1.0, 1.0, 1.0))
    rad = s.radiance_field(40, 60, decades=2.0, seed=4)
    rad[5:15, 5:15] = np.median(rad) * np.array([1.0, 0.8, 0.5])  # a warm grey card
    times = s.stops(4, 1.0, centre=1.0 / float(np.median(rad)))
    paths = []
    for k, (img, t) in enumerate(zip(s.bracket(rad, times, cam, noise=0.3, seed=1), times)):
        p = tmp_path / f"f{k}.jpg"
        write_photo(str(p), img, {"ExposureTime": float(t), "FNumber": 8.0, "Exif:PhotographicSensitivity": 200})
        paths.append(str(p))
    return paths, tmp_path


def _read(p):
    from hdrcl.io.radiance import read_radiance

    return read_radiance(str(p))


def test_neutral_patch_and_reference_patch(files, cl_device):
    paths, d = files
    r = CliRunner().invoke(main, ["merge", *paths, "-o", str(d / "a.exr"), "--dtype", "float",
                                  "--neutral", "5,5,10,10", "--reference-patch", "5,5,10,10=120"])
    assert r.exit_code == 0, r.output
    rad, meta = _read(d / "a.exr")
    patch = rad[5:15, 5:15].reshape(-1, 3).mean(axis=0)
    assert np.allclose(patch / patch.mean(), 1.0, atol=0.02)  # neutral
    assert rm.luminance(patch) == pytest.approx(120, rel=0.01)
    assert meta["units"] == "cd/m2"


def test_absolute_from_exif(files, cl_device):
    paths, d = files
    r = CliRunner().invoke(main, ["merge", *paths, "-o", str(d / "b.exr"), "--dtype", "float"])
    r2 = CliRunner().invoke(main, ["merge", *paths, "-o", str(d / "c.exr"), "--dtype", "float", "--absolute"])
    assert r.exit_code == 0 and r2.exit_code == 0, r2.output
    rel, _ = _read(d / "b.exr")
    ab, meta = _read(d / "c.exr")
    assert np.allclose(ab / rel, 12.5 * 8.0 ** 2 / 200, rtol=1e-3)
    assert "approximate" in meta["units"]


def test_patch_errors(files):
    paths, d = files
    r = CliRunner().invoke(main, ["merge", *paths, "-o", str(d / "x.exr"), "--neutral", "50,30,20,20"])
    assert r.exit_code == 2 and "outside" in r.output
    with pytest.raises(UsageError):
        rm.parse_reference_patch("1,2,3,4")
    with pytest.raises(UsageError):
        rm.parse_patch("1,2,0,4")


def test_motion_blur_on_radiance_keeps_highlight_energy():
    rad = np.full((20, 40, 1), 0.1, np.float32)
    rad[10, 10, 0] = 1000.0  # a point light far beyond the 8-bit range
    blurred = rm.motion_blur(rad, 9, 0)
    assert blurred.sum() == pytest.approx(rad.sum(), rel=1e-4)  # light is conserved
    assert blurred[10, 10:20, 0].min() > 90  # a bright streak, 10 pixels long
    clipped = np.minimum(rad, 1.0)  # what an 8-bit photo keeps of it
    assert rm.motion_blur(clipped, 9, 0)[10, 10:20, 0].max() < 0.2  # muddy
