"""Reading photographs: headers, EXIF, pixel formats, alpha, damaged files."""
import datetime as dt
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

oiio = pytest.importorskip("OpenImageIO")

from hdrcl.errors import InputError  # noqa: E402
from hdrcl.io.frames import read_image, read_images, read_info  # noqa: E402
from hdrcl.io.reader import ignore_color_mask  # noqa: E402


def _write(path, pixels, attrs=(), channelnames=None, alpha=None):
    """Write ``pixels`` (H, W, C) with OIIO in their own integer format."""
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, "uint8" if pixels.dtype == np.uint8 else "uint16")
    if channelnames:
        spec.channelnames = channelnames
    if alpha is not None:
        spec.alpha_channel = alpha
        spec.attribute("oiio:UnassociatedAlpha", 1)
    for name, value in attrs:
        spec.attribute(name, value)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), out.geterror()
    assert out.write_image(pixels), out.geterror()
    out.close()
    return path


def _noise(shape, dtype=np.uint8, seed=0):
    hi = np.iinfo(dtype).max
    return np.random.default_rng(seed).integers(0, hi, shape, dtype=dtype, endpoint=True)


EXIF = [
    ("ExposureTime", 1 / 30),
    ("FNumber", 8.0),
    ("Exif:PhotographicSensitivity", 200),
    ("Exif:ExposureBiasValue", -2.0 / 3.0),
    ("Exif:ExposureMode", 2),
    ("Exif:DateTimeOriginal", "2024:05:06 07:08:09"),
    ("Exif:SubsecTimeOriginal", "25"),
    ("Make", "Canon"),
    ("Model", "EOS 5D"),
    ("Exif:BodySerialNumber", "0123456"),
    ("Exif:LensModel", "EF 24-70mm"),
    ("Exif:FocalLength", 35.0),
]


def test_exif_round_trip_through_jpeg(tmp_path):
    path = _write(tmp_path / "IMG_0001.JPG", _noise((31, 47, 3)), EXIF)
    info = read_info(path)
    assert (info.width, info.height, info.nchannels, info.bits) == (47, 31, 3, 8)
    assert info.channel_names == ("R", "G", "B")
    assert info.exposure_time == 1 / 30  # float32 rational snapped back to exactly 1/30
    assert info.fnumber == 8.0
    assert info.iso == 200
    assert info.exposure_bias == pytest.approx(-2 / 3, abs=1e-3)
    assert info.exposure_mode == 2
    assert info.capture_time == dt.datetime(2024, 5, 6, 7, 8, 9, 250000)
    assert (info.make, info.model, info.serial, info.lens) == (
        "Canon", "EOS 5D", "0123456", "EF 24-70mm")
    assert info.focal_length == 35.0
    assert info.path == str(path)


def test_info_without_exif_and_datetime_fallback(tmp_path):
    """A converted PNG's DateTime is when the converter wrote it (a folder of them share
    one stamp), not a capture time (issue 27); a camera's own file's DateTime is."""
    path = _write(tmp_path / "plain.png", _noise((5, 7, 3)),
                  [("DateTime", "2023:01:02 03:04:05")])
    info = read_info(path)
    assert info.exposure_time is None and info.fnumber is None and info.iso is None
    assert info.capture_time is None
    path = _write(tmp_path / "camera.tif", _noise((5, 7, 3)),
                  [("DateTime", "2023:01:02 03:04:05"), ("Make", "Canon"), ("Model", "EOS 5D")])
    assert read_info(path).capture_time == dt.datetime(2023, 1, 2, 3, 4, 5)


def test_read_rgb_jpeg_and_16bit_png(tmp_path):
    jpg = read_image(_write(tmp_path / "a.jpg", _noise((31, 47, 3))))
    assert jpg.pixels.shape == (31, 47, 3) and jpg.pixels.dtype == np.uint8
    assert jpg.valid is None and jpg.info.bits == 8

    px = _noise((31, 47, 3), np.uint16, seed=1)
    png = read_image(_write(tmp_path / "b.png", px))
    assert png.pixels.dtype == np.uint16 and png.info.bits == 16
    np.testing.assert_array_equal(png.pixels, px)


def test_grey(tmp_path):
    px = _noise((9, 11, 1))
    img = read_image(_write(tmp_path / "g.png", px))
    assert img.pixels.shape == (9, 11, 1)
    np.testing.assert_array_equal(img.pixels, px)


@pytest.mark.parametrize("nch", [2, 4])
def test_alpha_gives_valid_mask_and_raw_colour(tmp_path, nch):
    px = _noise((6, 8, nch), np.uint16, seed=nch)
    alpha = px[:, :, -1]
    alpha[0, :] = 0
    alpha[1, :] = 1000  # partial alpha must not premultiply the colour
    names = ("Y", "A") if nch == 2 else ("R", "G", "B", "A")
    img = read_image(_write(tmp_path / "al.png", px, channelnames=names, alpha=nch - 1))
    assert img.pixels.shape == (6, 8, nch - 1)
    np.testing.assert_array_equal(img.pixels, px[:, :, : nch - 1])
    np.testing.assert_array_equal(img.valid, alpha != 0)
    assert not img.valid[0].any()


def test_truncated_jpeg(tmp_path):
    path = _write(tmp_path / "photo3.jpg", _noise((64, 96, 3)))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    read_info(path)  # the header is intact
    with pytest.raises(InputError, match=r"^.*photo3\.jpg: truncated JPEG data"):
        read_image(path)


def test_truncated_png(tmp_path):
    path = _write(tmp_path / "cut.png", _noise((64, 96, 3), np.uint16))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"cut\.png: truncated PNG data"):
        read_image(path)


def test_garbage_missing_empty(tmp_path):
    bad = tmp_path / "garbage.jpg"
    bad.write_bytes(b"this is not an image" * 20)
    with pytest.raises(InputError, match=r"garbage\.jpg: cannot read image"):
        read_image(bad)
    with pytest.raises(InputError, match=r"garbage\.jpg"):
        read_info(bad)
    with pytest.raises(InputError, match=r"nope\.jpg: no such file"):
        read_info(tmp_path / "nope.jpg")
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    with pytest.raises(InputError, match=r"empty\.png: empty file"):
        read_image(empty)


def test_float_image_rejected(tmp_path):
    spec = oiio.ImageSpec(4, 3, 3, "float")
    spec.attribute("tiff:write_exif", 0)
    path = str(tmp_path / "f.tif")
    out = oiio.ImageOutput.create(path)
    out.open(path, spec)
    out.write_image(np.ones((3, 4, 3), np.float32))
    out.close()
    with pytest.raises(InputError, match=r"f\.tif: unsupported pixel format float; hdrcl merges"):
        read_info(path)


def test_read_images_parallel_order_and_checks(tmp_path):
    paths = [_write(tmp_path / f"f{i}.png", _noise((7, 9, 3), seed=i)) for i in range(5)]
    images = read_images(paths)
    assert [im.info.path for im in images] == [str(p) for p in paths]
    np.testing.assert_array_equal(images[3].pixels, _noise((7, 9, 3), seed=3))

    odd = _write(tmp_path / "odd.png", _noise((9, 7, 3)))
    with pytest.raises(InputError, match=r"odd\.png: size 7x9 differs from .*f0\.png \(9x7\)"):
        read_images([paths[0], paths[1], odd])
    grey = _write(tmp_path / "grey.png", _noise((7, 9, 1)))
    with pytest.raises(InputError, match=r"grey\.png: 1 colour channel"):
        read_images([paths[0], grey])
    deep = _write(tmp_path / "deep.png", _noise((7, 9, 3), np.uint16))
    with pytest.raises(InputError, match=r"deep\.png: 16-bit"):
        read_images([paths[0], deep])
    with pytest.raises(InputError, match=r"gone\.png: no such file"):
        read_images([paths[0], tmp_path / "gone.png"])


def test_ignore_color_mask():
    px = np.zeros((2, 3, 3), np.uint8)
    px[0, 0] = (0, 0, 255)
    px[1, 2] = (0, 1, 255)
    mask = ignore_color_mask(px, (0, 0, 255))
    assert mask.tolist() == [[True, False, False], [False, False, False]]
    mask16 = ignore_color_mask(px.astype(np.uint16) * 257, (0, 0, 255))
    np.testing.assert_array_equal(mask16, mask)
    grey = np.array([[[7], [8]]], np.uint8)
    assert ignore_color_mask(grey, (7, 7, 7)).tolist() == [[True, False]]


def test_import_does_not_load_oiio():
    code = ("import sys, hdrcl.io.frames, hdrcl.io.reader, hdrcl.io.writers, hdrcl.io.radiance, hdrcl.io.metadata; "
            "sys.exit('OpenImageIO' in sys.modules)")
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=str(root))
    assert subprocess.run([sys.executable, "-c", code], cwd=root, env=env).returncode == 0


def test_interrupted_grid_read_stops_its_decoders_first(tmp_path, monkeypatch):
    """SIGTERM (raised in the main thread by the CLI) while the calibration grid decodes:
    every decoder thread has stopped before the exception leaves read_grid, so closing
    the reader never pulls files from under a running decode (that aborted the process)."""
    import signal
    import threading
    import time

    from hdrcl.io.reader import BracketReader

    rng = np.random.default_rng(0)
    paths = []
    for k in range(3):
        p = tmp_path / f"f{k}.png"
        _write(p, rng.integers(0, 255, (400, 64, 3), dtype=np.uint8))
        paths.append(str(p))
    slow = BracketReader._read
    running = []

    def slow_read(self, k, y0, y1):
        running.append(k)
        try:
            time.sleep(0.02)
            return slow(self, k, y0, y1)
        finally:
            running.remove(k)

    monkeypatch.setattr(BracketReader, "_read", slow_read)
    monkeypatch.setattr("hdrcl.io.reader.GRID_STRIP_ROWS", 8)

    class Stop(Exception):
        pass

    def raise_stop(signum, frame):
        raise Stop()

    old = signal.signal(signal.SIGALRM, raise_stop)
    try:
        with BracketReader(paths) as reader:
            signal.setitimer(signal.ITIMER_REAL, 0.1)
            with pytest.raises(Stop):
                reader.read_grid(2)
            assert running == []  # no decode in flight once the exception is out
            time.sleep(0.05)
            assert not any(t.name.startswith("hdrcl-grid") for t in threading.enumerate())
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def test_bare_times_list_taken_in_name_order(tmp_path, caplog):
    """A list of times alone (the Memorial download's shutter_times.txt) is taken for the
    frames in name order when the counts agree, with a warning; refused naming both counts
    otherwise (issue 34)."""
    import logging

    from hdrcl.errors import InputError
    from hdrcl.io.exposure_lists import read_times_file

    lst = tmp_path / "shutter_times.txt"
    lst.write_text("# longest first\n32\n1/2\n\n0.25\n")
    frames = [str(tmp_path / n) for n in ("m03.png", "m01.png", "m02.png")]
    with caplog.at_level(logging.WARNING):
        table = read_times_file(lst, frames)
    assert {k: v.time for k, v in table.items()} == {"m01.png": 32.0, "m02.png": 0.5, "m03.png": 0.25}
    assert "name order" in caplog.text
    with pytest.raises(InputError, match="bare list of 3 time.*2 frame"):
        read_times_file(lst, frames[:2])
    with pytest.raises(InputError, match="bare list of 3"):
        read_times_file(lst)
    lst.write_text("32\n-2\n")
    with pytest.raises(InputError, match="line 2: exposure time -2 s is not a positive time"):
        read_times_file(lst, frames[:2])
    lst.write_text("m01.png\n")  # a name without its time stays a bad line
    with pytest.raises(InputError, match="expected 'file seconds'"):
        read_times_file(lst, frames[:1])


def test_bare_times_list_merges_like_named_list(tmp_path, write_frames, cl_device):
    from click.testing import CliRunner

    from hdrcl.cli import main
    from hdrcl.core import synthetic

    cam = synthetic.Camera()
    rad = synthetic.radiance_field(31, 47, decades=3.0, seed=3)
    times = [1 / 60, 1 / 15, 1 / 4]
    frames = synthetic.bracket(rad, times, cam, seed=1)
    paths = write_frames(tmp_path, frames)
    (tmp_path / "bare.txt").write_text("".join(f"{t}\n" for t in times))
    (tmp_path / "named.txt").write_text("".join(f"{os.path.basename(p)} {t}\n" for p, t in zip(paths, times)))
    outs = []
    for lst in ("bare.txt", "named.txt"):
        out = tmp_path / f"{lst}.exr"
        r = CliRunner().invoke(main, ["merge", *paths, "--times-file", str(tmp_path / lst), "-o", str(out)])
        assert r.exit_code == 0, r.output
        from hdrcl.io.radiance import read_radiance

        outs.append(read_radiance(str(out))[0])
    assert np.array_equal(outs[0], outs[1])
