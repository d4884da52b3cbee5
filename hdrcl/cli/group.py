"""The ``hdrcl`` command group: logging set-up and the one-line error contract.

Errors are one line on stderr (``hdrcl: error: ...``) with the exit code of their
class: 1 processing failed, 2 usage, 3 unreadable input. ``--debug`` shows tracebacks.
"""
from __future__ import annotations

import logging
import os
import sys

import click

from hdrcl.errors import HdrclError


class _OneLine(logging.Formatter):
    def format(self, record):
        msg = record.getMessage().splitlines()[0] if record.getMessage() else ""
        return f"hdrcl: {record.levelname.lower()}: {msg}"


def _setup_logging(verbose: int, quiet: bool) -> None:
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    root = logging.getLogger("hdrcl")
    root.handlers[:] = []
    h = logging.StreamHandler(sys.stderr)
    h.setFormatter(_OneLine())
    root.addHandler(h)
    root.setLevel(level)
    root.propagate = False


class HdrclGroup(click.Group):
    """Turns library errors into one-line messages and exit codes."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except HdrclError as exc:
            if (ctx.obj or {}).get("debug"):
                raise
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            click.echo(f"hdrcl: error: {msg}", err=True)
            ctx.exit(exc.exit_code)
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException):
            raise
        except KeyboardInterrupt:
            click.echo("hdrcl: interrupted", err=True)
            ctx.exit(130)
        except Exception as exc:  # a bug or an environment problem: say so in one line
            if (ctx.obj or {}).get("debug"):
                raise
            first = str(exc).splitlines()[0] if str(exc) else ""
            click.echo(f"hdrcl: internal error: {type(exc).__name__}: {first} (run with --debug for details)", err=True)
            ctx.exit(1)


@click.group(cls=HdrclGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="hdrcl", prog_name="hdrcl")
@click.option("-v", "--verbose", count=True, help="More messages (-vv for debugging detail).")
@click.option("-q", "--quiet", is_flag=True, help="Only errors.")
@click.option("--debug", is_flag=True, help="Show tracebacks instead of one-line errors.")
@click.option("--max-pixels", type=click.IntRange(min=1), default=None, metavar="N",
              help="Refuse frames of more than N pixels, checked before decoding "
                   "[default: HDRCL_MAX_PIXELS, else 1000000000].")
@click.pass_context
def main(ctx, verbose, quiet, debug, max_pixels):
    """Merge bracketed photographs into HDR radiance maps (Debevec & Malik 1997).

    Fusion and virtual exposures run as OpenCL kernels (any OpenCL device; PoCL on
    CPU-only machines); the response curve is solved on the CPU.

    \b
    Exit codes: 0 success, 1 processing failed, 2 usage error, 3 unreadable input.
    Environment: PYOPENCL_CTX picks the device (or --device); HDRCL_OPENCL=0 uses the
    slower NumPy path; HDRCL_MAX_PIXELS bounds the pixels of one frame (--max-pixels).
    """
    ctx.ensure_object(dict)
    ctx.obj["debug"] = debug
    if max_pixels is not None:  # the environment carries it to batch workers too
        os.environ["HDRCL_MAX_PIXELS"] = str(max_pixels)
    _setup_logging(verbose, quiet)
