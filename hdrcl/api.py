"""The operations of hdrcl for scripts and pipelines, on arrays and on files.

The command line is a thin layer over these functions::

    import hdrcl
    resp = hdrcl.calibrate(["a.jpg", "b.jpg", "c.jpg"], times=[1/250, 1/60, 1/15])
    radiance = hdrcl.merge(["a.jpg", "b.jpg", "c.jpg"], times=[1/250, 1/60, 1/15], response=resp)
    photo = hdrcl.expose(radiance, resp, time=1/30)          # uint8 (H, W, 3)
"""
from __future__ import annotations

import logging
import os
import time as _time
from dataclasses import dataclass, field
from typing import List, Optional, Sequence, Union

import numpy as np

from .errors import InputError, UsageError
from .response import Response, recover_response

logger = logging.getLogger(__name__)

PathOrArray = Union[str, os.PathLike, np.ndarray]


@dataclass
class Bracket:
    """Decoded frames of one bracket set with their exposures.

    ``times`` are effective exposure times in seconds, relative to the first frame's
    aperture and ISO; ``valid`` holds one ``(H, W)`` mask per frame (or None: all valid).
    """

    frames: List[np.ndarray]
    times: np.ndarray
    valid: List[Optional[np.ndarray]]
    paths: List[str] = field(default_factory=list)
    infos: list = field(default_factory=list)
    grid: bool = False  # frames are the decimated sampling grid, not whole images

    @property
    def valid_all(self) -> Optional[np.ndarray]:
        masks = [v for v in self.valid if v is not None]
        if not masks:
            return None
        out = masks[0].copy()
        for m in masks[1:]:
            out &= m
        return out

    @property
    def camera(self) -> dict:
        if not self.infos:
            return {}
        i = self.infos[0]
        return {k: v for k, v in (("make", i.make), ("model", i.model), ("iso", i.iso)) if v is not None}


def _parse_ignore_color(ignore_color):
    if ignore_color is None:
        return None
    if isinstance(ignore_color, str):
        try:
            vals = tuple(int(v) for v in ignore_color.split(","))
        except ValueError:
            vals = ()
        if len(vals) != 3:
            raise UsageError(f"--ignore-color: expected R,G,B in 8-bit units, not '{ignore_color}'")
        ignore_color = vals
    vals = tuple(int(v) for v in ignore_color)
    if len(vals) != 3 or not all(0 <= v <= 255 for v in vals):
        raise UsageError(f"--ignore-color: expected three values 0-255, not {ignore_color}")
    return vals


def load_bracket(
    images: Sequence[PathOrArray],
    times: Optional[Sequence[float]] = None,
    *,
    times_file=None,
    ignore_color=None,
    valid: Optional[Sequence[Optional[np.ndarray]]] = None,
) -> Bracket:
    """Read (or wrap) a bracket set and resolve its exposures.

    Parameters
    ----------
    images : sequence of paths or arrays
        Paths are decoded with OpenImageIO (8/16-bit JPEG, PNG, TIFF; grey, RGB, RGBA);
        arrays must be ``(H, W)`` or ``(H, W, C)`` uint8/uint16.
    times : sequence of float, optional
        Exposure times in seconds (required for arrays). For files, the precedence is
        ``times``, then ``times_file``, then EXIF.
    times_file : path, optional
        HDRShop-style list or ``file seconds`` lines.
    ignore_color : (R, G, B) or "R,G,B", optional
        Pixels of exactly this colour (8-bit units) are invalid in that frame.
    valid : sequence of (H, W) bool arrays, optional
        Extra per-frame validity masks.
    """
    from . import metadata

    images = list(images)
    if len(images) < 2:
        name = os.fspath(images[0]) if images and not isinstance(images[0], np.ndarray) else "input"
        raise InputError(f"{name}: a bracket set needs at least two exposures")
    rgb = _parse_ignore_color(ignore_color)
    if all(isinstance(im, np.ndarray) for im in images):
        if times is None:
            raise UsageError("exposure times are required when the images are arrays")
        frames = []
        for k, im in enumerate(images):
            a = np.asarray(im)
            if a.ndim == 2:
                a = a[..., None]
            if a.dtype not in (np.uint8, np.uint16) or a.ndim != 3:
                raise UsageError(f"image {k}: expected (H, W[, C]) uint8 or uint16, got {a.dtype} {a.shape}")
            if a.shape != np.shape(frames[0] if frames else a):
                raise InputError(f"image {k}: size {a.shape} differs from image 0 {frames[0].shape}")
            frames.append(np.ascontiguousarray(a))
        exposures = metadata.resolve_exposures([f"image {k}" for k in range(len(frames))], times=times)
        masks: List[Optional[np.ndarray]] = [None] * len(frames)
        paths: List[str] = []
        infos: list = []
    elif any(isinstance(im, np.ndarray) for im in images):
        raise UsageError("give either file paths or arrays, not a mix")
    else:
        from .io import BracketReader

        paths = [os.fspath(p) for p in images]
        infos = read_infos(paths)
        exposures = metadata.resolve_exposures(paths, infos, times=times, times_file=times_file)
        with BracketReader(paths, infos) as reader:
            frames, masks = reader.read_all()
    if rgb is not None:
        from .io import ignore_color_mask

        masks = [(~ignore_color_mask(f, rgb)) if m is None else (m & ~ignore_color_mask(f, rgb))
                 for f, m in zip(frames, masks)]
    if valid is not None:
        masks = [m if v is None else (np.asarray(v, bool) if m is None else m & np.asarray(v, bool))
                 for m, v in zip(masks, valid)]
    rel = metadata.relative_exposures(exposures)
    return Bracket(frames=frames, times=np.asarray(rel, np.float64), valid=masks, paths=paths, infos=infos)


def read_infos(paths: Sequence[str]) -> list:
    """Headers of ``paths`` (no pixels decoded), read in parallel; InputError names the file."""
    import concurrent.futures

    from .io import read_info

    if len(paths) < 2:
        from .metadata import resolve_exposures

        resolve_exposures(paths)  # raises the "needs at least two exposures" error
    with concurrent.futures.ThreadPoolExecutor(max_workers=min(8, len(paths))) as pool:
        return list(pool.map(read_info, paths))


def memory_budget() -> int:
    """Bytes of decoded frames a calibrating merge may hold at once (``HDRCL_MEMORY_MB``).

    Above it, calibration reads a decimated grid in a first pass and fusion decodes the
    frames again strip by strip, so memory stays flat at the cost of a second decode.
    """
    try:
        mb = float(os.environ.get("HDRCL_MEMORY_MB", "1024"))
    except ValueError:
        raise UsageError(f"HDRCL_MEMORY_MB must be a number of megabytes, not {os.environ['HDRCL_MEMORY_MB']!r}")
    return int(mb * (1 << 20))


def _with_ignore(frames, valid, rgb):
    if rgb is None:
        return list(valid)
    from .io import ignore_color_mask

    return [(~ignore_color_mask(f, rgb)) if v is None else (v & ~ignore_color_mask(f, rgb))
            for f, v in zip(frames, valid)]


def _all_raw(paths) -> bool:
    from .raw import is_raw

    return bool(paths) and all(is_raw(p) for p in paths)


def _open_files(paths, times, times_file):
    from . import metadata
    from .io import check_compatible

    paths = [os.fspath(p) for p in paths]
    infos = read_infos(paths)
    exposures = metadata.resolve_exposures(paths, infos, times=times, times_file=times_file)
    check_compatible(infos)
    return paths, infos, np.asarray(metadata.relative_exposures(exposures), np.float64)


def _grid_bracket(paths, infos, rel, rgb) -> Bracket:
    """The decimated grid that sample selection uses, read in one streaming pass."""
    from .io import BracketReader
    from .sampling import grid_stride

    with BracketReader(paths, infos) as reader:
        frames, valid = reader.read_grid(grid_stride(reader.height, reader.width))
    return Bracket(frames=frames, times=rel, valid=_with_ignore(frames, valid, rgb), paths=paths, infos=infos,
                   grid=True)


def calibrate(
    images: Union[Sequence[PathOrArray], Bracket],
    times: Optional[Sequence[float]] = None,
    *,
    times_file=None,
    samples: Optional[int] = None,
    smoothness: Optional[float] = None,
    weight: str = "hat",
    ignore_color=None,
    seed: int = 0,
    fit_exposures: str = "auto",
    exposure_tolerance: Optional[float] = None,
) -> Response:
    """Recover the camera response from a bracket set.

    ``fit_exposures`` (``auto``, ``on``, ``off``): estimate each frame's relative
    exposure from the pixels (:func:`hdrcl.response.fit_exposures`) and report every
    frame whose metadata disagrees by more than ``exposure_tolerance`` stops (default
    0.5). ``auto`` uses the fitted value only for those frames, ``on`` for all, ``off``
    never fits. The times used are recorded per frame in ``Response.exposures``
    (``nominal``, ``fitted``, ``used``) and a merge of the same set uses them.

    Returns
    -------
    Response
        One curve per channel; ``save()`` writes it as JSON for ``--response``.

    Examples
    --------
    >>> resp = hdrcl.calibrate(paths, times_file="image_list.txt", ignore_color=(0, 0, 255))
    >>> resp.save("memorial.json")
    """
    if isinstance(images, Bracket):
        br = images
    elif len(images) and not any(isinstance(im, np.ndarray) for im in images):
        # Files: only the sampling grid is kept, so memory does not grow with the image.
        paths, infos, rel = _open_files(images, times, times_file)
        if _all_raw(paths):
            from .raw import linear_response

            logger.info("RAW input is linear; no calibration needed")
            resp = linear_response(3 if infos[0].nchannels >= 3 else 1)
            resp.camera = Bracket(frames=[], times=rel, valid=[], infos=infos).camera
            resp.exposures = [{"file": os.path.basename(p), "nominal": float(t), "fitted": None, "used": float(t)}
                              for p, t in zip(paths, rel)]
            return resp
        br = _grid_bracket(paths, infos, rel, _parse_ignore_color(ignore_color))
    else:
        br = load_bracket(images, times, times_file=times_file, ignore_color=ignore_color)
    from .metadata import format_time
    from .response import EXPOSURE_TOLERANCE_STOPS
    from .response import fit_exposures as _fit

    if fit_exposures not in ("auto", "on", "off"):
        raise UsageError(f"--fit-exposures: '{fit_exposures}' is not one of auto, on, off")
    tol = EXPOSURE_TOLERANCE_STOPS if exposure_tolerance is None else float(exposure_tolerance)
    names = br.paths or [f"image {k}" for k in range(len(br.frames))]
    used = np.asarray(br.times, np.float64)
    fitted = None
    if fit_exposures != "off" and len(br.frames) >= 3:
        # The fit always uses the paper's hat weights: their wide overlap between frames
        # conditions the exposure estimates better than a narrow weighting does (on the
        # Memorial set gaussian weights let the fit wander by up to 0.8 stops).
        fit = _fit(br.frames, br.times, valid=br.valid_all, samples=min(samples or 400, 400),
                   weight="hat", seed=seed, tolerance=tol, decimate=not br.grid)
        fitted = fit.fitted
        for k in np.flatnonzero(fit.flagged):
            logger.warning("%s: metadata says %s but the pixels say %s (%+.2f stops)%s", os.path.basename(names[k]),
                           format_time(fit.nominal[k]), format_time(fit.fitted[k]), fit.stops[k],
                           "" if fit_exposures != "auto" else "; using the fitted exposure")
        if fit_exposures == "on":
            used = fit.fitted.copy()
        elif fit.flagged.any():
            used = np.where(fit.flagged, fit.fitted, used)
    resp = recover_response(br.frames, used, valid=br.valid_all, samples=samples,
                            smoothness=smoothness, weight=weight, seed=seed, decimate=not br.grid)
    resp.camera = br.camera
    resp.exposures = [
        {"file": os.path.basename(n), "nominal": float(t), "fitted": None if fitted is None else float(f),
         "used": float(u)}
        for n, t, f, u in zip(names, br.times, fitted if fitted is not None else br.times, used)]
    return resp


def exposures_used(response: Response, bracket_times) -> np.ndarray:
    """The times a merge should use: those its response refined, when it was
    calibrated from this very set (same count and nominal values), else the nominal."""
    ex = response.exposures or []
    nominal = np.asarray(bracket_times, np.float64)
    if len(ex) == nominal.size and all("used" in e for e in ex) and np.allclose(
            [e["nominal"] for e in ex], nominal, rtol=1e-9):
        return np.asarray([e["used"] for e in ex], np.float64)
    return nominal


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
    shifts: Optional[list] = None  # (dy, dx) per frame when aligned
    nominal: Optional[np.ndarray] = None  # the set's own exposures before any refinement
    crop: Optional[tuple] = None  # (y0, y1, x0, x1) of the input kept, with align + crop

    def __post_init__(self):
        if not self.shape and self.radiance is not None:
            self.shape = tuple(self.radiance.shape)


def merge_bracket(
    bracket: Bracket,
    response: Optional[Response] = None,
    *,
    weight: str = "hat",
    samples: Optional[int] = None,
    smoothness: Optional[float] = None,
    seed: int = 0,
    device: Optional[str] = None,
    fit_exposures: str = "auto",
    exposure_tolerance: Optional[float] = None,
    deghost: bool = False,
) -> MergeResult:
    """Fuse a loaded :class:`Bracket`, calibrating from it when no response is given
    (then with the exposures that calibration refined, see :func:`calibrate`)."""
    from .fusion import fuse_frames

    t0 = _time.perf_counter()
    if response is None:
        response = calibrate(bracket, samples=samples, smoothness=smoothness, weight=weight, seed=seed,
                             fit_exposures=fit_exposures, exposure_tolerance=exposure_tolerance)
    t1 = _time.perf_counter()
    times = exposures_used(response, bracket.times)
    res = fuse_frames(bracket.frames, times, response, weight=weight, valid=bracket.valid, device=device,
                      deghost=deghost)
    t2 = _time.perf_counter()
    warnings = list(response.warnings)
    if res.counts.get("no_data"):
        warnings.append(f"{res.counts['no_data']} pixel-channels are invalid in every frame and were set to 0")
    return MergeResult(radiance=res.radiance, response=response, counts=res.counts, times=times,
                       paths=bracket.paths, backend=res.backend,
                       seconds={"calibrate": t1 - t0, "fuse": t2 - t1}, warnings=warnings,
                       nominal=np.asarray(bracket.times, np.float64))


def merge(
    images: Sequence[PathOrArray],
    times: Optional[Sequence[float]] = None,
    response: Union[Response, str, os.PathLike, None] = None,
    *,
    times_file=None,
    weight: str = "hat",
    ignore_color=None,
    samples: Optional[int] = None,
    smoothness: Optional[float] = None,
    device: Optional[str] = None,
    fit_exposures: str = "auto",
) -> np.ndarray:
    """Merge a bracket into a float32 radiance map ``(H, W, C)``.

    ``response`` may be a :class:`Response`, a path to a response JSON file, or None to
    calibrate from the set itself. Radiance is relative: a pixel that reads ``Zmid``
    in a 1 s exposure (at the first frame's aperture and ISO) has radiance about 1.
    """
    br = load_bracket(images, times, times_file=times_file, ignore_color=ignore_color)
    return merge_bracket(br, _as_response(response), weight=weight, samples=samples, smoothness=smoothness,
                         device=device, fit_exposures=fit_exposures).radiance


def _as_response(response) -> Optional[Response]:
    if response is None or isinstance(response, Response):
        return response
    return Response.load(response)


def expose(radiance: np.ndarray, response: Union[Response, str, os.PathLike], time: float,
           *, bits: Optional[int] = None, device: Optional[str] = None) -> np.ndarray:
    """Virtual photograph of ``radiance`` at exposure ``time`` seconds through ``response``."""
    from .exposure import render

    return render(radiance, _as_response(response), time, bits=bits, device=device)


def _provenance(result: MergeResult, response_source: str) -> dict:
    from .metadata import format_time

    r = result.response
    meta = {
        "software": "hdrcl",
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
    weight: str = "hat",
    ignore_color=None,
    samples: Optional[int] = None,
    smoothness: Optional[float] = None,
    seed: int = 0,
    dtype: str = "half",
    compression: str = "zip",
    device: Optional[str] = None,
    keep_radiance: bool = False,
    thumbnail: int = 0,
    fit_exposures: str = "auto",
    exposure_tolerance: Optional[float] = None,
    deghost: bool = False,
    ghost_mask: Union[str, os.PathLike, None] = None,
    neutral=None,
    reference_patch=None,
    absolute: bool = False,
    align: bool = False,
    crop: bool = False,
) -> MergeResult:
    """Merge image files into a radiance file (EXR, HDR, TIFF or PFM by extension).

    The frames are decoded, fused and written strip by strip, with decoding, fusion and
    encoding overlapping, so memory stays bounded whatever the image size. Without a
    ``response`` the set calibrates itself: frames up to :func:`memory_budget` are held
    in memory for that; larger sets are read twice (a decimated grid, then the strips).
    The output is written atomically: nothing appears at ``output`` unless the whole
    merge succeeded.

    Parameters
    ----------
    keep_radiance : bool
        Also return the whole radiance map in ``result.radiance`` (memory grows with the
        image); otherwise it is None.
    thumbnail : int
        If > 0, ``result.thumbnail`` holds every k-th pixel of the radiance, with the
        long side about this many pixels (for previews).
    deghost : bool
        Take pixels where the frames disagree (moving objects) from the middle exposure
        alone (:mod:`hdrcl.deghost`); ``result.counts["ghost"]`` counts them.
    ghost_mask : path, optional
        With ``deghost``, also write the ghost mask as an 8-bit PNG/TIFF (255 = ghost).
    neutral : "x,y,w,h", optional
        White balance: scale the channels so this patch comes out neutral
        (:mod:`hdrcl.radiometry`).
    reference_patch : "x,y,w,h=VALUE", optional
        Absolute scale: the patch's mean luminance becomes VALUE (cd/m^2).
    absolute : bool
        Approximate absolute scale (cd/m^2) from the first frame's f-number and ISO.
    align : bool
        Align hand-held frames by translation (median threshold bitmaps, Ward 2003;
        :mod:`hdrcl.align`) to the middle exposure; ``result.shifts`` holds each
        frame's ``(dy, dx)``. Pixels a shifted frame no longer covers are masked in that
        frame. The frames are held in memory for this.
    crop : bool
        With ``align``: crop the output to the box every frame covers.
    """
    from .backend import get_processor
    from .io import BracketReader
    from .pipeline import ArraySink, ArraySource, Thumbnail, stream_merge
    from .writers import RADIANCE_EXTENSIONS, RadianceWriter

    output = os.fspath(output)
    ext = os.path.splitext(output)[1].lower()
    if ext not in RADIANCE_EXTENSIONS:
        raise UsageError(f"{output}: unsupported output type '{ext}'; use one of {', '.join(RADIANCE_EXTENSIONS)}")
    for target in (output, ghost_mask):
        if target is not None and not os.path.isdir(os.path.dirname(os.path.abspath(os.fspath(target)))):
            raise UsageError(f"{os.fspath(target)}: output folder does not exist")
    rgb = _parse_ignore_color(ignore_color)
    if crop and not align:
        raise UsageError("--crop needs --align")
    if ghost_mask is not None and not deghost:
        raise UsageError("--ghost-mask needs --deghost")
    source_name = os.fspath(response) if isinstance(response, (str, os.PathLike)) else (
        "given" if response is not None else "calibrated from these frames")
    resp = _as_response(response)
    t0 = _time.perf_counter()
    paths, infos, rel = _open_files(paths, times, times_file)
    warm = _warm_up(device, calibrating=resp is None)
    first = infos[0]
    nch = 3 if first.nchannels >= 3 else 1
    h, w = first.height, first.width
    if resp is None and _all_raw(paths):
        from .raw import linear_response

        resp, source_name = linear_response(nch), "linear (RAW input)"
        resp.exposures = [{"file": os.path.basename(p), "nominal": float(t), "fitted": None, "used": float(t)}
                          for p, t in zip(paths, rel)]
    t1 = _time.perf_counter()
    shifts = crop_box = None
    itemsize = 1 if first.bits == 8 else 2
    in_memory = align or (resp is None and len(paths) * h * w * nch * itemsize <= memory_budget())
    if in_memory:
        with BracketReader(paths, infos) as reader:
            frames, valid = reader.read_all()
        valid = _with_ignore(frames, valid, rgb)
        if align:
            frames, valid, shifts, box = _align(frames, valid, rel, device)
            if crop:
                y0, y1, x0, x1 = crop_box = box
                frames = [np.ascontiguousarray(f[y0:y1, x0:x1]) for f in frames]
                valid = [None if v is None else np.ascontiguousarray(v[y0:y1, x0:x1]) for v in valid]
                h, w = y1 - y0, x1 - x0
        if resp is None:
            br = Bracket(frames=frames, times=rel, valid=valid, paths=paths, infos=infos)
            resp = calibrate(br, samples=samples, smoothness=smoothness, weight=weight, seed=seed,
                             fit_exposures=fit_exposures, exposure_tolerance=exposure_tolerance)
        source = ArraySource(frames, valid)
        ignore = None
    elif resp is None:
        resp = calibrate(_grid_bracket(paths, infos, rel, rgb), samples=samples, smoothness=smoothness,
                         weight=weight, seed=seed, fit_exposures=fit_exposures,
                         exposure_tolerance=exposure_tolerance)
        source = BracketReader(paths, infos)
        ignore = rgb
    else:
        source = BracketReader(paths, infos)
        ignore = rgb
    nominal = rel
    rel = exposures_used(resp, rel)
    t2 = _time.perf_counter()
    warm.join()
    backend = "numpy" if get_processor("fusion", device) is None else "opencl"
    result = MergeResult(radiance=None, response=resp, counts={}, times=rel, paths=paths, backend=backend,
                         shape=(h, w, nch), warnings=list(resp.warnings), output=output, shifts=shifts,
                         nominal=nominal, crop=crop_box)
    # Any per-frame mask (alpha, ignore colour, or pixels an aligned frame lost) must
    # reach the kernel.
    has_valid = (rgb is not None or any(i.nchannels in (2, 4) for i in infos)
                 or any(v is not None for v in getattr(source, "valid", [])))
    thumb = Thumbnail(h, w, nch, thumbnail) if thumbnail else None
    keep = ArraySink(h, w, nch) if keep_radiance else None
    mask = np.zeros((h, w), bool) if ghost_mask is not None else None
    try:
        factors, units = _radiometric_factors(paths, infos, source, rel, resp, weight, rgb, device, nch,
                                              neutral, reference_patch, absolute, h, w)
        meta = _provenance(result, source_name)
        meta.update(units)
        if shifts is not None:
            meta["alignShifts"] = [list(map(int, sh)) for sh in shifts]
        with RadianceWriter(output, w, h, nch, dtype=dtype, compression=compression, metadata=meta) as writer:
            sink = writer if keep is None else _Tee(writer, keep)
            if factors is not None:
                from .radiometry import ScaledSink

                sink = ScaledSink(sink, factors)
            counts, backend = stream_merge(source, rel, resp, sink, weight=weight, ignore_color=ignore,
                                           has_valid=has_valid, device=device, thumbnail=thumb,
                                           deghost=deghost, ghost_mask=mask)
        result.warnings += writer.warnings
        if mask is not None:
            from .writers import write_ldr

            write_ldr(ghost_mask, (mask.astype(np.uint8) * 255)[..., None])
    finally:
        if hasattr(source, "close"):
            source.close()
    result.counts = counts
    result.backend = backend
    result.radiance = keep.array if keep is not None else None
    result.thumbnail = thumb.array if thumb is not None else None
    if counts.get("no_data"):
        msg = f"{output}: {counts['no_data']} pixel-channels are invalid in every frame and were set to 0"
        logger.warning(msg)
        result.warnings.append(msg)
    if deghost:
        logger.info("%s: ghost pixels %.2f %%", output, 100.0 * counts.get("ghost", 0) / max(h * w, 1))
    result.seconds = {"open": t1 - t0, "calibrate": t2 - t1, "fuse_and_write": _time.perf_counter() - t2}
    return result


def _align(frames, valid, times, device):
    """Shift ``frames`` onto the middle exposure; returns frames, masks, shifts, common box."""
    from .align import apply_shifts, estimate_shifts
    from .metadata import format_time

    order = np.argsort(np.asarray(times, np.float64), kind="stable")
    est = estimate_shifts([frames[i] for i in order], device=device)
    shifts = [None] * len(frames)
    for pos, i in enumerate(order):
        shifts[i] = tuple(int(v) for v in est[pos])
    for i, sh in enumerate(shifts):
        logger.info("align: frame %d (%s) shifted by dy=%d dx=%d", i, format_time(times[i]), sh[0], sh[1])
    out, masks, box = apply_shifts(frames, shifts, valid)
    return list(out), list(masks), shifts, box


def _warm_up(device, calibrating: bool):
    """Open the OpenCL device (and import the solver) on a helper thread while the
    frames decode: both take a few tenths of a second that need not add up."""
    import threading

    def work():
        try:
            if calibrating:
                import scipy.sparse  # noqa: F401
            from .backend import get_processor

            get_processor("fusion", device)
        except Exception:  # the main thread meets the same error and reports it
            pass

    t = threading.Thread(target=work, name="hdrcl-warm-up", daemon=True)
    t.start()
    return t


def _radiometric_factors(paths, infos, source, rel, resp, weight, rgb, device, nch, neutral, reference_patch,
                         absolute, h, w):
    """Per-channel factors (or None) and metadata for white balance and absolute scale."""
    from . import radiometry as rm

    if reference_patch is not None and absolute:
        raise UsageError("--absolute and --reference-patch both set the scale; give one")
    units = {"units": "relative"}
    if neutral is None and reference_patch is None and not absolute:
        return None, units
    factors = np.ones(nch)  # h, w: the output's size (cropped when aligned with --crop)

    def patch_radiance(patch):
        from .fusion import fuse_frames

        x, y, pw, ph = patch
        if hasattr(source, "frames"):  # in memory already
            frames = [f[y:y + ph, x:x + pw] for f in source.frames]
            valid = [None if v is None else v[y:y + ph, x:x + pw] for v in source.valid]
        else:
            from .io import BracketReader

            with BracketReader(paths, infos) as reader:
                fs, vs = reader.read_rows(y, y + ph)
            frames = [np.ascontiguousarray(f[:, x:x + pw]) for f in fs]
            valid = _with_ignore(frames, [None if v is None else v[:, x:x + pw] for v in vs], rgb)
        return fuse_frames(frames, rel, resp, weight=weight, valid=valid, device=device).radiance

    if neutral is not None:
        patch = rm.parse_patch(neutral, "--neutral")
        rm.check_patch(patch, h, w, "--neutral")
        gains = rm.neutral_gains(patch_radiance(patch))
        factors *= gains
        units["whiteBalance"] = [round(float(g), 6) for g in gains]
    if reference_patch is not None:
        patch, value = rm.parse_reference_patch(reference_patch)
        rm.check_patch(patch, h, w, "--reference-patch")
        scale = rm.patch_scale(patch_radiance(patch) * factors, value)
        factors *= scale
        units.update({"units": "cd/m2", "scaleSource": f"reference patch {patch} = {value:g} cd/m2",
                      "scale": float(scale)})
    elif absolute:
        scale = rm.exif_scale(infos[0].fnumber, infos[0].iso)
        factors *= scale
        units.update({"units": "cd/m2 (approximate)",
                      "scaleSource": f"K N^2/ISO, K={rm.METER_K:g}, N={infos[0].fnumber:g}, ISO={infos[0].iso:g}",
                      "scale": float(scale)})
    return factors, units


class _Tee:
    def __init__(self, *sinks):
        self.sinks = sinks

    def write_rows(self, y0, y1, data):
        for s in self.sinks:
            s.write_rows(y0, y1, data)


def expose_file(
    radiance_path: Union[str, os.PathLike],
    output: Union[str, os.PathLike],
    response: Union[Response, str, os.PathLike],
    time: float,
    *,
    bits: Optional[int] = None,
    device: Optional[str] = None,
    motion_blur: Optional[tuple] = None,
) -> np.ndarray:
    """Render a radiance file as a virtual photograph file (JPEG, PNG or TIFF).

    ``motion_blur=(dx, dy)`` first blurs the radiance along that vector
    (:func:`hdrcl.radiometry.motion_blur`), as a camera moving during the exposure would.
    """
    from .writers import LDR_EXTENSIONS, read_radiance, write_ldr

    output = os.fspath(output)
    ext = os.path.splitext(output)[1].lower()
    if ext not in LDR_EXTENSIONS:
        raise UsageError(f"{output}: unsupported output type '{ext}'; use one of {', '.join(LDR_EXTENSIONS)}")
    if ext in (".jpg", ".jpeg") and bits == 16:
        raise UsageError(f"{output}: JPEG holds 8 bits; use .png or .tif for 16-bit output")
    resp = _as_response(response)
    rad, _meta = read_radiance(radiance_path)
    if motion_blur is not None:
        from .radiometry import motion_blur as _blur

        rad = _blur(rad, *motion_blur)
    if ext in (".jpg", ".jpeg"):
        bits = 8
    img = expose(rad, resp, time, bits=bits, device=device)
    from .metadata import format_time

    write_ldr(output, img, metadata={"exposure": float(time), "exposureText": format_time(time),
                                     "source": os.path.basename(os.fspath(radiance_path))})
    return img


def write_quality_report(result: MergeResult, folder: Union[str, os.PathLike], *, ignore_color=None,
                         weight: str = "hat", device: Optional[str] = None, name: Optional[str] = None,
                         loo: bool = True):
    """Quality figures of a file merge and their report in ``folder``.

    Writes the response plot, coverage map, preview and JSON of the set, and an
    ``index.html`` contact sheet (:mod:`hdrcl.report`). The frames are read again: whole
    when they fit :func:`memory_budget`, else as the sampling grid (the clipping and
    coverage figures are then on that grid).

    Returns
    -------
    (QualityFigures, ReportEntry)
    """
    from .io import BracketReader
    from .quality import measure
    from .report import write_contact_sheet, write_set_report
    from .sampling import grid_stride

    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    paths = result.paths
    infos = read_infos(paths)
    rgb = _parse_ignore_color(ignore_color)
    h, w, c = result.shape
    with BracketReader(paths, infos) as reader:
        if result.shifts is not None or len(paths) * h * w * c * reader.dtype.itemsize <= memory_budget():
            frames, valid = reader.read_all()
        else:
            frames, valid = reader.read_grid(grid_stride(h, w))
    valid = _with_ignore(frames, valid, rgb)
    if result.shifts is not None:  # measure what was merged: the aligned (and cropped) frames
        from .align import apply_shifts

        frames, valid, _box = apply_shifts(frames, result.shifts, valid)
        frames, valid = list(frames), list(valid)
        if result.crop is not None:
            y0, y1, x0, x1 = result.crop
            frames = [np.ascontiguousarray(f[y0:y1, x0:x1]) for f in frames]
            valid = [None if v is None else v[y0:y1, x0:x1] for v in valid]
    nominal = result.nominal if result.nominal is not None else result.times
    br = Bracket(frames=frames, times=np.asarray(nominal), valid=valid, paths=paths, infos=infos)
    preview = result.thumbnail if result.thumbnail is not None else result.radiance
    fig = measure(br, result.response, preview, weight=weight, times=result.times, device=device, loo=loo)
    stem = name or os.path.splitext(os.path.basename(result.output or paths[0]))[0]
    entry = write_set_report(folder, stem, fig, result.response, preview, fig.coverage, warnings=result.warnings)
    write_contact_sheet(folder, [entry])
    return fig, entry
