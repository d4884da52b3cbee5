"""Recovering the camera response g = ln f^-1 (CPU, scipy.sparse least squares).

The paper's objective, exactly::

    O = sum_ij [w(Z_ij) (g(Z_ij) - ln E_i - ln dt_j)]^2
      + sum_{z=Zmin+1}^{Zmax-1} [lambda w(z) g''(z)]^2        (rows carry lambda w [1,-2,1])

with ``g(Zmid) = 0``. One curve per channel. 8-bit data solves for all 256 levels;
16-bit data solves for ``BINS_16BIT`` knots at bin centres, the data rows interpolating
g linearly between knots, so the system never has 65536 columns.
"""
from __future__ import annotations

import json
import logging
import os
import tempfile
from dataclasses import dataclass, field
from typing import List, Optional, Sequence

import numpy as np

from .errors import InputError, UsageError
from .weights import weight_values

logger = logging.getLogger(__name__)

RESPONSE_FORMAT = "hdrcl-response"
RESPONSE_VERSION = 1
#: Knots of the solved curve for 16-bit data.
BINS_16BIT = 1024
#: Default smoothness lambda per weighting (rows carry lambda * w(z) * [1, -2, 1]), for
#: the default sample count. Chosen on synthetic scenes (curve error) and the Memorial
#: set (leave-one-out error); see scripts/memorial_loo.py.
DEFAULT_SMOOTHNESS = {"hat": 40.0, "gaussian": 60.0}


def default_smoothness(weight: str = "hat") -> float:
    """The default lambda for a weighting function."""
    return DEFAULT_SMOOTHNESS.get(weight, DEFAULT_SMOOTHNESS["hat"])


def _check_smoothness(smoothness, weight: str) -> float:
    if smoothness is None:
        return default_smoothness(weight)
    smoothness = float(smoothness)
    if not (smoothness > 0 and np.isfinite(smoothness)):
        raise UsageError(f"--smoothness must be a positive number, not {smoothness:g}")
    return smoothness


def knot_positions(bits: int) -> np.ndarray:
    """Code values at which the curve is solved: every level for 8-bit, bin centres above."""
    levels = 1 << bits
    if levels <= BINS_16BIT:
        return np.arange(levels, dtype=np.float64)
    step = levels / BINS_16BIT
    return (np.arange(BINS_16BIT) + 0.5) * step - 0.5


def _segments(z: np.ndarray, knots: np.ndarray):
    """Knot segment index and fraction for code values ``z`` (uniform knots)."""
    step = knots[1] - knots[0]
    i = np.clip(np.floor((z - knots[0]) / step).astype(np.int64), 0, knots.size - 2)
    f = (z - knots[i]) / step
    return i, f


@dataclass
class Response:
    """A recovered response curve, one per channel, with its provenance.

    Attributes
    ----------
    bits : int
        Bits per sample of the photographs it describes (8 or 16).
    g : ndarray, shape (C, K)
        ``g = ln f^-1`` at ``knots``, natural-log exposure units, ``g(Zmid) = 0``.
    knots : ndarray, shape (K,)
        Code values of the samples of ``g``.
    channels : tuple of str
    smoothness, weight, samples, seed
        The solve's parameters.
    camera : dict
        Make, model, ISO of the source photographs where known.
    exposures : list of dict
        Per source frame: ``{"file", "nominal", "fitted"}`` (seconds).
    warnings : list of str
        Problems noticed, e.g. a non-monotonic curve.
    """

    bits: int
    g: np.ndarray
    knots: np.ndarray
    channels: tuple = ("R", "G", "B")
    smoothness: float = 40.0
    weight: str = "hat"
    samples: int = 0
    seed: int = 0
    camera: dict = field(default_factory=dict)
    exposures: list = field(default_factory=list)
    warnings: list = field(default_factory=list)

    @property
    def levels(self) -> int:
        return 1 << self.bits

    @property
    def nchannels(self) -> int:
        return int(self.g.shape[0])

    def tables(self) -> np.ndarray:
        """``g`` at every code value, shape ``(C, levels)``, float64.

        Between knots the curve is linear; beyond the outermost knots (16-bit only) it
        is extended along the last segment.
        """
        z = np.arange(self.levels, dtype=np.float64)
        if self.knots.size == self.levels:
            return np.array(self.g, dtype=np.float64, copy=True)
        i, f = _segments(z, self.knots)
        return self.g[:, i] * (1.0 - f) + self.g[:, i + 1] * f

    def table_for(self, nchannels: int) -> np.ndarray:
        """Tables matched to an image of ``nchannels`` colour channels."""
        t = self.tables()
        if t.shape[0] == nchannels:
            return t
        if t.shape[0] == 1:
            return np.repeat(t, nchannels, axis=0)
        raise UsageError(
            f"the response has {t.shape[0]} channels but the images have {nchannels}"
        )

    def monotonic_problems(self) -> List[str]:
        """Describe every channel whose curve decreases somewhere."""
        out = []
        t = self.tables()
        for c, name in enumerate(self.channels):
            d = np.diff(t[c])
            bad = np.flatnonzero(d < -1e-9)
            if bad.size:
                out.append(
                    f"channel {name}: recovered curve is not monotonic "
                    f"({bad.size} decreasing steps, first between levels {bad[0]} and {bad[0] + 1}); "
                    "try more --smoothness or more --samples"
                )
        return out

    # -- persistence -------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "format": RESPONSE_FORMAT,
            "version": RESPONSE_VERSION,
            "bits": self.bits,
            "levels": self.levels,
            "channels": list(self.channels),
            "knots": [float(k) for k in self.knots],
            "g": {name: [round(float(v), 9) for v in self.g[c]] for c, name in enumerate(self.channels)},
            "smoothness": self.smoothness,
            "weight": self.weight,
            "samples": self.samples,
            "seed": self.seed,
            "camera": self.camera,
            "exposures": self.exposures,
            "warnings": self.warnings,
        }

    @classmethod
    def from_dict(cls, d: dict, source: str = "response") -> "Response":
        if not isinstance(d, dict) or d.get("format") != RESPONSE_FORMAT:
            raise InputError(f"{source}: not an hdrcl response file (no \"format\": \"{RESPONSE_FORMAT}\")")
        if int(d.get("version", 0)) > RESPONSE_VERSION:
            raise InputError(
                f"{source}: response file version {d.get('version')} is newer than this hdrcl "
                f"understands ({RESPONSE_VERSION}); upgrade hdrcl"
            )
        try:
            channels = tuple(d["channels"])
            knots = np.asarray(d["knots"], np.float64)
            g = np.asarray([d["g"][c] for c in channels], np.float64)
            bits = int(d["bits"])
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{source}: malformed response file ({exc!s})") from None
        if bits not in (8, 16) or g.shape != (len(channels), knots.size) or knots.size < 3:
            raise InputError(f"{source}: malformed response file (bits {bits}, curve shape {g.shape})")
        if not np.all(np.isfinite(g)):
            raise InputError(f"{source}: response curve holds non-finite values")
        return cls(
            bits=bits, g=g, knots=knots, channels=channels,
            smoothness=float(d.get("smoothness", 0.0)), weight=str(d.get("weight", "hat")),
            samples=int(d.get("samples", 0)), seed=int(d.get("seed", 0)), camera=dict(d.get("camera", {})),
            exposures=list(d.get("exposures", [])), warnings=list(d.get("warnings", [])),
        )

    def save(self, path) -> None:
        """Write the response as JSON, atomically (temporary file, then rename)."""
        path = os.fspath(path)
        folder = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(folder):
            raise UsageError(f"{path}: output folder does not exist")
        fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp", dir=folder)
        try:
            with os.fdopen(fd, "w") as fh:
                json.dump(self.to_dict(), fh, indent=1)
                fh.write("\n")
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise

    @classmethod
    def load(cls, path) -> "Response":
        path = os.fspath(path)
        try:
            with open(path) as fh:
                d = json.load(fh)
        except FileNotFoundError:
            raise InputError(f"{path}: response file not found") from None
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: cannot read response file ({exc!s})") from None
        return cls.from_dict(d, source=path)


def solve_curve(
    z: np.ndarray,
    log_times: np.ndarray,
    bits: int,
    smoothness: Optional[float] = None,
    weight: str = "hat",
    usable: Optional[np.ndarray] = None,
) -> np.ndarray:
    """Solve one channel's curve from sampled codes.

    Parameters
    ----------
    z : ndarray, shape (N, P)
        Integer codes of N sampled pixels in P frames.
    log_times : ndarray, shape (P,) or (N, P)
        ``ln dt_j``; a 2-D array gives each sample its own exposures (samples pooled
        from several bracket sets, padded with ``usable = False``).
    bits : int
        8 or 16.
    smoothness : float, optional
        lambda; default :func:`default_smoothness` of ``weight``.
    weight : str
        Weighting function name (:mod:`hdrcl.weights`).
    usable : ndarray of bool, shape (N, P), optional
        False drops a sample (invalid pixel in that frame).

    Returns
    -------
    numpy.ndarray
        g at :func:`knot_positions` (float64), shifted so that ``g(levels // 2) = 0``.
    """
    import scipy.sparse as sp

    smoothness = _check_smoothness(smoothness, weight)
    levels = 1 << bits
    knots = knot_positions(bits)
    k = knots.size
    z = np.asarray(z, np.float64)
    n, p = z.shape
    w = weight_values(z, levels, weight)
    if usable is not None:
        w = np.where(usable, w, 0.0)
    keep = w > 0
    si, sj = np.nonzero(keep)
    ws = w[si, sj]
    seg, frac = _segments(z[si, sj], knots)
    m = si.size
    rows_d = np.arange(m)
    # Data rows: w*g(z) (interpolated between knots) - w*lnE_i = w*ln dt_j
    r = np.concatenate([rows_d, rows_d, rows_d])
    c = np.concatenate([seg, seg + 1, k + si])
    v = np.concatenate([ws * (1.0 - frac), ws * frac, -ws])
    lt = np.broadcast_to(np.asarray(log_times, np.float64), z.shape)
    b_data = ws * lt[si, sj]
    # Smoothness rows: lambda w(z) [1, -2, 1] at interior knots.
    interior = np.arange(1, k - 1)
    wk = smoothness * weight_values(knots[interior], levels, weight)
    rows_s = m + np.arange(interior.size)
    r = np.concatenate([r, rows_s, rows_s, rows_s])
    c = np.concatenate([c, interior - 1, interior, interior + 1])
    v = np.concatenate([v, wk, -2.0 * wk, wk])
    # g(mid knot) = 0 fixes the free additive constant.
    row_c = m + interior.size
    r = np.concatenate([r, [row_c]])
    c = np.concatenate([c, [k // 2]])
    v = np.concatenate([v, [1.0]])
    nrows = row_c + 1
    a = sp.csr_matrix((v, (r, c)), shape=(nrows, k + n))
    b = np.zeros(nrows)
    b[:m] = b_data
    # Normal equations [[G, B], [B^T, D]] [g; lnE] = [u; e]. Each ln E_i appears only in
    # its own sample's rows, so D is diagonal and the ln E block is eliminated exactly
    # (Schur complement), leaving a small dense levels x levels system for g:
    # (G - B D^-1 B^T) g = u - B D^-1 e. Same solution as solving the whole system.
    ata = (a.T @ a).tocsc()
    atb = a.T @ b
    d = ata.diagonal()[k:].copy()
    empty = d <= 0  # a sample with no usable measurement: its ln E is free; pin it to 0
    d[empty] = 1.0
    gb = ata[:k, k:]
    dinv = sp.diags(1.0 / d)
    schur = ata[:k, :k].toarray() - (gb @ dinv @ gb.T).toarray()
    rhs = atb[:k] - gb @ (atb[k:] / d)
    g = np.linalg.solve(schur, rhs)
    # Re-anchor exactly at Zmid = levels // 2 (equal to a knot for 8-bit data).
    zmid = levels // 2
    i, f = _segments(np.array([float(zmid)]), knots)
    g = g - (g[i[0]] * (1 - f[0]) + g[i[0] + 1] * f[0])
    return g


def recover_response(
    frames: Sequence[np.ndarray],
    times: Sequence[float],
    *,
    valid: Optional[np.ndarray] = None,
    samples: Optional[int] = None,
    smoothness: Optional[float] = None,
    weight: str = "hat",
    seed: int = 0,
    channels: Optional[Sequence[str]] = None,
    decimate: bool = True,
) -> Response:
    """Recover the response of a bracket.

    Parameters
    ----------
    frames : sequence of ndarray
        P images ``(H, W, C)`` of uint8 or uint16 codes, same shape.
    times : sequence of float
        Relative exposure of each frame (seconds).
    valid : ndarray of bool (H, W), optional
        Pixels measured in every frame (alpha, ignore-colour); others are never sampled.
    samples : int, optional
        Number of pixels; default :func:`hdrcl.sampling.default_sample_count`.
    smoothness, weight, seed, decimate
        See :func:`solve_curve` and :func:`hdrcl.sampling.select_samples`.

    Returns
    -------
    Response
    """
    from .sampling import default_sample_count, select_samples

    if len(frames) < 2:
        raise UsageError("calibration needs at least two exposures")
    smoothness = _check_smoothness(smoothness, weight)
    dtype = frames[0].dtype
    if dtype == np.uint8:
        bits = 8
    elif dtype == np.uint16:
        bits = 16
    else:
        raise UsageError(f"frames must be uint8 or uint16, not {dtype}")
    nch = frames[0].shape[2] if frames[0].ndim == 3 else 1
    log_t = np.log(np.asarray(times, np.float64))
    knots = knot_positions(bits)
    n = int(samples) if samples else default_sample_count(knots.size, len(frames))
    if n < 1:
        raise UsageError(f"--samples must be positive, not {samples}")
    idx = select_samples(frames, valid, n, seed=seed, decimate=decimate)
    if idx.size * (len(frames) - 1) <= knots.size // 4:
        raise InputError(
            f"only {idx.size} usable calibration pixels were found; the frames may be blank, "
            "clipped or masked almost everywhere"
        )
    if idx.size * (len(frames) - 1) <= knots.size:
        logger.warning(
            "%d samples x %d frames leave the response under-determined "
            "(N(P-1) should exceed %d); the curve leans on smoothness", idx.size, len(frames), knots.size,
        )
    zs = np.stack([f.reshape(-1, nch)[idx] for f in frames], axis=1)  # (N, P, C)
    return _finish(zs, np.broadcast_to(log_t, zs.shape[:2]), None, bits, smoothness, weight, seed, channels)


#: A sample whose residual (weighted RMS over its frames, ln units) exceeds this many
#: times the median sample's, and 0.1, is dropped before a second solve: a pixel that
#: moved between frames, or sits on an edge that misregistration smears, must not bend
#: the curve.
OUTLIER_FACTOR = 6.0


def _sample_residuals(z, log_t, usable, g_tables, weight, levels):
    """Weighted RMS residual of each sample under curves ``g_tables`` (C, levels)."""
    nch = z.shape[2]
    res = np.zeros(z.shape[0])
    for ch in range(nch):
        zc = z[:, :, ch].astype(np.int64)
        w = weight_values(zc, levels, weight)
        if usable is not None:
            w = np.where(usable, w, 0.0)
        x = g_tables[ch][zc] - log_t
        sw = w.sum(axis=1)
        ln_e = np.where(sw > 0, (w * x).sum(axis=1) / np.maximum(sw, 1e-12), 0.0)
        r2 = (w * (x - ln_e[:, None]) ** 2).sum(axis=1) / np.maximum(sw, 1e-12)
        res = np.maximum(res, np.sqrt(r2))
    return res


def _finish(zs, log_t, usable, bits, smoothness, weight, seed, channels) -> Response:
    nch = zs.shape[2]
    smoothness = _check_smoothness(smoothness, weight)
    knots = knot_positions(bits)

    def solve(keep):
        u = None if usable is None else usable[keep]
        return np.stack([solve_curve(zs[keep][:, :, ch], log_t[keep], bits, smoothness, weight, u)
                         for ch in range(nch)])

    keep = np.ones(zs.shape[0], bool)
    g = solve(keep)
    probe = Response(bits=bits, g=g, knots=knots, channels=("R", "G", "B")[:nch] if nch == 3 else ("Y",) * nch)
    res = _sample_residuals(zs, log_t, usable, probe.tables(), weight, 1 << bits)
    limit = max(OUTLIER_FACTOR * float(np.median(res)), 0.1)
    outliers = res > limit
    if outliers.any() and outliers.mean() < 0.5:
        keep = ~outliers
        g = solve(keep)
        logger.info("response: dropped %d of %d samples as outliers (residual > %.3f)",
                    int(outliers.sum()), outliers.size, limit)
    names = tuple(channels) if channels else (("R", "G", "B")[:nch] if nch == 3 else tuple(f"Y{c}" if c else "Y" for c in range(nch)))
    resp = Response(bits=bits, g=g, knots=knots, channels=names, smoothness=float(smoothness),
                    weight=weight, samples=int(keep.sum()), seed=int(seed))
    resp.warnings.extend(resp.monotonic_problems())
    for wmsg in resp.warnings:
        logger.warning(wmsg)
    return resp


def recover_response_pooled(
    brackets: Sequence[tuple],
    *,
    samples: Optional[int] = None,
    smoothness: Optional[float] = None,
    weight: str = "hat",
    seed: int = 0,
    channels: Optional[Sequence[str]] = None,
) -> Response:
    """One response from samples pooled over several bracket sets of one camera.

    Parameters
    ----------
    brackets : sequence of (frames, times, valid)
        Each set's frames (same bit depth and channel count across sets), exposure
        times in seconds, and ``(H, W)`` validity mask or None. Sets may differ in size
        and frame count.
    samples : int, optional
        Total pixels, shared out evenly between the sets.

    Returns
    -------
    Response
    """
    from .sampling import default_sample_count, select_samples

    brackets = [b for b in brackets if len(b[0]) >= 2]
    if not brackets:
        raise UsageError("calibration needs at least one set of two or more exposures")
    first = brackets[0][0][0]
    bits = 8 if first.dtype == np.uint8 else 16
    nch = first.shape[2]
    pmax = max(len(b[0]) for b in brackets)
    knots = knot_positions(bits)
    total = int(samples) if samples else default_sample_count(knots.size, min(len(b[0]) for b in brackets))
    per = max(1, total // len(brackets))
    zs_all, lt_all, ok_all = [], [], []
    for k, (frames, times, valid) in enumerate(brackets):
        if frames[0].dtype != first.dtype or frames[0].shape[2] != nch:
            raise UsageError("pooled calibration needs sets of one bit depth and channel count")
        idx = select_samples(frames, valid, per, seed=seed + k)
        p = len(frames)
        z = np.zeros((idx.size, pmax, nch), first.dtype)
        z[:, :p] = np.stack([f.reshape(-1, nch)[idx] for f in frames], axis=1)
        lt = np.zeros((idx.size, pmax))
        lt[:, :p] = np.log(np.asarray(times, np.float64))
        ok = np.zeros((idx.size, pmax), bool)
        ok[:, :p] = True
        zs_all.append(z)
        lt_all.append(lt)
        ok_all.append(ok)
    zs = np.concatenate(zs_all)
    if zs.shape[0] * (pmax - 1) <= knots.size // 4:
        raise InputError(f"only {zs.shape[0]} usable calibration pixels were found across {len(brackets)} sets")
    return _finish(zs, np.concatenate(lt_all), np.concatenate(ok_all), bits, smoothness, weight, seed, channels)


#: Weight of the prior that holds each fitted ln dt to its metadata value, relative to
#: the data (each frame has ~N data rows of weight ~0.5): weak enough that pixels
#: override a wrong value, strong enough to fix what the pixels cannot tell (the
#: overall slope of the exposure axis).
EXPOSURE_PRIOR = 0.05
#: Metadata that disagrees with the pixels by more than this (stops) is reported, and in
#: "auto" mode replaced by the fitted value.
EXPOSURE_TOLERANCE_STOPS = 0.5


@dataclass
class ExposureFit:
    """Per-frame exposures estimated from the pixels.

    ``nominal`` and ``fitted`` are seconds; ``stops`` = log2(fitted / nominal), after
    the fit has been mapped onto the metadata's overall scale; ``flagged`` marks frames
    whose metadata the pixels clearly contradict (``|stops| > tolerance``).
    """

    nominal: np.ndarray
    fitted: np.ndarray
    stops: np.ndarray
    flagged: np.ndarray
    tolerance: float


def _theil_sen(x: np.ndarray, y: np.ndarray):
    """Robust line y = a + b x (median of pairwise slopes, median intercept)."""
    i, j = np.triu_indices(x.size, 1)
    dx = x[j] - x[i]
    ok = np.abs(dx) > 1e-12
    b = float(np.median((y[j] - y[i])[ok] / dx[ok])) if ok.any() else 1.0
    a = float(np.median(y - b * x))
    return a, b


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
) -> ExposureFit:
    """Estimate each frame's true relative exposure jointly with the response.

    The paper's system is linear in ``g``, ``ln E_i`` *and* ``ln dt_j``, so the
    exposures can be unknowns too (one per frame, shared by the channels), each held to
    its metadata value by a weak prior (:data:`EXPOSURE_PRIOR`). The pixels cannot tell
    the overall offset and slope of the exposure axis (scaling g and all ln dt together
    fits as well), so the fitted values are mapped back onto the metadata by a robust
    line through (nominal, fitted) (Theil-Sen): a frame whose metadata is wrong stands
    out as a residual from that line, and the overall scale is the metadata's.
    """
    import scipy.sparse as sp

    from .sampling import default_sample_count, select_samples

    smoothness = _check_smoothness(smoothness, weight)
    nominal = np.asarray(times, np.float64)
    p = len(frames)
    if p < 3:
        # Two frames: one ratio, and the overall scale is the metadata's; nothing to fit.
        return ExposureFit(nominal, nominal.copy(), np.zeros(p), np.zeros(p, bool), tolerance)
    bits = 8 if frames[0].dtype == np.uint8 else 16
    levels = 1 << bits
    nch = frames[0].shape[2]
    knots = knot_positions(bits)
    k = knots.size
    n = int(samples) if samples else default_sample_count(k, p)
    idx = select_samples(frames, valid, n, seed=seed, decimate=decimate)
    n = idx.size
    # The exposures are the same in every channel: the middle one (G of RGB) tells them
    # as well as all three, at a third of the cost.
    zs = np.stack([f.reshape(-1, nch)[idx, nch // 2:nch // 2 + 1] for f in frames], axis=1).astype(np.float64)
    nch = 1
    lt_nom = np.log(nominal)
    block = k + n
    ncols = nch * block + p
    rr, cc, vv, bb = [], [], [], []
    row = 0
    interior = np.arange(1, k - 1)
    wk = smoothness * weight_values(knots[interior], levels, weight)
    for ch in range(nch):
        z = zs[:, :, ch]
        w = weight_values(z, levels, weight)
        si, sj = np.nonzero(w > 0)
        ws = w[si, sj]
        seg, frac = _segments(z[si, sj], knots)
        m = si.size
        rows = row + np.arange(m)
        base = ch * block
        rr += [rows, rows, rows, rows]
        cc += [base + seg, base + seg + 1, base + k + si, nch * block + sj]
        vv += [ws * (1 - frac), ws * frac, -ws, -ws]
        bb.append(np.zeros(m))
        row += m
        rows = row + np.arange(interior.size)
        rr += [rows, rows, rows]
        cc += [base + interior - 1, base + interior, base + interior + 1]
        vv += [wk, -2 * wk, wk]
        bb.append(np.zeros(interior.size))
        row += interior.size
        rr.append(np.array([row]))
        cc.append(np.array([base + k // 2]))
        vv.append(np.array([1.0]))
        bb.append(np.zeros(1))
        row += 1
    prior = EXPOSURE_PRIOR * np.sqrt(n)
    rows = row + np.arange(p)
    rr.append(rows)
    cc.append(nch * block + np.arange(p))
    vv.append(np.full(p, prior))
    bb.append(prior * lt_nom)
    row += p
    a = sp.csr_matrix((np.concatenate(vv), (np.concatenate(rr), np.concatenate(cc))), shape=(row, ncols))
    b = np.concatenate(bb)
    # A few hundred unknowns (one channel, ~400 samples): a dense solve is quickest.
    ata = (a.T @ a).toarray() + np.eye(ncols) * 1e-10
    x = np.linalg.solve(ata, a.T @ b)
    lt_fit = x[nch * block:]
    # Back onto the metadata's offset and slope, robustly.
    a0, b1 = _theil_sen(lt_nom, lt_fit)
    lt_mapped = (lt_fit - a0) / (b1 if abs(b1) > 1e-6 else 1.0)
    stops = (lt_mapped - lt_nom) / np.log(2.0)
    return ExposureFit(nominal=nominal, fitted=np.exp(lt_mapped), stops=stops,
                       flagged=np.abs(stops) > tolerance, tolerance=float(tolerance))
