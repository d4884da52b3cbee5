"""Measures of how well a merge explains its own photographs, and what it missed.

:func:`measure` gathers the figures of the quality report (:mod:`hdrcl.report`) for one
merge: leave-one-out error, dynamic range, the pixels no frame measured (clipped high
or low), how much more exposure range would have caught them, and a coverage map.

Definitions
-----------
Definitions, with ``L`` levels, ``Zmax = L - 1`` and frames ordered by exposure:

* A frame *measures* a pixel-channel when fusion takes evidence from it
  (:func:`hdrcl.core.reference.fuse`): the pixel is valid in that frame, its code
  lies strictly between the clip levels ``(lo, hi)`` of
  :func:`hdrcl.core.weights.clip_levels` (8-bit: 5 and 250, not merely 0 and 255:
  JPEG highlights clip anywhere in 250..255) with non-zero weight, no shorter valid
  frame reads ``>= hi`` and no longer one ``<= lo``. **coverage** of a pixel is the
  number of frames that measure its least-measured channel; :data:`NO_DATA` (255)
  where the pixel is valid in no frame.
* A pixel-channel that no frame measures is **clipped high** when its shortest valid
  frame reads ``>= hi``, else **clipped low** when its longest valid frame reads
  ``<= lo``, else (frames that contradict each other) high when the shortest valid
  frame reads in the upper half (``2 Z >= L``): the rule fusion uses to fill it. A
  pixel is clipped high (low) when any of its channels is; the fractions are over
  the pixels valid in at least one frame. So coverage 0 means clipped high or low.
* **extra_ev_high**: a clipped-high pixel-channel reads ``Z_s >= hi`` in its
  shortest valid frame ``s``, so ``ln E + ln t_s >= g(Z_s)``: fusion's
  ``g(Z_s) - ln t_s`` is a lower bound on ``ln E``, and nothing in the frames bounds
  it from above. A frame of time ``t`` reads it within the working range only if
  ``ln E + ln t <= g(Z_top)``, with ``Z_top = 245`` (8-bit). Hence
  ``log2(t / t_shortest) <= log2(t_s / t_shortest) - (g(Z_s) - g(Z_top)) / ln 2``;
  the minimum of that bound over the clipped pixel-channels is reported. It is
  honest but optimistic: the true change needed is at least this large, and may be
  far larger (the sun). ``g`` is taken non-decreasing, as for rendering.
* **extra_ev_low**, the mirror image: a clipped-low pixel-channel reads
  ``Z_l <= lo`` in its longest valid frame ``l``, so ``ln E <= g(Z_l) - ln t_l``,
  and a frame reads it at ``Z_bot = 10`` or above only if ``log2(t / t_longest) >=
  log2(t_l / t_longest) + (g(Z_bot) - g(Z_l)) / ln 2``; the maximum over the
  clipped pixel-channels. Pixel-channels filled by the contradiction rule prove no
  bound and are left out of both.
* **dynamic_range_stops**: :func:`dynamic_range_stops` of ``radiance``, 0.1th to
  99.9th percentile. Clipped pixels enter at their fusion bounds, so when more than
  0.1 % are clipped it is flagged as a lower bound.
* **loo_rmse**: :func:`hdrcl.report.leaveoneout.leave_one_out_all` (interior frames, each rendered from a
  response calibrated on the others) on :func:`decimate`'s grid, with the merge's
  exposures, weighting and smoothness and no refitting of exposures; the median
  over the interior frames.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import List, Optional, Tuple

import numpy as np

from hdrcl.core.bracket import Bracket
from hdrcl.core.calibrate import exposures_used
from hdrcl.core.response import Response
from hdrcl.errors import UsageError
from hdrcl.report.clipping import NO_DATA, WORKING_HIGH, WORKING_LOW, clipping_figures
from hdrcl.report.leaveoneout import LeaveOneOut, leave_one_out_all
from hdrcl.report.leaveoneout import leave_one_out  # noqa: F401  (named here by docs/api.md before issue 33)
from hdrcl.report.memory import release_free_memory
from hdrcl.report.verdicts import verdicts_dict
from hdrcl.report.preview import (
    _LUMA,  # Rec.709 luminance weights, as the preview's tone map
)

#: Percentiles of positive luminance whose ratio is the dynamic range.
DR_PERCENTILES = (0.1, 99.9)
#: Leave-one-out runs on every k-th row and column, k chosen so a frame has at most this
#: many pixels: the error is a statistic over pixels, and decimation keeps it cheap on
#: 24-megapixel frames (five calibrations and merges for a 7-frame set).
LOO_MAX_PIXELS = 500_000
#: Value of :attr:`QualityFigures.coverage` for a pixel that is valid in no frame.


def report_stride(height: int, width: int, max_pixels: int = LOO_MAX_PIXELS) -> int:
    """k = ceil(sqrt(pixels / max_pixels)): every k-th row and column of a
    ``height`` x ``width`` frame is about ``max_pixels`` pixels at most. The quality
    report measures every figure but the dynamic range on that grid (see :func:`measure`)."""
    return max(1, int(math.ceil(math.sqrt(int(height) * int(width) / max(int(max_pixels), 1)))))


def decimate(bracket: Bracket, max_pixels: int = LOO_MAX_PIXELS) -> Tuple[Bracket, int]:
    """Every k-th row and column of ``bracket``, k = :func:`report_stride`: about
    ``max_pixels`` pixels at most.

    Returns the decimated bracket (the original when k = 1) and k.
    """
    h, w = bracket.frames[0].shape[:2]
    k = report_stride(h, w, max_pixels)
    if k == 1:
        return bracket, 1
    frames = [np.ascontiguousarray(f[::k, ::k]) for f in bracket.frames]
    valid = [None if v is None else np.ascontiguousarray(v[::k, ::k]) for v in bracket.valid]
    return Bracket(frames=frames, times=np.asarray(bracket.times, np.float64), valid=valid,
                   paths=list(bracket.paths), infos=list(bracket.infos), grid=True), k


@dataclass
class QualityFigures:
    """The quality report's figures for one merge (:func:`measure` defines each one).

    Attributes
    ----------
    shape : tuple
        ``(H, W, C)`` of the frames measured.
    frames, bits, weight
        Frame count, bits per sample, weighting function.
    exposures : list of dict
        Per frame, in the bracket's order: ``nominal`` (metadata, relative seconds),
        ``used`` (what the merge used) and ``fitted`` (from the pixels, None unless the
        response was calibrated from this very set with exposure fitting).
    loo_rmse : float or None
        Median over the interior frames of the leave-one-out RMSE, in 8-bit code levels;
        None when not computed (``loo=False``) or fewer than three frames.
    loo : list of LeaveOneOut
        The per-frame errors behind ``loo_rmse``.
    loo_stride : int
        Leave-one-out ran on every ``loo_stride``-th row and column of the frames merged
        (1: every pixel).
    grid_stride : int
        The clipping and coverage figures were measured on every ``grid_stride``-th row
        and column of the frames merged (1: every pixel; see :func:`measure`).
    dynamic_range_stops : float or None
        ``log2(P99.9 / P0.1)`` of the positive luminance of the radiance map.
    dynamic_range_is_lower_bound : bool
        More than 0.1 % of pixels are clipped (high or low), so a percentile sits on a
        clipped pixel's bound and the scene's range is at least this.
    clipped_high_fraction, clipped_low_fraction : float
        Fractions of the pixels valid in some frame that no frame measured, in at least
        one channel, because its frames read at or above the clip level (at or below the
        noise floor) of :func:`hdrcl.core.weights.clip_levels`, as fusion decides.
    clipped_high_pixels, clipped_low_pixels, valid_pixels : int
        The counts behind the fractions.
    extra_ev_high : float
        ``<= 0``. Exposure change relative to the shortest frame that a further frame
        needs *at least* to read every clipped-high pixel within the working range: the
        true change is this or more negative. 0 when nothing is clipped high.
    extra_ev_low : float
        ``>= 0``. Likewise relative to the longest frame for clipped-low pixels: at
        least this many stops more exposure.
    coverage_histogram : list of int
        Pixels with coverage 0, 1, ..., ``frames`` (pixels valid in no frame left out):
        the frames fusion takes evidence from (see :func:`measure`).
    coverage : ndarray (H, W) uint8, optional
        Per pixel, the number of frames that measure it (see :func:`measure`); not
        serialised by :meth:`to_dict`.
    """

    shape: tuple
    frames: int
    bits: int
    weight: str
    exposures: list
    loo_rmse: Optional[float]
    loo: List[LeaveOneOut]
    loo_stride: int
    dynamic_range_stops: Optional[float]
    dynamic_range_is_lower_bound: bool
    clipped_high_fraction: float
    clipped_low_fraction: float
    clipped_high_pixels: int
    clipped_low_pixels: int
    valid_pixels: int
    extra_ev_high: float
    extra_ev_low: float
    coverage_histogram: list
    dynamic_range_percentiles: tuple = DR_PERCENTILES
    working_range: tuple = (WORKING_LOW, WORKING_HIGH)
    grid_stride: int = 1
    coverage: Optional[np.ndarray] = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict:
        """JSON-ready figures (NaN as None, no coverage array)."""

        def num(v):
            return None if v is None or not np.isfinite(v) else float(v)

        return {
            "shape": [int(v) for v in self.shape],
            "frames": int(self.frames),
            "bits": int(self.bits),
            "weight": self.weight,
            "exposures": self.exposures,
            "looRmse": num(self.loo_rmse),
            "looFrames": [{"index": r.index, "time": r.time, "rmse": num(r.rmse), "pixels": r.pixels}
                          for r in self.loo],
            "looStride": int(self.loo_stride),
            "gridStride": int(self.grid_stride),
            "dynamicRangeStops": num(self.dynamic_range_stops),
            "dynamicRangePercentiles": list(self.dynamic_range_percentiles),
            "dynamicRangeIsLowerBound": bool(self.dynamic_range_is_lower_bound),
            "clippedHighFraction": float(self.clipped_high_fraction),
            "clippedLowFraction": float(self.clipped_low_fraction),
            "clippedHighPixels": int(self.clipped_high_pixels),
            "clippedLowPixels": int(self.clipped_low_pixels),
            "validPixels": int(self.valid_pixels),
            "extraEvHigh": float(self.extra_ev_high),
            "extraEvLow": float(self.extra_ev_low),
            "workingRange": list(self.working_range),
            "coverageHistogram": [int(v) for v in self.coverage_histogram],
            # Each verdict with its cause (figure, value, limit); derived, so from_dict ignores it.
            "verdicts": verdicts_dict(self),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "QualityFigures":
        """Inverse of :meth:`to_dict` (without the coverage array)."""

        def num(v):
            return float("nan") if v is None else float(v)

        return cls(
            shape=tuple(d["shape"]), frames=int(d["frames"]), bits=int(d["bits"]), weight=d["weight"],
            exposures=list(d.get("exposures", [])),
            loo_rmse=None if d.get("looRmse") is None else float(d["looRmse"]),
            loo=[LeaveOneOut(int(r["index"]), float(r["time"]), num(r["rmse"]), int(r["pixels"]))
                 for r in d.get("looFrames", [])],
            loo_stride=int(d.get("looStride", 1)), grid_stride=int(d.get("gridStride", 1)),
            dynamic_range_stops=None if d.get("dynamicRangeStops") is None else float(d["dynamicRangeStops"]),
            dynamic_range_is_lower_bound=bool(d.get("dynamicRangeIsLowerBound", False)),
            clipped_high_fraction=float(d["clippedHighFraction"]), clipped_low_fraction=float(d["clippedLowFraction"]),
            clipped_high_pixels=int(d["clippedHighPixels"]), clipped_low_pixels=int(d["clippedLowPixels"]),
            valid_pixels=int(d["validPixels"]), extra_ev_high=float(d["extraEvHigh"]),
            extra_ev_low=float(d["extraEvLow"]), coverage_histogram=list(d.get("coverageHistogram", [])),
            dynamic_range_percentiles=tuple(d.get("dynamicRangePercentiles", DR_PERCENTILES)),
            working_range=tuple(d.get("workingRange", (WORKING_LOW, WORKING_HIGH))),
        )


def dynamic_range_stops(radiance: np.ndarray, percentiles=DR_PERCENTILES) -> Optional[float]:
    """``log2(P_hi / P_lo)`` of the positive, finite luminance of ``radiance``.

    Luminance is Rec.709 (``0.2126 R + 0.7152 G + 0.0722 B``) for colour maps, the
    channel itself for grey ones. Percentiles rather than the extremes make the figure
    robust to a few hot or dead pixels. None when fewer than two pixels are positive.
    """
    rad = np.asarray(radiance)
    if rad.ndim == 2:
        rad = rad[..., None]
    # float32 is ample for a ratio of percentiles and halves the memory of a big map.
    lum = rad[..., 0].astype(np.float32) if rad.shape[2] < 3 else rad[..., :3] @ _LUMA.astype(np.float32)
    pos = lum[lum > 0]  # NaN compares false
    pos = pos[pos < np.inf]
    if pos.size < 2:
        return None
    lo, hi = np.percentile(pos, percentiles).astype(np.float64)
    return float(np.log2(hi / lo)) if lo > 0 else None


def measure(
    bracket: Bracket,
    response: Response,
    radiance: Optional[np.ndarray],
    *,
    weight: Optional[str] = None,
    times=None,
    loo: bool = True,
    loo_max_pixels: int = LOO_MAX_PIXELS,
    device: Optional[str] = None,
    stride: int = 1,
    shape: Optional[tuple] = None,
) -> QualityFigures:
    """The quality report's figures for a merge of ``bracket`` through ``response``.

    Parameters
    ----------
    bracket : Bracket
        The frames that were merged, or every ``stride``-th row and column of them (the
        grid of :func:`report_stride`, as ``hdrcl merge --report`` and ``hdrcl batch
        --report`` measure): then every figure but the dynamic range is on that grid.
    response : Response
        The curve the merge used.
    radiance : ndarray or None
        The merged map, or a decimated copy (``MergeResult.thumbnail``): only its
        luminance percentiles are used. None: no dynamic range.
    weight : str, optional
        The merge's weighting; default ``response.weight``.
    times : sequence of float, optional
        The exposures the merge used; default :func:`hdrcl.core.calibrate.exposures_used`.
    loo : bool
        Compute the leave-one-out error (the costly part: a calibration and a merge per
        interior frame).
    loo_max_pixels : int
        Leave-one-out runs on every k-th row and column, at most this many pixels.
    stride : int
        ``bracket`` holds every ``stride``-th row and column of the frames merged
        (recorded as :attr:`QualityFigures.grid_stride`; ``loo_stride`` counts in the
        frames merged).
    shape : tuple, optional
        ``(H, W, C)`` of the frames merged, recorded as :attr:`QualityFigures.shape`;
        default the bracket's frames' (right unless ``stride > 1``).

    The definitions of every figure are in this module's docstring (*Definitions*).
    """
    weight = weight or response.weight
    frames = bracket.frames
    nominal = np.asarray(bracket.times, np.float64)
    used = exposures_used(response, nominal) if times is None else np.asarray(times, np.float64)
    if used.size != len(frames):
        raise UsageError(f"{used.size} exposure times for {len(frames)} frames")
    if len(frames) >= NO_DATA:
        raise UsageError(f"{len(frames)} frames: the quality figures count at most {NO_DATA - 1}")
    levels = response.levels
    if int(np.iinfo(frames[0].dtype).max) + 1 != levels:
        raise UsageError(f"the response describes {response.bits}-bit images but the frames are "
                         f"{8 * frames[0].dtype.itemsize}-bit")
    h, w, c = frames[0].shape
    release_free_memory()
    coverage, hist, n_high, n_low, n_valid, extra_high, extra_low = clipping_figures(bracket, used, response, weight)

    dr = dynamic_range_stops(radiance) if radiance is not None else None
    tail = (100.0 - DR_PERCENTILES[1]) / 100.0
    frac_high = n_high / n_valid if n_valid else 0.0
    frac_low = n_low / n_valid if n_valid else 0.0

    loo_rows, loo_stride, loo_rmse = _loo(bracket, used, response, weight, device, loo_max_pixels) if loo \
        else ([], 1, None)

    release_free_memory()
    fitted = _fitted_for(response, nominal)
    exposures = [{"nominal": float(n), "used": float(u), "fitted": None if fitted is None else float(f)}
                 for n, u, f in zip(nominal, used, fitted if fitted is not None else nominal)]
    for e, p in zip(exposures, bracket.paths or []):
        e["file"] = os.path.basename(p)
    return QualityFigures(
        shape=tuple(int(v) for v in shape) if shape is not None else (h, w, c), frames=len(frames),
        bits=response.bits, weight=weight, exposures=exposures,
        loo_rmse=loo_rmse, loo=loo_rows, loo_stride=loo_stride * max(1, int(stride)), dynamic_range_stops=dr,
        dynamic_range_is_lower_bound=bool(frac_high > tail or frac_low > tail),
        clipped_high_fraction=float(frac_high), clipped_low_fraction=float(frac_low),
        clipped_high_pixels=n_high, clipped_low_pixels=n_low, valid_pixels=n_valid,
        extra_ev_high=min(extra_high, 0.0), extra_ev_low=max(extra_low, 0.0),
        coverage_histogram=[int(v) for v in hist], grid_stride=max(1, int(stride)), coverage=coverage)


def _loo(bracket: Bracket, used, response: Response, weight: str, device, loo_max_pixels: int):
    """``(rows, stride, median rmse)``: :func:`measure`'s leave-one-out figure."""
    frames = bracket.frames
    loo_rows: List[LeaveOneOut] = []
    stride = 1
    loo_rmse = None
    if len(frames) >= 3:
        sub, stride = decimate(Bracket(frames=list(frames), times=used, valid=list(bracket.valid)), loo_max_pixels)
        loo_rows = leave_one_out_all(sub, weight=weight, smoothness=response.smoothness, device=device,
                                     fit_exposures="off")
        finite = [r.rmse for r in loo_rows if np.isfinite(r.rmse)]
        loo_rmse = float(np.median(finite)) if finite else None

    return loo_rows, stride, loo_rmse


def _fitted_for(response: Response, nominal: np.ndarray) -> Optional[np.ndarray]:
    """The response's fitted exposures when it was calibrated from this very set."""
    ex = response.exposures or []
    if len(ex) != nominal.size or not all(e.get("fitted") is not None for e in ex):
        return None
    if not np.allclose([e.get("nominal", np.nan) for e in ex], nominal, rtol=1e-9):
        return None
    return np.asarray([e["fitted"] for e in ex], np.float64)
