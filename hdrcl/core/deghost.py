"""Ghost removal: pixels where the frames disagree with a static scene.

With a moving subject (leaves, water, people) each frame sees something different at
some pixels, and the weighted average of the paper blends them into semi-transparent
"ghosts". Every frame's own radiance estimate, ``ln E_j = g(Z_j) - ln dt_j``, is
compared with the fused one. On a static scene these residuals are not zero: noise,
and the curve's own error (largest near the shoulder, where g is steep), and on film
departures from reciprocity, give each frame a bias and a spread that depend on its
code value. So the set's own residual distribution is learnt first
(:func:`learn`: per frame, channel and code bin, the median residual and its robust
spread over a subsample of the image), and a pixel is a ghost only where a frame
departs from that distribution by more than ``threshold`` robust standard deviations
and by more than :data:`FLOOR` (ln units). The bin is the code the frame *should* read
given the fused radiance, not the code it reads: a moving object then falls among the
static pixels of the same radiance, where it is a minority, and cannot teach the model
that its own departure is normal. Ghost pixels take the reference frame's own
estimate (the middle exposure by default); where the reference itself is out of its
working range at a ghost pixel (per channel), the nearest exposure on the side that
measures it (longer for dark, shorter for bright) stands in, its estimate corrected by
the set's learnt bias for the code it reads; where none does, the fused value is kept,
clamped into what the reference's code proves, and the pixel-channel is counted as
unresolved. The grown rings blend the two values (:func:`feather`), so the mask's edge
leaves no step.

A departure counts only outside the fused radiance's 3x3 envelope (edges that a
one-pixel misregistration or blur smears are not motion), the raw mask is opened
(lone pixels go) and then dilated by :data:`GROW` pixels so the edges of a moving
object go too.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence, Union

import numpy as np

#: Default ghost threshold, in robust standard deviations of the set's own residuals
#: (``--ghost-threshold``). Measured: 0.45 % ghost pixels on the static Memorial set
#: (6 gives 3 %, the old detector 99.86 %), 0.00 % on the ``hdrcl demo`` set, and the
#: synthetic moving objects of tests/test_trust.py fully caught.
THRESHOLD = 8.0
#: Smallest ln-radiance departure that counts as a ghost (0.25 ~ 1/3 stop).
FLOOR = 0.25
#: Smallest robust spread (ln units) a bin is credited with.
MIN_SPREAD = 0.02
GROW = 2
#: Codes within this fraction of either end are too near clipping to judge.
MARGIN = 0.04
#: Code bins (of the predicted code) per frame and channel of the learnt distribution.
BINS = 16
#: Pixels the distribution is learnt from (a regular subsample of the image).
LEARN_PIXELS = 250_000
#: A bin with fewer samples than this falls back to all frames' pooled distribution.
MIN_BIN = 64


@dataclass
class GhostResult:
    mask: np.ndarray  # (H, W) bool, pixels taken from the reference
    fraction: float
    unresolved: int  # ghost pixels where the reference itself is clipped


@dataclass
class GhostModel:
    """The set's own frame-to-frame residuals on a static scene.

    ``bias`` and ``spread`` have shape ``(P, C, BINS)``: per frame (exposure order),
    channel and code bin, the median of ``ln E_j - ln E_fused`` and 1.4826 times its
    median absolute deviation. ``threshold`` is in spreads.
    """

    bias: np.ndarray
    spread: np.ndarray
    threshold: float = THRESHOLD
    #: ``(P, C, BINS)``: the median residual per bin of the code *read* (None: zeros).
    #: What a frame's estimate is corrected by where it stands in for the fused value
    #: (:func:`replace`): binned by the predicted code, as ``bias`` is, the bins near
    #: the floor would hold only the readings the noise lifted above it.
    read_bias: Optional[np.ndarray] = None


def reference_index(times: Sequence[float], choice: Union[None, str, int] = None) -> int:
    """Index (in exposure order) of the reference frame.

    ``choice``: ``None``/``"middle"`` (default), ``"shortest"``, ``"longest"``, or an
    int: that frame of the input (0-based, in the order given).
    """
    from hdrcl.errors import UsageError

    times = np.asarray(times, np.float64)
    order = np.argsort(times, kind="stable")
    if choice is None or choice == "middle":
        return len(order) // 2
    if choice == "shortest":
        return 0
    if choice == "longest":
        return len(order) - 1
    try:
        k = int(choice)
    except (TypeError, ValueError):
        raise UsageError(f"--ghost-reference: '{choice}' is not middle, shortest, longest or a frame number") from None
    if not 0 <= k < len(order):
        raise UsageError(f"--ghost-reference: frame {k} does not exist (0..{len(order) - 1})")
    return int(np.flatnonzero(order == k)[0])


def _estimates(frames, log_times, tables, valid, j):
    levels = tables.shape[1]
    lo, hi = MARGIN * (levels - 1), (1 - MARGIN) * (levels - 1)
    z = frames[j]
    # one table per channel, indexed by the codes as they are (no int64 copy of the frame)
    ln_e = np.empty(z.shape, np.float64)
    for ch in range(tables.shape[0]):
        ln_e[..., ch] = tables[ch][z[..., ch]]
    ln_e -= log_times[j]
    ok = (z >= lo) & (z <= hi)
    if valid is not None and valid[j] is not None:
        ok &= valid[j][..., None]
    return z, ln_e, ok


def _bins(z, levels):
    return np.minimum(z.astype(np.int64) * BINS // levels, BINS - 1)


def _predicted_bins(ln_f, log_time, mono):
    """Code bin each pixel *should* read in a frame of ``log_time`` given the fused
    radiance ``ln_f`` (H, W, C): ``g^-1(ln E + ln dt)`` on the non-decreasing curves
    ``mono`` (C, L). Binning residuals by it, not by the code read, puts a moving
    object's pixels among the static pixels of the same radiance, where they are few."""
    levels = mono.shape[1]
    out = np.empty(ln_f.shape, np.int64)
    for ch in range(mono.shape[0]):
        out[..., ch] = np.searchsorted(mono[ch], ln_f[..., ch] + log_time)
    return _bins(np.clip(out, 0, levels - 1), levels)


def _predicted_bins_at(ln_f, log_time, mono, ch):
    """:func:`_predicted_bins` of samples ``ln_f`` (1-D) of channels ``ch``: the bin is
    the number of bin starts whose code the curve reaches below ``ln_f + log_time``
    (bin q starts at code ceil(q L / BINS); the code read is at or past it exactly when
    the curve one code below it is under the value), 15 comparisons instead of a search
    of L codes."""
    levels = mono.shape[1]
    starts = -(-np.arange(1, BINS) * levels // BINS)  # ceil(q L / BINS)
    edges = mono[:, starts - 1]  # (C, BINS - 1)
    x = ln_f + log_time
    out = np.zeros(x.shape, np.int64)
    for c in range(mono.shape[0]):
        sel = ch == c
        if sel.any():
            out[sel] = np.searchsorted(edges[c], x[sel], side="left")
    return out


def learn(frames: Sequence[np.ndarray], log_times: Sequence[float], tables: np.ndarray, weights: np.ndarray,
          valid: Optional[Sequence[Optional[np.ndarray]]] = None, threshold: Optional[float] = None) -> GhostModel:
    """Learn a set's residual distribution (frames in exposure order, as fused).

    A regular subsample of at most :data:`LEARN_PIXELS` pixels is fused with the
    NumPy twin; each frame's residual ``ln E_j - ln E_fused`` over the pixels it
    measures is summarised per channel and code bin by its median and robust spread
    (moving objects are a minority of pixels and barely move either).
    """
    from hdrcl.core import reference

    threshold = THRESHOLD if threshold is None else float(threshold)
    if not (threshold > 0 and np.isfinite(threshold)):
        from hdrcl.errors import UsageError

        raise UsageError(f"--ghost-threshold must be a positive number, not {threshold:g}")
    h, w = frames[0].shape[:2]
    k = max(1, int(np.ceil(np.sqrt(h * w / LEARN_PIXELS))))
    sub = [np.ascontiguousarray(f[::k, ::k]) for f in frames]
    vsub = None if valid is None else [None if v is None else v[::k, ::k] for v in valid]
    log_t = np.asarray(log_times, np.float64)
    fused, _ = reference.fuse(sub, log_t, tables, weights, vsub)
    p, c = len(frames), tables.shape[0]
    rs = [[] for _ in range(c)]
    bs = [[] for _ in range(c)]
    zs = [[] for _ in range(c)]
    with np.errstate(divide="ignore"):
        ln_f = np.log(np.where(fused > 0, fused, np.nan))
    mono = reference.monotone_tables(tables)
    ln_f0 = np.where(np.isfinite(ln_f), ln_f, -1e30)
    for j in range(p):
        z, ln_e, ok = _estimates(sub, log_t, tables, vsub, j)
        r = ln_e - ln_f
        ok &= np.isfinite(r)
        b = _predicted_bins(ln_f0, log_t[j], mono)
        zb = _bins(z, tables.shape[1])
        for ch in range(c):
            rs[ch].append(r[..., ch][ok[..., ch]])
            bs[ch].append(b[..., ch][ok[..., ch]])
            zs[ch].append(zb[..., ch][ok[..., ch]])
    pooled = [_bin_stats(np.concatenate(rs[ch]), np.concatenate(bs[ch]), None) for ch in range(c)]
    bias = np.empty((p, c, BINS))
    spread = np.empty((p, c, BINS))
    for ch in range(c):
        for j in range(p):
            bias[j, ch], spread[j, ch] = _bin_stats(rs[ch][j], bs[ch][j], pooled[ch])
    spread = np.maximum(spread, MIN_SPREAD)
    read_bias = np.zeros((p, c, BINS))
    for ch in range(c):
        pooled_read = _bin_stats(np.concatenate(rs[ch]), np.concatenate(zs[ch]), None)
        for j in range(p):
            read_bias[j, ch] = _bin_stats(rs[ch][j], zs[ch][j], pooled_read)[0]
    read_bias = np.where(np.isfinite(read_bias), read_bias, 0.0)
    return GhostModel(bias=bias, spread=spread, threshold=threshold, read_bias=read_bias)


def _bin_stats(r, b, fallback):
    """Median and robust spread of residuals ``r`` per code bin ``b``; bins with fewer
    than :data:`MIN_BIN` samples take ``fallback`` (or the overall figures)."""
    if fallback is None:
        if r.size >= MIN_BIN:
            m0 = float(np.median(r))
            fallback = (np.full(BINS, m0), np.full(BINS, 1.4826 * float(np.median(np.abs(r - m0)))))
        else:
            fallback = (np.zeros(BINS), np.full(BINS, np.inf))
    bias, spread = fallback[0].copy(), fallback[1].copy()
    order = np.argsort(b, kind="stable")
    r, b = r[order], b[order]
    edges = np.searchsorted(b, np.arange(BINS + 1))
    for q in range(BINS):
        part = r[edges[q]:edges[q + 1]]
        if part.size >= MIN_BIN:
            m = float(np.median(part))
            bias[q] = m
            spread[q] = 1.4826 * float(np.median(np.abs(part - m)))
    return bias, spread


#: Rows of context a strip needs on each side for :func:`find` to give exactly the
#: whole image's weights: 1 (envelope) + 2 (opening) + GROW (dilation) + GROW (the
#: feathered edge: :func:`feather`).
CONTEXT = 3 + 2 * GROW


def _stack(parts):
    parts = [p for p in parts if p is not None]
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def ghost_tables(log_times, tables: np.ndarray, model: GhostModel) -> dict:
    """The tables :func:`departures` reads, as the kernel takes them (float32): ``tab``
    (C, L) g, ``lt`` (P,) ln dt, ``edges`` (C, BINS - 1) the running maximum of g one code
    below each bin's first code, ``bias`` and ``tol`` (P, C, BINS; ``tol`` =
    max(threshold x spread, FLOOR)), ``screen`` (P, C, 2) the least and largest bias over
    the bins, ``floor`` (FLOOR) and the working range ``zlo``..``zhi`` (codes)."""
    from hdrcl.core import reference

    levels = tables.shape[1]
    starts = -(-np.arange(1, BINS) * levels // BINS)
    f32 = lambda a: np.ascontiguousarray(a, np.float32)  # noqa: E731
    return {"tab": f32(tables), "lt": f32(log_times), "edges": f32(reference.monotone_tables(tables)[:, starts - 1]),
            "bias": f32(model.bias), "tol": f32(np.maximum(model.threshold * model.spread, FLOOR)),
            "screen": f32(np.stack([model.bias.min(axis=2), model.bias.max(axis=2)], axis=-1)), "floor": FLOOR,
            "zlo": int(np.ceil(MARGIN * (levels - 1))), "zhi": int(np.floor((1 - MARGIN) * (levels - 1)))}


def departures(frames, log_times, tables, valid, fused, model: GhostModel) -> np.ndarray:
    """Raw ghost mask ``(H, W)`` bool (kernel: ``ghost_raw`` in ``kernels/fusion.cl``).

    Pixel i is marked when, for some frame j and channel c with ``fused > 0`` and a
    code ``z`` in the working range (valid, ``MARGIN`` from either end)::

        x = g_c(z) - ln dt_j - bias[j, c, b],   b = the bin of the code predicted
            from ln F (the fused value), :func:`_predicted_bins`
        x > max_3x3(ln F) + tol[j, c, b]  or  x < min_3x3(ln F) - tol[j, c, b]

    with ``tol = max(threshold x spread, FLOOR)`` and the envelope over the 3x3
    neighbourhood (edges repeated).
    """
    from scipy import ndimage

    from hdrcl.core import reference

    with np.errstate(divide="ignore"):
        ln_f = np.log(np.maximum(fused, 1e-30))
    hi = ndimage.maximum_filter(ln_f, size=(3, 3, 1), mode="nearest")
    lo = ndimage.minimum_filter(ln_f, size=(3, 3, 1), mode="nearest")
    raw = np.zeros(fused.shape[:2], bool)
    mono = reference.monotone_tables(tables)
    live = fused > 0
    for j in range(len(frames)):
        z, ln_e, ok = _estimates(frames, log_times, tables, valid, j)
        # Screen: a sample can depart only if it does by FLOOR with its bin's bias at the
        # most favourable; the bins and spreads are then looked up for those alone (the
        # same test as on every sample, at a fraction of the cost).
        bmin, bmax = model.bias[j].min(axis=1), model.bias[j].max(axis=1)
        cand = ok & live & ((ln_e - bmin > hi + FLOOR) | (ln_e - bmax < lo - FLOOR))
        idx = np.nonzero(cand)
        if not idx[0].size:
            continue
        ch = idx[2]
        b = _predicted_bins_at(ln_f[idx], log_times[j], mono, ch)
        x = ln_e[idx] - model.bias[j, ch, b]
        tol = np.maximum(model.threshold * model.spread[j, ch, b], FLOOR)
        hit = (x > hi[idx] + tol) | (x < lo[idx] - tol)
        raw[idx[0][hit], idx[1][hit]] = True
    return raw


def find(frames: Sequence[np.ndarray], log_times: Sequence[float], tables: np.ndarray,
         valid: Optional[Sequence[Optional[np.ndarray]]], fused: np.ndarray, model: GhostModel,
         above=None, below=None, processor=None) -> np.ndarray:
    """Ghost weights ``(H, W)`` float32 in [0, 1] of a strip or image (frames in exposure
    order): the mask is where they are above 0 (:func:`feather`).

    A frame that measures a pixel within its working range marks it when its estimate,
    less the learnt bias of its bin, lies outside the fused radiance's 3x3 envelope
    (min..max: a one-pixel misregistration or blur at an edge is not motion) by more
    than ``model.threshold`` learnt spreads and by more than :data:`FLOOR`. The raw mask
    is opened (3x3: lone pixels and one-pixel lines go) and dilated by :data:`GROW`.

    ``above`` and ``below`` are ``(frames, valid, fused)`` of up to :data:`CONTEXT`
    neighbouring rows from the strips before and after (unreplaced fused values), so a
    strip's mask equals the whole image's. ``processor``, an OpenCL fusion processor,
    finds the departures with its kernel (``ghost_raw`` of ``kernels/fusion.cl``),
    otherwise :func:`departures`, its twin, does.
    """
    from scipy import ndimage

    top = 0 if above is None else above[2].shape[0]
    rows = fused.shape[0]
    p = len(frames)
    fr = [_stack([None if above is None else above[0][j], frames[j], None if below is None else below[0][j]])
          for j in range(p)]
    vv = None
    if valid is not None and any(v is not None for v in valid):
        def part(ctx, j):
            if ctx is None:
                return None
            v = ctx[1][j] if ctx[1] is not None else None
            return np.ones(ctx[2].shape[:2], bool) if v is None else v
        vv = [_stack([part(above, j), np.ones(fused.shape[:2], bool) if valid[j] is None else valid[j],
                      part(below, j)]) for j in range(p)]
    fu = _stack([None if above is None else above[2], fused, None if below is None else below[2]])
    if processor is not None:
        raw = processor.ghost_departures(fr, vv, fu, ghost_tables(log_times, tables, model))
    else:
        raw = departures(fr, log_times, tables, vv, fu, model)
    rows_hit, cols_hit = np.flatnonzero(raw.any(axis=1)), np.flatnonzero(raw.any(axis=0))
    out = np.zeros(raw.shape, np.float32)
    if not rows_hit.size:
        return out[top:top + rows]
    # The morphology in the departures' bounding box with a margin the mask cannot reach
    # (the same result as on the whole strip; ghosts are usually a small part of it).
    m = GROW + 3
    win = (slice(max(rows_hit[0] - m, 0), rows_hit[-1] + m + 1), slice(max(cols_hit[0] - m, 0), cols_hit[-1] + m + 1))
    mask = ndimage.binary_opening(raw[win], structure=np.ones((3, 3), bool))
    if GROW:
        mask = ndimage.binary_dilation(mask, iterations=GROW)
    out[win] = feather(mask)
    return out[top:top + rows]


def feather(mask: np.ndarray) -> np.ndarray:
    """Weight of the deghosted value per pixel of a grown mask: 1 inside, falling
    linearly over its outer :data:`GROW` rings (1/(GROW+1) on the outermost, 0 outside).

    A hard switch from the fused value to one frame's leaves a step wherever the two
    differ a little (curve error, noise); over the grown rings, which hold static
    pixels next to the moving object, the two are blended instead."""
    from scipy import ndimage

    out = mask.astype(np.float32)
    inner = mask
    for _ in range(GROW):
        inner = ndimage.binary_erosion(inner, border_value=1)
        out += inner
    return out / np.float32(GROW + 1)


def _corrected(frames, log_times, tables, valid, j, model):
    """Frame ``j``'s estimate less the learnt bias of the bin of the code it reads, so it
    agrees with the fused map on a static scene (a curve wrong in the toe or shoulder
    otherwise makes one frame's estimate darker or brighter than the fused one)."""
    z, ln_e, ok = _estimates(frames, log_times, tables, valid, j)
    if model is not None and model.read_bias is not None:
        chan = np.arange(tables.shape[0])
        ln_e = ln_e - model.read_bias[j, chan, _bins(z, tables.shape[1])]
    return z, ln_e, ok


def replace(radiance: np.ndarray, frames, log_times, tables, ghost: np.ndarray, valid, ref: int,
            model: Optional[GhostModel] = None) -> int:
    """Give ghost pixels the reference exposure's own estimate (in place).

    ``ghost`` holds :func:`find`'s weights (or a bool mask): ``ln E = a ln E_ref + (1 - a)
    ln E_fused``. The estimate is corrected by ``model``'s learnt bias for the code read (``read_bias``).
    Where the reference is out of its working range the nearest exposure that measures
    the pixel stands in (longer for dark, shorter for bright); where none does, the
    fused value is kept but clamped into the interval the reference's code proves
    (its reading of code z says ``g(z-1) <= ln E + ln dt <= g(z+1)``): an under-exposed
    reading is no measurement, yet it does say the moving object is not there.

    Returns the number of ghost pixel-channels no single frame could serve.
    """
    alpha = np.asarray(ghost, np.float32)
    ys, xs = np.nonzero(alpha > 0)
    if not ys.size:
        return 0
    # Only the ghost pixels are gathered, worked on and put back: the cost follows the
    # mask, not the image.
    fr = [f[ys, xs] for f in frames]
    vv = None if valid is None else [None if v is None else v[ys, xs] for v in valid]
    px = radiance[ys, xs].astype(np.float64)
    levels = tables.shape[1]
    nch = radiance.shape[-1]
    with np.errstate(divide="ignore"):
        ln_fused = np.log(np.where(px > 0, px, np.nan))
    rz, r_ln, r_ok = _corrected(fr, log_times, tables, vv, ref, model)
    target = np.where(r_ok, r_ln, np.nan)
    todo = ~r_ok
    dark = rz < levels // 2
    for step, side in ((1, dark), (-1, ~dark)):  # longer exposures for dark, shorter for bright
        j = ref + step
        while 0 <= j < len(fr) and (todo & side).any():
            _, ln_e, ok = _corrected(fr, log_times, tables, vv, j, model)
            use = todo & side & ok
            target[use] = ln_e[use]
            todo &= ~use
            j += step
    if todo.any():
        mono = np.maximum.accumulate(tables, axis=1)
        chan = np.arange(nch)
        rzi = rz.astype(np.int64)
        lo = mono[chan, np.maximum(rzi - 1, 0)] - log_times[ref]
        hi = mono[chan, np.minimum(rzi + 1, levels - 1)] - log_times[ref]
        if model is not None and model.read_bias is not None:
            b = model.read_bias[ref, chan, _bins(rz, levels)]
            lo, hi = lo - b, hi - b
        lo = np.where(rzi > 0, lo, -np.inf)
        hi = np.where(rzi < levels - 1, hi, np.inf)
        target[todo] = np.clip(ln_fused[todo], lo[todo], hi[todo])
    have = np.isfinite(target) & np.isfinite(ln_fused)
    a = np.broadcast_to(alpha[ys, xs][:, None], px.shape)
    px[have] = np.exp(a[have] * target[have] + (1 - a[have]) * ln_fused[have])
    radiance[ys, xs] = px
    return int(np.count_nonzero(todo))
