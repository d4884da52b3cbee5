"""Tone mapping: each operator against its NumPy reference and closed forms, the OpenCL
kernel against its float64 twin, Hable's filmic against colour-hdri, files and CLI."""
import math

import numpy as np
import pytest

from hdrcl.errors import UsageError
from hdrcl.report import tonemap as tm


def _scene(h=61, w=83, seed=0):
    """Synthetic radiance over ~8 decades, coloured, with NaN, inf, negative and zero pixels."""
    rng = np.random.default_rng(seed)
    rad = np.exp(rng.normal(0.0, 3.0, (h, w, 3))) * np.array([1.0, 0.8, 1.3])
    rad[0, 0] = np.nan
    rad[0, 1] = -1.0
    rad[0, 2] = np.inf
    rad[1, :10] = 0.0
    return rad.astype(np.float32)


def _srgb(v):
    v = np.clip(v, 0, 1)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)


def test_statistics():
    rad = _scene()
    lum = tm.luminance(tm._clean(rad))
    eps = 1e-6 * lum[lum > 0].max()
    key = math.exp(np.mean(np.log(eps + lum)))
    p = tm.statistics(rad, "reinhard", exposure=1.0)
    assert p.log_average == pytest.approx(key, rel=1e-12)
    assert p.scale == pytest.approx(0.18 / key * 2.0, rel=1e-12)
    assert p.white == pytest.approx(np.percentile(p.scale * lum, 99.9), rel=1e-12)
    assert tm.statistics(rad, "drago").scale == pytest.approx(1.0 / key, rel=1e-12)
    # Large maps: the statistics read every k-th row and column.
    assert tm.stats_stride(4000, 6000) == 5 and tm.stats_stride(512, 768) == 1


def test_reinhard_closed_form():
    """One grey pixel and one coloured one: Reinhard 2002 eq. 4 written out by hand."""
    rad = np.array([[[2.0, 2.0, 2.0], [1.0, 0.5, 0.25]]])
    p = tm.ToneParams("reinhard", scale=0.5, white=3.0, log_average=0.36)
    out = tm.display_global(rad, p)
    lum = 0.5 * 2.0
    assert out[0, 0] == pytest.approx([lum * (1 + lum / 9) / (1 + lum) / 2.0 * 2.0] * 3)
    lw = 0.2126 + 0.7152 * 0.5 + 0.0722 * 0.25
    ld = 0.5 * lw * (1 + 0.5 * lw / 9) / (1 + 0.5 * lw)
    np.testing.assert_allclose(out[0, 1], np.array([1.0, 0.5, 0.25]) * ld / lw, rtol=1e-12)
    # The hue is kept: channel ratios survive.
    assert out[0, 1, 0] / out[0, 1, 1] == pytest.approx(2.0)


def test_drago_closed_form():
    lmax = 50.0
    p = tm.ToneParams("drago", scale=1.0, white=lmax, log_average=1.0)
    lums = np.array([0.0, 0.01, 1.0, 10.0, lmax])
    rad = np.repeat(lums[None, :, None], 3, axis=2)
    out = tm.display_global(rad, p)[0, :, 0]
    expo = math.log(0.85) / math.log(0.5)
    ref = [0.0] + [math.log(v + 1) / (math.log10(lmax + 1) * math.log(2 + 8 * (v / lmax) ** expo))
                   for v in lums[1:]]
    np.testing.assert_allclose(out, ref, rtol=1e-12)
    assert out[-1] == pytest.approx(1.0)  # Lmax maps to display white
    assert np.all(np.diff(out) > 0)


# colour-hdri's documented example of tonemapping_operator_filmic (its docstring).
_HABLE_IN = np.array([[[0.48046875, 0.35156256, 0.23632812], [1.39843753, 0.55468757, 0.39062594]],
                      [[4.40625388, 2.15625895, 1.34375372], [6.59375023, 3.43751395, 2.21875829]]])
_HABLE_OUT = np.array([[[0.4507954, 0.3619673, 0.2617269], [0.7567191, 0.4933310, 0.3911730]],
                       [[0.9725554, 0.8557374, 0.7465713], [1.0158782, 0.9382937, 0.8615161]]])


def test_filmic_matches_colour_hdri_example():
    """Hable's curve with colour-hdri's parameters reproduces its published example
    (display values above 1 are clipped by hdrcl, as any display would)."""
    p = tm.ToneParams("filmic", scale=1.0, white=1.0, log_average=1.0)
    np.testing.assert_allclose(tm.display_global(_HABLE_IN, p), np.clip(_HABLE_OUT, 0, 1), atol=1e-7)


def test_filmic_matches_colour_hdri():
    colour_hdri = pytest.importorskip("colour_hdri", reason="colour-hdri (the 'dev' extra) not installed")
    rad = tm._clean(_scene())
    p = tm.statistics(rad, "filmic", exposure=-0.5)
    ref = np.clip(colour_hdri.tonemapping_operator_filmic(rad * p.scale), 0, 1)
    np.testing.assert_allclose(tm.display_global(rad, p), ref, atol=1e-12)


def test_reinhard_local():
    """A uniform scene has no local contrast: every scale is kept and Ld = L / (1 + L);
    a scene with a bright window keeps the dark side darker than the window."""
    flat = np.full((40, 50, 3), 3.0)
    p = tm.statistics(flat, "reinhard-local")
    out = tm.reinhard_local(flat, params=p)
    lum = p.scale * 3.0
    np.testing.assert_allclose(out, lum / (1 + lum) / 3.0 * 3.0, rtol=1e-5)
    scene = np.full((64, 64, 1), 0.05)
    scene[20:40, 20:40] = 50.0
    out = tm.reinhard_local(scene)
    assert out[30, 30, 0] > out[5, 5, 0] > 0
    assert np.all((out >= 0) & (out <= 1))
    codes = tm.tone_map_array(scene, "reinhard-local")
    assert codes.dtype == np.uint8 and codes.shape == scene.shape


@pytest.mark.parametrize("operator", ["reinhard", "drago", "filmic"])
def test_twin_encodes_display_values(operator):
    rad = _scene()
    p = tm.statistics(rad, operator, exposure=0.7)
    disp = tm.display_global(rad, p)
    for bits in (8, 16):
        codes = tm.apply_global(rad, p, bits)
        top = (1 << bits) - 1
        np.testing.assert_array_equal(codes, np.floor(_srgb(disp) * top + 0.5).astype(codes.dtype))
    assert np.all(np.isfinite(disp)) and disp.min() >= 0 and disp.max() <= 1
    assert np.all(disp[0, :3] == 0)  # NaN, negative and infinite input count as 0


@pytest.mark.parametrize("operator", ["reinhard", "drago", "filmic"])
@pytest.mark.parametrize("bits", [8, 16])
def test_kernel_matches_twin(cl_device, operator, bits):
    """The OpenCL kernel (float32) against the float64 twin: at most one code apart."""
    from hdrcl.cl.tonemap import TonemapProcessor

    proc = TonemapProcessor(ctx=cl_device, strip_pixels=1000)  # several strips
    for rad in (_scene(), _scene(37, 29, seed=3)[..., 1:2]):  # colour and grey
        p = tm.statistics(rad, operator, exposure=-1.25)
        ref = tm.apply_global(rad, p, bits)
        got = proc.apply(rad, tm.OP_CODES[operator], p.scale, p.white, bits)
        assert got.dtype == ref.dtype and got.shape == ref.shape
        diff = np.abs(got.astype(np.int64) - ref.astype(np.int64))
        assert diff.max() <= 1
        assert np.mean(diff == 0) > (0.999 if bits == 8 else 0.99)
        # The picture spans the range: the test would see a constant output.
        assert ref.max() > 0.8 * ((1 << bits) - 1) and ref.min() == 0


def test_tonemap_api(cl_device):
    import hdrcl

    with pytest.raises(UsageError, match=r"^radiance: \d+ NaN or infinite value"):  # as expose and the CLI
        hdrcl.tonemap(_scene(), "drago")
    rad = _scene()
    rad[~np.isfinite(rad)] = 0.0  # the API takes finite radiance only; the twins still clean it
    a = hdrcl.tonemap(rad, "drago", exposure=0.5, bits=16)
    b = tm.apply_global(rad, tm.statistics(rad, "drago", 0.5), 16)
    assert a.dtype == np.uint16 and np.abs(a.astype(int) - b.astype(int)).max() <= 1
    grey = hdrcl.tonemap(rad[..., 0], "reinhard")
    assert grey.shape == rad.shape[:2] and grey.dtype == np.uint8
    with pytest.raises(UsageError, match="^operator: 'mantiuk'"):  # the API names parameters, not flags
        hdrcl.tonemap(rad, "mantiuk")
    with pytest.raises(UsageError, match="^bits: 12"):
        hdrcl.tonemap(rad, "reinhard", bits=12)


def test_tonemap_file_and_cli(tmp_path):
    import OpenImageIO as oiio
    from click.testing import CliRunner

    from hdrcl.cli import main
    from hdrcl.io.writers import write_radiance

    rad = np.abs(_scene()) + 1e-3
    rad[~np.isfinite(rad)] = 1.0
    write_radiance(tmp_path / "in.exr", rad, dtype="float")
    write_radiance(tmp_path / "ap1.exr", rad, dtype="float", colorspace="acescg")
    runner = CliRunner()
    for op in tm.OPERATORS:
        res = runner.invoke(main, ["tonemap", str(tmp_path / "in.exr"), "-o", str(tmp_path / f"{op}.png"),
                                   "--operator", op, "--bits", "16", "--exposure", "0.5"])
        assert res.exit_code == 0, res.output
        assert f"16-bit sRGB, {op}, +0.5 EV" in res.output
        img = oiio.ImageBuf(str(tmp_path / f"{op}.png"))
        assert img.spec().format == oiio.UINT16 and img.spec().width == rad.shape[1]
    res = runner.invoke(main, ["tonemap", str(tmp_path / "in.exr"), "-o", str(tmp_path / "x.jpg"), "--bits", "16"])
    assert res.exit_code == 2 and "JPEG holds 8 bits" in res.output
    assert not (tmp_path / "x.jpg").exists()
    # An ACEScg file is converted back to Rec.709 before the operator: the same picture.
    a = tm.tonemap_file(tmp_path / "in.exr", tmp_path / "a.png")
    b = tm.tonemap_file(tmp_path / "ap1.exr", tmp_path / "b.png")
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 1
    from hdrcl.io.radiance import read_metadata

    assert read_metadata(tmp_path / "a.png")["tonemap"] == "reinhard"
