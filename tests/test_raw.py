"""RAW input (hdrcl.raw) on synthetic DNG files with known truth.

Tests that decode need rawpy (the ``raw`` extra) and tifffile (to write the DNGs). They
skip when either is missing and ``HDRCL_REQUIRE_RAW`` is unset; with it set (CI), a
missing package fails the run instead of passing silently.
"""
import os
import sys

import numpy as np
import pytest

import hdrcl
from hdrcl.core import synthetic
from hdrcl.core.response import Response, linear_response
from hdrcl.io.exif import snap_reciprocal
from hdrcl.errors import InputError
from hdrcl.io import raw as hr
from hdrcl.io import rawheader

sys.path.insert(0, os.path.dirname(__file__))
import rawgen  # noqa: E402

H, W = 64, 96
GAIN = 8000.0  # DN per unit radiance-second


@pytest.fixture(scope="module")
def rawpy_mod():
    missing = []
    for mod in ("rawpy", "tifffile"):
        try:
            __import__(mod)
        except ImportError:
            missing.append(mod)
    if missing:
        msg = f"{' and '.join(missing)} not installed (pip install 'hdrcl[raw]' tifffile)"
        if os.environ.get("HDRCL_REQUIRE_RAW"):
            pytest.fail(f"HDRCL_REQUIRE_RAW is set but {msg}")
        pytest.skip(f"{msg}; set HDRCL_REQUIRE_RAW=1 to make this an error")
    import rawpy

    return rawpy


@pytest.fixture(scope="module")
def radiance():
    return synthetic.radiance_field(H, W, decades=3.0, seed=3)


@pytest.fixture(scope="module")
def bracket(rawpy_mod, radiance, tmp_path_factory):
    """Three DNGs one stop apart; the longest is clipped over about half the frame."""
    folder = tmp_path_factory.mktemp("dng")
    times = [0.25, 0.5, 1.0]
    paths = rawgen.write_bracket(folder, radiance, times, gain=GAIN, capture="2024:05:06 07:08:09",
                                 subsec="25", bias=-1.0, serial="A123")
    return {"paths": paths, "times": times, "frames": [hr.read_raw(p) for p in paths]}


# -- without rawpy ---------------------------------------------------------------------

def test_is_raw():
    for name in ("a.CR2", "b.cr3", "c.nef", "d.ARW", "e.dng", "f.RAF", "g.rw2", "h.orf", "i.pef",
                 "j.srw", "/x/y/IMG_0001.Dng"):
        assert hr.is_raw(name), name
    for name in ("a.jpg", "b.tif", "c.png", "dng", "a.dng.txt"):
        assert not hr.is_raw(name), name


def test_missing_rawpy_names_the_extra(monkeypatch, tmp_path):
    path = tmp_path / "IMG_0001.dng"
    path.write_bytes(b"II*\0" + bytes(64))
    monkeypatch.setitem(sys.modules, "rawpy", None)  # import rawpy -> ImportError
    assert not hr.rawpy_available()
    for fn in (hr.read_raw_info, hr.read_raw):
        with pytest.raises(InputError) as err:
            fn(path)
        assert str(err.value) == f"{path}: RAW files need the optional extra: pip install 'hdrcl[raw]'"


def test_linear_response_is_ln_linear():
    resp = linear_response()
    assert resp.bits == 16 and resp.channels == ("R", "G", "B") and resp.knots.size == 65536
    t = resp.tables()
    assert t.shape == (3, 65536)
    z = np.arange(1, 65536, dtype=np.float64)
    np.testing.assert_allclose(t[:, 1:], np.log(z / 32768.0)[None, :].repeat(3, 0), rtol=0, atol=1e-12)
    assert np.all(t[:, 32768] == 0.0)
    assert np.all(np.isfinite(t)) and np.all(np.diff(t, axis=1) > 0)
    # One stop more light is ln 2 more, wherever on the curve.
    np.testing.assert_allclose(t[:, 2000] - t[:, 1000], np.log(2.0), atol=1e-12)
    back = Response.from_dict(resp.to_dict())
    np.testing.assert_allclose(back.tables(), t, atol=1e-8)
    assert back.channels == resp.channels and back.bits == 16 and not back.monotonic_problems()
    assert linear_response(1).tables().shape == (1, 65536)


def test_clip_to_saturation():
    px = np.array([[[100, 60000, 65535], [59999, 10, 20]]], np.uint16)
    out = hr.clip_to_saturation(px, 60000)
    assert out.tolist() == [[[100, 65535, 65535], [59999, 10, 20]]]
    assert px[0, 0, 1] == 60000  # a copy, not in place
    mask = np.array([[False, True]])
    assert hr.clip_to_saturation(px, 65535, mask).tolist() == [[[100, 60000, 65535], [65535] * 3]]
    with pytest.raises(ValueError):
        hr.clip_to_saturation(px, 65535, np.zeros((2, 2), bool))


def test_exif_in_embedded_headers(tmp_path):
    """RAF carries EXIF in an embedded JPEG, CR3 in its CMT1/CMT2 boxes."""
    ifd0 = [(271, "ascii", "FUJIFILM"), (272, "ascii", "X-T3")]
    exif = [(33434, "rational", (1, 250)), (33437, "rational", (56, 10)), (34855, "short", 400),
            (36867, "ascii", "2023:01:02 03:04:05"), (37521, "ascii", "5"),
            (37380, "srational", (-2, 3)), (41986, "short", 2)]
    raf = tmp_path / "a.raf"
    raf.write_bytes(b"FUJIFILMCCD-RAW 0201" + bytes(200) + b"\xff\xd8\xff\xe1\x10\x00Exif\0\0"
                    + rawgen.exif_tiff(ifd0, exif) + bytes(100))
    got = rawheader.header_fields(str(raf))
    assert got["make"] == "FUJIFILM" and got["model"] == "X-T3"
    assert got["exposure_time"] == 1 / 250 and got["fnumber"] == 5.6 and got["iso"] == 400
    assert got["exposure_bias"] == pytest.approx(-2 / 3) and got["exposure_mode"] == 2
    assert hr._capture_time(got).isoformat() == "2023-01-02T03:04:05.500000"
    cmt1 = rawgen.exif_tiff([(271, "ascii", "Canon"), (272, "ascii", "Canon EOS R5")], [])
    cmt2 = rawgen.exif_tiff([(33434, "rational", (1, 30)), (42033, "ascii", "0123")], [])
    cr3 = tmp_path / "b.cr3"
    cr3.write_bytes(b"\0\0\0\x18ftypcrx " + bytes(40) + (len(cmt1) + 8).to_bytes(4, "big") + b"CMT1"
                    + cmt1 + (len(cmt2) + 8).to_bytes(4, "big") + b"CMT2" + cmt2)
    got = rawheader.header_fields(str(cr3))
    assert (got["make"], got["model"], got["exposure_time"], got["serial"]) == ("Canon", "Canon EOS R5", 1 / 30, "0123")
    junk = tmp_path / "c.orf"
    junk.write_bytes(b"IIRO" + b"\xff" * 60)  # an IFD offset far past the end
    assert rawheader.header_fields(str(junk)) == {}


# -- with rawpy ------------------------------------------------------------------------

def test_generated_dng_opens_in_libraw(rawpy_mod, radiance, tmp_path):
    cfa = rawgen.mosaic(radiance, 0.5, gain=GAIN)
    path = rawgen.write_dng(tmp_path / "x.dng", cfa, exposure_time=0.5)
    with rawpy_mod.imread(path) as raw:
        assert raw.white_level == rawgen.WHITE
        assert list(raw.black_level_per_channel) == [rawgen.BLACK] * 4
        assert raw.raw_pattern.tolist() == [[0, 1], [3, 2]]
        np.testing.assert_array_equal(raw.raw_image_visible, cfa)


def test_read_raw_info(bracket):
    info = hr.read_raw_info(bracket["paths"][0])
    assert (info.width, info.height, info.nchannels, info.bits) == (W, H, 3, 16)
    assert info.channel_names == ("R", "G", "B")
    assert info.exposure_time == 0.25 and info.fnumber == 8.0 and info.iso == 100.0
    assert (info.make, info.model, info.serial) == ("hdrcl", "Synthetic DNG", "A123")
    assert info.capture_time.isoformat() == "2024-05-06T07:08:09.250000"
    assert info.exposure_bias == -1.0
    frame = bracket["frames"][0]
    assert (frame.info.width, frame.info.height) == (info.width, info.height)
    assert frame.info.exposure_time == info.exposure_time


def test_exposure_time_from_rawpy_and_missing(rawpy_mod, radiance, tmp_path):
    cfa = rawgen.mosaic(radiance, 1 / 30, gain=GAIN)
    # The TIFF reader finds 1/30 exactly; LibRaw's float32 copy snaps to the same value.
    path = rawgen.write_dng(tmp_path / "t.dng", cfa, exposure_time=1 / 30)
    assert hr.read_raw_info(path).exposure_time == 1 / 30
    with rawpy_mod.imread(path) as raw:
        assert snap_reciprocal(raw.other.shutter_speed) == 1 / 30
    path = rawgen.write_dng(tmp_path / "n.dng", cfa, exposure_time=None)
    info = hr.read_raw_info(path)
    assert info.exposure_time is None  # --times / --times-file must give it


def test_pixels_are_linear(bracket, radiance):
    frames, times = bracket["frames"], bracket["times"]
    for f in frames:
        assert f.pixels.dtype == np.uint16 and f.pixels.shape == (H, W, 3)
        assert f.saturation == 65535 and f.saturated.shape == (H, W)
    assert 0.3 < frames[-1].saturated.mean() < 0.7 and frames[0].saturated.mean() < 0.25
    base = frames[0].pixels.astype(np.float64)
    for f, t in zip(frames[1:], times[1:]):
        use = ~f.saturated & ~frames[0].saturated & (base.min(axis=2) > 1000)
        assert use.sum() > 1000
        ratio = f.pixels.astype(np.float64)[use] / base[use] / (t / times[0])
        assert np.all(np.abs(np.median(ratio, axis=0) - 1) < 0.01)
        # Every pixel left unmarked is unclipped: none bent by a clipped neighbour.
        assert np.abs(ratio - 1).max() < 0.06
    # Each channel is proportional to the scene's (identity colour matrix, neutral WB).
    f = frames[-1]
    use = ~f.saturated & (f.pixels.min(axis=2) > 1000)
    scale = f.pixels.astype(np.float64)[use] / (radiance[use] * times[-1])
    expected = GAIN * 65535 / (rawgen.WHITE - rawgen.BLACK)
    np.testing.assert_allclose(np.median(scale, axis=0), expected, rtol=0.01)


def test_saturated_areas_end_at_top_code(bracket, radiance):
    for f, t in zip(bracket["frames"], bracket["times"]):
        cfa = rawgen.mosaic(radiance, t, gain=GAIN)
        clipped = cfa >= rawgen.WHITE
        assert clipped.any()
        assert f.saturated[clipped].all()
        assert np.all(f.pixels[f.saturated] == 65535)
        again = hr.clip_to_saturation(f.pixels, f.saturation, f.saturated)
        np.testing.assert_array_equal(again, f.pixels)
    # Without the mask, clipping leaks below 65535 (colour mixing and demosaicing).
    raw = hr.read_raw(bracket["paths"][-1], clip=False)
    assert np.any(raw.pixels[raw.saturated] < 65535)
    np.testing.assert_array_equal(hr.clip_to_saturation(raw.pixels, raw.saturation, raw.saturated),
                                  bracket["frames"][-1].pixels)


def test_sensor_clipping_below_the_white_level(rawpy_mod, radiance, tmp_path):
    """Samples piled up just under WhiteLevel are where this sensor clips."""
    clip = rawgen.WHITE - 500  # below the 2 % margin
    short = rawgen.write_dng(tmp_path / "s.dng", rawgen.mosaic(radiance, 0.25, gain=GAIN), exposure_time=0.25)
    long_ = rawgen.write_dng(tmp_path / "l.dng", rawgen.mosaic(radiance, 1.0, gain=GAIN, clip=clip),
                             exposure_time=1.0)
    a, b = hr.read_raw(short), hr.read_raw(long_)
    cfa = rawgen.mosaic(radiance, 1.0, gain=GAIN, clip=clip)
    assert b.saturated[cfa >= clip].all()
    use = ~a.saturated & ~b.saturated & (a.pixels.min(axis=2) > 1000)
    ratio = b.pixels.astype(np.float64)[use] / a.pixels[use] / 4.0
    assert np.abs(ratio - 1).max() < 0.06


@pytest.mark.parametrize("orientation,rot", [(3, 2), (6, -1), (8, 1)])
def test_orientation(rawpy_mod, radiance, tmp_path, orientation, rot):
    cfa = rawgen.mosaic(radiance, 1.0, gain=GAIN)
    up = hr.read_raw(rawgen.write_dng(tmp_path / "u.dng", cfa, exposure_time=1.0))
    path = rawgen.write_dng(tmp_path / f"o{orientation}.dng", cfa, exposure_time=1.0, orientation=orientation)
    info = hr.read_raw_info(path)
    turned = hr.read_raw(path)
    assert turned.pixels.shape == (info.height, info.width, 3)
    np.testing.assert_array_equal(turned.pixels, np.rot90(up.pixels, rot))
    np.testing.assert_array_equal(turned.saturated, np.rot90(up.saturated, rot))


def test_white_balance(rawpy_mod, radiance, tmp_path):
    cfa = rawgen.mosaic(radiance, 0.25, gain=GAIN)
    neutral = hr.read_raw(rawgen.write_dng(tmp_path / "n.dng", cfa, exposure_time=0.25))
    warm_path = rawgen.write_dng(tmp_path / "w.dng", cfa, exposure_time=0.25, neutral=(0.5, 1.0, 0.8))
    warm = hr.read_raw(warm_path)
    np.testing.assert_allclose(warm.white_balance[:3], [2.0, 1.0, 1.25], rtol=1e-5)
    assert hr.camera_white_balance(warm_path) == warm.white_balance
    use = ~warm.saturated & (neutral.pixels.min(axis=2) > 1000)
    gains = np.median(warm.pixels.astype(np.float64)[use] / neutral.pixels[use], axis=0)
    np.testing.assert_allclose(gains, [2.0, 1.0, 1.25], rtol=0.01)
    # A bracket shares the first frame's multipliers, whatever each frame's as-shot WB.
    same = hr.read_raw(rawgen.write_dng(tmp_path / "n2.dng", cfa, exposure_time=0.25),
                       white_balance=warm.white_balance)
    np.testing.assert_array_equal(same.pixels, warm.pixels)
    # LibRaw's daylight multipliers for these primaries are 1 within float rounding.
    daylight = hr.read_raw(warm_path, white_balance="daylight")
    np.testing.assert_allclose(daylight.pixels, neutral.pixels, rtol=0.01, atol=2)
    with pytest.raises(ValueError):
        hr.read_raw(warm_path, white_balance="tungsten")


def test_merge_end_to_end(bracket, radiance):
    frames, times = bracket["frames"], bracket["times"]
    rad = hdrcl.merge([f.pixels for f in frames], times, response=linear_response())
    assert rad.shape == (H, W, 3) and rad.dtype == np.float32
    measured = ~frames[0].saturated  # unclipped in the shortest frame at least
    q = rad[measured].astype(np.float64) / radiance[measured]
    scale = np.median(q)
    err = np.abs(q / scale - 1)
    assert np.median(err) < 0.03
    # Pixels clipped in the longer frames come from the shorter ones, unbiased.
    from_short = measured & frames[-1].saturated
    assert from_short.sum() > 500
    assert np.median(np.abs(rad[from_short] / radiance[from_short] / scale - 1)) < 0.03
    # Radiance is relative to a 1 s exposure reading Zmid: scale = gain * 65535/range / 32768.
    assert scale == pytest.approx(GAIN * 65535 / (rawgen.WHITE - rawgen.BLACK) / 32768, rel=0.02)


def test_unreadable_files(rawpy_mod, tmp_path):
    with pytest.raises(InputError, match="no such file"):
        hr.read_raw(tmp_path / "missing.nef")
    bad = tmp_path / "bad.cr2"
    bad.write_bytes(b"this is not a raw file" * 100)
    for fn in (hr.read_raw, hr.read_raw_info):
        with pytest.raises(InputError) as err:
            fn(bad)
        assert str(err.value).startswith(f"{bad}: ")
    empty = tmp_path / "empty.arw"
    empty.write_bytes(b"")
    with pytest.raises(InputError, match="empty file"):
        hr.read_raw_info(empty)


def test_cli_merge_of_raw_files_skips_calibration(bracket, radiance, tmp_path):
    """RAW files through the command line: EXIF times from the files, a linear curve,
    strips served from whole decoded frames, the same radiance as the array path."""
    from click.testing import CliRunner

    from hdrcl.cli import main
    from hdrcl.io.radiance import read_radiance

    out = tmp_path / "raw.exr"
    r = CliRunner().invoke(main, ["merge", *bracket["paths"], "-o", str(out), "--dtype", "float"])
    assert r.exit_code == 0, r.output
    rad, meta = read_radiance(str(out))
    assert meta["response"] == "linear (RAW input)"
    frames = [hr.read_raw(p, white_balance=hr.camera_white_balance(bracket["paths"][0])).pixels
              for p in bracket["paths"]]
    want = hdrcl.merge(frames, bracket["times"], response=linear_response())
    np.testing.assert_allclose(rad, want, rtol=1e-5)
    r = CliRunner().invoke(main, ["calibrate", *bracket["paths"], "-o", str(tmp_path / "r.json")])
    assert r.exit_code == 0, r.output
    assert Response.load(tmp_path / "r.json").knots.size == 65536


def test_mixing_raw_and_jpeg_is_an_error(bracket, tmp_path):
    from hdrcl.io.reader import BracketReader

    jpg = tmp_path / "x.jpg"
    from hdrcl.io.ldr import write_ldr

    f = hr.read_raw(bracket["paths"][0]).pixels
    write_ldr(str(jpg), (f >> 8).astype(np.uint8))
    with pytest.raises(InputError, match="mixes RAW"):
        BracketReader([bracket["paths"][0], str(jpg)])
