"""The operations of hdrcl on one bracket, on arrays and on files (:mod:`hdrcl.api`).

This is the public facade: it re-exports the library's entry points from the layers
below (:mod:`hdrcl.core`, :mod:`hdrcl.report`) and holds no engine of its own. The
command line is a thin layer over the same engine::

    import hdrcl
    resp = hdrcl.calibrate(["a.jpg", "b.jpg", "c.jpg"], times=["1/250", "1/60", "1/15"])
    radiance = hdrcl.merge(["a.jpg", "b.jpg", "c.jpg"], times="1/250,1/60,1/15", response=resp)
    photo = hdrcl.expose(radiance, resp, time=1/30)          # uint8 (H, W, 3)
    picture = hdrcl.tonemap(radiance, "reinhard-local")      # sRGB uint8 (H, W, 3)

Errors are :class:`hdrcl.HdrclError` subclasses (``UsageError`` for bad arguments,
``InputError`` for unreadable or inconsistent files) whose messages name the parameter
(``times: 2 exposure time(s) given for 3 files``), not the command line's flag.
Warnings are issued through :mod:`warnings` as :class:`hdrcl.HdrclWarning` (and logged
on the ``hdrcl`` logger). ``times`` may be numbers, strings such as ``"1/30"``, or one
comma-separated string, as on the command line.
"""
from __future__ import annotations

import functools
import os
import re
from typing import Optional, Sequence, Union

import numpy as np

from hdrcl.core import bracket as _bracket
from hdrcl.core import calibrate as _calibrate
from hdrcl.core.exposure import virtual as _exposure
from hdrcl.core import merge as _merge
from hdrcl.core.bracket import Bracket, PathOrArray, memory_budget, read_infos
from hdrcl.core.calibrate import exposures_used
from hdrcl.core.merge import MergeResult
from hdrcl.core.options import MergeOptions
from hdrcl.core.response import Response, as_response
from hdrcl.errors import HdrclError, UsageError, auto_install_warnings_bridge
from hdrcl.report.merge_report import write_quality_report
from hdrcl.report.tonemap import tonemap, tonemap_file

__all__ = [
    "Bracket", "MergeOptions", "MergeResult", "Response", "calibrate", "expose", "expose_file", "exposures_used",
    "load_bracket", "memory_budget", "merge", "merge_bracket", "merge_files", "read_infos",
    "tonemap", "tonemap_file", "write_quality_report",
]

# First use of the API: its warnings also go through the warnings module (HdrclWarning).
auto_install_warnings_bridge()

_FLAG = re.compile(r"(?<![\w-])--([a-z][a-z0-9-]*)")


def python_words(message: str) -> str:
    """A library message with command-line flags (``--times-file``) named as the Python
    parameters they correspond to (``times_file``)."""
    return _FLAG.sub(lambda m: m.group(1).replace("-", "_"), message)


def _public(fn):
    """Wrap an engine function so that its errors name parameters, not CLI flags."""

    @functools.wraps(fn)
    def call(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except HdrclError as exc:
            if exc.args and isinstance(exc.args[0], str):
                exc.args = (python_words(exc.args[0]),) + exc.args[1:]
            raise

    return call


load_bracket = _public(_bracket.load_bracket)
calibrate = _public(_calibrate.calibrate)
merge_bracket = _public(_merge.merge_bracket)
merge_files = _public(_merge.merge_files)
tonemap = _public(tonemap)
tonemap_file = _public(tonemap_file)


@_public
def expose(radiance: np.ndarray, response: Union[Response, str, os.PathLike], time: float, *,
           bits: Optional[int] = None, device: Optional[str] = None, channel_order: str = "rgb") -> np.ndarray:
    """Virtual photograph of ``radiance`` at exposure ``time`` seconds through ``response``.

    ``radiance`` is ``(H, W)`` or ``(H, W, C)`` finite linear radiance; ``time`` a number
    or a string such as ``"1/30"``; ``bits`` 8 or 16 (default the response's).
    ``channel_order="bgr"`` takes and returns OpenCV's channel order (default RGB).
    """
    from hdrcl.core.params import check_options, to_rgb

    check_options(time=time, bits=bits, channel_order=channel_order, device=device)
    if not isinstance(radiance, np.ndarray):
        from hdrcl.errors import ParameterTypeError

        raise ParameterTypeError(f"radiance: expected a NumPy array, not {type(radiance).__name__}")
    resp = as_response(response)
    if radiance.ndim == 3:
        name = os.fspath(response) if isinstance(response, (str, os.PathLike)) else "response"
        if resp.nchannels not in (1, radiance.shape[2]):
            raise UsageError(f"{name}: a response with {resp.nchannels} channel(s), but radiance has "
                             f"{radiance.shape[2]}")
        (radiance,) = to_rgb([radiance], channel_order)
    out = _exposure.expose(radiance, resp, time, bits=bits, device=device)
    return to_rgb([out], channel_order)[0] if out.ndim == 3 else out


@_public
def expose_file(radiance_path, output, response, time, *, bits: Optional[int] = None,
                device: Optional[str] = None, motion_blur=None) -> np.ndarray:
    """Render a radiance file as a virtual photograph file (JPEG, PNG or TIFF); see
    :func:`hdrcl.core.exposure.virtual.expose_file`. The options, and whether the response fits
    the file's channels and the blur its size, are checked from the header first."""
    from hdrcl.core.params import check_expose, check_options

    o = check_options(time=time, bits=bits, motion_blur=motion_blur, device=device)
    radiance_path, output = (os.fsdecode(os.fspath(p)) for p in (radiance_path, output))
    resp = as_response(response)
    source = os.fspath(response) if isinstance(response, (str, os.PathLike)) else "response"
    check_expose(radiance_path, resp, motion_blur=o["motion_blur"], source=source)
    return _exposure.expose_file(radiance_path, output, resp, o["time"], bits=bits, device=device,
                                 motion_blur=o["motion_blur"])


@_public
def merge(images: Sequence[PathOrArray], times: Optional[Sequence[float]] = None,
          response: Union[Response, str, os.PathLike, None] = None, *, times_file=None, channel_order: str = "rgb",
          options: Optional[MergeOptions] = None, **kwargs) -> np.ndarray:
    """Merge a bracket into a float32 radiance map ``(H, W, C)``.

    ``response`` may be a :class:`Response`, a path to a response JSON file, or None to
    calibrate from the set itself. Radiance is relative: a pixel that reads ``Zmid``
    in a 1 s exposure (at the first frame's aperture and ISO) has radiance about 1.
    The options are those of :func:`merge_files` (and ``hdrcl merge``): a
    :class:`MergeOptions` or its fields as keywords (``weight``, ``ignore_color``,
    ``samples``, ``smoothness``, ``seed``, ``device``, ``fit_exposures``,
    ``exposure_tolerance``, ``deghost``, ``align``, ``align_model``, ``crop``, ``neutral``,
    ``reference_patch``, ``absolute``):

    Parameters
    ----------
    align, crop : bool
        Align hand-held frames to the middle exposure (:mod:`hdrcl.core.align.handheld`);
        ``crop`` keeps only the area every frame covers.
    align_model : {"auto", "shift", "similarity", "homography"}
        With ``align``: the motion model (``auto``: the simplest the residuals allow).
    deghost : bool
        Take pixels where the frames disagree from the middle exposure alone.
    neutral : "x,y,w,h" or (x, y, w, h), optional
        White balance: make this patch neutral grey.
    reference_patch : "x,y,w,h=VALUE", optional
        Absolute scale: this patch's mean luminance becomes VALUE cd/m^2.
    absolute : bool
        Approximate cd/m^2 from the first frame's f-number and ISO (image files only).
    channel_order : {"rgb", "bgr"}
        Channel order of array frames and of the map returned: ``"bgr"`` for OpenCV's
        (``cv2.imread``). Files are always read as RGB; the default takes arrays as RGB.

    Every option is checked before any file is decoded (:mod:`hdrcl.core.params`), a
    patch against the frames' size too.
    """
    from hdrcl.core.params import check, check_image_size, check_images, to_rgb

    images = check_images(images)
    o = options.replace(**kwargs) if options is not None else MergeOptions(**kwargs)  # checked once, here
    o.check_frames(len(images))
    check("channel_order", channel_order)
    arrays = bool(images) and all(isinstance(im, np.ndarray) for im in images)
    if o.absolute and arrays:
        raise UsageError("absolute needs the frames' f-number and ISO: give image files, not arrays")
    if o.neutral is not None or o.reference_patch is not None:
        if arrays:
            size = images[0].shape[1], images[0].shape[0]
        else:
            first = read_infos(images[:2])[0]
            size = first.width, first.height
        check_image_size(*size, neutral=o.neutral, reference_patch=o.reference_patch)
    br = _bracket.load_bracket(images, times, times_file=times_file, ignore_color=o.ignore_color,
                               channel_order=channel_order)
    resp = as_response(response)
    if resp is not None and br.frames and resp.bits != 8 * br.frames[0].dtype.itemsize:
        name = os.fspath(response) if isinstance(response, (str, os.PathLike)) else "response"
        raise UsageError(f"{name}: a response for {resp.bits}-bit frames, but the frames are "
                         f"{8 * br.frames[0].dtype.itemsize}-bit")
    from hdrcl.core.sources import GivenResponse, ResponseSource
    from hdrcl.core.executor import execute
    from hdrcl.core.plan import plan_merge

    source = ResponseSource() if resp is None else GivenResponse(
        resp, os.fspath(response) if isinstance(response, (str, os.PathLike)) else "given")
    radiance = execute(plan_merge(None, o, source, bracket=br)).radiance
    return to_rgb([radiance], channel_order)[0]
