"""A second, independent estimate of a frame's motion, for the frames registration
sees little of (:mod:`hdrcl.core.align.handheld`): block matching of tiles.

**Picture.** Both frames' rank images (:mod:`hdrcl.core.align.register`: histogram-equalised,
so the same scene point has about the same value at any exposure) are clipped to the
ranks both frames record well: below the higher of the two floors everything is the
floor (a dark frame's pedestal noise, fill and masked pixels are flat), above the
lower of the two ceilings the ceiling. What is left is the shared bright structure (the
windows of a dark frame) on a flat ground, the same isophotes in both.

**Matching.** The template frame is cut into :data:`TILE` x :data:`TILE` tiles; each
tile with structure is searched exhaustively in the other frame over every whole-pixel
shift within :data:`RADIUS` of where the start matrix puts it (normalised
cross-correlation through FFTs), refined to a sub-pixel peak (a parabola through the
peak's neighbours on each axis). A tile whose peak correlates at least
:data:`MIN_NCC` and stands clear of the best shift :data:`UNIQUE_PX` or more away
counts.

**Model.** A similarity (two tiles determine one) by RANSAC over all pairs of tiles (a
fixed sample of :data:`MAX_PAIRS` of them where there are more),
inliers within :data:`INLIER_PX`, refitted by least squares on the inliers; with fewer
than three tiles agreeing, no estimate. Nothing here shares code or samples with the
Gauss-Newton fit it checks: it is the check the fit's own small residual cannot be
(a fit over a few hundred pixels of noise can report 0.6 px while 9 px off).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

#: Tile side and search radius, pixels of the estimation level.
TILE = 48
RADIUS = 40
#: A tile needs this share of its pixels inside the shared usable ranks ...
MIN_TILE_USABLE = 0.04
#: ... a match this correlation, and no other shift this far from it within
#: :data:`UNIQUE_GAP` of its correlation.
MIN_NCC = 0.6
UNIQUE_PX = 3
UNIQUE_GAP = 0.05
#: RANSAC: inlier distance (level pixels), and the tiles that must agree.
INLIER_PX = 1.0
MIN_TILES = 3
#: Pairs of tiles tried at most (all of them below that: a dark frame's few).
MAX_PAIRS = 300


@dataclass
class TileEstimate:
    """The block-matching estimate: a similarity (template -> frame, level pixels
    of ``scale``: use :meth:`full`), the tile centres that agreed with it (template
    level pixels) and how many tiles were matched in all."""

    matrix: np.ndarray
    points: np.ndarray
    matched: int
    scale: int

    def full(self):
        """``(matrix, points)`` in full-size pixels."""
        from hdrcl.core.align.register import to_full

        c = (self.scale - 1) / 2.0
        return to_full(self.matrix, self.scale), self.points * self.scale + c


def shared_picture(rank_a, usable_a, valid_a, rank_b, usable_b, valid_b):
    """Both rank images clipped to the ranks both frames record well (module
    docstring); None when they share none."""
    if not usable_a.any() or not usable_b.any():
        return None
    lo = max(float(rank_a[usable_a].min()), float(rank_b[usable_b].min()))
    hi = min(float(rank_a[usable_a].max()), float(rank_b[usable_b].max()))
    if hi <= lo:
        return None
    out = []
    for r, v in ((rank_a, valid_a), (rank_b, valid_b)):
        p = np.clip(r, lo, hi).astype(np.float64)
        if v is not None:
            p[~v] = lo
        out.append(p)
    return out[0], out[1], lo, hi


def _box(a: np.ndarray, k: int) -> np.ndarray:
    """Sums of every ``k`` x ``k`` window of ``a`` (valid positions only)."""
    c = np.zeros((a.shape[0] + 1, a.shape[1] + 1))
    c[1:, 1:] = a.cumsum(0).cumsum(1)
    return c[k:, k:] - c[:-k, k:] - c[k:, :-k] + c[:-k, :-k]


def ncc_surface(tpl: np.ndarray, win: np.ndarray) -> np.ndarray:
    """Normalised cross-correlation of ``tpl`` (k x k) at every whole-pixel position
    inside ``win``: ``(win_h - k + 1, win_w - k + 1)``."""
    k = tpl.shape[0]
    t = tpl - tpl.mean()
    tn = np.sqrt((t * t).sum())
    shape = (win.shape[0] + k, win.shape[1] + k)
    f = np.fft.rfft2(win, shape) * np.conj(np.fft.rfft2(t, shape))
    corr = np.fft.irfft2(f, shape)[: win.shape[0] - k + 1, : win.shape[1] - k + 1]
    s1, s2 = _box(win, k), _box(win * win, k)
    var = np.maximum(s2 - s1 * s1 / (k * k), 0.0)
    return corr / (tn * np.sqrt(var) + 1e-12)


def _peak(ncc: np.ndarray):
    """``(dy, dx, value)`` of the sub-pixel peak, or None when it is not clear."""
    j, i = np.unravel_index(int(np.argmax(ncc)), ncc.shape)
    v = float(ncc[j, i])
    if not v >= MIN_NCC:
        return None
    yy, xx = np.ogrid[: ncc.shape[0], : ncc.shape[1]]
    far = (np.abs(yy - j) >= UNIQUE_PX) | (np.abs(xx - i) >= UNIQUE_PX)
    if far.any() and float(ncc[far].max()) > v - UNIQUE_GAP:
        return None

    def sub(a, b, c):
        d = a - 2 * b + c
        return 0.0 if d >= 0 else float(np.clip(0.5 * (a - c) / d, -0.5, 0.5))

    fy = sub(ncc[j - 1, i], v, ncc[j + 1, i]) if 0 < j < ncc.shape[0] - 1 else 0.0
    fx = sub(ncc[j, i - 1], v, ncc[j, i + 1]) if 0 < i < ncc.shape[1] - 1 else 0.0
    return j + fy, i + fx, v


def match_tiles(a: np.ndarray, b: np.ndarray, usable: np.ndarray, start: np.ndarray, lo: float, radius: int = RADIUS):
    """``(points, targets)``: template tile centres ``(x, y)`` and where each was found
    in ``b`` (level pixels), for the tiles that match clearly."""
    from hdrcl.core.align.warp import apply

    h, w = a.shape
    k, r = TILE, int(radius)
    pad = np.pad(b, r + k, constant_values=lo)
    pts, tgt = [], []
    for y0 in range(0, h - k + 1, k):
        for x0 in range(0, w - k + 1, k):
            if usable[y0:y0 + k, x0:x0 + k].mean() < MIN_TILE_USABLE:
                continue
            tpl = a[y0:y0 + k, x0:x0 + k]
            if tpl.std() <= 1e-6:
                continue
            c = np.array([[x0 + (k - 1) / 2.0, y0 + (k - 1) / 2.0]])
            q = apply(start, c)[0]
            if not np.all(np.isfinite(q)):
                continue
            ox, oy = int(round(q[0] - (k - 1) / 2.0)) - r, int(round(q[1] - (k - 1) / 2.0)) - r
            if not (-r - k <= ox <= w - r and -r - k <= oy <= h - r):
                continue
            win = pad[oy + r + k: oy + r + k + k + 2 * r, ox + r + k: ox + r + k + k + 2 * r]
            pk = _peak(ncc_surface(tpl, win))
            if pk is None:
                continue
            pts.append(c[0])
            tgt.append([ox + pk[1] + (k - 1) / 2.0, oy + pk[0] + (k - 1) / 2.0])
    return np.array(pts).reshape(-1, 2), np.array(tgt).reshape(-1, 2)


def fit_similarity(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Least-squares similarity ``q ~ M p`` (``(N, 2)`` points, N >= 2)."""
    n = len(p)
    a = np.zeros((2 * n, 4))
    a[0::2] = np.c_[p[:, 0], -p[:, 1], np.ones(n), np.zeros(n)]
    a[1::2] = np.c_[p[:, 1], p[:, 0], np.zeros(n), np.ones(n)]
    s, *_ = np.linalg.lstsq(a, q.reshape(-1), rcond=None)
    return np.array([[s[0], -s[1], s[2]], [s[1], s[0], s[3]], [0.0, 0.0, 1.0]])


def robust_similarity(p: np.ndarray, q: np.ndarray):
    """``(matrix, inliers)`` by RANSAC over every pair of points (module docstring), or
    None with fewer than :data:`MIN_TILES` agreeing."""
    from hdrcl.core.align.warp import apply

    n = len(p)
    if n < MIN_TILES:
        return None
    ii, jj = np.triu_indices(n, 1)
    far = np.hypot(*(p[ii] - p[jj]).T) >= TILE
    ii, jj = ii[far], jj[far]
    if ii.size > MAX_PAIRS:  # a bright frame's hundreds of tiles: a fixed sample of the pairs
        pick = np.random.default_rng(0).choice(ii.size, MAX_PAIRS, replace=False)
        ii, jj = ii[pick], jj[pick]
    best = None
    for i, j in zip(ii, jj):
        m = fit_similarity(p[[i, j]], q[[i, j]])
        inl = np.hypot(*(apply(m, p) - q).T) <= INLIER_PX
        if best is None or inl.sum() > best.sum():
            best = inl
    if best is None or best.sum() < MIN_TILES:
        return None
    for _ in range(3):
        m = fit_similarity(p[best], q[best])
        inl = np.hypot(*(apply(m, p) - q).T) <= INLIER_PX
        if inl.sum() < MIN_TILES:
            return None
        best = inl
    return fit_similarity(p[best], q[best]), best


def tile_matches(lev_a, valid_a, lev_b, valid_b, start_full: np.ndarray, radius: int = RADIUS):
    """``(points, targets)``: the centres of the template's tiles that match clearly
    and where each was found in frame ``b``, full-size pixels (searched within
    ``radius`` level pixels of where ``start_full`` puts them)."""
    from hdrcl.core.align.register import to_level

    pic = shared_picture(lev_a.rank, lev_a.ok, valid_a, lev_b.rank, lev_b.ok, valid_b)
    if pic is None:
        return np.zeros((0, 2)), np.zeros((0, 2))
    a, b, lo, hi = pic
    usable = (a > lo) & (a < hi)
    start = to_level(np.asarray(start_full, np.float64), lev_a.scale)
    p, q = match_tiles(a, b, usable, start, lo, radius)
    c = (lev_a.scale - 1) / 2.0
    return p * lev_a.scale + c, q * lev_a.scale + c


def tile_estimate(lev_a, valid_a, lev_b, valid_b, start_full: np.ndarray) -> Optional[TileEstimate]:
    """The block-matching similarity of frame ``b`` against template ``a``
    (:class:`hdrcl.core.align.register.Level`, same level; ``valid_*`` their masks or None),
    searched around ``start_full`` (full size), or None when too few tiles agree."""
    p, q = tile_matches(lev_a, valid_a, lev_b, valid_b, start_full)
    s = lev_a.scale
    fit = robust_similarity(p / s, q / s)  # level pixels: the inlier distance is the level's
    if fit is None:
        return None
    m, inl = fit
    c = (s - 1) / 2.0
    return TileEstimate(fit_similarity((p[inl] - c) / s, (q[inl] - c) / s), (p[inl] - c) / s, len(p), s)


def model_errors(matrices, points: np.ndarray, targets: np.ndarray) -> list:
    """Median distance (full-size pixels) from where each matrix puts the tile
    centres to where block matching found them, over the tiles within 2 px of at
    least one of the matrices (a mismatched tile judges none); NaN without tiles."""
    from hdrcl.core.align.warp import apply

    if len(points) == 0:
        return [float("nan")] * len(matrices)
    d = np.array([np.hypot(*(apply(m, points) - targets).T) for m in matrices])
    keep = d.min(axis=0) <= 2.0
    if keep.sum() < 2 * MIN_TILES:
        return [float("nan")] * len(matrices)
    return [float(np.median(row[keep])) for row in d]


def disagreement(m: np.ndarray, est: TileEstimate) -> float:
    """Largest distance (full-size pixels) between where ``m`` and the estimate put
    the template's agreeing tile centres: how far apart the two estimates are where
    the frame has content."""
    from hdrcl.core.align.warp import apply

    mf, pts = est.full()
    return float(np.max(np.hypot(*(apply(m, pts) - apply(mf, pts)).T)))
