"""Fast encoders for :mod:`hdrcl.io.writers`: Radiance RGBE in NumPy, on several threads;
OpenEXR on all cores (:mod:`hdrcl.io.exrbatch`).

**Radiance RGBE** (``.hdr``), encoded strip by strip. A Radiance picture is a text header
(``#?RADIANCE``, ``FORMAT=32-bit_rle_rgbe``, other ``NAME=value`` lines, a blank line), a
resolution line (``-Y H +X W``: rows top to bottom, columns left to right; another one where
EXIF Orientation turns the picture, :func:`hdrcl.io.exif.hdr_resolution`) and H scanlines
of W pixels of four bytes: three 8-bit mantissas sharing an exponent byte, value =
mantissa x 2^(exponent - 136).

The conversion is Greg Ward's (Radiance's ``setcolr``, OpenImageIO's ``float2rgbe``): with
``m, e = frexp(max(r, g, b))`` the mantissas are ``floor(c x 2^(8 - e))`` and the exponent
byte is ``e + 128``, so the largest channel's mantissa lies in 128..255 (readers add half
a step, or not: OpenImageIO's does not). The scaling is exact here (a power of two built
from the float's exponent bits, no division), so the bytes are OpenImageIO's wherever
OpenImageIO's are defined; they differ only where OpenImageIO's are undefined or lose
values:

* a pixel is 0 0 0 0 only when its largest channel is below :data:`RGBE_MIN` = 2^-128,
  the smallest value RGBE holds (OpenImageIO writes everything below 1e-32 as 0);
* negative channels and NaN are written as 0, ``+inf`` and values beyond
  :data:`RGBE_MAX` (255 x 2^119, about 1.7e38) as RGBE_MAX.

Scanlines 8..32767 pixels wide are run-length encoded the new way, each of the four byte
planes (R, G, B, E) of a scanline on its own, as every Radiance writer does; other widths
cannot be, and are written flat (four bytes a pixel). The run-length encoder is
vectorised: runs of 4 or more equal bytes become run packets (2 bytes for up to 127),
everything else literal packets of up to 128 bytes. A plane-row whose runs would save
less than a third of it (the mantissas of a photograph) is cut into literal packets by
reshaping alone: bookkeeping of many short runs would cost more time than they save bytes.

**OpenEXR** on all cores: :mod:`hdrcl.io.exrbatch` (its names are importable from here too).
"""
from __future__ import annotations

import errno
import math
import os
from typing import Iterable, Optional, Sequence

import numpy as np

from hdrcl.errors import ProcessingError
from hdrcl.io.exrbatch import (EXR_BATCH_BYTES, EXR_BLOCK_LINES, EXR_BLOCKS_PER_THREAD, ExrBatch,  # noqa: F401
                               exr_batch_rows, exr_threads)

__all__ = ["RGBE_MAX", "RGBE_MIN", "MIN_RLE_WIDTH", "MAX_RLE_WIDTH", "header", "to_rgbe",
           "RGBEEncoder", "RGBEFile", "write_rgbe", "rgbe_threads", "part_bounds", "RGBE_PART_ROWS",
           "EXR_BLOCK_LINES", "EXR_BLOCKS_PER_THREAD",
           "EXR_BATCH_BYTES", "exr_threads", "exr_batch_rows", "ExrBatch"]

#: Largest value RGBE holds: mantissa 255 at exponent byte 255.
RGBE_MAX = float(255 * 2.0 ** 119)
#: Smallest value RGBE holds (largest channel of a pixel): mantissa 128 at exponent byte 1.
RGBE_MIN = float(2.0 ** -128)
#: Widths run-length encoding is defined for; others are written flat.
MIN_RLE_WIDTH, MAX_RLE_WIDTH = 8, 0x7FFF

_MIN_RUN = 4            # equal bytes worth a run packet
_RUN_MAX = 127          # bytes one run packet repeats
_LIT_MAX = 128          # bytes one literal packet holds
_PLAIN_SHARE = 3        # rows whose runs would save under 1/3 of them stay literal
# Float32 biased exponent (bits 23..30) of the largest channel: below _LOW_EXP the value
# is under 2^-120 and 2^(8 - e) is no normal float32; those pixels take a float64 path.
_LOW_EXP = 7
_F32_MAX_RGBE = np.float32(RGBE_MAX)
_CHUNK_PIXELS = 1 << 18  # pixels per strip of write_rgbe
#: Fewest rows a part of a strip that :class:`RGBEFile` encodes on several threads has
#: (below, the threads' bookkeeping costs more than it saves).
RGBE_PART_ROWS = 8
#: Most threads one strip is encoded on (:func:`rgbe_threads`).
RGBE_MAX_THREADS = 4


def header(width: int, height: int, lines: Iterable[str] = (), orientation: int = 1) -> bytes:
    """The header and resolution line of a ``width`` x ``height`` picture, top row first.

    ``lines`` (without newlines) follow ``FORMAT=``, as OpenImageIO's header followed by
    the lines hdrcl inserts into it (:func:`hdrcl.io.outmeta.hdr_header_lines`). The
    scanlines are stored alike whatever EXIF ``orientation`` says; the resolution line
    says how to show them (:func:`hdrcl.io.exif.hdr_resolution`).
    """
    from hdrcl.io.exif import hdr_resolution

    text = "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n"
    for line in lines:
        line = str(line)
        if "\n" in line or "\r" in line:
            raise ValueError(f"Radiance header lines cannot hold newlines: {line!r}")
        text += line + "\n"
    return (text + f"\n{hdr_resolution(orientation, int(height), int(width))}\n").encode("utf-8")


class _Buffers:
    """Work arrays kept from one strip to the next: fresh memory for every strip would
    cost page faults that take as long as the arithmetic."""

    def __init__(self):
        self._arrays = {}
        self._views = {}

    def get(self, name: str, shape: tuple, dtype) -> np.ndarray:
        """An uninitialised ``shape`` array of ``dtype``, the same memory on every call."""
        view = self._views.get((name, shape))
        if view is not None:
            return view
        size = math.prod(shape)
        arr = self._arrays.get(name)
        if arr is None or arr.size < size or arr.dtype != np.dtype(dtype):
            arr = self._arrays[name] = np.empty(max(size, 1), dtype)
            self._views = {k: v for k, v in self._views.items() if k[0] != name}
        view = self._views[(name, shape)] = arr[:size].reshape(shape)
        return view


def _fill_rgbe(rgb: np.ndarray, planes: Sequence[np.ndarray], buf: _Buffers, scale: float = 1.0,
               clean: Optional[bool] = None) -> None:
    """Write the R, G, B mantissas and the exponent of ``rgb x scale`` (float32
    ``(n, W, 3)``; the product rounded to float32) into the four uint8 ``(n, W)`` views
    ``planes``. ``clean``: whether the caller knows ``rgb x scale`` to lie within
    0 .. RGBE_MAX (None: look)."""
    n, w, _ = rgb.shape
    s = np.float32(scale)
    lo, hi = (0, 0) if clean else (-1, 0) if clean is not None else (rgb.min(), rgb.max())
    # One transposing copy (scaled on the way) makes every later pass contiguous (3x
    # faster than strided).
    x = buf.get("x", (3, n, w), np.float32)
    with np.errstate(over="ignore", invalid="ignore"):
        if lo >= 0 and hi * s <= _F32_MAX_RGBE:  # NaN fails both tests
            if s == 1:
                np.copyto(x, rgb.transpose(2, 0, 1))
            else:
                np.multiply(rgb.transpose(2, 0, 1), s, out=x)
        else:
            if s == 1:
                np.fmax(rgb.transpose(2, 0, 1), np.float32(0), out=x)  # negatives and NaN -> 0
            else:
                np.multiply(rgb.transpose(2, 0, 1), s, out=x)
                np.fmax(x, np.float32(0), out=x)
            np.minimum(x, _F32_MAX_RGBE, out=x)  # inf and beyond -> RGBE_MAX
    v = buf.get("v", (n, w), np.float32)
    np.maximum(x[0], x[1], out=v)
    np.maximum(v, x[2], out=v)
    b = buf.get("b", (n, w), np.uint32)
    np.right_shift(v.view(np.uint32), 23, out=b)
    np.bitwise_and(b, 0xFF, out=b)  # -0.0 has the sign bit set
    # frexp(v) = (m, B - 126) for the biased exponent B, so 2^(8 - e) = 2^(134 - B): a
    # float32 with biased exponent 261 - B.
    scale_bits = buf.get("s", (n, w), np.uint32)
    np.subtract(np.uint32(261), b, out=scale_bits)
    np.left_shift(scale_bits, 23, out=scale_bits)
    scale = scale_bits.view(np.float32)
    low = buf.get("low", (n, w), bool)
    np.less(b, _LOW_EXP, out=low)
    any_low = bool(low.any())
    if any_low:
        np.copyto(scale, 0, where=low)
    m = buf.get("m", (n, w), np.float32)
    for c in range(3):
        np.multiply(x[c], scale, out=m)  # exact: a power of two, result < 256
        planes[c][...] = m  # the cast truncates, as Ward's (unsigned char) does
    np.add(b, 2, out=planes[3], casting="unsafe")  # e + 128 = B + 2 (B <= 253 here)
    if any_low:
        np.copyto(planes[3], 0, where=low)
        tiny = low & (v >= np.float32(RGBE_MIN))
        if tiny.any():  # 2^-128 <= v < 2^-120: exact in float64
            iy, ix = np.nonzero(tiny)
            _, e = np.frexp(v[iy, ix].astype(np.float64))
            s = np.ldexp(1.0, 8 - e)
            for c in range(3):
                planes[c][iy, ix] = (x[c][iy, ix].astype(np.float64) * s).astype(np.uint8)
            planes[3][iy, ix] = (e + 128).astype(np.uint8)


def to_rgbe(rgb) -> np.ndarray:
    """RGBE bytes of float radiance: ``(..., 3)`` -> uint8 ``(..., 4)`` (R, G, B, E).

    See the module's description for the conversion and its edge cases.
    """
    x = np.asarray(rgb, dtype=np.float32)
    if x.shape[-1:] != (3,):
        raise ValueError(f"RGBE needs 3 channels, got shape {x.shape}")
    lead = x.shape[:-1]
    x = np.ascontiguousarray(x.reshape(1, -1, 3))
    out = np.empty((1, x.shape[1], 4), np.uint8)
    _fill_rgbe(x, [out[..., c] for c in range(4)], _Buffers())
    return out.reshape(lead + (4,))


class RGBEEncoder:
    """Encodes strips of a ``width``-pixel-wide picture into Radiance scanlines.

    Keeps its work arrays between strips. ``rle=False`` writes flat scanlines whatever
    the width (also valid Radiance; a third larger for photographs).
    """

    def __init__(self, width: int, *, rle: bool = True):
        self.width = int(width)
        if self.width < 1:
            raise ValueError(f"width must be at least 1, got {width}")
        self.rle = bool(rle) and MIN_RLE_WIDTH <= self.width <= MAX_RLE_WIDTH
        self._buf = _Buffers()

    def encode(self, rgb, scale: float = 1.0, clean: Optional[bool] = None) -> bytes:
        """The bytes of the scanlines of float32 ``(rows, width, 3)`` radiance, multiplied
        by ``scale`` on the way (as ``rgb * np.float32(scale)`` would). ``clean``: the
        caller has measured the values (True: all within 0 .. RGBE_MAX)."""
        x = np.asarray(rgb, dtype=np.float32)
        if x.ndim != 3 or x.shape[1:] != (self.width, 3):
            raise ValueError(f"expected (rows, {self.width}, 3) pixels, got {x.shape}")
        n = x.shape[0]
        if n == 0:
            return b""
        if not self.rle:
            flat = self._buf.get("flat", (n, self.width, 4), np.uint8)
            _fill_rgbe(x, [flat[..., c] for c in range(4)], self._buf, scale, clean)
            return flat.tobytes()
        planes = self._buf.get("planes", (n, 4, self.width), np.uint8)
        _fill_rgbe(x, [planes[:, c, :] for c in range(4)], self._buf, scale, clean)
        return self._rle(planes)

    def _rle(self, planes: np.ndarray) -> bytes:
        """New-style run-length encoding of uint8 ``(n, 4, W)`` byte planes."""
        n, _, w = planes.shape
        seg = planes.reshape(n * 4, w)  # one plane of one scanline per row
        eq = self._buf.get("eq", (n * 4, w - 1), bool)
        np.equal(seg[:, 1:], seg[:, :-1], out=eq)  # byte j+1 repeats byte j
        win = self._buf.get("win", (n * 4, w - 3), bool)  # bytes j..j+3 equal
        np.logical_and(eq[:, :-2], eq[:, 1:-1], out=win)
        np.logical_and(win, eq[:, 2:], out=win)
        # A run of L >= 4 bytes starts L - 3 windows and saves about L bytes; rows where
        # runs would save less than 1/_PLAIN_SHARE of their size are written as literals.
        coded = np.array([np.count_nonzero(r) for r in win]) * _PLAIN_SHARE > w  # faster than axis=1
        pieces = [None] * (n * 4)
        runs = np.flatnonzero(coded).tolist()
        if len(runs) < n * 4:
            lit = _literal_rows(seg, w, self._buf)  # all rows: cheaper than picking
            size = lit.shape[1]
            view = memoryview(lit.reshape(-1))
            for s in np.flatnonzero(~coded).tolist():
                pieces[s] = view[s * size:(s + 1) * size]
        if len(runs) == n * 4:
            data, bounds = _rle_rows(seg, eq, self._buf)
        elif runs:
            k = len(runs)
            rows = np.take(seg, runs, axis=0, out=self._buf.get("rows", (k, w), np.uint8))
            data, bounds = _rle_rows(rows, np.take(eq, runs, axis=0, out=self._buf.get("roweq", (k, w - 1), bool)),
                                     self._buf)
        if runs:
            view, bounds = memoryview(data), bounds.tolist()
            for i, s in enumerate(runs):
                pieces[s] = view[bounds[i]:bounds[i + 1]]
        line = bytes((2, 2, w >> 8, w & 0xFF))
        out = []
        for y in range(n):
            out.append(line)
            out.extend(pieces[4 * y:4 * y + 4])
        return b"".join(out)


def _literal_rows(rows: np.ndarray, w: int, buf: _Buffers) -> np.ndarray:
    """Literal packets of 128 bytes (and a shorter last one) for each row of ``rows``."""
    k = rows.shape[0]
    q, r = divmod(w, _LIT_MAX)
    out = buf.get("lit", (k, q * (_LIT_MAX + 1) + (r + 1 if r else 0)), np.uint8)
    body = out[:, :q * (_LIT_MAX + 1)].reshape(k, q, _LIT_MAX + 1)
    body[:, :, 0] = _LIT_MAX
    body[:, :, 1:] = rows[:, :q * _LIT_MAX].reshape(k, q, _LIT_MAX)
    if r:
        out[:, q * (_LIT_MAX + 1)] = r
        out[:, q * (_LIT_MAX + 1) + 1:] = rows[:, q * _LIT_MAX:]
    return out


def _rle_rows(rows: np.ndarray, eq: np.ndarray, buf: _Buffers):
    """Run-length encode each row of uint8 ``rows`` ``(k, W)`` separately.

    ``eq`` is the rows' ``byte j+1 == byte j`` mask ``(k, W - 1)``. Works on runs of
    equal bytes, not bytes, so it is fast where runs are long. Returns the concatenated
    encodings and the ``k + 1`` offsets of each row's.
    """
    k, w = rows.shape
    flat = rows.reshape(-1)
    brk = buf.get("brk", (k, w), bool)
    brk[:, 0] = True
    np.logical_not(eq, out=brk[:, 1:])
    start = np.flatnonzero(brk)  # runs of equal bytes (none crosses a row)
    length = np.diff(start, append=flat.size)
    long = length >= _MIN_RUN
    # A packet region is a long run, or the short runs between long runs in one row.
    region = long.copy()
    region[1:] |= long[:-1]
    row_first = np.searchsorted(start, np.arange(k) * w)  # every row's first run
    region[row_first] = True
    head = np.flatnonzero(region)
    pstart = start[head]
    plen = np.diff(pstart, append=flat.size)
    run = long[head]
    if plen.size and plen.max() > _RUN_MAX:  # cut long regions into packets, in order
        limit = np.where(run, _RUN_MAX, _LIT_MAX)
        count = (plen + (limit - 1)) // limit
        seq = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
        end = np.repeat(pstart + plen, count)
        pstart = np.repeat(pstart, count) + seq * np.repeat(limit, count)
        plen = np.minimum(end - pstart, np.repeat(limit, count))
        run = np.repeat(run, count)
    psize = np.where(run, 2, plen + 1)
    offset = np.cumsum(psize) - psize  # where each packet's count byte goes
    total = int(offset[-1] + psize[-1])
    # The file holds every byte of the rows but the repeats inside run packets, in order,
    # with a count byte before each packet: bytes are moved by masks, not by index. A
    # byte is in a run of 4 or more when a window of 4 equal bytes holds it.
    win = buf.get("win4", (k, w - 3), bool)
    np.logical_and(eq[:, :-2], eq[:, 1:-1], out=win)
    np.logical_and(win, eq[:, 2:], out=win)
    keep = buf.get("keep", (k, w), bool)
    keep[:, :3] = False
    keep[:, 3:] = win
    for d in range(3):
        keep[:, d:d + w - 3] |= win
    keep = keep.reshape(-1)
    keep[pstart] = False  # packet starts stay; every other byte of a long run goes
    np.logical_not(keep, out=keep)
    head = buf.get("head", (total,), bool)
    head[...] = False
    head[offset] = True
    out = np.empty(total, np.uint8)
    out[offset] = np.where(run, 128 + plen, plen)
    np.logical_not(head, out=head)
    # out[head] = flat[keep], without the temporary: compress and place are 1.6x faster
    np.place(out, head, np.compress(keep, flat, out=buf.get("kept", (total - offset.size,), np.uint8)))
    bounds = np.append(offset[np.searchsorted(pstart, np.arange(k) * w)], total)
    return out, bounds


class RGBEFile:
    """Writes a Radiance picture to ``path`` strip by strip, top row first.

    Opens (creates or truncates) ``path`` and writes the header at once; :meth:`write`
    encodes and appends a strip; :meth:`close` checks that all ``height`` rows came and
    closes the file. Atomic replacement is the caller's (:mod:`hdrcl.io.atomic`, or
    :func:`write_rgbe`). A failing file system (a full disk) raises ProcessingError
    naming ``name`` (default ``path``), with the file closed; the caller deletes it.
    """

    def __init__(self, path: str, width: int, height: int, lines: Iterable[str] = (), *,
                 rle: bool = True, name: Optional[str] = None, orientation: int = 1, threads: int = 1):
        self.width, self.height = int(width), int(height)
        if self.width < 1 or self.height < 1:
            raise ValueError(f"picture must be at least 1x1, got {width}x{height}")
        self.name = name or path
        self.rows_written = 0
        # one encoder (its own work arrays) per part of a strip encoded at once
        self._encoders = [RGBEEncoder(self.width, rle=rle) for _ in range(max(1, int(threads)))]
        self._pool = None
        head = header(self.width, self.height, lines, orientation)
        self._file = None
        try:
            self._file = open(path, "wb")
            self._file.write(head)
        except OSError as exc:
            raise self._failed(exc) from None

    def _failed(self, exc: OSError, what: str = "") -> ProcessingError:
        """Close the file and describe ``exc``."""
        self.abort()
        reason = "no space left on the device" if exc.errno == errno.ENOSPC else (exc.strerror or str(exc))
        return ProcessingError(f"{self.name}: cannot write{what} ({reason})")

    def write(self, rgb, scale: float = 1.0, clean: Optional[bool] = None, check=None) -> None:
        """Append the scanlines of float ``(rows, width, 3)`` radiance x ``scale``
        (``clean``: see :meth:`RGBEEncoder.encode`).

        With ``threads`` > 1 a strip of at least :data:`RGBE_PART_ROWS` rows a part is cut
        into parts of whole scanlines encoded at once, the first on the calling thread
        (each scanline is encoded on its own: the bytes are one encoder's). ``check``,
        when given, is called as ``check(part, y0, y1)`` on the thread that encodes rows
        ``y0 .. y1`` of ``rgb`` (part ``part``), before it encodes them, and returns their
        ``clean`` (a caller measures there, with state of its own per part).
        """
        rows = int(np.shape(rgb)[0])
        if self.rows_written + rows > self.height:
            raise ValueError(f"{self.rows_written + rows} rows written to a picture {self.height} high")
        parts = part_bounds(rows, len(self._encoders))
        futures = []
        if len(parts) > 1:
            if self._pool is None:
                from concurrent.futures import ThreadPoolExecutor

                self._pool = ThreadPoolExecutor(len(self._encoders) - 1, thread_name_prefix="hdrcl-rgbe")
            futures = [self._pool.submit(self._encode, i, rgb, y0, y1, scale, clean, check)
                       for i, (y0, y1) in enumerate(parts) if i]
        try:
            data = [self._encode(0, rgb, *parts[0], scale, clean, check)]
        finally:  # never leave a helper encoding the caller's strip
            data += [f.result() for f in futures]
        try:
            for d in data:
                self._file.write(d)
        except OSError as exc:
            raise self._failed(exc, f" rows {self.rows_written}-{self.rows_written + rows}") from None
        self.rows_written += rows

    def _encode(self, part: int, rgb, y0: int, y1: int, scale: float, clean, check) -> bytes:
        rows = rgb[y0:y1]
        if check is not None:
            clean = check(part, y0, y1)
        return self._encoders[part].encode(rows, scale, clean)

    def close(self) -> None:
        """Flush and close; raises ValueError when rows are missing (the file is closed)."""
        self._stop()
        if self._file is None or self._file.closed:
            return
        try:
            self._file.close()
        except OSError as exc:
            raise self._failed(exc) from None
        if self.rows_written != self.height:
            raise ValueError(f"{self.name}: only {self.rows_written} of {self.height} rows were written")

    def abort(self) -> None:
        """Close without checking or raising (the caller deletes the file)."""
        self._stop()
        if self._file is not None and not self._file.closed:
            try:
                self._file.close()
            except OSError:
                pass

    def _stop(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None


def part_bounds(rows: int, parts: int) -> list:
    """``(y0, y1)`` of up to ``parts`` runs of whole rows that cover ``rows`` rows, each
    at least :data:`RGBE_PART_ROWS` rows (one run for a short strip)."""
    n = max(1, min(int(parts), rows // RGBE_PART_ROWS))
    cuts = [rows * i // n for i in range(n + 1)]
    return [(cuts[i], cuts[i + 1]) for i in range(n)]


def rgbe_threads() -> int:
    """Threads a strip of a Radiance picture is encoded on: the CPUs this process may run
    on, at most :data:`RGBE_MAX_THREADS`."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(RGBE_MAX_THREADS, cpus))


def write_rgbe(path, image, lines: Iterable[str] = (), *, rle: bool = True, orientation: int = 1,
               threads: Optional[int] = None) -> None:
    """Write float ``(H, W, 3)`` (or ``(H, W, 1)``: grey, written as RGB) radiance to the
    Radiance file ``path``, atomically (:func:`hdrcl.io.atomic.atomic_output`), in strips
    of about 256K pixels so that the work arrays stay small, each encoded on ``threads``
    threads (default :func:`rgbe_threads`; the same bytes whatever the number).

    Raises
    ------
    UsageError
        Missing or unwritable output folder.
    ProcessingError
        The file system failed (nothing is left at ``path`` or beside it).
    """
    from hdrcl.io.atomic import atomic_output

    target = os.fspath(path)
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] not in (1, 3):
        raise ValueError(f"radiance must be (H, W, 1) or (H, W, 3), got {img.shape}")
    h, w, _ = img.shape
    step = max(1, _CHUNK_PIXELS // w)
    with atomic_output(target) as tmp:
        out = RGBEFile(tmp, w, h, lines, rle=rle, name=target, orientation=orientation,
                       threads=rgbe_threads() if threads is None else threads)
        try:
            for y in range(0, h, step):
                out.write(np.broadcast_to(img[y:y + step], (min(step, h - y), w, 3)))
            out.close()
        except BaseException:
            out.abort()
            raise
