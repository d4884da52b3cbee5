"""Exposure fusion in horizontal bands: memory bounded by the band, not the image.

A Laplacian pyramid's coarse levels span the whole image, so the fusion cannot simply
run strip by strip. It runs in two passes over bands of rows, each band read with a
halo of :data:`HALO_UNITS` x 2^D rows above and below (D = :data:`BAND_LEVELS`):

1. each band's frames give their Gaussian pyramids down to level D (of the images and
   of the normalised weights V_k, which are per pixel and so exact in any band); the
   band's own rows of level D are kept: K small images of 1/4^D of the pixels;
2. the coarse part -- the blend of levels D .. top, collapsed to level D -- is computed
   from them once, by the float64 twin (:func:`hdrcl.core.pyramids.blend` on the level-D
   images: pyrDown of level D *is* level D + 1);
3. each band again: its fine levels 0 .. D - 1 blended and collapsed on top of its rows
   of the coarse part; the band's own rows are the result.

This is OpenCV's result, not an approximation: band starts are multiples of 2^D, so every
level of a band lies on the whole image's sampling grid, and the halo is wider than the
reach of the rows the band's edges spoil (its reflect-101 border is wrong inside the
image). ``tests/test_mertens.py`` checks bands against the whole image. The cost is the
halo, decoded and filtered twice, and the pyramid down to level D computed in both passes.

The other way, normalising after the pyramids (``sum_k Lap(I_k) G(W_k) / G(sum_k W_k)``,
one pass with no full-size weight sum), is not OpenCV's: G(W/S) != G(W)/G(S).
"""
from __future__ import annotations

import logging
from typing import Callable, Iterator, Optional, Sequence, Tuple

import numpy as np

from hdrcl.core.pyramids import blend, level_size, max_level
from hdrcl.errors import UsageError

logger = logging.getLogger(__name__)

#: Pyramid levels a band computes itself; the rest is the coarse part (1/4^D of the pixels).
BAND_LEVELS = 4
#: Halo above and below a band, in units of 2^BAND_LEVELS rows (measured: 3 is the least
#: that keeps bands equal to the whole image; 4 leaves a margin).
HALO_UNITS = 4
#: Working set (bytes) up to which an image is fused whole, in one pass (24 MP x 7 frames
#: of 8-bit RGB: 1.7 GB; OpenCV's MergeMertens holds 5.8 GB for them).
WHOLE_BYTES = 2_000_000_000
#: Working set (bytes) of one band, halo included, when the image is fused in bands.
BAND_BYTES = 320_000_000


def working_bytes(rows: int, width: int, channels: int, itemsize: int, frames: int, made: bool = False) -> int:
    """Bytes a window of ``rows`` rows costs on the kernel path: one frame's codes on the
    device, every frame's weights, their sum and the grey, and the pyramids (4/3) of one
    image, one weight and the blend, in float32; with ``made``, every frame's codes too
    (a :class:`RowSource` makes them for the window; an :class:`ArraySource` lends views)."""
    host = frames * channels * itemsize if made else 0
    return int(rows * width * (host + channels * itemsize + 4 * frames + 8 + (4 * (2 * channels + 1) * 4) // 3))


class ArraySource:
    """Frames held in memory: ``rows(k, a, b)`` is rows ``a .. b`` of frame ``k``."""

    made = False  # rows are views of the caller's frames

    def __init__(self, frames, valid=None):
        if isinstance(frames, np.ndarray) and frames.ndim >= 3 and frames.dtype != object:
            frames = list(frames)
        frames = [np.asarray(f) for f in frames]
        if len(frames) < 2:
            raise UsageError(f"frames: exposure fusion needs at least 2 frames, not {len(frames)}")
        frames = [f[..., None] if f.ndim == 2 else f for f in frames]
        first = frames[0]
        for i, f in enumerate(frames):
            if f.ndim != 3 or f.shape[2] not in (1, 3):
                raise UsageError(f"frame {i}: expected (H, W, 3) or (H, W), not shape {f.shape}")
            if f.shape != first.shape:
                raise UsageError(f"frame {i}: size {f.shape[1]}x{f.shape[0]} differs from frame 0's "
                                 f"{first.shape[1]}x{first.shape[0]}")
            if f.dtype != first.dtype:
                raise UsageError(f"frame {i}: {f.dtype} differs from frame 0's {first.dtype}")
            if f.dtype.kind not in "uf" or (f.dtype.kind == "u" and f.dtype.itemsize > 2):
                raise UsageError(f"frame {i}: expected uint8, uint16 or float pixels, not {f.dtype}")
            if f.dtype.kind == "f" and not np.isfinite(f).all():
                raise UsageError(f"frame {i}: NaN or infinite pixel values")
        if min(first.shape[:2]) < 2:
            raise UsageError(f"frames: {first.shape[1]}x{first.shape[0]} is too small to fuse (2x2 at least)")
        self.frames = frames
        if valid is not None:
            valid = [None if v is None else np.asarray(v, bool) for v in valid]
            if len(valid) != len(frames) or any(v is not None and v.shape != first.shape[:2] for v in valid):
                raise UsageError("valid: expected one (H, W) mask (or None) per frame")
            if all(v is None for v in valid):
                valid = None
        self.valid = valid
        self.height, self.width, self.channels = first.shape
        self.count = len(frames)
        self.dtype = first.dtype

    def rows(self, k: int, a: int, b: int) -> np.ndarray:
        return self.frames[k][a:b]

    def valid_rows(self, a: int, b: int):
        if self.valid is None:
            return None
        return [None if v is None else v[a:b] for v in self.valid]


class RowSource:
    """Frames made or decoded on demand: ``read(k, a, b)`` returns rows ``a .. b`` of frame
    ``k`` as ``(b - a, width, channels)`` codes (generated frames, band readers)."""

    made = True  # every window's rows are made for it: memory of the band

    def __init__(self, height: int, width: int, channels: int, count: int, dtype,
                 read: Callable[[int, int, int], np.ndarray]):
        self.height, self.width, self.channels, self.count = int(height), int(width), int(channels), int(count)
        self.dtype = np.dtype(dtype)
        self.valid = None
        self._read = read

    def rows(self, k: int, a: int, b: int) -> np.ndarray:
        return self._read(k, a, b)

    def valid_rows(self, a: int, b: int):
        return None


def plan_bands(src, band_rows: Optional[int] = None) -> Tuple[int, int, int]:
    """``(levels D, band rows, halo rows)``; D = the full depth for a whole-image run."""
    h, w = src.height, src.width
    top = max_level(h, w)
    item = np.dtype(src.dtype).itemsize
    if band_rows is None and working_bytes(h, w, src.channels, item, src.count, src.made) <= WHOLE_BYTES:
        return top, h, 0
    d = min(BAND_LEVELS, top)
    unit = 1 << d
    halo = HALO_UNITS * unit
    if band_rows is None:
        fit = BAND_BYTES // max(1, working_bytes(1, w, src.channels, item, src.count, src.made)) - 2 * halo
        band_rows = max(unit, fit)
    band = max(unit, (int(band_rows) // unit) * unit)
    if band >= h:
        return top, h, 0
    return d, band, halo


def fuse_bands(src, fw, backend, band_rows: Optional[int] = None
               ) -> Iterator[Tuple[int, int, np.ndarray]]:
    """Yield ``(r0, r1, rows)`` of the fused image, top to bottom (float32 rows).

    ``fw``: the :class:`hdrcl.core.mertens.FusionWeights`; ``backend``: the OpenCL
    processor or the twin (``tops`` and ``blend``, :class:`hdrcl.core.mertens.NumpyFusion`).
    """
    h, w = src.height, src.width
    top = max_level(h, w)
    d, band, halo = plan_bands(src, band_rows)
    k = src.count

    def window(a, b):
        return [src.rows(i, a, b) for i in range(k)], src.valid_rows(a, b)

    if band >= h:
        logger.info("exposure fusion: %dx%d x %d whole, %d levels, on %s", w, h, k, top + 1, backend.name)
        frames, valid = window(0, h)
        yield 0, h, backend.blend(frames, valid, fw, top)
        return
    bands = [(r0, min(h, r0 + band)) for r0 in range(0, h, band)]
    logger.info("exposure fusion: %dx%d x %d in %d bands of %d rows (halo %d), %d levels (%d per band), on %s",
                w, h, k, len(bands), band, halo, top + 1, d, backend.name)
    hd, wd = level_size(h, d), level_size(w, d)
    gi = np.empty((k, hd, wd, src.channels), np.float32)
    gv = np.empty((k, hd, wd), np.float32)
    for r0, r1 in bands:
        a, b = max(0, r0 - halo), min(h, r1 + halo)
        ti, tv = backend.tops(*window(a, b), fw, d)
        c0, c1 = r0 >> d, (r1 >> d if r1 < h else hd)
        off = a >> d
        for i in range(k):
            gi[i, c0:c1] = ti[i][c0 - off:c1 - off]
            gv[i, c0:c1] = tv[i][c0 - off:c1 - off]
    coarse = blend([g.astype(np.float64) for g in gi], [g.astype(np.float64) for g in gv], top - d)
    coarse = coarse.astype(np.float32)
    del gi, gv
    frames = valid = None
    for r0, r1 in bands:
        a, b = max(0, r0 - halo), min(h, r1 + halo)
        off = a >> d
        frames = valid = None  # the last band's rows go before this band's are made
        frames, valid = window(a, b)
        yield r0, r1, backend.blend(frames, valid, fw, d, coarse[off:off + level_size(b - a, d)],
                                    rows=(r0 - a, r1 - a))
