"""hdrcl falsecolor: luminance read in cd/m^2 from .hdr (179 convention) and EXR, the
colour scale against its formula, the legend, and the command's errors."""
import math

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli.group import main
from hdrcl.core.luminance.fisheye_math import RADIANCE_LUMA
from hdrcl.io.writers import write_radiance
from hdrcl.report import falsecolor as fc


def _luminance_field(h=120, w=160):
    """cd/m^2 from 10 to 10^5 left to right, grey; a black disc corner (outside a lens)."""
    lum = 10.0 ** np.linspace(1.0, 5.0, w)[None, :].repeat(h, 0)
    lum[:10, :10] = 0.0
    return lum


def _read_png(path):
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(path))
    return np.asarray(buf.get_pixels(oiio.UINT8))


def test_hdr_is_read_in_radiance_179_convention(tmp_path):
    lum = _luminance_field()
    tint = np.array([1.1, 1.0, 0.8])
    rgb = lum[..., None] * tint / (tint @ RADIANCE_LUMA) / 179.0  # stored W/sr/m2
    write_radiance(tmp_path / "m.hdr", rgb.astype(np.float32), camera={"units": "cd/m2"})
    got = fc.read_luminance(tmp_path / "m.hdr")
    np.testing.assert_allclose(got, lum, rtol=0.01)  # RGBE: about 1 %


def test_exr_needs_its_units(tmp_path):
    from hdrcl.errors import InputError

    lum = _luminance_field()
    write_radiance(tmp_path / "cd.exr", np.repeat(lum[..., None], 3, 2).astype(np.float32), dtype="float",
                   metadata={"units": "cd/m2"})
    np.testing.assert_allclose(fc.read_luminance(tmp_path / "cd.exr"), lum, rtol=1e-6)
    write_radiance(tmp_path / "rel.exr", np.ones((8, 8, 3), np.float32), metadata={"referenceExposure": 0.5})
    with pytest.raises(InputError, match="rel.exr: not a luminance map"):
        fc.read_luminance(tmp_path / "rel.exr")


@pytest.mark.parametrize("scale,lo,hi", [("linear", 0.0, 2e5), ("log", 20.0, 5e4), ("linear", 1e3, 1e4)])
def test_colour_index_is_radiance_v(scale, lo, hi):
    """Radiance's falsecolor: v = L/max (linear), log10(L/max)/decades + 1 above max/10^decades, else 0;
    not clipped (the palette clamps)."""
    lum = _luminance_field()
    v = fc.colour_index(lum, scale, lo, hi)
    pos = lum > 0
    if scale == "linear":
        want = np.maximum((lum - lo) / (hi - lo), 0)
    else:
        d = math.log10(hi / lo)
        r = np.where(pos, lum, 1) / hi
        want = np.where(r > 10 ** -d, np.log10(r) / d + 1, 0)
    np.testing.assert_allclose(v[pos], want[pos], rtol=1e-12, atol=1e-15)
    assert np.all(v[~pos] == 0)


def test_palettes_are_radiance_formulas():
    k = np.arange(23)
    np.testing.assert_allclose(fc.palette(k * 0.0454545, "def"), fc.DEF_TABLE, atol=1e-9)
    mid = fc.palette(np.array([0.5 * 0.0454545]), "def")[0]
    np.testing.assert_allclose(mid, (fc.DEF_TABLE[0] + fc.DEF_TABLE[1]) / 2, rtol=1e-6)
    assert fc.palette(np.array([-1.0, 7.0]), "def").tolist() == [fc.DEF_TABLE[0].tolist(), fc.DEF_TABLE[22].tolist()]
    v = np.linspace(0, 1, 101)
    spec = fc.palette(v, "spec")
    np.testing.assert_allclose(spec[:, 0], np.clip(1.6 * v - 0.6, 0, 1))
    np.testing.assert_allclose(spec[:, 1], np.clip(np.where(v > 0.375, 1.6 - 1.6 * v, 8 / 3 * v), 0, 1))
    np.testing.assert_allclose(spec[:, 2], np.clip(1 - 8 / 3 * v, 0, 1))
    np.testing.assert_allclose(fc.palette(v, "hot")[:, 0], np.clip(3 * v, 0, 1) ** 2.2)
    assert fc.display_codes(np.array([0.0, 1.0, 0.5])).tolist() == [0, 255, int(256 * 0.5 ** (1 / 2.2))]


def test_defaults_show_the_map_not_the_sun():
    lum = _luminance_field()
    assert fc.nice_max(1234.0) == 2000.0 and fc.nice_max(5000.0) == 5000.0 and fc.nice_max(0.031) == 0.05
    assert fc.scale_limits(lum, "log", None, None) == (10.0, 1e5)  # power of ten above, down to the 1st percentile
    sky = np.full((100, 100), 3000.0)
    sky[50:53, 50:53] = 1e9  # a sun of 9 pixels
    lo, hi = fc.scale_limits(sky, "linear", None, None)
    assert (lo, hi) == (0.0, 5000.0)  # the 99th percentile, rounded up: the sky is mid-scale, not dark blue


@pytest.mark.parametrize("shape", [(1, 1), (8, 8), (3, 40)])
def test_tiny_maps_get_a_whole_legend(tmp_path, shape):
    """Issue 29: a 1x1 map and a --resize 8 map crashed (the legend needs about 14 rows)."""
    lum = np.full(shape, 150.8)
    picture, _ = fc.render(lum)
    assert picture.shape[0] >= fc.legend_height(8, 1) and picture.shape[1] > shape[1]
    assert np.all(picture[shape[0]:, :shape[1]] == 0)  # padded with black below the map
    write_radiance(tmp_path / "one.exr", np.full(shape + (3,), 150.8, np.float32), dtype="float",
                   metadata={"units": "cd/m2"})
    r = CliRunner().invoke(main, ["falsecolor", str(tmp_path / "one.exr"), "-o", str(tmp_path / "one.png")])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "one.png").exists()


def test_contours_extrema_and_multiplier(tmp_path):
    ramp = np.tile(np.linspace(1.0, 999.0, 200), (60, 1))
    lines, _ = fc.render(ramp, hi=1000.0, contour="lines")
    map_part = lines[:, :200]
    coloured = map_part.any(axis=2).any(axis=0)
    # a line where floor(8 v + 0.5) changes: at v = 1/16, 3/16, ... (7 lines inside 0..1)
    assert 7 <= int(np.sum(np.diff(coloured.astype(int)) == 1)) <= 8
    bands, _ = fc.render(ramp, hi=1000.0, contour="bands")
    share = bands[:, :200].any(axis=2).mean()
    assert 0.1 < share < 0.25  # frac(8 v) in 0.4..0.6: a fifth of the ramp, less the ends
    plain, _ = fc.render(ramp, hi=1000.0)
    marked, _ = fc.render(ramp, hi=1000.0, show_extrema=True)
    assert not np.array_equal(plain[:20, :40], marked[:20, :40])  # the minimum's label at its pixel (0, 0)
    assert (fc.extrema(ramp)[1][1], fc.extrema(ramp)[0][2]) == (199, 1.0)
    write_radiance(tmp_path / "r.exr", np.repeat(ramp[..., None], 3, 2).astype(np.float32), dtype="float",
                   metadata={"units": "cd/m2"})
    limits = fc.falsecolor_file(tmp_path / "r.exr", tmp_path / "r.png", multiplier=3.14159, label="lux")
    assert limits == (0.0, 5000.0)  # 3.14 x ~990 -> 5000


def test_command_writes_png(tmp_path):
    lum = _luminance_field()
    write_radiance(tmp_path / "m.exr", np.repeat(lum[..., None], 3, 2).astype(np.float32), dtype="float",
                   metadata={"units": "cd/m2"})
    r = CliRunner().invoke(main, ["falsecolor", str(tmp_path / "m.exr"), "-o", str(tmp_path / "fc.png"),
                                  "--scale", "log", "--max", "1e5", "--min", "10", "--palette", "spec"])
    assert r.exit_code == 0, r.output
    assert "log scale 10 .. 100000 cd/m2" in r.output
    px = _read_png(tmp_path / "fc.png")
    want = fc.display_codes(fc.palette(fc.colour_index(lum, "log", 10.0, 1e5), "spec"))
    # the file holds float32 luminance: a code may round the other way
    np.testing.assert_allclose(px[:lum.shape[0], :lum.shape[1]].astype(int), want.astype(int), atol=1, rtol=0)


def test_display_codes_equal_radiance_ra_ppm(tmp_path, radiance_bin):
    """A picture of the default palette converted by Radiance (ra_ppm, gamma 2.2) has hdrcl's codes."""
    import subprocess

    v = np.linspace(0, 1.05, 64)
    rgb = np.repeat(fc.palette(v, "def")[None], 4, axis=0).astype(np.float32)
    pic = subprocess.run([str(radiance_bin / "pvalue"), "-r", "-h", "-df", "-y", "4", "+x", "64"],
                         input=rgb.tobytes(), capture_output=True, check=True).stdout
    ppm = subprocess.run([str(radiance_bin / "ra_ppm")], input=pic, capture_output=True, check=True).stdout
    codes = np.frombuffer(ppm, np.uint8)[-4 * 64 * 3:].reshape(4, 64, 3)
    # the colours as the picture holds them (RGBE: 8 bits of each pixel's largest channel)
    held = np.frombuffer(subprocess.run([str(radiance_bin / "pvalue"), "-h", "-H", "-df"], input=pic,
                                        capture_output=True, check=True).stdout, np.float32).reshape(4, 64, 3)
    diff = np.abs(codes.astype(int) - fc.display_codes(held).astype(int))
    small = held < 0.02 * held.max(axis=-1, keepdims=True)  # Radiance's gamma table at a mantissa of 0 or 1
    assert diff[~small].max() <= 1 and diff[small].max() <= 4


@pytest.mark.parametrize("args,code,text", [
    (["--scale", "log", "--min", "0"], 2, "--min:"),
    (["--max", "-5"], 2, "--max:"),
    (["--scale", "cubic"], 2, "--scale"),
])
def test_command_errors(tmp_path, args, code, text):
    write_radiance(tmp_path / "m.hdr", np.ones((8, 8, 3), np.float32))
    r = CliRunner().invoke(main, ["falsecolor", str(tmp_path / "m.hdr"), "-o", str(tmp_path / "fc.png")] + args)
    assert r.exit_code == code and text in r.output
    assert not (tmp_path / "fc.png").exists()


def test_command_refuses_relative_map_with_exit_3(tmp_path):
    write_radiance(tmp_path / "rel.exr", np.ones((8, 8, 3), np.float32), metadata={"referenceExposure": 0.5})
    r = CliRunner().invoke(main, ["falsecolor", str(tmp_path / "rel.exr"), "-o", str(tmp_path / "fc.png")])
    assert r.exit_code == 3 and "rel.exr: not a luminance map" in r.output


def _ramp_map(path):
    lum = np.geomspace(1.0, 2e4, 64 * 64).reshape(64, 64)
    lum[0, 0] = 144.6
    write_radiance(path, np.repeat((lum / 179.0)[..., None], 3, axis=2).astype(np.float32),
                   metadata={"units": "cd/m2", "luminanceChain": '{"calibrationFactor": 1.0}'})
    return lum


def test_log_scale_of_400_decades_puts_144_cd_near_the_middle(tmp_path):
    """--min 1e-200 --max 1e200: max / min overflowed, the decades were inf and every pixel
    got the top colour; 144.6 cd/m2 sits at v = 0.505."""
    v = fc.colour_index(np.array([144.6, 1e-300, 1e199]), "log", 1e-200, 1e200)
    assert v[0] == pytest.approx((math.log10(144.6) - 200) / 400 + 1, rel=1e-12) and v[1] == 0.0
    assert v[2] == pytest.approx(0.9975)
    _ramp_map(tmp_path / "m.hdr")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = CliRunner().invoke(main, ["falsecolor", str(tmp_path / "m.hdr"), "-o", str(tmp_path / "fc.png"),
                                      "--scale", "log", "--min", "1e-200", "--max", "1e200"])
    assert r.exit_code == 0, r.output
    img = _read_png(tmp_path / "fc.png")
    top = (fc.display_codes(fc.palette(np.array([1.0])))[0]).astype(int)
    mid = (fc.display_codes(fc.palette(np.array([0.505])))[0]).astype(int)
    assert np.abs(img[0, 0, :3].astype(int) - mid).max() <= 1 and np.abs(img[0, 0, :3].astype(int) - top).max() > 10


def test_multiplier_past_the_largest_float_names_the_multiplier(tmp_path):
    """--multiplier 1e308 blamed '--max ... not inf' (never given) after a two-line NumPy warning."""
    import warnings

    _ramp_map(tmp_path / "m.hdr")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = CliRunner().invoke(main, ["falsecolor", str(tmp_path / "m.hdr"), "-o", str(tmp_path / "fc.png"),
                                      "--multiplier", "1e308"])
    assert r.exit_code == 2, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and "--multiplier: 1e+308" in lines[0] and "m.hdr" in lines[0] and "--max" not in lines[0]
    assert not (tmp_path / "fc.png").exists()
    # just below the edge: drawn, scale in range
    r = CliRunner().invoke(main, ["falsecolor", str(tmp_path / "m.hdr"), "-o", str(tmp_path / "fc.png"),
                                  "--multiplier", "1e303"])
    assert r.exit_code == 0, r.output


@pytest.mark.parametrize("scale", ["linear", "log"])
def test_subnormal_max_draws_without_numpy_warnings(tmp_path, scale):
    """--max 1e-320 drew correctly but printed a two-line NumPy overflow warning (and with
    --scale log the default min underflowed to 0 and was refused)."""
    import warnings

    _ramp_map(tmp_path / "m.hdr")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = CliRunner().invoke(main, ["falsecolor", str(tmp_path / "m.hdr"), "-o", str(tmp_path / "fc.png"),
                                      "--max", "1e-320", "--scale", scale])
    assert r.exit_code == 0, r.output
    img = _read_png(tmp_path / "fc.png")
    top = (fc.display_codes(fc.palette(np.array([1.0])))[0]).astype(int)
    assert np.abs(img[10, 10, :3].astype(int) - top).max() <= 1  # everything above max: the top colour
