"""Host side of ``kernels/exposure.cl``: radiance in, a virtual photograph out."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from hdrcl.cl.processing import OpenCLProcessor, round_up


class ExposureProcessor(OpenCLProcessor):
    """Renders ``Z = g^-1(ln E + ln dt)`` in strips; contract: :func:`hdrcl.core.reference.expose`.

    ``tables`` must already be non-decreasing (:func:`hdrcl.core.reference.monotone_tables`),
    as the kernel's inversion by search requires.
    """

    source = "exposure"

    def expose(self, radiance: np.ndarray, tables: np.ndarray, log_time: float, out_bits: int = 8) -> np.ndarray:
        h, w, c = radiance.shape
        levels = tables.shape[1]
        otype = np.uint8 if out_bits == 8 else np.uint16
        knl = self.ctx.kernel("exposure", "expose", ("-DOUT_T=" + ("uchar" if out_bits == 8 else "ushort"),))
        g_b = self.constant("gtab", np.asarray(tables, np.float32))
        outmax = (1 << out_bits) - 1
        rows = self.strip_rows(w)
        nmax = rows * w * c
        in_b = self.buffer("radiance", nmax * 4, cl.mem_flags.READ_ONLY)
        out_b = self.buffer("codes", nmax * np.dtype(otype).itemsize, cl.mem_flags.WRITE_ONLY)
        out = np.empty((h, w, c), otype)
        src = np.ascontiguousarray(radiance, dtype=np.float32)
        q = self.queue
        for r0 in range(0, h, rows):
            r1 = min(h, r0 + rows)
            n = (r1 - r0) * w * c
            cl.enqueue_copy(q, in_b, src[r0:r1], is_blocking=False)
            knl(q, (round_up(n),), None, in_b, g_b, out_b, np.int32(n), np.int32(c), np.int32(levels),
                np.float32(log_time), np.float32(outmax / (levels - 1)), np.float32(outmax))
            cl.enqueue_copy(q, out[r0:r1], out_b, is_blocking=True)
        return out
