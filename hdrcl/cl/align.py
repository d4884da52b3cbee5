"""Host side of ``kernels/align.cl``: grey pyramids, bit-packed threshold bitmaps and
shift costs on the device.

The search (coarse to fine, thresholds, the tie rule) lives in :mod:`hdrcl.core.align.mtb`,
which drives this processor or its NumPy twin :class:`hdrcl.core.align.mtb.NumpyAligner`
through the same three calls: :meth:`~AlignProcessor.grey_pyramid`,
:meth:`~AlignProcessor.bitmaps` and :meth:`~AlignProcessor.costs`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Sequence, Tuple

import numpy as np
import pyopencl as cl

from hdrcl.cl.processing import OpenCLProcessor, round_up
from hdrcl.cl.pyramid import GreyPyramid, level_shapes

_PIXEL_T = {np.dtype(np.uint8): "uchar", np.dtype(np.uint16): "ushort"}
#: Work-group size asked of shift_cost (a power of two; less where the device allows less).
_WG = 64
#: At most this many work-groups in shift_cost's grid-stride loop.
_MAX_GROUPS = 1024


@dataclass
class DeviceBitmaps:
    """Bit-packed threshold and exclusion bitmaps of a pyramid (device buffers)."""

    slot: str
    shapes: List[Tuple[int, int]]
    thresholds: List[int]
    tb: List["cl.Buffer"] = field(default_factory=list)
    eb: List["cl.Buffer"] = field(default_factory=list)


def words(w: int) -> int:
    """uint words per bitmap row of ``w`` pixels."""
    return (w + 31) // 32


class AlignProcessor(OpenCLProcessor):
    """Median threshold bitmaps and their shift costs on the device.

    Contract: the twins in :mod:`hdrcl.core.align.mtb` (``grey_image``, ``downsample``,
    ``threshold_bitmaps``, ``shift_costs``); results are equal, not merely close.
    Buffers belong to a *slot* (``"ref"``, ``"frame"``) and are reused from one call to
    the next: a pyramid or its bitmaps stay valid until their slot is rebuilt.
    """

    source = "align"

    def _cost_kernel(self):
        knl = getattr(self, "_cost_knl", None)
        if knl is None:
            wg = _WG
            knl = self.ctx.kernel("align", "shift_cost", (f"-DWG={wg}",))
            limit = knl.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE, self.ctx.device)
            if limit < wg:  # the largest power of two the device takes
                wg = 1 << (int(limit).bit_length() - 1)
                knl = self.ctx.kernel("align", "shift_cost", (f"-DWG={wg}",))
            self._cost_knl, self._wg = knl, wg
        return knl

    def grey_pyramid(self, frame: np.ndarray, levels: int, slot: str = "frame", host_from: int = 0) -> GreyPyramid:
        """Grey levels of ``frame`` ``(H, W, C)`` or ``(H, W)``, built on the device and
        also read back (the host picks thresholds from them), from level ``host_from``
        on (the finer ones are None in ``host``)."""
        frame = np.asarray(frame)
        if frame.ndim == 2:
            frame = frame[:, :, None]
        dtype = frame.dtype
        if dtype not in _PIXEL_T:
            raise TypeError(f"frames must be uint8 or uint16, not {dtype}")
        h, w, c = frame.shape
        if c == 2:
            raise ValueError("alignment needs 1 channel or at least 3 (R, G, B first), not 2")
        if h * w >= 2**31:
            raise ValueError(f"a {h}x{w} frame is too large to align (2^31 pixels at most)")
        shapes = level_shapes(h, w, levels)
        q = self.queue
        grey_k = self.ctx.kernel("align", "grey", (f"-DPIXEL_T={_PIXEL_T[dtype]}", f"-DNCH={c}"))
        down_k = self.ctx.kernel("align", "downsample")
        dev = [self.buffer(f"{slot}_grey{k}", hk * wk * 2) for k, (hk, wk) in enumerate(shapes)]
        # Level 0 in strips: the frame itself never has to fit the device whole.
        rows = self.strip_rows(w)
        in_b = self.buffer("codes", rows * w * c * dtype.itemsize, cl.mem_flags.READ_ONLY)
        for r0 in range(0, h, rows):
            r1 = min(h, r0 + rows)
            n = (r1 - r0) * w
            cl.enqueue_copy(q, in_b, np.ascontiguousarray(frame[r0:r1]), is_blocking=False)
            grey_k(q, (round_up(n),), None, in_b, dev[0], np.int32(n), np.int32(r0 * w))
        for k in range(1, len(shapes)):
            (_, sw), (dh, dw) = shapes[k - 1], shapes[k]
            down_k(q, (round_up(dw, 16), round_up(dh, 4)), None, dev[k - 1], dev[k],
                   np.int32(sw), np.int32(dh), np.int32(dw))
        host = [np.empty(s, np.uint16) if k >= host_from else None for k, s in enumerate(shapes)]
        for k in range(host_from, len(shapes)):
            cl.enqueue_copy(q, host[k], dev[k], is_blocking=False)
        q.finish()
        return GreyPyramid(slot, shapes, host, dev)

    def bitmaps(self, gp: GreyPyramid, thresholds: Sequence[int], tol: int) -> DeviceBitmaps:
        """Packed ``tb = grey > t`` and ``eb = |grey - t| > tol`` of every level, into the
        pyramid's slot."""
        thr_k = self.ctx.kernel("align", "threshold")
        bm = DeviceBitmaps(gp.slot, gp.shapes, [int(t) for t in thresholds])
        for k, (hk, wk) in enumerate(gp.shapes):
            nw = words(wk)
            tb = self.buffer(f"{gp.slot}_tb{k}", hk * nw * 4)
            eb = self.buffer(f"{gp.slot}_eb{k}", hk * nw * 4)
            thr_k(self.queue, (round_up(nw, 16), round_up(hk, 4)), None, gp.dev[k], tb, eb, np.int32(hk),
                  np.int32(wk), np.int32(nw), np.int32(bm.thresholds[k]), np.int32(tol))
            bm.tb.append(tb)
            bm.eb.append(eb)
        return bm

    def costs(self, ref: DeviceBitmaps, frm: DeviceBitmaps, level: int, cy: int, cx: int) -> np.ndarray:
        """Mismatch counts ``(3, 3)`` int64 of the shifts ``(cy + j - 1, cx + i - 1)`` at
        ``level``; contract: :func:`hdrcl.core.align.mtb.shift_costs`."""
        if ref.shapes[level] != frm.shapes[level]:
            raise ValueError(f"pyramid levels differ in shape: {ref.shapes[level]} vs {frm.shapes[level]}")
        knl = self._cost_kernel()
        h, w = ref.shapes[level]
        nw = words(w)
        q = self.queue
        counts = np.zeros(9, np.uint32)
        counts_b = self.buffer("counts", counts.nbytes)
        cl.enqueue_copy(q, counts_b, counts, is_blocking=False)
        groups = max(1, min(_MAX_GROUPS, -(-h * nw // self._wg)))
        knl(q, (groups * self._wg,), (self._wg,), ref.tb[level], ref.eb[level], frm.tb[level], frm.eb[level],
            counts_b, np.int32(h), np.int32(nw), np.int32(cy), np.int32(cx))
        cl.enqueue_copy(q, counts, counts_b, is_blocking=True)
        return counts.astype(np.int64).reshape(3, 3)

    def read_bitmaps(self, bm: DeviceBitmaps, level: int) -> Tuple[np.ndarray, np.ndarray]:
        """The ``(tb, eb)`` of ``level`` unpacked to ``(h, w)`` bool, and the padding bits
        checked to be 0 (for tests)."""
        h, w = bm.shapes[level]
        nw = words(w)
        out = []
        for buf in (bm.tb[level], bm.eb[level]):
            packed = np.empty((h, nw), np.uint32)
            cl.enqueue_copy(self.queue, packed, buf, is_blocking=True)
            bits = np.unpackbits(packed.astype("<u4").view(np.uint8), axis=1, bitorder="little")
            if bits[:, w:].any():
                raise AssertionError("bitmap padding bits are not 0")
            out.append(bits[:, :w].astype(bool))
        return out[0], out[1]
