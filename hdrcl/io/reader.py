"""Reading a bracket set's frames together: whole, as the decimated sampling grid, or
strip by strip with the next strip decoded ahead (:class:`BracketReader`).
"""
from __future__ import annotations

import concurrent.futures
import logging
import os
import threading
import time
from typing import Optional, Sequence

import numpy as np

from hdrcl.errors import InputError
from hdrcl.io.frames import (
    _channel_layout,
    _channel_layout_counts,
    _name,
    open_input,
    _read_error,
    check_compatible,
    check_pixel_limit,
    decoder_stderr,
    read_info,
)
from hdrcl.io.metadata import FrameInfo
from hdrcl.io.raw import is_raw

logger = logging.getLogger(__name__)

#: Rows per strip of :meth:`BracketReader.read_grid` (rounded up to the grid's stride):
#: small enough that a strip of one frame stays in cache while its grid is taken.
GRID_STRIP_ROWS = 64


class BracketReader:
    """Decodes the frames of a bracket set strip by strip, all frames in parallel.

    Memory stays bounded by the strip height whatever the image size: each frame's
    file is opened once and read top to bottom with ``read_scanlines``, one thread per
    frame (OpenImageIO releases the GIL while decoding), and :meth:`strips` decodes the
    next strip while the caller works on the current one.

    Parameters
    ----------
    paths : sequence of path
    infos : sequence of FrameInfo, optional
        Headers already read (skips a second header read).
    ahead : bool
        Take the frames a batch decoded ahead for this set (:mod:`hdrcl.io.ahead`), if
        any: they become a complete in-memory :attr:`cache` (frames the helper did not
        reach are decoded now), so the grid and the strips are read from there.

    Raises
    ------
    InputError
        A file cannot be opened, or the frames are incompatible.
    """

    def __init__(self, paths: Sequence, infos: Optional[Sequence[FrameInfo]] = None, ahead: bool = True):
        self.paths = [_name(p) for p in paths]
        raws = [is_raw(p) for p in self.paths]
        if any(raws) and not all(raws):
            odd = self.paths[raws.index(False) if raws[0] else raws.index(True)]
            raise InputError(f"{odd}: a bracket set mixes RAW and non-RAW files")
        self.infos = list(infos) if infos is not None else [read_info(p) for p in self.paths]
        for info in self.infos:
            check_pixel_limit(info)
        check_compatible(self.infos)
        first = self.infos[0]
        self.width, self.height = first.width, first.height
        self.dtype = np.dtype(np.uint8 if first.bits == 8 else np.uint16)
        self._inputs: list = [None] * len(self.paths)
        self._layout: list = [None] * len(self.paths)
        self._raw_wb = None
        self._first = None  # (rows, _Prefetch) started by prefetch()
        self._grid = None  # (stride, frames, valid) of the last read_grid
        self.cache = None  # FrameCache filled by read_grid(keep=True): strips() reads it back
        self.decode_seconds = 0.0  # CPU seconds of decoding, summed over the decoder threads
        self._time_lock = threading.Lock()
        if any(raws):
            from hdrcl.io.raw import camera_white_balance

            # one white balance for every frame: auto WB must not rescale channels per frame
            self._raw_wb = camera_white_balance(self.paths[0])
        self._pool = concurrent.futures.ThreadPoolExecutor(
            max_workers=max(1, min(len(self.paths), (os.cpu_count() or 1) + 1)),
            thread_name_prefix="hdrcl-decode")
        if ahead:
            self._adopt_ahead()

    def _adopt_ahead(self) -> None:
        """Make the frames decoded ahead for this set (if any) the complete cache."""
        from hdrcl.io import ahead
        from hdrcl.io.framecache import FrameCache

        got = ahead.take(self.paths)
        if got is None:
            return
        if isinstance(got, ahead.Held):  # decoded whole by the pooled calibration
            c = got.cache
            if (c.nframes, c.height, c.width, c.nch, c.dtype) != \
                    (len(self.paths), self.height, self.width, self.nch, self.dtype):
                got.close()  # not the frames this reader would decode: decode them itself
                return
            self.cache, got.cache = c, None
            self._grid = got.grid
            self.decode_seconds += got.seconds  # the set's own frames' decoding, wherever it ran
            return
        missing = [k for k, f in enumerate(got.frames) if f is None]
        futs = {k: self._pool.submit(self._read, k, 0, self.height) for k in missing}
        try:
            for k, fut in futs.items():
                got.frames[k], got.valid[k] = fut.result()
        except BaseException:
            self._pool.shutdown(wait=True)
            raise
        cache = FrameCache(len(self.paths), self.height, self.width, self.nch, self.dtype, in_memory=True)
        try:
            for k, (f, v) in enumerate(zip(got.frames, got.valid)):
                cache.adopt(k, f, v)
        except ValueError:  # not the frames this reader would decode: decode them itself
            cache.close()
            return
        cache.finish()
        self.cache = cache
        self.decode_seconds += got.seconds

    def decode_frame(self, k: int):
        """Frame ``k`` whole, decoded on the calling thread: ``(codes, alpha mask or None)``."""
        return self._read(k, 0, self.height)

    @property
    def nch(self) -> int:
        return len(_channel_layout_counts(self.infos[0]))

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        if self._first is not None:  # never close the files under a running decode
            self._first[1].wait()
            self._first = None
        self._pool.shutdown(wait=True)
        if self.cache is not None:
            self.cache.close()
            self.cache = None
        for k, inp in enumerate(self._inputs):
            if inp is not None and hasattr(inp, "close"):
                inp.close()
            self._inputs[k] = None

    def _read(self, k: int, y0: int, y1: int):
        t0 = time.thread_time()  # CPU time of this decoder thread: threads that wait for a
        try:                       # core while others decode do not count
            out = self._decode(k, y0, y1)
        finally:
            with self._time_lock:
                self.decode_seconds += time.thread_time() - t0
        if y1 >= self.height:  # a pass reached the frame's last row
            _count_full_decode(self.paths[k])
        return out

    def _decode(self, k: int, y0: int, y1: int):
        name = self.paths[k]
        if self._raw_wb is not None:
            # LibRaw decodes whole frames: keep the frame while its strips are served
            px = self._inputs[k]
            if px is None:
                from hdrcl.io.raw import read_raw

                px = self._inputs[k] = read_raw(name, white_balance=self._raw_wb).pixels
                if px.shape[:2] != (self.height, self.width):
                    raise InputError(f"{name}: decoded {px.shape[1]}x{px.shape[0]}, header says "
                                     f"{self.width}x{self.height}")
            out = np.ascontiguousarray(px[y0:y1])
            if y1 >= self.height:
                self._inputs[k] = None
            return out, None
        inp = self._inputs[k]
        if inp is None:
            inp = self._inputs[k] = open_input(name)
            self._layout[k] = _channel_layout(inp.spec(), name)
        colour, alpha = self._layout[k]
        spec = inp.spec()
        fmt = "uint8" if self.dtype == np.uint8 else "uint16"
        with decoder_stderr():
            data = inp.read_scanlines(0, 0, y0, y1, 0, 0, spec.nchannels, fmt)
        problem = _read_error(inp, name)
        if problem is None and data is None:
            problem = f"{name}: cannot decode pixel data"
        if problem is not None:
            raise InputError(problem)
        data = np.asarray(data)
        if data.ndim == 2:
            data = data[:, :, None]
        if data.shape != (y1 - y0, self.width, spec.nchannels):
            raise InputError(f"{name}: decoded {data.shape} samples for rows {y0}-{y1}")
        if alpha is None:
            return np.ascontiguousarray(data), None
        return np.ascontiguousarray(data[:, :, colour]), data[:, :, alpha] != 0

    def read_rows(self, y0: int, y1: int):
        """Rows ``y0..y1`` of every frame: ``(frames, valid)`` lists in path order."""
        futs = [self._pool.submit(self._read, k, y0, y1) for k in range(len(self.paths))]
        got = [f.result() for f in futs]  # first failure in path order is raised
        return [g[0] for g in got], [g[1] for g in got]

    def prefetch(self, rows: int) -> None:
        """Start decoding the first strip of ``rows`` rows now, on helper threads, so
        that a later :meth:`strips` with the same ``rows`` finds it ready (a merge
        overlaps it with the response solve). Nothing to do when the frames are cached."""
        if self.cache is not None and self.cache.complete:
            return
        if self._first is None:
            rows = max(1, int(rows))
            self._first = (rows, _Prefetch(self, 0, min(self.height, rows)))

    def strips(self, rows: int):
        """Yield ``(y0, y1, frames, valid)`` top to bottom, decoding one strip ahead."""
        rows = max(1, int(rows))
        if self.cache is not None and self.cache.complete:  # decoded once already (read_grid)
            for y0 in range(0, self.height, rows):
                y1 = min(self.height, y0 + rows)
                yield (y0, y1) + tuple(self.cache.rows(y0, y1))
            return
        starts = list(range(0, self.height, rows))
        ahead = None
        if self._first is not None:
            first_rows, ahead = self._first
            self._first = None
            if first_rows != rows:  # not the strip asked for: drop it, decode afresh
                ahead.wait()
                ahead = None
                self._rewind()
        try:
            for n, y0 in enumerate(starts):
                y1 = min(self.height, y0 + rows)
                current = ahead.result() if ahead is not None else self.read_rows(y0, y1)
                ahead = None
                if n + 1 < len(starts):
                    ny0 = starts[n + 1]
                    ahead = _Prefetch(self, ny0, min(self.height, ny0 + rows))
                yield (y0, y1) + tuple(current)
        finally:
            if ahead is not None:  # never close the files under a running decode
                ahead.wait()

    def rewind(self) -> None:
        """Start the next :meth:`strips` pass from the top (from the cache when there is one)."""
        if self._first is not None:
            self._first[1].wait()
            self._first = None
        self._rewind()

    def _rewind(self) -> None:
        """Close the open files so the next read starts again from the top."""
        for k, inp in enumerate(self._inputs):
            if inp is not None and hasattr(inp, "close"):
                inp.close()
            self._inputs[k] = None

    def read_all(self):
        """Every frame whole: ``(frames, valid)``; memory grows with the image.

        Each frame is decoded in one call on its own thread, straight into the array
        returned (no strip copies). Frames decoded ahead (:attr:`cache` complete, in
        memory) are handed over as they are, and the cache let go.
        """
        if self.cache is not None and self.cache.complete and self.cache.in_memory:
            frames, valid = self.cache.rows(0, self.height)
            self.cache = None  # the caller owns the arrays now (aligning warps them in place)
            return frames, valid
        futs = [self._pool.submit(self._read, k, 0, self.height) for k in range(len(self.paths))]
        got = [f.result() for f in futs]
        return [g[0] for g in got], [g[1] for g in got]

    def read_grid(self, stride: int, keep: bool = False, in_memory: Optional[bool] = None):
        """Every ``stride``-th row and column of every frame, read in one streaming pass
        (once: a second call with the same stride returns the same arrays, not to be
        modified).

        With ``keep``, every decoded strip is also stored in a
        :class:`~hdrcl.io.framecache.FrameCache` (:attr:`cache`), from which a later
        :meth:`strips` pass reads instead of decoding the frames a second time
        (``in_memory``: where it keeps them, :class:`~hdrcl.io.framecache.FrameCache`).

        Each frame is decoded top to bottom in strips of about :data:`GRID_STRIP_ROWS`
        rows on its own thread, which keeps only the grid's rows and columns of each
        strip (while the strip is still in cache): memory is the grid plus one small
        strip per frame, whatever the image size. One thread per frame (not per core)
        lets the frames finish together instead of leaving a core idle at the end.
        """
        stride = max(1, int(stride))
        if self._grid is not None and self._grid[0] == stride:  # read already (calibration)
            return list(self._grid[1]), list(self._grid[2])
        if self.cache is not None and self.cache.complete:  # decoded ahead, or held (a spill file)
            rows = self.height if self.cache.in_memory else stride * max(1, -(-GRID_STRIP_ROWS // stride))
            parts = [self.cache.rows(y0, min(self.height, y0 + rows)) for y0 in range(0, self.height, rows)]
            frames = [np.concatenate([p[0][k][::stride, ::stride] for p in parts]) for k in range(len(self.paths))]
            valid = [None if parts[0][1][k] is None else
                     np.concatenate([p[1][k][::stride, ::stride] for p in parts]) for k in range(len(self.paths))]
            self._grid = (stride, frames, valid)
            return list(frames), list(valid)
        if self._first is not None:  # a strip decoding ahead would share the open files
            self._first[1].wait()
            self._first = None
        self._rewind()
        hh = len(range(0, self.height, stride))
        ww = len(range(0, self.width, stride))
        cache = None
        if keep:
            from hdrcl.io.framecache import FrameCache

            if self.cache is not None:
                self.cache.close()
            cache = self.cache = FrameCache(len(self.paths), self.height, self.width, self.nch, self.dtype,
                                            in_memory=in_memory)
        frames = [np.empty((hh, ww, self.nch), self.dtype) for _ in self.paths]
        valid: list = [None] * len(self.paths)
        rows = stride * max(1, -(-GRID_STRIP_ROWS // stride))  # a multiple of the stride
        errors: list = [None] * len(self.paths)

        stop = threading.Event()
        finished = threading.Condition()
        running = [len(self.paths)]

        def frame(k):
            try:
                if cache is not None and cache.in_memory:
                    # The frame is kept whole anyway: decode it in one call, straight into
                    # the array the cache keeps (no strip copies), then take its grid.
                    if stop.is_set():
                        return
                    f, v = self._read(k, 0, self.height)
                    cache.adopt(k, f, v)
                    frames[k][...] = f[::stride, ::stride]
                    if v is not None:
                        valid[k] = np.ascontiguousarray(v[::stride, ::stride])
                    return
                for y0 in range(0, self.height, rows):
                    if stop.is_set():  # the caller is unwinding (an error, SIGTERM, Ctrl-C)
                        return
                    f, v = self._read(k, y0, min(self.height, y0 + rows))
                    if cache is not None:
                        cache.put(k, y0, f, v)
                    g0 = y0 // stride
                    sub = f[::stride, ::stride]
                    frames[k][g0:g0 + sub.shape[0]] = sub
                    if v is not None:
                        if valid[k] is None:
                            valid[k] = np.ones((hh, ww), bool)
                        valid[k][g0:g0 + sub.shape[0]] = v[::stride, ::stride]
            except BaseException as exc:  # handed to the caller, first file first
                errors[k] = exc
            finally:
                with finished:
                    running[0] -= 1
                    finished.notify_all()

        def wait_all():
            with finished:
                while running[0]:
                    finished.wait()

        for k in range(len(self.paths)):
            threading.Thread(target=frame, args=(k,), name=f"hdrcl-grid-{k}", daemon=True).start()
        # Not Thread.join: on CPython 3.11 a join interrupted by an exception (SIGTERM and
        # Ctrl-C raise in this thread) can leave later joins returning while the thread
        # still runs. Interrupted, every decoder finishes its strip and stops before
        # anything closes the files under it.
        try:
            wait_all()
        finally:
            stop.set()
            wait_all()
        for exc in errors:
            if exc is not None:
                if cache is not None:
                    cache.close()
                    self.cache = None
                raise exc
        if cache is not None:
            cache.finish()
        self._rewind()  # a later strips() pass starts from the top again
        self._grid = (stride, frames, valid)  # small; a second call (ghost model) reuses it
        return list(frames), list(valid)


_counts_lock = threading.Lock()
_full_decodes: Optional[dict] = None  # by path, while counting (count_full_decodes)


def _count_full_decode(path: str) -> None:
    if _full_decodes is None:
        return
    with _counts_lock:
        n = _full_decodes[path] = _full_decodes.get(path, 0) + 1
    if n > 1:
        logger.debug("%s: decoded whole %d times", path, n)


def count_full_decodes(on: bool = True) -> None:
    """Start (afresh) or stop counting how many times each file is decoded to its last row
    in this process (a debug counter for tests and benchmarks: each frame of a batch should
    be decoded once; :func:`full_decodes` reads it). Off by default: a long-lived process
    would keep one entry per file it ever read."""
    global _full_decodes
    with _counts_lock:
        _full_decodes = {} if on else None


def full_decodes() -> dict:
    """The counts since :func:`count_full_decodes`, by path (empty when not counting)."""
    with _counts_lock:
        return dict(_full_decodes or {})


class _Prefetch:
    """A strip being decoded on a helper thread while the caller uses the previous one."""

    def __init__(self, reader: "BracketReader", y0: int, y1: int):
        import threading

        self._result = None
        self._error = None
        # Not a daemon: a merge that fails leaves at most this strip decoding, and the
        # interpreter waits for it rather than exiting under a running decoder.
        self._thread = threading.Thread(target=self._run, args=(reader, y0, y1), daemon=False,
                                        name="hdrcl-prefetch")
        self._thread.start()

    def _run(self, reader, y0, y1):
        try:
            self._result = reader.read_rows(y0, y1)
        except BaseException as exc:  # handed to the consumer
            self._error = exc

    def wait(self):
        self._thread.join()

    def result(self):
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._result


def ignore_color_mask(pixels: np.ndarray, rgb) -> np.ndarray:
    """Mark pixels that equal a colour exactly (for example the blue fill of Memorial).

    Parameters
    ----------
    pixels : numpy.ndarray
        ``(H, W, C)`` ``uint8`` or ``uint16`` samples, C = 1 or 3 (or ``(H, W)`` grey).
    rgb : sequence of int
        The colour in 8-bit units, e.g. ``(0, 0, 255)``; multiplied by 257 for 16-bit
        pixels so that 255 maps to 65535. Grey images compare with ``rgb[0]``.

    Returns
    -------
    numpy.ndarray
        ``(H, W)`` bool, True where the pixel equals the colour.
    """
    px = np.asarray(pixels)
    if px.ndim == 2:
        px = px[:, :, None]
    if px.ndim != 3 or px.shape[2] not in (1, 3):
        raise ValueError(f"pixels must be (H, W, 1) or (H, W, 3), got shape {px.shape}")
    values = [int(v) for v in (rgb if np.ndim(rgb) else (rgb,))]
    if any(v < 0 or v > 255 for v in values):
        raise ValueError(f"colour {tuple(values)} is not in 8-bit units 0..255")
    scale = 257 if px.dtype == np.uint16 else 1
    if px.shape[2] == 1:
        target = np.array([values[0] * scale])
    else:
        if len(values) != 3:
            raise ValueError(f"colour {tuple(values)} needs three values for RGB pixels")
        target = np.array(values) * scale
    return np.all(px == target.astype(px.dtype), axis=2)
