"""Exceptions with the exit code the command line returns for them.

Every error a user can cause is one of these, with a message that names the file and
the problem on one line. The CLI prints ``hdrcl: error: <message>`` and exits with
``exit_code``; library users catch :class:`HdrclError`.

Warnings: modules log them (``logging.getLogger(__name__).warning``); for library users
:class:`WarningsBridge` on the ``hdrcl`` logger also raises each one through the
:mod:`warnings` module as an :class:`HdrclWarning`, so ``warnings.catch_warnings``,
``-W error::hdrcl.HdrclWarning`` and pytest's warning capture all see them. The command
line replaces the bridge by its one-line stderr handler.
"""
import logging
import warnings


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


class HdrclWarning(UserWarning):
    """Category of hdrcl's warnings (a doubtful input, a value clamped, a frame flagged)."""


class WarningsBridge(logging.Handler):
    """Logging handler that re-raises ``hdrcl`` warning records as :class:`HdrclWarning`.

    Installed on the ``hdrcl`` logger when the package is imported. Records keep
    propagating to the root logger, so an application's logging set-up sees them too;
    with the bridge present, logging's bare last-resort printing is not used.
    """

    def __init__(self):
        super().__init__(level=logging.WARNING)

    def emit(self, record: logging.LogRecord) -> None:  # exceptions (warnings as errors) propagate
        warnings.warn_explicit(record.getMessage(), HdrclWarning, record.pathname, record.lineno,
                               module=record.module)


def install_warnings_bridge() -> None:
    """Add one :class:`WarningsBridge` to the ``hdrcl`` logger (idempotent)."""
    log = logging.getLogger("hdrcl")
    if not any(isinstance(h, WarningsBridge) for h in log.handlers):
        log.addHandler(WarningsBridge())


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
