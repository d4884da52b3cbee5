"""hdrcl falsecolor: luminance read in cd/m^2 from .hdr (179 convention) and EXR, the
colour scale against its formula, the legend, and the command's errors."""
import math

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli.group import main
from hdrcl.core.fisheye_math import RADIANCE_LUMA
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
def test_colour_index_against_its_formula(scale, lo, hi):
    lum = _luminance_field()
    t = fc.colour_index(lum, scale, lo, hi)
    pos = lum > 0
    if scale == "linear":
        want = (lum - lo) / (hi - lo)
    else:
        want = (np.log10(np.where(pos, lum, 1)) - math.log10(lo)) / (math.log10(hi) - math.log10(lo))
    np.testing.assert_allclose(t[pos], np.clip(want, 0, 1)[pos], rtol=1e-12, atol=1e-15)
    assert np.all(t[~pos] == 0)
    rgb = fc.palette(t)
    assert np.all(np.diff(rgb[60, :, 2][t[60] < 0.2]) >= 0)  # the low end is blue, brightening
    assert rgb[60, np.argmax(t[60])].tolist() == pytest.approx(fc.palette(np.array([t[60].max()]))[0].tolist())


def test_defaults_and_legend(tmp_path):
    lum = _luminance_field()
    assert fc.nice_max(1234.0) == 2000.0 and fc.nice_max(5000.0) == 5000.0 and fc.nice_max(0.031) == 0.05
    picture, (lo, hi) = fc.render(lum, scale="log")
    assert (lo, hi) == (10.0, 1e5)  # max rounded up, 4 decades below it
    h, w = lum.shape
    assert picture.shape[0] == h and picture.shape[1] > w and picture.dtype == np.uint8
    assert np.all(picture[:10, :10] == 0)  # no luminance: black
    pane = picture[:, w:]
    assert pane.max() == 255 and (pane == 255).all(axis=2).sum() > 100  # white legend text and ticks
    assert fc.text_mask("10e5", 1).shape == (5, 4 * 3 + 3)


def test_command_writes_png(tmp_path):
    lum = _luminance_field()
    write_radiance(tmp_path / "m.exr", np.repeat(lum[..., None], 3, 2).astype(np.float32), dtype="float",
                   metadata={"units": "cd/m2"})
    r = CliRunner().invoke(main, ["falsecolor", str(tmp_path / "m.exr"), "-o", str(tmp_path / "fc.png"),
                                  "--scale", "log", "--max", "1e5", "--min", "10"])
    assert r.exit_code == 0, r.output
    assert "log scale 10 .. 100000 cd/m2" in r.output
    px = _read_png(tmp_path / "fc.png")
    t = fc.colour_index(lum, "log", 10.0, 1e5)
    want = np.round(fc.palette(t) * 255)
    want[lum <= 0] = 0
    # the file holds float32 luminance: a code may round the other way
    np.testing.assert_allclose(px[:, :lum.shape[1]].astype(int), want.astype(int), atol=1, rtol=0)


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
