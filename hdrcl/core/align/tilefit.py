"""The frame as a whole: a fitted motion refined so that every part of the frame counts
the same (:mod:`hdrcl.core.align.handheld`, after each frame's fit).

**Why.** The Gauss-Newton fit of :mod:`hdrcl.core.align.register` is weighted by the
template's strongest gradients: a few edges decide it. Where two frames differ by more
than a rigid motion (film frames scanned one by one: Memorial 0067 against 0068 on a
tripod moves from -1.1 to +1.2 px across the frame, tile by tile, median 0), it lands
where those edges agree, up to 1.2 px (99th percentile over the frame's content) from
where the frame as a whole sits; a merge then blurs everything else.

**Refinement.** The template is cut into tiles (:data:`hdrcl.core.align.check.TILE`
pixels of the estimation level); each tile with structure is block matched within
:data:`RADIUS` level pixels of where the fit puts it
(:func:`hdrcl.core.align.check.tile_matches`: normalised cross-correlation of the shared
bright picture, a sub-pixel peak); tiles more than :data:`OUTLIER_PX` from the fit (a
moving object, a false match) are left out. The fit's model (translation or
similarity; a homography is kept as fitted) is then refitted to the tiles by least
squares, each tile once.

**Never worse.** The refit is taken only when, tiles split in two (a checkerboard),
each half's refit lands the *other* half's tiles closer (mean squared distance) than
the fit does, on both halves: with few tiles (a dark frame's windows) a least-squares
fit to them would follow their matching noise, and the held-out tiles say so. At least
:data:`MIN_TILES` tiles are needed.
"""
from __future__ import annotations

import logging
from typing import Optional, Tuple

import numpy as np

from hdrcl.core.align import check as RC
from hdrcl.core.align.warp import apply

logger = logging.getLogger("hdrcl.core.align.handheld")

#: Search radius (estimation-level pixels) around where the fit puts each tile.
RADIUS = 4
#: Tiles farther than this (full-size pixels) from the fit are not the frame's motion.
OUTLIER_PX = 2.0
#: Tiles needed for a refit (each held-out half gets half of them).
MIN_TILES = 12
#: Models refitted to the tiles.
REFIT = ("shift", "similarity")


def fit_model(kind: str, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Least-squares ``kind`` (``shift`` or ``similarity``) mapping points ``p`` to
    ``q`` (``(N, 2)``, ``(x, y)``), each point once."""
    if kind == "shift":
        d = (q - p).mean(axis=0)
        return np.array([[1.0, 0.0, d[0]], [0.0, 1.0, d[1]], [0.0, 0.0, 1.0]])
    return RC.fit_similarity(p, q)


def _sq(m: np.ndarray, p: np.ndarray, q: np.ndarray) -> float:
    return float(np.mean(np.sum((apply(m, p) - q) ** 2, axis=1)))


def held_out(kind: str, m: np.ndarray, p: np.ndarray, q: np.ndarray, step: float) -> Tuple[bool, float, float]:
    """``(better, refit, fit)``: whether the refit beats ``m`` on held-out tiles (each
    checkerboard half fitted on the other, both halves better), and the two mean
    squared distances summed over the halves. ``step``: the tile pitch (full size)."""
    cell = np.floor(p / step).astype(np.int64)
    black = (cell[:, 0] + cell[:, 1]) % 2 == 0
    e_new = e_old = 0.0
    better = True
    for a, b in ((black, ~black), (~black, black)):
        if a.sum() < MIN_TILES // 2 or b.sum() < MIN_TILES // 2:
            return False, float("nan"), float("nan")
        n, o = _sq(fit_model(kind, p[a], q[a]), p[b], q[b]), _sq(m, p[b], q[b])
        e_new, e_old = e_new + n, e_old + o
        better = better and n < o
    return better, e_new, e_old


def refine(reg, anchor: int, j: int, kind: str, matrix: np.ndarray) -> Optional[np.ndarray]:
    """The fit ``matrix`` (anchor -> frame ``j``, full size) refitted to the frame's
    tiles (module docstring), or None when the tiles do not confirm a refit."""
    if kind not in REFIT or np.any(matrix[2, :2] != 0.0):
        return None
    # The matrix says what was fitted (a retry from the second estimate can leave a
    # similarity under a translation's name).
    kind = "shift" if np.array_equal(matrix[:2, :2], np.eye(2)) else "similarity"
    la, lj = reg.levels(anchor)[0], reg.levels(j)[0]
    va, vj = (reg.valid[k][0] if reg.valid[k] is not None else None for k in (anchor, j))
    p, q = RC.tile_matches(la, va, lj, vj, matrix, radius=RADIUS)
    if len(p) < MIN_TILES:
        return None
    near = np.hypot(*(apply(matrix, p) - q).T) <= OUTLIER_PX
    p, q = p[near], q[near]
    if len(p) < MIN_TILES:
        return None
    better, e_new, e_old = held_out(kind, matrix, p, q, RC.TILE * la.scale)
    logger.debug("align: frame %d against %d: %d tiles, held out %.3f px^2 refit, %.3f px^2 fit", j, anchor,
                 len(p), e_new, e_old)
    return fit_model(kind, p, q) if better else None
