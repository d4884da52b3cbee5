"""Fusing a bracket into a radiance map: the OpenCL kernel or its NumPy twin."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

from hdrcl.cl.backend import get_processor
from hdrcl.core import reference
from hdrcl.core.response import Response
from hdrcl.core.weights import weight_table


@dataclass
class FusionResult:
    """A radiance map and what happened making it.

    ``counts`` are pixel-channel samples: ``clipped_high`` (the shortest valid frame
    reads at or above the clip level, :func:`hdrcl.core.weights.clip_levels`: no frame is
    evidence, the value is the lower bound that frame proves), ``clipped_low`` (the
    longest valid frame at the noise floor: its upper bound), ``no_data`` (invalid in
    every frame; 0). The rule is :func:`hdrcl.core.reference.fuse`'s.
    """

    radiance: np.ndarray
    counts: dict = field(default_factory=dict)
    backend: str = "opencl"
    ghost_mask: Optional[np.ndarray] = None


def fusion_tables(response: Response, dtype, nch: int, weight: str = "hat"):
    """``g`` per channel at every code, shape (C, L), and the weights (L,) for frames of
    ``dtype`` with ``nch`` channels; UsageError when the response's depth differs."""
    tables = response.table_for(nch)
    levels = tables.shape[1]
    if int(np.iinfo(dtype).max) + 1 != levels:
        from hdrcl.errors import UsageError

        raise UsageError(
            f"the response describes {response.bits}-bit images but the frames are "
            f"{8 * np.dtype(dtype).itemsize}-bit"
        )
    return tables, weight_table(levels, weight)


def fuse_frames(
    frames: Sequence[np.ndarray],
    times: Sequence[float],
    response: Response,
    *,
    weight: str = "hat",
    valid: Optional[Sequence[Optional[np.ndarray]]] = None,
    device: Optional[str] = None,
    deghost: bool = False,
    ghost_threshold: Optional[float] = None,
    ghost_reference=None,
    clip_mask: Optional[np.ndarray] = None,
) -> FusionResult:
    """Radiance map of ``frames`` with exposures ``times`` (any order) and ``response``.

    ``clip_mask``, an ``(H, W)`` uint8 array, receives each pixel's clip flags (1: some
    channel clipped high, 2: clipped low; :func:`hdrcl.core.reference.fuse`).

    ``deghost`` replaces pixels where the frames disagree beyond the set's own learnt
    residuals (``ghost_threshold`` spreads) by the reference exposure's own estimate
    (``ghost_reference``: middle, shortest, longest or an input index;
    :mod:`hdrcl.core.deghost`); ``counts`` then has ``ghost`` and ``ghost_unresolved``, and
    ``ghost_mask`` the (H, W) mask.
    """
    order = np.argsort(np.asarray(times, np.float64), kind="stable")
    frames = [frames[i] for i in order]
    log_t = np.log(np.asarray(times, np.float64)[order])
    vals = None if valid is None else [valid[i] for i in order]
    tables, wts = fusion_tables(response, frames[0].dtype, frames[0].shape[2], weight)
    proc = get_processor("fusion", device)
    if proc is None:
        rad, counts = reference.fuse(frames, log_t, tables, wts, vals, clip_mask=clip_mask)
        res = FusionResult(rad.astype(np.float32), counts, "numpy")
    else:
        rad, counts = proc.fuse(frames, log_t, tables, wts, vals, clip_mask=clip_mask)
        res = FusionResult(rad, counts, "opencl")
    if deghost:
        from hdrcl.core import deghost as dg

        ref = dg.reference_index(times, ghost_reference)
        model = dg.learn(frames, log_t, tables, wts, vals, ghost_threshold)
        mask = dg.find(frames, log_t, tables, vals, res.radiance, model)
        res.counts["ghost_unresolved"] = dg.replace(res.radiance, frames, log_t, tables, mask, vals, ref)
        res.counts["ghost"] = int(np.count_nonzero(mask))
        res.ghost_mask = mask
    return res


def radiance_bounds(response: Response, times: Sequence[float], nch: int) -> tuple:
    """Smallest and largest radiance a fusion of frames at ``times`` can produce.

    Every value is ``exp`` of a weighted mean of ``g(Z_j) - ln dt_j``, of a bound rule's
    single term (``g`` at some code, or its running maximum or minimum, minus one
    ``ln dt_j``), or, by the hue rule, another channel's value of the same pixel, so it
    lies within ``exp(min g - max ln dt)`` and ``exp(max g - min ln dt)``. Used to decide
    the storage before any strip is written.
    """
    tables = response.table_for(nch)
    lt = np.log(np.asarray(times, np.float64))
    return float(np.exp(tables.min() - lt.max())), float(np.exp(tables.max() - lt.min()))
