"""SIGTERM from the command's first line of Python, before click is imported.

The command's own handler (:func:`hdrcl.cli.group._sigterm_exits`) is installed when
the group starts parsing, some 20-40 ms after the interpreter began (``site``, click and
the group's imports come first). A SIGTERM in that window used to meet Python's default
action: the process died with no line on stderr (a shell shows 143, the contract's code
for "terminated", with nothing said). :func:`take_sigterm`, called by
:mod:`hdrcl.cli` before anything else is imported, closes that window: nothing has been
written yet, so the handler only says ``hdrcl: terminated`` and exits 143. Only the
interpreter's own start-up (before any hdrcl code runs) remains outside any handler.

It is installed only when this process *is* the ``hdrcl`` command (the console script
or ``python -m hdrcl``) and SIGTERM still has its default action: a program or a test
that imports :mod:`hdrcl.cli` keeps its own handling.
"""
from __future__ import annotations

import os
import signal
import sys
import threading

#: The line a terminated command prints (README "Errors and exit codes").
TERMINATED_LINE = "hdrcl: terminated"


def _early(signum, frame):
    try:  # one SIGTERM is enough
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    except (ValueError, OSError):
        pass
    try:  # no click yet: the line straight to the descriptor
        os.write(2, (TERMINATED_LINE + "\n").encode())
    except OSError:
        pass
    raise SystemExit(128 + int(signum))


def is_command() -> bool:
    """True when this process runs the ``hdrcl`` command (console script or ``-m``)."""
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    if spec is not None and getattr(spec, "name", None) in ("hdrcl.__main__", "hdrcl"):
        return True
    name = os.path.basename(getattr(main, "__file__", None) or "")
    return name in ("hdrcl", "hdrcl.exe", "hdrcl-script.py")


def take_sigterm() -> bool:
    """Install the start-up SIGTERM handler (see the module docstring); True if installed."""
    if threading.current_thread() is not threading.main_thread() or not is_command():
        return False
    try:
        if signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
            return False  # an embedding program's handler, or SIGTERM ignored: theirs
        signal.signal(signal.SIGTERM, _early)
    except (ValueError, OSError, AttributeError):
        return False
    return True
