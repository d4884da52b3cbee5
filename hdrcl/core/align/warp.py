"""Warping frames by a 3x3 matrix: the NumPy twin of ``kernels/warp.cl``, and the
geometry around it (corners, the box every warped frame covers).

**Convention.** A frame's matrix ``M`` maps reference pixel coordinates to frame pixel
coordinates: ``frame(M (x, y, 1)) ~ reference(x, y)`` (pixel centres at integers, x the
column). A translation ``M = [[1, 0, dx], [0, 1, dy], [0, 0, 1]]`` is the shift
``(dy, dx)`` of :mod:`hdrcl.core.align.mtb`: ``frame(y + dy, x + dx) ~ reference(y, x)``.

**Warp.** ``out(x, y) = frame(sx, sy)`` with ``(sx, sy) = (u / s, v / s)``,
``(u, v, s) = M (x, y, 1)``, interpolated by Keys' cubic convolution (``a = -1/2``,
Catmull-Rom) over the 4x4 source pixels around ``(sx, sy)``. A coordinate within
:data:`SNAP` of an integer is taken as that integer (its other taps then weigh exactly
0, so an integer shift is an exact copy). Tap weights for the fraction ``t``::

    w(-1) = a (t^3 - 2 t^2 + t)          w(0) = (a + 2) t^3 - (a + 3) t^2 + 1
    w(+1) = -(a + 2) t^3 + (2a + 3) t^2 - a t        w(+2) = -a (t^3 - t^2)

A tap *contributes* when its weight ``w_i w_j`` is not 0: both ``w_i`` and ``w_j``
are not 0 (all 4 per axis for ``t != 0``, the centre one for ``t == 0``). An output
pixel is *covered* when ``s > 0`` and every contributing tap lies in the frame;
*valid* when covered and every contributing tap is valid in the frame's own mask
(conservative: one invalid source pixel invalidates the result). The value is
``clamp(floor(sum_j w_j (sum_i w_i z_ij) + 1/2), 0, zmax)`` in the frame's code units
where covered, 0 where not (separable: each row of taps summed over x, then the rows
over y; the kernel in float32 in the same order), held between the smallest and the
largest contributing tap of the channel (no ringing: the cubic's overshoot at a hard
edge, one channel at a time, made single-pixel colour speckles beside clipped
highlights and along black fill), and the largest code where a contributing tap is at or
above the clip level ``clip_hi``.
"""
from __future__ import annotations

from typing import List, Optional, Sequence, Tuple

import numpy as np

#: Keys' cubic convolution parameter.
KEYS_A = -0.5
#: Coordinates within this of an integer snap to it (kernel and twin alike).
SNAP = 1.0 / 1024.0


def tap_weights(t: np.ndarray, taps: int = 4):
    """``(offsets, weights)``: Keys' cubic (``taps`` 4: offsets -1, 0, +1, +2) or
    bilinear (``taps`` 2: offsets 0, +1, weights ``1 - t``, ``t``)."""
    if taps == 2:
        return (0, 1), (1.0 - t, t)
    return (-1, 0, 1, 2), keys_weights(t)


def keys_weights(t: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Weights of the taps at offsets -1, 0, +1, +2 for the fractions ``t`` in [0, 1)."""
    a = KEYS_A
    t2, t3 = t * t, t * t * t
    return (a * (t3 - 2.0 * t2 + t), (a + 2.0) * t3 - (a + 3.0) * t2 + 1.0,
            -(a + 2.0) * t3 + (2.0 * a + 3.0) * t2 - a * t, -a * (t3 - t2))


def source_coords(matrix: np.ndarray, ys: np.ndarray, xs: np.ndarray):
    """``(sx, sy, ok)`` for the output pixels ``(ys, xs)`` (broadcast): the source
    coordinates, snapped (:data:`SNAP`), and whether the projective ``s`` is > 0."""
    m = np.asarray(matrix, np.float64)
    u = m[0, 0] * xs + m[0, 1] * ys + m[0, 2]
    v = m[1, 0] * xs + m[1, 1] * ys + m[1, 2]
    s = m[2, 0] * xs + m[2, 1] * ys + m[2, 2]
    ok = s > 0
    s = np.where(ok, s, 1.0)
    sx, sy = u / s, v / s
    for c in (sx, sy):
        r = np.round(c)
        np.copyto(c, r, where=np.abs(c - r) < SNAP)
    return sx, sy, ok


def clip_high(zmax: int) -> int:
    """Fusion's clip level for codes up to ``zmax`` (:func:`hdrcl.core.weights.clip_levels`):
    a warped channel with a contributing tap at or above it is ``zmax`` (clipped)."""
    from hdrcl.core.weights import clip_levels

    return clip_levels(int(zmax) + 1)[1]


def warp_rows(frame: np.ndarray, matrix: np.ndarray, y0: int, y1: int,
              valid: Optional[np.ndarray] = None, taps: int = 4,
              clip_hi: Optional[int] = None) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows ``y0:y1`` of the warped ``frame`` ``(H, W, C)``: ``(codes, valid, covered)``.

    The twin of the ``warp`` kernel (module docstring), in float64; ``taps`` 4 (Keys'
    cubic) or 2 (bilinear).
    """
    return warp_grid(frame, 0, frame.shape[0], matrix, np.arange(y0, y1), np.arange(frame.shape[1]), valid,
                     taps, clip_hi)


def warp_grid(band: np.ndarray, b0: int, h: int, matrix: np.ndarray, ys: np.ndarray, xs: np.ndarray,
              valid: Optional[np.ndarray] = None, taps: int = 4,
              clip_hi: Optional[int] = None) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The warped frame at the output rows ``ys`` and columns ``xs`` (frame coordinates,
    1-D): ``(codes (len(ys), len(xs), C), valid, covered)``; the twin of the
    ``warp_grid`` kernel. ``band``: source rows ``b0 ..`` of a frame ``h`` rows high
    holding every contributing tap (rows outside it are read clamped to it, as the
    kernel does); ``valid``: the band's mask."""
    bh, w, c = band.shape
    zmax = float(np.iinfo(band.dtype).max)
    ys, xs = np.meshgrid(np.asarray(ys, np.float64), np.asarray(xs, np.float64), indexing="ij")
    sx, sy, ok = source_coords(matrix, ys, xs)
    ix, iy = np.floor(sx), np.floor(sy)
    tx, ty = sx - ix, sy - iy
    offs, wx = tap_weights(tx, taps)
    _, wy = tap_weights(ty, taps)
    big = 4.0 * max(h, w) + 8.0  # keeps far-away coordinates in int range
    ix = np.clip(ix, -big, big).astype(np.int64)
    iy = np.clip(iy, -big, big).astype(np.int64)
    covered = ok.copy()
    good = ok.copy()
    acc = np.zeros(ys.shape + (c,), np.float64)
    top = np.zeros(ys.shape + (c,), np.float64)  # the largest contributing tap per channel
    bot = np.full(ys.shape + (c,), zmax)  # and the smallest
    for j, oy in enumerate(offs):  # separable: each tap row over x, then the rows over y
        py = iy + oy
        cy = np.clip(np.clip(py, 0, h - 1) - b0, 0, bh - 1)
        row = np.zeros(ys.shape + (c,), np.float64)
        for i, ox in enumerate(offs):
            contrib = (wx[i] != 0.0) & (wy[j] != 0.0)
            px = ix + ox
            inside = (px >= 0) & (px < w) & (py >= 0) & (py < h)
            covered &= inside | ~contrib
            cx = np.clip(px, 0, w - 1)
            if valid is not None:
                good &= valid[cy, cx] | ~contrib
            z = band[cy, cx]
            row += wx[i][..., None] * z
            np.maximum(top, np.where(contrib[..., None], z, 0), out=top)
            np.minimum(bot, np.where(contrib[..., None], z, zmax), out=bot)
        acc += wy[j][..., None] * row
    codes = np.clip(np.floor(acc + 0.5), bot, top)  # no ringing (module docstring)
    if clip_hi is not None:  # a clipped contributing tap: clipped (the kernel's docstring)
        codes[top >= clip_hi] = zmax
    codes[~covered] = 0
    return codes.astype(band.dtype), covered & good, covered


def warp_frame(frame: np.ndarray, matrix: np.ndarray, valid: Optional[np.ndarray] = None,
               rows: int = 256, taps: int = 4, clip_hi: Optional[int] = None) -> Tuple[np.ndarray, np.ndarray]:
    """The whole warped frame and its validity ``(H, W)`` bool, in strips of ``rows``."""
    frame = np.asarray(frame)
    squeeze = frame.ndim == 2
    if squeeze:
        frame = frame[:, :, None]
    h, w, c = frame.shape
    out = np.empty_like(frame)
    ok = np.empty((h, w), bool)
    for y0 in range(0, h, rows):
        y1 = min(h, y0 + rows)
        out[y0:y1], ok[y0:y1], _ = warp_rows(frame, matrix, y0, y1, valid, taps, clip_hi)
    return (out[:, :, 0] if squeeze else out), ok


def region_band(matrix: np.ndarray, y0: int, y1: int, x0: int, x1: int, h: int, w: int) -> Tuple[int, int]:
    """Source rows ``[b0, b1)`` holding every tap of the output pixels with rows
    ``y0 .. y1`` and columns ``x0 .. x1`` (inclusive, frame coordinates): the corners of
    that box bound its projective image; 3 rows of margin above, 4 below (as
    :func:`hdrcl.cl.warp.source_band` for a whole-width strip)."""
    m = np.asarray(matrix, np.float64)
    xs = np.array([x0, x1, x0, x1], np.float64)
    ys = np.array([y0, y0, y1, y1], np.float64)
    s = m[2, 0] * xs + m[2, 1] * ys + m[2, 2]
    if np.any(s <= 0):
        return 0, h
    sy = (m[1, 0] * xs + m[1, 1] * ys + m[1, 2]) / s
    lo, hi = np.floor(sy.min()) - 3, np.floor(sy.max()) + 5
    b0, b1 = int(np.clip(lo, 0, h)), int(np.clip(hi, 0, h))
    return (b0, b1) if b1 > b0 else (0, 1)


def border_fill(frame: np.ndarray) -> Optional[np.ndarray]:
    """Fill: the pixels at code 0 in every channel that connect to the frame's border
    (the black a camera or a converter paints where a rotation uncovered the frame), as
    an ``(H, W)`` bool mask, or None when there is none. Such a pixel is no measurement:
    a warp that blends it into its neighbours makes dark, oddly coloured edges."""
    f = np.asarray(frame)

    def black(a):
        return a == 0 if a.ndim == 1 else np.all(a == 0, axis=-1)

    # The border first: a frame with no black pixel on it (nearly every photograph) costs
    # four rows and columns, not a pass over the frame.
    if not (black(f[0]).any() or black(f[-1]).any() or black(f[:, 0]).any() or black(f[:, -1]).any()):
        return None
    zero = f == 0 if f.ndim == 2 else np.all(f == 0, axis=2)
    from scipy import ndimage

    seed = np.zeros_like(zero)
    seed[[0, -1]] = zero[[0, -1]]
    seed[:, [0, -1]] = zero[:, [0, -1]]
    return ndimage.binary_propagation(seed, mask=zero)


# ------------------------------------------------------------------------ geometry


def translation(dy: float, dx: float) -> np.ndarray:
    """The matrix of the shift ``(dy, dx)``."""
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])


def apply(matrix: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """``(N, 2)`` points ``(x, y)`` mapped by ``matrix`` (projective division)."""
    p = np.c_[pts, np.ones(len(pts))] @ np.asarray(matrix, np.float64).T
    return p[:, :2] / p[:, 2:3]


def corners(h: int, w: int) -> np.ndarray:
    """The four corner pixel centres ``(x, y)`` of an ``h`` x ``w`` frame."""
    return np.array([[0.0, 0.0], [w - 1.0, 0.0], [w - 1.0, h - 1.0], [0.0, h - 1.0]])


def corner_distance(a: np.ndarray, b: np.ndarray, h: int, w: int) -> float:
    """Largest distance, in pixels, between where ``a`` and ``b`` send the corners and
    the centre of the frame."""
    pts = np.r_[corners(h, w), [[(w - 1) / 2.0, (h - 1) / 2.0]]]
    return float(np.max(np.hypot(*(apply(a, pts) - apply(b, pts)).T)))


def is_integer_shift(matrix: np.ndarray) -> bool:
    """True for a translation by whole pixels (its warp is an exact copy)."""
    m = np.asarray(matrix, np.float64)
    lin = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    lin[:2, 2] = np.round(m[:2, 2])
    return bool(np.allclose(m, lin, atol=SNAP / 4, rtol=0))


def _row_interval(matrix: np.ndarray, y: np.ndarray, h: int, w: int, margin: float):
    """Per output row ``y``, the interval ``[lo, hi]`` of x whose source lies in
    ``[margin, w-1-margin] x [margin, h-1-margin]`` (empty: lo > hi)."""
    m = np.asarray(matrix, np.float64)
    lo = np.full(y.shape, -np.inf)
    hi = np.full(y.shape, np.inf)
    # s > 0, and each bound u - b s >= 0 or b s - u >= 0: linear in x, a x + c >= 0
    cons = [(m[2, 0], m[2, 1] * y + m[2, 2])]
    for row, top in ((0, w - 1.0), (1, h - 1.0)):
        a_u, c_u = m[row, 0], m[row, 1] * y + m[row, 2]
        a_s, c_s = m[2, 0], m[2, 1] * y + m[2, 2]
        cons.append((a_u - margin * a_s, c_u - margin * c_s))
        cons.append(((top - margin) * a_s - a_u, (top - margin) * c_s - c_u))
    span = float(w + h)
    for a, c in cons:
        c = np.broadcast_to(np.asarray(c, np.float64), y.shape)
        flat = abs(a) * span <= 1e-9 * np.maximum(np.abs(c), 1.0)  # a x negligible over the frame
        bad = flat & (c < 0)
        lo[bad], hi[bad] = np.inf, -np.inf
        if a > 0:
            lo = np.where(flat, lo, np.maximum(lo, -c / a))
        elif a < 0:
            hi = np.where(flat, hi, np.minimum(hi, -c / a))
    return lo, hi


def crop_box(shape: Tuple[int, int], matrices: Sequence[np.ndarray]) -> Tuple[int, int, int, int]:
    """``(y0, y1, x0, x1)``: the largest axis-aligned box every warped frame covers.

    A frame warped by a whole-pixel shift covers what its source covers exactly; any
    other matrix loses a pixel more at each edge (the cubic's outer taps). Exact for
    the row-convex region the frames share (a convex polygon): each row's covered
    interval, then the best run of rows. Empty (``y1 == y0``) when nothing is shared.
    """
    h, w = shape
    y = np.arange(h, dtype=np.float64)
    lo = np.zeros(h)
    hi = np.full(h, w - 1.0)
    for m in matrices:
        margin = 0.0 if is_integer_shift(m) else 1.0 + 4e-3  # float32 coordinates on the device
        a, b = _row_interval(m, y, h, w, margin - (1e-6 if margin == 0 else 0))
        lo, hi = np.maximum(lo, a), np.minimum(hi, b)
    x0 = np.ceil(lo - 1e-9).clip(0, w).astype(np.int64)
    x1 = (np.floor(hi + 1e-9) + 1).clip(0, w).astype(np.int64)  # exclusive
    best = (0, 0, 0, 0, 0)
    for r0 in range(h):
        if x1[r0] <= x0[r0]:
            continue
        left = np.maximum.accumulate(x0[r0:])
        right = np.minimum.accumulate(x1[r0:])
        width = np.maximum(right - left, 0)
        area = width * np.arange(1, h - r0 + 1)
        k = int(np.argmax(area))
        if area[k] > best[0]:
            best = (int(area[k]), r0, r0 + k + 1, int(left[k]), int(right[k]))
    _, y0, y1, bx0, bx1 = best
    return y0, y1, bx0, bx1


def crop_frames(frames: List[np.ndarray], valid: List[Optional[np.ndarray]], box):
    """Frames and masks cut to ``box`` ``(y0, y1, x0, x1)`` (contiguous copies)."""
    y0, y1, x0, x1 = box
    out = [np.ascontiguousarray(f[y0:y1, x0:x1]) for f in frames]
    masks = [None if v is None else np.ascontiguousarray(v[y0:y1, x0:x1]) for v in valid]
    return out, masks
