"""Host side of ``kernels/tonemap.cl``: a global tone-mapping operator, strip by strip."""
from __future__ import annotations

import numpy as np

from hdrcl.cl.processing import OpenCLProcessor, round_up


class TonemapProcessor(OpenCLProcessor):
    """Per-pixel stage of the global operators; contract: ``tonemap.apply_global``."""

    source = "tonemap"

    def apply(self, radiance: np.ndarray, op_code: int, scale: float, white: float, bits: int = 8) -> np.ndarray:
        """sRGB codes ``(H, W, C)`` (uint8 or uint16) of float32 radiance ``(H, W, C)``."""
        c = radiance.shape[2]
        otype = np.uint8 if bits == 8 else np.uint16
        knl = self.ctx.kernel("tonemap", "tonemap_global", ("-DOUT_T=" + ("uchar" if bits == 8 else "ushort"),))

        def run(q, in_b, out_b, npix):
            knl(q, (round_up(npix),), None, in_b, out_b, np.int32(npix), np.int32(c), np.int32(op_code),
                np.float32(scale), np.float32(white), np.float32((1 << bits) - 1))

        return self.map_strips(radiance, otype, run)
