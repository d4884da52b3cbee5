"""One set committing while the next one starts (issue 33 item 4).

A batch in this process (:func:`hdrcl.shoot.batch.run._run_pipelined`) runs each set's
merge up to its commit on the main thread, which owns the OpenCL queue
(:func:`hdrcl.shoot.batch.setrun._merge_begin`: open, calibrate, measure, agreement,
fusion into the open writer), and hands the set's tail to :class:`Committer`'s one
thread (:func:`hdrcl.shoot.batch.setrun._commit_set`: the preview and deliverables, the
rest of the encode, the EXR moved into place, the set's record, its quality report),
so that set n's tail runs while set n+1 opens, measures and fuses: the single-threaded
phases of one set leave a core to the other's.

The rules:

* **One set committing at a time.** Set n+1's commit is handed over once set n's is
  done, and set n's result is emitted then, before n+1's: results, progress lines and
  report entries stay in set order.
* **Within the memory budget.** A set's streamed frames are released before its commit
  (:func:`release_frames`); what the committing set still holds (an aligned set's frames,
  its full-size sinks, the frames its quality report keeps: :func:`held_bytes`)
  and what the next set will hold (its frames' codes, up to the in-memory share:
  :func:`need_bytes`) must fit :func:`hdrcl.io.framecache.memory_budget_bytes` together;
  otherwise the next set waits for the commit.
* **A failure stays local.** A commit that fails returns its set's failed result (its
  temporary files removed); the batch goes on.
* **Cancel stops both.** :meth:`Committer.close` with ``cancelled`` sets the commit's stop
  event: a commit that has not moved its EXR into place undoes its set (no temporary
  file left), one that has is recorded; the thread is joined, so nothing is left running.
"""
from __future__ import annotations

import logging
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Optional

import numpy as np

logger = logging.getLogger(__name__)


def held_bytes(run) -> int:
    """Bytes a fused run (:class:`hdrcl.core.runstate.RunState`) holds until its commit ends:
    its decoded frames in memory, the full-size sinks and kept map, the quality report's
    kept frames."""
    src, n = run.source, 0
    cache = getattr(src, "cache", None)
    if cache is not None and getattr(cache, "in_memory", False):
        n += int(cache.frame_bytes) * int(cache.nframes)
    if hasattr(src, "frames"):  # frames held as arrays (an aligned source's are views of
        # its cache, counted above: asking them for nbytes would warp each one whole)
        n += sum(int(f.nbytes) for f in src.frames if isinstance(f, np.ndarray))
    for sink in list(run.sinks.values()) + [run.keep]:
        arr = getattr(sink, "array", None)
        n += int(getattr(arr, "nbytes", 0))
    tapped = run.tapped
    if tapped is not None:
        n += sum(int(k.nbytes) for k in getattr(tapped, "kept", ()))
    return n


def release_frames(run) -> None:
    """Close a fused run's frame source before its commit where the commit never reads it
    (streamed frames: the quality report reads the frames it kept as they passed), so the
    set committing does not hold its decoded frames beside the next set's. An aligned
    run's frames (the deliverables' exposure fusion, the report) and frames the plan keeps
    stay until :func:`hdrcl.core.executor.finish` closes them."""
    if hasattr(run.source, "frames") or run.plan.extras.keep_frames:
        return
    run.close()  # finish closes it again: a no-op


def need_bytes(step) -> int:
    """Bytes a set about to start (:class:`hdrcl.shoot.batch.setrun._Opening`) will hold:
    its frames' codes, up to the share a set keeps in memory (beyond it they spill to the
    scratch file, :class:`hdrcl.io.framecache.FrameCache`)."""
    from hdrcl.io.framecache import MEMORY_SHARE_DIVISOR, memory_budget_bytes

    codes = sum(int(i.width) * int(i.height) * int(i.nchannels) * (2 if int(i.bits or 8) > 8 else 1)
                for i in step.opened.infos)
    return min(codes, memory_budget_bytes() // MEMORY_SHARE_DIVISOR)


class Committer:
    """Commits started sets (:class:`hdrcl.shoot.batch.setrun._Started`) one at a time on
    one thread, emitting each result, in set order, through ``emit``.

    ``make_room(step)`` before a set starts, ``merge(step, t_begin)`` to run it, ``drain()``
    before emitting a set that did not merge, ``close(cancelled)`` at the end.
    """

    def __init__(self, ctx, emit: Callable):
        self.ctx, self.emit = ctx, emit
        self.stop = threading.Event()
        self._pool: Optional[ThreadPoolExecutor] = None
        self._pending = None  # (bytes held, future) of the set committing
        self._gate: Optional[_Gate] = None  # the last set handed over, or being handed

    def make_room(self, step) -> None:
        """Wait for the set committing if the next one would not fit beside it."""
        if self._pending is None:
            return
        from hdrcl.io.framecache import memory_budget_bytes

        held, need, budget = self._pending[0], need_bytes(step), memory_budget_bytes()
        if held + need > budget:
            logger.debug("set %d waits for the commit before it: %d + %d bytes > budget %d",
                         step.job.index, held, need, budget)
            self.drain()

    def merge(self, step, t_begin: float):
        """Run set ``step`` (:class:`hdrcl.shoot.batch.setrun._Opening`) up to its commit here,
        then hand it to the commit thread (once the set committing is done and emitted).
        Returns None when handed over, else the set's result (skipped, failed) to emit
        after :meth:`drain`. A set started but never handed over (an exception, a signal
        on the way) is undone: its temporary files removed, its claim released."""
        from hdrcl.shoot.batch.setrun import _merge_begin, _Started

        begun = _merge_begin(step, self.ctx)
        if not isinstance(begun, _Started):
            return begun
        try:
            self._submit(begun, t_begin)
        except BaseException:
            gate = self._gate
            if gate is None or gate.started is not begun or not gate.settle(False):
                self._undo(begun)  # not handed over: the commit thread will not touch it
            raise
        return None

    def _submit(self, started, t_begin: float) -> None:
        from hdrcl.shoot.batch.setrun import _commit_set

        self.drain()  # one set committing at a time; its result first (set order)
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="hdrcl-commit")

        gate = self._gate = _Gate(started)

        def task():
            if not gate.wait():  # a signal came before the hand-over: undone on the main thread
                return None
            res = _commit_set(started, self.ctx, stop=self.stop)
            res.seconds["total"] = time.perf_counter() - t_begin
            return res

        release_frames(started.run)
        held = held_bytes(started.run)
        # A signal can land anywhere here (the thread start inside submit waits): the set
        # belongs to the commit thread only once settled below, else merge() undoes it.
        self._pending = (held, self._pool.submit(task))
        gate.settle(True)

    def drain(self) -> None:
        """Wait for the set committing, if any, and emit its result."""
        if self._pending is None:
            return
        fut = self._pending[1]
        res = fut.result()  # _commit_set returns the set's result, failed or not
        self._pending = None
        self.emit(res)

    def close(self, cancelled: bool) -> None:
        """The end of the batch: emit the last commit's result; ``cancelled``: stop the commit
        first (its set undone unless its EXR is in place already). The thread is joined."""
        from hdrcl.shoot.batch.setrun import _Stopped

        if cancelled:
            self.stop.set()
        if self._gate is not None:
            self._gate.settle(False)  # a hand-over a second signal left unsettled: dropped
        try:
            if self._pending is not None:
                fut = self._pending[1]
                try:
                    res = _wait(fut)
                except _Stopped:
                    res = None
                self._pending = None
                if res is not None:
                    self.emit(res)
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
                self._pool = None

    @staticmethod
    def _undo(started) -> None:
        from hdrcl.core.executor import abort

        try:
            abort(started.run)
        finally:
            started.claim.release()


class _Gate:
    """Who owns a set being handed over: the commit thread (``settle(True)``, once the
    main thread holds its future) or the main thread that undoes it (``settle(False)``,
    a signal came first). Settled once, by the main thread; the commit thread waits."""

    def __init__(self, started):
        self.started = started
        self.handed: Optional[bool] = None
        self._settled = threading.Event()

    def settle(self, handed: bool) -> bool:
        """Settle it (the first call decides); returns whether it was handed over."""
        if self.handed is None:
            self.handed = handed  # one store: a signal after it finds the decision made
        self._settled.set()
        return self.handed

    def wait(self) -> bool:
        while self.handed is None:  # a signal between the store and set(): polled
            self._settled.wait(0.05)
        return self.handed


def _wait(fut):
    """The future's result, waited for even through a second signal (the commit then stops
    at its next step: leaving it running would leave its temporary files)."""
    while True:
        try:
            return fut.result()
        except BaseException as exc:
            if fut.done():
                raise
            logger.debug("waiting for the commit to stop (%s)", type(exc).__name__)
