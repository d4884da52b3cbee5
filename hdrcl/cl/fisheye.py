"""Host side of ``kernels/fisheye.cl``: the projection and vignetting steps of a fisheye
luminance map; contracts: :func:`hdrcl.core.luminance.fisheye_math.equisolid_to_equidistant` and
:func:`hdrcl.core.luminance.fisheye_math.apply_vignetting`."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from hdrcl.cl.processing import OpenCLProcessor, round_up


class FisheyeProcessor(OpenCLProcessor):
    """Whole ``N x N`` pictures (the chain's output is small: 1000 x 1000 x 3 is 12 MB)."""

    source = "fisheye"

    def _run(self, img: np.ndarray, name: str, *extra) -> np.ndarray:
        n, _, c = img.shape
        src = np.ascontiguousarray(img, dtype=np.float32)
        in_b = self.buffer("fisheye_in", src.nbytes, cl.mem_flags.READ_ONLY)
        out_b = self.buffer("fisheye_out", src.nbytes, cl.mem_flags.WRITE_ONLY)
        cl.enqueue_copy(self.queue, in_b, src)
        knl = self.ctx.kernel("fisheye", name)
        args = (in_b, out_b) + extra[:1] + (np.int32(n), np.int32(c)) + extra[1:]
        knl(self.queue, (round_up(n * n),), None, *args)
        out = np.empty_like(src)
        cl.enqueue_copy(self.queue, out, out_b, is_blocking=True)
        return out

    def project(self, img: np.ndarray) -> np.ndarray:
        """Equisolid-angle to equidistant, float32 ``(N, N, C)``."""
        return self._run(img, "project_equisolid")

    def vignette(self, img: np.ndarray, coefficients, xc: float, yc: float, radius: float) -> np.ndarray:
        """``img / (a0 + a1 r + ... + a8 r^8)``, float32 ``(N, N, C)``."""
        a = np.zeros(9, np.float32)
        a[:len(coefficients)] = coefficients
        coeff_b = self.constant("fisheye_coeffs", a)
        return self._run(img, "vignette", coeff_b, np.float32(xc), np.float32(yc), np.float32(radius))
