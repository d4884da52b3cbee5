"""Sub-pixel registration of a frame against another: translation, similarity or
homography, robust to the exposure difference.

**Exposure-invariant picture.** Each grey level image (the 2x2 box pyramid of
:mod:`hdrcl.core.align.mtb`) is replaced by its *rank image*: the fraction of the image's
pixels darker than the pixel (mid-rank for ties). Any monotonic response and any
exposure give the same ranks to the same scene points, except where a frame clips:
pixels within ``2 tol + 1`` codes of either end, or near the frame's own noise floor or
saturation (:func:`usable_range`), in either frame, are left out. What
the frames do not share (borders that moved in or out) bends ranks slightly; a gain and
offset between the two rank images, refitted every iteration, absorbs it (as ECC's
invariance to gain and bias does).

**Estimation.** Inverse-compositional Gauss-Newton (Baker & Matthews 2004) on the
template's strongest-gradient pixels where both frames are usable (at most
:data:`MAX_SAMPLES`), with Huber weights
(moving objects), coarse to fine from a level whose short side is about
:data:`START_SIDE` pixels down to the finest level with at most
:data:`ESTIMATE_PIXELS` pixels; it starts from the whole-pixel shift of the median
threshold bitmaps. Parameters live in centred coordinates scaled to about [-1, 1].
Matrices use the convention of :mod:`hdrcl.core.align.warp`: ``frame(M p) ~ template(p)``.

**Residual.** After the fit, the frame is cut into 4 x 4 tiles and each textured
tile's own remaining translation is estimated; ``residual_px`` is the median of their
lengths, in full-size pixels: how far, typically, the aligned frame still sits from the
template (a moving object or parallax in a few tiles does not dominate it).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional, Tuple

import numpy as np

from hdrcl.core.align.warp import apply, corners

#: Finest level used for estimation has at most this many pixels.
ESTIMATE_PIXELS = 2_500_000
#: Coarsest level used has its short side at least this long.
START_SIDE = 48
#: Template pixels used per level at most (the strongest gradients).
MAX_SAMPLES = 50_000
#: Gauss-Newton iterations per level at most, and the step (level pixels at the corners)
#: that counts as converged; on the coarser levels (they only bring the fit within the
#: finest level's reach) fewer, and looser.
MAX_ITER = 15
CONVERGED = 0.02
COARSE_ITER = 8
COARSE_CONVERGED = 0.05
#: Iterations per level of ``auto``'s translation probe: a translation converges in a
#: few; one that does not (the frame turned) is not the model anyway.
PROBE_ITER = 6
#: A coarse level needs this many samples per parameter, else the fit starts finer.
MIN_LEVEL_SAMPLES = 15
#: Parameters per model.
NPARAM = {"shift": 2, "similarity": 4, "homography": 8}
#: Quantiles taken as a frame's noise floor and saturation level.
FLOOR_Q, CEIL_Q = 0.005, 0.999
#: The top codes are a saturation only where at least this fraction of the pixels piles
#: up within half the margin of the brightest code (a dark frame's few highlights thin
#: out instead: they are the frame's best texture, not a clip).
PILE_FRAC = 0.0005
#: Pixels around fill (code 0) left out too (:func:`fill_mask`).
FILL_GROW = 2
#: Tiles per side for the residual; a tile counts with this many samples, and a
#: smallest eigenvalue of its gradients' normal matrix of at least this per sample
#: (rank units per pixel, squared): texture in two directions.
TILES = 4
MIN_TILE_SAMPLES = 200
MIN_TILE_TEXTURE = 1e-5


@dataclass
class Level:
    """One pyramid level of one frame: rank image and its usable-pixel mask."""

    rank: np.ndarray  # float32 (h, w)
    ok: np.ndarray  # bool (h, w): well exposed (eroded by one pixel)
    scale: int  # 2^k: full-size pixels per level pixel
    _masked: Optional[np.ndarray] = None

    @property
    def masked(self) -> np.ndarray:
        """``rank`` with NaN where not ``ok``, flat (made once): one gather tells both."""
        if self._masked is None:
            self._masked = np.where(self.ok, self.rank, np.float32(np.nan)).ravel()
        return self._masked


def usable_range(grey: np.ndarray, lo: int, hi: int, valid: Optional[np.ndarray] = None,
                 margin: int = 8) -> Tuple[int, int]:
    """``(lo, hi)`` narrowed to the frame: ``margin`` codes above its pedestal (the
    :data:`FLOOR_Q` quantile of its codes, fill and masked pixels left out: a film base,
    a sensor's black level) and half of that below its :data:`CEIL_Q` quantile (where a
    scan or a camera saturates below full scale).

    Fill (:func:`fill_mask`: black corners a rotation uncovered) is left out of the
    pedestal: counted, 2-5 % of zeros drive the quantile to 0, and on a dark frame whose
    codes sit on a pedestal of 15 the sensor's noise then passes for texture."""
    keep = ~fill_mask(grey)
    if valid is not None:
        keep &= valid
    g = grey[keep]
    if g.size == 0:
        return lo, hi
    sub = g.ravel()[:: max(1, g.size // 262144)]
    floor, ceil = np.quantile(sub, [FLOOR_Q, CEIL_Q], method="lower")
    top = int(sub.max())
    if np.count_nonzero(sub >= top - margin // 2) < PILE_FRAC * sub.size:
        ceil = hi + margin // 2  # the brightest codes thin out: a dark frame's highlights, not a saturation
    return max(lo, int(floor) + margin), min(hi, int(ceil) - margin // 2)


def fill_mask(grey: np.ndarray, grow: int = FILL_GROW) -> np.ndarray:
    """Fill: pixels at code 0 in every channel (grey 0: the black a converter or a
    camera paints where a rotation uncovered the frame) and ``grow`` pixels around
    them (an interpolated edge of the fill). Scene pixels at 0 are clipped anyway."""
    fill = np.asarray(grey) == 0
    if not fill.any():
        return fill
    from scipy import ndimage

    return ndimage.binary_dilation(fill, np.ones((2 * grow + 1, 2 * grow + 1), bool))


def rank_image(grey: np.ndarray, lo: int, hi: int, valid: Optional[np.ndarray] = None) -> Tuple[np.ndarray, np.ndarray]:
    """``(rank, ok)`` of a grey level image (uint16): mid-rank of each pixel in [0, 1]
    among the valid pixels, and whether it is usable: valid and ``lo < grey < hi``
    (see :func:`usable_range`), eroded by one pixel."""
    g = grey if valid is None else grey[valid]
    hist = np.bincount(g.ravel(), minlength=int(grey.max()) + 1).astype(np.float64)
    cum = np.cumsum(hist)
    lut = ((cum - 0.5 * hist) / max(g.size, 1)).astype(np.float32)
    ok = (grey > lo) & (grey < hi)
    if valid is not None:
        ok &= valid
    return lut[grey], erode3(ok)


def erode3(ok: np.ndarray) -> np.ndarray:
    """``ok`` eroded by a 3 x 3 square, the outside counting as False (as
    ``scipy.ndimage.binary_erosion(ok, ones((3, 3)), border_value=0)``), by slices."""
    out = np.zeros_like(ok)
    if ok.shape[0] < 3 or ok.shape[1] < 3:
        return out
    row = ok[:, :-2] & ok[:, 1:-1] & ok[:, 2:]  # across x, columns 1 .. w-2
    out[1:-1, 1:-1] = row[:-2] & row[1:-1] & row[2:]
    return out


def valid_pyramid(valid: Optional[np.ndarray], levels: int) -> List[Optional[np.ndarray]]:
    """A validity mask per pyramid level: a level pixel is valid when its 2x2 sources are
    (the odd last row or column dropped, as :func:`hdrcl.core.align.mtb.downsample`)."""
    out = [None if valid is None else np.asarray(valid, bool)]
    for _ in range(levels - 1):
        v = out[-1]
        if v is not None:
            h, w = v.shape[0] // 2, v.shape[1] // 2
            v = v[: 2 * h, : 2 * w]
            v = v[0::2, 0::2] & v[0::2, 1::2] & v[1::2, 0::2] & v[1::2, 1::2]
        out.append(v)
    return out


def levels_of(pyramid: List[np.ndarray], first: int, lo: int, hi: int,
              valid: Optional[List[Optional[np.ndarray]]] = None) -> List[Level]:
    """:class:`Level` for each grey image of ``pyramid`` (level ``first`` onwards), with
    the validity masks of the same levels; ``lo``, ``hi`` as :func:`usable_range` gives."""
    valid = valid or [None] * len(pyramid)
    return [Level(*rank_image(g, lo, hi, v), 1 << (first + k)) for k, (g, v) in enumerate(zip(pyramid, valid))]


def estimation_level(h: int, w: int, levels: int) -> int:
    """The finest level with at most :data:`ESTIMATE_PIXELS` pixels."""
    k = 0
    while k < levels - 1 and (h >> k) * (w >> k) > ESTIMATE_PIXELS:
        k += 1
    return k


def start_level(h: int, w: int, levels: int) -> int:
    """The coarsest level whose short side keeps :data:`START_SIDE` pixels (at least 0)."""
    k = levels - 1
    while k > 0 and min(h >> k, w >> k) < START_SIDE:
        k -= 1
    return k


def to_level(m: np.ndarray, scale: int) -> np.ndarray:
    """A full-size matrix in the coordinates of a level of ``scale`` (2x2 box pyramid:
    level pixel ``i`` is centred on full-size ``scale i + (scale - 1) / 2``)."""
    c = (scale - 1) / 2.0
    s = np.array([[scale, 0.0, c], [0.0, scale, c], [0.0, 0.0, 1.0]])
    return np.linalg.inv(s) @ m @ s


def to_full(m: np.ndarray, scale: int) -> np.ndarray:
    """Inverse of :func:`to_level`."""
    c = (scale - 1) / 2.0
    s = np.array([[scale, 0.0, c], [0.0, scale, c], [0.0, 0.0, 1.0]])
    return s @ m @ np.linalg.inv(s)


def _norm(h: int, w: int) -> np.ndarray:
    """Pixel -> centred coordinates of about [-1, 1]."""
    L = max(h, w) / 2.0
    return np.array([[1 / L, 0.0, -(w - 1) / 2 / L], [0.0, 1 / L, -(h - 1) / 2 / L], [0.0, 0.0, 1.0]])


def param_matrix(model: str, d: np.ndarray) -> np.ndarray:
    """Warp of the parameter vector ``d`` (centred coordinates), identity at 0."""
    if model == "shift":
        return np.array([[1.0, 0.0, d[0]], [0.0, 1.0, d[1]], [0.0, 0.0, 1.0]])
    if model == "similarity":
        a, b = d[0], d[1]
        return np.array([[1.0 + a, -b, d[2]], [b, 1.0 + a, d[3]], [0.0, 0.0, 1.0]])
    return np.array([[1.0 + d[0], d[1], d[2]], [d[3], 1.0 + d[4], d[5]], [d[6], d[7], 1.0]])


def jacobian(model: str, xn: np.ndarray, yn: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """d(x', y')/d(params) at identity, rows ``(N, P)`` for x' and y'."""
    one, zero = np.ones_like(xn), np.zeros_like(xn)
    if model == "shift":
        return np.c_[one, zero], np.c_[zero, one]
    if model == "similarity":
        return np.c_[xn, -yn, one, zero], np.c_[yn, xn, zero, one]
    return (np.c_[xn, yn, one, zero, zero, zero, -xn * xn, -xn * yn],
            np.c_[zero, zero, zero, xn, yn, one, -xn * yn, -yn * yn])


class Template:
    """The picture frames are registered to, one level: samples (its strongest
    gradients where it and, given ``also``, the other frame are usable) and steepest
    descent."""

    def __init__(self, lev: Level, also: Optional[np.ndarray] = None):
        r = lev.rank
        h, w = r.shape
        gy, gx = np.zeros_like(r), np.zeros_like(r)
        gx[:, 1:-1] = 0.5 * (r[:, 2:] - r[:, :-2])
        gy[1:-1, :] = 0.5 * (r[2:, :] - r[:-2, :])
        mag2 = gx * gx + gy * gy  # squared: the same order, no square roots
        keep = lev.ok & (mag2 > np.float32(1e-12))
        if also is not None:  # usable in the other frame too
            keep &= also
        idx = np.flatnonzero(keep)
        if idx.size > MAX_SAMPLES:
            idx = idx[np.argpartition(-mag2.ravel()[idx], MAX_SAMPLES)[:MAX_SAMPLES]]
        self.h, self.w, self.scale = h, w, lev.scale
        self.y, self.x = np.divmod(idx, w)
        self.t = r.ravel()[idx].astype(np.float64)
        self.gx, self.gy = gx.ravel()[idx].astype(np.float64), gy.ravel()[idx].astype(np.float64)
        self.N = _norm(h, w)
        self.L = max(h, w) / 2.0
        self.pts = np.c_[self.x, self.y].astype(np.float64)
        self.px, self.py = self.pts[:, 0].copy(), self.pts[:, 1].copy()

    def tiles(self) -> np.ndarray:
        """Each sample's residual tile (:data:`TILES` x :data:`TILES` over the level)."""
        return (np.minimum(self.y * TILES // self.h, TILES - 1) * TILES
                + np.minimum(self.x * TILES // self.w, TILES - 1))

    def half(self, fold: int, keep: bool = True) -> "Template":
        """The samples of half of the frame (``fold`` 0: the top half of the tiles, 1:
        the left half, 2: a checkerboard of them), or, with ``keep`` False, of the other
        half: a fit on one half is judged on the other, which it did not use."""
        t = self.tiles()
        ty, tx = t // TILES, t % TILES
        inside = (ty < TILES // 2, tx < TILES // 2, (ty + tx) % 2 == 0)[fold]
        sel = inside if keep else ~inside
        out = object.__new__(Template)
        out.__dict__.update(self.__dict__)
        for k in ("y", "x", "t", "gx", "gy", "pts", "px", "py"):
            setattr(out, k, getattr(self, k)[sel])
        return out

    def steepest(self, model: str) -> np.ndarray:
        """``(N, P)``: template gradient times the warp's Jacobian (pixel units)."""
        pn = apply(self.N, self.pts)
        jx, jy = jacobian(model, pn[:, 0], pn[:, 1])
        return self.L * (self.gx[:, None] * jx + self.gy[:, None] * jy)


def joint_ok(img: Level, m_full: np.ndarray, scale: int) -> np.ndarray:
    """``img.ok`` brought to the template's pixels by the translation part of ``m_full``
    (whole pixels of the level): where the template's samples can find a usable partner."""
    from hdrcl.core.align.mtb import _shift

    m = to_level(m_full, scale)
    h, w = img.ok.shape
    c = apply(m, np.array([[(w - 1) / 2.0, (h - 1) / 2.0]]))[0] - [(w - 1) / 2.0, (h - 1) / 2.0]
    return _shift(img.ok, int(round(c[1])), int(round(c[0])), fill=False)


def sample(lev: Level, m: np.ndarray, pts: np.ndarray, xy=None) -> Tuple[np.ndarray, np.ndarray]:
    """Rank of ``lev`` at ``M pts`` (bilinear; NaN where not usable) and whether all four
    neighbours are usable (``xy``: ``pts`` as two contiguous columns, when the caller has
    them)."""
    px, py = xy if xy is not None else (pts[:, 0], pts[:, 1])
    h, w = lev.rank.shape
    if m[2, 0] == 0.0 and m[2, 1] == 0.0 and m[2, 2] == 1.0:
        x = m[0, 0] * px + m[0, 1] * py + m[0, 2]
        y = m[1, 0] * px + m[1, 1] * py + m[1, 2]
    else:
        s = m[2, 0] * px + m[2, 1] * py + m[2, 2]
        x = (m[0, 0] * px + m[0, 1] * py + m[0, 2]) / s
        y = (m[1, 0] * px + m[1, 1] * py + m[1, 2]) / s
    inside = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    x0 = np.clip(np.floor(x), 0, w - 2).astype(np.intp)
    y0 = np.clip(np.floor(y), 0, h - 2).astype(np.intp)
    fx, fy = np.clip(x - x0, 0.0, 1.0), np.clip(y - y0, 0.0, 1.0)
    i = y0 * w + x0
    r = lev.masked  # NaN where not usable: a NaN neighbour makes v NaN, whatever its weight
    a, b = r[i], r[i + 1]
    top = a + (b - a) * fx
    i += w
    a, b = r[i], r[i + 1]
    v = top + (a + (b - a) * fx - top) * fy
    good = inside & ~np.isnan(v)
    return v, good


def _photometric(t: np.ndarray, v: np.ndarray, wt: np.ndarray) -> Tuple[float, float]:
    """Weighted least-squares gain and offset of ``v ~ g t + b``."""
    sw = wt.sum()
    mt, mv = (wt * t).sum() / sw, (wt * v).sum() / sw
    var = (wt * (t - mt) ** 2).sum()
    g = (wt * (t - mt) * (v - mv)).sum() / var if var > 0 else 1.0
    g = g if g > 0.05 else 0.05
    return g, mv - g * mt


def _huber(e: np.ndarray) -> np.ndarray:
    s = 1.4826 * np.median(np.abs(e)) + 1e-6
    a = np.abs(e) / (1.5 * s)
    return np.where(a <= 1.0, 1.0, 1.0 / np.maximum(a, 1e-12))


@dataclass
class Fit:
    """A fitted matrix (full size), whether the last level converged, and how well the
    frame matched (correlation of the rank images over the samples)."""

    matrix: np.ndarray
    converged: bool
    zncc: float
    samples: int


def fit_level(tpl: Template, img: Level, m_full: np.ndarray, model: str, max_iter: int = MAX_ITER,
              tol: float = CONVERGED) -> Tuple[np.ndarray, bool, float, int]:
    """Gauss-Newton at one level from ``m_full``, at most ``max_iter`` steps, converged
    at a step under ``tol`` (level pixels at the corners);
    ``(matrix, converged, zncc, samples)``."""
    m = to_level(m_full, tpl.scale)
    sd = tpl.steepest(model)
    ninv = np.linalg.inv(tpl.N)
    ends = corners(tpl.h, tpl.w)
    converged, zncc, used = False, 0.0, 0
    for _ in range(max_iter):
        v, ok = sample(img, m, tpl.pts, (tpl.px, tpl.py))
        used = int(ok.sum())
        if used < 4 * NPARAM[model] + 16:
            return to_full(m, tpl.scale), False, 0.0, used
        t, v, s = tpl.t[ok], v[ok], sd[ok]
        wt = np.ones_like(t)
        g, b = _photometric(t, v, wt)
        e = (v - b) / g - t
        wt = _huber(e)
        g, b = _photometric(t, v, wt)
        e = (v - b) / g - t
        A = s.T @ (s * wt[:, None])
        rhs = s.T @ (wt * e)
        try:
            d = np.linalg.solve(A, rhs)
        except np.linalg.LinAlgError:
            return to_full(m, tpl.scale), False, 0.0, used
        dw = ninv @ param_matrix(model, d) @ tpl.N
        m = m @ np.linalg.inv(dw)
        if not np.all(np.isfinite(m)):
            return m_full, False, 0.0, used
        step = float(np.max(np.hypot(*(apply(dw, ends) - ends).T)))
        if step < tol:
            converged = True
            break
    tc, vc = t - t.mean(), v - v.mean()
    zncc = float((tc * vc).sum() / (np.sqrt((tc * tc).sum() * (vc * vc).sum()) + 1e-12))
    return to_full(m, tpl.scale), converged, zncc, used


def fit(templates: List[Template], images: List[Level], m0: np.ndarray, model: str,
        max_iter: int = MAX_ITER) -> Fit:
    """Coarse to fine over paired levels (coarsest last in the lists); at most
    ``max_iter`` steps per level (a probe takes fewer)."""
    m, conv, zncc, used = np.asarray(m0, np.float64), False, 0.0, 0
    pairs = list(zip(templates, images))
    for k in range(len(pairs) - 1, -1, -1):
        tpl, img = pairs[k]
        if k > 0 and tpl.x.size < MIN_LEVEL_SAMPLES * NPARAM[model]:
            continue  # too little to go on at this size: start finer
        if k > 0:
            m, conv, zncc, used = fit_level(tpl, img, m, model, min(max_iter, COARSE_ITER), COARSE_CONVERGED)
        else:
            m, conv, zncc, used = fit_level(tpl, img, m, model, max_iter)
    return Fit(m, conv, zncc, used)


def tile_residual(tpl: Template, img: Level, m_full: np.ndarray, iters: int = 5) -> float:
    """Median over the textured tiles of each tile's remaining translation, full-size
    pixels (NaN when no tile has enough texture). Each tile's translation is a
    Gauss-Newton fit of its own, with Huber weights."""
    m = to_level(m_full, tpl.scale)
    tile = tpl.tiles()
    n = TILES * TILES
    gx, gy = tpl.gx, tpl.gy
    shifts = np.zeros((n, 2))
    good = np.zeros(n, bool)
    for _ in range(iters):
        v, ok = sample(img, m, tpl.pts - shifts[tile])
        if ok.sum() <= 16:
            return float("nan")
        g, b = _photometric(tpl.t[ok], v[ok], np.ones(int(ok.sum())))
        e = np.where(ok, (v - b) / g - tpl.t, 0.0)
        wt = np.where(ok, _huber(e), 0.0)

        def acc(a):
            return np.bincount(tile, weights=a * wt, minlength=n)

        axx, axy, ayy, cnt = acc(gx * gx), acc(gx * gy), acc(gy * gy), acc(np.ones_like(e))
        det = axx * ayy - axy * axy
        lam = 0.5 * (axx + ayy) - np.sqrt(np.maximum(0.25 * (axx - ayy) ** 2 + axy * axy, 0.0))
        good = (cnt >= MIN_TILE_SAMPLES) & (lam > MIN_TILE_TEXTURE * np.maximum(cnt, 1.0))
        safe = np.where(good, det, 1.0)
        bx, by = acc(gx * e), acc(gy * e)
        step = np.c_[(ayy * bx - axy * by) / safe, (axx * by - axy * bx) / safe]
        shifts = np.clip(shifts + np.where(good[:, None], step, 0.0), -8.0, 8.0)
    if not good.any():
        return float("nan")
    return float(np.sqrt(np.median(np.sum(shifts[good] ** 2, axis=1))) * tpl.scale)
