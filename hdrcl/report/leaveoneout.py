"""Leave-one-out reciprocity: how well a merge explains its own photographs.

Merge every frame but one, render the missing frame at its own exposure through the
recovered curve, and compare with the real frame. The error is in the photograph's code
values, over the pixels the real frame holds in its working range. It tests the response,
the exposure times and the fusion together. The merge is the bracket's plan without frame
k, run by :mod:`hdrcl.core.executor`; :func:`hdrcl.report.quality.measure` reports the
median over the interior frames (``loo_rmse``).
"""
from __future__ import annotations

import os
import threading
from dataclasses import dataclass
from typing import List, Optional, Tuple

import numpy as np

from hdrcl.core.bracket import Bracket
from hdrcl.core.calibrate import calibrate
from hdrcl.core.exposure.virtual import render
from hdrcl.core.sources import ResponseSource
from hdrcl.core.weights import DEFAULT_WEIGHT


@dataclass
class LeaveOneOut:
    """Error of one frame rendered from the others (see :func:`leave_one_out`)."""

    index: int
    time: float
    rmse: float
    pixels: int


def leave_one_out(
    bracket: Bracket,
    index: int,
    *,
    low: int = 10,
    high: int = 245,
    smoothness: Optional[float] = None,
    samples: Optional[int] = None,
    weight: str = DEFAULT_WEIGHT,
    device: Optional[str] = None,
    fit_exposures: str = "auto",
    grid: Optional[Bracket] = None,
) -> LeaveOneOut:
    """RMSE (8-bit levels) of frame ``index`` rendered from a merge of the others.

    The merge is the bracket's plan without frame ``index``
    (:func:`hdrcl.core.plan.plan_merge` on the remaining frames, run by
    :mod:`hdrcl.core.executor`): it calibrates its own response from them (with
    ``fit_exposures`` as :func:`hdrcl.core.calibrate.calibrate`), fuses them at the
    exposures that curve used, and the missing frame is rendered at
    ``bracket.times[index]``: pass refined times to measure a refined set. Pixel-channels
    count where the real frame reads within ``[low, high]`` (8-bit units; scaled for
    16-bit data) and the pixel is valid in that frame. ``grid``, with ``fit_exposures="off"``:
    the bracket's sampling grid (:func:`hdrcl.core.sampling.grid_stride`, contiguous), which
    the curve's sample selection would decimate to: the same curve, no copy per solve.
    """
    from hdrcl.core.executor import finish, prepare, proceed
    from hdrcl.core.options import MergeOptions
    from hdrcl.core.plan import plan_merge

    keep = [k for k in range(len(bracket.frames)) if k != index]
    times = np.asarray(bracket.times, np.float64)
    sub = Bracket(frames=[bracket.frames[k] for k in keep], times=times[keep],
                  valid=[bracket.valid[k] for k in keep])
    options = MergeOptions(weight=weight, samples=samples, smoothness=smoothness, device=device,
                           fit_exposures=fit_exposures)
    plan = plan_merge(None, options, _Remeasured(keep, grid), bracket=sub, checks=False)
    run = prepare(plan)  # the curve: solved on several threads at once
    with _DEVICE_LOCK:  # the OpenCL kernels' arguments are shared: the fusions and renderings take turns
        res = finish(proceed(run))
        rendered = render(res.radiance, res.response, float(bracket.times[index]), device=device)
    del res, run
    rmse, n = _rmse_levels(bracket.frames[index], rendered, bracket.valid[index], low, high)
    return LeaveOneOut(index=index, time=float(bracket.times[index]), rmse=rmse, pixels=n)


class _Remeasured(ResponseSource):
    """The curve of a leave-one-out merge, solved from its frames as the merge's own
    calibration would be, with ``warn=False``: the re-solves' curves are a measuring
    device, not the user's response. With ``fit_exposures="off"``: what calibrate() does
    then, less its checks for the user's frames (nothing measurable, identical
    exposures), on the given sampling grid (``grid``, the whole bracket's; ``keep``
    the frames merged) when there is one: the same curve."""

    name = "leave-one-out"
    raw_linear = False

    def __init__(self, keep, grid: Optional[Bracket]):
        self.keep, self.grid = keep, grid

    def solve(self, run, sub):
        o = run.options
        if o.fit_exposures != "off":
            return calibrate(sub, smoothness=o.smoothness, samples=o.samples, weight=o.weight,
                             fit_exposures=o.fit_exposures, warn=False)
        from hdrcl.core.solve import recover_response

        g = self.grid
        cal = sub if g is None else Bracket(frames=[g.frames[k] for k in self.keep], times=sub.times,
                                            valid=[g.valid[k] for k in self.keep])
        return recover_response(cal.frames, cal.times, valid=cal.valid_all, samples=o.samples,
                                smoothness=o.smoothness, weight=o.weight, warn=False, decimate=g is None)


#: Serialises the leave-one-out fusions and renderings on the OpenCL device.
_DEVICE_LOCK = threading.Lock()


def _rmse_levels(real: np.ndarray, rendered: np.ndarray, valid, low: int, high: int) -> Tuple[float, int]:
    """RMSE in 8-bit levels of ``rendered`` against ``real`` over the pixel-channels the
    real frame reads within ``[low, high]`` (8-bit units) where ``valid``; exact integer
    differences (16-bit codes scaled by 1/257 after)."""
    scale = 1 if real.dtype == np.uint8 else 257
    mask = (real >= low * scale) & (real <= high * scale)
    if valid is not None:
        mask &= valid[..., None]
    n = int(np.count_nonzero(mask))
    if not n:
        return float("nan"), 0
    # Whole arrays, no gathers: float64 holds the integer differences and their sum of
    # squares exactly (below 2^53 for any frame the report measures).
    d = rendered.astype(np.float64).ravel()
    d -= real.ravel()
    d *= mask.ravel()
    return float(np.sqrt(np.dot(d, d) / n)) / scale, n


#: Threads that solve the leave-one-out curves at once (the fusions take turns):
#: ``HDRCL_REPORT_THREADS`` (a positive integer), else the cores, at most 4; read when a
#: report runs (None), so a bad value is refused then, not at import (:mod:`hdrcl.env`).
LOO_THREADS = None


def _loo_threads() -> int:
    from hdrcl.env import number

    if LOO_THREADS is not None:
        return LOO_THREADS
    n = number("HDRCL_REPORT_THREADS")
    return n if n is not None else max(1, min(4, os.cpu_count() or 1))


def leave_one_out_all(bracket: Bracket, interior_only: bool = True, **kw) -> List[LeaveOneOut]:
    """:func:`leave_one_out` for every frame (by default not the shortest and longest),
    the curves solved on up to :data:`LOO_THREADS` threads."""
    order = np.argsort(bracket.times)
    idx = [int(k) for k in (order[1:-1] if interior_only else order)]
    if kw.get("fit_exposures") == "off" and "grid" not in kw:
        from hdrcl.core.sampling import grid_stride

        s = grid_stride(*bracket.frames[0].shape[:2])
        kw["grid"] = Bracket(frames=[np.ascontiguousarray(f[::s, ::s]) for f in bracket.frames], times=bracket.times,
                             valid=[None if v is None else np.ascontiguousarray(v[::s, ::s]) for v in bracket.valid])
    threads = min(_loo_threads(), len(idx))
    if threads <= 1:
        return [leave_one_out(bracket, k, **kw) for k in idx]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(threads, thread_name_prefix="hdrcl-loo") as pool:
        return list(pool.map(lambda k: leave_one_out(bracket, k, **kw), idx))
