"""Limits on what one command may be asked to do: pixels per frame (checked from the
header, before decoding) and the length of ``--motion-blur``. Each is a one-line error
with its exit code and writes nothing."""
import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.core import synthetic as s


@pytest.fixture()
def bracket(tmp_path, monkeypatch):
    from hdrcl.io.ldr import write_ldr

    monkeypatch.setenv("HDRCL_MAX_PIXELS", "")  # restored after the test (--max-pixels sets it)
    rad = s.radiance_field(20, 30, decades=3.0, seed=2)
    times = s.stops(3, 2.0, centre=1.0 / float(np.median(rad)))
    paths = []
    for k, f in enumerate(s.bracket(rad, times, s.Camera(), noise=0.5, seed=1)):
        p = tmp_path / f"f{k}.png"
        write_ldr(str(p), f)
        paths.append(str(p))
    return paths, ",".join(repr(float(t)) for t in times), tmp_path


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def one_line_error(r, code, *words):
    assert r.exit_code == code, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hdrcl: error: "), r.output
    for w in words:
        assert w in lines[0], r.output


def test_pixel_limit_from_the_environment(bracket, monkeypatch):
    paths, times, d = bracket
    monkeypatch.setenv("HDRCL_MAX_PIXELS", "599")  # frames are 30x20 = 600 pixels
    for cmd in (["merge", *paths, "--times", times, "-o", d / "out.exr"],
                ["calibrate", *paths, "--times", times, "-o", d / "r.json"]):
        one_line_error(run(*cmd), 3, "f0.png", "30x20", "HDRCL_MAX_PIXELS")
    assert not (d / "out.exr").exists() and not (d / "r.json").exists()
    monkeypatch.setenv("HDRCL_MAX_PIXELS", "600")  # exactly at the limit: merged
    assert run("merge", *paths, "--times", times, "-o", d / "out.exr").exit_code == 0
    assert (d / "out.exr").exists()


def test_pixel_limit_option(bracket):
    paths, times, d = bracket
    r = run("--max-pixels", "599", "merge", *paths, "--times", times, "-o", d / "out.exr")
    one_line_error(r, 3, "f0.png", "--max-pixels")
    assert not (d / "out.exr").exists()
    r = run("--max-pixels", "0", "merge", *paths, "--times", times, "-o", d / "out.exr")
    assert r.exit_code == 2 and not (d / "out.exr").exists()


def test_pixel_limit_is_checked_before_decoding(bracket, monkeypatch):
    """The header alone decides: the pixels are never read."""
    import hdrcl.io.reader as reader

    paths, times, d = bracket
    monkeypatch.setenv("HDRCL_MAX_PIXELS", "599")

    def no_decode(*a, **k):
        raise AssertionError("decoded a frame over the pixel limit")

    monkeypatch.setattr(reader.BracketReader, "_read", no_decode)
    one_line_error(run("merge", *paths, "--times", times, "-o", d / "out.exr"), 3, "f0.png")


def test_bad_pixel_limit_is_a_usage_error(bracket, monkeypatch):
    paths, times, d = bracket
    monkeypatch.setenv("HDRCL_MAX_PIXELS", "lots")
    one_line_error(run("merge", *paths, "--times", times, "-o", d / "out.exr"), 2, "HDRCL_MAX_PIXELS")


@pytest.fixture()
def radiance(tmp_path):
    from hdrcl.core.response import linear_response
    from hdrcl.io.writers import write_radiance

    write_radiance(str(tmp_path / "r.exr"), s.radiance_field(40, 60, decades=2.0, seed=3), dtype="float")
    linear_response(3).save(str(tmp_path / "resp.json"))
    return tmp_path


@pytest.mark.parametrize("blur, words", [
    ("1e9,1e9", ["longer than the image (60x40)"]),
    ("nan,0", ["expected DX,DY"]),
    ("inf,1", ["expected DX,DY"]),
    ("61,0", ["longer than the image"]),
])
def test_motion_blur_is_bounded(radiance, blur, words):
    d = radiance
    r = run("expose", d / "r.exr", "-o", d / "v.png", "--response", d / "resp.json", "--time", "1",
            "--motion-blur", blur)
    one_line_error(r, 2, "--motion-blur", *words)
    assert not (d / "v.png").exists()


def test_motion_blur_fixed_cap(tmp_path):
    """On an image larger than the cap, a blur within the image but over
    MAX_MOTION_BLUR pixels is refused before any blurring."""
    from hdrcl.core.exposure.virtual import MAX_MOTION_BLUR, _check_blur_length
    from hdrcl.errors import UsageError

    with pytest.raises(UsageError, match="at most 1000"):
        _check_blur_length((900.0, 900.0), (4000, 6000, 3))
    _check_blur_length((float(MAX_MOTION_BLUR), 0.0), (4000, 6000, 3))  # at the cap: allowed


def test_motion_blur_within_bounds(radiance):
    d = radiance
    r = run("expose", d / "r.exr", "-o", d / "v.png", "--response", d / "resp.json", "--time", "1",
            "--motion-blur", "5,-3")
    assert r.exit_code == 0, r.output
    assert (d / "v.png").exists()
