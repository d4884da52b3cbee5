"""Safe to cancel, kill and requeue: set claims, folder locks, workers tied to the batch.

**Claims.** Before a process merges a set it claims it: it opens (never through a
symbolic link) ``OUT_DIR/.<stem>.claim`` and takes an exclusive ``flock`` on it, waiting
while another process holds it. The kernel drops the lock when its holder dies, however
it dies, so a claim never outlives its owner. Whoever holds a set's claim is the only
writer of that set's files: it removes the set's temporary files left by a dead owner
(``.<stem>.tmp-*``), checks again whether the output became current while it waited
(another batch on the same folder just wrote it) and only then merges. Two batches on
one folder therefore never delete each other's files and never merge a set twice.

**Folder lock.** The report's read-modify-write is serialised by an ``flock`` on the
folder itself (a directory cannot be replaced by a symbolic link to somewhere else under
an open descriptor), so no lock file can be redirected.

**Workers die with the batch.** Each worker process asks the kernel to kill it when its
parent dies (Linux ``prctl(PR_SET_PDEATHSIG, SIGKILL)``) and also runs a watchdog thread
that kills it when its parent process id changes (every platform, also covers the race
before ``prctl``). On SIGTERM or SIGINT the batch (the CLI, :func:`cancel_signals`)
kills its workers at once, removes the temporary files of the sets they held, writes the
report of what finished and exits 143 or 130; called from Python, the caller's handlers
stay and whatever they raise reaches the caller after the same cleanup.
"""
from __future__ import annotations

import contextlib
import errno
import glob
import logging
import os
import signal
import threading
import time
from typing import Iterator, Optional

from hdrcl.errors import check_regular  # noqa: F401 - moved to hdrcl.errors; kept importable here

logger = logging.getLogger(__name__)

__all__ = ["Cancelled", "check_regular", "SetClaim", "claim_set", "folder_lock", "tie_to_parent", "cancel_signals",
           "remove_orphan_temps"]

#: How often (seconds) a worker's watchdog checks that its parent is alive.
WATCHDOG_PERIOD = 0.25


class Cancelled(BaseException):
    """The batch received SIGTERM or SIGINT (a BaseException: no set swallows it)."""

    def __init__(self, signum: int):
        super().__init__(f"cancelled by {signal.Signals(signum).name}")
        self.signum = signum

    @property
    def exit_code(self) -> int:
        """128 + the signal number: 143 for SIGTERM, 130 for SIGINT."""
        return 128 + int(self.signum)


# ------------------------------------------------------------------------- claims


def _open_nofollow(path: str, flags: int) -> int:
    return os.open(path, flags | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0), 0o666)


class SetClaim:
    """An exclusive, kernel-held claim on one set's outputs (see the module docstring)."""

    def __init__(self, out_dir: str, stem: str):
        self.path = os.path.join(out_dir, f".{stem}.claim")
        self.stem = stem
        self.out_dir = out_dir
        self.fd: Optional[int] = None

    def acquire(self, wait: bool = True) -> bool:
        """Take the claim; with ``wait`` block until its holder is done.

        Returns False (only without ``wait``) when another live process holds it.
        Where there is no ``flock`` (Windows) claims are not taken: one batch per
        output folder there.
        """
        try:
            import fcntl
        except ImportError:
            return True

        while True:
            try:
                fd = _open_nofollow(self.path, os.O_RDWR | os.O_CREAT)
            except OSError as exc:
                if exc.errno == errno.ELOOP:
                    os.unlink(self.path)  # a symbolic link in our folder is never ours: drop it
                    continue
                raise
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
            except BlockingIOError:
                os.close(fd)
                return False
            except BaseException:
                os.close(fd)
                raise
            # The holder before us may have removed the file after we opened it: the
            # lock must be on the file that is at the path now.
            try:
                same = os.stat(self.path, follow_symlinks=False).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                self.fd = fd
                with contextlib.suppress(OSError):
                    os.ftruncate(fd, 0)
                    os.write(fd, f"{os.getpid()}\n".encode())
                return True
            os.close(fd)

    def remove_temps(self) -> int:
        """Delete this set's temporary files (only its claim holder may)."""
        n = 0
        for p in set_temps(self.out_dir, self.stem):
            with contextlib.suppress(OSError):
                os.remove(p)
                n += 1
                logger.debug("removed temporary file of a dead run: %s", p)
        return n

    def release(self) -> None:
        """Remove the claim file and drop the lock (in that order: see :meth:`acquire`)."""
        if self.fd is None:
            return
        with contextlib.suppress(OSError):
            os.unlink(self.path)
        os.close(self.fd)  # closing drops the flock
        self.fd = None

    def __enter__(self):
        if self.fd is None:
            self.acquire()
        return self

    def __exit__(self, *exc):
        self.release()


def claim_set(out_dir: str, stem: str) -> SetClaim:
    """Claim a set (blocking) and remove the temporary files a dead owner left."""
    c = SetClaim(out_dir, stem)
    c.acquire()
    c.remove_temps()
    return c


def temp_infixes() -> tuple:
    """What stands between a set's stem and ``.tmp-`` in its files' temporary names: nothing
    (``.IMG_1.tmp-1a2b3c4d.exr``, its preview, AVIF, JPEG XL) or a deliverable's inner
    suffix (``.IMG_1.uhdr.tmp-1a2b3c4d.jpg``; :data:`hdrcl.report.deliver.DELIVERABLES`)."""
    from hdrcl.report.deliver import DELIVERABLES

    inner = {d.suffix.rsplit(".", 1)[0] for d in DELIVERABLES.values()}  # ".uhdr.jpg" -> ".uhdr", ".avif" -> ""
    return ("",) + tuple(sorted(x for x in inner if x))


def set_temps(out_dir: str, stem: str) -> list:
    """The temporary files of set ``stem`` in ``out_dir`` (its outputs' and deliverables')."""
    folder = glob.escape(out_dir)
    return [p for infix in temp_infixes()
            for p in glob.glob(os.path.join(folder, f".{glob.escape(stem)}{infix}.tmp-*"))]


def remove_orphan_temps(out_dir: str, stems) -> None:
    """Remove temporary files and claim files of sets nobody holds a claim on (their
    writer is gone); those of sets a live process works on stay."""
    for stem in stems:
        c = SetClaim(out_dir, stem)
        if not (os.path.lexists(c.path) or set_temps(out_dir, stem)):
            continue
        try:
            got = c.acquire(wait=False)
        except OSError:
            continue
        if got:
            try:
                c.remove_temps()
            finally:
                c.release()


@contextlib.contextmanager
def folder_lock(folder: str) -> Iterator[None]:
    """Exclusive ``flock`` on the folder itself (no lock file, nothing to redirect)."""
    try:
        import fcntl
    except ImportError:  # Windows: chunks there should use --report-json per chunk
        yield
        return
    fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


# ------------------------------------------------------------------------ workers


def _pdeathsig() -> bool:
    """Linux: the kernel sends SIGKILL to this process when its parent dies."""
    import sys

    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        PR_SET_PDEATHSIG = 1
        return libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def tie_to_parent(parent_pid: int) -> None:
    """Make this (worker) process die when ``parent_pid`` dies, whatever kills it.

    ``prctl(PR_SET_PDEATHSIG)`` where available, and a daemon watchdog thread that
    checks ``os.getppid()`` every :data:`WATCHDOG_PERIOD` seconds everywhere (it also
    catches a parent that died before ``prctl`` was called). Ctrl-C in a terminal
    reaches the whole process group: workers ignore SIGINT and leave it to the batch.
    """
    with contextlib.suppress(ValueError, OSError):
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    _pdeathsig()

    kill = getattr(signal, "SIGKILL", signal.SIGTERM)  # Windows has no SIGKILL

    def watch():
        while True:
            if os.getppid() != parent_pid:
                os.kill(os.getpid(), kill)
            time.sleep(WATCHDOG_PERIOD)

    if os.getppid() != parent_pid:
        os.kill(os.getpid(), kill)
    threading.Thread(target=watch, name="hdrcl-parent-watchdog", daemon=True).start()


@contextlib.contextmanager
def cancel_signals(install: bool = True) -> Iterator[None]:
    """Turn SIGTERM and SIGINT into :class:`Cancelled` in the main thread.

    Parameters
    ----------
    install : bool
        False leaves the handlers alone (an embedding application's, or Python's
        default that raises ``KeyboardInterrupt``); :func:`hdrcl.shoot.batch.run.run_batch`
        installs them only when asked to (the CLI does). In another thread nothing is
        installed either. The previous handlers are restored on exit.
    """
    if not install or threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        # Further signals while cleaning up are ignored: one cancel is enough.
        for s in (signal.SIGTERM, signal.SIGINT):
            with contextlib.suppress(ValueError, OSError):
                signal.signal(s, signal.SIG_IGN)
        raise Cancelled(signum)

    old = {}
    for s in (signal.SIGTERM, signal.SIGINT):
        try:
            old[s] = signal.signal(s, handler)
        except (ValueError, OSError):
            pass
    try:
        yield
    finally:
        for s, h in old.items():
            with contextlib.suppress(ValueError, OSError):
                signal.signal(s, h)
