"""Automatic choice of the pixels that calibrate the response curve.

The paper picked its 28-50 pixels by hand and asked for an automatic choice: pixels in
smooth regions (so small misregistration or blur does not matter), spread over the
image, never invalid, and together covering the whole brightness range. This module
does that deterministically for a given seed.
"""
from __future__ import annotations

import logging
from typing import Optional, Sequence

import numpy as np

logger = logging.getLogger(__name__)

#: Selection works on a decimated grid of at most this many pixels, so its cost does not
#: grow with the photograph.
MAX_GRID_PIXELS = 250_000

#: Number of brightness strata; the samples are shared out among them.
MAX_BINS = 64


def _box_sum(a: np.ndarray, k: int, mode: str) -> np.ndarray:
    """Sum over the k x k window centred on each pixel (summed-area table), the image
    extended by ``mode`` ("constant": zeros, "edge": nearest pixel). NumPy only, so
    calibration does not pay for importing scipy.ndimage."""
    r = k // 2
    p = np.pad(a, r, mode=mode) if mode == "edge" else np.pad(a, r)
    c = np.zeros((p.shape[0] + 1, p.shape[1] + 1))
    c[1:, 1:] = p.cumsum(0).cumsum(1)
    h, w = a.shape
    return c[k:k + h, k:k + w] - c[:h, k:k + w] - c[k:k + h, :w] + c[:h, :w]


def grid_stride(height: int, width: int) -> int:
    """Stride of the decimated grid that sample selection works on."""
    return max(1, int(np.ceil(np.sqrt(height * width / MAX_GRID_PIXELS))))


def default_sample_count(knots: int, frames: int) -> int:
    """Samples needed for a well-posed solve with some margin.

    The system is over-determined when ``N (P - 1) > levels``; three times that, and
    never fewer than 200 pixels, keeps noise in any one pixel from bending the curve.
    """
    needed = int(np.ceil(3.0 * knots / max(frames - 1, 1)))
    return int(min(max(1000, needed), 5000))


def _quarter_quantiles(order: np.ndarray, values: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """``np.quantile(values[bins == b], 0.25)`` for every bin b (NaN for an empty bin), bit
    for bit: the same virtual index and the same interpolation as NumPy's default
    ("linear") method. ``order`` sorts the pixels by bin, ``starts`` where each bin
    begins in it."""
    nb = starts.size - 1
    counts = np.diff(starts)
    virtual = counts * 0.25 - 0.25  # NumPy: n q + (1 + q (1 - 1 - 1)) - 1, exact here
    prev = np.floor(virtual)
    gamma = virtual - prev
    prev = prev.astype(np.int64)
    nxt = np.minimum(prev + 1, counts - 1)
    ok = counts > 0
    q = np.full(nb, np.nan)
    # The two order statistics of each bin by partition (values, not positions: the same
    # numbers a sort by (bin, value) puts there), linear in the bin's size.
    a = np.empty(int(ok.sum()))
    b = np.empty_like(a)
    by_bin = values[order]
    for m, j in enumerate(np.flatnonzero(ok)):
        part = np.partition(by_bin[starts[j]:starts[j + 1]], (prev[j], nxt[j]))
        a[m], b[m] = part[prev[j]], part[nxt[j]]
    t = gamma[ok]
    diff = b - a
    q[ok] = np.where(t >= 0.5, b - diff * (1 - t), a + diff * t)
    return q


def _smallest_first(values: np.ndarray, k: int) -> np.ndarray:
    """Positions of the ``k`` smallest ``values``, ties to the earlier: the set
    ``np.argsort(values, kind="stable")[:k]`` holds (in position order), found by
    partition instead of a sort of them all."""
    if k >= values.size:
        return np.arange(values.size)
    if k <= 0:
        return np.zeros(0, np.int64)
    kth = np.partition(values, k - 1)[k - 1]
    less = np.flatnonzero(values < kth)
    return np.sort(np.concatenate([less, np.flatnonzero(values == kth)[:k - less.size]]))


def _small_keys(bins: np.ndarray, nbins: int) -> np.ndarray:
    """``bins`` (0 .. nbins - 1) as the smallest unsigned integers that hold them: NumPy's
    stable sort of 8- and 16-bit integers is a radix sort, the same order at a fraction
    of the cost of sorting int64."""
    return bins.astype(np.uint8 if nbins <= 256 else np.uint16 if nbins <= 65536 else np.int64)


class SampleCandidates:
    """The pixels a bracket's samples are drawn from, with their brightness key and
    smoothness: everything :func:`select_samples` computes before it knows how many
    samples are wanted. A calibration draws twice from one bracket (the exposure check's
    400 samples, then the curve's), so it makes this once (:func:`sample_candidates`) and
    passes it to both; the draws are those :func:`select_samples` makes without it."""

    def __init__(self, frames, valid, decimate):
        h, w = frames[0].shape[:2]
        stride = grid_stride(h, w) if decimate else 1
        key = np.zeros((len(range(0, h, stride)), len(range(0, w, stride))), np.float64)
        top = 0.0
        for f in frames:
            sub = f[::stride, ::stride]
            sub = sub.reshape(sub.shape[0], sub.shape[1], -1)
            for c in range(sub.shape[2]):  # integer sums: exact in float64 in any order
                key += sub[:, :, c]
            top += sub.shape[2] * float(np.iinfo(f.dtype).max)

        usable = np.ones(key.shape, bool) if valid is None else valid[::stride, ::stride].copy()
        # Stay clear of invalid areas and of the image border: samples must sit inside
        # smooth, fully measured neighbourhoods.
        if min(key.shape) > 8:
            usable = _box_sum(usable.astype(np.float64), 5, "constant") > 24.5  # 5x5 erosion, outside = 0
        # A pixel clipped in every frame and channel carries no measurement.
        usable &= (key > 0) & (key < top)

        mean = _box_sum(key, 5, "edge") / 25.0
        var = _box_sum(key * key, 5, "edge") / 25.0 - mean * mean

        self.shape = (h, w)
        self.stride = stride
        self.grid = key.shape
        self.frames = len(frames)
        self.cand = np.flatnonzero(usable)
        self.kv = key.ravel()[self.cand]
        self.vv = var.ravel()[self.cand]
        self._strata = {}

    def fits(self, frames, decimate) -> bool:
        """Whether these candidates are those of ``frames`` (by shape and count)."""
        h, w = frames[0].shape[:2]
        return (h, w) == self.shape and len(frames) == self.frames and \
            self.stride == (grid_stride(h, w) if decimate else 1)

    def strata(self, nbins: int):
        """``(bins, order, starts, smooth_at, smooth_starts)`` of ``nbins`` brightness
        strata (equal-width key bins), made once per ``nbins``."""
        got = self._strata.get(nbins)
        if got is None:
            kv, vv = self.kv, self.vv
            lo, hi = kv.min(), kv.max()
            bins = np.minimum(((kv - lo) / max(hi - lo, 1e-12) * nbins).astype(np.int64), nbins - 1)
            order = np.argsort(_small_keys(bins, nbins), kind="stable")
            starts = np.searchsorted(bins[order], np.arange(nbins + 1))
            smooth_at = order[vv[order] <= _quarter_quantiles(order, vv, starts)[bins[order]]]
            smooth_starts = np.searchsorted(bins[smooth_at], np.arange(nbins + 1))
            got = self._strata[nbins] = (bins, order, starts, smooth_at, smooth_starts)
        return got


def sample_candidates(frames: Sequence[np.ndarray], valid: Optional[np.ndarray] = None,
                      decimate: bool = True) -> SampleCandidates:
    """The candidates of :func:`select_samples` for ``frames``, to draw from several times."""
    return SampleCandidates(frames, valid, decimate)


def select_samples(
    frames: Sequence[np.ndarray],
    valid: Optional[np.ndarray],
    n: int,
    seed: int = 0,
    decimate: bool = True,
    candidates: Optional[SampleCandidates] = None,
) -> np.ndarray:
    """Choose ``n`` calibration pixels.

    Parameters
    ----------
    frames : sequence of ndarray
        The bracket, each ``(H, W, C)`` integer codes.
    valid : ndarray of bool, shape (H, W), optional
        Pixels usable in *every* frame (alpha and ignore-colour already applied).
    n : int
        Number of pixels wanted.
    seed : int
        Seed of the random choice within each stratum; the result depends only on it
        and the data.
    decimate : bool
        Work on the :func:`grid_stride` grid (the default). False when ``frames`` are
        that grid already, read so by :meth:`hdrcl.io.reader.BracketReader.read_grid`.
    candidates : SampleCandidates, optional
        :func:`sample_candidates` of these ``frames``, ``valid`` and ``decimate``, made
        once for several draws; the result is the same as without it.

    Returns
    -------
    numpy.ndarray
        Flat indices (row * W + col) into the full-resolution image, at most ``n`` of
        them, sorted. Fewer are returned only when fewer usable pixels exist.

    Notes
    -----
    The key that orders pixels by brightness is the sum of their codes over all frames
    and channels: each frame adds a monotonic function of the scene radiance, so the key
    is monotonic in radiance and roughly linear in log radiance over the bracketed
    range. Pixels are stratified into equal-width key bins; within a bin the choice is
    random among the smoothest quarter (lowest 5x5 variance of the key), which spreads
    the samples over the image while keeping them away from edges.
    """
    pool = candidates if candidates is not None and candidates.fits(frames, decimate) else \
        SampleCandidates(frames, valid, decimate)
    cand, vv = pool.cand, pool.vv
    if cand.size == 0:
        return np.zeros(0, np.int64)
    n = int(min(n, cand.size))
    nbins = int(min(MAX_BINS, n))
    bins, order, starts, smooth_at, smooth_starts = pool.strata(nbins)

    rng = np.random.default_rng(seed)
    chosen: list = []
    quota = n / nbins
    owed = 0.0
    for b in range(nbins):
        owed += quota
        if starts[b + 1] == starts[b]:
            continue
        smooth = smooth_at[smooth_starts[b]:smooth_starts[b + 1]]
        take = int(min(np.floor(owed + 1e-9), smooth.size))
        pick = rng.choice(smooth, size=take, replace=False) if take else np.zeros(0, np.int64)
        chosen.append(pick)
        owed -= take
    sel = np.concatenate(chosen) if chosen else np.zeros(0, np.int64)
    missing = n - sel.size
    if missing > 0:
        # Sparse strata could not fill their share: take the smoothest of the rest.
        picked = np.zeros(cand.size, bool)
        picked[sel] = True
        rest = order[~picked[order]]
        rest = rest[_smallest_first(vv[rest], missing)]
        sel = np.concatenate([sel, rest])

    flat = cand[sel]
    rows, cols = np.divmod(flat, pool.grid[1])
    full = (rows * pool.stride) * pool.shape[1] + cols * pool.stride
    logger.debug("selected %d samples on a %dx%d grid (stride %d)", full.size, *pool.grid, pool.stride)
    return np.sort(full.astype(np.int64))
