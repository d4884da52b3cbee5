"""Gaussian and Laplacian pyramids exactly as OpenCV builds them (float64): ``pyrDown``,
``pyrUp``, the depth of ``MergeMertens`` and the blend of weighted Laplacian pyramids.
Used by the exposure-fusion twin (:mod:`hdrcl.core.mertens`) and its band scheduler
(:mod:`hdrcl.core.mertens_bands`); ``kernels/mertens.cl`` writes the same operations.
"""
from __future__ import annotations

from typing import List, Optional, Sequence

import numpy as np

#: Kernel of OpenCV's pyrDown and pyrUp, one dimension.
_K5 = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0


def max_level(h: int, w: int) -> int:
    """OpenCV's pyramid depth: ``int(logf(min(h, w)) / logf(2))`` in float32."""
    m = np.float32(min(h, w))
    return int(np.float32(np.log(m, dtype=np.float32)) / np.float32(np.log(np.float32(2.0), dtype=np.float32)))


def level_size(n: int, levels: int) -> int:
    """Size of ``n`` after ``levels`` pyrDowns (each ``(n + 1) // 2``)."""
    for _ in range(levels):
        n = (n + 1) // 2
    return n


def reflect101(p: np.ndarray, n: int) -> np.ndarray:
    """OpenCV's BORDER_REFLECT_101 index for any integer ``p`` (arrays)."""
    p = np.asarray(p, np.int64)
    if n == 1:
        return np.zeros_like(p)
    while True:
        bad = (p < 0) | (p >= n)
        if not bad.any():
            return p
        p = np.where(p < 0, -p, np.where(p >= n, 2 * n - 2 - p, p))


def _down_axis(a: np.ndarray, axis: int) -> np.ndarray:
    n = a.shape[axis]
    m = (n + 1) // 2
    y = 2 * np.arange(m)
    out = 0.0
    for t in range(5):
        out = out + _K5[t] * np.take(a, reflect101(y + t - 2, n), axis=axis)
    return out


def pyr_down(a: np.ndarray) -> np.ndarray:
    """OpenCV ``pyrDown``: ``(h, w[, c])`` to ``((h + 1) // 2, (w + 1) // 2[, c])``."""
    return _down_axis(_down_axis(a, 0), 1)


def _up_axis(a: np.ndarray, axis: int, m: int) -> np.ndarray:
    n = a.shape[axis]
    y = np.arange(m)
    out = 0.0
    for t in range(5):
        j = reflect101(y + t - 2, 2 * n)
        coef = np.where(j % 2 == 0, 2.0 * _K5[t], 0.0)
        shape = [1] * a.ndim
        shape[axis] = m
        out = out + coef.reshape(shape) * np.take(a, j // 2, axis=axis)
    return out


def pyr_up(a: np.ndarray, h: int, w: int) -> np.ndarray:
    """OpenCV ``pyrUp`` of ``(n, m[, c])`` to ``(h, w[, c])`` (h = 2n or 2n - 1)."""
    return _up_axis(_up_axis(a, 0, h), 1, w)


def gaussian(img: np.ndarray, levels: int) -> List[np.ndarray]:
    """Levels 0 .. ``levels`` of the Gaussian pyramid (finest first)."""
    out = [img]
    for _ in range(levels):
        out.append(pyr_down(out[-1]))
    return out


def blend(imgs: Sequence[np.ndarray], vs: Sequence[np.ndarray], levels: int,
          top: Optional[np.ndarray] = None) -> np.ndarray:
    """``sum_l up^l( sum_k Lap_l(I_k) G_l(V_k) )`` over levels 0 .. ``levels``.

    ``top`` given: the blended result already collapsed at level ``levels`` (the coarse
    part, :mod:`hdrcl.core.mertens_bands`), which replaces ``sum_k G(I_k) G(V_k)`` there.
    Float64 ``(h, w, c)``.
    """
    acc: List = [0.0] * (levels + 1)
    for img, v in zip(imgs, vs):
        gi, gv = gaussian(img, levels), gaussian(v, levels)
        for lv in range(levels):
            h, w = gi[lv].shape[:2]
            acc[lv] = acc[lv] + (gi[lv] - pyr_up(gi[lv + 1], h, w)) * gv[lv][..., None]
        if top is None:
            acc[levels] = acc[levels] + gi[levels] * gv[levels][..., None]
    res = np.asarray(top, np.float64) if top is not None else acc[levels]
    for lv in range(levels - 1, -1, -1):
        h, w = acc[lv].shape[:2]
        res = acc[lv] + pyr_up(res, h, w)
    return res


def tops(imgs: Sequence[np.ndarray], vs: Sequence[np.ndarray], levels: int):
    """Level ``levels`` of each frame's Gaussian pyramids: ``([G(I_k)], [G(V_k)])``."""
    return [gaussian(i, levels)[-1] for i in imgs], [gaussian(v, levels)[-1] for v in vs]
