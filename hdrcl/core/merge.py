"""The merge engine: a loaded bracket (:func:`merge_bracket`) or files streamed strip by
strip into a radiance file (:func:`merge_files`), with provenance metadata.
"""
from __future__ import annotations

import logging
import os
import time as _time
from dataclasses import dataclass, field
from typing import List, Optional, Sequence, Union

import numpy as np

from hdrcl.core.bracket import (
    Bracket,
    _all_raw,
    _grid_bracket,
    _open_files,
    _parse_ignore_color,
    _with_ignore,
)
from hdrcl.core.calibrate import calibrate, exposures_used
from hdrcl.core.response import Response, _as_response
from hdrcl.core.scale import _radiometric_factors
from hdrcl.core.stages import _kept_frames, _measured_exposures, _report_exposure_check, _Tee, _warm_up  # noqa: F401
from hdrcl.core.weights import DEFAULT_WEIGHT
from hdrcl.errors import UsageError

logger = logging.getLogger(__name__)


@dataclass
class MergeResult:
    """A merged radiance map with what went into it."""

    radiance: Optional[np.ndarray]
    response: Response
    counts: dict
    times: np.ndarray
    paths: List[str]
    backend: str
    seconds: dict = field(default_factory=dict)
    warnings: List[str] = field(default_factory=list)
    output: Optional[str] = None
    shape: tuple = ()
    thumbnail: Optional[np.ndarray] = None
    shifts: Optional[list] = None  # (dy, dx) per frame when aligned: whole-pixel motion of its centre
    alignment: Optional[list] = None  # per frame when aligned: hdrcl.core.handheld.describe dicts
    nominal: Optional[np.ndarray] = None  # the set's own exposures before any refinement
    crop: Optional[tuple] = None  # (y0, y1, x0, x1) of the input kept, with align + crop
    storage_note: Optional[str] = None  # how an EXR was stored when half could not hold it
    stored: Optional[object] = None  # hdrcl.core.encode.Stored: type, reference exposure, measured range
    kept: Optional[tuple] = None  # (frames, valid, is_grid) with keep_frames: for the quality report
    stages: dict = field(default_factory=dict)  # seconds per stage (decode, solve, fuse, encode, write); overlapping
    vertical_illuminance: Optional[float] = None  # lux at the lens, with a fisheye luminance chain (-vta view)

    def __post_init__(self):
        if not self.shape and self.radiance is not None:
            self.shape = tuple(self.radiance.shape)


def merge_bracket(
    bracket: Bracket,
    response: Optional[Response] = None,
    *,
    weight: str = DEFAULT_WEIGHT,
    samples: Optional[int] = None,
    smoothness: Optional[float] = None,
    seed: int = 0,
    device: Optional[str] = None,
    fit_exposures: str = "auto",
    exposure_tolerance: Optional[float] = None,
    deghost: bool = False,
    ghost_threshold: Optional[float] = None,
    ghost_reference=None,
) -> MergeResult:
    """Fuse a loaded :class:`Bracket`, calibrating from it when no response is given
    (then with the exposures that calibration refined, see :func:`calibrate`).
    ``deghost``, ``ghost_threshold`` and ``ghost_reference`` as
    :func:`hdrcl.core.fusion.fuse_frames`."""
    from hdrcl.core.fusion import fuse_frames
    from hdrcl.core.params import check_options

    o = check_options(frames=len(bracket.frames), weight=weight, samples=samples, smoothness=smoothness, seed=seed,
                      fit_exposures=fit_exposures, exposure_tolerance=exposure_tolerance, deghost=deghost,
                      ghost_threshold=ghost_threshold, ghost_reference=ghost_reference)
    samples, smoothness, seed, exposure_tolerance = o["samples"], o["smoothness"], o["seed"], o["exposure_tolerance"]
    t0 = _time.perf_counter()
    if response is None:
        response = calibrate(bracket, samples=samples, smoothness=smoothness, weight=weight, seed=seed,
                             fit_exposures=fit_exposures, exposure_tolerance=exposure_tolerance)
    t1 = _time.perf_counter()
    times = exposures_used(response, bracket.times)
    res = fuse_frames(bracket.frames, times, response, weight=weight, valid=bracket.valid, device=device,
                      deghost=deghost, ghost_threshold=ghost_threshold, ghost_reference=ghost_reference)
    t2 = _time.perf_counter()
    warnings = list(response.warnings)
    if res.counts.get("no_data"):
        warnings.append(f"{res.counts['no_data']} pixel-channels are invalid in every frame and were set to 0")
    return MergeResult(radiance=res.radiance, response=response, counts=res.counts, times=times,
                       paths=bracket.paths, backend=res.backend,
                       seconds={"calibrate": t1 - t0, "fuse": t2 - t1}, warnings=warnings,
                       nominal=np.asarray(bracket.times, np.float64))


def _provenance(result: MergeResult, response_source: str) -> dict:
    from hdrcl.io.metadata import format_time

    r = result.response
    meta = {
        "sources": [os.path.basename(p) for p in result.paths],
        "exposures": [float(t) for t in result.times],
        "exposuresNominal": [float(t) for t in (result.nominal if result.nominal is not None else result.times)],
        "exposureText": ", ".join(format_time(t) for t in result.times),
        "response": response_source,
        "responseSmoothness": float(r.smoothness),
        "responseSamples": int(r.samples),
        "weight": r.weight,
        "backend": result.backend,
    }
    if result.counts:  # a streamed file's header is written before the counts are known
        meta.update({"clippedHigh": int(result.counts.get("clipped_high", 0)),
                     "clippedLow": int(result.counts.get("clipped_low", 0)),
                     "noData": int(result.counts.get("no_data", 0))})
    if r.camera:
        meta["camera"] = " ".join(str(r.camera[k]) for k in ("make", "model") if k in r.camera)
    return meta


def merge_files(
    paths: Sequence[Union[str, os.PathLike]],
    output: Union[str, os.PathLike],
    *,
    times: Optional[Sequence[float]] = None,
    times_file=None,
    response: Union[Response, str, os.PathLike, None] = None,
    weight: str = DEFAULT_WEIGHT,
    ignore_color=None,
    samples: Optional[int] = None,
    smoothness: Optional[float] = None,
    seed: int = 0,
    dtype: str = "auto",
    compression: str = "piz",
    device: Optional[str] = None,
    keep_radiance: bool = False,
    keep_frames: bool = False,
    thumbnail: int = 0,
    fit_exposures: str = "auto",
    exposure_tolerance: Optional[float] = None,
    deghost: bool = False,
    ghost_mask: Union[str, os.PathLike, None] = None,
    clip_mask: Union[str, os.PathLike, None] = None,
    ghost_threshold: Optional[float] = None,
    ghost_reference=None,
    neutral=None,
    reference_patch=None,
    absolute: bool = False,
    align: bool = False,
    align_model: str = "auto",
    crop: bool = False,
    colorspace: str = "rec709",
    owner: Optional[str] = None,
    save_response: Union[str, os.PathLike, None] = None,
    reference_exposure=None,
    chain=None,
) -> MergeResult:
    """Merge image files into a radiance file (EXR, HDR, TIFF or PFM by extension).

    The frames are decoded, fused and written strip by strip, with decoding, fusion and
    encoding overlapping, so memory stays bounded whatever the image size. Without a
    ``response`` the set calibrates itself from a first streaming pass that keeps only
    each frame's sampling grid (:meth:`hdrcl.io.reader.BracketReader.read_grid`); the
    fusion pass then decodes the frames again, its first strip while the response is
    solved. Only ``align`` holds whole frames in memory. The output is written
    atomically: nothing appears at ``output`` unless the whole merge succeeded.

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
        Align hand-held frames to the middle exposure (:mod:`hdrcl.core.handheld`):
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
    chain : hdrcl.core.fisheye.LuminanceChain, optional
        A calibrated fisheye luminance map (``LuminanceChain.from_options``): the fused
        strips, in cd/m^2 (``absolute`` is implied unless ``reference_patch`` sets the
        scale), are cropped to the lens circle and area-averaged to ``N x N`` as they
        come, corrected at the end and written as the output (``N x N``);
        ``result.vertical_illuminance`` holds the lux at the lens for ``-vta`` views.
        ``result.radiance`` and the thumbnail stay the full merged map.
    """
    from hdrcl.cl.backend import get_processor
    from hdrcl.core.encode import fuse_to_file, radiance_opener, reference_for
    from hdrcl.core.pipeline import ArraySink, ArraySource, Thumbnail, stream_merge
    from hdrcl.io.colorspace import check as check_space
    from hdrcl.io.outmeta import camera_from_infos
    from hdrcl.io.reader import BracketReader
    from hdrcl.io.atomic import check_output, stage_text
    from hdrcl.core.params import check_image_size, check_images, check_options, check_response_fits
    from hdrcl.io.writers import RADIANCE_EXTENSIONS

    # Every option, before any file is opened (hdrcl.core.params: the CLI's table too).
    paths = check_images(paths, "paths", arrays=False)
    o = check_options(frames=len(paths), weight=weight, ignore_color=ignore_color, samples=samples,
                      smoothness=smoothness, seed=seed, dtype=dtype, compression=compression,
                      fit_exposures=fit_exposures, exposure_tolerance=exposure_tolerance, deghost=deghost,
                      ghost_threshold=ghost_threshold, ghost_reference=ghost_reference, neutral=neutral,
                      reference_patch=reference_patch, absolute=absolute, align=align, crop=crop,
                      colorspace=colorspace, reference_exposure=reference_exposure)
    samples, smoothness, seed, exposure_tolerance = o["samples"], o["smoothness"], o["seed"], o["exposure_tolerance"]
    reference_exposure = o["reference_exposure"]
    if chain is not None and reference_patch is None:
        absolute = True  # a luminance map is in cd/m^2; the chain multiplies by its K
    if isinstance(output, bytes):
        output = os.fsdecode(output)
    colorspace = check_space(colorspace)
    output = os.fspath(output)
    ext = os.path.splitext(output)[1].lower()
    if ext not in RADIANCE_EXTENSIONS:
        raise UsageError(f"{output}: unsupported output type '{ext}'; use one of {', '.join(RADIANCE_EXTENSIONS)}")
    for target in (output, ghost_mask, clip_mask):
        if target is not None and not os.path.isdir(os.path.dirname(os.path.abspath(os.fspath(target)))):
            raise UsageError(f"{os.fspath(target)}: output folder does not exist")
    inputs = [p for p in paths if isinstance(p, (str, os.PathLike))]
    for target, what in ((output, "radiance map"), (ghost_mask, "ghost mask"), (clip_mask, "clip mask"),
                         (save_response, "response")):
        if target is not None:
            check_output(target, inputs + ([response] if isinstance(response, (str, os.PathLike)) else []),
                         what=what)
    rgb = _parse_ignore_color(ignore_color)
    if crop and not align:
        raise UsageError("--crop needs --align")
    if align:
        from hdrcl.core.handheld import check_model

        align_model = check_model(align_model)
    if ghost_mask is not None and not deghost:
        raise UsageError("--ghost-mask needs --deghost")
    if not deghost and (ghost_threshold is not None or ghost_reference is not None):
        raise UsageError("--ghost-threshold and --ghost-reference need --deghost")
    if colorspace != "rec709" and ext not in (".exr", ".hdr"):
        raise UsageError(f"{output}: --colorspace {colorspace} needs an .exr or .hdr output "
                         f"({ext} cannot say which primaries it holds)")
    source_name = os.fspath(response) if isinstance(response, (str, os.PathLike)) else (
        "given" if response is not None else "calibrated from these frames")
    resp = _as_response(response)
    calibrated = resp is None
    seconds: dict = {}
    t0 = _time.perf_counter()
    # --- read: headers, exposures
    paths, infos, rel = _open_files(paths, times, times_file)
    first = infos[0]
    work = first.width * first.height * len(paths)  # a small job skips OpenCL's start-up
    warm = _warm_up(device, calibrating=resp is None, work=work)
    nch = 3 if first.nchannels >= 3 else 1
    h, w = first.height, first.width
    check_image_size(w, h, neutral=neutral, reference_patch=reference_patch)  # from the headers
    if chain is not None:
        chain.bind(h, w, nch)  # --lens-circle against the image, before any decoding
        if reference_patch is None and not (first.fnumber and first.iso):
            raise UsageError(f"{paths[0]}: a luminance map (--lens-circle) is in cd/m^2 from the first frame's "
                             "f-number and ISO, which its EXIF does not give; use --reference-patch")
    if resp is not None:
        check_response_fits(resp, source_name, paths[0], first.bits, nch)
    if resp is None and _all_raw(paths):
        from hdrcl.core.response import linear_response

        resp, source_name = linear_response(nch), "linear (RAW input)"
        resp.exposures = [{"file": os.path.basename(p), "nominal": float(t), "fitted": None, "used": float(t)}
                          for p, t in zip(paths, rel)]
    t1 = _time.perf_counter()
    seconds["open"] = t1 - t0
    shifts = crop_box = alignment = None
    nominal = rel
    grid = None  # the sampling grid, when a streaming pass read it
    fit_notes: List[str] = []
    if align:  # alignment works on whole frames: they are held in memory
        with BracketReader(paths, infos) as reader:
            frames, valid = reader.read_all()
            seconds["decode"] = reader.decode_seconds
        valid = _with_ignore(frames, valid, rgb)
        from hdrcl.core.handheld import align_bracket

        ta = _time.perf_counter()
        al = align_bracket(frames, valid, rel, device, crop, align_model, paths, inplace=True)
        seconds["align"] = _time.perf_counter() - ta
        frames, valid, shifts, crop_box, alignment = al.frames, al.valid, al.shifts, al.crop, al.alignment
        del al
        if crop_box is not None:
            y0, y1, x0, x1 = crop_box
            h, w = y1 - y0, x1 - x0
        if resp is None:  # from the sampling grid of the aligned frames, as a streaming merge does
            from hdrcl.core.sampling import grid_stride

            k = grid_stride(h, w)
            br = Bracket(frames=[f[::k, ::k] for f in frames], times=rel,
                         valid=[None if v is None else v[::k, ::k] for v in valid], paths=paths, infos=infos,
                         grid=True)
            resp = calibrate(br, samples=samples, smoothness=smoothness, weight=weight, seed=seed,
                             fit_exposures=fit_exposures, exposure_tolerance=exposure_tolerance)
        source = ArraySource(frames, valid)
        ignore = None
        if not calibrated and fit_exposures != "off":
            from hdrcl.core.sampling import grid_stride

            k = grid_stride(h, w)
            rel, notes = _measured_exposures([f[::k, ::k] for f in frames],
                                             [None if v is None else v[::k, ::k] for v in valid], rel, resp,
                                             fit_exposures, weight, exposure_tolerance, paths)
            fit_notes += notes
    else:
        source = BracketReader(paths, infos)
        ignore = rgb
        if not calibrated and fit_exposures != "off":
            # A known curve measures every frame's exposure (no exponential ambiguity):
            # from the sampling grid of the one decode that also feeds the fusion.
            try:
                grid = _grid_bracket(paths, infos, rel, rgb, reader=source, keep=True)
                seconds["decode"] = source.decode_seconds
                rel, notes = _measured_exposures(grid.frames, grid.valid, rel, resp, fit_exposures, weight,
                                                 exposure_tolerance, paths)
                fit_notes += notes
            except BaseException:
                source.close()
                raise
        if resp is None:
            # --- sample + solve. One streaming pass decodes every frame once: it keeps
            # the sampling grid and the decoded codes (io.framecache), which the fusion
            # pass then reads instead of decoding again.
            try:
                grid = _grid_bracket(paths, infos, rel, rgb, reader=source, keep=True)
                seconds["decode"] = source.decode_seconds
                # The solve overlaps the OpenCL start-up on the warm-up thread (the fusion
                # pass reads the decoded frames back: nothing to prefetch).
                ts = _time.perf_counter()
                resp = calibrate(grid, samples=samples, smoothness=smoothness, weight=weight, seed=seed,
                                 fit_exposures=fit_exposures, exposure_tolerance=exposure_tolerance)
                seconds["solve"] = _time.perf_counter() - ts
            except BaseException:
                source.close()
                raise
    rel = exposures_used(resp, rel)
    if chain is not None:
        chain.bind(h, w, nch)  # again: --crop may have made the image smaller
    t2 = _time.perf_counter()
    seconds["calibrate"] = t2 - t1
    warm.join()
    backend = "numpy" if get_processor("fusion", device, work=work) is None else "opencl"
    result = MergeResult(radiance=None, response=resp, counts={}, times=rel, paths=paths, backend=backend,
                         shape=(h, w, nch), warnings=list(resp.warnings) + fit_notes, output=output, shifts=shifts,
                         nominal=nominal, crop=crop_box, alignment=alignment)
    # Any per-frame mask (alpha, ignore colour, or pixels an aligned frame lost) must
    # reach the kernel.
    has_valid = (rgb is not None or any(i.nchannels in (2, 4) for i in infos)
                 or any(v is not None for v in getattr(source, "valid", [])))
    thumb = Thumbnail(h, w, nch, thumbnail) if thumbnail else None
    keep = ArraySink(h, w, nch) if keep_radiance else None
    mask = np.zeros((h, w), bool) if ghost_mask is not None else None
    clips = np.zeros((h, w), np.uint8) if clip_mask is not None else None
    # A second output is staged first: a full disk fails here, before the radiance exists.
    staged = stage_text(save_response, resp.to_json()) if save_response is not None else None
    try:
        factors, units = _radiometric_factors(paths, infos, source, rel, resp, weight, rgb, device, nch,
                                              neutral, reference_patch, absolute, h, w)
        meta = _provenance(result, source_name)
        meta.update(units)
        unit = units.get("units", "relative")
        t_ref = reference_for(output, rel, reference_exposure, unit)
        if unit == "relative":
            meta["referenceExposure"] = t_ref
        check = None
        if not calibrated and fit_exposures == "off":  # a given response: check the exposures only
            from hdrcl.core.exposure_fit import ExposureCheck
            from hdrcl.core.fusion import fusion_tables

            order = np.argsort(rel, kind="stable")
            check = ExposureCheck(np.log(rel[order]), fusion_tables(resp, source.dtype, nch, weight)[0],
                                  [paths[i] for i in order])
        meta["colorspace"] = colorspace
        if shifts is not None:
            from hdrcl.core.handheld import alignment_meta

            meta.update(alignment_meta(shifts, alignment))
        camera = camera_from_infos(infos, owner=owner, units=unit, exposure_time=t_ref)
        when = first.capture_time.strftime("%Y:%m:%d %H:%M:%S") if first.capture_time else None

        open_writer = radiance_opener(output, w, h, nch, meta, camera, compression=compression, timestamp=when,
                                      colorspace=colorspace)

        def run(file_sink, first_pass):
            # --- fuse (the encode and write happen in the writer's thread as strips come)
            sinks = [file_sink] + ([keep] if keep is not None and first_pass else [])
            sink = sinks[0] if len(sinks) == 1 else _Tee(*sinks)
            if factors is not None:
                from hdrcl.core.radiometry import ScaledSink

                sink = ScaledSink(sink, factors)
            if not first_pass and hasattr(source, "rewind"):
                source.rewind()
            counts, backend = stream_merge(source, rel, resp, sink, weight=weight, ignore_color=ignore,
                                           has_valid=has_valid, device=device,
                                           thumbnail=thumb if first_pass else None,
                                           deghost=deghost, ghost_mask=mask,
                                           ghost_reference=ghost_reference, ghost_threshold=ghost_threshold,
                                           exposure_check=check if first_pass else None, seconds=seconds,
                                           work=work, clip_mask=clips)
            result.backend = backend
            if check is not None and first_pass:
                _report_exposure_check(check, result, exposure_tolerance)
            return counts

        writer, counts, stored = fuse_to_file(open_writer, run, output=output, dtype=dtype, reference=t_ref,
                                              keep_units=unit != "relative", chain=chain)
        tw = _time.perf_counter()
        try:
            result.warnings += writer.close()
        except BaseException:
            writer.abort()
            raise
        seconds["write"] = _time.perf_counter() - tw
        result.stored = stored
        if chain is not None:
            result.vertical_illuminance = chain.vertical_illuminance
        if stored.note:
            msg = f"{output}: {stored.note}"
            result.warnings.append(msg)
            result.storage_note = stored.note
        if mask is not None:
            from hdrcl.io.writers import write_ldr

            write_ldr(ghost_mask, (mask.astype(np.uint8) * 255)[..., None])
        if clips is not None:
            from hdrcl.io.writers import write_ldr

            img = np.where(clips & 1, 255, np.where(clips & 2, 128, 0)).astype(np.uint8)
            write_ldr(clip_mask, img[..., None])
        if staged is not None:
            staged.commit()
        if keep_frames:
            result.kept = _kept_frames(source, grid)
    finally:
        if staged is not None:
            staged.discard()
        if hasattr(source, "close"):
            source.close()
    result.counts = counts
    result.radiance = keep.array if keep is not None else None
    result.thumbnail = thumb.array if thumb is not None else None
    if counts.get("no_data"):
        msg = f"{output}: {counts['no_data']} pixel-channels are invalid in every frame and were set to 0"
        logger.warning(msg)
        result.warnings.append(msg)
    if deghost:
        logger.info("%s: ghost pixels %.2f %%", output, 100.0 * counts.get("ghost", 0) / max(h * w, 1))
    result.stages = {k: seconds[k] for k in ("decode", "solve", "fuse", "encode", "write") if k in seconds}
    result.seconds = {"open": seconds["open"], "calibrate": seconds["calibrate"],
                      "fuse_and_write": _time.perf_counter() - t2}
    if "align" in seconds:  # within "calibrate" (the frames are aligned before the solve): a stage
        result.stages["align"] = seconds["align"]
    return result


def _align(frames, valid, times, device, crop: bool = False, model: str = "auto", names=None):
    """``(frames, valid, shifts, box)`` of :func:`hdrcl.core.handheld.align_bracket`
    (``box`` None without ``crop``)."""
    from hdrcl.core.handheld import align_bracket

    al = align_bracket(frames, valid, times, device, crop, model, names)
    return al.frames, al.valid, al.shifts, al.crop
