"""Verifying exposure metadata from the pixels, without trusting an unconstrained fit.

The paper's system is linear in ``g``, ``ln E`` *and* ``ln dt``, so exposures can be
unknowns too. But the pixels tell them only up to ``a + b ln dt``: curve and exposures
raised to a common power fit the frames equally well (the exponential ambiguity), so a
free fit can stretch an 8-bit curve over many decades. Here the metadata are nominal
values with an uncertainty; the frames whose metadata agree with each other fix the
scale; a frame is changed only when its pixels contradict it decisively *and* the
change lowers the fit error (:func:`fit_exposures`, :func:`verify_exposures`).
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

from hdrcl.core.response import SPAN_BODY, Response, _check_smoothness, _segments, knot_positions
from hdrcl.core.solve import one_blas_thread, solve_curve
from hdrcl.core.weights import weight_values
from hdrcl.errors import UsageError

logger = logging.getLogger(__name__)

#: Weight of the prior that holds each fitted ln dt to its metadata value in the first,
#: exploratory fit, relative to the data (each frame has ~N data rows of weight ~0.5).
EXPOSURE_PRIOR = 0.05
#: A frame whose metadata disagrees with the pixels by more than this (stops) is a
#: candidate for correction; "auto" corrects it only when that also lowers the fit error.
EXPOSURE_TOLERANCE_STOPS = 0.5
#: Metadata is nominal with this uncertainty (stops): EXIF rounding (1/4000 written for
#: 2^-12 s is 0.03 stop), third-stop ladders, phone shutters. Frames whose pixels agree
#: with each other's metadata within it form the trusted set that fixes the scale.
TRUST_STOPS = 0.2
#: A correction is kept only if it lowers the RMS fit residual (in code values) by this
#: factor: a change that does not clearly improve the fit is not made.
IMPROVEMENT = 0.8
#: Frames whose pixel-measured exposures are this close (stops) are at the same exposure.
SAME_STOPS = 0.1
#: How a verdict of :func:`hdrcl.core.exposure.verdict.untrusted_metadata` begins, and how it
#: ends (what to try; a batch says instead what it did, :mod:`hdrcl.shoot.batch.pooling`).
UNTRUSTED = "the exposure metadata of this set cannot be trusted"
PREFER_GOOD = "; prefer a response from a good set of the same camera (--response, or a batch's pooled response)"
#: Relative weight that pins a trusted frame to its metadata in the second fit.
_PIN = 1e3


@dataclass
class ExposureFit:
    """Per-frame exposures verified against the pixels.

    Attributes
    ----------
    nominal, fitted : ndarray
        Seconds: the metadata, and the pixels' estimate on the trusted frames' scale.
    stops : ndarray
        ``log2(fitted / nominal)``.
    flagged : ndarray of bool
        Frames whose metadata the pixels contradict decisively (``|stops| > tolerance``)
        *and* whose correction lowers the fit error: "auto" changes exactly these.
    tolerance : float
    trusted : ndarray of bool
        Frames whose metadata agree with each other (within :data:`TRUST_STOPS`); they
        fix the scale of the exposure axis. All False when no consensus was found.
    same : list of (int, int)
        Pairs of frames with different metadata that the pixels put at the same exposure.
    contradicted : ndarray of bool
        ``|stops| > tolerance``, whether or not the correction was accepted.
    residual : dict
        RMS fit residual (code values) with the metadata (``"nominal"``) and with the
        corrections (``"corrected"``).
    note : str
        How the scale was fixed, or why nothing was changed.
    """

    nominal: np.ndarray
    fitted: np.ndarray
    stops: np.ndarray
    flagged: np.ndarray
    tolerance: float
    trusted: Optional[np.ndarray] = None
    same: list = field(default_factory=list)
    contradicted: Optional[np.ndarray] = None
    residual: dict = field(default_factory=dict)
    note: str = ""


def _theil_sen(x: np.ndarray, y: np.ndarray):
    """Robust line y = a + b x (median of pairwise slopes, median intercept)."""
    i, j = np.triu_indices(x.size, 1)
    dx = x[j] - x[i]
    ok = np.abs(dx) > 1e-12
    b = float(np.median((y[j] - y[i])[ok] / dx[ok])) if ok.any() else 1.0
    a = float(np.median(y - b * x))
    return a, b


def _consensus(nominal_lt: np.ndarray, fitted_lt: np.ndarray, trust: float):
    """The largest set of frames whose fitted and nominal ln dt lie on one line.

    The pixels tell the exposures only up to ``a + b ln dt`` (the exponential
    ambiguity: curve and exposures raised to a common power fit equally well), so the
    line is fitted, not assumed. Every pair of frames with different metadata proposes
    a line; frames within ``trust`` (ln units, on the metadata's scale) are its inliers;
    the line is refined by least squares on them. Returns ``(inliers, a, b)``, or
    ``(None, a, b)`` (Theil-Sen line) when no unique set of at least three frames with
    two different exposures exists.
    """
    p = nominal_lt.size
    sets = {}
    for i in range(p):
        for j in range(i + 1, p):
            dn = nominal_lt[j] - nominal_lt[i]
            if abs(dn) < 0.3 * np.log(2.0):
                continue
            b = (fitted_lt[j] - fitted_lt[i]) / dn
            if b <= 0.05:
                continue
            a = fitted_lt[i] - b * nominal_lt[i]
            inl = np.abs((fitted_lt - a) / b - nominal_lt) <= trust
            for _ in range(3):  # refine on the inliers
                if np.ptp(nominal_lt[inl]) < 1e-9:
                    break
                b, a = np.polyfit(nominal_lt[inl], fitted_lt[inl], 1)
                if b <= 0.05:
                    break
                new = np.abs((fitted_lt - a) / b - nominal_lt) <= trust
                if (new == inl).all():
                    break
                inl = new
            if b <= 0.05 or np.ptp(nominal_lt[inl]) < 1e-9:
                continue
            key = tuple(np.flatnonzero(inl))
            sse = float(np.sum(((fitted_lt[inl] - a) / b - nominal_lt[inl]) ** 2))
            if key not in sets or sse < sets[key][0]:
                sets[key] = (sse, a, b)
    a0, b0 = _theil_sen(nominal_lt, fitted_lt)
    if not sets:
        return None, a0, b0
    best = max(len(k) for k in sets)
    top = [k for k in sets if len(k) == best]
    if best < 3 or len(top) > 1:
        return None, a0, b0
    _, a, b = sets[top[0]]
    inl = np.zeros(p, bool)
    inl[list(top[0])] = True
    return inl, a, b


def _joint_fit(z: np.ndarray, prior_lt: np.ndarray, prior_w: np.ndarray, bits: int, smoothness: float,
               weight: str) -> np.ndarray:
    """ln dt of each frame from one channel's samples ``z`` (N, P), solved jointly with g
    and ln E; frame j is held to ``prior_lt[j]`` with weight ``prior_w[j]``.

    The least-squares system (data rows ``w (g(z) - ln E_i - ln dt_j) = 0``, the curve's
    smoothness rows, ``g(mid) = 0``, the priors) is solved through its normal equations
    with the N ln E unknowns eliminated first: each appears only in its own sample's
    rows, so their block of A^T A is diagonal, and the Schur complement on the curve's
    knots and the exposures (k + P unknowns, a few hundred) is solved densely. The blocks
    are accumulated with ``bincount`` (no sparse matrix, no scipy import)."""
    levels = 1 << bits
    knots = knot_positions(bits)
    k = knots.size
    n, p = z.shape
    m = k + p  # kept unknowns: g at the knots, then ln dt
    w = weight_values(z, levels, weight)
    si, sj = np.nonzero(w > 0)
    ws = w[si, sj]
    seg, frac = _segments(z[si, sj], knots)
    w2 = ws * ws
    # each data row's coefficients on the kept unknowns (the ln E one is -w at si)
    cols = np.stack([seg, seg + 1, k + sj], axis=1)
    coef = np.stack([ws * (1 - frac), ws * frac, -ws], axis=1)
    outer = coef[:, :, None] * coef[:, None, :]
    flat = cols[:, :, None] * m + cols[:, None, :]
    a11 = np.bincount(flat.ravel(), outer.ravel(), m * m).reshape(m, m)
    a12 = np.bincount((cols * n + si[:, None]).ravel(), (coef * -ws[:, None]).ravel(), m * n).reshape(m, n)
    d = np.bincount(si, w2, n) + 1e-10
    # smoothness: wk (g[i-1] - 2 g[i] + g[i+1]) = 0 for the interior knots
    interior = np.arange(1, k - 1)
    wk = smoothness * weight_values(knots[interior], levels, weight)
    stencil = np.array([1.0, -2.0, 1.0])
    idx = interior[:, None] + np.array([-1, 0, 1])
    np.add.at(a11, (idx[:, :, None], idx[:, None, :]), (wk * wk)[:, None, None] * np.outer(stencil, stencil))
    a11[k // 2, k // 2] += 1.0  # g(mid) = 0
    t = k + np.arange(p)
    a11[t, t] += prior_w * prior_w
    rhs = np.zeros(m)
    rhs[t] = prior_w * prior_w * prior_lt
    with one_blas_thread():  # m x N x m: milliseconds on one thread, tens on a busy pool
        s_mat = a11 - (a12 / d) @ a12.T + np.eye(m) * 1e-10
        x = np.linalg.solve(s_mat, rhs)
    return x[k:]


def _fit_residual(z: np.ndarray, lt: np.ndarray, bits: int, smoothness: float, weight: str) -> float:
    """RMS residual, in code values, of the response solved from samples ``z`` (N, P)
    with exposures ``lt``: how well one curve explains the frames at these exposures."""
    levels = 1 << bits
    g = solve_curve(z, lt, bits, smoothness, weight)
    table = Response(bits=bits, g=g[None], knots=knot_positions(bits), channels=("Y",)).tables()[0]
    slope = np.maximum(np.gradient(table), 1e-6)
    zi = z.astype(np.int64)
    w = weight_values(zi, levels, weight)
    x = table[zi] - lt
    sw = w.sum(axis=1)
    ln_e = np.where(sw > 0, (w * x).sum(axis=1) / np.maximum(sw, 1e-12), 0.0)
    r = (x - ln_e[:, None]) / slope[zi]
    return float(np.sqrt((w * r * r).sum() / max(w.sum(), 1e-12)) * 256.0 / levels)


def fit_exposures(
    frames: Sequence[np.ndarray],
    times: Sequence[float],
    *,
    valid: Optional[np.ndarray] = None,
    samples: Optional[int] = None,
    smoothness: Optional[float] = None,
    weight: str = "hat",
    seed: int = 0,
    tolerance: float = EXPOSURE_TOLERANCE_STOPS,
    decimate: bool = True,
    candidates=None,
) -> ExposureFit:
    """Verify each frame's exposure against the pixels; never trust an unconstrained fit.

    1. A joint fit of curve, ln E and ln dt (each ln dt weakly held to its metadata)
       measures the exposures up to ``a + b ln dt``: the pixels cannot fix the scale of
       the exposure axis (exponential ambiguity).
    2. The largest set of frames whose metadata agree with that measurement on one line
       (:func:`_consensus`, within :data:`TRUST_STOPS`) is trusted; its metadata fix
       the scale. With no such set of three or more frames, nothing is changed.
    3. A second fit pins the trusted frames to their metadata and measures the others.
    4. A frame is flagged only when it departs by more than ``tolerance`` stops *and*
       the corrected exposures lower the fit residual by :data:`IMPROVEMENT`.

    Frames with different metadata that the pixels put within :data:`SAME_STOPS` of
    each other are listed in ``same``. ``candidates``: the frames'
    :func:`hdrcl.core.sampling.sample_candidates`, when the caller draws from them again.
    """
    from hdrcl.core.sampling import default_sample_count, select_samples

    smoothness = _check_smoothness(smoothness, weight)
    nominal = np.asarray(times, np.float64)
    p = len(frames)
    none = np.zeros(p, bool)
    if p < 3:
        # Two frames: one ratio, and the overall scale is the metadata's; nothing to fit.
        return ExposureFit(nominal, nominal.copy(), np.zeros(p), none, tolerance, trusted=~none,
                           contradicted=none, note="two frames: the metadata is the only scale")
    bits = 8 if frames[0].dtype == np.uint8 else 16
    nch = frames[0].shape[2]
    k = knot_positions(bits).size
    n = int(samples) if samples else default_sample_count(k, p)
    idx = select_samples(frames, valid, n, seed=seed, decimate=decimate, candidates=candidates)
    n = idx.size
    # The exposures are the same in every channel: the middle one (G of RGB) tells them
    # as well as all three, at a third of the cost.
    z = np.stack([f.reshape(-1, nch)[idx, nch // 2] for f in frames], axis=1).astype(np.float64)
    lt_nom = np.log(nominal)
    ln2 = np.log(2.0)
    lt_fit = _joint_fit(z, lt_nom, np.full(p, EXPOSURE_PRIOR * np.sqrt(n)), bits, smoothness, weight)
    trusted, a, b = _consensus(lt_nom, lt_fit, TRUST_STOPS * ln2)
    mapped = (lt_fit - a) / (b if abs(b) > 1e-6 else 1.0)
    if trusted is None:
        stops = (mapped - lt_nom) / ln2
        far = np.abs(stops) > tolerance
        note = ("no three frames agree with each other's metadata; give --response from a good set of "
                "this camera to check it")
        return ExposureFit(nominal, np.exp(mapped), stops, none, tolerance, trusted=none,
                           contradicted=far, note=note)
    # Second fit: the trusted frames fix the scale; the others are measured on it.
    prior_w = np.where(trusted, _PIN, 1e-3) * np.sqrt(n)
    lt_pin = _joint_fit(z, lt_nom, prior_w, bits, smoothness, weight)
    lt_est = np.where(trusted, mapped, lt_pin)
    stops = (lt_est - lt_nom) / ln2
    far = ~trusted & (np.abs(stops) > tolerance)
    res = {"nominal": _fit_residual(z, lt_nom, bits, smoothness, weight)}
    flagged = none.copy()
    note = f"scale fixed by the {int(trusted.sum())} frames whose metadata agree"
    if far.any():
        lt_new = np.where(far, lt_pin, lt_nom)
        res["corrected"] = _fit_residual(z, lt_new, bits, smoothness, weight)
        if res["corrected"] < IMPROVEMENT * res["nominal"]:
            flagged = far
        else:
            note += "; the corrections did not lower the fit error"
    used = np.where(flagged, lt_est, lt_nom)
    same = []
    for i in range(p):
        for j in range(i + 1, p):
            if (abs(lt_nom[i] - lt_nom[j]) > tolerance * ln2 and abs(used[i] - used[j]) < SAME_STOPS * ln2
                    and (flagged[i] or flagged[j])):
                same.append((i, j))
    return ExposureFit(nominal=nominal, fitted=np.exp(lt_est), stops=stops, flagged=flagged,
                       tolerance=float(tolerance), trusted=trusted, same=same, contradicted=far,
                       residual=res, note=note)


def verify_exposures(frames, times, names, *, mode: str = "auto", valid=None, samples=None, seed: int = 0,
                     tolerance: Optional[float] = None, decimate: bool = True, warn: bool = True,
                     candidates=None):
    """Exposures a calibration should use, with what the pixels said about the metadata.

    ``mode`` ``off`` keeps the metadata; ``auto`` changes only the frames
    :func:`fit_exposures` flags (decisive *and* improving); ``on`` uses the pixel
    estimate for every frame, on the trusted frames' scale. Warnings name the files.

    Returns
    -------
    used : ndarray
        Seconds per frame.
    fit : ExposureFit or None
    """
    from hdrcl.io.metadata import format_time

    if mode not in ("auto", "on", "off"):
        raise UsageError(f"--fit-exposures: '{mode}' is not one of auto, on, off")
    kinds = {np.asarray(f).dtype for f in frames}
    if len(kinds) > 1:  # a 16-bit frame among 8-bit ones: codes index tables of the wrong size
        raise UsageError(f"frames of mixed bit depth ({', '.join(sorted(k.name for k in kinds))}); "
                         "give frames of one bit depth")
    nominal = np.asarray(times, np.float64)
    tol = EXPOSURE_TOLERANCE_STOPS if tolerance is None else float(tolerance)
    level = logging.WARNING if warn else logging.DEBUG
    _check_identical(frames, nominal, names, tol, level)
    if mode == "off" or len(frames) < 3:
        return nominal.copy(), None
    # The fit uses the paper's hat weights: their wide overlap between frames conditions
    # the exposure estimates better than a narrow weighting does.
    fit = fit_exposures(frames, nominal, valid=valid, samples=min(samples or 400, 400), weight="hat",
                        seed=seed, tolerance=tol, decimate=decimate, candidates=candidates)
    base = [os.path.basename(n) for n in names]
    for k in np.flatnonzero(fit.contradicted):
        change = fit.flagged[k] and mode == "auto"
        logger.log(level, "%s: metadata says %s but the pixels say %s (%+.2f stops); %s", base[k],
                       format_time(fit.nominal[k]), format_time(fit.fitted[k]), fit.stops[k],
                       "using the fitted exposure" if change or mode == "on" else
                       "metadata kept: " + fit.note)
    for i, j in fit.same:
        logger.log(level, "%s and %s are at the same exposure (the pixels say %s; the metadata says %s and %s)",
                       base[i], base[j], format_time(fit.fitted[i] if fit.flagged[i] else fit.nominal[i]),
                       format_time(fit.nominal[i]), format_time(fit.nominal[j]))
    logger.log(logging.INFO if warn else logging.DEBUG, "exposure check: %s", fit.note)
    if mode == "on":
        used = fit.fitted.copy() if fit.trusted is not None and fit.trusted.any() else nominal.copy()
    else:
        used = np.where(fit.flagged, fit.fitted, nominal)
    return used, fit


def _check_identical(frames, nominal, names, tol, level=logging.WARNING):
    """Warn about frames with identical pixels labelled with different exposures."""
    p = len(frames)
    for i in range(p):
        for j in range(i + 1, p):
            if (abs(np.log2(nominal[j] / nominal[i])) > tol and frames[i].shape == frames[j].shape
                    and np.array_equal(frames[i], frames[j])):
                logger.log(level, "%s and %s have identical pixels but exposures %g s and %g s; "
                               "the same photograph given twice?", os.path.basename(names[i]),
                               os.path.basename(names[j]), nominal[i], nominal[j])


class ExposureCheck:
    """Checks the exposures of a merge with a given response against the pixels.

    With the curve known, the pixels tell each exposure ratio directly: for two frames
    adjacent in exposure, ``g(Z_b) - g(Z_a)`` over pixels both hold in the curve's body
    (codes 25..230 in 8-bit units) is ``ln(dt_b / dt_a)``. Strips are added as they stream by (a subsample of
    their pixels, in the middle channel) and :meth:`problems` compares the median with
    the metadata.

    Parameters
    ----------
    log_times : ndarray
        ``ln dt`` of the frames in exposure order.
    tables : ndarray (C, L)
        The response at every code.
    names : sequence of str
        The files, in exposure order.
    """

    #: Histogram of ln-ratio differences: range and bin width (ln units).
    RANGE, BIN = 12.0, 0.01
    #: Every k-th row and column of each strip is measured.
    STEP = 4
    #: Pairs measured on fewer pixels than this are not judged.
    MIN_PIXELS = 200

    def __init__(self, log_times, tables, names):
        self.log_times = np.asarray(log_times, np.float64)
        self.names = [os.path.basename(os.fspath(n)) for n in names]
        ch = tables.shape[0] // 2
        self.table = np.asarray(tables[ch], np.float64)
        self.channel = ch
        levels = self.table.size
        scale = (levels - 1) / 255.0
        # The body of the curve only: near black, film fog and scanner floor hold codes
        # that do not change with exposure (the Memorial set's short frames sit at 10-20
        # in most of the picture), which would read as a ratio of 1.
        self.lo, self.hi = SPAN_BODY[0] * scale, SPAN_BODY[1] * scale
        nb = int(round(2 * self.RANGE / self.BIN))
        self.hist = np.zeros((max(len(self.log_times) - 1, 0), nb), np.int64)

    def add(self, frames, valid=None) -> None:
        """Measure a strip (frames in exposure order, ``(rows, W, C)`` codes)."""
        s = self.STEP
        zs = [f[::s, ::s, min(self.channel, f.shape[2] - 1)].astype(np.int64) for f in frames]
        oks = [(z >= self.lo) & (z <= self.hi) for z in zs]
        if valid is not None:
            oks = [ok if v is None else ok & v[::s, ::s] for ok, v in zip(oks, valid)]
        nb = self.hist.shape[1]
        for j in range(len(zs) - 1):
            ok = oks[j] & oks[j + 1]
            if not ok.any():
                continue
            d = self.table[zs[j + 1][ok]] - self.table[zs[j][ok]]
            idx = np.clip(((d + self.RANGE) / self.BIN).astype(np.int64), 0, nb - 1)
            self.hist[j] += np.bincount(idx, minlength=nb)

    def measured(self) -> np.ndarray:
        """Median ``ln(dt_{j+1} / dt_j)`` per adjacent pair; NaN where too few pixels."""
        out = np.full(self.hist.shape[0], np.nan)
        for j, h in enumerate(self.hist):
            n = int(h.sum())
            if n >= self.MIN_PIXELS:
                k = int(np.searchsorted(np.cumsum(h), (n + 1) // 2))
                out[j] = (k + 0.5) * self.BIN - self.RANGE
        return out

    def problems(self, tolerance: float = EXPOSURE_TOLERANCE_STOPS):
        """``(messages, reversed)``: one message per adjacent pair the pixels contradict
        (order, or ratio off by more than ``tolerance`` stops), and whether every
        judged pair is in reverse order (the exposures are then meaningless)."""
        from hdrcl.io.metadata import format_time

        meas = self.measured()
        nominal = np.diff(self.log_times)
        msgs, judged, backwards = [], 0, 0
        for j, (m, n) in enumerate(zip(meas, nominal)):
            if not np.isfinite(m) or abs(n) < 1e-9:
                continue
            judged += 1
            a, b = self.names[j], self.names[j + 1]
            ta, tb = format_time(np.exp(self.log_times[j])), format_time(np.exp(self.log_times[j + 1]))
            if m < -0.1:
                backwards += 1
                msgs.append(f"{b} ({tb}) is darker than {a} ({ta}) although its exposure is longer: "
                            f"the pixels say {np.exp(m):.3g}x, the metadata {np.exp(n):.3g}x")
            elif abs(m - n) > tolerance * np.log(2.0):
                msgs.append(f"{b} ({tb}) vs {a} ({ta}): the pixels say {np.exp(m):.3g}x, "
                            f"the metadata {np.exp(n):.3g}x")
        return msgs, judged > 0 and backwards == judged
