"""Calibrated fisheye luminance maps: each step against its formula, the one-pass chain
against the steps applied one by one, the OpenCL kernels against their NumPy twins,
and the files (Radiance's 179 convention, VIEW=, vertical illuminance)."""
import math

import numpy as np
import pytest
from scipy import ndimage

from hdrcl.core.luminance import fisheye_math as fm
from hdrcl.core.encode import fuse_to_file
from hdrcl.core.luminance.fisheye import LuminanceChain
from hdrcl.errors import UsageError

RTOL32 = 2e-6  # float32 arithmetic over a few terms


def _equisolid_sky(lum_of_theta, cx, cy, diameter, shape):
    """A bracket's merged image (cd/m^2): a sky whose luminance depends on the angle off
    axis only, seen by an equisolid 180-degree fisheye whose circle is (cx, cy, diameter)."""
    h, w = shape
    y, x = np.mgrid[0:h, 0:w] + 0.5
    r = np.hypot(x - cx, y - cy) / diameter  # in units of the circle's diameter, 0..0.5
    theta = 2.0 * np.arcsin(np.clip(math.sqrt(2.0) * r, 0.0, 1.0))
    lum = np.where(r <= 0.5, lum_of_theta(theta), 0.0)
    tint = np.array([1.05, 1.0, 0.9])  # a colour whose Radiance luminance is not 1
    return (lum[..., None] * tint / (tint @ fm.RADIANCE_LUMA)).astype(np.float32)


def _stream(chain, image, rows=37):
    h, w, c = image.shape
    chain.bind(h, w, c)
    for y in range(0, h, rows):
        chain.write_rows(y, min(h, y + rows), image[y:y + rows].copy())
    return chain.finish()


# ------------------------------------------------------------------- the formulas
def test_vertical_illuminance_of_uniform_sky_is_pi_l():
    for n, vh in ((1000, 180.0), (500, 186.0), (301, 190.0)):
        img = np.full((n, n, 3), 2500.0)
        img[~fm.inside_view(n)] = 0.0
        ev = fm.vertical_illuminance(img, vh)
        assert ev == pytest.approx(math.pi * 2500.0, rel=0.005), (n, vh)
    # L = L0 cos(theta): Ev = 2 pi L0 / 3
    n = 800
    k = np.arange(n) + 0.5 - n / 2
    theta = np.hypot(k[None, :], k[:, None]) * math.pi / n
    img = np.repeat((1000.0 * np.cos(np.minimum(theta, math.pi / 2)))[..., None], 3, axis=2)
    assert fm.vertical_illuminance(img, 180.0) == pytest.approx(2 * math.pi * 1000.0 / 3, rel=0.005)


def test_projection_against_its_formula():
    """A sky of L(theta) seen through an equisolid lens reads L(pi rd) at equidistant radius rd."""
    n = 400
    lum = lambda t: 1000.0 + 800.0 * np.cos(t) + 300.0 * np.sin(3 * t)  # noqa: E731
    src = _equisolid_sky(lum, n / 2, n / 2, n, (n, n)).astype(np.float64)
    out = fm.equisolid_to_equidistant(src)
    u = (np.arange(n) + 0.5) / n - 0.5
    rd = np.hypot(u[None, :], u[:, None])
    inside = rd < 0.49  # away from the circle's edge, where bilinear reads the black outside
    want = lum(math.pi * rd)
    got = fm.radiance_luminance(out)
    assert np.max(np.abs(got - want)[inside] / want[inside]) < 2e-3  # bilinear on a smooth sky
    assert np.all(out[~fm.inside_view(n)] == 0.0)


def test_vignetting_against_its_formula():
    n, coeffs = 120, (1.0, 0.02, -0.3, 0.05, -0.2, 0.0, 0.1, 0.0, -0.01)
    img = np.full((n, n, 3), 7.0)
    out = fm.apply_vignetting(img, coeffs, 60.0, 58.0, 60.0)
    for i, j in ((0, 0), (59, 60), (119, 3), (17, 101)):
        x, y = j, n - 1 - i  # Radiance's pcomb: y from the bottom
        r = math.hypot(x - 60.0, y - 58.0) / 60.0
        assert out[i, j, 1] == pytest.approx(7.0 / sum(a * r ** k for k, a in enumerate(coeffs)), rel=1e-12)


def test_crop_and_area_resize_against_block_means():
    """An integer ratio: each output pixel is the mean of its block of the masked crop."""
    rng = np.random.default_rng(4)
    h, w, cx, cy, d, n = 90, 130, 61.0, 47.0, 80.0, 20
    img = rng.uniform(1.0, 9.0, (h, w, 3)).astype(np.float32)
    chain = LuminanceChain.from_options(lens_circle=(cx, cy, d), resize=n)
    got = _stream(chain, img, rows=7)
    left, top = int(cx - d / 2), int(cy - d / 2)
    crop = img[top:top + 80, left:left + 80].astype(np.float64)
    yy, xx = np.mgrid[top:top + 80, left:left + 80] + 0.5
    crop[np.hypot(xx - cx, yy - cy) > d / 2] = 0.0
    want = crop.reshape(n, 4, n, 4, 3).mean(axis=(1, 3))
    np.testing.assert_allclose(got, want, rtol=RTOL32)


# ------------------------------------------------------------ one pass = one by one
def _area_matrix(size, n):
    edges = np.arange(n + 1) * size / n
    lo, hi = edges[:-1, None], edges[1:, None]
    y = np.arange(size)[None, :]
    return np.clip(np.minimum(y + 1, hi) - np.maximum(y, lo), 0, None) * n / size


def _one_by_one(img, cx, cy, d, n, vig, nd, k):
    """The chain written step by step with other NumPy/SciPy means than hdrcl's."""
    left, top, side = round(cx - d / 2), round(cy - d / 2), round(d)
    crop = img[top:top + side, left:left + side].astype(np.float64)
    yy, xx = np.mgrid[top:top + side, left:left + side] + 0.5
    crop[np.hypot(xx - cx, yy - cy) > d / 2] = 0.0  # black outside the lens circle
    a = _area_matrix(side, n)
    small = np.einsum("ky,yxc,jx->kjc", a, crop, a)  # area average, N x N
    c = (np.arange(n) + 0.5) / n - 0.5
    u, v = np.meshgrid(c, c)
    rd = np.hypot(u, v)
    rs = np.sin(np.pi * rd / 2) / math.sqrt(2)  # inverse of rad(r) = 2/PI*asin(sqrt(2)*r)
    with np.errstate(invalid="ignore"):
        f = np.where(rd > 0, rs / rd, np.pi / (2 * math.sqrt(2)))
    coords = [(0.5 + v * f) * n - 0.5, (0.5 + u * f) * n - 0.5]
    proj = np.stack([ndimage.map_coordinates(small[..., ch], coords, order=1, mode="nearest") for ch in range(3)], -1)
    proj[rd > 0.5] = 0.0
    x, y = np.meshgrid(np.arange(n), n - 1 - np.arange(n))
    r = np.hypot(x - n / 2, y - n / 2) / (n / 2)
    proj /= (1 + sum(ak * r ** (i + 1) for i, ak in enumerate(vig)))[..., None]
    return proj * np.asarray(nd) * k


def test_chain_in_one_pass_equals_the_steps_one_by_one():
    rng = np.random.default_rng(7)
    h, w, (cx, cy, d), n = 210, 260, (131.3, 104.8, 183.5), 64
    img = _equisolid_sky(lambda t: 500 + 400 * np.cos(t), cx, cy, d, (h, w))
    img *= rng.uniform(0.8, 1.25, img.shape).astype(np.float32)  # texture
    vig, nd, k = (0.01, -0.12, 0.05, -0.2), (900.0, 1000.0, 1100.0), 1.21
    chain = LuminanceChain.from_options(lens_circle=f"{cx},{cy},{d}", resize=n, projection="equisolid-to-equidistant",
                                        vignetting=",".join(map(str, vig)), nd_filter=",".join(map(str, nd)),
                                        calibration_factor=str(k))
    got = _stream(chain, img, rows=11)
    want = _one_by_one(img, cx, cy, d, n, vig, nd, k)
    scale = float(want.max())
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6 * scale)
    assert chain.vertical_illuminance == pytest.approx(fm.vertical_illuminance(want, 180.0), rel=1e-5)


def test_known_sky_through_the_whole_chain_gives_its_illuminance():
    """L = a + b cos(theta) seen through an equisolid lens: Ev = pi a + 2 pi b / 3."""
    a, b = 3000.0, 6000.0
    img = _equisolid_sky(lambda t: a + b * np.cos(t), 612.0, 400.0, 720.0, (800, 1200))
    chain = LuminanceChain.from_options(lens_circle="612,400,720", resize=360, projection="equisolid-to-equidistant")
    _stream(chain, img, rows=64)
    assert chain.vertical_illuminance == pytest.approx(math.pi * a + 2 * math.pi * b / 3, rel=0.005)


# ---------------------------------------------------------------------- OpenCL
def test_kernels_match_twins(cl_device):
    from hdrcl.cl.fisheye import FisheyeProcessor

    proc = FisheyeProcessor(ctx=cl_device)
    n = 257  # odd: a centre pixel at rd = 0
    yy, xx = np.mgrid[0:n, 0:n] / n
    img = (np.stack([1 + xx, 2 + yy * xx, 3 + np.sin(5 * xx)], -1) * 100.0).astype(np.float32)
    got, want = proc.project(img), fm.equisolid_to_equidistant(img)
    np.testing.assert_allclose(got, want, rtol=RTOL32 * 4, atol=0)
    assert np.array_equal(got == 0, want == 0)  # the same pixels are outside the view
    coeffs = (1.0, 0.1, -0.3, 0.2, 0.0, 0.0, 0.0, 0.0, -0.01)
    got = proc.vignette(img, coeffs, 128.0, 127.5, 128.5)
    np.testing.assert_allclose(got, fm.apply_vignetting(img, coeffs, 128.0, 127.5, 128.5), rtol=RTOL32)


def test_chain_uses_opencl_when_required(cl_device):
    img = _equisolid_sky(lambda t: 100 + 50 * np.cos(t), 50.0, 50.0, 100.0, (100, 100))
    opts = dict(lens_circle="50,50,100", resize=50, projection="equisolid-to-equidistant", vignetting="0.1")
    chain = LuminanceChain.from_options(**opts)
    got = _stream(chain, img)
    assert chain.backend == "opencl"
    plain = _stream(LuminanceChain.from_options(lens_circle="50,50,100", resize=50), img)
    want = fm.apply_vignetting(fm.equisolid_to_equidistant(plain), (1.0, 0.1) + (0.0,) * 7, 25.0, 25.0, 25.0)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5 * float(want.max()))


# ----------------------------------------------------------------------- files
def _write(chain, img, output, dtype="auto"):
    from hdrcl.io.writers import RadianceWriter

    h, w, _ = img.shape
    chain.bind(h, w, 3)

    def run(sink, first):
        for y in range(0, h, 50):
            sink.write_rows(y, min(h, y + 50), img[y:y + 50].copy())
        return {"pixels": h * w}

    def open_writer(dt, half_scale, ch=None):
        meta, cam, width, height = ch.writer_args({"units": "cd/m2 (approximate)", "referenceExposure": 0.25},
                                                 {"exposure_time": 0.25, "owner": "Jane Doe"})
        return RadianceWriter(output, width, height, 3, dtype=dt, metadata=meta, camera=cam)

    writer, counts, stored = fuse_to_file(open_writer, run, output=str(output), dtype=dtype, reference=0.25,
                                          keep_units=True, chain=chain)
    writer.close()
    return stored


def test_hdr_holds_radiance_in_the_179_convention(tmp_path):
    import OpenImageIO as oiio

    from hdrcl.io.radiance import read_radiance
    from hdrcl.report.falsecolor import read_luminance

    img = _equisolid_sky(lambda t: 800 + 400 * np.cos(t), 150.0, 100.0, 200.0, (200, 300))
    opts = dict(lens_circle="150,100,200", resize=100, projection="equisolid-to-equidistant", calibration_factor=1.2)
    ref = _stream(LuminanceChain.from_options(**opts), img)
    chain = LuminanceChain.from_options(**opts, view="-vta -vh 186 -vv 186")
    _write(chain, img, tmp_path / "lum.hdr")
    raw = (tmp_path / "lum.hdr").read_bytes()
    head = raw[:raw.index(b"\n\n")].decode().split("\n")
    assert "VIEW= -vta -vh 186 -vv 186" in head
    assert not any(x.startswith("EXPOSURE") for x in head)  # the values are not scaled
    ev = [float(x.split("=")[1]) for x in head if x.startswith("VERTICAL_ILLUMINANCE=")]
    assert ev == [pytest.approx(chain.vertical_illuminance, rel=1e-5)]
    inp = oiio.ImageInput.open(str(tmp_path / "lum.hdr"))  # OpenImageIO still reads it
    assert inp is not None and inp.spec().width == 100
    stored = inp.read_image(0, 0, 0, 3, "float")  # the values as stored
    inp.close()
    lum_ref = fm.radiance_luminance(ref)
    inside = lum_ref > 0
    np.testing.assert_allclose((fm.radiance_luminance(stored) * 179.0)[inside], lum_ref[inside], rtol=0.01)
    cd, meta = read_radiance(tmp_path / "lum.hdr")  # read back in cd/m^2
    assert meta["whiteEfficacy"] == 179.0
    np.testing.assert_allclose(fm.radiance_luminance(cd)[inside], lum_ref[inside], rtol=0.01)
    np.testing.assert_allclose(read_luminance(tmp_path / "lum.hdr")[inside], lum_ref[inside], rtol=0.01)


def test_exr_holds_cd_per_m2_and_says_so(tmp_path):
    import OpenImageIO as oiio

    from hdrcl.io.radiance import read_radiance

    img = _equisolid_sky(lambda t: 80000 + 4000 * np.cos(t), 150.0, 100.0, 200.0, (200, 300))
    chain = LuminanceChain.from_options(lens_circle="150,100,200", resize=100, projection="equisolid-to-equidistant")
    stored = _write(chain, img, tmp_path / "lum.exr")
    assert stored.dtype == "float" and stored.note  # 84000 cd/m2 is beyond half: float, units kept
    pixels, meta = read_radiance(tmp_path / "lum.exr")
    np.testing.assert_allclose(pixels, _stream(LuminanceChain.from_options(
        lens_circle="150,100,200", resize=100, projection="equisolid-to-equidistant"), img), rtol=1e-6)
    assert meta["units"] == "cd/m2" and meta["view"] == "-vta -vh 180 -vv 180"
    assert "referenceExposure" not in meta and meta["verticalIlluminance"] == pytest.approx(
        chain.vertical_illuminance, rel=1e-6)
    inp = oiio.ImageInput.open(str(tmp_path / "lum.exr"))
    assert inp.spec().getattribute("whiteLuminance") == 1.0
    inp.close()


# ---------------------------------------------------------------------- options
@pytest.mark.parametrize("opts,flag", [
    (dict(lens_circle="10,10"), "--lens-circle"),
    (dict(lens_circle="a,b,c"), "--lens-circle"),
    (dict(lens_circle="10,10,20", resize=1.5), "--resize"),
    (dict(lens_circle="10,10,20", resize=0), "--resize"),
    (dict(lens_circle="10,10,20", projection="stereographic"), "--fisheye-projection"),
    (dict(lens_circle="10,10,20", view="-vta -vh"), "--view"),
    (dict(lens_circle="10,10,20", view="-vta -vh 400"), "--view"),
    (dict(lens_circle="10,10,20", vignetting="-2"), "--vignetting"),  # 1 - 2 r <= 0 inside the circle
    (dict(lens_circle="10,10,20", nd_filter="1,2"), "--nd-filter"),
    (dict(lens_circle="10,10,20", calibration_factor="-1"), "--calibration-factor"),
])
def test_options_are_checked_and_name_their_flag(opts, flag):
    with pytest.raises(UsageError, match=f"^{flag}: "):
        LuminanceChain.from_options(**opts)


def test_circle_whose_centre_is_outside_the_image_is_refused():
    chain = LuminanceChain.from_options(lens_circle="100,160,130", resize=10)
    with pytest.raises(UsageError, match="^--lens-circle: .* outside the 200x100 image"):
        chain.bind(100, 200, 3)


def test_circle_cut_by_the_image_edges_is_padded_with_black():
    """A circular fisheye on a smaller sensor: the circle's top, bottom and sides run past
    the image; the chain equals the steps on the image padded with black (pcompos)."""
    rng = np.random.default_rng(3)
    h, w, (cx, cy, d), n = 90, 120, (61.0, 44.0, 130.0), 40
    img = (rng.uniform(0.5, 2.0, (h, w, 3)) * 100).astype(np.float32)
    chain = LuminanceChain.from_options(lens_circle=f"{cx},{cy},{d}", resize=n, projection="equisolid-to-equidistant")
    chain.bind(h, w, 3)
    got = _stream(chain, img, rows=13)
    pad = 40
    padded = np.zeros((h + 2 * pad, w + 2 * pad, 3), np.float32)
    padded[pad:pad + h, pad:pad + w] = img
    want = _one_by_one(padded, cx + pad, cy + pad, d, n, (0.0,), (1.0, 1.0, 1.0), 1.0)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6 * float(want.max()))


# ------------------------------------------------------------- through the fusion
def test_bracket_of_a_known_sky_through_fusion_and_chain(tmp_path, cl_device):
    """8-bit frames of a sky L = a + b cos(theta) (an sRGB camera, its curve given as an
    hdrgen .rsp), fused in cd/m^2 and streamed through the chain: Ev = pi a + 2 pi b / 3."""
    from hdrcl.core.pipeline import ArraySource, stream_merge
    from hdrcl.core.radiometry import ScaledSink, exif_scale
    from hdrcl.core.response import Response

    z = np.arange(256.0) / 255.0
    lin = np.where(z <= 0.04045, z / 12.92, ((z + 0.055) / 1.055) ** 2.4)
    g = np.log(np.maximum(lin, 1e-4))
    rsp = tmp_path / "srgb.rsp"
    Response(bits=8, g=np.stack([g - g[128]] * 3), knots=np.arange(256.0)).save(rsp)
    resp = Response.load(rsp)
    a, b, unit = 1500.0, 4000.0, exif_scale(8.0, 100.0)
    sky = _equisolid_sky(lambda t: a + b * np.cos(t), 301.0, 200.0, 380.0, (400, 600)).astype(np.float64)
    times = np.array([1 / 512, 1 / 128, 1 / 32, 1 / 8])
    expo = np.exp(resp.g[0])  # relative exposure at each code, 1 at code 128
    frames = [np.searchsorted((expo[1:] + expo[:-1]) / 2, sky / unit * t).astype(np.uint8) for t in times]
    chain = LuminanceChain.from_options(lens_circle="301,200,380", resize=190, projection="equisolid-to-equidistant")
    chain.bind(400, 600, 3)
    stream_merge(ArraySource(frames, [None] * len(frames)), times, resp, ScaledSink(chain, [unit] * 3))
    chain.finish()
    assert chain.vertical_illuminance == pytest.approx(math.pi * a + 2 * math.pi * b / 3, rel=0.005)


def test_chain_or_none():
    from hdrcl.core.luminance.fisheye import chain_or_none

    assert chain_or_none() is None
    with pytest.raises(UsageError, match="^--vignetting: needs --lens-circle"):
        chain_or_none(vignetting="0.1")
    chain = chain_or_none(lens_circle="50,50,100", projection="equisolid-to-equidistant")
    assert chain.size == 1000 and chain.view[0] == "-vta -vh 180 -vv 180"
