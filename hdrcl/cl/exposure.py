"""Host side of ``kernels/exposure.cl``: radiance in, a virtual photograph out."""
from __future__ import annotations

import numpy as np

from hdrcl.cl.processing import OpenCLProcessor, round_up


class ExposureProcessor(OpenCLProcessor):
    """Renders ``Z = g^-1(ln E + ln dt)`` in strips; contract: :func:`hdrcl.core.reference.expose`.

    ``tables`` must already be non-decreasing (:func:`hdrcl.core.reference.monotone_tables`),
    as the kernel's inversion by search requires.
    """

    source = "exposure"

    def expose(self, radiance: np.ndarray, tables: np.ndarray, log_time: float, out_bits: int = 8) -> np.ndarray:
        c = radiance.shape[2]
        levels = tables.shape[1]
        otype = np.uint8 if out_bits == 8 else np.uint16
        knl = self.ctx.kernel("exposure", "expose", ("-DOUT_T=" + ("uchar" if out_bits == 8 else "ushort"),))
        g_b = self.constant("gtab", np.asarray(tables, np.float32))
        outmax = (1 << out_bits) - 1

        def run(q, in_b, out_b, npix):
            n = npix * c
            knl(q, (round_up(n),), None, in_b, g_b, out_b, np.int32(n), np.int32(c), np.int32(levels),
                np.float32(log_time), np.float32(outmax / (levels - 1)), np.float32(outmax))

        return self.map_strips(radiance, otype, run)
