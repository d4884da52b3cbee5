"""Options shared by several commands (defined once, used everywhere)."""
from __future__ import annotations

import click

from ..response import DEFAULT_SMOOTHNESS
from ..weights import WEIGHTS


def _times(ctx, param, value):
    if value is None:
        return None
    from ..metadata import parse_times

    try:
        return parse_times(value)
    except Exception as exc:  # UsageError carries the message
        raise click.BadParameter(str(exc)) from None


def _seconds(ctx, param, value):
    if value is None:
        return None
    from ..metadata import parse_times

    try:
        vals = parse_times(value)
    except Exception as exc:
        raise click.BadParameter(str(exc)) from None
    if len(vals) != 1:
        raise click.BadParameter(f"one exposure time expected, got '{value}'")
    return vals[0]


def exposure_options(f):
    f = click.option("--ignore-color", metavar="R,G,B",
                     help="Treat pixels of exactly this colour (8-bit units) as invalid, e.g. 0,0,255.")(f)
    f = click.option("--times-file", type=click.Path(dir_okay=False),
                     help="Exposure list: HDRShop columns (file, seconds, 1/shutter, f-stop, gain dB, ND) "
                          "or 'file seconds' lines.")(f)
    f = click.option("--times", callback=_times, metavar="T1,T2,...",
                     help="Exposure times in seconds, one per image, e.g. 1/250,1/60,1/15 "
                          "(overrides --times-file and EXIF).")(f)
    return f


def solve_options(f):
    f = click.option("--seed", type=int, default=0, show_default=True, help="Seed of the sample choice.")(f)
    f = click.option("--smoothness", type=float, default=None,
                     help="Smoothness lambda of the response solve [default: "
                          + ", ".join(f"{v:g} with --weight {k}" for k, v in DEFAULT_SMOOTHNESS.items()) + "].")(f)
    f = click.option("--samples", type=click.IntRange(min=1), default=None,
                     help="Calibration pixels [default: enough for the bit depth, at least 1000].")(f)
    return f


def weight_option(f):
    return click.option("--weight", type=click.Choice(WEIGHTS), default="hat", show_default=True,
                        help="Weighting of code values: the paper's hat, or a smoother gaussian.")(f)


def device_option(f):
    return click.option("--device", default=None, metavar="ID|NAME",
                        help="OpenCL device: 'P:D' from 'hdrcl devices', or part of its name "
                             "[default: PYOPENCL_CTX, else the first GPU, else the first device].")(f)


def output_options(f):
    f = click.option("--compression", default="zip", show_default=True,
                     help="EXR compression: none, zip, zips, piz, pxr24, b44, b44a, dwaa, dwab (dwaa:45 sets a level).")(f)
    f = click.option("--dtype", type=click.Choice(["half", "float"]), default="half", show_default=True,
                     help="EXR sample type.")(f)
    return f


seconds_callback = _seconds
