"""Translation alignment of hand-held brackets by median threshold bitmaps (Ward 2003).

``merge --align`` starts here and goes on in :mod:`hdrcl.core.align.handheld` (sub-pixel
translation, similarity or homography, and the warp).

G. Ward, "Fast, robust image registration for compositing high dynamic range
photographs from hand-held exposures", Journal of Graphics Tools 8(2), 2003.

Each frame is reduced to a grey image, ``grey = (54 R + 183 G + 19 B) >> 8`` (or its one
channel), and a pyramid of 2x2 box averages. At every level the *threshold bitmap*
``tb = grey > t`` at the median ``t`` is nearly the same picture whatever the exposure,
and the *exclusion bitmap* ``eb = |grey - t| > tol`` drops the pixels too close to the
threshold to be trusted. The shift of a frame against the reference is searched from
the coarsest level down: the estimate is doubled, and the 9 shifts around it are scored
by

    cost(dy, dx) = #{(y, x) : (tb_r(y, x) ^ tb_f(y + dy, x + dx)) & eb_r(y, x) & eb_f(y + dy, x + dx)}

where pixels of the frame outside the image count nothing. The cheapest wins; ties go
to the smaller ``dy^2 + dx^2``, then the smaller ``(dy, dx)``.

Two extensions of Ward's method, both inert on ordinary brackets:

* **Coarse search radius.** The coarsest level is searched exhaustively over
  ``|dy|, |dx| <= R`` with ``R = max(1, 2^(7 - L) - 1)`` for ``L`` levels, so the reach,
  ``(R + 1) 2^(L - 1) - 1``, is at least 63 pixels whatever ``L`` (Ward: ``R = 1``, reach
  ``2^L - 1``). Small frames get fewer levels (a coarsest level of a few pixels cannot
  be trusted) and a wider coarse search instead.
* **Shared percentile.** The bitmaps work because a given percentile of the grey levels
  marks the same scene isophote at every exposure; the median is Ward's choice. When
  the median of the frame or of the reference lies in the clipped or noise-floor range
  (within ``2 tol + 1`` codes of either end), the pair uses instead the percentile
  nearest the median at which both frames are well exposed (see
  :func:`shared_percentile`). Frames 6 or more stops from the reference then still
  align.

**Shift convention.** A frame's shift ``(dy, dx)`` means its content sits ``(dy, dx)``
pixels from where it sits in the reference: ``frame(y + dy, x + dx) ~ reference(y, x)``.
:func:`apply_shifts` undoes it.

The bitmap building and the shift search run as OpenCL kernels (``kernels/align.cl``,
host side :class:`hdrcl.cl.align.AlignProcessor`); thresholds (order statistics of the
grey levels) are picked on the host. :func:`grey_image`, :func:`downsample`,
:func:`threshold_bitmaps` and :func:`shift_costs` are the kernels' NumPy twins, integer
throughout, so kernel and twin give *equal* costs. :class:`NumpyAligner` (the twins
behind the processor's interface) is also the fallback when OpenCL is off
(``HDRCL_OPENCL=0``) or has no device (unless ``HDRCL_REQUIRE_OPENCL=1``).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from hdrcl.cl.pyramid import GreyPyramid, level_shapes

logger = logging.getLogger(__name__)

#: Pyramid levels at most by default (Ward's 6: reach 63 pixels).
DEFAULT_LEVELS = 6
#: With the default levels, the coarsest level keeps at least this many pixels on its
#: short side.
MIN_LEVEL_SIDE = 16
#: Percentiles are fixed point: q = Q / QONE.
QONE = 1 << 16
QMEDIAN = QONE // 2

Shift = Tuple[int, int]


# --------------------------------------------------------------------------- twins


def grey_image(frame: np.ndarray) -> np.ndarray:
    """Grey level of each pixel, ``(H, W)`` uint16, in the frame's code units.

    ``(54 R + 183 G + 19 B) >> 8`` (Ward 2003) for 3 or more channels (the first three
    are R, G, B), the channel itself for one. Twin of the ``grey`` kernel.
    """
    frame = np.asarray(frame)
    if frame.ndim == 2:
        return frame.astype(np.uint16)
    c = frame.shape[2]
    if c == 1:
        return frame[:, :, 0].astype(np.uint16)
    if c == 2:
        raise ValueError("alignment needs 1 channel or at least 3 (R, G, B first), not 2")
    f = frame.astype(np.uint32)
    return ((54 * f[..., 0] + 183 * f[..., 1] + 19 * f[..., 2]) >> 8).astype(np.uint16)


def downsample(grey: np.ndarray) -> np.ndarray:
    """Next pyramid level: 2x2 box mean rounded half up, ``(a + b + c + d + 2) >> 2``.

    An odd last row or column is dropped. Twin of the ``downsample`` kernel.
    """
    h, w = grey.shape[0] // 2, grey.shape[1] // 2
    g = grey[: 2 * h, : 2 * w].astype(np.uint32)
    s = g[0::2, 0::2] + g[0::2, 1::2] + g[1::2, 0::2] + g[1::2, 1::2]
    return ((s + 2) >> 2).astype(np.uint16)


def threshold_bitmaps(grey: np.ndarray, threshold: int, tol: int) -> Tuple[np.ndarray, np.ndarray]:
    """``(tb, eb)``: ``grey > threshold`` and ``|grey - threshold| > tol``, ``(H, W)`` bool.

    Twin of the ``threshold`` kernel (which packs the same bits 32 to a word).
    """
    g = np.asarray(grey).astype(np.int32)
    return g > threshold, np.abs(g - threshold) > tol


def shift_costs(tb1: np.ndarray, eb1: np.ndarray, tb2: np.ndarray, eb2: np.ndarray,
                cy: int, cx: int) -> np.ndarray:
    """Mismatch counts of the 9 shifts of frame 2 around ``(cy, cx)``, ``(3, 3)`` int64.

    ``out[j, i]`` is the cost (module docstring) of ``(dy, dx) = (cy + j - 1, cx + i - 1)``
    over the pixels of frame 1 whose shifted partner lies inside frame 2. Twin of the
    ``shift_cost`` kernel.
    """
    h, w = tb1.shape
    out = np.zeros((3, 3), np.int64)
    for j in range(3):
        dy = cy + j - 1
        y0, y1 = max(0, -dy), min(h, h - dy)
        for i in range(3):
            dx = cx + i - 1
            x0, x1 = max(0, -dx), min(w, w - dx)
            if y0 >= y1 or x0 >= x1:
                continue
            a = (slice(y0, y1), slice(x0, x1))
            b = (slice(y0 + dy, y1 + dy), slice(x0 + dx, x1 + dx))
            out[j, i] = np.count_nonzero((tb1[a] ^ tb2[b]) & eb1[a] & eb2[b])
    return out


# ------------------------------------------------------------- thresholds (host)


def level_threshold(grey: np.ndarray, q: int = QMEDIAN) -> int:
    """Grey value of rank ``((n - 1) q) >> 16`` (``q = QMEDIAN``: the lower median).

    Exact and integer, so both paths threshold at the same value.
    """
    flat = np.asarray(grey).ravel()
    k = ((flat.size - 1) * int(q)) >> 16
    return int(np.partition(flat, k)[k])


def usable_interval(grey: np.ndarray, lo: int, hi: int) -> Tuple[float, float]:
    """Fractions of pixels ``<= lo`` and ``< hi``: percentiles between them fall in the
    well-exposed range ``(lo, hi)``."""
    n = max(grey.size, 1)
    return np.count_nonzero(grey <= lo) / n, np.count_nonzero(grey < hi) / n


def shared_percentile(ref: Tuple[float, float], frm: Tuple[float, float]) -> int:
    """The percentile (fixed point, :data:`QONE` = 100 %) a pair is thresholded at.

    The overlap of the two frames' usable intervals (:func:`usable_interval`) is
    narrowed by 5 percentage points at each end (a quarter of its width if that is
    less); the result is the median if it lies inside, else the nearer end. When the
    intervals do not overlap, the middle of the gap between them.
    """
    a, b = max(ref[0], frm[0]), min(ref[1], frm[1])
    if a <= b:
        m = min(0.05, (b - a) / 4.0)
        q = min(max(0.5, a + m), b - m)
    else:
        q = (a + b) / 2.0
    return int(min(max(round(q * QONE), 0), QONE))




def default_levels(h: int, w: int) -> int:
    """:data:`DEFAULT_LEVELS`, or fewer so the coarsest level keeps
    :data:`MIN_LEVEL_SIDE` pixels on its short side (at least 1)."""
    levels = 1
    while levels < DEFAULT_LEVELS and (min(h, w) >> levels) >= MIN_LEVEL_SIDE:
        levels += 1
    return levels


def coarse_radius(levels: int) -> int:
    """Search radius at the coarsest level: reach ``(R + 1) 2^(L - 1) - 1 >= 63``."""
    return max(1, (1 << max(0, 7 - levels)) - 1)


# ------------------------------------------------------------ the twin aligner




@dataclass
class HostBitmaps:
    """Threshold and exclusion bitmaps of a pyramid as ``(h, w)`` bool arrays."""

    shapes: List[Tuple[int, int]]
    thresholds: List[int]
    tb: List[np.ndarray]
    eb: List[np.ndarray]


class NumpyAligner:
    """The twins behind the interface of :class:`hdrcl.cl.align.AlignProcessor`:
    :meth:`grey_pyramid`, :meth:`bitmaps`, :meth:`costs`."""

    def grey_pyramid(self, frame: np.ndarray, levels: int, slot: str = "frame", host_from: int = 0) -> GreyPyramid:
        frame = np.asarray(frame)
        if frame.dtype not in (np.uint8, np.uint16):
            raise TypeError(f"frames must be uint8 or uint16, not {frame.dtype}")
        g = grey_image(frame)
        shapes = level_shapes(g.shape[0], g.shape[1], levels)
        host = [g]
        for _ in range(levels - 1):
            host.append(downsample(host[-1]))
        return GreyPyramid(slot, shapes, [g if k >= host_from else None for k, g in enumerate(host)])

    def bitmaps(self, gp: GreyPyramid, thresholds: Sequence[int], tol: int) -> HostBitmaps:
        tb, eb = zip(*(threshold_bitmaps(g, t, tol) for g, t in zip(gp.host, thresholds)))
        return HostBitmaps(gp.shapes, list(thresholds), list(tb), list(eb))

    def costs(self, ref: HostBitmaps, frm: HostBitmaps, level: int, cy: int, cx: int) -> np.ndarray:
        if ref.shapes[level] != frm.shapes[level]:
            raise ValueError(f"pyramid levels differ in shape: {ref.shapes[level]} vs {frm.shapes[level]}")
        return shift_costs(ref.tb[level], ref.eb[level], frm.tb[level], frm.eb[level], cy, cx)


# ---------------------------------------------------------------- processor choice

def get_aligner(device: Optional[str] = None):
    """The process-wide :class:`~hdrcl.cl.align.AlignProcessor` for ``device``, or a
    :class:`NumpyAligner` (the twins).

    Same rules as :func:`hdrcl.cl.backend.get_processor`: ``HDRCL_OPENCL=0`` selects the
    twins; a device that cannot be opened falls back to them with a warning, unless
    ``HDRCL_REQUIRE_OPENCL=1`` or a ``device`` was named, which make it an error.
    """
    from hdrcl.cl.backend import get_processor

    proc = get_processor("align", device)
    return NumpyAligner() if proc is None else proc


# ------------------------------------------------------------------------- search


def _key(cost: int, dy: int, dx: int) -> Tuple[int, int, int, int]:
    """Order of candidates: cost, then dy^2 + dx^2, then (dy, dx)."""
    return (int(cost), dy * dy + dx * dx, dy, dx)


def search_shift(aligner, ref_bm, frm_bm, levels: int, radius: int = 1) -> Tuple[Shift, int]:
    """Coarse-to-fine shift of ``frm_bm`` against ``ref_bm`` (bitmap pyramids of
    ``aligner``); also its cost at full size.

    The coarsest level is searched over ``|dy|, |dx| <= radius`` (in 3x3 tiles, the
    kernel's unit), every finer one over the 9 shifts around twice the estimate so far.
    """
    top = levels - 1
    best = None
    tiles = range(-radius + 1, radius + 2, 3)  # 3x3 tiles whose union covers [-radius, radius]
    for ty in tiles:
        for tx in tiles:
            c = aligner.costs(ref_bm, frm_bm, top, ty, tx)
            for j in range(3):
                for i in range(3):
                    dy, dx = ty + j - 1, tx + i - 1
                    if abs(dy) <= radius and abs(dx) <= radius:
                        k = _key(c[j, i], dy, dx)
                        best = k if best is None or k < best else best
    cost, _, dy, dx = best
    for level in range(top - 1, -1, -1):
        cy, cx = 2 * dy, 2 * dx
        c = aligner.costs(ref_bm, frm_bm, level, cy, cx)
        cost, _, dy, dx = min(_key(c[j, i], cy + j - 1, cx + i - 1) for j in range(3) for i in range(3))
    return (dy, dx), cost


def _tolerance(tolerance: float, dtype) -> int:
    """``tolerance`` (8-bit code units) in the frames' own code units."""
    if not tolerance >= 0:
        raise ValueError(f"tolerance must be >= 0, not {tolerance}")
    scale = 257.0 if np.dtype(dtype) == np.uint16 else 1.0  # 65535 / 255
    return int(round(tolerance * scale))


def _check_frames(frames: Sequence[np.ndarray]) -> None:
    if len(frames) == 0:
        raise ValueError("no frames to align")
    shape, dtype = frames[0].shape, frames[0].dtype
    for j, f in enumerate(frames):
        if f.shape != shape:
            raise ValueError(f"frame {j} is {f.shape} but frame 0 is {shape}: frames must be the same size")
        if f.dtype != dtype:
            raise ValueError(f"frame {j} is {f.dtype} but frame 0 is {dtype}: frames must share one depth")


def estimate_shifts(
    frames: Sequence[np.ndarray],
    reference: Optional[int] = None,
    *,
    levels: Optional[int] = None,
    tolerance: float = 4,
    device: Optional[str] = None,
) -> List[Shift]:
    """Translation of each frame against the reference, by median threshold bitmaps.

    Parameters
    ----------
    frames : sequence of ndarray (H, W, C) or (H, W), uint8 or uint16
        The bracket, ordered by increasing exposure; one size and depth.
    reference : int, optional
        Index of the frame the others are aligned to. Default ``len(frames) // 2``, the
        middle exposure when frames are ordered by exposure (it has the most pixels
        well exposed, and the fewest stops to the extremes).
    levels : int, optional
        Pyramid levels. Default 6 (Ward's), fewer for frames too small for them (the
        coarsest level keeps 16 pixels on its short side). The search reaches at least
        63 pixels whatever the levels (module docstring); few levels on large frames
        make the coarse search slow.
    tolerance : float
        Exclusion half-width around the threshold, in 8-bit code units (scaled by 257
        for 16-bit frames). Ward's default, 4, ignores sensor noise near the threshold.
    device : str, optional
        OpenCL device (as for :func:`hdrcl.cl.context.select_device`).

    Returns
    -------
    list of (dy, dx) int
        Per frame (the reference's is ``(0, 0)``), with the convention
        ``frame(y + dy, x + dx) ~ reference(y, x)``.
    """
    _check_frames(frames)
    n = len(frames)
    ref = n // 2 if reference is None else int(reference)
    if not 0 <= ref < n:
        raise ValueError(f"reference {reference} out of range for {n} frames")
    h, w = frames[0].shape[:2]
    levels = default_levels(h, w) if levels is None else int(levels)
    level_shapes(h, w, levels)  # validates before any device work
    radius = coarse_radius(levels)
    tol = _tolerance(tolerance, frames[0].dtype)
    top = np.iinfo(frames[0].dtype).max
    lo, hi = 2 * tol + 1, top - 2 * tol - 1  # threshold range away from noise floor and clipping
    if n == 1:
        return [(0, 0)]
    aligner = get_aligner(device)

    shifts, _ = shift_search(aligner, frames, ref, levels, radius, tol, lo, hi)
    return shifts


def shift_search(aligner, frames, ref: int, levels: int, radius: int, tol: int, lo: int, hi: int,
                 keep_from: Optional[int] = None) -> Tuple[List[Shift], List[List[np.ndarray]]]:
    """The search of :func:`estimate_shifts` per frame; also, with ``keep_from``, each
    frame's grey pyramid from that level down to the coarsest (host arrays, for the
    sub-pixel registration of :mod:`hdrcl.core.align.register`)."""
    ref_gp = aligner.grey_pyramid(frames[ref], levels, slot="ref")
    kept: List[List[np.ndarray]] = [[] for _ in frames]
    if keep_from is not None:
        kept[ref] = list(ref_gp.host[keep_from:])
    ref_use = usable_interval(ref_gp.host[0], lo, hi)
    ref_bms: Dict[int, Any] = {}  # reference bitmaps by percentile, rebuilt when it changes
    shifts: List[Shift] = []
    for j, f in enumerate(frames):
        if j == ref:
            shifts.append((0, 0))
            logger.info("align: frame %d is the reference", j)
            continue
        gp = aligner.grey_pyramid(f, levels, slot="frame")
        if keep_from is not None:
            kept[j] = list(gp.host[keep_from:])
        q = shared_percentile(ref_use, usable_interval(gp.host[0], lo, hi))
        if q not in ref_bms:
            ref_bms.clear()  # one reference set at a time: the device holds one slot
            ref_bms[q] = aligner.bitmaps(ref_gp, [level_threshold(g, q) for g in ref_gp.host], tol)
        bm = aligner.bitmaps(gp, [level_threshold(g, q) for g in gp.host], tol)
        (dy, dx), cost = search_shift(aligner, ref_bms[q], bm, levels, radius)
        shifts.append((dy, dx))
        logger.info("align: frame %d shift dy=%+d dx=%+d px (threshold at the %.1f%% point; "
                    "%d mismatching pixels)", j, dy, dx, 100.0 * q / QONE, cost)
    return shifts, kept


def crop_box(shape: Tuple[int, int], shifts: Sequence[Shift]) -> Tuple[int, int, int, int]:
    """``(y0, y1, x0, x1)``: the region every aligned frame covers (may be empty:
    ``y1 <= y0`` or ``x1 <= x0`` when shifts exceed the frame)."""
    h, w = shape
    y0 = max([0] + [-dy for dy, _ in shifts])
    y1 = min([h] + [h - dy for dy, _ in shifts])
    x0 = max([0] + [-dx for _, dx in shifts])
    x1 = min([w] + [w - dx for _, dx in shifts])
    return y0, max(y0, y1), x0, max(x0, x1)


def _shift(a: np.ndarray, dy: int, dx: int, fill=0) -> np.ndarray:
    """``out(y, x) = a(y + dy, x + dx)``, ``fill`` where that is outside ``a``."""
    h, w = a.shape[:2]
    y0, y1 = max(0, -dy), min(h, h - dy)
    x0, x1 = max(0, -dx), min(w, w - dx)
    if y0 >= y1 or x0 >= x1:
        return np.full_like(a, fill)
    out = np.empty_like(a)  # fill only the borders: one pass over the frame, not two
    out[:y0] = fill
    out[y1:] = fill
    out[y0:y1, :x0] = fill
    out[y0:y1, x1:] = fill
    out[y0:y1, x0:x1] = a[y0 + dy:y1 + dy, x0 + dx:x1 + dx]
    return out


def apply_shifts(
    frames: Sequence[np.ndarray],
    shifts: Sequence[Shift],
    valid: Optional[Sequence[Optional[np.ndarray]]] = None,
) -> Tuple[List[np.ndarray], List[Optional[np.ndarray]], Tuple[int, int, int, int]]:
    """Undo integer translations: aligned frames, their validity masks, the common box.

    Parameters
    ----------
    frames : sequence of ndarray (H, W, ...)
    shifts : sequence of (dy, dx)
        As :func:`estimate_shifts` returns them.
    valid : sequence of (H, W) bool or None, optional
        Existing per-frame validity (None: all valid); shifted with the frames.

    Returns
    -------
    frames : list of ndarray
        Same shape and dtype; ``out(y, x) = frame(y + dy, x + dx)``, 0 where that falls
        outside the frame (no wrap-around).
    valid : list of (H, W) bool or None
        False where a frame lost coverage (or was invalid before); None for a frame that
        is valid everywhere (unshifted, no mask given), as :func:`hdrcl.core.reference.fuse`
        accepts.
    crop : (y0, y1, x0, x1)
        The box every frame covers (:func:`crop_box`), for callers that crop rather
        than mask.
    """
    if len(shifts) != len(frames):
        raise ValueError(f"{len(shifts)} shifts for {len(frames)} frames")
    if valid is not None and len(valid) != len(frames):
        raise ValueError(f"{len(valid)} validity masks for {len(frames)} frames")
    out_f: List[np.ndarray] = []
    out_v: List[Optional[np.ndarray]] = []
    for j, (f, (dy, dx)) in enumerate(zip(frames, shifts)):
        dy, dx = int(dy), int(dx)
        v = None if valid is None else valid[j]
        if dy == 0 and dx == 0:
            out_f.append(f)
            out_v.append(None if v is None else np.asarray(v, bool))
            continue
        out_f.append(_shift(np.asarray(f), dy, dx))
        base = np.ones(f.shape[:2], bool) if v is None else np.asarray(v, bool)
        out_v.append(_shift(base, dy, dx, fill=False))
    return out_f, out_v, crop_box(frames[0].shape[:2], shifts)


@dataclass
class AlignResult:
    """What :func:`align` found and made.

    Attributes
    ----------
    shifts : list of (dy, dx)
        Per frame, ``frame(y + dy, x + dx) ~ reference(y, x)``.
    crop : (y0, y1, x0, x1)
        Box covered by every aligned frame.
    valid : list of (H, W) bool or None
        Per-frame validity after alignment (None: valid everywhere).
    frames : list of ndarray
        The aligned frames (same shape and dtype as given).
    reference : int
        Index of the reference frame.
    """

    shifts: List[Shift]
    crop: Tuple[int, int, int, int]
    valid: List[Optional[np.ndarray]]
    frames: List[np.ndarray]
    reference: int


def align(
    frames: Sequence[np.ndarray],
    reference: Optional[int] = None,
    *,
    levels: Optional[int] = None,
    tolerance: float = 4,
    device: Optional[str] = None,
    valid: Optional[Sequence[Optional[np.ndarray]]] = None,
) -> AlignResult:
    """:func:`estimate_shifts` then :func:`apply_shifts` (parameters as theirs)."""
    ref = len(frames) // 2 if reference is None else int(reference)
    shifts = estimate_shifts(frames, ref, levels=levels, tolerance=tolerance, device=device)
    out, v, crop = apply_shifts(frames, shifts, valid)
    y0, y1, x0, x1 = crop
    logger.info("align: region covered by every frame rows %d:%d, columns %d:%d", y0, y1, x0, x1)
    return AlignResult(shifts=shifts, crop=crop, valid=v, frames=out, reference=ref)
