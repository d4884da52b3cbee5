"""Fusing a bracket held in memory into a radiance map: a thin caller of the streaming
path (:func:`hdrcl.core.pipeline.stream_merge`, array source and sink), the OpenCL kernel
or its NumPy twin."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

from hdrcl.cl.backend import get_processor
from hdrcl.core.pipeline import fusion_tables  # noqa: F401 (its home was here)
from hdrcl.core.response import Response


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
    from hdrcl.core.pipeline import ArraySink, ArraySource, FusionSpec, stream_merge

    frames = list(frames)
    h, w, nch = frames[0].shape
    vals = [None] * len(frames) if valid is None else list(valid)
    sink = ArraySink(h, w, nch)
    mask = np.zeros((h, w), bool) if deghost else None
    spec = FusionSpec(weight=weight, has_valid=any(v is not None for v in vals), device=device, deghost=deghost,
                      ghost_mask=mask, ghost_threshold=ghost_threshold, ghost_reference=ghost_reference,
                      clip_mask=clip_mask, processor=get_processor("fusion", device))
    counts, backend = stream_merge(ArraySource(frames, vals), times, response, sink, spec)
    return FusionResult(sink.array, counts, backend, mask)


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
