"""OpenEXR on all cores for :mod:`hdrcl.io.writers` (re-exported by :mod:`hdrcl.io.encoders`).

**OpenEXR** compresses scanline blocks (:data:`EXR_BLOCK_LINES`) on OpenImageIO's
``exr_threads`` threads, but only the blocks of one ``write_scanlines`` call at a time:
each call waits for all of its blocks. A strip of a few dozen rows is one to three
blocks, so :class:`ExrBatch` gathers strips into batches of :data:`EXR_BLOCKS_PER_THREAD`
blocks per thread (:func:`exr_batch_rows`). It takes OpenImageIO objects from its
caller: only :mod:`hdrcl.io.writers` and :mod:`hdrcl.io.frames` import OpenImageIO.
"""
from __future__ import annotations

import os

import numpy as np

__all__ = ["EXR_BLOCK_LINES", "EXR_BLOCKS_PER_THREAD", "EXR_BATCH_BYTES", "exr_threads", "exr_batch_rows",
           "ExrBatch"]


#: Scanlines OpenEXR compresses as one block, by compression.
EXR_BLOCK_LINES = {"none": 1, "rle": 1, "zips": 1, "zip": 16, "piz": 32, "pxr24": 16, "b44": 32,
                   "b44a": 32, "dwaa": 32, "dwab": 256}
#: Blocks per compression thread in one batch of :class:`ExrBatch`.
EXR_BLOCKS_PER_THREAD = 2
#: Most bytes (as float32 samples) one batch of :class:`ExrBatch` holds.
EXR_BATCH_BYTES = 64 << 20


def exr_threads(oiio) -> int:
    """Threads OpenEXR compresses with: the ``exr_threads`` attribute of OpenImageIO
    (module ``oiio``; all the processor's threads unless set), lowered to the CPUs this
    process may run on (setting the attribute)."""
    n = oiio.get_int_attribute("exr_threads", 0)
    if n == -1:  # OpenImageIO's "no thread pool"
        return 1
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if n <= 0 or n > cpus:
        n = cpus
        oiio.attribute("exr_threads", n)
    return max(1, n)


def exr_batch_rows(compression: str, width: int, nch: int, threads: int) -> int:
    """Rows per ``write_scanlines`` call that keep ``threads`` OpenEXR threads busy:
    :data:`EXR_BLOCKS_PER_THREAD` whole blocks per thread, at most
    :data:`EXR_BATCH_BYTES` (and at least one block)."""
    block = EXR_BLOCK_LINES.get(str(compression).split(":")[0].strip().lower(), 16)
    rows = block * EXR_BLOCKS_PER_THREAD * max(1, int(threads))
    cap = EXR_BATCH_BYTES // max(1, width * nch * 4) // block * block
    return max(block, min(rows, cap))


class ExrBatch:
    """Gathers strips for an open OpenImageIO EXR ``output`` and hands them over ``rows``
    at a time (from row 0 down) on a helper thread, as half when ``half`` (the values
    must fit; NumPy rounds to nearest even, as OpenEXR does), else float32.

    Two batches alternate: the caller fills one while OpenEXR compresses the other
    (OpenImageIO releases the GIL), so copying strips in overlaps compression.
    :meth:`add` copies (callers may reuse their strip) and returns False when a write
    failed, with ``(y0, y1, error)`` in :attr:`failed`; so does :meth:`flush`, which
    writes what is left and waits. :meth:`cancel` waits for a write in progress (call
    it before closing ``output``).
    """

    def __init__(self, output, rows: int, width: int, nch: int, half: bool):
        self.output = output
        dtype = np.float16 if half else np.float32
        self._rows = [np.empty((int(rows), int(width), int(nch)), dtype) for _ in range(2)]
        self._cur = 0
        self.y0 = self.n = 0
        self.failed = None
        self._pool = self._pending = None

    def add(self, data: np.ndarray, fill=None) -> bool:
        """Append float32 ``(rows, width, nch)`` rows; send every batch that fills.

        ``fill(src, dst)``, when given, puts rows ``src`` of ``data`` into the batch's
        rows ``dst`` (half or float32, C-contiguous) instead of a plain copy (for
        :class:`hdrcl.io.halfrange.OnePass`: scaled, measured and converted at once).
        """
        done, total = 0, data.shape[0]
        while done < total:
            rows = self._rows[self._cur]
            take = min(total - done, rows.shape[0] - self.n)
            if fill is None:
                rows[self.n:self.n + take] = data[done:done + take]
            else:
                fill(data[done:done + take], rows[self.n:self.n + take])
            self.n += take
            done += take
            if self.n == rows.shape[0] and not self._send():
                return False
        return True

    def _write(self, rows: np.ndarray, y0: int):
        """On the helper thread: None, or what failed (OpenImageIO's errors are per thread)."""
        if self.output.write_scanlines(y0, y0 + rows.shape[0], 0, rows):
            return None
        return y0, y0 + rows.shape[0], self.output.geterror()

    def _wait(self) -> bool:
        if self._pending is not None:
            pending, self._pending = self._pending, None
            self.failed = self.failed or pending.result()
        return self.failed is None

    def _send(self) -> bool:
        """Send the current batch once the previous write is done; switch batches."""
        if not self._wait():
            return False
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor

            self._pool = ThreadPoolExecutor(1, thread_name_prefix="hdrcl-exr")
        self._pending = self._pool.submit(self._write, self._rows[self._cur][:self.n], self.y0)
        self.y0, self.n, self._cur = self.y0 + self.n, 0, 1 - self._cur
        return True

    def flush(self) -> bool:
        """Write the rows gathered so far and wait for every write."""
        ok = self._send() if self.n else True
        ok = self._wait() and ok
        self.cancel()
        return ok

    def cancel(self) -> None:
        """Wait for a write in progress (its result is dropped) and stop the helper thread."""
        if self._pending is not None:
            try:
                self._pending.result()
            except Exception:  # the file is being dropped or has failed already
                pass
            self._pending = None
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
