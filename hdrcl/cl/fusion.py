"""Host side of ``kernels/fusion.cl``: a bracket in, a float32 radiance map out."""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np
import pyopencl as cl

from .processing import OpenCLProcessor, round_up

_PIXEL_T = {np.dtype(np.uint8): "uchar", np.dtype(np.uint16): "ushort"}


class FusionProcessor(OpenCLProcessor):
    """Weighted log-domain fusion, streamed through the device in horizontal strips.

    The numeric contract is :func:`hdrcl.reference.fuse` (its docstring has the
    equations and the zero-weight rule).
    """

    source = "fusion"

    def fuse(
        self,
        frames: Sequence[np.ndarray],
        log_times: Sequence[float],
        tables: np.ndarray,
        weights: np.ndarray,
        valid: Optional[Sequence[Optional[np.ndarray]]] = None,
        out: Optional[np.ndarray] = None,
    ):
        """Fuse ``frames`` (ordered by increasing exposure).

        Parameters are those of :func:`hdrcl.reference.fuse`; ``out`` may be a
        preallocated ``(H, W, C)`` float32 array.

        Returns
        -------
        radiance : ndarray (H, W, C) float32
        counts : dict
        """
        p = len(frames)
        h, w, c = frames[0].shape
        dtype = frames[0].dtype
        if dtype not in _PIXEL_T:
            raise TypeError(f"frames must be uint8 or uint16, not {dtype}")
        levels = tables.shape[1]
        log_t = np.asarray(log_times, np.float64)
        knl = self.ctx.kernel("fusion", "fuse", (f"-DPIXEL_T={_PIXEL_T[dtype]}",))

        wt = np.asarray(weights, np.float64)
        lut = (wt[None, None, :] * (tables[None, :, :] - log_t[:, None, None])).astype(np.float32)
        hi = (tables[None, :, levels - 1] - log_t[:, None]).astype(np.float32)
        lo = (tables[None, :, 0] - log_t[:, None]).astype(np.float32)
        lut_b = self.constant("lut", lut)
        w_b = self.constant("wlut", wt.astype(np.float32))
        hi_b = self.constant("hi", hi)
        lo_b = self.constant("lo", lo)
        counts = np.zeros(3, np.uint32)
        cnt_b = self.constant("counts", counts)

        rows = self.strip_rows(w)
        spix = rows * w
        plane = spix * c
        frames_b = self.buffer("frames", p * plane * dtype.itemsize, cl.mem_flags.READ_ONLY)
        has_valid = valid is not None and any(v is not None for v in valid)
        valid_b = self.buffer("valid", p * spix if has_valid else 1, cl.mem_flags.READ_ONLY)
        out_b = self.buffer("out", plane * 4, cl.mem_flags.WRITE_ONLY)
        if out is None:
            out = np.empty((h, w, c), np.float32)
        ones = np.ones(spix, np.uint8) if has_valid else None

        q = self.queue
        for r0 in range(0, h, rows):
            r1 = min(h, r0 + rows)
            npix = (r1 - r0) * w
            for j, f in enumerate(frames):
                cl.enqueue_copy(q, frames_b, np.ascontiguousarray(f[r0:r1]),
                                dst_offset=j * plane * dtype.itemsize, is_blocking=False)
                if has_valid:
                    v = ones[:npix] if valid[j] is None else np.ascontiguousarray(valid[j][r0:r1], dtype=np.uint8)
                    cl.enqueue_copy(q, valid_b, v, dst_offset=j * spix, is_blocking=False)
            knl(q, (round_up(npix),), None, frames_b, valid_b, lut_b, w_b, hi_b, lo_b, out_b, cnt_b,
                np.int32(npix), np.int32(p), np.int32(c), np.int32(levels), np.int32(plane),
                np.int32(spix), np.int32(1 if has_valid else 0))
            cl.enqueue_copy(q, out[r0:r1], out_b, is_blocking=True)
        cl.enqueue_copy(q, counts, cnt_b, is_blocking=True)
        return out, {"clipped_high": int(counts[0]), "clipped_low": int(counts[1]), "no_data": int(counts[2])}
