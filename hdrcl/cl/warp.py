"""Host side of ``kernels/warp.cl``: a frame resampled through a 3x3 matrix, strip by
strip of output rows.

Contract: the twin :func:`hdrcl.core.align.warp.warp_rows` (float64; the kernel computes in
float32). Each strip uploads only the band of source rows its taps reach, so neither
the frame nor its result has to fit the device whole.
"""
from __future__ import annotations

import threading
from typing import Optional, Tuple

import numpy as np
import pyopencl as cl

from hdrcl.cl.processing import OpenCLProcessor, round_up

_PIXEL_T = {np.dtype(np.uint8): ("uchar", 255), np.dtype(np.uint16): ("ushort", 65535)}
#: Output pixels per strip (a rotated frame's strip needs a taller band of source rows:
#: larger strips keep that overhead small).
WARP_STRIP_PIXELS = 1 << 22


def source_band(matrix: np.ndarray, y0: int, y1: int, h: int, w: int) -> Tuple[int, int]:
    """Source rows ``[b0, b1)`` holding every tap of output rows ``y0:y1`` (the corners
    of the strip bound a projective image of it; 3 rows of margin either side)."""
    m = np.asarray(matrix, np.float64)
    xs = np.array([0.0, w - 1.0, 0.0, w - 1.0])
    ys = np.array([y0, y0, y1 - 1.0, y1 - 1.0])
    s = m[2, 0] * xs + m[2, 1] * ys + m[2, 2]
    if np.any(s <= 0):
        return 0, h
    sy = (m[1, 0] * xs + m[1, 1] * ys + m[1, 2]) / s
    lo, hi = np.floor(sy.min()) - 3, np.floor(sy.max()) + 5
    b0, b1 = int(np.clip(lo, 0, h)), int(np.clip(hi, 0, h))
    return (b0, b1) if b1 > b0 else (0, 1)


#: ``warp_grid`` is one kernel object per context: its arguments are set and the kernel
#: enqueued under this lock (two sets aligned at once in one process).
_GRID_LOCK = threading.Lock()


class WarpProcessor(OpenCLProcessor):
    """Frames warped on the device; see :mod:`hdrcl.core.align.warp` for the equations."""

    source = "warp"

    def _kernel(self, name: str, dtype, nch: int, has_valid: bool, taps: int, clip_hi: Optional[int]):
        """Kernel ``name`` of kernels/warp.cl built for frames of ``dtype`` and ``nch`` channels."""
        ptype, zmax = _PIXEL_T[np.dtype(dtype)]
        return self.ctx.kernel("warp", name, (f"-DPIXEL_T={ptype}", f"-DZMAX={zmax}", f"-DNCH={nch}",
                                              f"-DHAS_VALID={int(has_valid)}", f"-DTAPS={int(taps)}",
                                              f"-DCLIP_HI={zmax if clip_hi is None else int(clip_hi)}"))

    def warp(self, frame: np.ndarray, matrix: np.ndarray, valid: Optional[np.ndarray] = None,
             strip_pixels: int = WARP_STRIP_PIXELS, taps: int = 4,
             out: Optional[np.ndarray] = None,
             clip_hi: Optional[int] = None) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(codes, valid, covered)`` of ``frame`` ``(H, W, C)`` warped by ``matrix``
        (same shape and dtype; ``valid`` and ``covered`` ``(H, W)`` bool); ``taps`` 4
        (Keys' cubic) or 2 (bilinear). ``out``: a C-contiguous array of the frame's shape
        and dtype, not overlapping it, to write the codes into (a recycled frame: no
        fresh pages to fault in). ``clip_hi``: a channel with a contributing tap at or
        above it comes out as the largest code (clipped; default: no such rule)."""
        frame = np.ascontiguousarray(frame)
        if frame.ndim == 2:
            frame = frame[:, :, None]
        if frame.dtype not in _PIXEL_T:
            raise TypeError(f"frames must be uint8 or uint16, not {frame.dtype}")
        h, w, c = frame.shape
        has_valid = valid is not None
        knl = self._kernel("warp", frame.dtype, c, has_valid, taps, clip_hi)
        m = [np.float32(v) for v in np.asarray(matrix, np.float64).ravel()]
        rows = max(1, min(h, int(strip_pixels) // max(w, 1)))
        px = frame.dtype.itemsize * c
        if out is None:
            out = np.empty_like(frame)
        else:
            out = out.reshape(frame.shape)
            if out.dtype != frame.dtype or not out.flags.c_contiguous or np.shares_memory(out, frame):
                raise ValueError("out must be a separate C-contiguous array of the frame's shape and dtype")
        flags = np.empty((h, w), np.uint8)
        q = self.queue
        out_b = self.buffer("warp_out", rows * w * px)
        flag_b = self.buffer("warp_flags", rows * w)
        vmask = np.ascontiguousarray(valid, dtype=np.uint8) if has_valid else None
        for y0 in range(0, h, rows):
            y1 = min(h, y0 + rows)
            b0, b1 = source_band(matrix, y0, y1, h, w)
            src_b = self.buffer("warp_src", (b1 - b0) * w * px, cl.mem_flags.READ_ONLY)
            cl.enqueue_copy(q, src_b, np.ascontiguousarray(frame[b0:b1]), is_blocking=False)
            val_b = self.buffer("warp_valid", (b1 - b0) * w if has_valid else 4, cl.mem_flags.READ_ONLY)
            if has_valid:
                cl.enqueue_copy(q, val_b, np.ascontiguousarray(vmask[b0:b1]), is_blocking=False)
            knl(q, (round_up(w, 16), round_up(y1 - y0, 4)), None, src_b, val_b, out_b, flag_b,
                np.int32(h), np.int32(w), np.int32(b0), np.int32(b1 - b0), np.int32(y0), np.int32(y1 - y0), *m)
            cl.enqueue_copy(q, out[y0:y1], out_b, is_blocking=False)
            cl.enqueue_copy(q, flags[y0:y1], flag_b, is_blocking=True)
        return out, (flags & 1).view(bool), (flags >> 1).view(bool)  # 0/1 bytes: views, no copies

    def warp_grid(self, band: np.ndarray, b0: int, h: int, matrix: np.ndarray, y0: int, rows: int, x0: int,
                  cols: int, step: int = 1, valid: Optional[np.ndarray] = None, taps: int = 4,
                  clip_hi: Optional[int] = None) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(codes, valid, covered)`` of the warped frame at frame coordinates
        ``(y0 + r step, x0 + x step)``, ``r < rows``, ``x < cols``: ``(rows, cols, C)``
        and ``(rows, cols)`` bool. ``band``: the frame's source rows ``b0 ..`` (``(B, W,
        C)``, every tap of those pixels inside it: :func:`hdrcl.core.align.warp.region_band`) of a frame ``h``
        rows high; ``valid``: the band's mask. Each pixel's value equals :meth:`warp`'s."""
        band = np.ascontiguousarray(band)
        if band.ndim == 2:
            band = band[:, :, None]
        if band.dtype not in _PIXEL_T:
            raise TypeError(f"frames must be uint8 or uint16, not {band.dtype}")
        bh, w, c = band.shape
        has_valid = valid is not None
        knl = self._kernel("warp_grid", band.dtype, c, has_valid, taps, clip_hi)
        m = [np.float32(v) for v in np.asarray(matrix, np.float64).ravel()]
        out = np.empty((rows, cols, c), band.dtype)
        flags = np.empty((rows, cols), np.uint8)
        q = self.queue
        out_b = self.buffer("grid_out", out.nbytes)
        flag_b = self.buffer("grid_flags", flags.nbytes)
        src_b = self.buffer("grid_src", band.nbytes, cl.mem_flags.READ_ONLY)
        val_b = self.buffer("grid_valid", bh * w if has_valid else 4, cl.mem_flags.READ_ONLY)
        cl.enqueue_copy(q, src_b, band, is_blocking=False)
        if has_valid:
            cl.enqueue_copy(q, val_b, np.ascontiguousarray(valid, dtype=np.uint8), is_blocking=False)
        with _GRID_LOCK:
            knl(q, (round_up(cols, 16), round_up(rows, 4)), None, src_b, val_b, out_b, flag_b,
                np.int32(h), np.int32(w), np.int32(b0), np.int32(bh), np.int32(y0), np.int32(rows),
                np.int32(x0), np.int32(cols), np.int32(step), *m)
        cl.enqueue_copy(q, out, out_b, is_blocking=False)
        cl.enqueue_copy(q, flags, flag_b, is_blocking=True)
        return out, (flags & 1).view(bool), (flags >> 1).view(bool)
