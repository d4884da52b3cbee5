"""NumPy twins of the OpenCL kernels, in float64.

Each function writes the same equations as its kernel in ``kernels/``; tests hold the
kernels to these within float32 tolerance, and they are the fallback path when no
OpenCL device is available (``HDRCL_OPENCL=0``).

Conventions shared with the kernels
-----------------------------------
* Frames are ordered by increasing exposure; "shortest" and "longest" refer to that order.
* A sample (pixel, channel, frame) takes part only where the frame's pixel is valid.
* ``tables`` holds ``g_c(z)`` for every code value, shape ``(C, L)``.
"""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from hdrcl.core.weights import clip_levels, evidence_weights


def fuse(
    frames: Sequence[np.ndarray],
    log_times: Sequence[float],
    tables: np.ndarray,
    weights: np.ndarray,
    valid: Optional[Sequence[Optional[np.ndarray]]] = None,
    clip_mask: Optional[np.ndarray] = None,
):
    """Radiance map of a bracket (kernel: ``kernels/fusion.cl``, ``fuse`` and ``fuse_fix``).

    For each pixel i and channel c::

        ln E = sum_j w(Z_j) (g_c(Z_j) - ln dt_j) / sum_j w(Z_j)

    over the *evidence* frames j of that pixel-channel. With ``(lo, hi)`` =
    :func:`hdrcl.core.weights.clip_levels` (8-bit: 5 and 250), among the frames where the
    pixel is valid, in order of exposure: the shortest frame reading ``Z >= hi`` and every
    longer one give no evidence (the light clipped there, so a longer frame's 253 is no
    measurement), and neither do the longest frame reading ``Z <= lo`` and every shorter
    one (the noise floor). The evidence is what lies strictly between; codes outside
    ``(lo, hi)`` weigh 0 (:func:`hdrcl.core.weights.evidence_weights`).

    Where the evidence weighs nothing, the value is a bound its frames prove:

    * clipped high (the shortest valid frame reads ``Z >= hi``): the lower bound
      ``G_c(Z) - ln dt_shortest``, with ``G`` = running maximum of ``g``
      (:func:`bound_tables`); counted in ``clipped_high``;
    * else black (the longest valid frame reads ``Z <= lo``): the upper bound
      ``G'_c(Z) - ln dt_longest``, ``G'`` = running minimum of ``g`` from the top;
      counted in ``clipped_low``;
    * else (frames that contradict each other, or a bracket with a gap: a shorter frame
      black and the next one clipped) the weighted mean over every valid frame reading
      inside ``(lo, hi)``, or when there is none, the first rule if the shortest valid
      frame reads in the upper half (``2 Z >= L``), the second otherwise; counted in
      neither.
    * valid in no frame: 0, counted in ``no_data``.

    Hue: a camera renders a clipped channel white, not darker than the others. So a
    channel clipped high takes the largest value among the pixel's channels that are
    measured or clipped high (a pixel clipped high in every channel comes out neutral at
    its largest bound; a red light whose red alone is clipped keeps red the largest
    channel, not cyan). Mirror: a channel clipped low takes the smallest value among the
    measured and clipped-low channels. Both only move a value further inside its bound.

    Parameters
    ----------
    frames : sequence of ndarray, each (H, W, C) integer codes
        Ordered by increasing exposure.
    log_times : sequence of float
        ``ln dt_j`` in the same order.
    tables : ndarray (C, L)
        Response ``g`` per channel at every code.
    weights : ndarray (L,)
        ``w(z)`` (codes outside ``(lo, hi)`` are zeroed here).
    valid : sequence of (H, W) bool or None, optional
        Per frame; None means every pixel is valid.
    clip_mask : ndarray (H, W) uint8, optional
        Filled per pixel: bit 0 (1) some channel clipped high, bit 1 (2) some channel
        clipped low; 0 otherwise.

    Returns
    -------
    radiance : ndarray (H, W, C) float64
        Linear relative radiance ``E``.
    counts : dict
        ``clipped_high``, ``clipped_low``, ``no_data``: samples (pixel-channels) that
        took each rule.
    """
    h, w, c = frames[0].shape
    log_t = np.asarray(log_times, np.float64)
    tables = np.asarray(tables, np.float64)
    levels = tables.shape[1]
    zlo, zhi = clip_levels(levels)
    sums = _fusion_sums(frames, log_t, tables, evidence_weights(levels, weights), valid, zlo, zhi)
    num, den, num_all, den_all, first_z, last_z, first_p, last_p = sums
    out = np.zeros((h, w, c))
    pos = den > 0
    out[pos] = np.exp(num[pos] / den[pos])
    anyv = (first_p >= 0)[..., None] & np.ones((1, 1, c), bool)
    zero = ~pos & anyv
    high = zero & (first_z >= zhi)
    low = zero & ~high & (last_z <= zlo)
    _bound_values(out, zero & ~high & ~low, high, low, sums, tables, log_t)
    if c > 1:  # hue: see the docstring
        top = np.where(pos | high, out, -np.inf).max(axis=2, keepdims=True)
        out = np.where(high, top, out)
        bottom = np.where(pos | low, out, np.inf).min(axis=2, keepdims=True)
        out = np.where(low, bottom, out)
    if clip_mask is not None:
        clip_mask[...] = high.any(axis=2).astype(np.uint8) | (2 * low.any(axis=2)).astype(np.uint8)
    counts = {
        "clipped_high": int(high.sum()),
        "clipped_low": int(low.sum()),
        "no_data": int((~anyv).sum()),
    }
    return out, counts


def _fusion_sums(frames, log_t: np.ndarray, tables: np.ndarray, wts: np.ndarray, valid, zlo: int, zhi: int) -> tuple:
    """The walk of :func:`fuse` over the frames, shortest first: ``(num, den)``, the
    weighted sums of ``g - ln dt`` and of the weights over each value's evidence frames;
    ``(num_all, den_all)`` the same over every valid frame (the contradiction rule); the
    codes of the shortest and longest valid frames per value (``first_z``, ``last_z``,
    -1 where none) and their indices per pixel (``first_p``, ``last_p``)."""
    h, w, c = frames[0].shape
    num = np.zeros((h, w, c))
    den = np.zeros((h, w, c))
    num_all = np.zeros((h, w, c))  # over every valid frame: the contradiction rule
    den_all = np.zeros((h, w, c))
    done = np.zeros((h, w, c), bool)
    first_z = np.full((h, w, c), -1, np.int64)
    last_z = np.full((h, w, c), -1, np.int64)
    first_p = np.full((h, w), -1, np.int64)
    last_p = np.full((h, w), -1, np.int64)
    chan = np.arange(c)
    for j in range(len(frames)):
        z = frames[j].astype(np.int64)
        ok = np.ones((h, w), bool) if valid is None or valid[j] is None else np.asarray(valid[j], bool)
        ok3 = ok[..., None]
        black = ok3 & (z <= zlo)
        num[black] = 0.0  # this frame and every shorter one: no evidence
        den[black] = 0.0
        wz = np.where(ok3, wts[z], 0.0)
        term = wz * (tables[chan, z] - log_t[j])
        num_all += term
        den_all += wz
        take = ~done
        num += np.where(take, term, 0.0)
        den += np.where(take, wz, 0.0)
        done |= ok3 & (z >= zhi)  # every longer frame: no evidence
        newly = ok & (first_p < 0)
        first_p[newly] = j
        first_z[newly] = z[newly]
        last_p[ok] = j
        last_z[ok] = z[ok]
    return num, den, num_all, den_all, first_z, last_z, first_p, last_p


def _bound_values(out: np.ndarray, other: np.ndarray, high: np.ndarray, low: np.ndarray, sums: tuple,
                  tables: np.ndarray, log_t: np.ndarray) -> None:
    """The values of :func:`fuse` whose evidence weighs nothing, written into ``out``:
    ``other`` (frames that contradict each other) the weighted mean over every valid
    frame where that weighs something, else, like ``high`` and ``low``, the bound rules
    (the first if the shortest valid frame reads ``2 Z >= L``, else the second)."""
    _, _, num_all, den_all, first_z, last_z, first_p, last_p = sums
    h, w, c = out.shape
    levels = tables.shape[1]
    mixed = other & (den_all > 0)
    out[mixed] = np.exp(num_all[mixed] / den_all[mixed])
    high_like = high | (other & ~mixed & (2 * first_z >= levels))
    low_like = (low | other) & ~mixed & ~high_like
    cc = np.broadcast_to(np.arange(c), (h, w, c))
    fp = np.broadcast_to(first_p[..., None], (h, w, c))
    lp = np.broadcast_to(last_p[..., None], (h, w, c))
    ghi, glo = bound_tables(tables)
    out[high_like] = np.exp(ghi[cc[high_like], first_z[high_like]] - log_t[fp[high_like]])
    out[low_like] = np.exp(glo[cc[low_like], last_z[low_like]] - log_t[lp[low_like]])


def bound_tables(tables: np.ndarray) -> tuple:
    """``(G, G')`` for the bound rules of :func:`fuse`: the running maximum of ``g`` from
    code 0 (a lower bound never below a smaller code's) and the running minimum from the
    top code (an upper bound never above a larger code's). Equal to ``g`` where ``g``
    increases."""
    t = np.asarray(tables, np.float64)
    return np.maximum.accumulate(t, axis=1), np.minimum.accumulate(t[:, ::-1], axis=1)[:, ::-1]


def monotone_tables(tables: np.ndarray) -> np.ndarray:
    """Non-decreasing version of ``g`` used for inversion (running maximum)."""
    return np.maximum.accumulate(np.asarray(tables, np.float64), axis=1)


def expose(radiance: np.ndarray, tables: np.ndarray, log_time: float, out_bits: int = 8) -> np.ndarray:
    """Virtual photograph ``Z = g^-1(ln E + ln dt)`` (kernel: ``kernels/exposure.cl``).

    ``g`` is made non-decreasing (:func:`monotone_tables`) and inverted by linear
    interpolation between code values: with ``x = ln E + ln dt`` and ``k`` the largest
    code with ``g(k) <= x``, ``z = k + (x - g(k)) / (g(k+1) - g(k))``. ``x`` below
    ``g(0)``, ``E <= 0`` and NaN give 0; ``x >= g(L-1)`` and ``+inf`` give ``L-1``. The
    code is rescaled to the output depth, ``round(z (2^bits - 1) / (L - 1))``, rounding
    half up.

    Returns
    -------
    ndarray
        uint8 or uint16, same shape as ``radiance``.
    """
    g = monotone_tables(tables)
    levels = g.shape[1]
    rad = np.asarray(radiance, np.float64)
    c = rad.shape[-1]
    outmax = (1 << out_bits) - 1
    z = np.zeros(rad.shape)
    for ch in range(c):
        e = rad[..., ch]
        gc = g[ch]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.log(e) + log_time
        zc = np.zeros(e.shape)
        pos = e > 0
        top = pos & (x >= gc[-1])
        mid = pos & ~top & (x >= gc[0])
        k = np.searchsorted(gc, x[mid], side="right") - 1
        zc[mid] = k + (x[mid] - gc[k]) / (gc[k + 1] - gc[k])
        zc[top] = levels - 1
        z[..., ch] = zc
    v = np.floor(z * (outmax / (levels - 1)) + 0.5)
    v = np.clip(v, 0, outmax)
    return v.astype(np.uint8 if out_bits == 8 else np.uint16)
