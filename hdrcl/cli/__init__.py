"""The ``hdrcl`` command line: click commands that parse options, call the library
(:mod:`hdrcl.api` and the layers below it) and print.

Errors are one line on stderr (``hdrcl: error: ...``) with the exit code of their
class: 1 processing failed, 2 usage, 3 unreadable input. ``--debug`` shows tracebacks.
"""
from hdrcl.cli.early import take_sigterm

take_sigterm()  # the command says "terminated" from here on, not only once click is loaded

from hdrcl.cli.group import main  # noqa: E402  # the commands' modules load when a command is used

__all__ = ["main"]
