"""The merge engine: a loaded bracket (:func:`merge_bracket`) or files streamed strip by
strip into a radiance file (:func:`merge_files`), with provenance metadata.
"""
from __future__ import annotations

import logging
import os
from typing import Optional, Sequence, Union

import numpy as np

from hdrcl.core.bracket import Bracket
from hdrcl.core.calibrate import calibrate, exposures_used
from hdrcl.core.options import MergeOptions
from hdrcl.core.result import MergeResult, provenance  # noqa: F401 (public here too)
from hdrcl.core.response import Response
from hdrcl.errors import UsageError

logger = logging.getLogger(__name__)


def merge_bracket(bracket: Bracket, response: Optional[Response] = None, options: Optional[MergeOptions] = None,
                  **kwargs) -> MergeResult:
    """Fuse a loaded :class:`Bracket`, calibrating from it when no response is given
    (then with the exposures that calibration refined, see :func:`calibrate`).

    ``options`` is a :class:`hdrcl.core.options.MergeOptions`; its fields may also be given
    as keywords (``weight=``, ``deghost=``, ``ghost_reference=`` ...; they override
    ``options``'s; an unknown keyword is a TypeError). In memory the response solve's
    options, ``fit_exposures``/``exposure_tolerance``, the deghosting's and ``device``
    apply (as :func:`hdrcl.core.fusion.fuse_frames`); the file's and the alignment's are
    :func:`merge_files`'s."""
    from hdrcl.core.executor import execute
    from hdrcl.core.plan import plan_merge
    from hdrcl.core.sources import response_source

    o = options.replace(**kwargs) if options is not None else MergeOptions(**kwargs)
    o.check_frames(len(bracket.frames))
    return execute(plan_merge(None, o, response_source(response), bracket=bracket))


def merge_files(paths: Sequence[Union[str, os.PathLike]], output: Union[str, os.PathLike],
                options: Optional[MergeOptions] = None, *, times: Optional[Sequence[float]] = None,
                times_file=None, response: Union[Response, str, os.PathLike, None] = None,
                **kwargs) -> MergeResult:
    """Merge image files into a radiance file (EXR, HDR, TIFF or PFM by extension).

    The frames are decoded, fused and written strip by strip, with decoding, fusion and
    encoding overlapping, so memory stays bounded whatever the image size. Without a
    ``response`` the set calibrates itself from a first streaming pass that keeps only
    each frame's sampling grid (:meth:`hdrcl.io.reader.BracketReader.read_grid`); the
    fusion pass then decodes the frames again, its first strip while the response is
    solved. Only ``align`` holds whole frames in memory. The output is written
    atomically: nothing appears at ``output`` unless the whole merge succeeded.

    ``options`` is a :class:`hdrcl.core.options.MergeOptions`; its fields may also be given
    as keywords (``weight=``, ``align=`` ...; they override ``options``'s). The other
    keywords are the extras of :class:`hdrcl.core.plan.Extras`. The merge is planned
    (:func:`hdrcl.core.plan.plan_merge`) and run by :func:`hdrcl.core.executor.execute`.

    Parameters
    ----------
    keep_frames : bool
        Also return the decoded frames the merge had in memory anyway, in
        ``result.kept = (frames, valid, grid)`` (whole frames, or the sampling grid when
        they were spilled to the scratch file; aligned frames as merged), so that a
        quality report needs no second decode; None when the frames only streamed past.
    keep_radiance : bool
        Also return the whole radiance map in ``result.radiance`` (memory grows with the
        image); otherwise it is None.
    thumbnail : int
        If > 0, ``result.thumbnail`` holds every k-th pixel of the radiance, with the
        long side about this many pixels (for previews).
    deghost : bool
        Take pixels where the frames disagree (moving objects) beyond the set's own
        learnt residuals from the reference exposure alone (:mod:`hdrcl.core.deghost`);
        ``result.counts["ghost"]`` counts them.
    ghost_mask : path, optional
        With ``deghost``, also write the ghost mask as an 8-bit PNG/TIFF (255 = ghost).
    clip_mask : path, optional
        Also write the pixels clipped in every frame as an 8-bit PNG/TIFF: 255 where a
        channel was clipped high in every frame (its value is the lower bound the
        shortest frame proves), 128 where one was black in every frame (an upper bound).
    ghost_threshold : float, optional
        With ``deghost``: departure, in robust spreads of the set's residuals, that makes
        a ghost (default :data:`hdrcl.core.deghost.THRESHOLD`).
    ghost_reference : "middle", "shortest", "longest" or int, optional
        With ``deghost``: the frame ghost pixels are taken from (an int is an index into
        ``paths``); default the middle exposure.

    The file holds radiance times the reference exposure (:mod:`hdrcl.core.encode`: 1.0
    is what a frame of ``reference_exposure`` seconds records as white; default the
    power of two nearest the bracket's middle exposure; recorded as ``expTime`` and
    ``hdrcl:referenceExposure``, or ``EXPOSURE=`` in a Radiance file). An EXR is half
    float whenever the merged values fit, which is measured on the data as it streams;
    otherwise (``dtype="auto"``, or absolute units) it is fused again into float, or
    (``dtype="half"``) into half rescaled by a power of two recorded as
    ``hdrcl:halfScale``; ``result.warnings`` and ``result.stored`` say which.
    reference_exposure : float or str, optional
        The reference exposure in seconds (``"1/125"`` accepted) at the first frame's
        f-number and ISO.
    neutral : "x,y,w,h", optional
        White balance: scale the channels so this patch comes out neutral
        (:mod:`hdrcl.core.radiometry`).
    reference_patch : "x,y,w,h=VALUE", optional
        Absolute scale: the patch's mean luminance becomes VALUE (cd/m^2).
    absolute : bool
        Approximate absolute scale (cd/m^2) from the first frame's f-number and ISO.
    align : bool
        Align hand-held frames to the middle exposure (:mod:`hdrcl.core.align.handheld`):
        whole-pixel shift by median threshold bitmaps, then a sub-pixel fit of
        ``align_model``, and a warp. ``result.alignment`` holds one dict per frame
        (model, matrix, rotation, scale, shift, residual); ``result.shifts`` each
        frame's whole-pixel ``(dy, dx)``. Pixels a warped frame no longer covers are
        masked in that frame. A frame that cannot be aligned is refused (InputError
        naming it). The frames are held in memory for this.
    align_model : {"auto", "shift", "similarity", "homography"}
        With ``align``: the motion model; ``auto`` takes the simplest that fits.
    crop : bool
        With ``align``: crop the output to the box every frame covers.
    colorspace : {"rec709", "acescg"}
        Colour space of the file (:mod:`hdrcl.io.colorspace`; ACEScg needs EXR or HDR).
        The merge itself, ``result.radiance`` and ``result.thumbnail`` stay linear Rec.709.
    owner : str, optional
        The file's ``owner`` (EXR) / Copyright; default the frames' EXIF Copyright.

    The file carries the standard metadata of :mod:`hdrcl.io.outmeta` (software, camera,
    lens, the reference exposure, the first frame's capture time).
    save_response : path, optional
        Also write the response used (JSON). It is written to a temporary file before
        the radiance, so a full disk or a read-only folder fails the merge before the
        radiance file appears, and renamed into place after it.
    chain : hdrcl.core.luminance.fisheye.LuminanceChain, optional
        A calibrated fisheye luminance map (``LuminanceChain.from_options``): the fused
        strips, in cd/m^2 (``absolute`` is implied unless ``reference_patch`` sets the
        scale), are cropped to the lens circle and area-averaged to ``N x N`` as they
        come, corrected at the end and written as the output (``N x N``);
        ``result.vertical_illuminance`` holds the lux at the lens for ``-vta`` views.
        ``result.radiance`` and the thumbnail stay the full merged map.
    """
    from hdrcl.core.executor import execute
    from hdrcl.core.plan import Extras, plan_merge
    from hdrcl.core.sources import Inputs, response_source
    from hdrcl.core.options import MergeOptions
    from hdrcl.core.params import check_images

    paths = check_images(paths, "paths", arrays=False)
    if options is None:
        options, rest = MergeOptions.split(kwargs)  # the options checked once, here
    else:
        options, rest = options.replace(**{k: v for k, v in kwargs.items() if k in options.asdict()}), {
            k: v for k, v in kwargs.items() if k not in options.asdict()}
    extras = Extras(**rest)  # TypeError naming an unknown keyword, as before
    options.check_frames(len(paths))
    output = check_targets(paths, output, options, extras, response)
    for line in options.ignored(output, chain=extras.chain is not None):
        logger.warning("%s", line)
    source = response_source(response)
    inputs = Inputs.open(paths, times, times_file)
    return execute(plan_merge(inputs, options, source, output, extras=extras))


def check_targets(paths, output, options, extras, response) -> str:
    """``output`` as a str, after the checks of every file a merge writes (its type, its
    folder, that it overwrites no input) and of the options that need one another."""
    from hdrcl.io.atomic import check_output
    from hdrcl.io.colorspace import check as check_space
    from hdrcl.io.writers import RADIANCE_EXTENSIONS

    if isinstance(output, bytes):
        output = os.fsdecode(output)
    check_space(options.colorspace)
    output = os.fspath(output)
    ext = os.path.splitext(output)[1].lower()
    if ext not in RADIANCE_EXTENSIONS:
        raise UsageError(f"{output}: unsupported output type '{ext}'; use one of {', '.join(RADIANCE_EXTENSIONS)}")
    targets = ((output, "radiance map"), (extras.ghost_mask, "ghost mask"), (extras.clip_mask, "clip mask"),
               (extras.save_response, "response"))
    for target, _what in targets[:3]:
        if target is not None and not os.path.isdir(os.path.dirname(os.path.abspath(os.fspath(target)))):
            raise UsageError(f"{os.fspath(target)}: output folder does not exist")
    inputs = [p for p in paths if isinstance(p, (str, os.PathLike))]
    for target, what in targets:
        if target is not None:
            check_output(target, inputs + ([response] if isinstance(response, (str, os.PathLike)) else []),
                         what=what)
    if extras.ghost_mask is not None and not options.deghost:
        raise UsageError("--ghost-mask needs --deghost")
    if options.colorspace != "rec709" and ext not in (".exr", ".hdr"):
        raise UsageError(f"{output}: --colorspace {options.colorspace} needs an .exr or .hdr output "
                         f"({ext} cannot say which primaries it holds)")
    return output


def _align(frames, valid, times, device, crop: bool = False, model: str = "auto", names=None):
    """``(frames, valid, shifts, box)`` of :func:`hdrcl.core.align.handheld.align_bracket`
    (``box`` None without ``crop``)."""
    from hdrcl.core.align.handheld import align_bracket

    al = align_bracket(frames, valid, times, device, crop, model, names)
    return al.frames, al.valid, al.shifts, al.crop
