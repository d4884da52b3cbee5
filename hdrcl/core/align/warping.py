"""Warping a hand-held bracket's frames once their matrices are known
(:func:`hdrcl.core.align.handheld.align_bracket`): one frame (:func:`warp_one`), the frames as
their matrices become final (:class:`_Warps`), or again from a merge's record
(:func:`apply_alignment`)."""
from __future__ import annotations

import numpy as np

from hdrcl.core.align import warp as W

#: Interpolation of the warp: 4 (Keys' cubic, 4 x 4 taps) or 2 (bilinear).
WARP_TAPS = 4
#: Device warps run on a worker thread while the host estimates the next frames
#: (24 MP x 7, 2 cores: alignment 5.5 s against 6.4 s one after the other, medians of 3;
#: peak memory about 150 MB higher: the estimation's pyramids and the first warp at once).
OVERLAP_WARPS = True


def _warper(aligner):
    """A :class:`~hdrcl.cl.warp.WarpProcessor` on the aligner's device, or None (NumPy)."""
    ctx = getattr(aligner, "ctx", None)
    if ctx is None:
        return None
    from hdrcl.cl.warp import WarpProcessor

    proc = _WARPERS.get(id(ctx))
    if proc is None or proc.ctx is not ctx:
        proc = _WARPERS[id(ctx)] = WarpProcessor(ctx=ctx)
    return proc


_WARPERS: dict = {}


def warp_one(frame, m, valid, warper, out=None):
    """``(frame, valid)`` warped by ``m``: untouched for the identity, an exact copy for a
    whole-pixel shift, else resampled (device or twin; on the device into ``out`` when
    it is a free array of the frame's size and type). Black fill at the frame's border
    (:func:`hdrcl.core.align.warp.border_fill`) is masked before a frame is moved."""
    from hdrcl.core.align.mtb import _shift

    if W.is_integer_shift(m):
        dx, dy = int(round(m[0, 2])), int(round(m[1, 2]))
        if dx == 0 and dy == 0:
            return frame, None if valid is None else np.asarray(valid, bool)
    fill = W.border_fill(frame)  # a moved frame's black corners are no measurement: masked with it
    if fill is not None:
        valid = ~fill if valid is None else np.asarray(valid, bool) & ~fill
    if W.is_integer_shift(m):
        base = np.ones(frame.shape[:2], bool) if valid is None else np.asarray(valid, bool)
        return _shift(np.asarray(frame), dy, dx), _shift(base, dy, dx, fill=False)
    # Fusion's clip level: a channel blended from a clipped code is clipped (a lower bound
    # blended with its neighbours would be a believable mid-range value fusion trusts).
    clip_hi = W.clip_high(int(np.iinfo(np.asarray(frame).dtype).max))
    if warper is not None:
        if out is not None and (out.dtype != frame.dtype or out.size != np.size(frame)
                                or not out.flags.c_contiguous or np.may_share_memory(out, frame)):
            out = None
        res, ok, _ = warper.warp(frame, m, valid, taps=WARP_TAPS, out=out, clip_hi=clip_hi)
        return res.reshape(frame.shape), ok
    return W.warp_frame(frame, m, valid, taps=WARP_TAPS, clip_hi=clip_hi)


class _Warps:
    """Frames warped into ``out_f``/``out_v`` (by position in ``order``) as their
    matrices become final: on one worker thread when a device warps (it runs while the
    host estimates the next frames), recycling, with ``inplace``, the memory of frames
    already replaced."""

    def __init__(self, out_f, out_v, order, warper, inplace: bool):
        self.out_f, self.out_v, self.order, self.warper, self.inplace = out_f, out_v, order, warper, inplace
        self.spare = None
        self.done: set = set()
        self.futs: list = []
        self.pool = None
        if warper is not None and OVERLAP_WARPS:
            from concurrent.futures import ThreadPoolExecutor

            self.pool = ThreadPoolExecutor(1, thread_name_prefix="hdrcl-warp")

    def submit(self, pos: int, m: np.ndarray) -> None:
        if pos in self.done:
            return
        self.done.add(pos)
        if self.pool is None:
            self._one(pos, m)
        else:
            self.futs.append(self.pool.submit(self._one, pos, m))

    def _one(self, pos: int, m: np.ndarray) -> None:
        i = self.order[pos]
        src = self.out_f[i]
        self.out_f[i], self.out_v[i] = warp_one(src, m, self.out_v[i], self.warper, self.spare)
        if self.spare is not None and np.may_share_memory(self.out_f[i], self.spare):
            self.spare = None
        if self.inplace and self.out_f[i] is not src and isinstance(src, np.ndarray) and src.flags.writeable \
                and src.flags.c_contiguous and not any(np.may_share_memory(src, f) for f in self.out_f):
            self.spare = src

    def finish(self) -> None:
        """Wait for every warp (the first error raised) and stop the worker."""
        if self.pool is None:
            return
        try:
            for f in self.futs:
                f.result()
        finally:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.pool = None  # what is submitted from now on is warped at once


def apply_alignment(frames, valid, alignment, crop=None, device=None):
    """The frames and masks as a merge aligned them, from its ``result.alignment``
    (and ``result.crop``): for measuring what was merged (quality report)."""
    from hdrcl.core.align.mtb import get_aligner

    warper = _warper(get_aligner(device))
    out_f, out_v = [], []
    for f, v, a in zip(frames, valid, alignment):
        g, u = warp_one(f, np.asarray(a["matrix"], np.float64), v, warper)
        out_f.append(g)
        out_v.append(u)
    if crop is not None:
        out_f, out_v = W.crop_frames(out_f, out_v, crop)
    return out_f, out_v
