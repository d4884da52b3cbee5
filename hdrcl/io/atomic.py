"""Atomic output: a hidden temporary file beside the target, fsync, then rename, so no
half-written file ever appears under the real name.
"""
from __future__ import annotations

import contextlib
import os
import secrets

from hdrcl.errors import UsageError


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
    stem, ext = os.path.splitext(os.path.basename(target))
    tmp = os.path.join(folder, f".{stem}.tmp-{secrets.token_hex(4)}{ext}")
    try:
        yield tmp
        _fsync(tmp)  # data on disk before the name points at it (power loss, not just kill)
        os.replace(tmp, target)
        _fsync(folder, directory=True)
    except BaseException:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        raise
