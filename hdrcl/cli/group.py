"""The ``hdrcl`` command group: logging set-up and the one-line error contract.

Every failure, click's own usage errors included, ends as one line on stderr,
``hdrcl: error: SUBJECT: problem`` (SUBJECT is the file or the option at fault), with
the exit code of its class: 1 processing failed, 2 usage, 3 unreadable or inconsistent
input, 130 interrupted, 143 terminated (SIGTERM: the output being written, a hidden
temporary file, is removed first). ``--debug`` (before or after the command) shows tracebacks.
``-q``/``-v``/``--debug`` are accepted before and after the command's name.
"""
from __future__ import annotations

import contextlib
import errno
import importlib
import logging
import os
import re
import signal
import sys
import threading
import warnings

import click

from hdrcl.errors import HdrclError, HdrclWarning, disable_warnings_bridge
from hdrcl.version import __version__

_GLOBAL_FLAGS = ("-q", "--quiet", "--debug")
_state = {"verbose": 0, "quiet": False, "debug": False}


def one_line(text) -> str:
    """``text`` on one line, nothing cut: a line break (a file name may hold one) is
    written as ``\\n``, other control characters as ``\\xNN``."""
    text = str(text).strip().replace("\r\n", "\n")
    return "".join(ch if ch.isprintable() or ch == "\t" else
                   {"\n": "\\n", "\r": "\\r"}.get(ch, f"\\x{ord(ch):02x}") for ch in text)


class _OneLine(logging.Formatter):
    def format(self, record):
        return f"hdrcl: {record.levelname.lower()}: {one_line(record.getMessage())}"


def _setup_logging() -> None:
    verbose, quiet = _state["verbose"], _state["quiet"]
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    disable_warnings_bridge()  # the line below is the one message; the API bridge stays off
    root = logging.getLogger("hdrcl")
    root.handlers[:] = []
    h = logging.StreamHandler(sys.stderr)
    h.setFormatter(_OneLine())
    root.addHandler(h)
    root.setLevel(level)
    root.propagate = False
    # The library also raises its warnings through the warnings module (for API users);
    # on the command line the log line above is the one message.
    warnings.simplefilter("ignore", HdrclWarning)


def quiet() -> bool:
    """True when ``-q`` was given (before or after the command)."""
    return bool(_state["quiet"])


def say(message: str = "", **kwargs) -> None:
    """Print a summary line on stdout unless ``-q`` was given."""
    if not _state["quiet"]:
        click.echo(message, **kwargs)


def _flag_callback(ctx, param, value):
    if param.name == "verbose":
        _state["verbose"] += int(value or 0)
    elif value:
        _state[param.name] = True
    _setup_logging()
    return value


def common_options():
    """``-v``, ``-q`` and ``--debug`` as parameters (of the group and of every command)."""
    return [
        click.Option(["-v", "--verbose"], count=True, expose_value=False, callback=_flag_callback,
                     help="More messages (-vv for debugging detail)."),
        click.Option(["-q", "--quiet"], is_flag=True, expose_value=False, callback=_flag_callback,
                     help="Only errors: no summary lines."),
        click.Option(["--debug"], is_flag=True, expose_value=False, callback=_flag_callback,
                     help="Show tracebacks instead of one-line errors."),
    ]


class HdrclCommand(click.Command):
    """A command that also takes ``-v``/``-q``/``--debug`` after its name."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.params.extend(common_options())


_TEMP_NAME = re.compile(r"^\.(?P<stem>.+)\.tmp-[0-9a-f]{8}(?P<ext>\.[^.]*)?$|^\.(?P<name>.+)\.[A-Za-z0-9_]{8}\.tmp$")


def public_name(path) -> str:
    """The file a hidden temporary name (``.out.tmp-1a2b3c4d.exr``) stands for."""
    path = os.fspath(path)
    folder, base = os.path.split(path)
    m = _TEMP_NAME.match(base)
    if not m:
        return path
    real = m.group("name") or (m.group("stem") + (m.group("ext") or ""))
    return os.path.join(folder, real)


def _os_error_message(exc: OSError) -> str:
    what = exc.strerror or str(exc)
    if exc.filename is not None:
        return f"{public_name(exc.filename)}: {what}"
    if exc.errno == errno.ENOSPC:
        return "no space left on the output device"
    return what


def _param_name(param) -> str:
    if isinstance(param, click.Option):
        return "/".join(param.opts)
    return param.human_readable_name


def _usage_message(exc: click.UsageError) -> str:
    """click's usage errors as ``SUBJECT: problem`` (no 'Usage:' or 'Try' lines)."""
    param = getattr(exc, "param", None)
    if isinstance(exc, click.MissingParameter) and param is not None:
        return f"{_param_name(param)}: missing (see '{_cmd(exc)} --help')"
    if isinstance(exc, click.BadParameter) and param is not None:
        return f"{_param_name(param)}: {' '.join(str(exc.message).split())}"
    if isinstance(exc, click.NoSuchOption):
        return f"{exc.option_name}: no such option of '{_cmd(exc)}' (see '{_cmd(exc)} --help')"
    msg = " ".join(exc.format_message().split())
    if isinstance(exc, click.BadOptionUsage):
        if "requires an argument" in msg:
            return f"{exc.option_name}: needs a value (see '{_cmd(exc)} --help')"
        return f"{exc.option_name}: {msg[:1].lower() + msg[1:]}"
    m = re.match(r"No such command '(.+?)'\.?\s*(.*)$", msg)
    if m:
        hint = m.group(2).rstrip("?").strip()
        hint = f"; {hint[:1].lower() + hint[1:]}?" if hint else f" (see '{_cmd(exc)} --help')"
        return f"{m.group(1)}: no such command{hint}"
    return f"{_cmd(exc)}: {msg[:1].lower() + msg[1:] if msg else 'usage error'}"


def _strip_quotes(s: str) -> str:
    return s.replace("'", "").replace('"', "")


def _cmd(exc) -> str:
    ctx = getattr(exc, "ctx", None)
    return ctx.command_path if ctx is not None else "hdrcl"


def _first_line(text: str) -> str:
    lines = [ln for ln in str(text).splitlines() if ln.strip()]
    return lines[0].strip() if lines else ""


def _fail(message: str, code: int, whole: bool = False):
    """The one error line. ``whole``: hdrcl's own messages are one line by construction,
    so a line break in them is part of a file name and is shown escaped, not cut; other
    exceptions' text is cut to its first line."""
    click.echo(f"hdrcl: error: {one_line(message) if whole else _first_line(message)}", err=True)
    sys.exit(code)


class Terminated(SystemExit):
    """SIGTERM reached the command line (exit 143). A SystemExit, so ``except Exception``
    blocks let it pass while ``atomic_output`` removes its temporary file on the way out."""

    def __init__(self, signum: int = signal.SIGTERM):
        super().__init__(128 + int(signum))


def _terminate(signum, frame):
    with contextlib.suppress(ValueError, OSError):  # one SIGTERM is enough: ignore more while cleaning up
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise Terminated(signum)


@contextlib.contextmanager
def _sigterm_exits(exiting: bool = False):
    """While a command runs (CLI process, main thread only): SIGTERM raises
    :class:`Terminated`; the previous handler is restored afterwards. ``batch`` installs
    its own handler (it cancels its workers) and puts this one back when done.

    ``exiting`` (the process is the command line itself, about to exit): once the
    command has returned, its work is committed, so a SIGTERM while the interpreter shuts
    down is ignored and the command's own exit code stands (never a silent 143)."""
    old = None
    if threading.current_thread() is threading.main_thread():
        with contextlib.suppress(ValueError, OSError):
            old = signal.signal(signal.SIGTERM, _terminate)
    try:
        yield
    finally:
        if old is not None:
            with contextlib.suppress(ValueError, OSError):
                signal.signal(signal.SIGTERM, signal.SIG_IGN if exiting else old)


#: Each command and the module that defines it, imported when the command runs (or
#: ``--help`` lists them): ``hdrcl --version`` loads none of them, ``hdrcl merge`` only
#: :mod:`hdrcl.cli.core`, so start-up pays for what the command uses.
COMMAND_MODULES = {
    "devices": "hdrcl.cli.core",
    "calibrate": "hdrcl.cli.core",
    "merge": "hdrcl.cli.core",
    "expose": "hdrcl.cli.core",
    "demo": "hdrcl.cli.core",
    "tonemap": "hdrcl.cli.output",
    "falsecolor": "hdrcl.cli.falsecolor",
    "fuse": "hdrcl.cli.fuse",
    "glare": "hdrcl.cli.glare",
    "calibrate-luminance": "hdrcl.cli.glare",
    "calibrate-luminance": "hdrcl.cli.glare",
    "scan": "hdrcl.cli.shoot",
    "batch": "hdrcl.cli.shoot",
    "sample-shoot": "hdrcl.cli.shoot",
}


class HdrclGroup(click.Group):
    """Runs a command and turns every failure into one line and an exit code.

    Commands are registered by importing their module (:data:`COMMAND_MODULES`), which
    happens the first time one of its commands is asked for.
    """

    command_class = HdrclCommand

    def list_commands(self, ctx):
        return sorted(set(super().list_commands(ctx)) | set(COMMAND_MODULES))

    def get_command(self, ctx, cmd_name):
        if cmd_name not in self.commands and cmd_name in COMMAND_MODULES:
            importlib.import_module(COMMAND_MODULES[cmd_name])  # registers its commands on main
        return super().get_command(ctx, cmd_name)

    def load_all(self) -> "HdrclGroup":
        """Import every command module (for code that reads :attr:`commands` itself)."""
        for mod in sorted(set(COMMAND_MODULES.values())):
            importlib.import_module(mod)
        return self

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        exiting = args is None  # the process is the command line (not a caller's CliRunner)
        if args is None:
            args = sys.argv[1:]
        args = list(args)
        head = args[:args.index("--")] if "--" in args else args
        _state.update(verbose=0, quiet=False, debug="--debug" in head)
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        try:
            with _sigterm_exits(exiting):
                rv = super().main(args, prog_name or "hdrcl", complete_var, standalone_mode=False, **extra)
        except Terminated as exc:
            click.echo("hdrcl: terminated", err=True)
            sys.exit(exc.code)
        except Exception as exc:  # noqa: BLE001 - the one place that turns failures into lines
            if _state["debug"] and not isinstance(exc, click.exceptions.Exit):
                raise
            self._report(exc)
            return  # unreachable: _report exits
        except KeyboardInterrupt:
            click.echo("hdrcl: interrupted", err=True)
            sys.exit(130)
        sys.exit(rv if isinstance(rv, int) else 0)

    @staticmethod
    def _report(exc: BaseException) -> None:
        no_args = getattr(click.exceptions, "NoArgsIsHelpError", ())
        if no_args and isinstance(exc, no_args):
            exc.show()
            sys.exit(exc.exit_code)
        if isinstance(exc, HdrclError):
            _fail(str(exc) or type(exc).__name__, exc.exit_code, whole=True)
        if isinstance(exc, click.UsageError):
            _fail(_usage_message(exc), 2, whole=True)
        if isinstance(exc, click.exceptions.Abort):
            click.echo("hdrcl: interrupted", err=True)
            sys.exit(130)
        if isinstance(exc, click.ClickException):
            _fail(exc.format_message(), exc.exit_code)
        if isinstance(exc, OSError):
            if exc.errno == errno.EPIPE:  # stdout closed by a pager or head: not an error
                sys.exit(1)
            _fail(_os_error_message(exc), 1)
        if isinstance(exc, MemoryError):
            _fail("out of memory (try a smaller HDRCL_MEMORY_MB or fewer --jobs)", 1)
        first = _first_line(str(exc))
        click.echo(f"hdrcl: internal error: {type(exc).__name__}: {first} (run with --debug for details)",
                   err=True)
        sys.exit(1)


class _MaxPixels(click.ParamType):
    """``--max-pixels``, checked by the shared option table (imported only when given)."""

    name = "integer"

    def convert(self, value, param, ctx):
        from hdrcl.core.params import check

        return check("max_pixels", value)


@click.group(cls=HdrclGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="hdrcl")  # not package_name: importlib.metadata costs 30 ms
@click.option("--max-pixels", type=_MaxPixels(), default=None, metavar="N",
              help="Refuse frames of more than N pixels, checked before decoding "
                   "[default: HDRCL_MAX_PIXELS, else 1000000000].")
@click.pass_context
def main(ctx, max_pixels):
    """Merge bracketed photographs into HDR radiance maps (Debevec & Malik 1997).

    Fusion and virtual exposures run as OpenCL kernels on the first GPU, else on the
    first CPU driver that builds them (Intel's CPU runtime, then PoCL); the response
    curve is solved on the CPU.

    \b
    Errors: one line on stderr, 'hdrcl: error: FILE: problem'.
    Exit codes: 0 success, 1 processing failed, 2 usage error, 3 unreadable or
    inconsistent input, 130 interrupted, 143 terminated.
    Environment: PYOPENCL_CTX picks the device (or --device); HDRCL_OPENCL=0 uses the
    slower NumPy path; HDRCL_MAX_PIXELS bounds the pixels of one frame (--max-pixels);
    HDRCL_MEMORY_MB the decoded frames held in memory. A variable set to a value it
    does not take is a usage error (exit 2); docs/cli.md lists them all.
    """
    ctx.ensure_object(dict)
    from hdrcl.env import check_all

    check_all()  # every HDRCL_* variable, one rule: a value it does not take is exit 2 (docs/cli.md)
    if max_pixels is not None:  # the environment carries it to batch workers too
        os.environ["HDRCL_MAX_PIXELS"] = str(max_pixels)
    _setup_logging()


main.params.extend(common_options())
