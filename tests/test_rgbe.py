"""The NumPy Radiance RGBE encoder (hdrcl.io.encoders): against OpenImageIO's own encoder
and reader, its run-length encoding byte by byte, edge values, atomic writes."""
import errno
import os

import numpy as np
import pytest

oiio = pytest.importorskip("OpenImageIO")

from hdrcl.errors import ProcessingError  # noqa: E402
from hdrcl.io import encoders  # noqa: E402
from hdrcl.io.encoders import (MAX_RLE_WIDTH, MIN_RLE_WIDTH, RGBE_MAX, RGBE_MIN, RGBEEncoder, RGBEFile,  # noqa: E402
                               header, to_rgbe, write_rgbe)
from hdrcl.io.writers import RadianceWriter, write_radiance  # noqa: E402


def _scene(h, w, seed=0, sigma=2.0):
    """Colour radiance over several decades, with flat patches (runs) and noise."""
    rng = np.random.default_rng(seed)
    img = np.exp(rng.normal(0.0, sigma, (h, w, 3))).astype(np.float32)
    img[: h // 2, : w // 3] = [0.25, 0.5, 1.0]  # a flat patch: long runs in every plane
    img[h // 2:, w // 2:] *= np.float32(1e-3)
    return img


def _read(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    try:
        return np.asarray(inp.read_image(0, 0, 0, 3, "float"), np.float32)
    finally:
        inp.close()


def _oiio_hdr(path, img):
    """The file OpenImageIO's own RGBE writer makes of ``img``."""
    spec = oiio.ImageSpec(img.shape[1], img.shape[0], 3, "float")
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(np.ascontiguousarray(img, np.float32))
    out.close()


def _decode(data: bytes):
    """A plain reference decoder: (header lines, RGBE bytes (H, W, 4)); checks every
    packet stays within its scanline and plane, as Radiance readers do."""
    end = data.index(b"\n\n")
    lines = data[:end].decode().split("\n")
    res_end = data.index(b"\n", end + 2)
    res = data[end + 2:res_end].split()
    assert res[0] == b"-Y" and res[2] == b"+X", res
    h, w = int(res[1]), int(res[3])
    buf = np.frombuffer(data, np.uint8)
    pos = res_end + 1
    out = np.zeros((h, w, 4), np.uint8)
    for y in range(h):
        rle = MIN_RLE_WIDTH <= w <= MAX_RLE_WIDTH and buf[pos] == 2 and buf[pos + 1] == 2 and buf[pos + 2] < 128
        if not rle:
            out[y] = buf[pos:pos + 4 * w].reshape(w, 4)
            pos += 4 * w
            continue
        assert (int(buf[pos + 2]) << 8 | int(buf[pos + 3])) == w
        pos += 4
        for c in range(4):
            x = 0
            while x < w:
                code = int(buf[pos])
                pos += 1
                if code > 128:
                    n = code - 128
                    assert x + n <= w, "run crosses the scanline's end"
                    out[y, x:x + n, c] = buf[pos]
                    pos += 1
                else:
                    assert 0 < code and x + code <= w, "literal crosses the scanline's end"
                    out[y, x:x + code, c] = buf[pos:pos + code]
                    pos += code
                x += n if code > 128 else code
    assert pos == len(data), "bytes left after the last scanline"
    return lines, out


def _values(rgbe):
    """What OpenImageIO's reader makes of RGBE bytes: m x 2^(e - 136), 0 for e = 0."""
    e = rgbe[..., 3:].astype(np.int32)
    return np.where(e > 0, rgbe[..., :3] * np.ldexp(1.0, e - 136), 0.0)


@pytest.mark.parametrize("w", [1, 5, 7, 8, 9, 47, 128, 129, 300])
def test_same_values_as_openimageio(tmp_path, w):
    img = _scene(11, w, seed=w)
    ours, theirs = tmp_path / "ours.hdr", tmp_path / "theirs.hdr"
    write_rgbe(ours, img)
    _oiio_hdr(theirs, img)
    np.testing.assert_array_equal(_read(ours), _read(theirs))
    # and byte for byte the same pixels (their run-length coding may differ)
    assert np.array_equal(_decode(ours.read_bytes())[1], _decode(theirs.read_bytes())[1])


def test_grey_is_written_as_rgb(tmp_path):
    grey = _scene(9, 40)[..., :1].copy()
    write_radiance(tmp_path / "g.hdr", grey)
    back = _read(tmp_path / "g.hdr")
    assert back.shape == (9, 40, 3)
    np.testing.assert_array_equal(back[..., 0], back[..., 2])
    rel = np.abs(back[..., 0] - grey[..., 0]) / grey[..., 0]
    assert rel.max() < 1 / 128


def test_rounding_is_wards():
    """Mantissas are floor(c x 2^(8 - e)); the largest in 128..255: never above the value,
    less than one part in 128 of the largest channel below it."""
    rng = np.random.default_rng(1)
    img = np.exp(rng.uniform(-80, 80, (5000, 3))).astype(np.float32)
    rgbe = to_rgbe(img)
    assert rgbe[:, :3].max(axis=1).min() >= 128
    got = _values(rgbe)
    assert (got <= img).all()
    assert ((img - got) / img.max(axis=1, keepdims=True)).max() < 1 / 128
    # exactly Ward's formula in float64
    m, e = np.frexp(img.max(axis=1).astype(np.float64))
    want = np.floor(img * np.ldexp(1.0, 8 - e)[:, None]).astype(np.uint8)
    np.testing.assert_array_equal(rgbe[:, :3], want)
    np.testing.assert_array_equal(rgbe[:, 3], e + 128)


def test_edge_values():
    vals = np.array([
        [0, 0, 0], [-0.0, -0.0, 0], [1e30, 1e30, 1e30], [1e30, 1, 0],
        [3e38, 1, 1], [np.inf, 1, 1], [np.nan, 1, 2], [-5, 1, 2],
        [1e-35, 1e-35, 1e-35], [2.0 ** -128, 0, 0], [2.0 ** -129, 0, 0], [1.5e-45, 0, 0],
        [1e-38, 1e-39, 0], [RGBE_MAX, 0, 0], [1e-32, 0, 0],
    ], np.float32)
    rgbe = to_rgbe(vals)
    got = _values(rgbe)
    assert (rgbe[0] == 0).all() and (rgbe[1] == 0).all()  # zeros, -0.0
    np.testing.assert_allclose(got[2], 1e30, rtol=1 / 128)  # huge: kept
    assert got[3][2] == 0 and got[3][1] == 0  # small beside huge: below one step
    np.testing.assert_allclose(got[4][0], RGBE_MAX, rtol=1e-6)  # beyond RGBE: its largest
    np.testing.assert_allclose(got[5][0], RGBE_MAX, rtol=1e-6)  # inf: the largest
    assert got[6][0] == 0 and got[6][2] == pytest.approx(2, rel=1 / 128)  # NaN channel: 0
    assert got[7][0] == 0 and got[7][2] == pytest.approx(2, rel=1 / 128)  # negative: 0
    np.testing.assert_allclose(got[8], 1e-35, rtol=1 / 128)  # tiny: kept (OpenImageIO zeroes it)
    assert got[9][0] == RGBE_MIN and rgbe[9][3] == 1  # the smallest RGBE value
    assert (rgbe[10] == 0).all() and (rgbe[11] == 0).all()  # below it: 0
    np.testing.assert_allclose(got[12][0], 1e-38, rtol=1 / 128)
    np.testing.assert_allclose(got[13][0], RGBE_MAX, rtol=1e-6)
    np.testing.assert_allclose(got[14][0], 1e-32, rtol=1 / 128)


def test_edge_values_read_back_by_openimageio(tmp_path):
    img = np.array([[[1e30, 2e29, 0], [1e-35, 1e-36, 1e-35], [0, 0, 0], [3e-39, 0, 0],
                     [5, 0.5, 0.05], [1e-20, 1e-20, 1e-20], [65504, 1, 1e-3], [1, 1, 1]]], np.float32)
    write_rgbe(tmp_path / "e.hdr", img)
    back = _read(tmp_path / "e.hdr")
    err = np.abs(back - img) / np.maximum(img.max(axis=2, keepdims=True), 1e-38)
    assert err.max() < 1 / 128
    assert (back[0, 1] > 0).all() and back[0, 3, 0] > 0  # OpenImageIO's reader keeps tiny values


@pytest.mark.parametrize("w", [MIN_RLE_WIDTH - 1, MIN_RLE_WIDTH, MAX_RLE_WIDTH, MAX_RLE_WIDTH + 1])
def test_run_length_only_for_widths_it_is_defined_for(tmp_path, w):
    img = np.ones((2, w, 3), np.float32)
    img[:, ::3] = 2.0
    path = tmp_path / "w.hdr"
    write_rgbe(path, img)
    data = path.read_bytes()
    start = data.index(b"\n", data.index(b"\n\n") + 2) + 1
    rle = data[start:start + 2] == b"\x02\x02"
    assert rle == (MIN_RLE_WIDTH <= w <= MAX_RLE_WIDTH)
    if not rle:
        assert len(data) - start == 2 * w * 4
    np.testing.assert_array_equal(_decode(data)[1], to_rgbe(img))
    np.testing.assert_array_equal(_read(path), img)


@pytest.mark.parametrize("seed", range(12))
def test_run_length_coding_bytes(seed):
    """Rows built from runs of every length around the packet limits (3, 4, 127, 128, ...),
    adjacent runs of different values, noise: the decoded bytes are the flat ones."""
    rng = np.random.default_rng(seed)
    w = int(rng.integers(8, 700))
    rows = []
    for _ in range(int(rng.integers(1, 5))):
        parts, n = [], 0
        while n < w:
            length = int(rng.choice([1, 2, 3, 4, 5, 126, 127, 128, 129, 254, 255, 256, 300]))
            parts.append(np.full(length, rng.uniform(0.1, 10), np.float32))
            n += length
        row = np.concatenate(parts)[:w]
        noise = rng.random(w) < 0.3
        row[noise] = rng.uniform(0.1, 10, int(noise.sum()))
        rows.append(np.stack([row, row * 0.5, np.roll(row, 3)], axis=1))
    img = np.stack(rows)
    data = header(w, img.shape[0]) + RGBEEncoder(w).encode(img)
    np.testing.assert_array_equal(_decode(data)[1], to_rgbe(img))


def test_run_length_shrinks_flat_and_keeps_noise_small():
    w = 1000
    zeros = RGBEEncoder(w).encode(np.zeros((4, w, 3), np.float32))
    assert len(zeros) < 4 * 4 * (4 + 2 * 8 + 2)  # runs of 127
    noise = np.random.default_rng(0).uniform(1, 2, (4, w, 3)).astype(np.float32)
    coded = RGBEEncoder(w).encode(noise)
    assert len(coded) < 4 * (4 + 3 * (w + 8) + 40)  # literal mantissas, a run of exponents
    np.testing.assert_array_equal(_decode(header(w, 4) + coded)[1], to_rgbe(noise))


def test_flat_option_and_strips_make_the_same_pixels(tmp_path):
    img = _scene(37, 61, seed=5)
    whole, flat, strips = tmp_path / "a.hdr", tmp_path / "b.hdr", tmp_path / "c.hdr"
    write_rgbe(whole, img)
    write_rgbe(flat, img, rle=False)
    assert flat.stat().st_size == len(header(61, 37)) + 37 * 61 * 4
    f = RGBEFile(str(strips), 61, 37)
    for y in range(0, 37, 5):
        f.write(img[y:y + 5])
    f.close()
    assert strips.read_bytes() == whole.read_bytes()  # scanlines are coded on their own
    np.testing.assert_array_equal(_read(flat), _read(whole))


def test_writer_header_and_streamed_bytes(tmp_path):
    """write_radiance and RadianceWriter write the same file: the header lines of
    hdrcl.io.outmeta, then the resolution line; EXPOSURE is read by OpenImageIO."""
    img = _scene(23, 50, seed=2)
    camera = {"owner": "Jane Doe"}
    a, b = tmp_path / "a.hdr", tmp_path / "b.hdr"
    write_radiance(a, img, timestamp="2024:06:01 10:00:00", camera=camera)
    with RadianceWriter(b, 50, 23, 3, timestamp="2024:06:01 10:00:00", camera=camera) as w:
        for y in range(0, 23, 6):
            w.write_rows(y, min(23, y + 6), img[y:y + 6].copy())
    assert a.read_bytes() == b.read_bytes()
    lines, _ = _decode(a.read_bytes())
    assert lines[:2] == ["#?RADIANCE", "FORMAT=32-bit_rle_rgbe"]
    assert any(x.startswith("SOFTWARE=hdrcl") for x in lines)
    assert any(x.startswith("PRIMARIES= 0.6400 0.3300") for x in lines)
    assert "CAPDATE= 2024:06:01 10:00:00" in lines and "# owner: Jane Doe" in lines
    assert b"\n\n-Y 23 +X 50\n" in a.read_bytes()[:1000]
    inp = oiio.ImageInput.open(str(a))
    assert inp.spec().getattribute("hdr:exposure") is not None
    inp.close()


def test_header_refuses_newlines():
    with pytest.raises(ValueError, match="newlines"):
        header(4, 4, ["SOFTWARE=a\nb"])


def _leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if ".tmp-" in p.name)


def _full_disk_after(monkeypatch, writes):
    """Make the Radiance file's writes fail like a full disk after ``writes`` writes
    (the header is the first)."""
    count = {"n": 0}

    class File:
        def __init__(self, path, mode):
            self.real = open(path, mode)
            self.closed = False

        def write(self, data):
            count["n"] += 1
            if count["n"] > writes:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return self.real.write(data)

        def close(self):
            self.closed = True
            self.real.close()

    monkeypatch.setattr(encoders, "open", File, raising=False)


def test_streamed_failure_leaves_previous_file(tmp_path, monkeypatch):
    target = tmp_path / "r.hdr"
    target.write_bytes(b"old")
    img = _scene(20, 30)
    _full_disk_after(monkeypatch, 2)
    w = RadianceWriter(target, 30, 20, 3)
    w.write_rows(0, 10, img[:10])
    with pytest.raises(ProcessingError, match=r"r\.hdr: cannot write rows 10-20 \(no space left on the device\)"):
        w.write_rows(10, 20, img[10:])
    assert target.read_bytes() == b"old"
    assert _leftovers(tmp_path) == []


def test_whole_failure_leaves_previous_file(tmp_path, monkeypatch):
    target = tmp_path / "r.hdr"
    write_radiance(target, _scene(8, 9))
    before = target.read_bytes()
    _full_disk_after(monkeypatch, 1)
    with pytest.raises(ProcessingError, match=r"r\.hdr: cannot write rows 0-8 \(no space left on the device\)"):
        write_radiance(target, _scene(8, 9, seed=3))
    _full_disk_after(monkeypatch, 0)
    with pytest.raises(ProcessingError, match=r"r\.hdr: cannot write \(no space left on the device\)"):
        write_radiance(target, _scene(8, 9, seed=3))
    assert target.read_bytes() == before
    assert _leftovers(tmp_path) == []


def test_missing_rows_and_exceptions_leave_nothing(tmp_path):
    w = RadianceWriter(tmp_path / "m.hdr", 10, 8, 1)
    w.write_rows(0, 4, np.ones((4, 10, 1), np.float32))
    with pytest.raises(ValueError, match="only 4 of 8 rows"):
        w.close()
    with pytest.raises(RuntimeError):
        with RadianceWriter(tmp_path / "n.hdr", 10, 8, 3) as w:
            w.write_rows(0, 4, np.ones((4, 10, 3), np.float32))
            raise RuntimeError("stop")
    assert list(tmp_path.iterdir()) == []


def test_warnings_for_negative_and_nonfinite_values(tmp_path):
    img = _scene(6, 12)
    img[0, 0] = [-1, 2, 3]
    img[1, 1, 1] = np.nan
    with RadianceWriter(tmp_path / "n.hdr", 12, 6, 3) as w:
        w.write_rows(0, 6, img)
    assert any("negative values are written as 0" in m for m in w.warnings)
    assert any("1 value(s) are NaN or infinite" in m for m in w.warnings)
    back = _read(tmp_path / "n.hdr")
    assert back[0, 0, 0] == 0 and back[1, 1, 1] == 0
    assert np.isfinite(back).all()


def test_buffers_follow_the_strip_height():
    enc = RGBEEncoder(40)
    img = _scene(30, 40, seed=4)
    parts = [enc.encode(img[y:y + h]) for y, h in ((0, 13), (13, 2), (15, 13), (28, 2))]
    assert b"".join(parts) == RGBEEncoder(40).encode(img)
    assert enc.encode(np.zeros((0, 40, 3), np.float32)) == b""
    with pytest.raises(ValueError, match="expected"):
        enc.encode(np.zeros((2, 41, 3), np.float32))
    assert encoders.to_rgbe(np.zeros((2, 2, 3))).shape == (2, 2, 4)


def test_run_length_packets_are_the_expected_ones():
    """The packets themselves (not only what they decode to): a run of 5, two single
    bytes, a run of 130 (127 + 3) and a plane of 137 equal bytes (127 + 10)."""
    row = np.array([7] * 5 + [1, 2] + [9] * 130, np.uint8)
    planes = np.zeros((2, 4, row.size), np.uint8)
    planes[:, 0] = row
    got = RGBEEncoder(row.size)._rle(planes)
    line = bytes([2, 2, 0, 137, 133, 7, 2, 1, 2, 255, 9, 131, 9]) + bytes([255, 0, 138, 0]) * 3
    assert got == line * 2
