"""Options shared by several commands (declared once, used everywhere), and the
parameter types that check files the way the error contract wants: one line naming the
file, exit 3 for an input that cannot be read, exit 2 for an output that cannot be
written (click's own path checks print three lines and always exit 2).
"""
from __future__ import annotations

import os

import click

from hdrcl.api.options import MergeOptions


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


def shared(*decls, **attrs):
    """One declaration of a flag that several commands take: ``shared(...)(**variant)`` is
    its click decorator, ``variant`` what one command declares otherwise (its ``help``
    where the meaning differs, a default, a type; a parameter name as ``names``)."""
    def option(*names, **variant):
        return click.option(*decls, *names, **{**attrs, **variant})

    return option


_FIELDS = {f.name: f for f in MergeOptions.declared()}


def field_option(name: str, **variant):
    """The click option of the merge option ``name``, made from its one declaration
    (:class:`hdrcl.core.options.MergeOptions`: default, help, metavar; kind and choices from
    the option table); ``variant`` as :func:`shared`'s."""
    from hdrcl.core.params import TABLE, choices

    f, kind = _FIELDS[name], TABLE[name].kind
    meta = f.metadata
    attrs = {"default": f.default, "help": meta["help"]}
    if meta["metavar"]:
        attrs["metavar"] = meta["metavar"]
    if meta["show_default"]:
        attrs["show_default"] = True
    if kind == "bool":
        attrs["is_flag"] = True
    elif kind == "choice":
        attrs["type"] = click.Choice(list(choices(name)), case_sensitive=meta["case_sensitive"])
    elif kind != "text":
        attrs["type"] = Checked(name)
    return click.option("--" + name.replace("_", "-"), name, **{**attrs, **variant})


def merge_options(f=None, *, solve: bool = False):
    """Every merge option (``merge``, ``batch``), or with ``solve`` those of the response
    solve (``calibrate``), in the order declared; the command takes them as keywords and
    makes one :class:`~hdrcl.core.options.MergeOptions` of them (``MergeOptions.from_params``)."""
    def decorate(fn):
        for name in reversed(list(_FIELDS)):
            if not solve or _FIELDS[name].metadata["solve"]:
                fn = field_option(name)(fn)
        return fn

    return decorate if f is None else decorate(f)


def device_option(f):
    """``--device`` (commands without the merge options)."""
    return field_option("device")(f)


#: ``--times-file`` (merge, calibrate, batch, scan); batch and scan take it for the frames it lists.
times_file_option = shared("--times-file", type=InputFile("times file"),
                           help="Exposure list: HDRShop columns (file, seconds, 1/shutter, f-stop, gain dB, ND) "
                                "or 'file seconds' lines; it wins over EXIF [default: for frames without EXIF "
                                "exposure time, image_list.txt or times.txt beside them].")
FOR_THE_FRAMES_IT_LISTS = ("Exposure list: HDRShop columns or 'file seconds' lines; it wins over EXIF for the "
                           "frames it lists [default: for frames without EXIF exposure time, image_list.txt or "
                           "times.txt beside them].")
#: ``--json``: what is printed as JSON, said by each command.
json_option = shared("--json", "as_json", is_flag=True, help="Print JSON.")
#: ``--response``: a response file (what it is used for, said by each command).
response_option = shared("--response", "response", type=InputFile("response file"), help="Response JSON.")
#: ``--response-cache``: merge's is a file, batch's a folder of them.
response_cache_option = shared("--response-cache", "response_cache")
#: ``--report``: the quality report's folder.
report_option = shared("--report", type=OutputFolder("report folder"))
#: ``--size``: WxH of what a command generates.
size_option = shared("--size", "size", type=Checked("size"), show_default=True, metavar="WxH")
#: ``--bits``: depth of a written photograph.
bits_option = shared("--bits", type=click.Choice(["8", "16"]))
#: ``--view``: a Radiance view of a luminance map.
view_option = shared("--view", default=None, metavar="VIEW")


def exposure_options(f):
    """``--times`` and ``--times-file`` (``calibrate``, ``merge``)."""
    f = times_file_option()(f)
    f = click.option("--times", callback=_times, metavar="T1,T2,...",
                     help="Exposure times in seconds, one per image, e.g. 1/250,1/60,1/15 "
                          "(overrides --times-file and EXIF).")(f)
    return f


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


def output_format_option(f):
    """``--format``: the file type of batch outputs."""
    return click.option("--format", "output_format", type=click.Choice(["exr", "hdr"]), default="exr",
                        show_default=True,
                        help="File type of the outputs: OpenEXR, or Radiance RGBE (.hdr; with the luminance "
                             "options, Radiance's 179 lm/W convention).")(f)


def given(name: str):
    """The value of option ``name`` if the user gave it on the command line, else None."""
    ctx = click.get_current_context()
    source = ctx.get_parameter_source(name)
    if source is None or source.name in ("DEFAULT", "DEFAULT_MAP"):
        return None
    return ctx.params.get(name)


def warn_inapplicable(output: str, *names: str) -> None:
    """Warn (once each) about the options ``names`` the output type ignores, where given
    explicitly."""
    import logging

    from hdrcl.api.support import inapplicable_options

    for msg in inapplicable_options(output, **{k: given(k) for k in names}):
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
        view_option(metavar='"-vta -vh 186 -vv 186"',
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
