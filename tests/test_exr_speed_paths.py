"""EXR on all cores (hdrcl.io.encoders.ExrBatch): batching strips changes no byte of the
file, whatever the compression, sample type or strip height; failures stay atomic.
Correctness only: timings are scripts/compression_bench.py's."""
import os

import numpy as np
import pytest

oiio = pytest.importorskip("OpenImageIO")

from hdrcl.errors import ProcessingError  # noqa: E402
from hdrcl.io import encoders, writers  # noqa: E402
from hdrcl.io.encoders import EXR_BATCH_BYTES, EXR_BLOCK_LINES, exr_batch_rows, exr_threads  # noqa: E402
from hdrcl.io.radiance import read_radiance  # noqa: E402
from hdrcl.io.writers import DEFAULT_EXR_COMPRESSION, EXR_COMPRESSIONS, RadianceWriter, write_radiance  # noqa: E402


def _scene(h, w, nch=3, seed=0):
    rng = np.random.default_rng(seed)
    img = np.exp(rng.normal(0.0, 1.5, (h, w, nch))).astype(np.float32)
    img[: h // 3] = 0.75
    return img


def _stream(path, img, rows, **kw):
    h, w, c = img.shape
    with RadianceWriter(path, w, h, c, timestamp="2024:06:01 10:00:00", **kw) as wr:
        for y in range(0, h, rows):
            wr.write_rows(y, min(h, y + rows), img[y:y + rows].copy())
    return wr


@pytest.fixture
def threads(monkeypatch):
    """Pretend OpenEXR has ``n`` threads (batches of 2 n blocks)."""
    def use(n):
        monkeypatch.setattr(writers, "exr_threads", lambda oiio_module: n)
    return use


def test_batch_rows():
    assert exr_batch_rows("zip", 6000, 3, 1) == 32
    assert exr_batch_rows("zip", 6000, 3, 8) == 16 * 2 * 8
    assert exr_batch_rows("zips", 6000, 3, 8) == 16
    assert exr_batch_rows("dwaa:45", 6000, 3, 4) == 32 * 2 * 4
    assert exr_batch_rows("DWAB", 6000, 3, 64) * 6000 * 3 * 4 <= EXR_BATCH_BYTES
    assert exr_batch_rows("dwab", 6000, 3, 64) % 256 == 0
    assert exr_batch_rows("dwab", 10 ** 6, 3, 64) == 256  # at least one block
    assert set(EXR_BLOCK_LINES) == set(EXR_COMPRESSIONS)


def test_exr_threads_follow_the_cpus(monkeypatch):
    class Fake:
        value = 0

        def get_int_attribute(self, name, default):
            return self.value

        def attribute(self, name, value):
            self.value = value

    fake = Fake()
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2}, raising=False)
    assert exr_threads(fake) == 3 and fake.value == 3  # 0: all, here 3
    fake.value = 64
    assert exr_threads(fake) == 3  # no more than the process may use
    fake.value = 2
    assert exr_threads(fake) == 2
    fake.value = -1
    assert exr_threads(fake) == 1  # no thread pool
    assert exr_threads(oiio) >= 1


@pytest.mark.parametrize("compression", ["zip", "zips", "piz", "pxr24", "dwaa", "dwab", "none", "b44"])
@pytest.mark.parametrize("dtype", ["half", "float"])
def test_batches_write_the_same_bytes(tmp_path, threads, compression, dtype):
    img = _scene(301, 37, seed=len(compression))
    threads(1)  # strips as they come
    _stream(tmp_path / "one.exr", img, 7, dtype=dtype, compression=compression)
    threads(3)  # gathered into batches, half converted by NumPy
    _stream(tmp_path / "many.exr", img, 7, dtype=dtype, compression=compression)
    assert (tmp_path / "one.exr").read_bytes() == (tmp_path / "many.exr").read_bytes()


@pytest.mark.parametrize("rows", [1, 5, 64, 200, 301])
def test_strip_heights_and_grey(tmp_path, threads, rows):
    threads(2)
    for nch in (1, 3):
        img = _scene(301, 29, nch, seed=rows)
        _stream(tmp_path / "s.exr", img, rows, dtype="float")
        back, _ = read_radiance(tmp_path / "s.exr")
        np.testing.assert_array_equal(back, img)
        _stream(tmp_path / "h.exr", img, rows, dtype="half")
        back, _ = read_radiance(tmp_path / "h.exr")
        np.testing.assert_array_equal(back, img.astype(np.float16).astype(np.float32))


def test_half_clamping_still_applies(tmp_path, threads):
    threads(2)
    img = _scene(40, 20)
    img[5, 5] = 1e6
    img[6, 6] = 1e-9
    wr = _stream(tmp_path / "c.exr", img, 9, dtype="half")
    assert any("6 value(s)" in m and "clamped" in m for m in wr.warnings)
    back, _ = read_radiance(tmp_path / "c.exr")
    assert back[5, 5, 0] == 65504.0 and back[6, 6, 0] > 0


def test_same_as_whole_image_write(tmp_path, threads):
    threads(4)
    img = _scene(130, 50)
    write_radiance(tmp_path / "w.exr", img, timestamp="2024:06:01 10:00:00", compression=DEFAULT_EXR_COMPRESSION)
    _stream(tmp_path / "s.exr", img, 13, compression=DEFAULT_EXR_COMPRESSION)
    assert read_radiance(tmp_path / "w.exr")[0].tobytes() == read_radiance(tmp_path / "s.exr")[0].tobytes()


def test_failed_batch_leaves_previous_file(tmp_path, threads, monkeypatch):
    threads(2)
    target = tmp_path / "keep.exr"
    target.write_bytes(b"old")

    class Failing:
        def __init__(self, real):
            self.real = real

        def __getattr__(self, name):
            return getattr(self.real, name)

        def write_scanlines(self, *args):
            return False

        def geterror(self):
            return "disk on fire"

    class FakeOiio:
        def __getattr__(self, name):
            if name == "ImageOutput":
                return type("IO", (), {"create": staticmethod(lambda p: Failing(oiio.ImageOutput.create(p)))})
            return getattr(oiio, name)

    monkeypatch.setattr(writers, "_oiio", lambda: FakeOiio())
    img = _scene(100, 10)
    with pytest.raises(ProcessingError, match=r"keep\.exr: cannot write rows 0-64 \(disk on fire\)"):
        _stream(target, img, 10, compression="zip")  # 2 threads x 2 blocks of 16 rows
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["keep.exr"]
    # rows still gathered when the image ends: the failure comes from close()
    with pytest.raises(ProcessingError, match=r"cannot write rows 0-30 \(disk on fire\)"):
        _stream(target, _scene(30, 10), 10, compression="zip")
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["keep.exr"]


def test_batch_is_a_copy(tmp_path, threads):
    """The pipeline reuses its strip buffers: rows gathered must not change with them."""
    threads(4)
    img = _scene(50, 16)
    with RadianceWriter(tmp_path / "r.exr", 16, 50, 3, dtype="float") as wr:
        buf = np.empty((10, 16, 3), np.float32)
        for y in range(0, 50, 10):
            buf[:] = img[y:y + 10]
            wr.write_rows(y, y + 10, buf)
            buf[:] = -1
    np.testing.assert_array_equal(read_radiance(tmp_path / "r.exr")[0], img)
    assert encoders.ExrBatch  # the class the writer batches with


def test_abort_while_a_batch_is_being_written(tmp_path, threads):
    """Leaving the writer by an exception waits for the helper thread's write, then drops
    the file; nothing is left and no thread keeps running."""
    import threading

    threads(2)
    img = _scene(300, 64)
    before = {t.name for t in threading.enumerate()}
    with pytest.raises(RuntimeError, match="stop"):
        with RadianceWriter(tmp_path / "a.exr", 64, 300, 3) as wr:
            for y in range(0, 200, 10):
                wr.write_rows(y, y + 10, img[y:y + 10])
            raise RuntimeError("stop")
    assert list(tmp_path.iterdir()) == []
    assert not [t for t in threading.enumerate() if t.name.startswith("hdrcl-exr") and t.name not in before]


def test_tiff_takes_the_exr_default_quietly(tmp_path):
    """The EXR default compression passed to a TIFF (a command's default) is zip there,
    without a warning; another EXR-only name still warns."""
    img = _scene(8, 9)
    assert write_radiance(tmp_path / "a.tif", img, compression=DEFAULT_EXR_COMPRESSION) == []
    assert write_radiance(tmp_path / "b.tif", img) == []
    other = next(c for c in ("dwaa", "b44") if c != DEFAULT_EXR_COMPRESSION)
    (msg,) = write_radiance(tmp_path / "c.tif", img, compression=other)
    assert f"TIFF has no '{other}' compression; used zip" in msg
    inp = oiio.ImageInput.open(str(tmp_path / "a.tif"))
    assert inp.spec().getattribute("compression") == "zip"
    inp.close()
    write_radiance(tmp_path / "d.exr", img)
    inp = oiio.ImageInput.open(str(tmp_path / "d.exr"))
    assert inp.spec().getattribute("compression") == DEFAULT_EXR_COMPRESSION
    inp.close()
