"""Exposures measured from the pixels with a known response curve.

With the curve fixed (``--response``, a batch's pooled response) there is no exponential
ambiguity: ``g(Z_k) - g(Z_j)`` over the pixels two frames both hold in the curve's body
is ``ln(dt_k / dt_j)``. Every pair of frames with enough such pixels gives one robust
ratio; a weighted least-squares solve over all pairs gives every frame's ``ln dt`` up to
one constant, which the metadata fixes (the frames whose metadata agree with the pixels,
as in :mod:`hdrcl.core.exposure.fit`). The metadata is kept where it agrees and replaced
where the pixels contradict it (:func:`estimate_exposures`): frames labelled a stop apart
that are identical, or a frame off by a stop, are corrected; EXIF rounding (1/60 written
for 1/64 s) is left alone.

Without a known curve the pixels tell the exposures only up to ``a + b ln dt``;
:func:`hdrcl.core.exposure.verdict.untrusted_metadata` says when a calibrating set's metadata cannot be trusted, so
a caller can prefer a response from a good set of the same camera.
"""
from __future__ import annotations

import functools
import logging
import os
from dataclasses import dataclass, field
from typing import List, Optional, Sequence

import numpy as np

from hdrcl.core.exposure.fit import (
    EXPOSURE_TOLERANCE_STOPS,
    SAME_STOPS,
    TRUST_STOPS,
    ExposureFit,
)
from hdrcl.core.response import SPAN_BODY, Response
from hdrcl.core.exposure.verdict import list_names as _list_names
from hdrcl.core.weights import weight_values
from hdrcl.errors import UsageError

logger = logging.getLogger(__name__)

#: A pair of frames is measured only when it shares at least this many pixel-channel
#: samples in the curve's body (:data:`hdrcl.core.response.SPAN_BODY`), both valid.
MIN_OVERLAP = 200
#: At most this many pixels of each frame are used (a fixed pseudo-random subset): the
#: ratios are medians, so more pixels add nothing but time.
MAX_PIXELS = 100_000
#: Spread (ln units) assumed at least for one pair's differences: identical frames have
#: none, and a curve from another set is never exact.
_SPREAD_FLOOR = 0.01
#: Slopes of the line between measured and nominal ``ln dt`` that the frames whose
#: metadata is right may lie on (:func:`_agreeing_line`): a curve that does not quite fit
#: (another picture style, a scene-adaptive tone curve) measures every exposure ratio
#: raised to one power. Kept frames then need no change: fusion's weighting follows the
#: radiance, so a map merged with their metadata is nearly right, and with pixel-measured
#: exposures it would carry the curve's error as a contrast change. Beyond these bounds
#: the metadata's spacing, not the curve, is taken to be wrong.
STRETCH = (0.75, 1.0 / 0.75)
#: Huber threshold (in standard errors) that down-weights pairs inconsistent with the rest.
_HUBER = 2.5

_LN2 = float(np.log(2.0))


@dataclass
class KnownCurveFit:
    """Per-frame exposures measured with a known response.

    Attributes
    ----------
    nominal : ndarray
        Seconds: the metadata.
    fitted : ndarray
        Seconds: the pixels' measurement, on the scale the metadata fixes (the nominal
        value for a frame that could not be measured).
    used : ndarray
        Seconds a merge should use: ``fitted`` where ``flagged``, else ``nominal``.
    stops : ndarray
        ``log2(fitted / nominal)`` (0 where not measured).
    flagged : ndarray of bool
        Frames whose metadata the pixels contradict by more than ``tolerance`` stops:
        exactly those whose exposure is changed.
    measured : ndarray of bool
        Frames whose exposure the pixels tell (enough well-exposed pixels shared with
        the other measured frames).
    trusted : ndarray of bool
        Frames whose metadata agree with the pixels within
        :data:`hdrcl.core.exposure.fit.TRUST_STOPS` (on one offset, or one line of slope
        ``stretch``); they fix the scale and keep their metadata. All False when no
        unique group of three or more was found (the scale is then the median frame's).
    pixels : ndarray of int
        Pixel-channel samples of each frame in the curve's body (codes 25..230).
    same : list of (int, int)
        Pairs of frames with different metadata that the pixels put at one exposure.
    tolerance : float
        Stops.
    stretch : float
        Slope of the line between measured and nominal ``ln dt`` on the trusted frames
        (1 when the curve fits them, or without trusted frames); ``fitted`` is on the
        metadata's scale and spacing: ``(ln dt_measured - a) / stretch``.
    notes : list of str
        Human-readable, naming the files: every change, every pair at one exposure,
        every frame that could not be measured. Empty when the metadata is right.
    scale_note : str
        How the scale was fixed.
    """

    nominal: np.ndarray
    fitted: np.ndarray
    used: np.ndarray
    stops: np.ndarray
    flagged: np.ndarray
    measured: np.ndarray
    trusted: np.ndarray
    pixels: np.ndarray
    same: list = field(default_factory=list)
    tolerance: float = EXPOSURE_TOLERANCE_STOPS
    stretch: float = 1.0
    notes: List[str] = field(default_factory=list)
    scale_note: str = ""


def _masks(valid, p: int, shape) -> list:
    """One (H, W) bool mask or None per frame from None, one shared mask, or a list."""
    if valid is None:
        return [None] * p
    if isinstance(valid, np.ndarray) and valid.ndim == 2:
        valid = [valid] * p
    valid = list(valid)
    if len(valid) != p:
        raise UsageError(f"valid: {len(valid)} masks for {p} frames")
    out = []
    for v in valid:
        if v is not None:
            v = np.asarray(v, bool)
            if v.shape != shape:
                raise UsageError(f"valid: a mask of shape {v.shape} for frames of {shape[0]}x{shape[1]} pixels")
        out.append(v)
    return out


def _location(d: np.ndarray, w: np.ndarray):
    """Median of ``d`` and its variance.

    The median, not a mean: through the curve's non-linear ends the differences of noisy
    codes are skewed, and a mean follows the skew (on a ladder two stops apart with
    3 codes of noise, a trimmed mean stretched the exposures 1.5 times as much). The
    variance is ``(pi / 2) s^2 / sum(w)`` with ``s`` the MAD spread (at least
    :data:`_SPREAD_FLOOR`) and ``w`` the samples' weights (1 at mid-grey): a pair that
    shares only samples near the ends of the body counts as fewer samples.
    """
    m = float(np.median(d, overwrite_input=True))  # ``d`` is the caller's temporary: reordered, not copied
    s = max(1.4826 * float(np.median(np.abs(d - m), overwrite_input=True)), _SPREAD_FLOOR)
    return m, 0.5 * np.pi * s * s / max(float(w.sum()), 1.0)


def _components(p: int, edges) -> list:
    """Connected components (lists of frame indices) of the pair graph."""
    parent = list(range(p))

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for j, k in edges:
        parent[root(j)] = root(k)
    groups = {}
    for i in range(p):
        groups.setdefault(root(i), []).append(i)
    return list(groups.values())


def _solve_pairs(members: list, pairs: list) -> np.ndarray:
    """``ln dt`` of ``members`` (mean 0) from pair ratios ``(j, k, d, var)`` by weighted
    least squares, pairs inconsistent with the rest down-weighted (Huber, a few rounds)."""
    col = {f: i for i, f in enumerate(members)}
    m = len(members)
    a = np.zeros((len(pairs) + 1, m))
    b = np.zeros(len(pairs) + 1)
    sd = np.zeros(len(pairs))
    for r, (j, k, d, var) in enumerate(pairs):
        a[r, col[k]], a[r, col[j]], b[r] = 1.0, -1.0, d
        sd[r] = np.sqrt(var)
    a[-1, :] = 1.0  # gauge: mean 0 (the scale comes from the metadata)
    robust = np.ones(len(pairs))
    x = np.zeros(m)
    for _ in range(4):
        w = np.append(np.sqrt(robust) / sd, 1.0)
        x = np.linalg.lstsq(a * w[:, None], b * w, rcond=None)[0]
        z = np.abs(a[:-1] @ x - b[:-1]) / sd
        new = np.where(z > _HUBER, _HUBER / np.maximum(z, 1e-12), 1.0)
        if np.allclose(new, robust):
            break
        robust = new
    return x


def _line_sets(lt_nom: np.ndarray, lt_meas: np.ndarray, trust: float, tilt: bool) -> dict:
    """Sets of frames on one line ``lt_meas = a + b lt_nom`` (within ``trust``, ln units
    on the metadata's scale): ``{inlier indices: (sse, a, b)}``. ``tilt`` False: slope
    1, one line per frame's offset; True: a line through every pair of frames with
    different metadata, slope within :data:`STRETCH`. Each is refined on its inliers
    (median offset, or least squares with ``tilt``)."""
    p = lt_nom.size
    lo, hi = STRETCH
    spread = 0.3 * _LN2

    def inliers(a, b):
        return np.abs((lt_meas - a) / b - lt_nom) <= trust

    cands = []
    if not tilt:
        cands = [(float(lt_meas[i] - lt_nom[i]), 1.0) for i in range(p)]
    else:
        for i in range(p):
            for j in range(i + 1, p):
                dn = lt_nom[j] - lt_nom[i]
                if abs(dn) >= spread:
                    b = (lt_meas[j] - lt_meas[i]) / dn
                    if lo <= b <= hi:
                        cands.append((float(lt_meas[i] - b * lt_nom[i]), float(b)))
    sets = {}
    for a, b in cands:
        inl = inliers(a, b)
        ok = True
        for _ in range(5):  # refine on the inliers
            if tilt:
                if np.ptp(lt_nom[inl]) < spread:
                    ok = False
                    break
                b2, a2 = np.polyfit(lt_nom[inl], lt_meas[inl], 1)
                if not lo <= b2 <= hi:
                    ok = False
                    break
                a, b = float(a2), float(b2)
            else:
                a = float(np.median(lt_meas[inl] - lt_nom[inl]))
            new = inliers(a, b)
            if (new == inl).all():
                break
            inl = new
        if not ok or not inl.any():
            continue
        key = tuple(np.flatnonzero(inl))
        sse = float(np.sum(((lt_meas[inl] - a) / b - lt_nom[inl]) ** 2))
        if key not in sets or sse < sets[key][0]:
            sets[key] = (sse, a, b)
    return sets


def _agreeing_line(lt_nom: np.ndarray, lt_meas: np.ndarray, trust: float):
    """The frames whose metadata agree with the pixels: ``(inliers, a, b)`` with
    ``lt_meas ~ a + b lt_nom`` on them, or ``(None, 0, 1)``.

    With the curve right, the frames whose metadata is right agree on one offset
    (slope 1). A curve that does not quite fit the frames (another picture style, a
    scene-adaptive tone curve) measures every ratio raised to one power: the frames then
    lie on a line of another slope (within :data:`STRETCH`). The largest set of at least
    three frames on one slope-1 line is taken, unless a tilted line holds more; either
    must be unique (a tie between different sets means no consensus).
    """
    found = None
    for tilt in (False, True):
        sets = _line_sets(lt_nom, lt_meas, trust, tilt)
        if not sets:
            continue
        best = max(len(k) for k in sets)
        if found is not None and best <= found[0]:
            continue
        top = [k for k in sets if len(k) == best]
        found = (best, top[0] if len(top) == 1 and best >= 3 else None, sets[top[0]])
    if found is None or found[1] is None:
        return None, 0.0, 1.0
    _, key, (_, a, b) = found
    out = np.zeros(lt_nom.size, bool)
    out[list(key)] = True
    return out, a, b


def estimate_exposures(
    frames: Sequence[np.ndarray],
    times: Sequence[float],
    response: Response,
    *,
    valid=None,
    weight: str = "gaussian",
    tolerance_stops: Optional[float] = None,
    names: Optional[Sequence[str]] = None,
    labels: Optional[Sequence[str]] = None,
) -> KnownCurveFit:
    """Measure each frame's exposure with a known response; correct contradicted metadata.

    1. Every code of every frame is mapped through the response: ``x = g(Z)``. Pixel
       channels in the curve's body (codes 25..230 in 8-bit units; near black and near
       clipping codes barely change with exposure), and valid, are usable.
    2. For every pair of frames sharing at least :data:`MIN_OVERLAP` usable samples,
       ``ln(dt_k / dt_j)`` is the median of ``x_k - x_j``; its precision counts the
       samples by their weights ``w(Z_j) w(Z_k)`` (:func:`_location`).
    3. A weighted least-squares solve over all pairs (Huber-reweighted) gives each
       frame's ``ln dt`` up to one constant. Frames outside the largest connected set
       of pairs are not measured and keep their metadata.
    4. The constant comes from the metadata: the offset of the largest unique group of
       at least three frames whose metadata agree with the pixels within
       :data:`hdrcl.core.exposure.fit.TRUST_STOPS` (the *trusted* frames,
       :func:`_agreeing_line`), else the offset of the median measured frame (the lower
       of the two middle ones for an even count, so that the scale is one frame's own
       metadata). When the trusted frames are evenly spaced wider or narrower than their
       metadata (a curve that does not quite fit: ``stretch`` within :data:`STRETCH`),
       their metadata is kept, a note says so, and the other frames' measurements are
       put on the same spacing.
    5. A frame whose metadata is off by more than ``tolerance_stops`` is corrected to
       the measurement; the others keep their metadata exactly.

    Fast enough to run on every set: 9 frames of 200,000 RGB pixels take about 0.7 s
    (at most :data:`MAX_PIXELS` pixels per frame are used).

    Parameters
    ----------
    frames : sequence of ndarray
        ``(H, W, C)`` or ``(H, W)`` uint8/uint16 codes, all one shape (in practice the
        set's decimated sampling grid).
    times : sequence of float
        Nominal exposure times (seconds, from the metadata), any order.
    response : hdrcl.core.response.Response
        The known curve; its depth must match the frames'.
    valid : ndarray or sequence of (ndarray or None), optional
        ``(H, W)`` bool masks of usable pixels, one per frame or one for all.
    weight : {"gaussian", "hat"}
        Weights of the samples when a pair's precision is counted (a pair sharing only
        samples near the ends of the curve's body counts less in the solve).
    tolerance_stops : float, optional
        Metadata off by more than this is corrected (default
        :data:`hdrcl.core.exposure.fit.EXPOSURE_TOLERANCE_STOPS`, 0.5).
    names : sequence of str, optional
        File names for the notes (default ``image 0``, ``image 1``, ...).
    labels : sequence of str, optional
        Per frame, the capture's settings as recorded, for the notes, where ``times`` are
        equivalent exposures on another reference (a batch's shoot-wide f-number and
        ISO); default the nominal times.

    Returns
    -------
    KnownCurveFit
    """
    nominal, tol, names = _checked_times(times, len(frames), tolerance_stops, names)
    p = nominal.size
    lt_nom = np.log(nominal)
    none = np.zeros(p, bool)
    if p < 2:  # nothing to compare a frame with
        return KnownCurveFit(nominal, nominal.copy(), nominal.copy(), np.zeros(p), none, none, none,
                             np.zeros(p, np.int64), tolerance=tol, scale_note=f"{p} frame(s): the metadata is kept")
    xs, ws, oks, pixels = _usable_samples(_checked_frames(frames, response), response, weight, valid)
    measured, lt_meas = _measure(xs, ws, oks, pixels, lt_nom)
    trusted, a, b, scale_note = _pin_scale(lt_nom, lt_meas, measured, names)
    # On the metadata's scale (and spacing, where the trusted frames set one).
    lt_fit = np.where(measured, (lt_meas - a) / b, lt_nom)
    stops = (lt_fit - lt_nom) / _LN2
    flagged = measured & ~trusted & (np.abs(stops) > tol)
    fit = KnownCurveFit(nominal=nominal, fitted=np.where(measured, np.exp(lt_fit), nominal),
                        used=np.where(flagged, np.exp(lt_fit), nominal),  # the metadata kept bit for bit
                        stops=stops, flagged=flagged, measured=measured, trusted=trusted, pixels=pixels,
                        tolerance=tol, stretch=float(b), scale_note=scale_note)
    _explain(fit, names, labels)
    return fit


def _checked_times(times, p: int, tolerance_stops, names):
    """``(nominal seconds, tolerance in stops, base names)``, or a UsageError."""
    nominal = np.asarray(times, np.float64).reshape(-1)
    if nominal.size != p:
        raise UsageError(f"{nominal.size} exposure times for {p} frames")
    if not np.all(np.isfinite(nominal) & (nominal > 0)):
        raise UsageError("exposure times must be positive and finite")
    tol = EXPOSURE_TOLERANCE_STOPS if tolerance_stops is None else float(tolerance_stops)
    if not (tol > 0 and np.isfinite(tol)):
        raise UsageError(f"the exposure tolerance must be a positive number of stops, not {tol:g}")
    names = [f"image {k}" for k in range(p)] if names is None else [os.path.basename(os.fspath(n)) for n in names]
    return nominal, tol, names


def _checked_frames(frames, response: Response) -> list:
    """The frames as ``(H, W, C)`` code arrays of one shape and of the response's depth."""
    arrs = [np.asarray(f) for f in frames]
    arrs = [f[..., None] if f.ndim == 2 else f for f in arrs]
    if any(f.shape != arrs[0].shape for f in arrs):
        raise UsageError("the frames differ in size")
    if arrs[0].dtype not in (np.uint8, np.uint16) or any(f.dtype != arrs[0].dtype for f in arrs):
        raise UsageError("the frames must all be uint8 or all uint16 codes")
    if int(np.iinfo(arrs[0].dtype).max) + 1 != response.levels:
        raise UsageError(f"the response describes {response.bits}-bit images but the frames are "
                         f"{8 * arrs[0].dtype.itemsize}-bit")
    return arrs


@functools.lru_cache(maxsize=8)
def _subsample(npx: int) -> np.ndarray:
    """The :data:`MAX_PIXELS` pixels (sorted flat indices) measured of ``npx``: a fixed
    draw, made once per frame size (every set of a shoot has the same)."""
    idx = np.sort(np.random.default_rng(0).choice(npx, MAX_PIXELS, replace=False))
    idx.flags.writeable = False
    return idx


def _usable_samples(arrs: list, response: Response, weight: str, valid):
    """Per frame: ``g(Z)`` of (at most :data:`MAX_PIXELS`) pixels, their weights, which are
    usable (valid, in the curve's body), and how many pixel-channels are."""
    p, shape = len(arrs), arrs[0].shape
    levels, nch = response.levels, shape[2]
    tables = response.table_for(nch)
    wtab = weight_values(np.arange(levels), levels, weight)
    scale = (levels - 1) / 255.0
    lo, hi = SPAN_BODY[0] * scale, SPAN_BODY[1] * scale
    masks = _masks(valid, p, shape[:2])
    npx = shape[0] * shape[1]
    idx = _subsample(npx) if npx > MAX_PIXELS else None
    xs, ws, oks = [], [], []
    for f, v in zip(arrs, masks):
        z = f.reshape(-1, nch)
        if idx is not None:
            z = z[idx]
        z = z.astype(np.int64)
        ok = (z >= lo) & (z <= hi)
        if v is not None:
            vv = v.reshape(-1)
            ok &= (vv if idx is None else vv[idx])[:, None]
        xs.append(np.stack([tables[c][z[:, c]] for c in range(nch)], axis=1))
        ws.append(wtab[z])
        oks.append(ok)
    pixels = np.array([int(ok.sum()) for ok in oks], np.int64)
    return xs, ws, oks, pixels


def _measure(xs, ws, oks, pixels, lt_nom):
    """``(measured, ln dt)``: the largest connected set of frames measured from their
    pairs' ratios (the others keep ``lt_nom``)."""
    p = len(xs)
    pairs = []
    # Flat views: the pixel-channels a pair shares are found once and taken from each
    # array (the values, in the order, of boolean indexing).
    xs, ws = [x.ravel() for x in xs], [w.ravel() for w in ws]
    for j in range(p):
        for k in range(j + 1, p):
            at = np.flatnonzero(oks[j] & oks[k])
            if at.size < MIN_OVERLAP:
                continue
            d, var = _location(xs[k][at] - xs[j][at], ws[j][at] * ws[k][at])
            pairs.append((j, k, d, var))
    comps = _components(p, [(j, k) for j, k, _, _ in pairs])
    main = max(comps, key=lambda c: (len(c), int(pixels[c].sum())))
    measured = np.zeros(p, bool)
    lt_meas = lt_nom.copy()
    if len(main) >= 2:
        measured[main] = True
        lt_meas[main] = _solve_pairs(main, [q for q in pairs if measured[q[0]]])
    return measured, lt_meas


def _pin_scale(lt_nom, lt_meas, measured, names):
    """``(trusted, a, b, note)``: the frames whose metadata fix the scale, the line
    ``ln dt_measured = a + b ln dt_nominal`` they lie on, and how the scale was fixed."""
    trusted = np.zeros(lt_nom.size, bool)
    m_idx = np.flatnonzero(measured)
    if m_idx.size == 0:
        return trusted, 0.0, 1.0, "no two frames share enough well-exposed pixels"
    group, a, b = _agreeing_line(lt_nom[m_idx], lt_meas[m_idx], TRUST_STOPS * _LN2)
    if group is not None:
        trusted[m_idx[group]] = True
        return trusted, a, b, f"scale fixed by the {int(group.sum())} frames whose metadata agree with the pixels"
    # The lower median: one frame's own metadata (two frames a stop apart by their labels
    # but identical: one is kept, the other corrected).
    r = lt_nom[m_idx] - lt_meas[m_idx]
    anchor = m_idx[np.argsort(r, kind="stable")[(r.size - 1) // 2]]
    a = float(lt_meas[anchor] - lt_nom[anchor])
    return trusted, a, 1.0, (f"no three frames agree with each other's metadata; the scale is that of "
                             f"{names[anchor]}, the median of the {m_idx.size} measured frames")


def _explain(fit: KnownCurveFit, names, labels) -> None:
    """Fill ``fit.notes`` (every change, every pair at one exposure, every frame not
    measured) and ``fit.same``. ``labels``: per frame, the capture's own settings as
    recorded (``1/4000 s f/1.4 ISO 1600``) where the times are equivalents on another
    reference; default the nominal time."""
    from hdrcl.io.metadata import format_time

    nominal, tol, b = fit.nominal, fit.tolerance, fit.stretch
    said = [format_time(t) for t in nominal] if labels is None else [str(x) for x in labels]
    lt_nom, lt_fit = np.log(nominal), np.log(fit.fitted)
    used_lt = np.log(fit.used)
    notes = fit.notes
    m_idx = np.flatnonzero(fit.measured)
    trusted = fit.trusted
    for k in np.flatnonzero(fit.flagged):
        pixels_say = "" if labels is not None else f"{format_time(fit.fitted[k])} "
        notes.append(f"{names[k]}: metadata says {said[k]} but the pixels say {pixels_say}"
                     f"({fit.stops[k]:+.2f} stops); the measured exposure is used")
    if fit.flagged.any() and not trusted.any():
        notes.append(f"exposure scale: {fit.scale_note}")
    if trusted.any() and abs(b - 1.0) * np.ptp(lt_nom[trusted]) > 2 * TRUST_STOPS * _LN2:
        who = "the frames" if trusted.sum() == fit.measured.sum() else _list_names([names[k] for k in
                                                                                   np.flatnonzero(trusted)])
        notes.append(f"the pixels space {who} {b:.2f}x as far apart in exposure as the metadata does, evenly: "
                     "the response may not fit these frames (another camera, ISO or picture style) or every "
                     "time is off by that factor; their metadata is kept")
    for i in m_idx:
        for j in m_idx:
            if j > i and (abs(lt_nom[i] - lt_nom[j]) > tol * _LN2
                          and abs(lt_fit[i] - lt_fit[j]) < SAME_STOPS * _LN2):
                fit.same.append((int(i), int(j)))
                notes.append(f"{names[i]} and {names[j]} are at the same exposure (the pixels say "
                             f"{format_time(np.exp(used_lt[i]))}; the metadata says {said[i]} and {said[j]})")
    if m_idx.size:  # with nothing measured there is nothing to compare a frame with
        # One line per cause for the set, not one per frame (a phone batch printed dozens).
        few = [k for k in np.flatnonzero(~fit.measured) if fit.pixels[k] < MIN_OVERLAP]
        apart = [k for k in np.flatnonzero(~fit.measured) if fit.pixels[k] >= MIN_OVERLAP]
        # A frame with next to nothing in the curve's body (a bracket's darkest or brightest
        # end) contradicts nothing: its label is used, said at -v only (not a warning).
        body = f"the curve's body (codes {SPAN_BODY[0]}..{SPAN_BODY[1]})"
        if few:
            logger.info("%s: too few pixels in %s to measure %s (at most %d); %s metadata is kept",
                        _list_names([names[k] for k in few]), body,
                        "its exposure" if len(few) == 1 else f"the exposures of {len(few)} frames",
                        int(max(fit.pixels[k] for k in few)), "its" if len(few) == 1 else "their")
        if len(apart) == 1:
            k = apart[0]
            notes.append(f"{names[k]}: shares too few well-exposed pixels with the other frames to measure its "
                         f"exposure; its metadata ({said[k]}) is kept")
        elif apart:
            notes.append(f"{_list_names([names[k] for k in apart])}: share too few well-exposed pixels with the "
                         f"other frames to measure their exposures ({len(apart)} frames); their metadata is kept")
    else:
        notes.append(f"{fit.scale_note}; the metadata is kept for all {nominal.size} frames")


def exposures_for_merge(frames, times, response: Response, *, mode: str = "auto", valid=None,
                        weight: str = "gaussian", tolerance_stops: Optional[float] = None,
                        names: Optional[Sequence[str]] = None, labels: Optional[Sequence[str]] = None):
    """The exposures a merge with a known curve (``--response``, a batch's pooled one)
    fuses with, and the notes to show, from :func:`estimate_exposures` on ``frames``
    (in practice the set's sampling grid, from the decode that also feeds the fusion).

    ``mode``: ``off`` keeps the metadata; ``auto`` (the default) corrects the frames the
    pixels contradict; ``on`` takes every measured exposure.

    Raises
    ------
    InputError
        The pixels put the frames in reverse order of their exposure times (a list of
        times given backwards): an error, not a correction.
    """
    from hdrcl.errors import InputError

    times = np.asarray(times, np.float64)
    if mode == "off" or times.size < 2:
        return times, []
    names = [f"image {k}" for k in range(times.size)] if names is None else \
        [os.path.basename(os.fspath(n)) for n in names]
    fit = estimate_exposures(frames, times, response, valid=valid, weight=weight,
                             tolerance_stops=tolerance_stops, names=names, labels=labels)
    order = np.argsort(times, kind="stable")
    measured = fit.measured[order]
    steps = np.diff(np.log(fit.fitted[order][measured]))
    if measured.sum() >= 2 and np.unique(times).size == times.size and np.all(steps < 0):
        raise InputError(f"{names[order[-1]]}: the exposure times run in reverse order of the frames' "
                         "brightness with this response; check the times")
    used = fit.used if mode == "auto" else np.where(fit.measured, fit.fitted, fit.nominal)
    if fit.scale_note:  # how the scale was pinned: information, not a problem
        logging.getLogger(__name__).info("exposure check: %s", fit.scale_note)
    return np.asarray(used, np.float64), list(fit.notes)
