"""Choice between the OpenCL kernels and their NumPy twins.

``HDRCL_OPENCL=0`` selects the NumPy path (float64, much slower, said so in the log).
Otherwise OpenCL is used; if no device can be opened the NumPy path is taken with a
warning, unless ``HDRCL_REQUIRE_OPENCL=1`` (CI sets it), which makes that an error.

Small jobs take the NumPy path too: starting OpenCL (importing pyopencl, opening the
driver and a context, loading the kernels) costs tenths of a second, more than the
kernels save on a job of under :data:`SMALL_WORK` pixel-samples (pixels x frames). A
caller that passes ``work`` to :func:`get_processor` gets None for such a job, unless a
device was asked for (``device`` or ``PYOPENCL_CTX``), ``HDRCL_REQUIRE_OPENCL`` is set,
or this process has already opened that device. ``HDRCL_SMALL_WORK`` sets the threshold
(0: always OpenCL). This module does not import pyopencl.
"""
from __future__ import annotations

import logging
import os
import threading
from typing import Optional

from hdrcl.errors import HdrclError

logger = logging.getLogger(__name__)

_warned = set()


def opencl_required() -> bool:
    from hdrcl.env import flag  # the one rule of every HDRCL_* variable (exit 2 on a value it does not take)

    return flag("HDRCL_REQUIRE_OPENCL")


def opencl_enabled() -> bool:
    from hdrcl.env import flag

    return flag("HDRCL_OPENCL")


def _warn_once(msg: str) -> None:
    if msg not in _warned:
        _warned.add(msg)
        logger.warning(msg)


#: Pixel-samples (pixels x frames) below which a job runs on the NumPy path when the
#: caller says how big it is. Measured on a 2-core x86-64 with Intel's CPU runtime and
#: the kernels in the program cache: NumPy's fusion of 3 8-bit RGB frames against
#: OpenCL's start-up (pyopencl import, driver, context, kernels) plus its fusion, each in
#: a fresh process, break even at about 0.6-0.8 M pixel-samples (0.3 M: NumPy 0.18 s,
#: OpenCL 0.33 s; 2.4 M: NumPy 0.94 s, OpenCL 0.47 s); whole merges (CPU time) at about
#: 0.5 M, the OpenCL start-up then overlapping the decoding.
SMALL_WORK = 600_000


def small_work() -> int:
    """The threshold in force: ``HDRCL_SMALL_WORK`` (an integer; 0 turns the small-job
    path off), else :data:`SMALL_WORK`."""
    from hdrcl.env import number

    n = number("HDRCL_SMALL_WORK")
    return SMALL_WORK if n is None else int(min(n, 1 << 62))


def _info_once(key: str, msg: str) -> None:
    if key not in _warned:
        _warned.add(key)
        logger.info(msg)


def get_processor(kind: str, device: Optional[str] = None, work: Optional[int] = None):
    """The process-wide OpenCL processor of ``kind`` ('fusion', 'exposure', 'align',
    'tonemap' or 'mertens'), or None.

    None means: use the NumPy twins (:mod:`hdrcl.core.reference`, :mod:`hdrcl.core.align.mtb`).

    Parameters
    ----------
    kind : str
    device : str, optional
        The device asked for (``--device``); None: ``PYOPENCL_CTX`` or hdrcl's choice.
    work : int, optional
        Pixel-samples the caller is about to process (pixels x frames of the job). Below
        :func:`small_work` the answer is None without pyopencl being imported, unless a
        device was named (``device`` or ``PYOPENCL_CTX``), ``HDRCL_REQUIRE_OPENCL`` is set
        or OpenCL is already open in this process. None (the default): no size rule.
        Every call of one job should pass the same ``work``.
    """
    with _lock:
        if work is not None and _small_job(kind, device, int(work)):
            return None
        return _get_processor(kind, device)


def _small_job(kind: str, device: Optional[str], work: int) -> bool:
    """True when the job of ``work`` pixel-samples should skip OpenCL (said once)."""
    if not opencl_enabled():
        return False  # _get_processor says why
    if device is not None or os.environ.get("PYOPENCL_CTX"):
        return False
    if opencl_required():
        return False
    # Not "OpenCL is open already": a job's backend is decided by the job alone, never by
    # what the process ran before (the same set gives the same bytes in any order).
    limit = small_work()
    if work >= limit:
        _info_once("small-work:opencl", f"OpenCL path: {work} pixel-samples, at least HDRCL_SMALL_WORK={limit}")
        return False
    _info_once("small-work:numpy", f"NumPy path: a small job ({work} pixel-samples, under HDRCL_SMALL_WORK={limit}); "
               "starting OpenCL would cost more than it saves")
    return True


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
        elif kind == "mertens":
            from hdrcl.cl.mertens import MertensProcessor as cls
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
