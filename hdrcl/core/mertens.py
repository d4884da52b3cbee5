"""Exposure fusion (Mertens, Kautz & Van Reeth 2007): the float64 NumPy twin of
``kernels/mertens.cl`` and the public :func:`exposure_fusion`.

The equations are OpenCV's ``MergeMertens`` (``photo/src/merge.cpp``), written out so
that the result matches it to float rounding. Each frame ``I_k`` (RGB in [0, 1]: codes /
255 or / 65535) gets a weight per pixel::

    C_k = |L * grey(I_k)|                   L = [0 1 0; 1 -4 1; 0 1 0], border reflect-101,
                                             grey = 0.299 R + 0.587 G + 0.114 B (L of each
                                             channel's codes, exact: :func:`laplacian`)
    S_k = sqrt(sum_c (I_kc - mean_c I_k)^2)  (not divided by the channel count; grey: 1)
    E_k = prod_c exp(-(I_kc - 0.5)^2 / (2 sigma^2))          sigma = 0.2
    W_k = C_k^wc * S_k^ws * E_k^we + 1e-12,  V_k = W_k / sum_j W_j

(``valid`` masks set ``C S E`` to 0 where a frame is invalid: its 1e-12 remains). The
result is the collapsed pyramid ``R = sum_l up^l( sum_k Lap_l(I_k) * G_l(V_k) )`` with
OpenCV's ``pyrDown`` (5x5 [1 4 6 4 1]/16, reflect-101, ``(n + 1) // 2``), its ``pyrUp``
(zero-stuffed reflect-101 of length 2n, kernel x 4) and ``int(log2(min(h, w)))`` levels
above the finest. Float32 ``(H, W, C)``, about [0, 1] but not clipped (as OpenCV's).

The pyramid's coarse levels span the whole image, so bounded memory needs more than
strips: :mod:`hdrcl.core.mertens_bands` runs the fusion in horizontal bands with a halo
(exact, not an approximation); see its docstring.
"""
from __future__ import annotations

import os

import logging
from dataclasses import dataclass
from typing import List, Optional, Sequence

import numpy as np

from hdrcl.core.pyramids import blend, gaussian, level_size, max_level, pyr_down, pyr_up, reflect101, tops
from hdrcl.errors import UsageError

__all__ = ["FusionWeights", "NumpyFusion", "backend", "blend", "exposure_fusion", "gaussian", "laplacian",
           "level_size", "max_level", "normalised_weights", "pyr_down", "pyr_up", "reflect101", "saturation",
           "to_codes", "to_unit", "tops", "weights"]

logger = logging.getLogger(__name__)

#: OpenCV's RGB2GRAY coefficients (R, G, B).
GREY = (0.299, 0.587, 0.114)
#: Added to every weight (as OpenCV does) so that a pixel with no weight anywhere is the mean.
EPS = 1e-12


@dataclass(frozen=True)
class FusionWeights:
    """The exponents of the three measures and the well-exposedness width.

    ``contrast``, ``saturation``, ``exposedness`` : float >= 0 (OpenCV's ``contrast_weight``,
    ``saturation_weight``, ``exposure_weight``; 0 turns a measure off). ``sigma`` > 0, in
    the [0, 1] units of the frames.
    """

    contrast: float = 1.0
    saturation: float = 1.0
    exposedness: float = 1.0
    sigma: float = 0.2

    def __post_init__(self):
        for name in ("contrast", "saturation", "exposedness"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.floating, np.integer)) and np.isfinite(v) and 0 <= v <= 100):
                raise UsageError(f"--{name}: the exponent must be a number from 0 to 100, not {v!r}")
        if not (isinstance(self.sigma, (int, float, np.floating)) and np.isfinite(self.sigma) and 0 < self.sigma <= 10):
            raise UsageError(f"sigma: the well-exposedness width must be above 0 and at most 10, not {self.sigma!r}")


def to_unit(frame: np.ndarray) -> np.ndarray:
    """Frame codes as float64 in [0, 1]: uint8 / 255, uint16 / 65535, floats as given."""
    f = np.asarray(frame)
    if f.dtype == np.uint8:
        return f.astype(np.float64) / 255.0
    if f.dtype == np.uint16:
        return f.astype(np.float64) / 65535.0
    return f.astype(np.float64)


def laplacian(frame: np.ndarray) -> np.ndarray:
    """4-neighbour Laplacian of the grey of ``frame``'s codes, in [0, 1] units: of
    ``1000 grey = 299 R + 587 G + 114 B`` in integers for integer codes (exact: a flat or
    linear ramp of codes has exactly no contrast), then scaled."""
    f = np.asarray(frame)
    h, w, c = f.shape
    codes = f.astype(np.int64) if f.dtype.kind == "u" else f.astype(np.float64)
    g = 1000 * codes[..., 0] if c == 1 else 299 * codes[..., 0] + 587 * codes[..., 1] + 114 * codes[..., 2]
    ry, rx = reflect101(np.arange(-1, h + 1), h), reflect101(np.arange(-1, w + 1), w)
    gg = g[ry][:, rx]
    lap = gg[:-2, 1:-1] + gg[2:, 1:-1] + gg[1:-1, :-2] + gg[1:-1, 2:] - 4 * g
    return lap * ((to_unit(np.ones(1, f.dtype))[0] if f.dtype.kind == "u" else 1.0) / 1000.0)


def saturation(frame: np.ndarray) -> np.ndarray:
    """``sqrt(sum_c (I_c - mean)^2)`` in [0, 1] units, as ``(3 sum c^2 - (sum c)^2) / 3`` of
    integer codes (exact: a grey pixel has exactly none)."""
    f = np.asarray(frame)
    if f.dtype.kind != "u":
        img = f.astype(np.float64)
        return np.sqrt(((img - img.mean(axis=2, keepdims=True)) ** 2).sum(axis=2))
    c = f.astype(np.int64)
    s1 = c.sum(axis=2)
    return np.sqrt((3 * (c * c).sum(axis=2) - s1 * s1) / 3.0) * to_unit(np.ones(1, f.dtype))[0]


def weights(frame: np.ndarray, fw: FusionWeights, valid: Optional[np.ndarray] = None) -> np.ndarray:
    """``W_k`` of one frame of codes ``(h, w, c)`` (float64 ``(h, w)``, with the 1e-12)."""
    img = to_unit(frame)
    c = img.shape[2]
    out = np.abs(laplacian(frame)) ** fw.contrast
    if c == 3:
        out = out * saturation(frame) ** fw.saturation
    wexp = np.exp(-((img - 0.5) ** 2).sum(axis=2) / (2.0 * fw.sigma ** 2))  # = prod_c exp(...)
    out = out * wexp ** fw.exposedness
    if valid is not None:
        out = np.where(np.asarray(valid, bool), out, 0.0)
    return out + EPS


def normalised_weights(frames: Sequence[np.ndarray], fw: FusionWeights,
                       valid: Optional[Sequence[Optional[np.ndarray]]] = None) -> List[np.ndarray]:
    """``V_k = W_k / sum_j W_j`` of every frame (codes)."""
    ws = [weights(f, fw, None if valid is None else valid[k]) for k, f in enumerate(frames)]
    total = np.sum(ws, axis=0)
    return [wk / total for wk in ws]


class NumpyFusion:
    """The twin as a band backend (:mod:`hdrcl.core.mertens_bands`): frames' codes in,
    float results out, float64 inside."""

    name = "NumPy (reference path)"

    def tops(self, frames, valid, fw: FusionWeights, levels: int):
        imgs = [to_unit(f) for f in frames]
        vs = normalised_weights(frames, fw, valid)
        gi, gv = tops(imgs, vs, levels)
        return [g.astype(np.float32) for g in gi], [g.astype(np.float32) for g in gv]

    def blend(self, frames, valid, fw: FusionWeights, levels: int, top=None, rows=None) -> np.ndarray:
        imgs = [to_unit(f) for f in frames]
        vs = normalised_weights(frames, fw, valid)
        out = blend(imgs, vs, levels, top)
        return (out if rows is None else out[rows[0]:rows[1]]).astype(np.float32)


def exposure_fusion(frames, valid=None, contrast: float = 1.0, saturation: float = 1.0,
                    exposedness: float = 1.0, device: Optional[str] = None, sigma: float = 0.2,
                    band_rows: Optional[int] = None) -> np.ndarray:
    """Fuse a bracket into one display image (Mertens et al. 2007), as OpenCV's MergeMertens.

    Parameters
    ----------
    frames : sequence of ndarray
        Two or more frames of one size, ``(H, W, 3)`` or ``(H, W)``/``(H, W, 1)``, uint8,
        uint16 or float in [0, 1]; RGB order (the grey uses 0.299 R + 0.587 G + 0.114 B).
    valid : sequence of bool ndarray (H, W) or None, optional
        Per-frame masks: an invalid pixel weighs nothing in that frame.
    contrast, saturation, exposedness : float
        Exponents of the three measures (0: the measure is off).
    device : str, optional
        OpenCL device (``--device``); the NumPy twin runs where OpenCL is off or missing.
    sigma : float
        Width of the well-exposedness Gaussian, in [0, 1] units.
    band_rows : int, optional
        Rows per band (memory bound); None: the whole image if its working set fits
        :data:`hdrcl.core.mertens_bands.WHOLE_BYTES`, else bands of
        :data:`~hdrcl.core.mertens_bands.BAND_BYTES`.

    Returns
    -------
    ndarray
        float32 ``(H, W, C)``, about [0, 1], not clipped (scale by 255 and clip for 8 bits).
    """
    from hdrcl.core.mertens_bands import ArraySource, fuse_bands

    src = ArraySource(frames, valid)
    fw = FusionWeights(float(contrast), float(saturation), float(exposedness), float(sigma))
    out = None
    for r0, r1, rows in fuse_bands(src, fw, backend(device, src.height * src.width * src.count), band_rows):
        if r0 == 0 and r1 == src.height:
            return rows  # the whole image at once: no copy
        if out is None:
            out = np.empty((src.height, src.width, src.channels), np.float32)
        out[r0:r1] = rows
    return out


def backend(device: Optional[str] = None, work: Optional[int] = None):
    """The OpenCL processor of ``kernels/mertens.cl``, else the NumPy twin."""
    from hdrcl.cl.backend import get_processor

    proc = get_processor("mertens", device, work=work)
    return NumpyFusion() if proc is None else proc


def read_frames(paths, ignore_color=None):
    """``(frames, valid)`` of the files ``paths`` as exposure fusion takes them: decoded
    whole, alpha and ``ignore_color`` (R, G, B in 8-bit units) marking pixels that weigh
    nothing (``valid`` None when every pixel counts)."""
    from hdrcl.core.bracket import parse_ignore_color, with_ignore
    from hdrcl.io.frames import read_images

    images = read_images([os.fspath(p) for p in paths])
    frames = [im.pixels for im in images]
    valid = [im.valid for im in images]
    del images
    rgb = parse_ignore_color(ignore_color)
    if rgb is not None:
        valid = with_ignore(frames, valid, rgb)
    return frames, (None if all(v is None for v in valid) else valid)


def to_codes(fused: np.ndarray, bits: int = 8) -> np.ndarray:
    """Fused float image to 8- or 16-bit codes: ``clip(round(x * max))``."""
    top = 255 if bits == 8 else 65535
    x = np.nan_to_num(np.asarray(fused, np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    return np.clip(np.rint(x * np.float32(top)), 0, top).astype(np.uint8 if bits == 8 else np.uint16)
