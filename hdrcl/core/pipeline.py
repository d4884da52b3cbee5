"""Streaming merge: decode, fuse and write a bracket strip by strip.

Memory stays bounded by the strip height whatever the image size. Three things overlap:
the frames' next strip is decoded on helper threads (:class:`hdrcl.io.reader.BracketReader`),
the current strip is fused on the OpenCL device (or by the NumPy twin), and the previous
strip is encoded by a writer thread (:class:`hdrcl.io.writers.RadianceWriter`).
"""
from __future__ import annotations

import concurrent.futures
import logging
import time
from collections import deque
from typing import Optional, Sequence

import numpy as np

from hdrcl.cl.backend import get_processor
from hdrcl.core import reference
from hdrcl.core.fusion import fusion_tables
from hdrcl.core.response import Response

logger = logging.getLogger(__name__)

#: Rows per strip on the NumPy path (the OpenCL path takes its processor's strip size).
NUMPY_STRIP_PIXELS = 1 << 18


class ArraySource:
    """In-memory frames presented as strips (same protocol as BracketReader)."""

    def __init__(self, frames: Sequence[np.ndarray], valid: Sequence[Optional[np.ndarray]]):
        self.frames = list(frames)
        self.valid = list(valid)
        self.height, self.width, self.nch = self.frames[0].shape
        self.dtype = self.frames[0].dtype

    def strips(self, rows: int):
        for y0 in range(0, self.height, rows):
            y1 = min(self.height, y0 + rows)
            yield (y0, y1, [f[y0:y1] for f in self.frames],
                   [None if v is None else v[y0:y1] for v in self.valid])


class ArraySink:
    """Collects strips into one float32 array (for the Python API)."""

    def __init__(self, height: int, width: int, nch: int):
        self.array = np.empty((height, width, nch), np.float32)

    def write_rows(self, y0: int, y1: int, data: np.ndarray) -> None:
        self.array[y0:y1] = data


class Thumbnail:
    """Keeps every ``stride``-th pixel of the radiance for previews."""

    def __init__(self, height: int, width: int, nch: int, long_side: int):
        self.stride = max(1, int(np.ceil(max(height, width) / max(long_side, 1))))
        self.array = np.empty((len(range(0, height, self.stride)), len(range(0, width, self.stride)), nch),
                              np.float32)

    def add(self, y0: int, y1: int, data: np.ndarray) -> None:
        first = (-y0) % self.stride
        rows = data[first::self.stride, ::self.stride]
        g0 = (y0 + first) // self.stride
        self.array[g0:g0 + rows.shape[0]] = rows


def strip_rows(width: int, device: Optional[str] = None, work: Optional[int] = None) -> int:
    """Rows per strip :func:`stream_merge` uses for frames ``width`` pixels wide (``work``:
    the job's pixel-samples, see :func:`hdrcl.cl.backend.get_processor`)."""
    proc = get_processor("fusion", device, work=work)
    if proc is not None:
        return proc.strip_rows(width)
    return max(1, NUMPY_STRIP_PIXELS // max(width, 1))


def _learn_ghosts(source, order, log_t, tables, wts, ignore_color, threshold):
    """The set's residual distribution (:func:`hdrcl.core.deghost.learn`) from the frames
    of an in-memory source, or from a decimated grid of a streamed one (one extra
    decoding pass)."""
    from hdrcl.core import deghost as dg
    from hdrcl.io.reader import ignore_color_mask

    if hasattr(source, "frames"):
        frames, valid = source.frames, source.valid
    else:
        from hdrcl.core.sampling import grid_stride

        frames, valid = source.read_grid(grid_stride(source.height, source.width))
    if ignore_color is not None:
        valid = [(~ignore_color_mask(f, ignore_color)) if v is None else (v & ~ignore_color_mask(f, ignore_color))
                 for f, v in zip(frames, valid)]
    vs = [valid[i] for i in order]
    return dg.learn([frames[i] for i in order], log_t, tables, wts,
                    vs if any(v is not None for v in vs) else None, threshold)


def stream_merge(
    source,
    times: Sequence[float],
    response: Response,
    sink,
    *,
    weight: str = "hat",
    ignore_color=None,
    has_valid: Optional[bool] = None,
    device: Optional[str] = None,
    thumbnail: Optional[Thumbnail] = None,
    deghost: bool = False,
    ghost_mask: Optional[np.ndarray] = None,
    ghost_model=None,
    ghost_reference=None,
    ghost_threshold: Optional[float] = None,
    exposure_check=None,
    seconds: Optional[dict] = None,
    work: Optional[int] = None,
    clip_mask: Optional[np.ndarray] = None,
):
    """Fuse every strip of ``source`` and hand it to ``sink.write_rows``.

    Parameters
    ----------
    source
        :class:`hdrcl.io.reader.BracketReader` or :class:`ArraySource`: ``height``, ``width``,
        ``nch``, ``dtype`` and ``strips(rows)`` yielding ``(y0, y1, frames, valid)``.
    times : sequence of float
        Exposure of each source frame (seconds), in source order.
    response : Response
    sink
        Anything with ``write_rows(y0, y1, float32 array)``; called from one writer
        thread, strips in order.
    ignore_color : (R, G, B), optional
        8-bit colour marking invalid pixels.
    has_valid : bool, optional
        Whether any frame can have invalid pixels (alpha or ignore colour); computed
        from the first strip when None.
    deghost : bool
        Replace pixels where the frames disagree beyond the set's learnt residuals
        (:mod:`hdrcl.core.deghost`) by the reference exposure's own estimate; ``counts`` then
        also holds ``ghost`` and ``ghost_unresolved`` (pixels). ``ghost_mask`` (H, W)
        bool receives the mask.
    ghost_model : hdrcl.deghost.GhostModel, optional
        The set's residual distribution (frames in exposure order); learnt from
        ``source.frames`` when None (in-memory sources), required otherwise.
    ghost_reference, ghost_threshold
        See :func:`hdrcl.core.deghost.reference_index` and :func:`hdrcl.core.deghost.learn`.
    exposure_check : hdrcl.core.exposure_fit.ExposureCheck, optional
        Given every strip (frames in exposure order) to measure the exposure ratios.
    clip_mask : numpy.ndarray, optional
        ``(H, W)`` uint8, C-contiguous: receives each pixel's clip flags (1: a channel
        clipped high in every frame, 2: clipped low; :func:`hdrcl.core.reference.fuse`).
    work : int, optional
        The job's pixel-samples (pixels x frames): a small job takes the NumPy path
        rather than paying for OpenCL's start-up (:func:`hdrcl.cl.backend.get_processor`).
    seconds : dict, optional
        Receives the time spent (added to what it holds): ``fuse`` (the kernel or its
        twin), ``encode`` (the sink, on the writer thread) and, for a decoding source,
        ``decode`` (summed over its decoder threads).

    Returns
    -------
    counts : dict
        As :func:`hdrcl.core.reference.fuse`.
    backend : str
        ``"opencl"`` or ``"numpy"``.
    """
    from hdrcl.io.reader import ignore_color_mask

    order = np.argsort(np.asarray(times, np.float64), kind="stable")
    log_t = np.log(np.asarray(times, np.float64)[order])
    nch = source.nch
    tables, wts = fusion_tables(response, source.dtype, nch, weight)
    proc = get_processor("fusion", device, work=work)
    if has_valid is None:
        has_valid = ignore_color is not None or any(
            v is not None for v in getattr(source, "valid", [None]))
    plan = None
    if proc is not None:
        plan = proc.plan(len(order), source.width, nch, source.dtype, log_t, tables, wts, has_valid)
        rows = plan.rows
    else:
        rows = strip_rows(source.width, device, work=work)
    counts = {"clipped_high": 0, "clipped_low": 0, "no_data": 0}
    ghosts = {"ghost": 0, "ghost_unresolved": 0}
    if deghost:
        from hdrcl.core import deghost as dg

        ref = dg.reference_index(times, ghost_reference)
        if ghost_model is None:
            ghost_model = _learn_ghosts(source, order, log_t, tables, wts, ignore_color, ghost_threshold)
    # Output strips: one being fused, one held back (deghost: its mask's growth into the
    # next strip is not known yet), two being written or queued.
    buffers = deque(np.empty((rows, source.width, nch), np.float32) for _ in range(4))
    pending: deque = deque()
    held = None  # deghost: (y0, y1, frames, valid, out) awaiting the next strip's rows
    tail = None  # deghost: last CONTEXT rows (frames, valid, unreplaced fused) of the strip before ``held``

    timing = {"fuse": 0.0, "encode": 0.0}
    decoded0 = getattr(source, "decode_seconds", 0.0)

    def write(y0, y1, out):
        t = time.perf_counter()
        sink.write_rows(y0, y1, out)
        timing["encode"] += time.perf_counter() - t

    def emit(y0, y1, out):
        if thumbnail is not None:
            thumbnail.add(y0, y1, out)
        pending.append(writer.submit(write, y0, y1, out))

    def rows_of(frames, vv, out, sl):
        return ([f[sl].copy() for f in frames],
                None if vv is None else [None if v is None else v[sl].copy() for v in vv],
                out[sl].copy())

    def finish_ghosts(item, below):
        y0, y1, frames, vv, out = item
        mask = dg.find(frames, log_t, tables, vv, out, ghost_model, above=tail, below=below)
        new_tail = rows_of(frames, vv, out, slice(-dg.CONTEXT, None))
        ghosts["ghost_unresolved"] += dg.replace(out, frames, log_t, tables, mask, vv, ref)
        ghosts["ghost"] += int(np.count_nonzero(mask))
        if ghost_mask is not None:
            ghost_mask[y0:y1] = mask
        emit(y0, y1, out)
        return new_tail

    with concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="hdrcl-write") as writer:
        for y0, y1, frames, valid in source.strips(rows):
            frames = [frames[i] for i in order]
            valid = [valid[i] for i in order]
            if ignore_color is not None:
                valid = [(~ignore_color_mask(f, ignore_color)) if v is None else (v & ~ignore_color_mask(f, ignore_color))
                         for f, v in zip(frames, valid)]
            if exposure_check is not None:
                exposure_check.add(frames, valid if has_valid else None)
            while len(pending) >= len(buffers) - 2:
                pending.popleft().result()  # bounded memory; also re-raises write errors
            buf = buffers[0]
            buffers.rotate(-1)
            out = buf[: y1 - y0]
            tf = time.perf_counter()
            cm = None if clip_mask is None else clip_mask[y0:y1]
            if plan is not None:
                plan.fuse_strip(frames, valid if has_valid else None, out, clip_mask=cm)
            else:
                rad, c = reference.fuse(frames, log_t, tables, wts, valid, clip_mask=cm)
                out[...] = rad
                for k in counts:
                    counts[k] += c[k]
            timing["fuse"] += time.perf_counter() - tf
            if deghost:
                vv = valid if has_valid else None
                if held is not None:
                    tail = finish_ghosts(held, rows_of(frames, vv, out, slice(0, dg.CONTEXT)))
                held = (y0, y1, frames, vv, out)
            else:
                emit(y0, y1, out)
        if held is not None:
            finish_ghosts(held, None)
        for fut in pending:
            fut.result()
    if plan is not None:
        counts = plan.result_counts()
    if seconds is not None:
        for k, v in timing.items():
            seconds[k] = seconds.get(k, 0.0) + v
        decoded = getattr(source, "decode_seconds", 0.0) - decoded0
        if decoded:
            seconds["decode"] = seconds.get("decode", 0.0) + decoded
    if deghost:
        counts.update(ghosts)
    return counts, ("opencl" if plan is not None else "numpy")
