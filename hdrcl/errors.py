"""Exceptions with the exit code the command line returns for them.

Every error a user can cause is one of these, with a message that names the file and
the problem on one line. The CLI prints ``hdrcl: error: <message>`` and exits with
``exit_code``; library users catch :class:`HdrclError`.

Warnings: modules log them (``logging.getLogger(__name__).warning``); for library users
:class:`WarningsBridge` on the ``hdrcl`` logger also raises each one through the
:mod:`warnings` module as an :class:`HdrclWarning`, so ``warnings.catch_warnings``,
``-W error::hdrcl.HdrclWarning`` and pytest's warning capture all see them. The bridge is
installed on first use of the API (:func:`hdrcl.api` import, or ``hdrcl.<name>``), not
by ``import hdrcl``, which stays cheap (no :mod:`logging`). The command line replaces the
bridge by its one-line stderr handler (:func:`disable_warnings_bridge`).
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


class ParameterTypeError(UsageError, TypeError):
    """A parameter of the wrong type (a string where a list of paths belongs, a nested
    list where an array belongs). Both a :class:`UsageError` (exit code 2) and a
    :class:`TypeError`, so either ``except`` catches it; the message names the parameter."""


class HdrclWarning(UserWarning):
    """Category of hdrcl's warnings (a doubtful input, a value clamped, a frame flagged)."""


_bridge = {"auto": True}


def _bridge_class():
    """:class:`WarningsBridge`, defined on first use so that importing this module does
    not import :mod:`logging`."""
    cls = _bridge.get("class")
    if cls is None:
        import logging
        import warnings

        class WarningsBridge(logging.Handler):
            """Logging handler that re-raises ``hdrcl`` warning records as :class:`HdrclWarning`.

            Installed on the ``hdrcl`` logger on first use of the API. Records keep
            propagating to the root logger, so an application's logging set-up sees them
            too; with the bridge present, logging's bare last-resort printing is not used.
            """

            def __init__(self):
                super().__init__(level=logging.WARNING)

            def emit(self, record: logging.LogRecord) -> None:  # warnings as errors propagate
                warnings.warn_explicit(record.getMessage(), HdrclWarning, record.pathname, record.lineno,
                                       module=record.module)

        WarningsBridge.__module__ = __name__
        WarningsBridge.__qualname__ = "WarningsBridge"
        cls = _bridge["class"] = WarningsBridge
    return cls


def __getattr__(name):
    if name == "WarningsBridge":
        return _bridge_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def install_warnings_bridge() -> None:
    """Add one :class:`WarningsBridge` to the ``hdrcl`` logger (idempotent)."""
    import logging

    cls = _bridge_class()
    log = logging.getLogger("hdrcl")
    if not any(isinstance(h, cls) for h in log.handlers):
        log.addHandler(cls())


def auto_install_warnings_bridge() -> None:
    """:func:`install_warnings_bridge` on first use of the API, unless the command line
    (:func:`disable_warnings_bridge`) owns the ``hdrcl`` logger."""
    if _bridge["auto"]:
        _bridge["auto"] = False
        install_warnings_bridge()


def disable_warnings_bridge() -> None:
    """The command line prints warnings itself: remove the bridge and install none later."""
    _bridge["auto"] = False
    if "class" in _bridge:
        import logging

        log = logging.getLogger("hdrcl")
        log.handlers[:] = [h for h in log.handlers if not isinstance(h, _bridge["class"])]


def check_regular(path, what: str = "image") -> None:
    """Raise :class:`InputError` at once unless ``path`` is a regular file.

    A FIFO would block the first read for ever and ``/dev/zero`` never ends: every file a
    user names for reading (images, times files, response and manifest JSON) is checked
    here before it is opened. ``what`` names the expected kind in the folder message.
    """
    import os
    import stat

    name = os.fspath(path)
    try:
        st = os.stat(name)
    except FileNotFoundError:
        raise InputError(f"{name}: no such file") from None
    except OSError as exc:
        raise InputError(f"{name}: cannot read ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"{name}: is a folder, not {_article(what)}")
    if not stat.S_ISREG(st.st_mode):
        kind = ("a FIFO" if stat.S_ISFIFO(st.st_mode) else "a device" if stat.S_ISCHR(st.st_mode)
                or stat.S_ISBLK(st.st_mode) else "a socket" if stat.S_ISSOCK(st.st_mode) else "special")
        raise InputError(f"{name}: not a regular file ({kind})")


def _article(what: str) -> str:
    return ("an " if what[:1].lower() in "aeiou" else "a ") + what


def check_readable(name, what: str = "image") -> None:
    """Raise :class:`InputError` unless ``name`` is an existing, readable, non-empty
    regular file (:func:`check_regular`: no FIFO, device or folder)."""
    import os

    name = os.fspath(name)
    check_regular(name, what)
    if not os.access(name, os.R_OK):
        raise InputError(f"{name}: permission denied")
    if os.path.getsize(name) == 0:
        raise InputError(f"{name}: empty file")
