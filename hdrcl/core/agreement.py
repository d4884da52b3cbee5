"""Do the frames agree? Misregistration and moving subjects found in every merge.

Once the exposures are known, two frames adjacent in exposure say the same thing about
every pixel both measure: ``ln E = g(Z) - ln t``. Where they do not, either the camera
moved between them (the disagreement sits at every edge and a small shift of one frame
explains it) or something in the scene moved (a compact region disagrees, whatever the
shift). This check measures both on the sampling grid the merge already holds
(:attr:`hdrcl.core.runstate.RunState.grid`, every k-th row and column), in one channel
(green, or the only one), so it costs a few hundredths of the fusion.

Per pair of frames ``a`` (shorter) and ``b`` (next longer), over the pixels both hold in
their well-exposed range (codes 8 % to 92 % of full scale):

* ``d = ln E_b - ln E_a``; its median per band of ``Z_a`` (16 bands) is removed: a
  curve's error, film reciprocity or a wrong exposure time shift a whole band, and they
  are other checks' business. The noise allowance ``T`` is
  ``max(0.3, 5 x 1.4826 MAD)`` ln units per band.
* **shift**: phase correlation of the two ``ln E`` maps (Hann window, fills outside the
  common pixels), peak refined by a parabola, in full-resolution pixels (grid pixels
  times k). It counts as misregistration when it is at least :data:`SHIFT_PX` and
  shifting ``b`` by it removes at least :data:`EXPLAINED` of the residual's energy (so a
  featureless sky's noise peak does not count). Film frames on a tripod differ by
  0.5-0.8 px (the Memorial set): under the limit.
* **ghost**: a pixel where ``b`` lies outside the 3x3 envelope of ``a`` (plus ``T``) and
  ``a`` outside that of ``b`` (a misregistration by a grid pixel is not motion), or where
  one frame's clipped code bounds the radiance and the other frame's envelope lies beyond
  the bound by ``T`` (a bright object in one frame only, clipped there); lone pixels are
  removed by a 3x3 opening. The figure is the share of the picture's grid pixels; it
  counts as a moving subject from :data:`GHOST_PERCENT`.

A set fails the check with one :class:`hdrcl.core.findings.Finding` (check
``agreement``) per cause: severity ``check`` (the result cannot be vouched for), or
``note`` where the merge already corrected it (``--align``'s frames still shifted is a
``check``; ghosts under ``--deghost`` a ``note``).
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from typing import List, Optional, Sequence

import numpy as np

from hdrcl.core.findings import CHECK, NOTE, Finding

logger = logging.getLogger(__name__)

#: Full-resolution pixels of shift between adjacent frames that count as misregistration.
SHIFT_PX = 1.5
#: Share of the residual's energy a shift must remove to count (not a noise peak).
EXPLAINED = 0.25
#: Percent of the picture (grid pixels) where two frames disagree beyond any shift of a
#: grid pixel, from which it counts as a moving subject.
GHOST_PERCENT = 1.0
#: Well-exposed codes, as fractions of full scale.
BODY = (0.08, 0.92)
#: Least noise allowance (ln units) and the spreads (robust sigma) beyond it.
FLOOR_LN, SPREADS = 0.3, 5.0
#: At the coarsest level a shift must cost under this share of no shift.
COARSE_GAIN = 0.8
#: Share of the grid two frames must both expose well for their shift to be measured.
SHIFT_SHARE = 0.05
#: Grid pixels the ghost test works on at most (every 2nd grid pixel beyond).
WORK_PIXELS = 120_000
#: Pixels two frames must share in their bodies to be compared.
MIN_PIXELS = 400
_BANDS = 16


@dataclass
class PairAgreement:
    """How frames ``short`` and ``long`` (indices into the merge's frames) agree."""

    short: int
    long: int
    pixels: int  # grid pixels both measure
    shift: tuple = (0.0, 0.0)  # (dy, dx) of ``long`` against ``short``, full-resolution px
    explained: float = 0.0  # share of the residual's energy the shift removes
    ghost_percent: float = 0.0  # of the picture's grid pixels

    @property
    def shift_px(self) -> float:
        return float(np.hypot(*self.shift))

    @property
    def moved(self) -> bool:
        return self.shift_px >= SHIFT_PX and self.explained >= EXPLAINED


@dataclass
class Agreement:
    """The pairs of a set (adjacent in exposure) and the grid's stride."""

    stride: int
    pairs: List[PairAgreement] = field(default_factory=list)


def _channel(frame: np.ndarray) -> np.ndarray:
    f = frame if frame.ndim == 3 else frame[..., None]
    return f[..., 1] if f.shape[2] >= 3 else f[..., 0]


def _envelope(x: np.ndarray, ok: np.ndarray):
    """3x3 min and max of ``x`` over the pixels ``ok`` (+inf / -inf where none):
    separable, a row pass then a column pass."""
    def run(v, op, fill):
        p = np.pad(v, ((0, 0), (1, 1)), constant_values=fill)
        r = op(op(p[:, :-2], p[:, 1:-1]), p[:, 2:])
        p = np.pad(r, ((1, 1), (0, 0)), constant_values=fill)
        return op(op(p[:-2], p[1:-1]), p[2:])

    return (run(np.where(ok, x, np.float32(np.inf)), np.minimum, np.inf),
            run(np.where(ok, x, np.float32(-np.inf)), np.maximum, -np.inf))


def _open3(mask: np.ndarray) -> np.ndarray:
    """3x3 binary opening: regions narrower than three grid pixels go."""
    def filt(m, op):
        p = np.pad(m, 1, constant_values=op is np.logical_and)
        h, w = m.shape
        out = m.copy()
        for dy in (0, 1, 2):
            for dx in (0, 1, 2):
                op(out, p[dy:dy + h, dx:dx + w], out=out)
        return out

    return filt(filt(mask, np.logical_and), np.logical_or)


def _banded(d: np.ndarray, band: np.ndarray):
    """Per band: the median of ``d`` and the allowance ``T``; global values where a band
    has too few pixels."""
    med = np.full(_BANDS, float(np.median(d)))
    mad = np.full(_BANDS, float(np.median(np.abs(d - med[0]))))
    order = np.argsort(band, kind="stable")
    starts = np.searchsorted(band[order], np.arange(_BANDS + 1))
    for b in range(_BANDS):
        part = d[order[starts[b]:starts[b + 1]]]
        if part.size >= 50:
            med[b] = float(np.median(part))
            mad[b] = float(np.median(np.abs(part - med[b])))
    return med, np.maximum(FLOOR_LN, SPREADS * 1.4826 * mad)


def _half(x: np.ndarray, ok: np.ndarray):
    """2x2 block means of ``x`` over ``ok`` (a block needs 3 of its 4 pixels)."""
    h, w = (x.shape[0] // 2) * 2, (x.shape[1] // 2) * 2
    xs = np.where(ok, x, np.float32(0))
    okf = ok.astype(np.float32)
    total = xs[0:h:2, 0:w:2] + xs[1:h:2, 0:w:2] + xs[0:h:2, 1:w:2] + xs[1:h:2, 1:w:2]
    n = okf[0:h:2, 0:w:2] + okf[1:h:2, 0:w:2] + okf[0:h:2, 1:w:2] + okf[1:h:2, 1:w:2]
    return total / np.maximum(n, 1), n >= 3


def _cost(a, ma, b, mb, dy: int, dx: int, cap: float, least: int) -> float:
    """Mean capped squared difference of ``a[y, x]`` and ``b[y - dy, x - dx]`` over the
    pixels both hold (inf when they share fewer than ``least``); ``ma``, ``mb`` are the
    masks as 0/1 floats."""
    h, w = a.shape
    if abs(dy) >= h or abs(dx) >= w:
        return np.inf
    ya, yb = (slice(dy, h), slice(0, h - dy)) if dy >= 0 else (slice(0, h + dy), slice(-dy, h))
    xa, xb = (slice(dx, w), slice(0, w - dx)) if dx >= 0 else (slice(0, w + dx), slice(-dx, w))
    m = ma[ya, xa] * mb[yb, xb]
    n = float(m.sum())
    if n < least:
        return np.inf
    d = a[ya, xa] - b[yb, xb]
    np.square(d, out=d)
    np.minimum(d, np.float32(cap * cap), out=d)
    return float(np.vdot(d, m)) / n


def _search(pa: list, pb: list, offset: float, cap: float, reach: int = 2):
    """``(dy, dx)`` in grid pixels that moves ``b`` onto ``a`` (pyramids ``pa``, ``pb`` of
    ``(ln E, mask)``, ``a`` plus ``offset`` against ``b``): the least capped squared
    difference, coarse to fine (``reach`` pixels at the coarsest level, one at each
    finer), refined by a parabola through the finest level's neighbours."""
    dy = dx = 0
    memo: dict = {}
    n = min(len(pa), len(pb))
    for k in range(n - 1, -1, -1):
        (la_, ma_), (lb_, mb_) = pa[k], pb[k]
        r = reach if k == n - 1 else 1
        dy, dx = (2 * dy, 2 * dx) if k < n - 1 else (dy, dx)
        # A shift must keep half the pixels the frames share unshifted (a few pixels'
        # overlap at a far shift could otherwise match by chance).
        least = max(MIN_PIXELS // 16, int(np.count_nonzero(ma_ & mb_)) // 2)
        # Outside the masks ln E is set to 0 (0 * NaN or inf would poison the sums).
        ma_, mb_ = ma_.astype(np.float32), mb_.astype(np.float32)
        la_, lb_ = np.where(ma_ > 0, la_ + np.float32(offset), 0), np.where(mb_ > 0, lb_, 0)

        def cost(y, x, la_=la_, ma_=ma_, lb_=lb_, mb_=mb_, k=k, least=least):
            if (k, y, x) not in memo:
                memo[(k, y, x)] = _cost(la_, ma_, lb_, mb_, y, x, cap, least)
            return memo[(k, y, x)]

        if k:
            costs = {(dy + y, dx + x): cost(dy + y, dx + x) for y in range(-r, r + 1) for x in range(-r, r + 1)}
            best = min(costs, key=costs.get)
            # The coarsest level's far shifts compare other pixels (a short frame's few
            # windows): one is taken only when clearly better than none.
            if k < n - 1 or costs[best] < COARSE_GAIN * costs[(dy, dx)]:
                dy, dx = best
            continue
        for _ in range(3):  # the finest level, the dearest: down the slope on a cross of 5
            c = {(y, x): cost(dy + y, dx + x) for y in (-1, 0, 1) for x in (-1, 0, 1) if abs(y) + abs(x) < 2}
            y, x = min(c, key=c.get)
            if (y, x) == (0, 0):
                break
            dy, dx = dy + y, dx + x

    def sub(cm, c0, cp):
        den = cm - 2 * c0 + cp
        return 0.0 if not np.isfinite(den) or den <= 0 else float(np.clip(0.5 * (cm - cp) / den, -0.5, 0.5))

    return dy + sub(c[(-1, 0)], c[(0, 0)], c[(1, 0)]), dx + sub(c[(0, -1)], c[(0, 0)], c[(0, 1)])


def _shifted(x: np.ndarray, dy: float, dx: float) -> np.ndarray:
    """``x`` moved by ``(dy, dx)`` grid pixels (bilinear; edges repeated): ``out[y, x] =
    x[y - dy, x - dx]``."""
    iy, ix = int(np.floor(dy)), int(np.floor(dx))
    fy, fx = dy - iy, dx - ix
    h, w = x.shape
    m = max(abs(iy), abs(ix)) + 2
    p = np.pad(x, m, mode="edge")

    def at(oy, ox):
        return p[m - oy:m - oy + h, m - ox:m - ox + w]

    return ((1 - fy) * ((1 - fx) * at(iy, ix) + fx * at(iy, ix + 1))
            + fy * ((1 - fx) * at(iy + 1, ix) + fx * at(iy + 1, ix + 1)))


def _explained(la, lb, ok, offset: float, dy, dx, cap) -> float:
    """Share of the residual energy (each residual capped at ``cap``) over the interior
    common pixels that shifting ``b`` by ``(dy, dx)`` grid pixels removes."""
    lbs = _shifted(np.where(ok, lb, 0.0), dy, dx)
    oks = _shifted(ok.astype(np.float32), dy, dx) > 0.999
    m = int(np.ceil(max(abs(dy), abs(dx)))) + 1
    inner = np.zeros_like(ok)
    inner[m:-m or None, m:-m or None] = True
    use = ok & oks & inner
    if int(use.sum()) < MIN_PIXELS:
        return 0.0
    e0 = np.minimum(np.abs(lb - offset - la)[use], cap) ** 2
    e1 = np.minimum(np.abs(lbs - offset - la)[use], cap) ** 2
    return float(1.0 - e1.mean() / max(e0.mean(), 1e-12))


@dataclass
class _Frame:
    """One frame on the grid as every pair it is in uses it: codes, mask, ``ln E``, its
    well-exposed pixels and their 3x3 envelope, on every ``sub``-th pixel of the grid
    (the ghost test), and the pyramid of the whole grid (the shift search)."""

    z: np.ndarray
    valid: np.ndarray
    ln: np.ndarray
    body: np.ndarray
    low: np.ndarray
    high: np.ndarray
    pyramid: list

    @classmethod
    def of(cls, z, valid, t: float, table: np.ndarray, sub: int) -> "_Frame":
        levels = table.shape[0]
        z = z.astype(np.intp)
        valid = np.ones(z.shape, bool) if valid is None else np.asarray(valid, bool)
        ln = table[z] - np.float32(np.log(t))
        body = valid & (z >= BODY[0] * (levels - 1)) & (z <= BODY[1] * (levels - 1))
        pyr = [(ln, body)]
        while min(pyr[-1][0].shape) >= 48 and len(pyr) < 7:
            pyr.append(_half(*pyr[-1]))
        z, valid, ln, body = z[::sub, ::sub], valid[::sub, ::sub], ln[::sub, ::sub], body[::sub, ::sub]
        low, high = _envelope(ln, body)
        return cls(z, valid, ln, body, low, high, pyr)


def compare_pair(a: _Frame, b: _Frame, ta: float, tb: float, table: np.ndarray, stride: int, short: int,
                 long: int) -> Optional[PairAgreement]:
    """:class:`PairAgreement` of frames ``a`` (time ``ta``) and ``b`` (``tb > ta``) through
    ``table``, the channel's ``g``; None when they share fewer than :data:`MIN_PIXELS`
    well-exposed pixels."""
    from hdrcl.core.weights import clip_levels

    levels = table.shape[0]
    c_lo, c_hi = clip_levels(levels)
    both = a.body & b.body
    n = int(np.count_nonzero(both))
    if n < MIN_PIXELS:
        return None
    band = np.minimum((a.z * _BANDS) // levels, _BANDS - 1)
    pick = np.flatnonzero(both)[::max(1, n // 10_000)]  # medians need no more
    med, allow = _banded((b.ln - a.ln).ravel()[pick], band.ravel()[pick])
    bias, t = med[band].astype(np.float32), allow[band].astype(np.float32)  # per pixel, by a's band
    res = PairAgreement(short, long, n)
    cap = 3.0 * float(np.median(allow))
    # Misregistration: the shift that moves b onto a (the pair's median offset removed),
    # and how much of the residual it explains.
    dy = dx = 0.0
    if n >= SHIFT_SHARE * a.z.size:  # a few bright pixels (a short frame's windows) fix no shift
        dy, dx = _search(a.pyramid, b.pyramid, float(np.median(med)), cap)
    res.shift = (float(dy) * stride, float(dx) * stride)
    if res.shift_px >= SHIFT_PX:
        (la, ma), (lb, mb) = a.pyramid[0], b.pyramid[0]
        res.explained = _explained(la, lb, ma & mb, float(np.median(med)), dy, dx, cap)
    # Ghosts: beyond each other's 3x3 envelope (the centre's offset), or beyond a clipped
    # frame's bound. The bounds are taken at the body's ends, not at the clip codes: a
    # camera's shoulder (JPEG highlights) leaves g least certain there.
    ghost = both & ((b.ln > a.high + bias + t) | (b.ln < a.low + bias - t))
    ghost &= (a.ln > b.high - bias + t) | (a.ln < b.low - bias - t)
    top, floor = float(table[int(BODY[1] * (levels - 1))]), float(table[int(np.ceil(BODY[0] * (levels - 1)))])
    near_a, near_b = np.isfinite(a.high), np.isfinite(b.high)  # a well-exposed pixel in the 3x3
    ghost |= b.valid & (b.z >= c_hi) & near_a & (a.high + bias < top - np.log(tb) - t)
    ghost |= a.valid & (a.z >= c_hi) & near_b & (b.high - bias < top - np.log(ta) - t)
    ghost |= a.valid & (a.z <= c_lo) & near_b & (b.low - bias > floor - np.log(ta) + t)
    ghost |= b.valid & (b.z <= c_lo) & near_a & (a.low + bias > floor - np.log(tb) + t)
    ghost = _open3(ghost)
    res.ghost_percent = 100.0 * float(np.count_nonzero(ghost)) / max(int(np.count_nonzero(a.valid & b.valid)), 1)
    return res


def measure_agreement(frames: Sequence[np.ndarray], valid, times, tables: np.ndarray,
                      stride: int = 1) -> Agreement:
    """:class:`Agreement` of grid ``frames`` (codes, ``(h, w[, C])``) with masks ``valid``
    (a list, None entries for all valid), exposure ``times`` and the response's ``tables``
    (``(C, L)``), on a grid of every ``stride``-th row and column."""
    times = np.asarray(times, np.float64)
    valid = list(valid) if valid is not None else [None] * len(frames)
    ch = 1 if tables.shape[0] >= 3 else 0
    table = np.asarray(tables[ch], np.float32)
    order = [int(i) for i in np.argsort(times, kind="stable")]
    out = Agreement(stride=int(stride))
    sub = int(np.ceil(np.sqrt(frames[0].shape[0] * frames[0].shape[1] / WORK_PIXELS)))
    last = (None, None)  # the longer frame of the previous pair: the shorter of the next
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        for a, b in zip(order, order[1:]):
            if not times[b] > times[a]:
                continue
            fa = last[1] if last[0] == a else _Frame.of(_channel(frames[a]), valid[a], float(times[a]), table, sub)
            fb = _Frame.of(_channel(frames[b]), valid[b], float(times[b]), table, sub)
            last = (b, fb)
            pa = compare_pair(fa, fb, float(times[a]), float(times[b]), table, stride, a, b)
            if pa is not None:
                out.pairs.append(pa)
    return out


def _named(paths, i) -> str:
    return os.path.basename(os.fspath(paths[i])) if paths else f"frame {i + 1}"


def findings(agreement: Agreement, paths=None, aligned: bool = False, deghost: bool = False,
             notes: Sequence[str] = ()) -> List[Finding]:
    """The findings of an :class:`Agreement`: at most one for misregistration (the pair
    shifted most) and one for moving subjects (the pair that disagrees most). ``notes``:
    the exposure measurement's lines (a frame they named and a ghost names is said)."""
    out: List[Finding] = []
    n = len(agreement.pairs)
    moved = [p for p in agreement.pairs if p.moved]
    if moved:
        p = max(moved, key=lambda q: q.shift_px)
        odd = _odd_frame(moved, p, paths, notes)
        name, other = _named(paths, odd), _named(paths, p.short if odd == p.long else p.long)
        # p.shift moves the longer frame onto the shorter: the longer lies at minus it.
        sign = -1.0 if odd == p.long else 1.0
        dy, dx = sign * p.shift[0], sign * p.shift[1]
        what = ("they still disagree after --align: check the alignment (--align-model)" if aligned
                else "the camera moved, try --align")
        out.append(Finding(
            "agreement", f"{name}: frames disagree by {p.shift_px:.1f} px: it lies x {dx:+.1f}, y {dy:+.1f} px off "
            f"{other} ({len(moved)} of {n} frame pairs shifted {SHIFT_PX:g} px or more): {what}", CHECK,
            file=name, figure=round(p.shift_px, 2)))
    # A shifted pair's disagreement is the shift's.
    ghosts = [p for p in agreement.pairs if p.ghost_percent >= GHOST_PERCENT and not p.moved]
    if ghosts:
        p = max(ghosts, key=lambda q: q.ghost_percent)
        frame = _odd_frame(ghosts, p, paths, notes)
        name = _named(paths, frame)
        other = _named(paths, p.short if frame == p.long else p.long)
        blamed = any(name in note for note in notes)
        known = blamed or len(ghosts) > 1  # else either frame of the one pair may hold the subject
        tail = ("; the exposure note on it may be this subject, not its exposure" if blamed else "")
        act = "--deghost took them from one frame" if deghost else "try --deghost"
        what = "a moving subject?" if known else f"a moving subject in {name} or {other}?"
        out.append(Finding(
            "agreement", f"{name}: frames disagree on {p.ghost_percent:.1f} % of the picture against {other} "
            f"({len(ghosts)} of {n} frame pairs over {GHOST_PERCENT:g} %: {what}){tail}: {act}",
            NOTE if deghost else CHECK, file=name, figure=round(p.ghost_percent, 2)))
    return out


def _odd_frame(pairs: List[PairAgreement], worst: PairAgreement, paths, notes: Sequence[str]) -> int:
    """The frame of ``worst`` that also disagrees in another of ``pairs`` (the one that
    has the subject, or moved); else the one an exposure note names; else the longer."""
    seen = [i for p in pairs if p is not worst for i in (p.short, p.long)]
    if (worst.short in seen) != (worst.long in seen):
        return worst.short if worst.short in seen else worst.long
    for i in (worst.short, worst.long):
        if paths and any(_named(paths, i) in note for note in notes):
            return i
    return worst.long


def check_job(job) -> None:
    """The check on a merge (:class:`hdrcl.core.runstate.RunState`) once its exposures are
    known: findings through ``job.find``, time as ``job.seconds["agreement"]``. Without a
    sampling grid (a given response, ``--fit-exposures off``) the aligned frames in memory
    are sampled; a streamed set is skipped, with the reason in the log."""
    grid, src = job.grid, job.source
    if len(job.times) < 2:
        return
    from hdrcl.core.sampling import grid_stride

    with job.timed("agreement"):
        held = grid if grid is not None and not getattr(grid, "grid", False) else src  # whole frames
        if grid is not None and getattr(grid, "grid", False):
            frames, valid, stride = grid.frames, grid.valid, grid_stride(job.h, job.w)
        elif hasattr(held, "frames"):
            stride = grid_stride(job.h, job.w)
            frames = [f[::stride, ::stride] for f in held.frames]
            valid = [None if v is None else v[::stride, ::stride] for v in held.valid]
        else:
            logger.info("frames' agreement not checked: no sampling grid (a given response with "
                        "--fit-exposures off)")
            return
        tables = job.response.table_for(frames[0].shape[2] if frames[0].ndim == 3 else 1)
        ag = measure_agreement(frames, valid, job.times, tables, stride)
    for p in ag.pairs:
        logger.debug("agreement %s/%s: shift %.2f px (explains %.0f %%), ghosts %.2f %%",
                     p.short, p.long, p.shift_px, 100 * p.explained, p.ghost_percent)
    o = job.options
    for f in findings(ag, job.inputs.paths, aligned=bool(o.align), deghost=bool(o.deghost), notes=job.notes):
        job.find(f)
