"""Options shared by several commands (defined once, used everywhere), and the
parameter types that check files the way the error contract wants: one line naming the
file, exit 3 for an input that cannot be read, exit 2 for an output that cannot be
written (click's own path checks print three lines and always exit 2).
"""
from __future__ import annotations

import os

import click

from hdrcl.api.support import DEFAULT_SMOOTHNESS, DEFAULT_WEIGHT, WEIGHTS


class Checked(click.ParamType):
    """An option checked by the shared table (:mod:`hdrcl.core.params`): the same rule and
    words as the library's parameter, one line and exit 2, before any file is decoded."""

    def __init__(self, option: str):
        from hdrcl.core.params import TABLE

        self.option = option
        kind = TABLE[option].kind
        self.name = {"int": "integer", "float": "float"}.get(kind, "text")

    def convert(self, value, param, ctx):
        from hdrcl.core.params import check

        return check(self.option, value)


class InputFile(click.ParamType):
    """A file the command reads: missing, a folder or unreadable is an input error (3)."""

    name = "file"

    def __init__(self, what: str = "file"):
        self.what = what

    def convert(self, value, param, ctx):
        from hdrcl.errors import InputError

        path = os.fspath(value)
        if not os.path.lexists(path):
            raise InputError(f"{path}: no such file")
        if os.path.isdir(path):
            if self.what == "image":
                raise InputError(f"{path}: is a folder, not an image; give its images with a glob "
                                 f"({os.path.join(path, '*')}) or run 'hdrcl batch {path} -o OUT_DIR'")
            raise InputError(f"{path}: is a folder, not a {self.what}")
        if not os.path.exists(path):
            raise InputError(f"{path}: broken symbolic link")
        if not os.access(path, os.R_OK):
            raise InputError(f"{path}: permission denied")
        return path


class InputPath(InputFile):
    """A file or a folder the command reads (``scan``/``batch`` sources)."""

    name = "path"

    def convert(self, value, param, ctx):
        from hdrcl.errors import InputError

        path = os.fspath(value)
        if os.path.isdir(path):
            if not os.access(path, os.R_OK | os.X_OK):
                raise InputError(f"{path}: permission denied")
            return path
        if not os.path.lexists(path):
            raise InputError(f"{path}: no such file or folder")
        return super().convert(value, param, ctx)


def sets_callback(ctx, param, value):
    """``--sets``: checked before any work; a leading minus is refused, not read as 0-N."""
    if value is None:
        return None
    from hdrcl.errors import UsageError
    from hdrcl.api.batch import parse_sets

    for item in str(value).split(","):
        if item.strip().startswith("-"):
            raise UsageError(f"--sets: '{item.strip()}' reads as a negative index; indices start at 0 "
                             f"(write 0{item.strip()} for the sets up to {item.strip()[1:] or 'N'})")
    parse_sets(value)
    return value


class OutputFile(click.ParamType):
    """A file the command writes, with the extensions it may have: usage error (2) when
    it is a folder, its folder is missing or read-only, or the extension is wrong."""

    name = "file"

    def __init__(self, extensions=None, what: str = "output", check_folder: bool = True):
        self.extensions, self.what, self.check_folder = extensions, what, check_folder

    def convert(self, value, param, ctx):
        from hdrcl.errors import UsageError
        from hdrcl.api.support import check_output

        path = os.fspath(value)
        ext = os.path.splitext(path)[1].lower()
        if self.extensions and ext not in self.extensions:
            raise UsageError(f"{path}: a {self.what} is written as {', '.join(self.extensions)}, "
                             f"not '{ext or 'no extension'}'")
        if not self.check_folder:  # the command checks it (e.g. a folder it creates first)
            if os.path.isdir(path):
                raise UsageError(f"{path}: is a folder; give a file name for the {self.what}")
            return path
        return check_output(path, what=self.what)


class OutputFolder(click.ParamType):
    """A folder the command creates or writes into: usage error (2) when it cannot."""

    name = "folder"

    def __init__(self, what: str = "output folder"):
        self.what = what

    def convert(self, value, param, ctx):
        from hdrcl.api.support import check_output_folder

        return check_output_folder(os.fspath(value), what=self.what)


def _times(ctx, param, value):
    if value is None:
        return None
    from hdrcl.api.support import parse_times

    return parse_times(value, "--times")  # UsageError: one line, exit 2


def _seconds(ctx, param, value):
    if value is None:
        return None
    from hdrcl.core.params import check

    return check("time", value)


def check_inputs_not_outputs(inputs, *outputs) -> None:
    """Refuse (usage error) an output that is one of the inputs: it would be destroyed."""
    from hdrcl.api.support import check_output

    for out in outputs:
        if out is not None:
            check_output(out, [p for p in inputs if p is not None])


def exposure_options(f):
    f = click.option("--ignore-color", type=Checked("ignore_color"), metavar="R,G,B",
                     help="Treat pixels of exactly this colour (8-bit units) as invalid, e.g. 0,0,255.")(f)
    f = click.option("--times-file", type=InputFile("times file"),
                     help="Exposure list: HDRShop columns (file, seconds, 1/shutter, f-stop, gain dB, ND) "
                          "or 'file seconds' lines; it wins over EXIF [default: for frames without EXIF "
                          "exposure time, image_list.txt or times.txt beside them].")(f)
    f = click.option("--times", callback=_times, metavar="T1,T2,...",
                     help="Exposure times in seconds, one per image, e.g. 1/250,1/60,1/15 "
                          "(overrides --times-file and EXIF).")(f)
    return f


def solve_options(f):
    f = click.option("--seed", type=Checked("seed"), default=0, show_default=True,
                     help="Seed of the sample choice (0 or more).")(f)
    f = click.option("--smoothness", type=Checked("smoothness"), default=None,
                     help="Smoothness lambda of the response solve [default: "
                          + ", ".join(f"{v:g} with --weight {k}" for k, v in DEFAULT_SMOOTHNESS.items())
                          + "; 0.001 to 1e6].")(f)
    f = click.option("--samples", type=Checked("samples"), default=None,
                     help="Calibration pixels [default: enough for the bit depth, at least 1000].")(f)
    return f


def weight_option(f):
    return click.option("--weight", type=click.Choice(WEIGHTS), default=DEFAULT_WEIGHT, show_default=True,
                        help="Weighting of code values: gaussian (measured best on real data), "
                             "or the paper's hat.")(f)


def device_option(f):
    return click.option("--device", default=None, metavar="ID|NAME",
                        help="OpenCL device: 'P:D' from 'hdrcl devices', or part of its name "
                             "[default: PYOPENCL_CTX, else the first GPU, else the first CPU driver that "
                             "builds the kernels: Intel's CPU runtime, then PoCL (HDRCL_CPU_DRIVERS "
                             "changes the order)].")(f)


def output_options(f):
    f = click.option("--compression", type=Checked("compression"), default="piz", show_default=True,
                     help="EXR compression: none, zip, zips, piz, pxr24, b44, b44a, dwaa, dwab (dwaa:45 sets a level).")(f)
    f = click.option("--dtype", type=click.Choice(["auto", "half", "float"]), default="auto", show_default=True,
                     help="EXR sample type. auto: half when every merged value fits half floats "
                          "(measured on the data), else float. half: half always, rescaled by a power of two "
                          "recorded as hdrcl:halfScale when needed (other tools then read it scaled). "
                          "float: float.")(f)
    return f


def reference_exposure_option(f):
    """What 1.0 means in the output (``merge`` and ``batch``)."""
    return click.option("--reference-exposure", type=Checked("reference_exposure"), default=None, metavar="SECONDS",
                        help="A value of 1.0 in the output is what a frame of this exposure (at the first "
                             "frame's f-number and ISO; batch: the shoot's) records as white [default: the "
                             "power of two nearest the middle exposure; batch: one per camera for the "
                             "whole shoot]. Recorded as expTime / EXPOSURE=.")(f)


seconds_callback = _seconds


def grouping_options(f):
    """How a folder is grouped into bracket sets (``scan``, and ``batch`` given a folder)."""
    f = click.option("--gap", type=Checked("gap"), default=None, metavar="SECONDS",
                     help="Largest end-to-start gap within a set [default: 8 s, plus the exposure time "
                          "after exposures of 1 s or more].")(f)
    f = click.option("--frames-per-set", type=Checked("frames_per_set"), default=None, metavar="N",
                     help="Cut the frames, in capture order, into sets of exactly N.")(f)
    f = click.option("-r", "--recursive", is_flag=True,
                     help="Include subfolders [default: only when the folder itself holds no photographs, "
                          "e.g. one subfolder per set; said in one line].")(f)
    return f


def batch_merge_options(f):
    """The options of ``merge`` that ``batch`` applies to every set."""
    f = click.option("--times-file", type=InputFile("times file"),
                     help="Exposure list: HDRShop columns or 'file seconds' lines; it wins over EXIF for the "
                          "frames it lists [default: for frames without EXIF exposure time, image_list.txt or "
                          "times.txt beside them].")(f)
    f = click.option("--fit-exposures", type=click.Choice(["auto", "on", "off"]), default="auto",
                     show_default=True,
                     help="Measure each frame's exposure from the pixels through the set's (pooled or given) "
                          "response: auto uses the measured value only where the metadata is clearly wrong "
                          "(and says so per frame), on always, off never (as merge).")(f)
    f = click.option("--exposure-tolerance", type=Checked("exposure_tolerance"), default=None, metavar="STOPS",
                     help="Report frames whose metadata the pixels contradict by more than this [default: 0.5], "
                          "as merge.")(f)
    f = click.option("--neutral", type=Checked("neutral"), metavar="X,Y,W,H",
                     help="White balance every set: make this patch (pixels) neutral grey.")(f)
    f = click.option("--crop", is_flag=True, help="With --align: crop to the area every frame covers.")(f)
    f = align_model_option(f)
    f = click.option("--align", is_flag=True, help=ALIGN_HELP)(f)
    return f


ALIGN_HELP = ("Align hand-held frames to the middle exposure (shift, rotation, scale; see --align-model) "
              "before merging; a frame that cannot be aligned fails the merge.")


def align_model_option(f):
    """``--align-model``: the motion model of ``--align`` (hdrcl.core.align.mtb)."""
    return click.option("--align-model", type=click.Choice(["auto", "shift", "similarity", "homography"]),
                        default="auto", show_default=True,
                        help="With --align: the motion model; auto picks the simplest one the residuals "
                             "allow (shift, similarity, homography for wide lenses).")(f)


def output_format_option(f):
    """``--format``: the file type of batch outputs."""
    return click.option("--format", "output_format", type=click.Choice(["exr", "hdr"]), default="exr",
                        show_default=True,
                        help="File type of the outputs: OpenEXR, or Radiance RGBE (.hdr; with the luminance "
                             "options, Radiance's 179 lm/W convention).")(f)


def ignore_color_option(f):
    """``--ignore-color`` alone (commands without --times), parsed to an (R, G, B) tuple."""
    return click.option("--ignore-color", type=Checked("ignore_color"), metavar="R,G,B",
                        help="Treat pixels of exactly this colour (8-bit units) as invalid, e.g. 0,0,255.")(f)


def fit_options(f):
    f = click.option("--exposure-tolerance", type=Checked("exposure_tolerance"), default=None, metavar="STOPS",
                     help="Report frames whose metadata the pixels contradict by more than this [default: 0.5].")(f)
    f = click.option("--fit-exposures", type=click.Choice(["auto", "on", "off"]), default="auto",
                     show_default=True,
                     help="Estimate each frame's exposure from the pixels (with --response: measured "
                          "through that curve): auto uses the estimate only where the metadata is clearly "
                          "wrong, on always, off never.")(f)
    return f


def deghost_option(f):
    """``--deghost`` (the flag alone; ``merge`` adds ``--ghost-mask`` for its one output)."""
    return click.option("--deghost", is_flag=True,
                        help="Take pixels where the frames disagree (moving objects) beyond the set's own "
                             "learnt residuals from one exposure alone.")(f)


def ghost_options(f):
    """``--ghost-threshold`` and ``--ghost-reference`` (with ``--deghost``)."""
    from hdrcl.api.support import THRESHOLD

    f = click.option("--ghost-threshold", type=Checked("ghost_threshold"), default=None,
                     help="With --deghost: departure, in robust spreads of the set's own frame-to-frame "
                          f"residuals, that makes a ghost [default: {THRESHOLD:g}].")(f)
    f = click.option("--ghost-reference", type=Checked("ghost_reference"), metavar="middle|shortest|longest|N",
                     default=None,
                     help="With --deghost: the frame ghost pixels are taken from; N counts the images "
                          "as given, from 0 [default: middle].")(f)
    return f


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

    from hdrcl.api.support import inapplicable_options

    for msg in inapplicable_options(output, **{k: given(k) for k in options}):
        logging.getLogger("hdrcl.cli").warning("%s", msg)


def luminance_options(f):
    """The calibrated fisheye luminance map (hdrcl.core.luminance.fisheye): seven options, all
    needing --lens-circle."""
    opts = [
        click.option("--lens-circle", metavar="CX,CY,DIAMETER",
                     help="Fisheye luminance map: crop to this lens circle (pixels of the merged image, origin top "
                          "left; square crop, black outside the circle); implies --absolute."),
        click.option("--resize", type=int, default=None, metavar="PIXELS",
                     help="With --lens-circle: side of the square output, area-averaged [default: 1000]."),
        click.option("--fisheye-projection", metavar="equisolid-to-equidistant|FILE.cal", default=None,
                     help="With --lens-circle: correct the lens projection (Radiance's fisheye_corr.cal), or your "
                          "own rad(r) in a .cal file (fisheye_corr.cal's convention)."),
        click.option("--vignetting", metavar="FILE.cal|A1,...,A8",
                     help="With --lens-circle: divide by 1 + A1 r + ... + A8 r^8 (r = 0 at the centre, 1 at the "
                          "circle), or a Radiance vignetting .cal file (evaluated as pcomb -f)."),
        click.option("--nd-filter", metavar="FILE.cal|KR,KG,KB",
                     help="With --lens-circle: neutral density filter factors per channel, or its .cal file."),
        click.option("--calibration-factor", metavar="FILE.cal|K",
                     help="With --lens-circle: photometric calibration factor against a luminance meter, or its "
                          ".cal file."),
        click.option("--view", metavar='"-vta -vh 186 -vv 186"',
                     help="With --lens-circle: the Radiance VIEW= of the map [default with --fisheye-projection: "
                          "-vta -vh 180 -vv 180]; -vta views get the vertical illuminance."),
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


def deliver_options(f):
    """``--deliver`` and its settings: pictures for HDR screens beside the radiance map
    (``merge``, ``batch``; :class:`hdrcl.core.options.DeliverOptions`, docs/deliver.md)."""
    f = click.option("--hdr-bits", type=click.Choice(["10", "12"]), default="10", show_default=True,
                     help="Bits per sample of the AVIF and JPEG XL deliverables.")(f)
    f = click.option("--hdr-transfer", type=click.Choice(["pq", "hlg"], case_sensitive=False), default="pq",
                     show_default=True,
                     help="Transfer of the AVIF and JPEG XL deliverables: PQ (absolute, reference white "
                          "203 cd/m^2) or HLG (relative; at most 1.9 stops above reference white).")(f)
    f = click.option("--headroom", type=Checked("headroom"), default=3.0, show_default=True, metavar="STOPS",
                     help="Stops above reference white the HDR renderings keep; brighter is clipped "
                          "(0 < STOPS <= 5.6).")(f)
    return click.option("--deliver", default="", metavar="LIST",
                        help="Also write pictures for HDR screens beside the radiance map, a comma list of: "
                             "uhdr (<stem>.uhdr.jpg, Ultra HDR JPEG: the tone-mapped SDR picture plus a gain "
                             "map), avif (<stem>.avif), jxl (<stem>.jxl), fusion (<stem>.fusion.jpg: exposure fusion "
                             "of the frames); see docs/deliver.md.")(f)
