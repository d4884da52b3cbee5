"""Writing radiance maps and LDR images: round trips, metadata, atomic replacement."""
import numpy as np
import pytest

oiio = pytest.importorskip("OpenImageIO")

from hdrcl.errors import InputError, UsageError  # noqa: E402
from hdrcl.io import writers  # noqa: E402
from hdrcl.io.atomic import atomic_output
from hdrcl.io.frames import read_image  # noqa: E402
from hdrcl.io.radiance import read_radiance
from hdrcl.io.writers import write_radiance
from hdrcl.io.ldr import write_ldr


def _radiance(channels=3, seed=0, sigma=2.0):
    """A 31x47 radiance field spanning several decades, with a left-right/top-bottom
    ramp so that flips would show."""
    rng = np.random.default_rng(seed)
    img = np.exp(rng.normal(0.0, sigma, (31, 47, channels))).astype(np.float32)
    img[:, :, 0] += np.arange(31, dtype=np.float32)[:, None] * 0.5
    return img


def _leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if ".tmp-" in p.name)


@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("dtype,rtol", [("half", 1e-3), ("float", 0.0)])
def test_exr_round_trip(tmp_path, channels, dtype, rtol):
    img = _radiance(channels)
    path = tmp_path / "out.exr"
    assert write_radiance(path, img, dtype=dtype) == []
    back, meta = read_radiance(path)
    assert back.dtype == np.float32 and back.shape == img.shape
    np.testing.assert_allclose(back, img, rtol=rtol)
    assert meta == {}
    assert _leftovers(tmp_path) == []


def test_exr_header(tmp_path):
    path = tmp_path / "m.exr"
    meta = {"lambda": 10.0, "frames": 16, "response": "debevec", "flag": True,
            "times": [1, 2]}
    write_radiance(path, _radiance(), compression="piz", metadata=meta)
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    inp.close()
    assert spec.format == oiio.TypeDesc("half")
    assert spec.getattribute("compression") == "piz"
    assert spec.getattribute("oiio:ColorSpace") == writers.LINEAR_COLORSPACE
    np.testing.assert_allclose(spec.getattribute("chromaticities"),
                               writers.REC709_CHROMATICITIES, rtol=1e-6)
    _, back = read_radiance(path)
    assert back == {"lambda": 10.0, "frames": 16, "response": "debevec", "flag": 1,
                    "times": "[1, 2]"}


def test_exr_compression_choice(tmp_path):
    for comp in ("none", "zip", "dwaa:45"):
        path = tmp_path / f"{comp.replace(':', '_')}.exr"
        write_radiance(path, _radiance(), compression=comp)
        inp = oiio.ImageInput.open(str(path))
        assert inp.spec().getattribute("compression") == comp.split(":")[0]
        inp.close()
    with pytest.raises(UsageError, match="--compression: 'bogus' is not one of"):
        write_radiance(tmp_path / "x.exr", _radiance(), compression="bogus")
    with pytest.raises(UsageError, match="--dtype: 'double'"):
        write_radiance(tmp_path / "x.exr", _radiance(), dtype="double")


def test_half_that_cannot_hold_the_values_is_written_as_float(tmp_path):
    """Issue 9: half would turn 1e6 into inf and 1e-9 into 0; the values are kept."""
    img = _radiance()
    img.reshape(-1)[:100] = 1e6
    img.reshape(-1)[100:110] = 1e-9
    path = tmp_path / "big.exr"
    warnings = write_radiance(path, img)
    assert len(warnings) == 1
    assert "big.exr: values beyond the half-float range" in warnings[0] and "written as float" in warnings[0]
    back = read_radiance(path)[0]
    np.testing.assert_array_equal(back, img)
    assert write_radiance(path, img, dtype="float") == []
    np.testing.assert_array_equal(read_radiance(path)[0], img)


def test_streamed_half_never_writes_inf_or_zero(tmp_path):
    """The last-resort guard of RadianceWriter: values half cannot hold are clamped to
    its range (and counted), never written as inf or an underflowed 0."""
    img = _radiance()
    img.reshape(-1)[:100] = 1e6
    img.reshape(-1)[100:110] = 1e-9
    path = tmp_path / "s.exr"
    with writers.RadianceWriter(path, 47, 31, 3) as w:
        w.write_rows(0, 31, img.copy())
    assert any("110 value(s)" in m and "clamped" in m for m in w.warnings)
    back = read_radiance(path)[0]
    assert np.isfinite(back).all() and (back > 0).all()
    assert back.max() == 65504.0


@pytest.mark.parametrize("channels", [1, 3])
def test_hdr_round_trip(tmp_path, channels):
    img = _radiance(channels, sigma=0.5)
    path = tmp_path / "out.hdr"
    write_radiance(path, img, metadata={"a": 1})
    back, meta = read_radiance(path)
    assert back.shape == (31, 47, 3)  # RGBE has no grey variant
    ref = np.repeat(img, 3, axis=2) if channels == 1 else img
    # RGBE shares one 8-bit exponent per pixel: error relative to the largest channel
    err = np.abs(back - ref) / ref.max(axis=2, keepdims=True)
    assert err.max() < 0.01
    assert meta == {"a": 1}  # on the header's HDRCL= line


@pytest.mark.parametrize("ext", [".tif", ".tiff", ".pfm"])
@pytest.mark.parametrize("channels", [1, 3])
def test_float_formats_round_trip(tmp_path, ext, channels):
    img = _radiance(channels)
    path = tmp_path / f"out{ext}"
    assert write_radiance(path, img, metadata={"scale": 0.25, "note": "x"}) == []
    back, meta = read_radiance(path)
    np.testing.assert_array_equal(back, img)  # float32 exactly, no vertical flip
    if ext == ".pfm":
        assert meta == {}
    else:
        assert meta == {"scale": 0.25, "note": "x"}


def test_unknown_extension_and_folder(tmp_path):
    with pytest.raises(UsageError, match=r"'\.png'; use \.exr, \.hdr, \.tif, \.tiff, \.pfm"):
        write_radiance(tmp_path / "x.png", _radiance())
    with pytest.raises(UsageError, match="output folder '.*missing' does not exist"):
        write_radiance(tmp_path / "missing" / "x.exr", _radiance())
    with pytest.raises(ValueError, match="too long"):
        write_radiance(tmp_path / "x.exr", _radiance(), metadata={"k" * 26: 1})
    write_radiance(tmp_path / "ok.exr", _radiance(), metadata={"k" * 25: 1})


def test_atomic_output_success_and_failure(tmp_path):
    target = tmp_path / "out.exr"
    target.write_bytes(b"previous")
    with atomic_output(target) as tmp:
        assert tmp.endswith(".exr") and "/.out.tmp-" in tmp
        with open(tmp, "wb") as fh:
            fh.write(b"new")
    assert target.read_bytes() == b"new"
    with pytest.raises(RuntimeError):
        with atomic_output(target) as tmp:
            with open(tmp, "wb") as fh:
                fh.write(b"half")
            raise RuntimeError("disk full")
    assert target.read_bytes() == b"new"
    assert _leftovers(tmp_path) == []


class _FailingOutput:
    """Wraps a real ImageOutput; writes part of the file, then fails."""

    def __init__(self, real):
        self.real = real

    def __getattr__(self, name):
        return getattr(self.real, name)

    def write_image(self, pixels):
        self.real.write_scanline(0, 0, np.ascontiguousarray(pixels[0]))
        raise RuntimeError("writer crashed mid-way")


def test_writer_failure_keeps_previous_file(tmp_path, monkeypatch):
    target = tmp_path / "keep.exr"
    old = _radiance(seed=1)
    write_radiance(target, old)
    before = target.read_bytes()

    class FakeImageOutput:
        @staticmethod
        def create(path):
            return _FailingOutput(oiio.ImageOutput.create(path))

    class FakeOiio:
        def __getattr__(self, name):
            return FakeImageOutput if name == "ImageOutput" else getattr(oiio, name)

    from hdrcl.io import attributes

    monkeypatch.setattr(attributes, "_oiio", lambda: FakeOiio())  # the whole-image write
    with pytest.raises(RuntimeError, match="mid-way"):
        write_radiance(target, _radiance(seed=2))
    assert target.read_bytes() == before
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize("ext,dtype", [(".png", np.uint8), (".png", np.uint16),
                                       (".tif", np.uint16), (".jpg", np.uint8)])
def test_ldr_round_trip(tmp_path, ext, dtype):
    rng = np.random.default_rng(3)
    px = rng.integers(0, np.iinfo(dtype).max, (31, 47, 3), dtype=dtype, endpoint=True)
    if ext == ".jpg":  # smooth content, which JPEG keeps well
        yy, xx = np.mgrid[0:31, 0:47]
        px = np.stack([xx * 5, yy * 8, 128 + 0 * xx], axis=2).astype(np.uint8)
    path = tmp_path / f"v{ext}"
    write_ldr(path, px, metadata={"exposure": 0.5})
    img = read_image(path)
    assert img.pixels.dtype == dtype
    if ext == ".jpg":
        assert np.abs(img.pixels.astype(int) - px).mean() < 2  # quality 95
    else:
        np.testing.assert_array_equal(img.pixels, px)
    assert _leftovers(tmp_path) == []


def test_ldr_alpha_and_errors(tmp_path):
    px = np.full((4, 5, 4), 200, np.uint8)
    px[..., 3] = 0
    px[0, :, 3] = 128
    write_ldr(tmp_path / "a.png", px)
    img = read_image(tmp_path / "a.png")
    np.testing.assert_array_equal(img.pixels, px[..., :3])  # not premultiplied
    assert img.valid.sum() == 5
    with pytest.raises(UsageError, match="JPEG holds 8-bit data only"):
        write_ldr(tmp_path / "a.jpg", px[..., :3].astype(np.uint16))
    with pytest.raises(UsageError, match="unsupported image format '.exr'"):
        write_ldr(tmp_path / "a.exr", px)


def test_read_radiance_errors(tmp_path):
    with pytest.raises(InputError, match=r"none\.exr: no such file"):
        read_radiance(tmp_path / "none.exr")
    path = tmp_path / "cut.exr"
    write_radiance(path, _radiance(sigma=3.0), compression="none")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"cut\.exr: (truncated|corrupt) EXR data"):
        read_radiance(path)
