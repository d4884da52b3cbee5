"""Decoded frames kept for a second pass, so that every frame is decoded once.

A calibrating merge needs the frames twice: first for the sampling grid the response is
solved from, then for the fusion. Decoding a JPEG costs far more than copying its
decoded codes, so the first pass (:meth:`hdrcl.io.reader.BracketReader.read_grid`)
stores every decoded strip in a :class:`FrameCache` and the fusion pass reads its strips
back from there instead of decoding again.

The codes stay in memory when they fit a quarter of the memory budget
(``HDRCL_MEMORY_MB``, default 1024 MB); otherwise they are spilled to an anonymous temporary file
(``HDRCL_SCRATCH_DIR``, else the system's temporary folder). The file is unlinked from
the moment it is created, so it leaves nothing behind however the process ends (kill -9
included), and its pages live in the operating system's page cache rather than in the
process, which keeps the merge's resident memory bounded whatever the image size.

A spilled cache is read back through a read-only mapping of the file: :meth:`FrameCache.rows`
returns views of the page cache, not copies (a copy into fresh memory cost a page fault
per 4 KB, as much CPU as the copy itself), and gives the mapping's pages back
(``MADV_DONTNEED``) once the reads have moved :data:`UNMAP_LAG_STRIPS` strips past them,
so the process's resident memory stays a few strips. The pages stay in the page cache: a view
still read after that reads the same bytes again.
"""
from __future__ import annotations

import mmap
import os
import tempfile
from typing import List, Optional

import numpy as np

#: Default memory budget (MB) for decoded frames, shared with :func:`hdrcl.core.bracket.memory_budget`.
DEFAULT_MEMORY_MB = 1024.0
#: The codes stay in memory up to this fraction of the budget (a quarter: a 24 MP x 7
#: set, 504 MB of codes, spills, and a calibrating merge of it peaks near 400 MB rather
#: than 800 MB; reading the scratch file back maps the page cache: no decode, no copy).
MEMORY_SHARE_DIVISOR = 4
#: Reads (strips) of a spilled cache kept mapped behind the last one (the strips a fusion
#: has in flight and a deghost look-back) before their pages are given back.
UNMAP_LAG_STRIPS = 4


def memory_budget_bytes() -> int:
    """This process's share of ``HDRCL_MEMORY_MB`` in bytes (default
    :data:`DEFAULT_MEMORY_MB`, divided between a batch's worker processes); a value the
    variable does not take (``abc``, 0) is a UsageError naming it (:mod:`hdrcl.env`: the
    CLI checks every variable up front, a script gets the same error here)."""
    from hdrcl.env import number

    mb = number("HDRCL_MEMORY_MB")
    share = number("HDRCL_MEMORY_SHARE")
    return int(mb * (1 << 20) / share)


def _scratch_dir() -> str:
    from hdrcl.env import text

    return text("HDRCL_SCRATCH_DIR") or tempfile.gettempdir()


class FrameCache:
    """Every frame's decoded rows (and alpha masks), written once, read back in strips.

    Parameters
    ----------
    nframes, height, width, nch : int
        Shape of the bracket.
    dtype : numpy.dtype
        ``uint8`` or ``uint16`` codes.
    in_memory : bool, optional
        Force memory (True) or a spill file (False); default: memory when the codes fit
        a quarter of :func:`memory_budget_bytes`.

    Writers may fill different frames from different threads at once (each frame's rows
    are a region of their own); :attr:`complete` turns True once :meth:`finish` is called
    after every row of every frame was written.
    """

    def __init__(self, nframes: int, height: int, width: int, nch: int, dtype, in_memory: Optional[bool] = None):
        self.nframes, self.height, self.width, self.nch = nframes, height, width, nch
        self.dtype = np.dtype(dtype)
        self.row_bytes = width * nch * self.dtype.itemsize
        self.frame_bytes = self.row_bytes * height
        total = self.frame_bytes * nframes
        if in_memory is None:
            in_memory = total <= memory_budget_bytes() // MEMORY_SHARE_DIVISOR
        self.in_memory = bool(in_memory)
        self._frames: Optional[List[np.ndarray]] = None
        self._file = None
        self._map = self._codes = None  # read-only mapping of the spill file, made by the first read
        self._unmapped = 0  # rows of every frame whose mapped pages were given back
        self._last = 0  # first row of the last read (a read above it starts a new pass)
        if self.in_memory:  # allocated on first use, or adopted whole (no copy)
            self._frames = [None] * nframes
        else:
            self._file = tempfile.TemporaryFile(dir=_scratch_dir(), prefix=".hdrcl-frames-")
            self._file.truncate(total)
        # Alpha masks are rare and one byte a pixel: always in memory, created on first use.
        self._valid: List[Optional[np.ndarray]] = [None] * nframes
        self.complete = False

    @property
    def where(self) -> str:
        return "memory" if self.in_memory else "a temporary file"

    def put(self, k: int, y0: int, rows: np.ndarray, valid: Optional[np.ndarray] = None) -> None:
        """Store rows ``y0..y0+len(rows)`` of frame ``k`` (and their alpha mask)."""
        n = rows.shape[0]
        if self._frames is not None:
            if self._frames[k] is None:
                self._frames[k] = np.empty((self.height, self.width, self.nch), self.dtype)
            self._frames[k][y0:y0 + n] = rows
        else:
            data = np.ascontiguousarray(rows, self.dtype)
            offset = k * self.frame_bytes + y0 * self.row_bytes
            view = memoryview(data).cast("B")
            done = 0
            while done < len(view):  # pwrite may write less than asked
                done += os.pwrite(self._file.fileno(), view[done:], offset + done)
        if valid is not None:
            if self._valid[k] is None:
                self._valid[k] = np.ones((self.height, self.width), bool)
            self._valid[k][y0:y0 + n] = valid

    def adopt(self, k: int, frame: np.ndarray, valid: Optional[np.ndarray] = None) -> None:
        """Keep a whole decoded frame as it is (memory caches only; no copy)."""
        if self._frames is None:
            raise ValueError("adopt() needs an in-memory cache")
        if frame.shape != (self.height, self.width, self.nch) or frame.dtype != self.dtype:
            raise ValueError(f"frame {k}: {frame.shape} {frame.dtype} is not a frame of this cache")
        self._frames[k] = frame
        self._valid[k] = valid

    def finish(self) -> None:
        self.complete = True

    def rows(self, y0: int, y1: int):
        """Rows ``y0..y1`` of every frame: ``(frames, valid)`` lists of views (read-only
        use; a spilled cache's are read-only arrays over the file's mapping)."""
        if self._frames is not None:  # views: the consumers only read them
            frames = [self._frames[k][y0:y1] for k in range(self.nframes)]
        else:
            codes = self._mapped()
            frames = [codes[k, y0:y1] for k in range(self.nframes)]
            self._give_back(y0, y1 - y0)
        valid = [None if v is None else v[y0:y1] for v in self._valid]
        return frames, valid

    def _mapped(self) -> np.ndarray:
        """The spill file as a read-only ``(nframes, height, width, nch)`` array."""
        if self._map is None:
            size = self.frame_bytes * self.nframes
            self._map = mmap.mmap(self._file.fileno(), size, flags=mmap.MAP_SHARED, prot=mmap.PROT_READ)
            self._codes = np.frombuffer(self._map, self.dtype).reshape(
                self.nframes, self.height, self.width, self.nch)
        return self._codes

    def _give_back(self, y0: int, rows: int) -> None:
        """Drop the mapping's pages of every frame's rows more than :data:`UNMAP_LAG_STRIPS`
        reads of ``rows`` rows above ``y0`` (read top to bottom; the page cache keeps them)."""
        if y0 < self._last:  # a new pass from the top: give back from there again
            self._unmapped = 0
        self._last = y0
        upto = y0 - UNMAP_LAG_STRIPS * rows
        if upto - self._unmapped < 2 * rows or not hasattr(self._map, "madvise"):
            return
        page = mmap.PAGESIZE
        for k in range(self.nframes):
            a = k * self.frame_bytes + self._unmapped * self.row_bytes
            b = k * self.frame_bytes + upto * self.row_bytes
            a = -(-a // page) * page  # whole pages inside the rows given back
            b = b // page * page
            if b > a:
                self._map.madvise(mmap.MADV_DONTNEED, a, b - a)
        self._unmapped = upto

    def frame_rows(self, k: int, y0: int, y1: int):
        """Rows ``y0..y1`` of frame ``k``: ``(codes, alpha mask or None)`` (read-only use;
        views of a memory cache; a spilled cache's rows are read into a new array, so an
        aligned merge reading each frame's own band keeps no pages of the file mapped)."""
        v = self._valid[k]
        v = None if v is None else v[y0:y1]
        if self._frames is not None:  # views: the consumers only read them
            return self._frames[k][y0:y1], v
        out = np.empty((y1 - y0, self.width, self.nch), self.dtype)
        view = memoryview(out).cast("B")
        offset = k * self.frame_bytes + y0 * self.row_bytes
        done = 0
        while done < len(view):
            got = os.preadv(self._file.fileno(), [view[done:]], offset + done)
            if got <= 0:
                raise OSError(f"decoded-frame cache: short read at byte {offset + done}")
            done += got
        return out, v

    def close(self) -> None:
        self._frames = None
        # The mapping is not closed: views handed out may still be read (it goes with the
        # last of them).
        self._map = self._codes = None
        if self._file is not None:
            self._file.close()
            self._file = None
        self.complete = False

    def __del__(self):  # pragma: no cover - belt and braces
        try:
            self.close()
        except Exception:
            pass
