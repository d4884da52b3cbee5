"""What the output files carry: ACEScg through OpenImageIO's colour management, standard
EXR attributes and Radiance header lines (read back with OpenImageIO), one time format,
warnings for options that do not apply, and curve warnings only when earned."""

import numpy as np
import pytest

oiio = pytest.importorskip("OpenImageIO")

from hdrcl.errors import UsageError  # noqa: E402
from hdrcl.io import colorspace as cs  # noqa: E402
from hdrcl.io.radiance import read_radiance, read_radiance_colorspace  # noqa: E402
from hdrcl.io.writers import write_radiance  # noqa: E402

AP1 = (0.713, 0.293, 0.165, 0.830, 0.128, 0.044, 0.32168, 0.33767)
CAMERA = {"make": "Canon", "model": "EOS 5D Mark III", "lens": "EF24-70mm f/2.8L II USM", "focal_length": 35.0,
          "fnumber": 8.0, "iso": 100.0, "exposure_time": 1.0, "owner": "Jane Doe"}


def _radiance(seed=0, shape=(31, 47, 3)):
    rng = np.random.default_rng(seed)
    return np.exp(rng.normal(0.0, 2.0, shape)).astype(np.float32)


def _spec(path):
    inp = oiio.ImageInput.open(str(path))
    try:
        return inp.spec()
    finally:
        inp.close()


def test_matrix_is_oiio_colour_management():
    """The per-strip matrix is what ImageBufAlgo.colorconvert does to every pixel."""
    img = _radiance()
    buf = oiio.ImageBuf(oiio.ImageSpec(img.shape[1], img.shape[0], 3, "float"))
    buf.set_pixels(oiio.ROI(), img)
    ref = oiio.ImageBufAlgo.colorconvert(buf, "lin_rec709_scene", "ACEScg").get_pixels(oiio.FLOAT)
    np.testing.assert_allclose(cs.convert(img, "rec709", "acescg"), ref, rtol=2e-6)
    m = cs.matrix("rec709", "acescg")
    np.testing.assert_allclose(m.sum(axis=1), 1.0, atol=1e-6)  # white stays white (D65 -> D60 adapted)
    np.testing.assert_allclose(m[0], [0.6131, 0.3395, 0.0474], atol=2e-4)  # the published matrix
    np.testing.assert_allclose(cs.matrix("acescg", "rec709") @ m, np.eye(3), atol=1e-6)
    assert np.all(cs.convert(img, "rec709", "acescg") > 0)  # AP1 holds Rec.709: positive stays positive
    with pytest.raises(UsageError, match="--colorspace: 'xyz'"):
        cs.check("xyz")


@pytest.mark.parametrize("dtype", ["float", "half"])
def test_acescg_exr_round_trip(tmp_path, dtype):
    img = _radiance()
    path = tmp_path / "ap1.exr"
    assert write_radiance(path, img, dtype=dtype, colorspace="acescg") == []
    spec = _spec(path)
    np.testing.assert_allclose(spec.getattribute("chromaticities"), AP1, atol=1e-6)
    assert spec.getattribute("oiio:ColorSpace") == "lin_ap1_scene"
    back, space = read_radiance_colorspace(path)
    assert space == "acescg"
    stored, _ = read_radiance(path)
    assert not np.allclose(stored, img, rtol=1e-2)  # the pixels really are in AP1
    # Within float (half) precision of each pixel: small channels beside large ones share its error.
    err = np.abs(cs.convert(back, "acescg", "rec709") - img).max(axis=2) / img.max(axis=2)
    assert err.max() < (1e-6 if dtype == "float" else 2e-3)
    rec, space = read_radiance_colorspace(tmp_path / "rec.exr") if write_radiance(
        tmp_path / "rec.exr", img, dtype=dtype) == [] else (None, None)
    assert space == "rec709"
    np.testing.assert_allclose(_spec(tmp_path / "rec.exr").getattribute("chromaticities"),
                               (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290), atol=1e-6)


def test_acescg_needs_exr_or_hdr(tmp_path):
    for ext in (".tif", ".pfm"):
        with pytest.raises(UsageError, match="needs an .exr or .hdr"):
            write_radiance(tmp_path / f"x{ext}", _radiance(), colorspace="acescg")
        assert not (tmp_path / f"x{ext}").exists()


def test_exr_standard_attributes(tmp_path):
    path = tmp_path / "m.exr"
    write_radiance(path, _radiance(), metadata={"units": "relative"}, timestamp="2024:06:01 10:00:00",
                   camera=CAMERA)
    spec = _spec(path)
    got = {p.name: p.value for p in spec.extra_attribs}
    # OpenImageIO's names for EXR's capDate, owner, expTime, aperture; the rest are EXR's own.
    assert got["Software"] == "hdrcl 0.1.0"
    assert got["DateTime"] == "2024:06:01 10:00:00"
    assert got["Copyright"] == "Jane Doe"
    assert got["cameraMake"] == "Canon" and got["cameraModel"] == "EOS 5D Mark III"
    assert got["lensModel"] == "EF24-70mm f/2.8L II USM"
    assert got["nominalFocalLength"] == pytest.approx(35.0)
    assert got["FNumber"] == pytest.approx(8.0) and got["isoSpeed"] == pytest.approx(100.0)
    assert got["ExposureTime"] == pytest.approx(1.0)
    assert got["hdrcl:units"] == "relative" and "hdrcl:software" not in got
    # In the file they are the standard EXR names.
    raw = path.read_bytes()[:4096]
    for name in (b"capDate", b"owner", b"expTime", b"aperture", b"isoSpeed", b"cameraMake", b"lensModel"):
        assert name + b"\0" in raw, name


def test_hdr_header_lines(tmp_path):
    img = _radiance()
    for colorspace, prim in (("rec709", b"0.6400 0.3300"), ("acescg", b"0.7130 0.2930")):
        path = tmp_path / f"{colorspace}.hdr"
        write_radiance(path, img, colorspace=colorspace, camera=CAMERA, timestamp="2024:06:01 10:00:00")
        head = path.read_bytes()[:400]
        header = head[:head.index(b"\n\n")].split(b"\n")
        assert header[:2] == [b"#?RADIANCE", b"FORMAT=32-bit_rle_rgbe"]
        assert b"SOFTWARE=hdrcl 0.1.0" in header and b"EXPOSURE=1.000000e+00" in header
        assert b"CAPDATE= 2024:06:01 10:00:00" in header
        assert any(line.startswith(b"PRIMARIES= " + prim) for line in header)
        spec = _spec(path)
        assert spec.getattribute("hdr:exposure") == pytest.approx(1.0)  # OpenImageIO reads EXPOSURE
        back, space = read_radiance_colorspace(path)
        assert space == colorspace
        # RGBE keeps about 1% of each pixel's largest channel.
        rec = cs.convert(back, colorspace, "rec709")
        err = np.abs(rec - img).max(axis=2) / img.max(axis=2)
        assert err.max() < 0.03


def test_streamed_writer_converts_and_tags(tmp_path):
    from hdrcl.io.writers import RadianceWriter

    img = _radiance(shape=(40, 23, 3))
    for ext in (".exr", ".hdr"):
        path = tmp_path / f"s{ext}"
        with RadianceWriter(path, 23, 40, 3, dtype="float", colorspace="acescg", camera=CAMERA) as w:
            for y in range(0, 40, 7):
                w.write_rows(y, min(y + 7, 40), img[y:y + 7])
        back, space = read_radiance_colorspace(path)
        assert space == "acescg"
        tol = 1e-6 if ext == ".exr" else 0.03
        rec = cs.convert(back, "acescg", "rec709")
        assert (np.abs(rec - img).max(axis=2) / img.max(axis=2)).max() < tol


def test_one_time_format():
    from hdrcl.io.metadata import format_time

    assert [format_time(t) for t in (1 / 245, 0.008163, 1 / 30, 0.25, 0.4, 2.0, 1 / 8000, 1 / 12345.6)] == [
        "1/245 s", "1/122.5 s", "1/30 s", "1/4 s", "0.4 s", "2 s", "1/8000 s", "1/12346 s"]


def test_inapplicable_options_warn(tmp_path, scene):
    from click.testing import CliRunner

    from hdrcl.cli import main
    from hdrcl.io.outmeta import inapplicable_options
    from hdrcl.io.ldr import write_photo

    assert inapplicable_options("a.exr", dtype="float", compression="piz") == []
    assert inapplicable_options("a.hdr") == []  # nothing given, nothing said
    (msg,) = inapplicable_options("a.hdr", dtype="half")
    assert "--dtype half applies to EXR only" in msg
    assert len(inapplicable_options("a.pfm", dtype="float", compression="zip")) == 2
    paths = []
    for k, f in enumerate(scene["frames"]):
        paths.append(str(tmp_path / f"f{k}.png"))
        write_photo(paths[-1], f)
    times = ",".join(f"{t:.8g}" for t in scene["times"])
    res = CliRunner().invoke(main, ["merge", *paths, "--times", times, "-o", str(tmp_path / "o.hdr"),
                                    "--dtype", "half"])
    assert res.exit_code == 0, res.output
    assert res.output.count("--dtype half applies to EXR only") == 1
    res = CliRunner().invoke(main, ["merge", *paths, "--times", times, "-o", str(tmp_path / "o.exr"),
                                    "--colorspace", "acescg"])
    assert res.exit_code == 0 and "applies to" not in res.output
    assert read_radiance_colorspace(tmp_path / "o.exr")[1] == "acescg"
    res = CliRunner().invoke(main, ["merge", *paths, "--times", times, "-o", str(tmp_path / "o.tif"),
                                    "--colorspace", "acescg"])
    assert res.exit_code == 2 and "needs an .exr or .hdr output" in res.output
    assert not (tmp_path / "o.tif").exists()


def test_small_curve_dips_are_not_reported():
    from hdrcl.core.response import Response
    from hdrcl.core.response import knot_positions

    g = np.linspace(-3, 3, 256)[None, :].copy()
    step = g[0, 1] - g[0, 0]
    g[0, 100] -= 2.5 * step  # turns back by 1.5 code levels' worth: quantisation, not a bad curve
    assert Response(bits=8, g=g, knots=knot_positions(8), channels=("Y",)).monotonic_problems() == []
    g[0, 100] -= 2.0 * step  # by 3.5 levels
    (msg,) = Response(bits=8, g=g, knots=knot_positions(8), channels=("Y",)).monotonic_problems()
    assert "not monotonic" in msg and "about 3.5 code levels" in msg


@pytest.mark.slow
def test_memorial_example_warns_only_when_earned(memorial, tmp_path):
    """The README's example: calibrate, then merge with that response and a report:
    no curve warnings (the data does not earn one), none from leave-one-out re-solves."""
    from click.testing import CliRunner

    from hdrcl.cli import main

    paths = [str(p) for p in sorted(memorial.glob("memorial*.png"))]
    common = ["--times-file", str(memorial / "image_list.txt"), "--ignore-color", "0,0,255"]
    runner = CliRunner()
    # The CLI logs through its own stderr handler (not propagated to pytest's caplog):
    # read what a user would see.
    res = runner.invoke(main, ["calibrate", *paths, *common, "-o", str(tmp_path / "m.json")])
    assert res.exit_code == 0, res.output
    seen = res.stderr
    res = runner.invoke(main, ["merge", *paths, *common, "--response", str(tmp_path / "m.json"),
                               "-o", str(tmp_path / "m.exr"), "--report", str(tmp_path / "rep")])
    assert res.exit_code == 0, res.output
    seen += res.stderr
    assert "warning" not in seen, seen
    spec = _spec(tmp_path / "m.exr")
    assert spec.getattribute("Software") == "hdrcl 0.1.0"
    # 1.0 is what the reference exposure records as white: the power of two nearest the
    # middle of 1/1024..32 s (median between 1/4 and 1/2 s), recorded as OpenEXR's expTime
    assert spec.getattribute("ExposureTime") == 0.25 == spec.getattribute("hdrcl:referenceExposure")
    assert spec.format == "half"  # measured on the data: Memorial fits half floats


def test_batch_colorspace_and_preview_operator(tmp_path):
    """``batch --colorspace acescg --tonemap filmic``: AP1 EXRs with the camera's metadata,
    filmic previews; changing only the operator rebuilds the previews, not the EXRs."""
    from click.testing import CliRunner

    from hdrcl.cli import main
    from hdrcl.io.radiance import read_metadata

    runner = CliRunner()
    shoot, out = tmp_path / "shoot", tmp_path / "out"
    assert runner.invoke(main, ["sample-shoot", str(shoot)]).exit_code == 0
    res = runner.invoke(main, ["batch", str(shoot), "-o", str(out), "--colorspace", "acescg", "--tonemap", "filmic"])
    assert res.exit_code == 0, res.output
    exrs = sorted(out.glob("*.exr"))
    assert len(exrs) == 3
    spec = _spec(exrs[0])
    np.testing.assert_allclose(spec.getattribute("chromaticities"), AP1, atol=1e-6)
    assert spec.getattribute("oiio:ColorSpace") == "lin_ap1_scene"
    assert spec.getattribute("cameraModel") == "Synthetic Camera" and spec.getattribute("Software") == "hdrcl 0.1.0"
    assert read_metadata(exrs[0].with_suffix(".jpg"))["tonemap"] == "filmic"
    before = {p.name: p.stat().st_mtime_ns for p in exrs}
    res = runner.invoke(main, ["batch", str(shoot), "-o", str(out), "--colorspace", "acescg", "--tonemap", "drago"])
    assert res.exit_code == 0, res.output
    assert {p.name: p.stat().st_mtime_ns for p in sorted(out.glob("*.exr"))} == before
    assert read_metadata(exrs[0].with_suffix(".jpg"))["tonemap"] == "drago"
    # Another colour space is another output: the EXRs are merged again.
    res = runner.invoke(main, ["batch", str(shoot), "-o", str(out), "--tonemap", "drago"])
    assert res.exit_code == 0, res.output
    assert _spec(exrs[0]).getattribute("oiio:ColorSpace") == "lin_rec709_scene"
