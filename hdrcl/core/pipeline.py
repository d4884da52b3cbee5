"""Streaming merge: decode, fuse and write a bracket strip by strip.

Memory stays bounded by the strip height whatever the image size. Three things overlap:
the frames' next strip is decoded on helper threads (:class:`hdrcl.io.reader.BracketReader`),
the current strip is fused on the OpenCL device (or by the NumPy twin), and the previous
strip is encoded by a writer thread (:class:`hdrcl.io.writers.RadianceWriter`).
"""
from __future__ import annotations

import concurrent.futures
import logging
import os
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

from hdrcl.core import reference
from hdrcl.core.weights import weight_table
from hdrcl.core.response import Response

logger = logging.getLogger(__name__)

#: Rows per strip on the NumPy path (the OpenCL path takes its processor's strip size).
NUMPY_STRIP_PIXELS = 1 << 18


def fusion_tables(response: Response, dtype, nch: int, weight: str = "hat"):
    """``g`` per channel at every code, shape (C, L), and the weights (L,) for frames of
    ``dtype`` with ``nch`` channels; UsageError when the response's depth differs."""
    tables = response.table_for(nch)
    levels = tables.shape[1]
    if int(np.iinfo(dtype).max) + 1 != levels:
        from hdrcl.errors import UsageError

        raise UsageError(
            f"the response describes {response.bits}-bit images but the frames are "
            f"{8 * np.dtype(dtype).itemsize}-bit"
        )
    return tables, weight_table(levels, weight)


def fusion_processor(device: Optional[str] = None, work: Optional[int] = None):
    """The fusion backend of a job of ``work`` pixel-samples (pixels x frames): the OpenCL
    processor, or None for the NumPy twin.

    A job under :func:`hdrcl.cl.backend.small_work` takes the NumPy path unless a device
    was named (``device`` or ``PYOPENCL_CTX``) or ``HDRCL_REQUIRE_OPENCL`` is set; every
    other job takes OpenCL when a device can be opened. Whether OpenCL is already open in
    this process does not count: the answer depends on the job alone.
    """
    from hdrcl.cl.backend import get_processor, opencl_enabled, opencl_required, small_work

    if (work is not None and opencl_enabled() and device is None and not os.environ.get("PYOPENCL_CTX")
            and not opencl_required() and int(work) < small_work()):
        return None
    return get_processor("fusion", device)


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
    the job's pixel-samples, see :func:`fusion_processor`)."""
    proc = fusion_processor(device, work)
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


@dataclass
class FusionSpec:
    """How :func:`stream_merge` fuses: everything but the source, the exposures, the response
    and the sink (see :func:`stream_merge` for each field).

    ``processor`` is the job's backend, decided once by its caller
    (:func:`fusion_processor`): an OpenCL fusion processor, or None for
    the NumPy twin. Left unset (the default ``...``), it is decided here from ``device``
    and ``work`` by the same rule.
    """

    weight: str = "hat"
    ignore_color: Any = None
    has_valid: Optional[bool] = None
    device: Optional[str] = None
    thumbnail: Optional[Thumbnail] = None
    deghost: bool = False
    ghost_mask: Optional[np.ndarray] = None
    ghost_model: Any = None
    ghost_reference: Any = None
    ghost_threshold: Optional[float] = None
    exposure_check: Any = None
    seconds: Optional[dict] = None
    work: Optional[int] = None
    clip_mask: Optional[np.ndarray] = None
    processor: Any = ...


def stream_merge(source, times: Sequence[float], response: Response, sink, spec: Optional[FusionSpec] = None,
                 **options):
    """Fuse every strip of ``source`` and hand it to ``sink.write_rows``.

    ``options`` are :class:`FusionSpec`'s fields (or give ``spec``):

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
    exposure_check : hdrcl.core.exposure.fit.ExposureCheck, optional
        Given every strip (frames in exposure order) to measure the exposure ratios.
    clip_mask : numpy.ndarray, optional
        ``(H, W)`` uint8, C-contiguous: receives each pixel's clip flags (1: a channel
        clipped high in every frame, 2: clipped low; :func:`hdrcl.core.reference.fuse`).
    work : int, optional
        The job's pixel-samples (pixels x frames): with ``processor`` unset, a small job
        takes the NumPy path (:func:`fusion_processor`).
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
    spec = spec if spec is not None else FusionSpec(**options)
    return _StripFusion(source, times, response, sink, spec).run()


class _StripFusion:
    """One :func:`stream_merge`: the strips fused in exposure order, written by one
    writer thread (bounded buffers), deghosted with one strip of look-ahead."""

    def __init__(self, source, times, response, sink, spec: FusionSpec):
        self.source, self.sink, self.spec = source, sink, spec
        self.times = times
        self.order = np.argsort(np.asarray(times, np.float64), kind="stable")
        self.log_t = np.log(np.asarray(times, np.float64)[self.order])
        self.tables, self.wts = fusion_tables(response, source.dtype, source.nch, spec.weight)
        if spec.processor is ...:
            self.proc = fusion_processor(spec.device, spec.work)
        else:
            self.proc = spec.processor
        self.has_valid = spec.has_valid
        if self.has_valid is None:
            self.has_valid = spec.ignore_color is not None or any(
                v is not None for v in getattr(source, "valid", [None]))
        self.plan = None
        if self.proc is not None:
            self.plan = self.proc.plan(len(self.order), source.width, source.nch, source.dtype, self.log_t,
                                       self.tables, self.wts, self.has_valid)
            self.rows = self.plan.rows
        else:
            self.rows = max(1, NUMPY_STRIP_PIXELS // max(source.width, 1))
        self.counts = {"clipped_high": 0, "clipped_low": 0, "no_data": 0}
        self.ghosts = {"ghost": 0, "ghost_unresolved": 0}
        self.timing = {"fuse": 0.0, "encode": 0.0}
        self.pending: deque = deque()
        self.tail = None  # deghost: last CONTEXT rows (frames, valid, unreplaced fused) of the strip before ``held``
        if spec.deghost:
            from hdrcl.core import deghost as dg

            self.ref = dg.reference_index(times, spec.ghost_reference)
            self.ghost_model = spec.ghost_model
            if self.ghost_model is None:
                self.ghost_model = _learn_ghosts(source, self.order, self.log_t, self.tables, self.wts,
                                                 spec.ignore_color, spec.ghost_threshold)

    def _write(self, y0, y1, out):
        t = time.perf_counter()
        self.sink.write_rows(y0, y1, out)
        self.timing["encode"] += time.perf_counter() - t

    def _emit(self, y0, y1, out):
        if self.spec.thumbnail is not None:
            self.spec.thumbnail.add(y0, y1, out)
        self.pending.append(self.writer.submit(self._write, y0, y1, out))

    @staticmethod
    def _rows_of(frames, vv, out, sl):
        return ([f[sl].copy() for f in frames],
                None if vv is None else [None if v is None else v[sl].copy() for v in vv],
                out[sl].copy())

    def _finish_ghosts(self, item, below):
        from hdrcl.core import deghost as dg

        y0, y1, frames, vv, out = item
        mask = dg.find(frames, self.log_t, self.tables, vv, out, self.ghost_model, above=self.tail, below=below,
                       processor=self.proc)
        new_tail = self._rows_of(frames, vv, out, slice(-dg.CONTEXT, None))
        self.ghosts["ghost_unresolved"] += dg.replace(out, frames, self.log_t, self.tables, mask, vv, self.ref,
                                                     self.ghost_model)
        self.ghosts["ghost"] += int(np.count_nonzero(mask))
        if self.spec.ghost_mask is not None:
            self.spec.ghost_mask[y0:y1] = mask
        self._emit(y0, y1, out)
        return new_tail

    def _fuse(self, y0, y1, frames, valid, out) -> list:
        """Fuse a strip, or queue it on the device; returns the strips finished by then,
        in order, as ``(y0, y1, frames, valid, out)``."""
        tf = time.perf_counter()
        cm = None if self.spec.clip_mask is None else self.spec.clip_mask[y0:y1]
        item = (y0, y1, frames, valid, out)
        if self.pipe is not None:
            done = self.pipe.put(frames, valid if self.has_valid else None, out, cm, tag=item)
        else:
            rad, c = reference.fuse(frames, self.log_t, self.tables, self.wts, valid, clip_mask=cm)
            out[...] = rad
            for k in self.counts:
                self.counts[k] += c[k]
            done = [item]
        self.timing["fuse"] += time.perf_counter() - tf
        return done

    def _drain(self) -> list:
        """The strips still on the device, waited for."""
        if self.pipe is None:
            return []
        tf = time.perf_counter()
        done = self.pipe.drain()
        self.timing["fuse"] += time.perf_counter() - tf
        return done

    def _strips(self):
        """The source's strips, frames in exposure order, the ignore colour masked."""
        from hdrcl.io.reader import ignore_color_mask

        rgb = self.spec.ignore_color
        for y0, y1, frames, valid in self.source.strips(self.rows):
            frames = [frames[i] for i in self.order]
            valid = [valid[i] for i in self.order]
            if rgb is not None:
                valid = [(~ignore_color_mask(f, rgb)) if v is None else (v & ~ignore_color_mask(f, rgb))
                         for f, v in zip(frames, valid)]
            if self.spec.exposure_check is not None:
                self.spec.exposure_check.add(frames, valid if self.has_valid else None)
            yield y0, y1, frames, valid

    def _fused(self, y0, y1, frames, valid, out) -> None:
        """A strip fused (in order): deghosted once the next one is known, then written."""
        from hdrcl.core import deghost as dg

        if not self.spec.deghost:
            self._emit(y0, y1, out)
            return
        vv = valid if self.has_valid else None
        if self.held is not None:
            self.tail = self._finish_ghosts(self.held, self._rows_of(frames, vv, out, slice(0, dg.CONTEXT)))
        self.held = (y0, y1, frames, vv, out)

    def run(self):
        source, spec = self.source, self.spec
        # Output strips: up to ``depth`` on the device (the OpenCL pipeline), one held back
        # (deghost: its mask's growth into the next strip is not known yet), one being
        # written and one queued for the writer.
        depth = self.plan.depth if self.plan is not None else 1
        buffers = deque(np.empty((self.rows, source.width, source.nch), np.float32) for _ in range(depth + 3))
        self.held = None  # deghost: (y0, y1, frames, valid, out) awaiting the next strip's rows
        decoded0 = getattr(source, "decode_seconds", 0.0)
        self.pipe = self.plan.pipeline() if self.plan is not None else None
        try:
            with concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="hdrcl-write") as writer:
                self.writer = writer
                for y0, y1, frames, valid in self._strips():
                    while len(self.pending) > len(buffers) - depth - 2:
                        self.pending.popleft().result()  # bounded memory; also re-raises write errors
                    buf = buffers[0]
                    buffers.rotate(-1)
                    for item in self._fuse(y0, y1, frames, valid, buf[: y1 - y0]):
                        self._fused(*item)
                for item in self._drain():
                    self._fused(*item)
                if self.held is not None:
                    self._finish_ghosts(self.held, None)
                for fut in self.pending:
                    fut.result()
        finally:
            if self.pipe is not None:
                self.pipe.close()  # after an error: the device lets go of the host arrays first
        counts = self.plan.result_counts() if self.plan is not None else self.counts
        if spec.seconds is not None:
            for k, v in self.timing.items():
                spec.seconds[k] = spec.seconds.get(k, 0.0) + v
            decoded = getattr(source, "decode_seconds", 0.0) - decoded0
            if decoded:
                spec.seconds["decode"] = spec.seconds.get("decode", 0.0) + decoded
        if spec.deghost:
            counts.update(self.ghosts)
        return counts, ("opencl" if self.plan is not None else "numpy")
