"""Verifying exposure metadata from the pixels: a joint linear fit of exposures and curve
with a weak prior to the metadata, mapped back onto the metadata's scale.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from hdrcl.core.response import _check_smoothness, _segments, knot_positions
from hdrcl.core.weights import weight_values

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

    from hdrcl.core.sampling import default_sample_count, select_samples

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
