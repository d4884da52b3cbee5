"""Options shared by several commands (defined once, used everywhere)."""
from __future__ import annotations

import click

from hdrcl.core.response import DEFAULT_SMOOTHNESS
from hdrcl.core.weights import WEIGHTS


def _times(ctx, param, value):
    if value is None:
        return None
    from hdrcl.io.metadata import parse_times

    try:
        return parse_times(value)
    except Exception as exc:  # UsageError carries the message
        raise click.BadParameter(str(exc)) from None


def _seconds(ctx, param, value):
    if value is None:
        return None
    from hdrcl.io.metadata import parse_times

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


def grouping_options(f):
    """How a folder is grouped into bracket sets (``scan``, and ``batch`` given a folder)."""
    f = click.option("--gap", type=click.FloatRange(min=0), default=None, metavar="SECONDS",
                     help="Largest end-to-start gap within a set [default: 8 s, plus the exposure time "
                          "after exposures of 1 s or more].")(f)
    f = click.option("--frames-per-set", type=click.IntRange(min=1), default=None, metavar="N",
                     help="Cut the frames, in capture order, into sets of exactly N.")(f)
    f = click.option("-r", "--recursive", is_flag=True, help="Include subfolders.")(f)
    return f


def batch_merge_options(f):
    """The options of ``merge`` that ``batch`` applies to every set."""
    f = click.option("--times-file", type=click.Path(dir_okay=False),
                     help="Exposure list for frames without EXIF: HDRShop columns or 'file seconds' lines "
                          "[default: image_list.txt or times.txt beside the frames, when there is one].")(f)
    f = click.option("--fit-exposures", type=click.Choice(["auto", "on", "off"]), default="off",
                     show_default=True,
                     help="Estimate each frame's exposure from the pixels: auto uses the fitted value only "
                          "where the metadata is clearly wrong, on always, off never.")(f)
    f = click.option("--neutral", metavar="X,Y,W,H",
                     help="White balance every set: make this patch (pixels) neutral grey.")(f)
    f = click.option("--crop", is_flag=True, help="With --align: crop to the area every frame covers.")(f)
    f = click.option("--align", is_flag=True,
                     help="Align hand-held frames by translation (median threshold bitmaps) before merging.")(f)
    return f


def _ignore_color(ctx, param, value):
    if value is None:
        return None
    parts = [p.strip() for p in str(value).split(",")]
    try:
        vals = tuple(int(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 3 or not all(0 <= v <= 255 for v in vals):
        raise click.BadParameter(f"expected R,G,B with values 0-255, not '{value}'")
    return vals


def ignore_color_option(f):
    """``--ignore-color`` alone (commands without --times), parsed to an (R, G, B) tuple."""
    return click.option("--ignore-color", callback=_ignore_color, metavar="R,G,B",
                        help="Treat pixels of exactly this colour (8-bit units) as invalid, e.g. 0,0,255.")(f)


def fit_options(f):
    f = click.option("--exposure-tolerance", type=click.FloatRange(min=0.0), default=None, metavar="STOPS",
                     help="Report frames whose metadata the pixels contradict by more than this [default: 0.5].")(f)
    f = click.option("--fit-exposures", type=click.Choice(["auto", "on", "off"]), default="auto",
                     show_default=True,
                     help="Estimate each frame's exposure from the pixels: auto uses the fitted value only "
                          "where the metadata is clearly wrong, on always, off never.")(f)
    return f


def deghost_option(f):
    """``--deghost`` (the flag alone; ``merge`` adds ``--ghost-mask`` for its one output)."""
    return click.option("--deghost", is_flag=True,
                        help="Take pixels where the frames disagree (moving objects) from the middle "
                             "exposure alone.")(f)


def colorspace_option(f):
    """``--colorspace`` of radiance outputs (``merge``, ``batch``)."""
    return click.option("--colorspace", type=click.Choice(["rec709", "acescg"], case_sensitive=False),
                        default="rec709", show_default=True,
                        help="Colour space of the radiance file: linear Rec.709/sRGB primaries, or ACEScg "
                             "(AP1, for VFX pipelines; EXR or HDR), converted with OpenImageIO's colour "
                             "management and tagged.")(f)


def given(name: str):
    """The value of option ``name`` if the user gave it on the command line, else None."""
    ctx = click.get_current_context()
    source = ctx.get_parameter_source(name)
    if source is None or source.name in ("DEFAULT", "DEFAULT_MAP"):
        return None
    return ctx.params.get(name)


def warn_inapplicable(output: str, **options) -> None:
    """Warn (once each) about explicitly given options the output type ignores."""
    import logging

    from hdrcl.io.outmeta import inapplicable_options

    for msg in inapplicable_options(output, **{k: given(k) for k in options}):
        logging.getLogger("hdrcl.cli").warning("%s", msg)
