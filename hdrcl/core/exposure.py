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
    if not (time > 0 and np.isfinite(time)):
        raise UsageError(f"exposure time must be a positive number of seconds, not {time}")
    bits = response.bits if bits is None else int(bits)
    if bits not in (8, 16):
        raise UsageError(f"output depth must be 8 or 16 bits, not {bits}")
    rad = np.asarray(radiance, np.float32)
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
    from hdrcl.core.exposure import render

    return render(radiance, _as_response(response), time, bits=bits, device=device)


#: Longest ``--motion-blur`` in pixels: its cost grows with the length (one shifted
#: copy of the image per pixel), so a typo like 1e9 must not run for ever.
MAX_MOTION_BLUR = 1000


def _check_blur(blur, shape) -> None:
    """UsageError unless ``blur = (dx, dy)`` is finite and no longer than
    :data:`MAX_MOTION_BLUR` nor the image's diagonal (``shape``; None: not known yet)."""
    dx, dy = (float(v) for v in blur)
    text = f"{blur[0]:g},{blur[1]:g}"
    if not (np.isfinite(dx) and np.isfinite(dy)):
        raise UsageError(f"--motion-blur: {text} is not a finite length in pixels")
    length = float(np.hypot(dx, dy))
    limit, what = float(MAX_MOTION_BLUR), f"{MAX_MOTION_BLUR} pixels"
    if shape is not None:
        diagonal = float(np.hypot(shape[0], shape[1]))
        if diagonal < limit:
            limit, what = diagonal, f"the image diagonal ({diagonal:.0f} pixels)"
    if length > limit:
        raise UsageError(f"--motion-blur: {text} is {length:.3g} pixels long; at most {what}")


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
    it must be finite and at most :data:`MAX_MOTION_BLUR` pixels and the image diagonal long
    (UsageError otherwise).
    """
    from hdrcl.io.radiance import read_radiance
    from hdrcl.io.writers import LDR_EXTENSIONS, write_ldr

    output = os.fspath(output)
    ext = os.path.splitext(output)[1].lower()
    if ext not in LDR_EXTENSIONS:
        raise UsageError(f"{output}: unsupported output type '{ext}'; use one of {', '.join(LDR_EXTENSIONS)}")
    if ext in (".jpg", ".jpeg") and bits == 16:
        raise UsageError(f"{output}: JPEG holds 8 bits; use .png or .tif for 16-bit output")
    resp = _as_response(response)
    if motion_blur is not None:
        _check_blur(motion_blur, None)
    rad, _meta = read_radiance(radiance_path)
    if motion_blur is not None:
        _check_blur(motion_blur, rad.shape)
        from hdrcl.core.radiometry import motion_blur as _blur

        rad = _blur(rad, *motion_blur)
    if ext in (".jpg", ".jpeg"):
        bits = 8
    img = expose(rad, resp, time, bits=bits, device=device)
    from hdrcl.io.metadata import format_time

    write_ldr(output, img, metadata={"exposure": float(time), "exposureText": format_time(time),
                                     "source": os.path.basename(os.fspath(radiance_path))})
    return img
