"""Atomic output: a hidden temporary file beside the target, fsync, then rename, so no
half-written file ever appears under the real name.
"""
from __future__ import annotations

import contextlib
import errno
import os
import secrets
from typing import Iterable, Optional

from hdrcl.errors import HdrclError, ProcessingError, UsageError


def _fsync(path: str, directory: bool = False) -> None:
    """Flush a file (or a folder's entries) to disk; best effort where unsupported."""
    try:
        fd = os.open(path, os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def temp_path(target: str, folder: str) -> str:
    """The hidden temporary name beside ``target`` (``.out.tmp-1a2b3c4d.exr``): the
    extension stays last so format detection by extension still works."""
    stem, ext = os.path.splitext(os.path.basename(target))
    return os.path.join(folder, f".{stem}.tmp-{secrets.token_hex(4)}{ext}")


@contextlib.contextmanager
def atomic_output(path):
    """Yield a temporary path beside ``path``; move it onto ``path`` on success.

    The temporary file is hidden and keeps the extension (``out.exr`` is written as
    ``.out.tmp-1a2b3c4d.exr``) so that format detection by extension still works. On
    any exception the temporary file is removed and an existing file at ``path`` is left
    untouched.

    Parameters
    ----------
    path : str or os.PathLike
        Final file name.

    Yields
    ------
    str
        The temporary file to write.

    Raises
    ------
    UsageError
        The output folder does not exist, or ``path`` is a folder.
    """
    target = os.fspath(path)
    folder = os.path.dirname(target) or "."
    if not os.path.isdir(folder):
        raise UsageError(f"output folder '{folder}' does not exist")
    if os.path.isdir(target):
        raise UsageError(f"output '{target}' is a folder")
    _check_folder_writable(target, folder)
    tmp = temp_path(target, folder)
    try:
        yield tmp
        _fsync(tmp)  # data on disk before the name points at it (power loss, not just kill)
        os.replace(tmp, target)
        _fsync(folder, directory=True)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        renamed = _renamed(exc, tmp, target)
        if renamed is None:
            raise
        raise renamed from None


def _renamed(exc: BaseException, tmp: str, target: str) -> Optional[BaseException]:
    """``exc`` reworded to name ``target`` instead of its temporary file (None: keep it)."""
    if isinstance(exc, HdrclError) and tmp in str(exc):
        return type(exc)(str(exc).replace(tmp, target))
    if isinstance(exc, OSError) and not isinstance(exc, (BlockingIOError, InterruptedError)):
        return ProcessingError(f"{target}: cannot write ({exc.strerror or exc})")
    return None


def _read_only_fs(folder: str) -> bool:
    try:
        return bool(os.statvfs(folder).f_flag & getattr(os, "ST_RDONLY", 1))
    except (OSError, AttributeError):
        return False


def _check_folder_writable(target: str, folder: str) -> None:
    if _read_only_fs(folder):
        raise UsageError(f"{target}: the output folder is on a read-only file system")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(f"{target}: no permission to write into the output folder")


def check_output(path, inputs: Iterable = (), *, what: str = "output") -> str:
    """Check, before any work, that ``path`` can be written and is none of ``inputs``.

    Parameters
    ----------
    path : str or os.PathLike
        The file to be written.
    inputs : iterable of paths
        Files the command reads; writing over one of them would destroy it.
    what : str
        What the file is, for the message.

    Returns
    -------
    str
        ``path`` as a string.

    Raises
    ------
    UsageError
        The folder is missing, read-only or not writable; ``path`` is a folder or one
        of ``inputs``.
    """
    target = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(target))
    if os.path.isdir(target):
        raise UsageError(f"{target}: is a folder; give a file name for the {what}")
    if not os.path.isdir(folder):
        raise UsageError(f"{target}: the output folder {os.path.dirname(target) or '.'} does not exist")
    _check_folder_writable(target, folder)
    for p in inputs:
        if p is None or not isinstance(p, (str, os.PathLike)):
            continue
        if _same_file(target, os.fspath(p)):
            raise UsageError(f"{target}: is also an input; refusing to overwrite it with the {what}")
    return target


def check_output_folder(path, *, what: str = "output folder") -> str:
    """Check that the folder ``path`` exists and is writable, or can be created."""
    folder = os.path.abspath(os.fspath(path))
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise UsageError(f"{os.fspath(path)}: is a file, not an {what}")
    probe = folder
    while not os.path.isdir(probe):
        parent = os.path.dirname(probe)
        if parent == probe:
            break
        probe = parent
    try:
        _check_folder_writable(os.fspath(path), probe)
    except UsageError:
        if probe == folder:
            raise UsageError(f"{os.fspath(path)}: the {what} is not writable") from None
        raise UsageError(f"{os.fspath(path)}: the {what} cannot be created in {probe} "
                         f"(not writable)") from None
    return os.fspath(path)


def _same_file(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def write_text(path, text: str, *, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically, with the permissions the umask allows.

    :func:`tempfile.mkstemp` would create the file 0600 (private to the account that
    wrote it); this creates the temporary file with mode 0666 less the umask, as
    ``open()`` does, so a manifest or response curve is readable by a render farm's
    other accounts exactly when any other file written there would be.

    Raises
    ------
    UsageError
        The folder is missing or not writable.
    ProcessingError
        Writing failed (a full disk); nothing is left at ``path`` or beside it.
    """
    staged = stage_text(path, text, encoding=encoding)
    staged.commit()


class StagedFile:
    """A complete temporary file beside its target, waiting for :meth:`commit`."""

    def __init__(self, target: str, tmp: str):
        self.target, self.tmp = target, tmp
        self.done = False

    def commit(self) -> None:
        """Rename the temporary file onto the target."""
        try:
            os.replace(self.tmp, self.target)
        except OSError as exc:
            self.discard()
            raise ProcessingError(f"{self.target}: cannot write ({exc.strerror or exc})") from None
        self.done = True
        _fsync(os.path.dirname(os.path.abspath(self.target)), directory=True)

    def discard(self) -> None:
        """Remove the temporary file (nothing appears at the target)."""
        if not self.done:
            with contextlib.suppress(OSError):
                os.remove(self.tmp)
            self.done = True


def stage_text(path, text: str, *, encoding: str = "utf-8") -> StagedFile:
    """Write ``text`` to a hidden temporary file beside ``path``; rename it with
    :meth:`StagedFile.commit` (or drop it with :meth:`StagedFile.discard`).

    Staging lets a command find a full disk or a read-only folder for a second output
    before it writes the first one.
    """
    target = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(target))
    if not os.path.isdir(folder):
        raise UsageError(f"{target}: the output folder {os.path.dirname(target) or '.'} does not exist")
    if os.path.isdir(target):
        raise UsageError(f"{target}: is a folder")
    _check_folder_writable(target, folder)
    tmp = temp_path(target, folder)
    data = text.encode(encoding)
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    except OSError as exc:
        raise ProcessingError(f"{target}: cannot write ({exc.strerror or exc})") from None
    try:
        try:
            view = memoryview(data)
            while view:
                n = os.write(fd, view)
                view = view[n:]
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        reason = "no space left on the device" if exc.errno == errno.ENOSPC else (exc.strerror or str(exc))
        raise ProcessingError(f"{target}: cannot write ({reason})") from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        raise
    return StagedFile(target, tmp)
