"""Alignment through the fusion: an aligned merge samples each frame through its
transform strip by strip, and no warped copy of a frame is ever held (``merge --align``).

:func:`aligned_source` decodes every frame once, into the same
:class:`hdrcl.io.framecache.FrameCache` a plain merge keeps for its fusion pass (in
memory, or spilled to an unlinked scratch file past a quarter of ``HDRCL_MEMORY_MB``),
estimates each frame's transform from it (:func:`hdrcl.core.align.handheld.estimate`,
on the pyramid level of at most :data:`hdrcl.core.align.register.ESTIMATE_PIXELS`,
refitted on tiles: :mod:`hdrcl.core.align.tilefit`), and returns an
:class:`AlignedSource`: the strip source the fusion reads (``strips``, ``dtype``,
``valid``, ``rewind``, ``close``, as :class:`hdrcl.io.reader.BracketReader`).

For each chunk of :data:`CHUNK_PIXELS` output pixels the source reads, per frame, only
the band of source rows that chunk's taps reach (:func:`hdrcl.cl.warp.region_band`: the
chunk's rows plus the transform's vertical extent over its width) and warps it there
(``warp_grid`` in ``kernels/warp.cl``, the NumPy twin
:func:`hdrcl.core.align.warp.warp_grid`): the same equations, the same float32
operations per pixel as the whole-frame warp (:func:`hdrcl.core.align.warping.warp_one`),
hence the same codes. A frame left where it is (the reference, a static bracket) is
served from the cache as decoded; a whole-pixel shift is a copy. The next chunk is
warped on a worker thread while the fusion works on this one.

``frames`` and ``valid`` are views (:class:`WarpedView`): slicing one (``f[::k, ::k]``
for the sampling grid, ``f[y:y + h, x:x + w]`` for a reference patch) warps only the
pixels asked for; anything else (``np.asarray``) warps the whole frame.
"""
from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from typing import List, Optional

import numpy as np

from hdrcl.core.align import warp as W

logger = logging.getLogger(__name__)

#: Output pixels per frame warped at once (one chunk: a multiple of the fusion's strip).
CHUNK_PIXELS = 1 << 19


@dataclass
class AlignRecord:
    """What the alignment found, for the merge's result and metadata: per frame merged,
    the whole-pixel shifts and records (:func:`hdrcl.core.align.handheld.describe`); the
    crop box or None; the indices (as given) of the frames left out; seconds decoding and
    estimating."""

    shifts: List[tuple]
    crop: Optional[tuple]
    alignment: List[dict]
    left_out: List[int]
    decode_seconds: float = 0.0
    align_seconds: float = 0.0


def aligned_source(inputs, options, find=None):
    """``(source, record)`` of an aligned merge of ``inputs`` (paths, headers, exposures)
    with ``options`` (``ignore_color``, ``device``, ``crop``, ``align_model``):
    :class:`AlignedSource` over the frames merged (those left out dropped, a finding
    naming each, handed to ``find``) and its :class:`AlignRecord`."""
    from hdrcl.core.sampling import grid_stride
    from hdrcl.io.reader import BracketReader

    reader = BracketReader(inputs.paths, inputs.infos)
    try:
        reader.read_grid(grid_stride(reader.height, reader.width), keep=True)  # decoded once, kept
        t = time.perf_counter()
        src = AlignedSource(reader, options.ignore_color, options.device)
        rec = src.fit(inputs.times, options.crop, options.align_model, inputs.paths, find)
        rec.decode_seconds, rec.align_seconds = reader.decode_seconds, time.perf_counter() - t
        return src, rec
    except BaseException:
        reader.close()
        raise


class _Frames:
    """Whole frames read from the cache in a given order (the estimate's input), the
    border fill of each found on the way (:func:`hdrcl.core.align.warp.border_fill`)."""

    def __init__(self, src: "AlignedSource", index: List[int]):
        self.src, self.index = src, index

    def __len__(self):
        return len(self.index)

    def __getitem__(self, j: int):
        if not -len(self.index) <= j < len(self.index):
            raise IndexError(j)
        return self.src.whole(self.index[j])

    def __iter__(self):
        return (self[j] for j in range(len(self)))


class AlignedSource:
    """The frames of an aligned merge as strips, each warped as the fusion asks for it
    (module docstring). Made by :func:`aligned_source`; :meth:`close` closes the reader
    that owns the decoded frames."""

    def __init__(self, reader, ignore_color=None, device=None):
        self.reader, self.cache = reader, reader.cache
        self.ignore, self.device = ignore_color, device
        self.full_h, self.full_w = reader.height, reader.width
        self.nch, self.dtype = reader.nch, np.dtype(reader.dtype)
        self.decode_seconds = 0.0  # decoded before the fusion (the record says how long)
        self.warp_seconds = 0.0
        self._fill: dict = {}
        self.keep: List[int] = list(range(self.cache.nframes))
        self.matrices = [np.eye(3)] * len(self.keep)
        self.box = (0, self.full_h, 0, self.full_w)
        self.warper = None

    # ----------------------------------------------------------------- estimate
    def whole(self, i: int) -> np.ndarray:
        """Frame ``i`` (as given) whole, as decoded; its border fill noted."""
        f = self.cache.frame_rows(i, 0, self.full_h)[0]
        if i not in self._fill:
            self._fill[i] = _Packed.of(W.border_fill(f))
        return f

    def _mask(self, codes, alpha):
        """The valid mask of decoded ``codes`` with their ``alpha``: the ignore colour
        left out; None where every pixel is valid by construction."""
        if self.ignore is None:
            return None if alpha is None else np.asarray(alpha, bool)
        from hdrcl.io.reader import ignore_color_mask

        m = ~ignore_color_mask(codes, self.ignore)
        return m if alpha is None else alpha & m

    def fit(self, times, crop: bool, model: str, paths, find=None) -> AlignRecord:
        """Estimate every frame's transform (as :func:`hdrcl.core.align.handheld.align_bracket`
        does, checks and findings included) and keep those of the frames merged."""
        from hdrcl.core.align import handheld as HH

        model = HH.check_model(model)
        n, h, w = self.cache.nframes, self.full_h, self.full_w
        names = [os.path.basename(os.fspath(p)) for p in paths]
        order = [int(i) for i in np.argsort(np.asarray(times, np.float64), kind="stable")]
        ref = n // 2
        if min(h, w) < HH.MIN_SIDE:  # nothing to register on: merged as they are, said once
            logger.warning("%s: frames of %dx%d pixels are too small to align (under %d on a side); they are "
                           "merged as they are", names[order[0]], w, h, HH.MIN_SIDE)
            ref_i = order[ref]
            records = [HH.describe(names[i], "reference" if i == ref_i else "none", np.eye(3), 0.0, h, w,
                                   names[ref_i]) for i in range(n)]
            if crop:
                self.box = (0, h, 0, w)
            return AlignRecord([(0, 0)] * n, (0, h, 0, w) if crop else None, records, [])
        alpha = [self.cache.frame_rows(i, 0, h)[1] for i in range(n)]
        valid = [self._mask(self.whole(i), a) if self.ignore is not None else self._mask(None, a) for i, a in
                 enumerate(alpha)]
        del alpha
        events: list = []
        fits, aligner = HH.estimate(_Frames(self, order), ref, model, self.device, [names[i] for i in order],
                                    [valid[i] for i in order], events=events, leave_out=find is not None)
        del valid
        _trim()  # the estimate's pyramids, freed: given back before the fusion's buffers
        st = HH.settle(fits, order, names, events, find, h, w, crop)
        self.keep, self.matrices = st.keep, st.matrices
        if st.crop is not None:
            self.box = st.crop
        from hdrcl.core.align.warping import _warper

        if _warper(aligner) is not None:  # a processor of its own: its buffers serve this source alone
            from hdrcl.cl.warp import WarpProcessor

            self.warper = WarpProcessor(ctx=aligner.ctx)
        return AlignRecord(st.shifts, st.crop, st.alignment, st.left)

    # ----------------------------------------------------------------- the source
    @property
    def height(self) -> int:
        return self.box[1] - self.box[0]

    @property
    def width(self) -> int:
        return self.box[3] - self.box[2]

    @property
    def frames(self) -> List["WarpedView"]:
        return [WarpedView(self, k, 0) for k in range(len(self.keep))]

    @property
    def valid(self) -> list:
        """Per frame merged: a view of its valid mask, or None where every pixel is valid
        (a frame left where it is, with no alpha and no ignore colour)."""
        return [None if (self._kind(k) == "same" and self.ignore is None
                         and self.cache.frame_rows(self.keep[k], 0, 1)[1] is None)
                else WarpedView(self, k, 1) for k in range(len(self.keep))]

    def _kind(self, k: int) -> str:
        m = self.matrices[k]
        if W.is_integer_shift(m):
            return "same" if int(round(m[0, 2])) == 0 and int(round(m[1, 2])) == 0 else "shift"
        return "warp"

    def region(self, k: int, ys: range, xs: range):
        """``(codes, valid or None)`` of frame ``k`` (merged) at the output rows ``ys`` and
        columns ``xs`` (ranges of the cropped image, one step for both when both have
        more than one element), in pieces of about :data:`CHUNK_PIXELS` source pixels
        (a sampling grid reads the frame a band at a time, not whole)."""
        step = ys.step if len(ys) > 1 else 1
        per = max(1, CHUNK_PIXELS // max(1, step * self.full_w))
        if len(ys) <= per:
            return self._region(k, ys, xs)
        got = [self._region(k, ys[j:j + per], xs) for j in range(0, len(ys), per)]
        valid = None if got[0][1] is None else np.concatenate([g[1] for g in got])
        return np.concatenate([g[0] for g in got]), valid

    def _region(self, k: int, ys: range, xs: range):
        i, m, kind = self.keep[k], self.matrices[k], self._kind(k)
        oy, ox = self.box[0], self.box[2]
        if len(ys) == 0 or len(xs) == 0:
            return (np.empty((len(ys), len(xs), self.nch), self.dtype), np.empty((len(ys), len(xs)), bool))
        fy0, fy1 = oy + ys[0], oy + ys[-1]  # frame coordinates, inclusive
        fx0, fx1 = ox + xs[0], ox + xs[-1]
        sy, sx = ys.step if len(ys) > 1 else 1, xs.step if len(xs) > 1 else 1
        if kind == "same":
            codes, alpha = self.cache.frame_rows(i, fy0, fy1 + 1)
            codes = codes[::sy, fx0:fx1 + 1:sx]
            alpha = None if alpha is None else alpha[::sy, fx0:fx1 + 1:sx]
            return codes, self._mask(codes, alpha)
        h, w = self.full_h, self.full_w
        if i not in self._fill:
            self.whole(i)
        fill = self._fill[i]
        if kind == "shift":
            dx, dy = int(round(m[0, 2])), int(round(m[1, 2]))
            return self._shifted(i, fill, np.arange(fy0, fy1 + 1, sy) + dy, np.arange(fx0, fx1 + 1, sx) + dx)
        b0, b1 = W.region_band(m, fy0, fy1, fx0, fx1, h, w)
        band, alpha = self.cache.frame_rows(i, b0, b1)
        vband = self._mask(band, alpha)
        if fill is not None:
            vband = ~fill.rows(b0, b1) if vband is None else vband & ~fill.rows(b0, b1)
        from hdrcl.core.align.warping import WARP_TAPS

        clip_hi = W.clip_high(int(np.iinfo(self.dtype).max))
        if self.warper is not None and (sy == sx or len(ys) == 1 or len(xs) == 1):
            step = sy if len(ys) > 1 else sx
            codes, ok, _ = self.warper.warp_grid(band, b0, h, m, fy0, len(ys), fx0, len(xs), step, vband,
                                                 taps=WARP_TAPS, clip_hi=clip_hi)
        else:
            codes, ok, _ = W.warp_grid(band, b0, h, m, np.arange(fy0, fy1 + 1, sy), np.arange(fx0, fx1 + 1, sx),
                                       vband, taps=WARP_TAPS, clip_hi=clip_hi)
        return codes, ok

    def _shifted(self, i: int, fill, ys: np.ndarray, xs: np.ndarray):
        """A whole-pixel shift: the source rows ``ys`` and columns ``xs`` copied, code 0
        and not valid outside the frame (:func:`hdrcl.core.align.mtb._shift`)."""
        h, w = self.full_h, self.full_w
        codes = np.zeros((len(ys), len(xs), self.nch), self.dtype)
        ok = np.zeros((len(ys), len(xs)), bool)
        ry, rx = (ys >= 0) & (ys < h), (xs >= 0) & (xs < w)
        if ry.any() and rx.any():
            y0, y1 = int(ys[ry][0]), int(ys[ry][-1]) + 1
            band, alpha = self.cache.frame_rows(i, y0, y1)
            cy, cx = ys[ry] - y0, xs[rx]
            got = band[cy][:, cx]
            codes[np.ix_(ry, rx)] = got
            v = self._mask(got, None if alpha is None else alpha[cy][:, cx])
            if fill is not None:
                out = ~fill.rows(y0, y1)[cy][:, cx]
                v = out if v is None else v & out
            ok[np.ix_(ry, rx)] = True if v is None else v
        return codes, ok

    def _chunk(self, y0: int, y1: int):
        t = time.perf_counter()
        ys, xs = range(y0, y1), range(0, self.width)
        got = [self.region(k, ys, xs) for k in range(len(self.keep))]
        self.warp_seconds += time.perf_counter() - t
        return [np.ascontiguousarray(g[0]) for g in got], [g[1] for g in got]

    def strips(self, rows: int):
        """Yield ``(y0, y1, frames, valid)`` top to bottom (frames merged, input order),
        warping the next chunk of rows on a worker thread while this one is used."""
        from concurrent.futures import ThreadPoolExecutor

        rows = max(1, int(rows))
        chunk = rows * max(1, CHUNK_PIXELS // max(1, rows * self.width))
        starts = list(range(0, self.height, chunk))
        pool = ThreadPoolExecutor(1, thread_name_prefix="hdrcl-warp")
        try:
            ahead = pool.submit(self._chunk, 0, min(self.height, chunk)) if starts else None
            for n, c0 in enumerate(starts):
                c1 = min(self.height, c0 + chunk)
                frames, valid = ahead.result()
                ahead = pool.submit(self._chunk, starts[n + 1], min(self.height, starts[n + 1] + chunk)) \
                    if n + 1 < len(starts) else None
                for y0 in range(c0, c1, rows):
                    y1 = min(c1, y0 + rows)
                    yield (y0, y1, [f[y0 - c0:y1 - c0] for f in frames],
                           [None if v is None else v[y0 - c0:y1 - c0] for v in valid])
        finally:
            pool.shutdown(wait=True, cancel_futures=True)

    def kept(self):
        """``(frames, valid, False)``: every frame merged warped whole (and cropped), for a
        caller that keeps the frames (``keep_frames``: the quality report)."""
        got = [self.region(k, range(self.height), range(self.width)) for k in range(len(self.keep))]
        return [np.ascontiguousarray(g[0]) for g in got], [g[1] for g in got], False

    def rewind(self) -> None:
        """Nothing to do: every pass reads the kept frames from the top."""

    def read_grid(self, stride: int, keep: bool = False):
        """Every ``stride``-th row and column of every frame merged, warped: ``(frames, valid)``."""
        got = [self.region(k, range(0, self.height, stride), range(0, self.width, stride))
               for k in range(len(self.keep))]
        return [g[0] for g in got], [g[1] for g in got]

    def close(self) -> None:
        """Close the files. The decoded frames stay while this source (or a view of it)
        is referenced: a caller may read the frames as merged after the merge (a batch's
        quality report); the cache's memory or scratch file goes with the last reference."""
        self.reader.cache = None  # not closed with the reader
        self.reader.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class _Packed:
    """A frame's border fill mask kept 8 pixels a byte (a dark exposure's is a whole
    frame of booleans: 12 MB at 12 MP), its rows unpacked as a band needs them."""

    def __init__(self, bits: np.ndarray, width: int):
        self.bits, self.width = bits, width

    @classmethod
    def of(cls, mask: Optional[np.ndarray]) -> Optional["_Packed"]:
        return None if mask is None else cls(np.packbits(mask, axis=1), mask.shape[1])

    def rows(self, y0: int, y1: int) -> np.ndarray:
        return np.unpackbits(self.bits[y0:y1], axis=1, count=self.width).view(bool)


def _trim() -> None:
    """Hand the heap's free pages back to the system (glibc): the estimate frees some
    hundred megabytes of small-to-middling arrays (rank pyramids of every frame) that the
    allocator would otherwise keep, and the fusion's peak would sit on top of them."""
    try:
        import ctypes

        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):  # not glibc: nothing to do
        pass


class WarpedView(np.lib.mixins.NDArrayOperatorsMixin):
    """Frame ``k`` of an :class:`AlignedSource` (``part`` 0: codes, 1: valid mask) as an
    array that warps only what is sliced out of it (module docstring); any other use
    (arithmetic, comparisons, methods: a quality report's measures) warps it whole, once."""

    def __init__(self, src: AlignedSource, k: int, part: int):
        self.src, self.k, self.part = src, k, part
        self._whole = None
        self.shape = (src.height, src.width, src.nch) if part == 0 else (src.height, src.width)
        self.dtype = src.dtype if part == 0 else np.dtype(bool)
        self.ndim = len(self.shape)

    def __getitem__(self, key):
        key = key if isinstance(key, tuple) else (key,)
        if len(key) <= 2 and all(isinstance(s, slice) for s in key):
            ys = range(*key[0].indices(self.shape[0]))
            xs = range(*key[1].indices(self.shape[1])) if len(key) == 2 else range(self.shape[1])
            if (len(ys) <= 1 or len(xs) <= 1 or ys.step == xs.step) and ys.step > 0 and xs.step > 0:
                got = self.src.region(self.k, ys, xs)[self.part]
                if got is None:  # a mask with every pixel valid
                    got = np.ones((len(ys), len(xs)), bool)
                return got
        return np.asarray(self)[key]

    def __array__(self, dtype=None, copy=None):
        if self._whole is None:
            self._whole = np.ascontiguousarray(self[:, :])
        if dtype is not None and np.dtype(dtype) != self._whole.dtype:
            return self._whole.astype(dtype)
        return self._whole.copy() if copy else self._whole  # np.array(view): a copy of its own

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        inputs = tuple(np.asarray(x) if isinstance(x, WarpedView) else x for x in inputs)
        return getattr(ufunc, method)(*inputs, **kwargs)

    def __getattr__(self, name):  # ndarray's methods and attributes, on the whole frame
        if name.startswith("__") or name in ("src", "k", "part", "_whole"):
            raise AttributeError(name)
        return getattr(np.asarray(self), name)

    def __len__(self):
        return self.shape[0]
