"""Clipping figures of the quality report: how many frames measure each pixel (the
coverage), which pixels no frame measures above or below, and how much more exposure a
further frame would need (:func:`hdrcl.report.quality.measure` calls
:func:`clipping_figures`; its Notes define them)."""
from __future__ import annotations

from typing import Optional, Tuple

import numpy as np

from hdrcl.core.bracket import Bracket
from hdrcl.core.response import Response

#: Working range of a frame in 8-bit codes (x257 for 16-bit), as for leave-one-out:
#: codes read reliably, away from the noise floor and the shoulder.
WORKING_LOW, WORKING_HIGH = 10, 245
#: The coverage map's value for a pixel without valid data in any frame.
NO_DATA = 255


def clipping_figures(bracket: Bracket, used, response: Response, weight: str):
    """``(coverage, histogram, clipped high pixels, clipped low pixels, valid pixels,
    extra_ev_high, extra_ev_low)`` of :func:`measure` (see its Notes)."""
    frames, levels = bracket.frames, response.levels
    from hdrcl.core.reference import monotone_tables
    from hdrcl.core.weights import clip_levels

    h, w, c = frames[0].shape
    order = np.argsort(used, kind="stable")
    count, first_j, last_j, first_z, last_z, valid_px = _evidence_counts(frames, bracket.valid, order, levels,
                                                                          weight)
    # Coverage: frames measuring the least-measured channel. 0 exactly where some
    # channel is measured by no frame, so the clipped pixels are found among those.
    coverage = count[..., 0].copy()
    for ch in range(1, c):
        np.minimum(coverage, count[..., ch], out=coverage)
    all_valid = bool(valid_px.all())
    idx = np.flatnonzero(coverage == 0) if all_valid else np.flatnonzero((coverage == 0) & valid_px)
    unmeasured = count.reshape(-1, c)[idx] == 0
    zfirst, zlast = first_z.reshape(-1, c)[idx], last_z.reshape(-1, c)[idx]  # int codes
    zlo, zhi = clip_levels(levels)
    # Fusion's rule (hdrcl.core.reference.fuse): clipped high when the shortest valid frame
    # clips; else black when the longest valid one is at the noise floor; else (frames
    # that contradict each other) by the half of the range the shortest one reads in.
    upper = (zfirst >= zhi) | ((zlast > zlo) & (2 * zfirst.astype(np.int64) >= levels))
    high, low = unmeasured & upper, unmeasured & ~upper  # (pixels, channels)
    n_high, n_low = int(high.any(axis=1).sum()), int(low.any(axis=1).sum())
    n_valid = int(valid_px.sum())

    # Bounds on the exposure change (see Notes), over the clipped pixel-channels.
    g = monotone_tables(response.table_for(c))
    scale = (levels - 1) / 255.0
    z_top, z_bot = int(round(WORKING_HIGH * scale)), int(round(WORKING_LOW * scale))
    log2_t = np.log2(used[order])
    ln2 = np.log(2.0)
    extra_high = extra_low = 0.0
    if (high & (zfirst >= zhi)).any():  # contradicting frames prove no bound
        rows, cc = np.nonzero(high & (zfirst >= zhi))
        gap = (g[cc, zfirst[rows, cc]] - g[cc, z_top]) / ln2
        extra_high = float(np.min(log2_t[first_j.ravel()[idx[rows]]] - log2_t[0] - gap))
    if (low & (zlast <= zlo)).any():
        rows, cc = np.nonzero(low & (zlast <= zlo))
        gap = (g[cc, z_bot] - g[cc, zlast[rows, cc]]) / ln2
        extra_low = float(np.max(log2_t[last_j.ravel()[idx[rows]]] - log2_t[-1] + gap))

    if not all_valid:
        coverage[~valid_px] = NO_DATA
    hist = np.bincount(coverage.ravel(), minlength=256)[: len(frames) + 1]

    return coverage, hist, n_high, n_low, n_valid, extra_high, extra_low


def _evidence_counts(frames, valid, order, levels: int, weight: str):
    """Per pixel-channel, the number of frames fusion takes evidence from
    (:func:`hdrcl.core.reference.fuse`'s rule, see :func:`measure`), and per pixel the
    exposure ranks of its shortest and longest valid frame, the shortest one's codes and
    whether any frame is valid.

    Returns ``(count (H, W, C) uint8, first_j, last_j (H, W) int16, first_z, last_z
    (H, W, C) codes of the shortest and longest valid frame, valid_px (H, W) bool)``.
    """
    from hdrcl.core.weights import clip_levels, evidence_weights, weight_table

    h, w, c = frames[0].shape
    zlo, zhi = clip_levels(levels)
    evidence = (evidence_weights(levels, weight_table(levels, weight)) > 0).astype(np.uint8)  # by code
    span = _code_interval(evidence)
    count = np.zeros((h, w, c), np.uint8)
    done = np.zeros((h, w, c), bool)  # clipped in a shorter frame: no longer evidence
    first_j = np.full((h, w), -1, np.int16)  # rank (exposure order) of the shortest valid frame
    last_j = np.full((h, w), -1, np.int16)  # ... and of the longest
    first_z = np.zeros((h, w, c), frames[0].dtype)
    last_z = np.zeros((h, w, c), frames[0].dtype)
    for rank, j in enumerate(order):
        z, ok = frames[j], valid[j]
        if span is None:
            m = np.take(evidence, z)
        else:  # the usual table, one run of codes: two comparisons, not a gather through intp indices
            m = (z >= span[0]).view(np.uint8)
            m &= (z <= span[1]).view(np.uint8)
        m &= ~done  # (not m[done] = 0: no boolean-index pass)
        black = z <= zlo
        if ok is None:
            ok = np.ones((h, w), bool)
        else:
            m &= ok[..., None]
            black &= ok[..., None]
        count += m
        count *= ~black  # = 0 at the noise floor: this frame and every shorter one are no evidence
        done |= (z >= zhi) & ok[..., None]
        newly = ok & (first_j < 0)
        first_j[newly] = rank
        np.copyto(first_z, z, where=newly[..., None])
        last_j[ok] = rank
        np.copyto(last_z, z, where=ok[..., None])
    return count, first_j, last_j, first_z, last_z, first_j >= 0


def _code_interval(table: np.ndarray) -> Optional[Tuple[int, int]]:
    """``(first, last)`` when the codes where ``table`` is non-zero are one run, else None."""
    nz = np.flatnonzero(table)
    if nz.size == 0 or nz[-1] - nz[0] + 1 != nz.size:
        return None
    return int(nz[0]), int(nz[-1])
