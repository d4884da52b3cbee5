"""Choice between the OpenCL kernels and their NumPy twins.

``HDRCL_OPENCL=0`` selects the NumPy path (float64, much slower, said so in the log).
Otherwise OpenCL is used; if no device can be opened the NumPy path is taken with a
warning, unless ``HDRCL_REQUIRE_OPENCL=1`` (CI sets it), which makes that an error.
"""
from __future__ import annotations

import logging
import os
import threading
from typing import Optional

from hdrcl.errors import HdrclError

logger = logging.getLogger(__name__)

_warned = set()


def _flag(name: str) -> Optional[bool]:
    v = os.environ.get(name)
    if v is None or v.strip() == "":
        return None
    return v.strip().lower() not in ("0", "false", "no", "off")


def opencl_required() -> bool:
    return bool(_flag("HDRCL_REQUIRE_OPENCL"))


def opencl_enabled() -> bool:
    return _flag("HDRCL_OPENCL") is not False


def _warn_once(msg: str) -> None:
    if msg not in _warned:
        _warned.add(msg)
        logger.warning(msg)


def get_processor(kind: str, device: Optional[str] = None):
    """The process-wide OpenCL processor of ``kind`` ('fusion', 'exposure', 'align' or
    'tonemap'), or None.

    None means: use the NumPy twins (:mod:`hdrcl.core.reference`, :mod:`hdrcl.core.align`).
    """
    with _lock:
        return _get_processor(kind, device)


def _get_processor(kind: str, device: Optional[str]):
    if not opencl_enabled():
        if opencl_required():
            raise HdrclError("HDRCL_OPENCL=0 contradicts HDRCL_REQUIRE_OPENCL=1")
        _warn_once("OpenCL disabled (HDRCL_OPENCL=0): using the NumPy reference path, which is much slower")
        return None
    key = (kind, device)
    proc = _processors.get(key)
    if proc is not None:
        return proc
    try:
        if kind == "fusion":
            from hdrcl.cl.fusion import FusionProcessor as cls
        elif kind == "align":
            from hdrcl.cl.align import AlignProcessor as cls
        elif kind == "tonemap":
            from hdrcl.cl.tonemap import TonemapProcessor as cls
        else:
            from hdrcl.cl.exposure import ExposureProcessor as cls
        proc = cls(device=device)
    except HdrclError as exc:
        if opencl_required() or device is not None:
            raise
        _warn_once(f"{exc}; falling back to the NumPy reference path (much slower)")
        return None
    except Exception as exc:  # a broken driver or ICD raises all sorts
        if opencl_required() or device is not None:
            raise HdrclError(f"OpenCL could not be initialised: {exc}") from exc
        _warn_once(f"OpenCL could not be initialised ({exc}); using the NumPy reference path (much slower)")
        return None
    _processors[key] = proc
    return proc


_processors: dict = {}
_lock = threading.RLock()


def device_name(device: Optional[str] = None) -> str:
    """Human-readable name of what computes: the OpenCL device or 'NumPy'."""
    proc = get_processor("fusion", device)
    return "NumPy (reference path)" if proc is None else proc.ctx.name
