"""Base of the OpenCL processors: device context, strip size, buffer reuse."""
from __future__ import annotations

from typing import Dict, Optional, Tuple

import numpy as np
import pyopencl as cl

from hdrcl.cl.context import DeviceContext, get_context

#: Pixels per strip: bounds host and device memory whatever the image size (256 K
#: pixels: at 24 MP x 7 a strip of codes is 5.5 MB; 1 M-pixel strips cost a merge about
#: 120 MB more peak memory and were no faster).
STRIP_PIXELS = 1 << 18
#: Global work sizes are rounded up to a multiple of this.
WORK_MULTIPLE = 64


def round_up(n: int, m: int = WORK_MULTIPLE) -> int:
    return ((n + m - 1) // m) * m


class OpenCLProcessor:
    """Owns a :class:`DeviceContext` and device buffers reused across calls.

    Subclasses name their kernel file and call :meth:`buffer` for scratch space; a
    buffer is re-allocated only when a larger one is needed.
    """

    source = ""

    def __init__(self, device: Optional[str] = None, ctx: Optional[DeviceContext] = None,
                 strip_pixels: Optional[int] = None):
        self.ctx = ctx or get_context(device)
        self.strip_pixels = int(strip_pixels or STRIP_PIXELS)  # read now: tests change it
        self._buffers: Dict[str, Tuple[int, "cl.Buffer"]] = {}

    @property
    def queue(self) -> "cl.CommandQueue":
        return self.ctx.queue

    def buffer(self, name: str, nbytes: int, flags=cl.mem_flags.READ_WRITE) -> "cl.Buffer":
        nbytes = max(int(nbytes), 4)
        have = self._buffers.get(name)
        if have is None or have[0] < nbytes:
            buf = cl.Buffer(self.ctx.context, flags, nbytes)
            self._buffers[name] = (nbytes, buf)
            return buf
        return have[1]

    def constant(self, name: str, array: np.ndarray) -> "cl.Buffer":
        """A read-only buffer holding ``array`` (copied now)."""
        array = np.ascontiguousarray(array)
        buf = self.buffer(name, array.nbytes, cl.mem_flags.READ_ONLY)
        cl.enqueue_copy(self.queue, buf, array)
        return buf

    def strip_rows(self, width: int) -> int:
        return max(1, self.strip_pixels // max(width, 1))

    def map_strips(self, radiance: np.ndarray, otype, run) -> np.ndarray:
        """Float32 ``radiance`` ``(H, W, C)`` through a per-pixel kernel, strip by strip.

        ``run(queue, in_buf, out_buf, npix)`` enqueues the kernel for the ``npix`` pixels
        of the strip now in ``in_buf`` (``C`` values each); the strip's ``otype`` results in
        ``out_buf`` are copied back. Returns the ``(H, W, C)`` array of ``otype``.
        """
        h, w, c = radiance.shape
        rows = self.strip_rows(w)
        nmax = rows * w * c
        in_b = self.buffer("radiance", nmax * 4, cl.mem_flags.READ_ONLY)
        out_b = self.buffer("codes", nmax * np.dtype(otype).itemsize, cl.mem_flags.WRITE_ONLY)
        out = np.empty((h, w, c), otype)
        src = np.ascontiguousarray(radiance, dtype=np.float32)
        q = self.queue
        for r0 in range(0, h, rows):
            r1 = min(h, r0 + rows)
            cl.enqueue_copy(q, in_b, src[r0:r1], is_blocking=False)
            run(q, in_b, out_b, (r1 - r0) * w)
            cl.enqueue_copy(q, out[r0:r1], out_b, is_blocking=True)
        return out
