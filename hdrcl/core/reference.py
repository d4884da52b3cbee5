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


def fuse(
    frames: Sequence[np.ndarray],
    log_times: Sequence[float],
    tables: np.ndarray,
    weights: np.ndarray,
    valid: Optional[Sequence[Optional[np.ndarray]]] = None,
):
    """Radiance map of a bracket (kernel: ``kernels/fusion.cl``, ``fuse``).

    For each pixel i and channel c::

        ln E = sum_j w(Z_j) (g_c(Z_j) - ln dt_j) / sum_j w(Z_j)

    over the frames j where the pixel is valid. Where the weights sum to zero (every
    valid sample clipped), the rule is: if the shortest valid exposure reads in the upper
    half of the codes (``2 Z >= L``) the pixel is clipped high and
    ``ln E = g_c(Zmax) - ln dt_shortest``; otherwise it is black and
    ``ln E = g_c(Zmin) - ln dt_longest``. A pixel valid in no frame is 0.

    Parameters
    ----------
    frames : sequence of ndarray, each (H, W, C) integer codes
        Ordered by increasing exposure.
    log_times : sequence of float
        ``ln dt_j`` in the same order.
    tables : ndarray (C, L)
        Response ``g`` per channel at every code.
    weights : ndarray (L,)
        ``w(z)``.
    valid : sequence of (H, W) bool or None, optional
        Per frame; None means every pixel is valid.

    Returns
    -------
    radiance : ndarray (H, W, C) float64
        Linear relative radiance ``E``.
    counts : dict
        ``clipped_high``, ``clipped_low``, ``no_data``: samples (pixel-channels) that
        took each rule.
    """
    p = len(frames)
    h, w, c = frames[0].shape
    log_t = np.asarray(log_times, np.float64)
    num = np.zeros((h, w, c))
    den = np.zeros((h, w, c))
    first_z = np.full((h, w, c), -1, np.int64)
    first_p = np.full((h, w), -1, np.int64)
    last_p = np.full((h, w), -1, np.int64)
    chan = np.arange(c)
    for j in range(p):
        z = frames[j].astype(np.int64)
        ok = np.ones((h, w), bool) if valid is None or valid[j] is None else np.asarray(valid[j], bool)
        wz = np.where(ok[..., None], weights[z], 0.0)
        num += wz * (tables[chan, z] - log_t[j])
        den += wz
        newly = ok & (first_p < 0)
        first_p[newly] = j
        first_z[newly] = z[newly]
        last_p[ok] = j
    out = np.zeros((h, w, c))
    pos = den > 0
    out[pos] = np.exp(num[pos] / den[pos])
    anyv = (first_p >= 0)[..., None] & np.ones((1, 1, c), bool)
    zero = ~pos & anyv
    levels = tables.shape[1]
    high = zero & (2 * first_z >= levels)
    low = zero & ~high
    cc = np.broadcast_to(chan, (h, w, c))
    fp = np.broadcast_to(first_p[..., None], (h, w, c))
    lp = np.broadcast_to(last_p[..., None], (h, w, c))
    out[high] = np.exp(tables[cc[high], levels - 1] - log_t[fp[high]])
    out[low] = np.exp(tables[cc[low], 0] - log_t[lp[low]])
    counts = {
        "clipped_high": int(high.sum()),
        "clipped_low": int(low.sum()),
        "no_data": int((~anyv).sum()),
    }
    return out, counts


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
