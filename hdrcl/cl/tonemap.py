"""Host side of ``kernels/tonemap.cl``: a global tone-mapping operator, strip by strip."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from hdrcl.cl.processing import OpenCLProcessor, round_up


class TonemapProcessor(OpenCLProcessor):
    """Per-pixel stage of the global operators; contract: ``tonemap.apply_global``."""

    source = "tonemap"

    def apply(self, radiance: np.ndarray, op_code: int, scale: float, white: float, bits: int = 8) -> np.ndarray:
        """sRGB codes ``(H, W, C)`` (uint8 or uint16) of float32 radiance ``(H, W, C)``."""
        h, w, c = radiance.shape
        otype = np.uint8 if bits == 8 else np.uint16
        knl = self.ctx.kernel("tonemap", "tonemap_global", ("-DOUT_T=" + ("uchar" if bits == 8 else "ushort"),))
        rows = self.strip_rows(w)
        nmax = rows * w * c
        in_b = self.buffer("radiance", nmax * 4, cl.mem_flags.READ_ONLY)
        out_b = self.buffer("codes", nmax * np.dtype(otype).itemsize, cl.mem_flags.WRITE_ONLY)
        out = np.empty((h, w, c), otype)
        src = np.ascontiguousarray(radiance, dtype=np.float32)
        q = self.queue
        for r0 in range(0, h, rows):
            r1 = min(h, r0 + rows)
            npix = (r1 - r0) * w
            cl.enqueue_copy(q, in_b, src[r0:r1], is_blocking=False)
            knl(q, (round_up(npix),), None, in_b, out_b, np.int32(npix), np.int32(c), np.int32(op_code),
                np.float32(scale), np.float32(white), np.float32((1 << bits) - 1))
            cl.enqueue_copy(q, out[r0:r1], out_b, is_blocking=True)
        return out
