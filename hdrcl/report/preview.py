"""Small tone-mapped previews of radiance maps (``hdrcl batch`` writes one per set).

A preview is for looking through a shoot, not for grading: the radiance map is
reduced by area averaging to a long side of at most ``size`` pixels, tone-mapped with
Reinhard et al.'s global operator on luminance (SIGGRAPH 2002, eq. 1-4)::

    Lw_avg = exp(mean(ln(eps + Lw)))            log-average ("key") of the scene
    L      = a / Lw_avg * Lw                    a = 0.18: the average maps to mid grey
    Ld     = L (1 + L / Lwhite^2) / (1 + L)     Lwhite: the 99.9th percentile of L
    RGBd   = RGBw * Ld / Lw

and sRGB-encoded to 8 bits (``hdrcl batch --tonemap`` chooses another operator of
:mod:`hdrcl.report.tonemap`). Everything is float64 NumPy on a few hundred thousand
pixels at most, so it costs little next to the merge, and is deterministic: the same
radiance map always gives the same bytes.
"""
from __future__ import annotations

import numpy as np

__all__ = ["DEFAULT_SIZE", "downscale", "AreaAverage", "tone_map", "encode", "preview"]

#: Long side of a preview in pixels.
DEFAULT_SIZE = 512
#: Reinhard's "key": the log-average luminance is mapped to this.
KEY = 0.18
#: Rec.709 luminance weights (linear RGB).
_LUMA = np.array([0.2126, 0.7152, 0.0722])


def _bin_edges(n: int, m: int) -> np.ndarray:
    """Start index of each of ``m`` nearly equal bins covering ``range(n)``."""
    return (np.arange(m, dtype=np.int64) * n) // m


def _out_size(h: int, w: int, size: int) -> tuple:
    scale = min(1.0, max(1, int(size)) / max(h, w))
    return max(1, int(round(h * scale))), max(1, int(round(w * scale)))


def downscale(image: np.ndarray, size: int = DEFAULT_SIZE) -> np.ndarray:
    """Area-average ``image`` ``(H, W, C)`` so that its long side is at most ``size``.

    Each output pixel is the mean of a block of input pixels (blocks differ by at most
    one row or column when the factor is not whole). Images already small enough are
    returned as float64 copies, never enlarged.
    """
    img = np.asarray(image, np.float64)
    if img.ndim == 2:
        img = img[:, :, None]
    h, w, c = img.shape
    acc = AreaAverage(h, w, c, size)
    acc.write_rows(0, h, img)
    return acc.result()


class AreaAverage:
    """:func:`downscale` of an image that arrives in strips, top to bottom.

    A sink for :func:`hdrcl.core.pipeline.stream_merge`: ``write_rows(y0, y1, strip)``
    adds each strip to its blocks, so a preview costs one small array whatever the
    image size.
    """

    def __init__(self, height: int, width: int, nch: int, size: int = DEFAULT_SIZE):
        oh, ow = _out_size(height, width, size)
        re, self._cols = _bin_edges(height, oh), _bin_edges(width, ow)
        self._row_bin = np.searchsorted(re, np.arange(height), side="right") - 1
        self._sum = np.zeros((oh, ow, nch), np.float64)
        rh = np.diff(np.append(re, height)).astype(np.float64)
        cw = np.diff(np.append(self._cols, width)).astype(np.float64)
        self._area = rh[:, None, None] * cw[None, :, None]

    def write_rows(self, y0: int, y1: int, data: np.ndarray) -> None:
        cols = np.add.reduceat(np.asarray(data, np.float64), self._cols, axis=1)
        bins = self._row_bin[y0:y1]
        starts = np.flatnonzero(np.r_[True, bins[1:] != bins[:-1]])
        self._sum[bins[starts]] += np.add.reduceat(cols, starts, axis=0)

    def result(self) -> np.ndarray:
        """The block means, ``(h, w, C)`` float64."""
        return self._sum / self._area


def tone_map(radiance: np.ndarray) -> np.ndarray:
    """Reinhard global tone map of linear radiance to display-linear values in [0, 1]
    (:func:`hdrcl.report.tonemap.display_global` with the scene's own statistics).

    Parameters
    ----------
    radiance : ndarray, (H, W, C)
        C = 1 (grey) or 3 (linear Rec.709 RGB). NaN and negative values count as 0.

    Returns
    -------
    ndarray, (H, W, C) float64
    """
    from hdrcl.report.tonemap import display_global, statistics

    rad = np.asarray(radiance, np.float64)
    if rad.ndim == 2:
        rad = rad[:, :, None]
    return display_global(rad, statistics(rad, "reinhard"))


def encode(small: np.ndarray, operator: str = "reinhard") -> np.ndarray:
    """Tone-map an already reduced radiance map with ``operator`` and encode it as sRGB
    ``uint8`` (the float64 NumPy path: deterministic, the same bytes every time)."""
    from hdrcl.report.tonemap import tone_map_array

    rad = np.asarray(small, np.float64)
    if rad.ndim == 2:
        rad = rad[:, :, None]
    return tone_map_array(rad, operator)


def preview(radiance: np.ndarray, size: int = DEFAULT_SIZE, operator: str = "reinhard") -> np.ndarray:
    """An sRGB 8-bit preview of ``radiance``, long side at most ``size`` pixels, tone-mapped
    with ``operator`` (:mod:`hdrcl.report.tonemap`).

    Returns
    -------
    ndarray, (h, w, C) uint8
        C = 1 or 3 as the input (grey stays grey).
    """
    return encode(downscale(radiance, size), operator)
