"""Virtual photographs from a radiance map: the OpenCL kernel or its NumPy twin."""
from __future__ import annotations

import os
from typing import Optional, Union

import numpy as np

from hdrcl.cl.backend import get_processor
from hdrcl.core import reference
from hdrcl.core.response import Response, _as_response
from hdrcl.errors import UsageError


def render(radiance: np.ndarray, response: Response, time: float, bits: Optional[int] = None,
           device: Optional[str] = None) -> np.ndarray:
    """``Z = g^-1(ln E + ln dt)`` for exposure ``time`` (seconds).

    Parameters
    ----------
    radiance : ndarray (H, W, C) or (H, W)
        Linear relative radiance, in the units the response's times define.
    response : Response
    time : float
        Exposure time of the virtual photograph, > 0.
    bits : {8, 16}, optional
        Output depth; default the response's own.
    """
    from hdrcl.io.exposure_lists import coerce_times

    (time,) = coerce_times([time], "time")
    bits = response.bits if bits is None else bits
    if str(bits) in ("8", "16"):
        bits = int(bits)
    if bits not in (8, 16):
        raise UsageError(f"bits: output depth must be 8 or 16, not {bits!r}")
    rad = np.asarray(radiance, np.float32)
    if rad.ndim not in (2, 3) or rad.size == 0:
        raise UsageError(f"radiance: expected an (H, W) or (H, W, C) array, not shape {rad.shape}")
    bad = int(np.count_nonzero(~np.isfinite(rad)))
    if bad:
        raise UsageError(f"radiance: {bad} NaN or infinite value(s); a radiance map must be finite")
    squeeze = rad.ndim == 2
    if squeeze:
        rad = rad[..., None]
    tables = response.table_for(rad.shape[2])
    proc = get_processor("exposure", device)
    if proc is None:
        out = reference.expose(rad, tables, float(np.log(time)), bits)
    else:
        out = proc.expose(rad, reference.monotone_tables(tables), float(np.log(time)), bits)
    return out[..., 0] if squeeze else out


def expose(radiance: np.ndarray, response: Union[Response, str, os.PathLike], time: float,
           *, bits: Optional[int] = None, device: Optional[str] = None) -> np.ndarray:
    """Virtual photograph of ``radiance`` at exposure ``time`` seconds through ``response``."""
    from hdrcl.core.exposure.virtual import render

    return render(radiance, _as_response(response), time, bits=bits, device=device)


#: Longest ``--motion-blur`` in pixels: its cost grows with the length (one shifted
#: copy of the image per pixel), so a typo like 1e9 must not run for ever.
MAX_MOTION_BLUR = 1000


def _check_blur_length(blur, shape) -> None:
    """UsageError unless no component of ``blur = (dx, dy)`` (finite: :func:`_check_blur`)
    is longer than the image (``shape``) and the whole is at most :data:`MAX_MOTION_BLUR`
    pixels long."""
    dx, dy = blur
    text = f"{dx:g},{dy:g}"
    if max(abs(dx), abs(dy)) > max(shape[:2]):
        raise UsageError(f"--motion-blur: {text} is longer than the image ({shape[1]}x{shape[0]})")
    length = float(np.hypot(dx, dy))
    if length > MAX_MOTION_BLUR:
        raise UsageError(f"--motion-blur: {text} is {length:.0f} pixels long; at most {MAX_MOTION_BLUR}")


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
    (:func:`hdrcl.core.radiometry.motion_blur`), as a camera moving during the exposure would;
    it must be finite, no component longer than the image and the whole at most
    :data:`MAX_MOTION_BLUR` pixels long (UsageError otherwise).
    """
    from hdrcl.io.radiance import read_radiance
    from hdrcl.io.ldr import LDR_EXTENSIONS, write_ldr

    from hdrcl.io.atomic import check_output

    output = os.fspath(output)
    ext = os.path.splitext(output)[1].lower()
    check_output(output, [radiance_path] + ([response] if isinstance(response, (str, os.PathLike)) else []),
                 what="photograph")
    if motion_blur is not None:
        motion_blur = _check_blur(motion_blur)
    if ext not in LDR_EXTENSIONS:
        raise UsageError(f"{output}: unsupported output type '{ext}'; use one of {', '.join(LDR_EXTENSIONS)}")
    if ext in (".jpg", ".jpeg") and bits == 16:
        raise UsageError(f"{output}: JPEG holds 8 bits; use .png or .tif for 16-bit output")
    resp = _as_response(response)
    rad, _meta = read_radiance(radiance_path, require_float=True)
    if motion_blur is not None:
        _check_blur_length(motion_blur, rad.shape)
        from hdrcl.core.radiometry import motion_blur as _blur

        rad = _blur(rad, *motion_blur)
    if ext in (".jpg", ".jpeg"):
        bits = 8
    img = expose(rad, resp, time, bits=bits, device=device)
    from hdrcl.io.metadata import format_time

    write_ldr(output, img, metadata={"exposure": float(time), "exposureText": format_time(time),
                                     "source": os.path.basename(os.fspath(radiance_path))})
    return img


def _check_blur(motion_blur) -> tuple:
    try:
        dx, dy = (float(v) for v in motion_blur)
    except (TypeError, ValueError):
        raise UsageError(f"--motion-blur: expected DX,DY in pixels, not {motion_blur!r}") from None
    if not (np.isfinite(dx) and np.isfinite(dy)):
        raise UsageError(f"--motion-blur: expected finite DX,DY in pixels, not {dx:g},{dy:g}")
    return dx, dy
