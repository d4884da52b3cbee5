"""Issue 33 (24 MP x 7 merge): a spilled decoded-frame cache is read back without copies,
and a Radiance strip is encoded on several threads with the bytes of one encoder.
"""
from __future__ import annotations

import os
import threading

import numpy as np
import pytest

from hdrcl.core import synthetic as s
from hdrcl.io import encoders
from hdrcl.io.encoders import RGBE_PART_ROWS, RGBEFile, part_bounds
from hdrcl.io.framecache import UNMAP_LAG_STRIPS, FrameCache
from hdrcl.io.halfrange import OnePass
from hdrcl.io.writers import RadianceWriter


def _spilled(tmp_path, monkeypatch, frames, step=16):
    monkeypatch.setenv("HDRCL_SCRATCH_DIR", str(tmp_path))
    n, (h, w, c) = len(frames), frames[0].shape
    cache = FrameCache(n, h, w, c, frames[0].dtype, in_memory=False)
    for k, f in enumerate(frames):
        for y0 in range(0, h, step):
            cache.put(k, y0, f[y0:y0 + step])
    cache.finish()
    return cache


# ------------------------------------------------------------------ spilled cache
def test_spilled_cache_is_read_back_without_copies(tmp_path, monkeypatch):
    """The rows of a spilled cache are read-only views of one mapping of the scratch file
    (two reads of overlapping rows share memory), bit for bit what was written, and stay
    readable after the cache is closed (a consumer may still hold a strip)."""
    rng = np.random.default_rng(1)
    frames = [rng.integers(0, 65535, (53, 31, 3), dtype=np.uint16) for _ in range(3)]
    cache = _spilled(tmp_path, monkeypatch, frames)
    a, _ = cache.rows(0, 20)
    b, _ = cache.rows(10, 40)
    for k in range(3):
        assert np.shares_memory(a[k], b[k])  # views, not copies
        assert not b[k].flags.writeable  # read-only use
        np.testing.assert_array_equal(b[k], frames[k][10:40])
    cache.close()
    assert os.listdir(tmp_path) == []
    for k in range(3):
        np.testing.assert_array_equal(b[k], frames[k][10:40])


def _mapped_rss_kb(addr: int) -> int:
    """Resident kB of the mapping of this process that holds address ``addr``."""
    with open("/proc/self/smaps") as f:
        inside = False
        for line in f:
            head = line.split()[0]
            if "-" in head and ":" not in head:
                lo, hi = (int(x, 16) for x in head.split("-"))
                inside = lo <= addr < hi
            elif inside and head == "Rss:":
                return int(line.split()[1])
    raise LookupError(hex(addr))


@pytest.mark.skipif(not os.path.exists("/proc/self/smaps"), reason="needs Linux /proc/self/smaps")
def test_spilled_cache_gives_back_pages_read_long_ago(tmp_path, monkeypatch):
    """Read top to bottom strip by strip, a spilled cache keeps only the last few strips
    of its mapping resident (the page cache keeps the file): the process's memory does
    not grow with the image. Rows given back still read the same bytes."""
    h, w, n, rows = 1200, 500, 3, 40
    rng = np.random.default_rng(2)
    frames = [rng.integers(0, 255, (h, w, 3), dtype=np.uint8) for _ in range(n)]
    cache = _spilled(tmp_path, monkeypatch, frames, step=64)
    first, _ = cache.rows(0, rows)
    peak = 0
    for y0 in range(0, h, rows):
        got, _ = cache.rows(y0, y0 + rows)
        total = sum(int(g.sum(dtype=np.int64)) for g in got)  # touch every page
        assert total == sum(int(f[y0:y0 + rows].sum(dtype=np.int64)) for f in frames)
        peak = max(peak, _mapped_rss_kb(got[0].ctypes.data))
    whole_kb = n * h * w * 3 // 1024
    strip_kb = n * rows * w * 3 // 1024
    assert peak <= (UNMAP_LAG_STRIPS + 4) * strip_kb + 64 < whole_kb // 2
    for k in range(n):  # given back, read again from the page cache
        np.testing.assert_array_equal(first[k], frames[k][:rows])
    cache.close()


# ------------------------------------------------------------------ RGBE on threads
def _radiance(h, w, seed=0):
    """Radiance with long runs (black, clipped), noise, and values RGBE cannot hold."""
    rad = s.radiance_field(h, w, decades=5.0, seed=seed).astype(np.float32)
    rad[: h // 5] = 0.0  # runs: the RLE's run packets
    rad[h // 2, : w // 3] = 1.0
    rad[h // 3, 1] = np.nan
    rad[h // 3, 2] = np.inf
    rad[h // 3, 3] = -2.0
    rad[h - 2, 4] = 3e38
    return rad


@pytest.mark.parametrize("w", [61, 7, 300])
def test_rgbe_strips_encoded_on_threads_give_the_bytes_of_one_encoder(tmp_path, w):
    """A strip cut into parts encoded at once (short strips: one part) gives the file of
    one encoder, bit for bit, RLE widths and flat ones, with NaN, Inf, negatives and
    values beyond RGBE."""
    rad = _radiance(157, w)
    outs = []
    for threads in (1, 3):
        p = tmp_path / f"t{threads}.hdr"
        f = RGBEFile(str(p), w, rad.shape[0], ["SOFTWARE=test"], threads=threads)
        for y0, n in ((0, 5), (5, 60), (65, RGBE_PART_ROWS), (65 + RGBE_PART_ROWS, 157)):
            f.write(rad[y0:y0 + n], 0.5)
        f.close()
        outs.append(p.read_bytes())
    assert outs[0] == outs[1]


def test_rgbe_parts_are_measured_and_encoded_on_their_own_threads(tmp_path):
    """``check`` sees every row once, each part on the thread that encodes it: the first
    on the caller's, the others on helpers."""
    rad = _radiance(96, 40)
    seen, threads = [], {}

    def check(part, y0, y1):
        seen.append((part, y0, y1))
        threads[part] = threading.get_ident()
        return None

    f = RGBEFile(str(tmp_path / "a.hdr"), 40, 96, threads=3)
    f.write(rad, 1.0, check=check)
    f.close()
    assert sorted(seen) == [(i, y0, y1) for i, (y0, y1) in enumerate(part_bounds(96, 3))]
    assert sum(y1 - y0 for _, y0, y1 in seen) == 96
    assert threads[0] == threading.get_ident()  # the first part on the caller's thread
    assert threads[1] != threads[0] and threads[2] != threads[0]  # the others on helpers
    assert part_bounds(RGBE_PART_ROWS * 2 - 1, 4) == [(0, RGBE_PART_ROWS * 2 - 1)]


@pytest.mark.parametrize("nch", [3, 1])
def test_hdr_writer_on_threads_returns_the_range_of_one_pass(tmp_path, monkeypatch, nch):
    """The radiance writer measures each part where it is encoded; the strip's range and
    counts are those of one pass over it, and the file is the same whatever the threads."""
    rad = _radiance(120, 90, seed=5)[:, :, :nch]
    got = {}
    for threads in (1, 4):
        monkeypatch.setattr(encoders, "rgbe_threads", lambda threads=threads: threads)
        p = tmp_path / f"w{threads}.hdr"
        wr = RadianceWriter(str(p), 90, 120, nch)
        ranges = [wr.write_scaled(y0, min(120, y0 + 50), rad[y0:y0 + 50], 0.25) for y0 in range(0, 120, 50)]
        wr.close()
        got[threads] = (p.read_bytes(), ranges)
    assert got[1][0] == got[4][0]
    for y0, r1, r4 in zip(range(0, 120, 50), got[1][1], got[4][1]):
        want = OnePass().measure(rad[y0:y0 + 50], 0.25)
        assert vars(r4) == vars(want) == vars(r1)


def test_whole_image_hdr_on_threads_gives_the_bytes_of_one_encoder(tmp_path):
    """:func:`hdrcl.io.encoders.write_rgbe` (a whole array, as ``write_radiance``) encodes
    its strips on threads: the same file as on one."""
    rad = _radiance(300, 1000, seed=7)
    encoders.write_rgbe(tmp_path / "one.hdr", rad, threads=1)
    encoders.write_rgbe(tmp_path / "four.hdr", rad, threads=4)
    assert (tmp_path / "one.hdr").read_bytes() == (tmp_path / "four.hdr").read_bytes()
