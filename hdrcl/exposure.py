"""Virtual photographs from a radiance map: the OpenCL kernel or its NumPy twin."""
from __future__ import annotations

from typing import Optional

import numpy as np

from . import reference
from .backend import get_processor
from .errors import UsageError
from .response import Response


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
        out = proc.expose(rad, tables, float(np.log(time)), bits)
    return out[..., 0] if squeeze else out
