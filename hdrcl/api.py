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
        from .io import read_images

        paths = [os.fspath(p) for p in images]
        decoded = read_images(paths)
        frames = [d.pixels for d in decoded]
        masks = [d.valid for d in decoded]
        infos = [d.info for d in decoded]
        exposures = metadata.resolve_exposures(paths, infos, times=times, times_file=times_file)
    if rgb is not None:
        from .io import ignore_color_mask

        masks = [(~ignore_color_mask(f, rgb)) if m is None else (m & ~ignore_color_mask(f, rgb))
                 for f, m in zip(frames, masks)]
    if valid is not None:
        masks = [m if v is None else (np.asarray(v, bool) if m is None else m & np.asarray(v, bool))
                 for m, v in zip(masks, valid)]
    rel = metadata.relative_exposures(exposures)
    return Bracket(frames=frames, times=np.asarray(rel, np.float64), valid=masks, paths=paths, infos=infos)


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
) -> Response:
    """Recover the camera response from a bracket set.

    Returns
    -------
    Response
        One curve per channel; ``save()`` writes it as JSON for ``--response``.

    Examples
    --------
    >>> resp = hdrcl.calibrate(paths, times_file="image_list.txt", ignore_color=(0, 0, 255))
    >>> resp.save("memorial.json")
    """
    br = images if isinstance(images, Bracket) else load_bracket(images, times, times_file=times_file,
                                                                 ignore_color=ignore_color)
    resp = recover_response(br.frames, br.times, valid=br.valid_all, samples=samples,
                            smoothness=smoothness, weight=weight, seed=seed)
    resp.camera = br.camera
    names = br.paths or [f"image {k}" for k in range(len(br.frames))]
    resp.exposures = [{"file": os.path.basename(n), "nominal": float(t)} for n, t in zip(names, br.times)]
    return resp


@dataclass
class MergeResult:
    """A merged radiance map with what went into it."""

    radiance: np.ndarray
    response: Response
    counts: dict
    times: np.ndarray
    paths: List[str]
    backend: str
    seconds: dict = field(default_factory=dict)
    warnings: List[str] = field(default_factory=list)
    output: Optional[str] = None


def merge_bracket(
    bracket: Bracket,
    response: Optional[Response] = None,
    *,
    weight: str = "hat",
    samples: Optional[int] = None,
    smoothness: Optional[float] = None,
    seed: int = 0,
    device: Optional[str] = None,
) -> MergeResult:
    """Fuse a loaded :class:`Bracket`, calibrating from it when no response is given."""
    from .fusion import fuse_frames

    t0 = _time.perf_counter()
    if response is None:
        response = calibrate(bracket, samples=samples, smoothness=smoothness, weight=weight, seed=seed)
    t1 = _time.perf_counter()
    res = fuse_frames(bracket.frames, bracket.times, response, weight=weight, valid=bracket.valid, device=device)
    t2 = _time.perf_counter()
    warnings = list(response.warnings)
    if res.counts.get("no_data"):
        warnings.append(f"{res.counts['no_data']} pixel-channels are invalid in every frame and were set to 0")
    return MergeResult(radiance=res.radiance, response=response, counts=res.counts, times=bracket.times,
                       paths=bracket.paths, backend=res.backend,
                       seconds={"calibrate": t1 - t0, "fuse": t2 - t1}, warnings=warnings)


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
) -> np.ndarray:
    """Merge a bracket into a float32 radiance map ``(H, W, C)``.

    ``response`` may be a :class:`Response`, a path to a response JSON file, or None to
    calibrate from the set itself. Radiance is relative: a pixel that reads ``Zmid``
    in a 1 s exposure (at the first frame's aperture and ISO) has radiance about 1.
    """
    br = load_bracket(images, times, times_file=times_file, ignore_color=ignore_color)
    return merge_bracket(br, _as_response(response), weight=weight, samples=samples, smoothness=smoothness,
                         device=device).radiance


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
        "exposureText": ", ".join(format_time(t) for t in result.times),
        "response": response_source,
        "responseSmoothness": float(r.smoothness),
        "responseSamples": int(r.samples),
        "weight": r.weight,
        "clippedHigh": int(result.counts.get("clipped_high", 0)),
        "clippedLow": int(result.counts.get("clipped_low", 0)),
        "noData": int(result.counts.get("no_data", 0)),
        "backend": result.backend,
    }
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
    dtype: str = "half",
    compression: str = "zip",
    device: Optional[str] = None,
) -> MergeResult:
    """Merge image files into a radiance file (EXR, HDR, TIFF or PFM by extension).

    The output is written atomically: nothing appears at ``output`` unless the whole
    merge succeeded.
    """
    from .writers import RADIANCE_EXTENSIONS, write_radiance

    output = os.fspath(output)
    ext = os.path.splitext(output)[1].lower()
    if ext not in RADIANCE_EXTENSIONS:
        raise UsageError(f"{output}: unsupported output type '{ext}'; use one of {', '.join(RADIANCE_EXTENSIONS)}")
    if not os.path.isdir(os.path.dirname(os.path.abspath(output))):
        raise UsageError(f"{output}: output folder does not exist")
    source = os.fspath(response) if isinstance(response, (str, os.PathLike)) else (
        "given" if response is not None else "calibrated from these frames")
    resp = _as_response(response)
    t0 = _time.perf_counter()
    br = load_bracket(paths, times, times_file=times_file, ignore_color=ignore_color)
    t1 = _time.perf_counter()
    result = merge_bracket(br, resp, weight=weight, samples=samples, smoothness=smoothness, device=device)
    t2 = _time.perf_counter()
    result.warnings += write_radiance(output, result.radiance, dtype=dtype, compression=compression,
                                      metadata=_provenance(result, source))
    result.seconds.update({"read": t1 - t0, "write": _time.perf_counter() - t2})
    result.output = output
    return result


def expose_file(
    radiance_path: Union[str, os.PathLike],
    output: Union[str, os.PathLike],
    response: Union[Response, str, os.PathLike],
    time: float,
    *,
    bits: Optional[int] = None,
    device: Optional[str] = None,
) -> np.ndarray:
    """Render a radiance file as a virtual photograph file (JPEG, PNG or TIFF)."""
    from .writers import LDR_EXTENSIONS, read_radiance, write_ldr

    output = os.fspath(output)
    ext = os.path.splitext(output)[1].lower()
    if ext not in LDR_EXTENSIONS:
        raise UsageError(f"{output}: unsupported output type '{ext}'; use one of {', '.join(LDR_EXTENSIONS)}")
    if ext in (".jpg", ".jpeg") and bits == 16:
        raise UsageError(f"{output}: JPEG holds 8 bits; use .png or .tif for 16-bit output")
    resp = _as_response(response)
    rad, _meta = read_radiance(radiance_path)
    if ext in (".jpg", ".jpeg"):
        bits = 8
    img = expose(rad, resp, time, bits=bits, device=device)
    from .metadata import format_time

    write_ldr(output, img, metadata={"exposure": float(time), "exposureText": format_time(time),
                                     "source": os.path.basename(os.fspath(radiance_path))})
    return img
