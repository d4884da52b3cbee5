"""Host side of ``kernels/mertens.cl``: a window of a bracket's frames in, its fused rows out.

Contract: :class:`hdrcl.core.mertens.NumpyFusion` (``tops`` and ``blend``; the float64
twin). :mod:`hdrcl.core.mertens_bands` decides the windows. On the device one frame's
codes are held at a time (uploaded twice: once for the weights, once for the pyramids),
with every frame's weights, their sum, the grey and one pyramid each of the image, its
weights and the blend: about ``C * itemsize + 4 K + 8 + 4/3 * (8 C + 4)`` bytes a pixel for
K frames (48 + 4 K for 8-bit RGB; :func:`hdrcl.core.mertens_bands.working_bytes`).
"""
from __future__ import annotations

from typing import List, Optional, Sequence, Tuple

import numpy as np
import pyopencl as cl

from hdrcl.cl.processing import OpenCLProcessor, round_up

_PIXEL_T = {np.dtype(np.uint8): ("uchar", 1 / 255.0), np.dtype(np.uint16): ("ushort", 1 / 65535.0),
            np.dtype(np.float32): ("float", 1.0)}


def _shapes(h: int, w: int, levels: int) -> List[Tuple[int, int]]:
    out = [(h, w)]
    for _ in range(levels):
        h, w = (h + 1) // 2, (w + 1) // 2
        out.append((h, w))
    return out


def _grid(w: int, h: int):
    return (round_up(w, 16), round_up(h, 4))


class MertensProcessor(OpenCLProcessor):
    """Exposure fusion of a window of frames; weights (a ``FusionWeights``) as the twin's."""

    source = "mertens"

    @property
    def name(self) -> str:
        return self.ctx.name

    def _kernels(self, dtype, nch: int, has_valid: bool):
        pix, scale = _PIXEL_T[dtype]
        opts = (f"-DPIXEL_T={pix}", f"-DNCH={nch}") + (("-DHAS_VALID",) if has_valid else ()) \
            + ((f"-DINTEGER_CODES", f"-DSAT_T={'int' if pix == 'uchar' else 'long'}") if pix != "float" else ())
        names = ("grey", "weight_sum", "load", "pyr_down1", "pyr_downc", "blend", "blend_top", "collapse")
        return {n: self.ctx.kernel("mertens", n, opts) for n in names}, np.float32(scale)

    def _prepare(self, frames: Sequence[np.ndarray], valid):
        frames = [np.ascontiguousarray(f) for f in frames]
        dt = frames[0].dtype
        if dt not in _PIXEL_T:
            frames = [f.astype(np.float32) for f in frames]
            dt = np.dtype(np.float32)
        has_valid = valid is not None and any(v is not None for v in valid)
        masks = None
        if has_valid:
            shape = frames[0].shape[:2]
            masks = [np.ones(shape, np.uint8) if v is None else np.ascontiguousarray(v, np.uint8) for v in valid]
        return frames, masks, dt, has_valid

    def _pyramids(self, frames, valid, fw, levels: int, each):
        """Weight sum, then per frame its two Gaussian pyramids, handed to
        ``each(k, img_bufs, wn_bufs, shapes)`` (device buffers, finest first)."""
        frames, masks, dt, has_valid = self._prepare(frames, valid)
        h, w, c = frames[0].shape
        knl, scale = self._kernels(dt, c, has_valid)
        q = self.queue
        shapes = _shapes(h, w, levels)
        codes = self.buffer("codes", frames[0].nbytes, cl.mem_flags.READ_ONLY)
        vbuf = self.buffer("valid", h * w if has_valid else 4, cl.mem_flags.READ_ONLY)
        wsum = self.buffer("wsum", h * w * 4)
        gi = [self.buffer(f"gi{l}", sh * sw * c * 4) for l, (sh, sw) in enumerate(shapes)]
        gv = [self.buffer(f"gv{l}", sh * sw * 4) for l, (sh, sw) in enumerate(shapes)]
        args = (np.int32(w), np.int32(h), scale, np.float32(fw.contrast), np.float32(fw.saturation),
                np.float32(fw.exposedness), np.float32(1.0 / (2.0 * fw.sigma ** 2)))
        wk = [self.buffer(f"w{k}", h * w * 4) for k in range(len(frames))]
        grey = self.buffer("grey", h * w * 4)
        for k, f in enumerate(frames):
            cl.enqueue_copy(q, codes, f, is_blocking=False)
            if has_valid:
                cl.enqueue_copy(q, vbuf, masks[k], is_blocking=False)
            knl["grey"](q, _grid(w, h), None, codes, grey, np.int32(w), np.int32(h))
            knl["weight_sum"](q, _grid(w, h), None, codes, grey, vbuf, wk[k], wsum, *args, np.int32(k == 0))
        for k, f in enumerate(frames):
            cl.enqueue_copy(q, codes, f, is_blocking=False)
            knl["load"](q, _grid(w, h), None, codes, wk[k], wsum, gi[0], gv[0], np.int32(w), np.int32(h), scale)
            for lv in range(levels):
                (sh, sw), (dh, dw) = shapes[lv], shapes[lv + 1]
                dims = (np.int32(sw), np.int32(sh), np.int32(dw), np.int32(dh))
                knl["pyr_downc"](q, _grid(dw, dh), None, gi[lv], gi[lv + 1], *dims)
                knl["pyr_down1"](q, _grid(dw, dh), None, gv[lv], gv[lv + 1], *dims)
            each(k, gi, gv, shapes, knl)
        q.finish()
        return knl

    def tops(self, frames, valid, fw, levels: int):
        """Level ``levels`` of every frame's pyramids: ``([G(I_k)], [G(V_k)])``, float32."""
        out_i, out_v = [], []
        c = np.asarray(frames[0]).shape[2]

        def each(k, gi, gv, shapes, knl):
            dh, dw = shapes[levels]
            a, b = np.empty((dh, dw, c), np.float32), np.empty((dh, dw), np.float32)
            cl.enqueue_copy(self.queue, a, gi[levels], is_blocking=False)
            cl.enqueue_copy(self.queue, b, gv[levels], is_blocking=False)
            out_i.append(a)
            out_v.append(b)

        self._pyramids(frames, valid, fw, levels, each)
        return out_i, out_v

    def blend(self, frames, valid, fw, levels: int, top: Optional[np.ndarray] = None,
              rows: Optional[Tuple[int, int]] = None) -> np.ndarray:
        """The fused window, float32 ``(h, w, c)``, or only its ``rows = (i0, i1)``;
        ``top``: the coarse part at level ``levels``."""
        q = self.queue
        f0 = np.asarray(frames[0])
        h, w, c = f0.shape
        shapes = _shapes(h, w, levels)
        acc = [self.buffer(f"acc{l}", sh * sw * c * 4) for l, (sh, sw) in enumerate(shapes)]

        def each(k, gi, gv, shapes, knl):
            first = np.int32(k == 0)
            for lv in range(levels):
                (sh, sw), (ch, cw) = shapes[lv], shapes[lv + 1]
                knl["blend"](q, _grid(sw, sh), None, acc[lv], gi[lv], gi[lv + 1], gv[lv], np.int32(sw), np.int32(sh),
                             np.int32(cw), np.int32(ch), first)
            if top is None:
                sh, sw = shapes[levels]
                knl["blend_top"](q, _grid(sw, sh), None, acc[levels], gi[levels], gv[levels], np.int32(sw),
                                 np.int32(sh), first)

        knl = self._pyramids(frames, valid, fw, levels, each)
        if top is not None:
            cl.enqueue_copy(q, acc[levels], np.ascontiguousarray(top, np.float32))
        for lv in range(levels - 1, -1, -1):
            (sh, sw), (ch, cw) = shapes[lv], shapes[lv + 1]
            knl["collapse"](q, _grid(sw, sh), None, acc[lv], acc[lv + 1], np.int32(sw), np.int32(sh), np.int32(cw),
                            np.int32(ch))
        i0, i1 = rows or (0, h)
        out = np.empty((i1 - i0, w, c), np.float32)
        cl.enqueue_copy(q, out, acc[0], src_offset=i0 * w * c * 4, is_blocking=True)
        return out
