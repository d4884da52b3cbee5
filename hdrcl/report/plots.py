"""Report pictures: the response curves and the luminance histogram as SVG charts
(:mod:`hdrcl.report.svg`), the coverage map as a raster image.
"""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from hdrcl.core.reference import monotone_tables
from hdrcl.core.response import Response
from hdrcl.report.clipping import NO_DATA, WORKING_HIGH, WORKING_LOW
from hdrcl.report.svg import Chart

#: Long side of the preview and of the coverage map, in pixels.
IMAGE_SIZE = 512
#: Curve colours per channel name (grey curves: dark grey).
CURVE_COLOURS = {"R": "#cd2828", "G": "#1e9632", "B": "#2850d2"}
GREY_CURVE = "#3c3c3c"
#: Rec.709 luminance weights (linear RGB).
LUMA = np.array([0.2126, 0.7152, 0.0722])


def response_svg(response: Response, width: int = 560, height: int = 360) -> str:
    """The response curves ``g(z) = ln exposure`` per channel, as an SVG document.

    x: pixel code z from 0 to ``Zmax``; y: ``g(z)``; the codes outside the working range
    (below 10, above 245 in 8-bit units) are shaded.
    """
    tables = response.tables()
    levels = response.levels
    finite = tables[np.isfinite(tables)]
    gmin, gmax = (float(finite.min()), float(finite.max())) if finite.size else (-1.0, 1.0)
    pad = 0.04 * max(gmax - gmin, 1e-6)
    top = levels - 1
    chart = Chart("Response curves", "pixel code z (shaded: outside the working range)",
                  "g(z) = ln exposure", (0.0, float(top)), (gmin - pad, gmax + pad), width, height,
                  xticks=[min(q * levels // 4, top) for q in range(5)])
    scale = top / 255.0
    chart.span(0, WORKING_LOW * scale)
    chart.span(WORKING_HIGH * scale, top)
    names = list(response.channels)[:tables.shape[0]]
    step = max(1, levels // 1024)  # 16-bit curves: at most about 1000 points each
    z = np.arange(0, levels, step, dtype=np.float64)
    for c in range(tables.shape[0]):
        colour = CURVE_COLOURS.get(names[c].upper(), GREY_CURVE) if tables.shape[0] > 1 else GREY_CURVE
        chart.line(z, tables[c][::step], colour, label=names[c] if tables.shape[0] > 1 else None)
    return chart.svg(desc="Recovered camera response per channel (Debevec & Malik 1997).")


def _luminance(rgb: np.ndarray) -> np.ndarray:
    a = np.asarray(rgb, np.float64)
    if a.ndim == 1:
        return float(a @ LUMA) if a.size == 3 else float(a[0])
    return a[..., 0] if a.shape[-1] == 1 else a[..., :3] @ LUMA


def clip_points(response: Response, times: Sequence[float], nch: int) -> tuple:
    """Luminance below which no frame measures a pixel (the longest frame at the noise
    floor) and above which every frame clips (the shortest frame at the clip level), in
    the radiance map's units: ``exp(g(lo)) / t_max`` and ``exp(g(hi)) / t_min`` per
    channel with ``(lo, hi)`` = :func:`hdrcl.core.weights.clip_levels` (8-bit: 5 and
    250, the levels fusion uses), combined as Rec.709 luminance."""
    from hdrcl.core.weights import clip_levels

    g = monotone_tables(response.table_for(nch))
    lo, hi = clip_levels(g.shape[1])
    t = np.asarray(times, np.float64)
    low = np.exp(g[:, lo]) / float(t.max())
    high = np.exp(g[:, hi]) / float(t.min())
    return _luminance(low), _luminance(high)


def histogram_svg(radiance: np.ndarray, response: Optional[Response], times: Optional[Sequence[float]],
                  width: int = 560, height: int = 300, bins_per_stop: int = 4) -> str:
    """Histogram of log2 luminance of ``radiance`` (share of pixels per bin, %), with
    the clip points of :func:`clip_points` marked, as an SVG document."""
    rad = np.asarray(radiance, np.float64)
    if rad.ndim == 2:
        rad = rad[..., None]
    lum = _luminance(rad).ravel()
    pos = lum[np.isfinite(lum) & (lum > 0)]
    marks = []
    if response is not None and times is not None and len(times):
        lo, hi = clip_points(response, times, rad.shape[2])
        marks = [(np.log2(lo), "no frame reads below", "#2850d2"), (np.log2(hi), "every frame clips above", "#cd2828")]
    if pos.size:
        l2 = np.log2(pos)
        x0, x1 = np.floor(np.percentile(l2, 0.01)) - 1, np.ceil(np.percentile(l2, 99.99)) + 1
    else:
        l2, x0, x1 = np.zeros(0), -1.0, 1.0
    for x, _label, _c in marks:
        if np.isfinite(x):
            x0, x1 = min(x0, np.floor(x) - 1), max(x1, np.ceil(x) + 1)
    edges = np.arange(x0, x1 + 1e-9, 1.0 / bins_per_stop)
    counts, _ = np.histogram(l2, bins=edges)
    share = 100.0 * counts / max(lum.size, 1)
    ymax = max(float(share.max()) * 1.1 if share.size else 1.0, 1e-3)
    chart = Chart("Luminance histogram", "log2 luminance (stops, relative units)", "% of pixels",
                  (float(x0), float(x1)), (0.0, ymax), width, height)
    chart.bars(edges, share, "#7a7a7a")
    zero = lum.size - pos.size
    for x, label, colour in marks:
        chart.marker(float(x), label, colour)
    desc = f"{pos.size} pixels with positive luminance" + (f", {zero} at zero" if zero else "")
    return chart.svg(desc=desc)


# Coverage colours: 0 frames (clipped) red, 1 frame orange, then light to dark blue-green.
_COV_ZERO = (215, 25, 28)
_COV_ONE = (253, 174, 97)
_COV_RAMP = ((199, 233, 180), (65, 182, 196), (34, 94, 168), (8, 29, 88))
_COV_NODATA = (150, 150, 150)


def coverage_colours(frames: int) -> np.ndarray:
    """Colour table ``(256, 3)`` uint8 for coverage values 0..frames and NO_DATA."""
    lut = np.zeros((256, 3), np.uint8)
    lut[:] = _COV_NODATA
    lut[0] = _COV_ZERO
    if frames >= 1:
        lut[1] = _COV_ONE
    n = max(frames - 1, 0)
    ramp = np.asarray(_COV_RAMP, np.float64)
    for i in range(n):
        t = i / max(n - 1, 1) * (len(ramp) - 1)
        k = min(int(t), len(ramp) - 2)
        lut[2 + i] = np.round(ramp[k] + (t - k) * (ramp[k + 1] - ramp[k])).astype(np.uint8)
    return lut


def _block_min(a: np.ndarray, size: int) -> np.ndarray:
    """Reduce ``a`` (H, W) to a long side of at most ``size`` by the minimum of each block,
    so an isolated clipped (0) pixel stays visible; NO_DATA (255) loses to any count."""
    h, w = a.shape
    k = max(1, int(np.ceil(max(h, w) / max(size, 1))))
    if k == 1:
        return a
    hh, ww = -(-h // k), -(-w // k)
    pad = np.full((hh * k, ww * k), NO_DATA, a.dtype)
    pad[:h, :w] = a
    return pad.reshape(hh, k, ww, k).min(axis=(1, 3))


def coverage_image(coverage: np.ndarray, frames: int, size: int = IMAGE_SIZE) -> np.ndarray:
    """The coverage map colour-mapped (:func:`coverage_colours`), RGB uint8.

    Reduced to a long side of at most ``size`` by block minimum (the worst pixel of each
    block shows) and enlarged by whole factors when small. Its legend is HTML on the
    report page (:func:`coverage_legend`).
    """
    cov = _block_min(np.asarray(coverage, np.uint8), size)
    h, w = cov.shape
    k = max(1, min(size // max(h, w), 8))
    cov = np.repeat(np.repeat(cov, k, axis=0), k, axis=1)
    return coverage_colours(frames)[cov]


def coverage_legend(frames: int, no_data: bool = False) -> list:
    """``(label, "#rrggbb")`` per coverage value shown by :func:`coverage_image`."""
    lut = coverage_colours(frames)
    values = list(range(frames + 1)) + ([NO_DATA] if no_data else [])
    out = []
    for v in values:
        label = "no data" if v == NO_DATA else ("0 (clipped)" if v == 0 else str(v))
        out.append((label, "#%02x%02x%02x" % tuple(int(c) for c in lut[v])))
    return out
