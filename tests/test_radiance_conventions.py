"""Radiance's conventions for .hdr, with Radiance's own programs (pyradiance) as the oracle:
RGBE decoded with Radiance's +0.5, EXPOSURE= lines multiplied, maps in cd/m^2 stored in
Radiance's units (x 179 = cd/m^2) with no EXPOSURE= line, older hdrcl files recognised."""
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from hdrcl.core.luminance.fisheye_math import radiance_luminance
from hdrcl.io.radiance import read_radiance

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "frobisher_001"


def _run(radiance_bin, prog, *args, stdin=None, stdout=None):
    return subprocess.run([str(radiance_bin / prog), *map(str, args)], input=stdin, stdout=stdout or subprocess.PIPE,
                          stderr=subprocess.PIPE, timeout=120, check=True).stdout


def _pvalue_floats(radiance_bin, path, *flags):
    return np.frombuffer(_run(radiance_bin, "pvalue", "-h", "-H", "-df", *flags, path), np.float32)


def _picture(radiance_bin, path, img, header=()):
    """A Radiance picture of ``img`` written by Radiance (pvalue -r), header lines added by getinfo -a."""
    h, w, _ = img.shape
    data = _run(radiance_bin, "pvalue", "-r", "-h", "-df", "-y", h, "+x", w, stdin=img.astype(np.float32).tobytes())
    if header:
        data = _run(radiance_bin, "getinfo", "-a", *header, stdin=data)
    Path(path).write_bytes(data)


def test_rgbe_is_decoded_as_radiance_does(tmp_path, radiance_bin):
    rng = np.random.default_rng(5)
    img = np.exp(rng.normal(0, 3, (31, 47, 3))).astype(np.float32)
    img[3, 4] = 0
    _picture(radiance_bin, tmp_path / "p.hdr", img)
    want = _pvalue_floats(radiance_bin, tmp_path / "p.hdr").reshape(img.shape)
    got, _ = read_radiance(tmp_path / "p.hdr")
    np.testing.assert_array_equal(got, want)  # exactly Radiance's values, +0.5 included
    # and hdrcl's own RGBE encoder's files
    from hdrcl.io.writers import write_radiance

    write_radiance(tmp_path / "own.hdr", img)
    want = _pvalue_floats(radiance_bin, tmp_path / "own.hdr", "-o").reshape(img.shape)
    got, _ = read_radiance(tmp_path / "own.hdr")
    np.testing.assert_allclose(got, want, rtol=1e-6)


def test_exposure_lines_multiply(tmp_path, radiance_bin):
    img = np.full((4, 5, 3), 3.0, np.float32)
    _picture(radiance_bin, tmp_path / "e.hdr", img, header=("EXPOSURE=2", "EXPOSURE=3"))
    want = _pvalue_floats(radiance_bin, tmp_path / "e.hdr", "-o").reshape(img.shape)  # original values
    got, _ = read_radiance(tmp_path / "e.hdr")
    np.testing.assert_allclose(got, want, rtol=1e-6)
    np.testing.assert_allclose(got, 3.0 / 6.0, rtol=5e-3)


def _old_hdrcl_file(path, radiance_bin, cd, meta):
    """A .hdr as hdrcl wrote them before Radiance's units: cd/m^2 stored directly, EXPOSURE=1."""
    text = json.dumps(meta, separators=(",", ":"))
    _picture(radiance_bin, path, cd, header=("SOFTWARE=hdrcl 0.1.0", "EXPOSURE=1.000000e+00", f"HDRCL={text}"))


def test_older_absolute_files_are_recognised_and_read_in_cd_m2(tmp_path, radiance_bin):
    from hdrcl.report.falsecolor import read_luminance

    cd = np.full((6, 8, 3), 150.8, np.float32)
    _old_hdrcl_file(tmp_path / "old.hdr", radiance_bin, cd, {"units": "cd/m2 (approximate)", "scale": 8.0})
    got, meta = read_radiance(tmp_path / "old.hdr")
    np.testing.assert_allclose(got, 150.8, rtol=5e-3)
    np.testing.assert_allclose(read_luminance(tmp_path / "old.hdr"), 150.8, rtol=5e-3)
    # an older luminance-chain map stored Radiance's units already (luminanceChain on its line)
    _old_hdrcl_file(tmp_path / "chain.hdr", radiance_bin, cd / 179.0, {"units": "cd/m2", "luminanceChain": "{}"})
    np.testing.assert_allclose(read_luminance(tmp_path / "chain.hdr"), 150.8, rtol=5e-3)
    # a Radiance tool indents the header: still read right (was 179x high)
    indented = _run(radiance_bin, "pcomb", "-e", "ro=ri(1);go=gi(1);bo=bi(1)", tmp_path / "chain.hdr")
    (tmp_path / "chain-pcomb.hdr").write_bytes(indented)
    assert b"\tHDRCL=" in indented or b"\t\tHDRCL=" in indented
    np.testing.assert_allclose(read_luminance(tmp_path / "chain-pcomb.hdr"), 150.8, rtol=5e-3)


@pytest.fixture(scope="module")
def absolute_merge(tmp_path_factory):
    from click.testing import CliRunner

    from hdrcl.cli import main

    frames = sorted(str(p) for p in DATA.glob("*.jpg"))
    if not frames:
        pytest.skip(f"the sample data {DATA} is not here")
    d = tmp_path_factory.mktemp("absolute")
    for name, extra in (("a.hdr", []), ("a.exr", ["--dtype", "float"]),
                        ("fish.hdr", ["--lens-circle", "320,213,400", "--resize", "200",
                                      "--view", "-vta -vh 180 -vv 180"])):
        res = CliRunner().invoke(main, ["merge", *frames, "--absolute", "-o", str(d / name), *extra])
        assert res.exit_code == 0, res.output
    return d


def test_radiance_reads_the_absolute_hdr_at_hdrcl_cd_m2(absolute_merge, radiance_bin):
    d = absolute_merge
    head = (d / "a.hdr").read_bytes().split(b"\n\n")[0].decode()
    assert "EXPOSURE" not in head  # a map in cd/m^2 has no exposure to undo
    exr, _ = read_radiance(d / "a.exr")
    ref = radiance_luminance(exr)
    rad = _pvalue_floats(radiance_bin, d / "a.hdr", "-b").reshape(ref.shape) * 179.0  # Radiance's cd/m^2
    ok = ref > 0
    ratio = rad[ok] / ref[ok]
    assert abs(float(np.median(ratio)) - 1.0) <= 0.01, float(np.median(ratio))
    assert float(np.percentile(np.abs(ratio - 1), 99)) < 0.01  # RGBE's 8-bit mantissa
    own, _ = read_radiance(d / "a.hdr")  # hdrcl reads its .hdr back in cd/m^2
    np.testing.assert_allclose(np.median(radiance_luminance(own)[ok] / ref[ok]), 1.0, atol=2e-3)


def test_evalglare_takes_the_chain_map_after_pcomb(absolute_merge, radiance_bin):
    """No EXPOSURE= line for pcomb to indent (evalglare refuses an indented one); its
    vertical illuminance equals hdrcl's."""
    d = absolute_merge
    out = d / "fish-pcomb.hdr"
    out.write_bytes(_run(radiance_bin, "pcomb", "-e", "ro=ri(1);go=gi(1);bo=bi(1)", d / "fish.hdr"))
    run = subprocess.run([str(radiance_bin / "evalglare"), "-V", str(out)], capture_output=True, text=True,
                         timeout=120)
    assert "invalid exposure" not in run.stderr, run.stderr
    ev = float(run.stdout.split()[-1])
    head = (d / "fish.hdr").read_bytes().split(b"\n\n")[0].decode().split("\n")
    ours = float(next(x for x in head if x.startswith("VERTICAL_ILLUMINANCE=")).split("=")[1])
    assert ev == pytest.approx(ours, rel=5e-3)


@pytest.mark.parametrize("resolution", ["-y 5 +x 7", "+y 5 +x 7", "-y 5 -x 7", "+y 5 -x 7", "+x 7 -y 5",
                                        "-x 7 +y 5", "+x 7 +y 5", "-x 7 -y 5"])
def test_resolution_line_orientation_as_radiance_reads_it(tmp_path, radiance_bin, resolution):
    """A picture stored ``+Y 5 +X 7`` (bottom scanline first) or column-major is read in
    picture order, top row first, as Radiance's ra_tiff says (its TIFF Orientation tag,
    applied by OpenImageIO's reorient); OpenImageIO alone returns the file's scanline
    order, and tonemap wrote such a map upside down."""
    import OpenImageIO as oiio

    from hdrcl.io.radiance import radiance_header

    values = np.arange(35, dtype=np.float32) + 1.0
    data = _run(radiance_bin, "pvalue", "-r", "-h", "-df", *resolution.split(),
                stdin=np.repeat(values, 3).astype(np.float32).tobytes())
    (tmp_path / "o.hdr").write_bytes(data)
    _run(radiance_bin, "ra_tiff", "-f", tmp_path / "o.hdr", tmp_path / "o.tif")
    want = oiio.ImageBufAlgo.reorient(oiio.ImageBuf(str(tmp_path / "o.tif"))).get_pixels(oiio.FLOAT)[..., 0]
    got, _ = read_radiance(tmp_path / "o.hdr")
    assert got.shape[:2] == (5, 7) and radiance_header(tmp_path / "o.hdr")[:2] == (7, 5)
    np.testing.assert_allclose(got[..., 0], want, rtol=0.01)


def test_tonemap_of_a_bottom_first_hdr_is_upright(tmp_path, radiance_bin):
    """The same picture stored ``-Y`` and ``+Y``: tonemap writes the same PNG."""
    from click.testing import CliRunner

    from hdrcl.cli import main

    img = np.full((24, 32, 3), 0.05, np.float32)
    img[2:6, 3:9] = 5.0  # a bright patch near the top left
    _picture(radiance_bin, tmp_path / "top.hdr", img)
    data = _run(radiance_bin, "pvalue", "-r", "-h", "-df", "+y", 24, "+x", 32, stdin=img[::-1].tobytes())
    (tmp_path / "bottom.hdr").write_bytes(data)
    for name in ("top", "bottom"):
        r = CliRunner().invoke(main, ["tonemap", str(tmp_path / f"{name}.hdr"), "-o", str(tmp_path / f"{name}.png")])
        assert r.exit_code == 0, r.output
    import OpenImageIO as oiio

    a = oiio.ImageInput.open(str(tmp_path / "top.png")).read_image(0, 0, 0, 3, "uint8")
    b = oiio.ImageInput.open(str(tmp_path / "bottom.png")).read_image(0, 0, 0, 3, "uint8")
    assert a[3, 5].max() > a[20, 20].max() and np.array_equal(a, b)
