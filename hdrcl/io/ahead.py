"""Decoding the next bracket set while the current one fuses and encodes.

A batch merges its sets one after another; within a set, decoding, fusion and encoding
overlap strip by strip, but the set's own phases leave a core idle now and then (the
response solve is one thread, the tail of the encode another). :func:`decode_ahead`
starts decoding the *next* set's frames whole, one frame after another, on one helper
thread whose scheduling priority is lowered (:data:`AHEAD_NICE`, Linux threads are
scheduled on their own): it takes the cycles the current set leaves, not the ones it
uses. When the next set's merge opens its frames (:class:`hdrcl.io.reader.BracketReader`),
:func:`take` hands the frames decoded so far over as a complete in-memory
:class:`~hdrcl.io.framecache.FrameCache`, after decoding the rest at normal priority on
the reader's own threads; the merge then reads its sampling grid and its strips from
there, each frame still decoded once.

Within the memory budget: a set is decoded ahead only when its codes fit the in-memory
share of :func:`hdrcl.io.framecache.memory_budget_bytes` (the same rule that keeps a
set's own decoded frames in memory), and at most one set is ahead at a time; nothing is
ever written to disk. A frame that fails to decode ahead is simply left to the merge,
which meets the same error and fails that set alone with its reason. :func:`cancel_all`
stops the helper (it finishes the frame in hand) and drops what it held; the helper is a
daemon thread holding no file beyond its own decoder. ``HDRCL_DECODE_AHEAD=0`` turns
decoding ahead off (for measuring what it gains).

Frames held for a later merge (:func:`hold`): a batch's pooled calibration decodes every
frame of the pooled sets whole to read their sampling grids (:func:`read_and_hold`); it
keeps what it decoded, and each set's merge takes it (:func:`take`) instead of decoding the
set again. Held sets stay in memory while together they fit :data:`HELD_MEMORY_DIVISOR`'s
share of the budget (half: as much as a merge's own frames plus the next set decoded
ahead); the sets beyond are spilled to an anonymous scratch file
(:class:`~hdrcl.io.framecache.FrameCache`, ``HDRCL_SCRATCH_DIR``: unlinked from the start,
so nothing is left however the process ends) up to :data:`SPILL_BUDGET_FACTOR` times the
budget, where that folder is a disk with room for them (:func:`scratch_room`: not tmpfs,
whose files are memory) (reading a 12 MP x 7 set back from it took 0.27 s and writing it 0.12 s against
1.65 s to decode it, on the 2-core test machine); a set beyond both keeps only its grid and
is decoded again by its merge (or ahead of it). A held set is never decoded ahead, and
:func:`cancel_all` drops held sets too.
"""
from __future__ import annotations

import atexit
import logging
import os
import threading
import time
from typing import Callable, Dict, List, Optional, Sequence, Tuple

logger = logging.getLogger(__name__)

#: Niceness of the decode-ahead thread (0 turns the lowering off): the current set's
#: decoding, fusion and encoding run first, the next set's decoding in what they leave.
AHEAD_NICE = 10

#: Held sets stay in memory up to ``memory_budget_bytes() // HELD_MEMORY_DIVISOR`` together.
HELD_MEMORY_DIVISOR = 2
#: Held sets beyond that are spilled to a scratch file up to this many times the budget.
SPILL_BUDGET_FACTOR = 4

_lock = threading.Lock()
_pending: Dict[Tuple[str, ...], "_Ahead"] = {}
_held: Dict[Tuple[str, ...], "Held"] = {}
#: Notified whenever a set leaves the registry (taken, discarded, cancelled).
_freed = threading.Condition(_lock)
_exit_hook: List[bool] = []  # cancel_all registered with atexit


def _key(paths: Sequence) -> Tuple[str, ...]:
    return tuple(os.path.realpath(os.fspath(p)) for p in paths)


def _stamp(paths: Sequence[str]):
    """(size, mtime_ns, inode) of each file: a file changed since it was decoded ahead is
    decoded again by the merge."""
    out = []
    for p in paths:
        st = os.stat(p)
        out.append((st.st_size, st.st_mtime_ns, st.st_ino))
    return out


class _Ahead:
    """One set's frames being decoded on a helper thread."""

    def __init__(self, paths: List[str], infos, open_reader: Callable):
        self.paths, self.infos, self.open_reader = paths, infos, open_reader
        self.stop = threading.Event()
        self.frames: List = [None] * len(paths)
        self.valid: List = [None] * len(paths)
        self.seconds = 0.0
        self.stamp = None
        self.thread = threading.Thread(target=self._run, name="hdrcl-decode-ahead", daemon=True)

    def _run(self) -> None:
        if AHEAD_NICE:
            try:
                os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), AHEAD_NICE)
            except (AttributeError, OSError):  # not Linux, or not allowed: run as is
                pass
        try:
            self.stamp = _stamp(self.paths)
            reader = self.open_reader(self.paths, self.infos)
            try:
                for k in range(len(self.paths)):
                    if self.stop.is_set():
                        return
                    self.frames[k], self.valid[k] = reader.decode_frame(k)
                self.seconds = reader.decode_seconds
            finally:
                reader.close()
        except Exception as exc:  # the merge decodes the frame again and reports it
            logger.debug("decode ahead of %s stopped: %s", self.paths[0], exc)


def decode_ahead(paths: Sequence, infos, open_reader: Callable, stop=None) -> bool:
    """Start decoding the set ``paths`` (headers ``infos``) on the helper thread, when its
    codes fit the in-memory share of the budget and no other set is ahead. True when
    started. ``open_reader(paths, infos)`` gives the decoder (a
    :class:`hdrcl.io.reader.BracketReader` that takes nothing decoded ahead itself):
    its ``decode_frame(k)``, ``decode_seconds`` and ``close()`` are used. ``stop``: a
    :class:`threading.Event` the caller sets before :func:`cancel_all`; checked under the
    registry's lock, so a set read after a cancel is never decoded ahead."""
    from hdrcl.io.framecache import MEMORY_SHARE_DIVISOR, memory_budget_bytes

    from hdrcl.env import flag

    if infos is None or not paths or not flag("HDRCL_DECODE_AHEAD"):
        return False
    first = infos[0]
    nch = 3 if first.nchannels >= 3 else 1
    size = first.width * first.height * nch * (1 if first.bits == 8 else 2) * len(paths)
    if size > memory_budget_bytes() // MEMORY_SHARE_DIVISOR:
        return False
    key = _key(paths)
    with _lock:
        if _pending or key in _held or (stop is not None and stop.is_set()):
            return False
        job = _pending[key] = _Ahead(list(key), list(infos), open_reader)
        if not _exit_hook:
            # A process that exits with a decoder running under a daemon thread crashes
            # in C++ teardown: stop the helper (the frame in hand finishes) first.
            atexit.register(cancel_all)
            _exit_hook.append(True)
    job.thread.start()
    return True


def take(paths: Sequence) -> "Optional[_Ahead | Held]":
    """The set ``paths`` held whole (:class:`Held`) or decoded ahead, removed from the
    registry (the helper stopped after the frame in hand), or None. Frames the helper
    did not reach are None."""
    key = _key(paths)
    with _lock:
        held = _held.pop(key, None)
        job = _pending.pop(key, None) if held is None else None
        _freed.notify_all()
    if held is not None:
        try:
            if _stamp(held.paths) == held.stamp:
                return held
        except OSError:
            pass
        held.close()  # a file changed since: its merge decodes it again
        return None
    if job is None:
        return None
    job.stop.set()
    job.thread.join()
    try:
        if job.stamp is None or _stamp(job.paths) != job.stamp:
            return None
    except OSError:
        return None
    return job


def discard(paths: Sequence) -> None:
    """Drop the set ``paths`` if it is still ahead (its merge did not open it: another
    process merged it, or it failed first), so the next set can be decoded ahead."""
    key = _key(paths)
    with _lock:
        job = _pending.pop(key, None)
        held = _held.pop(key, None)
        _freed.notify_all()
    if held is not None:
        held.close()
    if job is not None:
        job.stop.set()
        job.thread.join(timeout=2.0)


def cancel_all() -> None:
    """Stop every decode ahead and drop its frames, and every held set (a batch ending
    or cancelled)."""
    with _lock:
        jobs = list(_pending.values())
        _pending.clear()
        held = list(_held.values())
        _held.clear()
        _freed.notify_all()
    for h in held:
        h.close()
    for job in jobs:
        job.stop.set()
    for job in jobs:  # the frame in hand finishes (its decoder closes itself); not waited past that
        job.thread.join(timeout=2.0)


def wait_turn(stop=None, timeout: Optional[float] = None) -> bool:
    """Wait until no set is ahead (the one before was taken or dropped), so that the next
    set can be decoded ahead: one set at a time, without losing the turn to a race with
    the merge that takes the set before. False when ``stop`` is set or ``timeout`` passed
    first; ``stop`` (a :class:`threading.Event`) is checked at each notification and at
    least every second."""
    deadline = None if timeout is None else time.monotonic() + timeout
    with _freed:
        while _pending and not (stop is not None and stop.is_set()):
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return False
            _freed.wait(1.0 if left is None else min(1.0, left))
        return not (stop is not None and stop.is_set())


def pending() -> int:
    """Sets decoded ahead and not yet taken (tests)."""
    with _lock:
        return len(_pending)


# ------------------------------------------------------------------ held sets
class Held:
    """A set's frames decoded whole by an earlier pass, held for its merge: ``cache``
    (a complete :class:`~hdrcl.io.framecache.FrameCache`, in memory or spilled), the
    sampling ``grid`` read from them (``(stride, frames, valid)``), the CPU ``seconds``
    their decoding took, and the files' ``stamp`` from before they were decoded."""

    def __init__(self, paths: List[str], cache, grid, seconds: float, stamp):
        self.paths, self.cache, self.grid, self.seconds, self.stamp = paths, cache, grid, seconds, stamp

    @property
    def nbytes(self) -> int:
        return self.cache.frame_bytes * self.cache.nframes

    def close(self) -> None:
        if self.cache is not None:
            self.cache.close()
            self.cache = None


def room_for(nbytes: int) -> Optional[bool]:
    """Where a set of ``nbytes`` decoded codes may be held: True in memory, False in a
    scratch file, None nowhere (see the module docstring)."""
    from hdrcl.io.framecache import MEMORY_SHARE_DIVISOR, memory_budget_bytes

    budget = memory_budget_bytes()
    with _lock:
        in_memory = sum(h.nbytes for h in _held.values() if h.cache is not None and h.cache.in_memory)
        spilled = sum(h.nbytes for h in _held.values() if h.cache is not None and not h.cache.in_memory)
    if nbytes <= budget // MEMORY_SHARE_DIVISOR and in_memory + nbytes <= budget // HELD_MEMORY_DIVISOR:
        return True
    if spilled + nbytes <= budget * SPILL_BUDGET_FACTOR and scratch_room(nbytes):
        return False
    return None


#: Free space the scratch folder keeps beyond a spilled set (the outputs may share its disk).
SPILL_MARGIN_BYTES = 256 << 20
#: File systems whose files are memory: a spill there would hold the frames in RAM
#: beyond ``HDRCL_MEMORY_MB`` (a /tmp on tmpfs, as several distributions mount it).
MEMORY_FILE_SYSTEMS = ("tmpfs", "ramfs")


def scratch_room(nbytes: int) -> bool:
    """Whether the scratch folder (``HDRCL_SCRATCH_DIR``, else the temporary folder) can
    take ``nbytes`` more of held frames: a disk with that much free beyond
    :data:`SPILL_MARGIN_BYTES`, not memory (:data:`MEMORY_FILE_SYSTEMS`)."""
    import shutil

    from hdrcl.io.framecache import _scratch_dir

    try:
        folder = _scratch_dir()
        if file_system(folder) in MEMORY_FILE_SYSTEMS:
            return False
        return shutil.disk_usage(folder).free >= nbytes + SPILL_MARGIN_BYTES
    except OSError:  # no such folder: the spill would fail too
        return False


def file_system(folder: str) -> Optional[str]:
    """The type of the file system ``folder`` is on (``/proc/self/mounts``: Linux), or None."""
    try:
        with open("/proc/self/mounts", encoding="utf-8", errors="replace") as f:
            mounts = [line.split()[1:3] for line in f if len(line.split()) >= 3]
    except OSError:
        return None
    path = os.path.realpath(folder)
    best, kind = "", None
    for point, fstype in mounts:
        point = point.replace("\\040", " ").replace("\\011", "\t").replace("\\134", "\\")
        if (path == point or path.startswith(point.rstrip("/") + "/")) and len(point) >= len(best):
            best, kind = point, fstype
    return kind


def read_and_hold(reader, stride: int):
    """The sampling grid of the set ``reader`` (a :class:`hdrcl.io.reader.BracketReader`)
    opened, read in one pass that keeps the frames it decodes for the set's merge
    (:func:`take`) where :func:`room_for` finds room: ``(frames, valid)`` as
    :meth:`~hdrcl.io.reader.BracketReader.read_grid` gives them. The reader is left
    without its cache (the registry owns it) and may be closed."""
    first = reader.infos[0]
    nbytes = reader.width * reader.height * reader.nch * reader.dtype.itemsize * len(reader.paths)
    where = room_for(nbytes)
    stamp = _stamp(reader.paths)  # before decoding: a file changed meanwhile is decoded again
    if where is None:
        logger.info("%s: its frames do not fit the memory budget: its merge decodes them again", first.path)
        return reader.read_grid(stride)
    try:
        frames, valid = reader.read_grid(stride, keep=True, in_memory=where)
    except OSError as exc:
        if where:  # nothing was spilled: the decode itself failed
            raise
        # The scratch file could not be made or written (a full or missing HDRCL_SCRATCH_DIR):
        # holding is an optimisation, so the grid is read without it and the merge decodes
        # the set again, as a set beyond the budget does (read_grid dropped the cache).
        logger.warning("%s: cannot spill its frames to the scratch folder (%s): its merge decodes them again",
                       first.path, exc.strerror or exc)
        return reader.read_grid(stride)
    cache, reader.cache = reader.cache, None
    held = Held(list(_key(reader.paths)), cache, (stride, list(frames), list(valid)), reader.decode_seconds,
                stamp)
    with _lock:
        old = _held.pop(_key(reader.paths), None)
        _held[_key(reader.paths)] = held
    if old is not None:
        old.close()
    logger.debug("%s: %d frames held in %s for the merge", first.path, len(reader.paths), cache.where)
    return frames, valid


def held() -> int:
    """Sets held for a later merge and not yet taken (tests)."""
    with _lock:
        return len(_held)
