"""Recovering the camera response g = ln f^-1 (CPU least squares, NumPy only).

The paper's objective, exactly::

    O = sum_ij [w(Z_ij) (g(Z_ij) - ln E_i - ln dt_j)]^2
      + sum_{z=Zmin+1}^{Zmax-1} [lambda w(z) g''(z)]^2        (rows carry lambda w [1,-2,1])

with ``g(Zmid) = 0``. One curve per channel. 8-bit data solves for all 256 levels;
16-bit data solves for ``BINS_16BIT`` knots at bin centres, the data rows interpolating
g linearly between knots, so the system never has 65536 columns.
"""
from __future__ import annotations

import logging
from typing import Optional, Sequence

import numpy as np

from hdrcl.core.response import Response, _check_smoothness, _segments, knot_positions
from hdrcl.core.weights import weight_values
from hdrcl.errors import InputError, ProcessingError, UsageError

logger = logging.getLogger(__name__)


_blas = []  # the threadpoolctl controller of NumPy's BLAS, found once per process


def one_blas_thread():
    """A context that runs NumPy's BLAS on one thread. The controller is made once:
    ``threadpool_limits(1)`` scans every loaded library again on each call. The small
    dense products and solves of a calibration (a few hundred unknowns) take milliseconds
    on one thread and tens of them on OpenBLAS's pool when the cores are busy."""
    if not _blas:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:  # pragma: no cover - a declared dependency
            _blas.append(None)
        else:
            _blas.append(ThreadpoolController())
    if _blas[0] is None:  # pragma: no cover
        import contextlib

        return contextlib.nullcontext()
    return _blas[0].limit(limits=1, user_api="blas")


def small_solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.solve`` on one BLAS thread: a levels x levels system solves in a few
    milliseconds alone, but several times slower on OpenBLAS's thread pool, more so on a
    machine whose cores are busy decoding and fusing (measured 4.5 ms vs 41 ms, 256 x 256)."""
    with one_blas_thread():
        return np.linalg.solve(a, b)


#: Samples per block when the eliminated ln E unknowns are folded into the curve's
#: system: bounds the temporary outer products to about 16 MB whatever --samples is.
SCHUR_BLOCK_ENTRIES = 1 << 21


def _curve_normal_equations(seg, a0, a1, w, wb, k, interior, wk):
    """The curve's normal equations with every sample's ln E eliminated, built densely.

    Row (i, j) of the least-squares system reads ``a0 g[seg] + a1 g[seg+1] - w lnE_i =
    wb`` (``a0 + a1 = w``). In the normal equations ``[[G, B], [B^T, D]] [g; lnE] =
    [u; e]`` each ln E_i appears only in its own sample's rows, so D is diagonal and the
    Schur complement ``(G - B D^-1 B^T) g = u - B D^-1 e`` is exact: the same solution as
    the whole system. G, B D^-1 B^T and the right side are sums of a few products per
    sample, accumulated with ``bincount`` (no sparse matrices, no scipy import: a small
    set's start-up does not pay for scipy.sparse). All inputs are (N, P) arrays; a
    sample-frame with ``w = 0`` adds nothing.
    """
    kk = k * k
    d1 = k + 1
    g = (np.bincount((seg * d1).ravel(), (a0 * a0).ravel(), kk)
         + np.bincount((seg * d1 + 1).ravel(), (a0 * a1).ravel(), kk)
         + np.bincount((seg * d1 + k).ravel(), (a1 * a0).ravel(), kk)
         + np.bincount(((seg + 1) * d1).ravel(), (a1 * a1).ravel(), kk))
    cols = np.stack([interior - 1, interior, interior + 1])
    vals = np.stack([wk, -2.0 * wk, wk])
    g += np.bincount((cols[:, None, :] * k + cols[None, :, :]).ravel(),
                     (vals[:, None, :] * vals[None, :, :]).ravel(), kk)
    g[(k // 2) * d1] += 1.0  # the constraint row g(mid knot) = 0
    d = (w * w).sum(axis=1)
    d[d <= 0] = 1.0  # a sample with no usable measurement: its ln E is free (pinned to 0)
    e = -(w * wb).sum(axis=1)
    idx = np.concatenate([seg, seg + 1], axis=1)  # B's entries: (knot, -w a) per sample
    val = np.concatenate([-w * a0, -w * a1], axis=1)
    u = np.bincount(seg.ravel(), (a0 * wb).ravel(), k) + np.bincount((seg + 1).ravel(), (a1 * wb).ravel(), k)
    rhs = u - np.bincount(idx.ravel(), (val * (e / d)[:, None]).ravel(), k)
    step = max(1, SCHUR_BLOCK_ENTRIES // max(1, idx.shape[1] ** 2))
    for s0 in range(0, idx.shape[0], step):
        ib, vb, db = idx[s0:s0 + step], val[s0:s0 + step], d[s0:s0 + step]
        g -= np.bincount((ib[:, :, None] * k + ib[:, None, :]).ravel(),
                         (vb[:, :, None] * (vb / db[:, None])[:, None, :]).ravel(), kk)
    return g.reshape(k, k), rhs


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
        Weighting function name (:mod:`hdrcl.core.weights`).
    usable : ndarray of bool, shape (N, P), optional
        False drops a sample (invalid pixel in that frame).

    Returns
    -------
    numpy.ndarray
        g at :func:`knot_positions` (float64), shifted so that ``g(levels // 2) = 0``.
    """
    smoothness = _check_smoothness(smoothness, weight)
    levels = 1 << bits
    knots = knot_positions(bits)
    k = knots.size
    z = np.asarray(z, np.float64)
    w = weight_values(z, levels, weight)
    if usable is not None:
        w = np.where(usable, w, 0.0)
    seg, frac = _segments(z, knots)
    lt = np.broadcast_to(np.asarray(log_times, np.float64), z.shape)
    # Data rows: w*g(z) (interpolated between knots) - w*lnE_i = w*ln dt_j; smoothness
    # rows lambda w(z) [1, -2, 1] at interior knots; g(mid knot) = 0 fixes the constant.
    interior = np.arange(1, k - 1)
    wk = smoothness * weight_values(knots[interior], levels, weight)
    schur, rhs = _curve_normal_equations(seg, w * (1.0 - frac), w * frac, w, w * lt, k, interior, wk)
    try:
        g = small_solve(schur, rhs)
    except np.linalg.LinAlgError:
        raise ProcessingError("the response solve is singular (the samples leave some code levels free); "
                              "give more --smoothness or frames with more detail") from None
    if not np.all(np.isfinite(g)):
        raise ProcessingError("the response solve did not converge (non-finite curve); "
                              "give a --smoothness between 0.001 and 1e6")
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
    warn: bool = True,
    candidates=None,
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
        Number of pixels; default :func:`hdrcl.core.sampling.default_sample_count`.
    smoothness, weight, seed, decimate
        See :func:`solve_curve` and :func:`hdrcl.core.sampling.select_samples`.
    warn : bool
        Log the curve's problems (they are in ``Response.warnings`` either way); off for
        the internal re-solves of the quality figures.
    candidates : hdrcl.core.sampling.SampleCandidates, optional
        The frames' :func:`hdrcl.core.sampling.sample_candidates`, made once when the
        caller samples them more than once (:func:`hdrcl.core.calibrate.calibrate`).

    Returns
    -------
    Response
    """
    from hdrcl.core.sampling import default_sample_count, select_samples

    from hdrcl.core.params import check_options

    o = check_options(samples=samples, smoothness=smoothness, seed=seed, weight=weight)
    samples, smoothness, seed = o["samples"], o["smoothness"], o["seed"]
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
    idx = select_samples(frames, valid, n, seed=seed, decimate=decimate, candidates=candidates)
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
    return _finish(zs, np.broadcast_to(log_t, zs.shape[:2]), None, bits, smoothness, weight, seed, channels,
                   warn=warn)


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


def _finish(zs, log_t, usable, bits, smoothness, weight, seed, channels, warn: bool = True) -> Response:
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
    if warn:
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
    from hdrcl.core.sampling import default_sample_count, select_samples

    from hdrcl.core.params import check_options

    o = check_options(samples=samples, smoothness=smoothness, seed=seed, weight=weight)
    samples, smoothness, seed = o["samples"], o["smoothness"], o["seed"]
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
