"""Exceptions with the exit code the command line returns for them.

Every error a user can cause is one of these, with a message that names the file and
the problem on one line. The CLI prints ``hdrcl: error: <message>`` and exits with
``exit_code``; library users catch :class:`HdrclError`.
"""


class HdrclError(Exception):
    """Base class of hdrcl's user-facing errors."""

    exit_code = 1


class ProcessingError(HdrclError):
    """The input was read but the work could not be done (exit code 1)."""

    exit_code = 1


class UsageError(HdrclError):
    """Options or arguments that contradict each other or are malformed (exit code 2)."""

    exit_code = 2


class InputError(HdrclError):
    """An input file is missing, unreadable, truncated or inconsistent (exit code 3)."""

    exit_code = 3


def check_readable(name: str) -> None:
    """Raise :class:`InputError` unless ``name`` is an existing, readable, non-empty file."""
    import os

    if not os.path.exists(name):
        raise InputError(f"{name}: no such file")
    if os.path.isdir(name):
        raise InputError(f"{name}: is a folder, not an image")
    if not os.access(name, os.R_OK):
        raise InputError(f"{name}: permission denied")
    if os.path.getsize(name) == 0:
        raise InputError(f"{name}: empty file")
