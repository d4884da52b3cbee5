"""Measures of how well a merge explains its own photographs.

Leave-one-out reciprocity: merge every frame but one, render the missing frame at its
own exposure through the recovered curve, and compare with the real frame. The error is
in the photograph's code values, over the pixels the real frame holds in its working
range. It tests the response, the exposure times and the fusion together.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional

import numpy as np

from .api import Bracket, calibrate, merge_bracket
from .exposure import render


@dataclass
class LeaveOneOut:
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
    weight: str = "hat",
    device: Optional[str] = None,
    fit_exposures: str = "auto",
) -> LeaveOneOut:
    """RMSE (8-bit levels) of frame ``index`` rendered from a merge of the others.

    The merge calibrates its own response from the remaining frames (with
    ``fit_exposures`` as :func:`hdrcl.api.calibrate`) and renders the missing frame at
    ``bracket.times[index]``: pass refined times to measure a refined set. Pixel-channels
    count where the real frame reads within ``[low, high]`` (8-bit units; scaled for
    16-bit data) and the pixel is valid in that frame.
    """
    keep = [k for k in range(len(bracket.frames)) if k != index]
    sub = Bracket(frames=[bracket.frames[k] for k in keep], times=bracket.times[keep],
                  valid=[bracket.valid[k] for k in keep])
    resp = calibrate(sub, smoothness=smoothness, samples=samples, weight=weight, fit_exposures=fit_exposures)
    res = merge_bracket(sub, resp, weight=weight, device=device)
    real = bracket.frames[index]
    scale = 1.0 if real.dtype == np.uint8 else 257.0
    rendered = render(res.radiance, resp, float(bracket.times[index]), device=device)
    r = real.astype(np.float64) / scale
    v = rendered.astype(np.float64) / scale
    mask = (r >= low) & (r <= high)
    if bracket.valid[index] is not None:
        mask &= bracket.valid[index][..., None]
    d = (v - r)[mask]
    rmse = float(np.sqrt(np.mean(d * d))) if d.size else float("nan")
    return LeaveOneOut(index=index, time=float(bracket.times[index]), rmse=rmse, pixels=int(d.size))


def leave_one_out_all(bracket: Bracket, interior_only: bool = True, **kw) -> List[LeaveOneOut]:
    """:func:`leave_one_out` for every frame (by default not the shortest and longest)."""
    order = np.argsort(bracket.times)
    idx = order[1:-1] if interior_only else order
    return [leave_one_out(bracket, int(k), **kw) for k in idx]
