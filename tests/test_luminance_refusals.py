"""Luminance maps the commands must refuse, and numbers at the ends of the float range
(issue 34): negative light, an EXPOSURE= that overflows, a calibration factor no map can
hold, a patch far outside the map, log scales of 400 decades, multipliers near the
largest float. Every refusal is one line naming the file or option, with its exit code."""
import json
import warnings

import numpy as np
import pytest
from click.testing import CliRunner

import hdrcl.cli.falsecolor  # noqa: F401  (registers the commands)
import hdrcl.cli.glare  # noqa: F401
from hdrcl.cli.group import main
from hdrcl.core.luminance import glare as g
from hdrcl.errors import InputError
from hdrcl.io.writers import write_radiance

VIEW = "-vta -vh 180 -vv 180"


def rgbe_file(path, rgb, header=(), resolution=None):
    """A flat (uncompressed) Radiance picture of ``rgb`` (H, W, 3), rows top first unless
    ``resolution`` says otherwise, with extra header lines; written byte by byte, so no
    Radiance program is needed."""
    rgb = np.asarray(rgb, np.float64)
    h, w, _ = rgb.shape
    top = rgb.max(axis=-1)
    exp = np.where(top > 1e-32, np.floor(np.log2(np.where(top > 1e-32, top, 1.0))) + 1, 0).astype(int)
    scale = np.where(top > 1e-32, 256.0 / np.exp2(exp), 0.0)
    mant = np.clip(np.floor(rgb * scale[..., None]), 0, 255).astype(np.uint8)
    e = np.where(top > 1e-32, exp + 128, 0).astype(np.uint8)
    rows = np.concatenate([mant, e[..., None]], axis=-1)
    head = "#?RADIANCE\n" + "".join(f"{line}\n" for line in header) + "FORMAT=32-bit_rle_rgbe\n\n"
    res = resolution or f"-Y {h} +X {w}"
    with open(path, "wb") as f:
        f.write(head.encode() + f"{res}\n".encode() + rows.tobytes())


def _chain_map(path, lum, view=VIEW):
    rgb = np.repeat((np.asarray(lum) / 179.0)[..., None], 3, axis=2).astype(np.float32)
    meta = {"units": "cd/m2", "luminanceChain": json.dumps({"calibrationFactor": 1.0})}
    write_radiance(path, rgb, metadata=meta, camera={"units": "cd/m2", "view": view})


def _one_line_error(result, code, *words):
    assert result.exit_code == code, result.output
    lines = [x for x in result.output.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("hdrcl: error: "), result.output
    assert "internal error" not in result.output and "Warning" not in result.output
    for w in words:
        assert w in lines[0], lines[0]


def test_glare_refuses_negative_light_with_exit_3(tmp_path):
    """All-negative luminances gave Ev -30.7 lx and an average of -16.7 cd/m2, exit 0."""
    path = tmp_path / "neg.exr"
    _chain_map(path, np.full((40, 40), -16.7))
    _one_line_error(CliRunner().invoke(main, ["glare", str(path)]), 3, "neg.exr", "negative luminance")
    with pytest.raises(InputError, match="negative"):
        g.glare_metrics(np.full((20, 20), -5.0), g.parse_glare_view(VIEW))
    r = CliRunner().invoke(main, ["calibrate-luminance", str(path), "--illuminance", "100", "-o",
                                  str(tmp_path / "K.cal")])
    _one_line_error(r, 3, "neg.exr")
    assert not (tmp_path / "K.cal").exists()


def test_exposure_that_overflows_is_refused_by_glare_falsecolor_and_tonemap(tmp_path):
    """EXPOSURE=1e-38: the non-finite check ran before the division; falsecolor drew a
    legend 0..2e40 with the window 'no luminance', glare crashed (NaN to integer)."""
    rgb = np.full((16, 16, 3), 0.5)
    rgb[4:12, 4:12] = 100.0
    path = tmp_path / "exp.hdr"
    rgbe_file(path, rgb, header=[f"VIEW= {VIEW}", "EXPOSURE=1e-38"])
    for args in (["glare", str(path)], ["falsecolor", str(path), "-o", str(tmp_path / "fc.png")],
                 ["tonemap", str(path), "-o", str(tmp_path / "tm.png")]):
        _one_line_error(CliRunner().invoke(main, args), 3, "exp.hdr", "EXPOSURE=")
    assert not (tmp_path / "fc.png").exists() and not (tmp_path / "tm.png").exists()
    # a small EXPOSURE that stays in range is read as before
    rgbe_file(path, rgb, header=[f"VIEW= {VIEW}", "EXPOSURE=1e-30"])
    assert CliRunner().invoke(main, ["glare", str(path)]).exit_code == 0


def test_calibration_factor_no_map_can_hold_is_refused_where_it_is_made(tmp_path):
    """--illuminance 1e300 wrote K = 3.62e298, which merge --calibration-factor refused."""
    path = tmp_path / "m.hdr"
    _chain_map(path, np.full((40, 40), 100.0))
    r = CliRunner().invoke(main, ["calibrate-luminance", str(path), "--illuminance", "1e300", "-o",
                                  str(tmp_path / "K.cal")])
    _one_line_error(r, 2, "--illuminance")
    assert not (tmp_path / "K.cal").exists()


@pytest.mark.parametrize("patch", ["1e200,1e200,1e200", "500,500,3", "-1e200,20,1e199"])
def test_patch_holding_no_pixel_centre_is_refused(tmp_path, patch):
    """Squared distances of 1e200 overflowed to inf: every pixel fell inside, K came from
    the whole map, with a NumPy warning."""
    path = tmp_path / "m.hdr"
    _chain_map(path, np.full((40, 40), 100.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = CliRunner().invoke(main, ["calibrate-luminance", str(path), "--luminance", "50", "--patch", patch,
                                      "-o", str(tmp_path / "K.cal")])
    _one_line_error(r, 2, "--patch", "no pixel centre")


def test_a_patch_covering_the_map_still_calibrates(tmp_path):
    path = tmp_path / "m.hdr"
    _chain_map(path, np.full((40, 40), 100.0))
    r = g.calibration_from_measurement(path, luminance=50.0, patch="20,20,1e200")
    assert r["calibration_factor"] == pytest.approx(0.5, rel=1e-2)  # RGBE steps
