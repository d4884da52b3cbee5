"""The encode stage in one pass (issue 26): hdrcl.io.halfrange.OnePass scales, measures and
converts strips block by block, with integer operations on the bits for ordinary blocks.
It must give NumPy's own result bit for bit (``clamp(x * s).astype(float16)``) and the
exact range, for every kind of value; RadianceWriter.write_scaled must write the same file
as write_rows of the scaled strip; the merge's RangeMeter must decide as before."""
import math

import numpy as np
import pytest

from hdrcl.io import halfrange as hr

oiio = pytest.importorskip("OpenImageIO")

from hdrcl.core.encode import RangeMeter, fuse_to_file, radiance_opener  # noqa: E402
from hdrcl.io import encoders, writers  # noqa: E402
from hdrcl.io.radiance import read_radiance  # noqa: E402
from hdrcl.io.writers import RadianceWriter  # noqa: E402

SCALES = (1.0, 0.25, 2.0 ** -6, 2.0 ** 10, 1 / 60, 1 / 179)


def _values():
    """Every kind of float32 a strip can hold, in a few blocks of each kind."""
    rng = np.random.default_rng(5)
    halves = np.arange(0x0001, 0x7C00, dtype=np.uint16).view(np.float16).astype(np.float32)
    mid = ((halves[:-1].astype(np.float64) + halves[1:]) / 2).astype(np.float32)  # ties: to even
    near = np.concatenate([halves, mid, np.nextafter(mid, np.float32(0)), np.nextafter(mid, np.float32(np.inf))])
    plain = np.exp(rng.normal(0.0, 2.0, 60000)).astype(np.float32)
    zeros = plain.copy()
    zeros[::97] = 0.0
    zeros[5] = -0.0
    bits = rng.integers(0, 2 ** 32, 60000, dtype=np.uint64).astype(np.uint32).view(np.float32)  # NaN, Inf, all
    odd = plain.copy()
    odd[[3, 700]] = [np.nan, np.inf]
    odd[[9, 900]] = [-2.0, 1e-30]
    return {"near half steps": near, "plain": plain, "zeros": zeros, "random bits": bits, "odd": odd,
            "huge": plain * np.float32(1e4), "tiny": plain * np.float32(1e-6)}


def _want_range(v):
    fin = np.isfinite(v)
    pos = v[(v > 0) & fin]
    lo = float(pos.min()) if pos.size else math.inf
    hi = math.inf if not fin.all() else max(0.0, float(v.max()))
    return lo, hi, int(v.size - np.count_nonzero(fin)), int(np.count_nonzero(v < 0))


@pytest.mark.parametrize("name", sorted(_values()))
@pytest.mark.parametrize("scale", SCALES)
def test_half_equals_numpy_bit_for_bit(name, scale):
    x = _values()[name]
    one = hr.OnePass(block=4096)  # many blocks: plain ones beside odd ones
    out = np.empty(x.size, np.float16)
    found = one.to_half(x, scale, out)
    with np.errstate(all="ignore"):
        v = x * np.float32(scale)
    want, clamped = hr.clamp(v)
    want = want.astype(np.float16)
    same = out.view(np.uint16) == want.view(np.uint16)
    same |= np.isnan(out) & np.isnan(want)
    assert same.all(), (x[~same][:5], out[~same][:5], want[~same][:5])
    lo, hi, nonfinite, _ = _want_range(v)
    assert (found.lo, found.hi, found.nonfinite, found.clamped) == (lo, hi, nonfinite, clamped)


def test_no_inf_nan_or_zero_from_finite_positive():
    x = np.array([1e-9, 2.0 ** -25, 3e-7, 1.0, 70000.0, 1e30], np.float32)
    out = np.empty(x.size, np.float16)
    found = hr.OnePass().to_half(x, 1.0, out)
    assert np.isfinite(out).all() and (out > 0).all() and found.clamped == 4


@pytest.mark.parametrize("name", ["plain", "zeros", "odd", "random bits"])
@pytest.mark.parametrize("scale", [1.0, 2.0 ** -6, 1 / 179])
def test_float_and_measure(name, scale):
    x = _values()[name]
    one = hr.OnePass(block=4096)
    out = np.empty_like(x)
    found = one.to_float(x, scale, out)
    with np.errstate(all="ignore"):
        v = x * np.float32(scale)
    assert np.array_equal(out, v, equal_nan=True)
    want = _want_range(v)
    assert (found.lo, found.hi, found.nonfinite, found.negative) == want
    m = one.measure(x, scale)
    assert (m.lo, m.hi, m.nonfinite) == want[:3]
    same = x.copy()  # in place
    one.to_float(same, scale, same)
    assert np.array_equal(same, v, equal_nan=True)


def test_pow2_exponent():
    assert hr.pow2_exponent(2.0 ** -6) == -6 and hr.pow2_exponent(1.0) == 0 and hr.pow2_exponent(1024.0) == 10
    assert hr.pow2_exponent(1 / 60) is None and hr.pow2_exponent(3.0) is None and hr.pow2_exponent(2.0 ** -140) is None


def _scene(h, w, nch=3, seed=0):
    rng = np.random.default_rng(seed)
    img = np.exp(rng.normal(0.0, 1.5, (h, w, nch))).astype(np.float32)
    img[: h // 4] = 0.75
    img[h // 2, : w // 3] = 0.0  # pixels without data
    return img


@pytest.mark.parametrize("ext,dtype,threads", [(".exr", "half", 2), (".exr", "half", 1), (".exr", "float", 2),
                                               (".exr", "float", 1), (".pfm", "float", 1), (".hdr", "float", 1),
                                               (".tif", "float", 1)])
@pytest.mark.parametrize("scale", [2.0 ** -3, 1 / 60])
def test_write_scaled_is_write_rows_of_the_product(tmp_path, monkeypatch, ext, dtype, threads, scale):
    monkeypatch.setattr(writers, "exr_threads", lambda oiio_module: threads)
    img = _scene(150, 67, 3 if ext != ".pfm" else 1)
    h, w, c = img.shape
    a, b = tmp_path / f"a{ext}", tmp_path / f"b{ext}"
    kw = dict(dtype=dtype, timestamp="2024:06:01 10:00:00")
    with RadianceWriter(a, w, h, c, **kw) as wa, RadianceWriter(b, w, h, c, **kw) as wb:
        for y in range(0, h, 23):
            strip = img[y:y + 23]
            before = strip.copy()
            found = wa.write_scaled(y, y + strip.shape[0], strip, scale)
            assert np.array_equal(strip, before)  # the caller's strip is not changed
            v = strip * np.float32(scale)
            wb.write_rows(y, y + strip.shape[0], v)
            lo, hi, _, _ = _want_range(v)
            assert (found.lo, found.hi) == (lo, hi)
    assert a.read_bytes() == b.read_bytes()
    v = img * np.float32(scale)
    if ext == ".hdr":  # the scanlines of the encoder fed the scaled map (no scale, no known range)
        want = encoders.RGBEEncoder(w).encode(v)
        assert a.read_bytes().split(b"\n-Y ", 1)[1].split(b"\n", 1)[1] == want
    else:  # what OpenImageIO reads back is the scaled map, rounded to half for half
        got = read_radiance(str(a))[0].reshape(v.shape)
        assert np.array_equal(got, v.astype(np.float16).astype(np.float32) if dtype == "half" else v)


def test_range_meter_decides_as_before(tmp_path):
    """A strip beyond half: the first file is dropped, the range is the whole map's,
    the second pass writes float; within half: one pass, half, the scaled values."""
    img = _scene(96, 40)
    h, w, c = img.shape

    def run(sink, first):
        for y in range(0, h, 16):
            sink.write_rows(y, y + 16, img[y:y + 16])
        return {}

    out = tmp_path / "m.exr"
    opener = radiance_opener(str(out), w, h, c, {}, {}, compression="piz", timestamp=None, colorspace="rec709")
    writer, _, stored = fuse_to_file(opener, run, output=str(out), dtype="auto", reference=0.5, keep_units=False)
    writer.close()
    got = oiio.ImageBuf(str(out))
    assert stored.dtype == "half" and stored.passes == 1 and got.spec().format == "half"
    assert np.array_equal(got.get_pixels(oiio.FLOAT), (img * np.float32(0.5)).astype(np.float16).astype(np.float32))
    v = img * np.float32(0.5)
    assert (stored.lo, stored.hi) == (float(v[v > 0].min()), float(v.max()))
    img[70, 3] = 1e6  # beyond half, after the first strips went to the file
    writer, _, stored = fuse_to_file(opener, run, output=str(out), dtype="auto", reference=0.5, keep_units=False)
    writer.close()
    got = oiio.ImageBuf(str(out))
    assert stored.dtype == "float" and stored.passes == 2 and got.spec().format == "float"
    assert stored.hi == 5e5 and np.array_equal(got.get_pixels(oiio.FLOAT), img * np.float32(0.5))


class _Plain:
    """A sink without write_scaled: the meter scales and forwards as it always did."""

    def __init__(self):
        self.rows = []

    def write_rows(self, y0, y1, data):
        self.rows.append(np.array(data))


def test_range_meter_without_write_scaled():
    sink = _Plain()
    meter = RangeMeter(sink, 4.0, check=True)
    data = np.array([[[0.0, 1.0, 2.0]]], np.float32)
    meter.write_rows(0, 1, data)
    assert (meter.lo, meter.hi, meter.overflow) == (4.0, 8.0, False)
    assert np.array_equal(sink.rows[0], data * 4)
    meter.write_rows(1, 2, np.array([[[1e5, 1.0, 1.0]]], np.float32))
    assert meter.overflow and len(sink.rows) == 1 and meter.hi == 4e5


@pytest.mark.parametrize("zero", [False, True])
def test_subnormal_inputs_under_a_large_scale(zero):
    """float32 subnormals (1e-39) scaled by 2^120 land in half's normal range, but the bit
    trick read their zero exponent field as a normal one: 0.00848 instead of 0.001329."""
    x = np.array([1e-39, 3e-39, 2e-39, 1.5e-39] * 4, np.float32)
    if zero:
        x[0] = 0.0
    out = np.empty(x.size, np.float16)
    hr.OnePass().to_half(x, 2.0 ** 120, out)
    want = (x * np.float32(2.0 ** 120)).astype(np.float16)
    assert (out.view(np.uint16) == want.view(np.uint16)).all(), (out, want)
