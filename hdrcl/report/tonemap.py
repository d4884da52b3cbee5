"""Tone mapping: radiance maps to sRGB-encoded 8- or 16-bit pictures.

Four operators, chosen by name (:data:`OPERATORS`); each maps linear Rec.709 radiance
to display-linear values in [0, 1], which are then sRGB-encoded (IEC 61966-2-1) and
rounded to the output depth. ``exposure`` (EV) scales the scene before the operator.
Luminance is Rec.709, ``Lw = 0.2126 R + 0.7152 G + 0.0722 B`` (the channel itself for
grey maps); the scene statistics (log-average, white point) are taken on every k-th
row and column, k chosen so at most :data:`STATS_MAX_PIXELS` pixels are read, so
they cost little on large maps and are the same on both paths.

``reinhard``
    Reinhard et al. 2002, global operator (eq. 1-4): ``L = a / Lavg * 2^EV * Lw``,
    ``Ld = L (1 + L / Lwhite^2) / (1 + L)``, colour kept by ``RGBd = RGB * Ld / Lw``;
    ``a = 0.18``, ``Lavg = exp(mean(ln(eps + Lw)))``, ``Lwhite`` the 99.9th percentile
    of ``L`` (the paper's maximum, made robust to a few hot pixels).
``reinhard-local``
    Reinhard et al. 2002, the local "dodging and burning" operator (eq. 5-9): per
    pixel, the largest of eight centre-surround scales ``s = 1.6^i`` over which the
    scaled luminance is nearly uniform (``|V| < 0.05``, ``phi = 8``) gives the
    adaptation ``V1``, and ``Ld = L / (1 + V1)``. NumPy/SciPy only (Gaussian blurs).
``drago``
    Drago et al. 2003, adaptive logarithmic mapping with bias ``b = 0.85``:
    ``Ld = log(L + 1) / (log10(Lmax + 1) log(2 + 8 (L / Lmax)^(log b / log 0.5)))``,
    ``L = 2^EV * Lw / Lavg``, ``Lmax`` the 99.9th percentile of ``L``; ``Ld = 1`` at
    ``Lmax``.
``filmic``
    Hable 2010 ("Uncharted 2") filmic curve, per channel, on ``a / Lavg * 2^EV * RGB``
    with the parameters of colour-hdri's ``tonemapping_operator_filmic`` (shoulder
    0.22, linear 0.30, angle 0.10, toe 0.20, 0.01 / 0.30, exposure bias 2, linear
    white 11.2), which the tests compare against.

The global operators (all but ``reinhard-local``) are per pixel: their OpenCL kernel
(``kernels/tonemap.cl``) and its float64 NumPy twin :func:`apply_global` take the
scene statistics of :func:`statistics` and write the encoded codes directly.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from hdrcl.core.params import MAX_EXPOSURE_EV, OPERATORS

__all__ = ["OPERATORS", "ToneParams", "statistics", "apply_global", "reinhard_local", "srgb_encode",
           "quantize", "tone_map_array", "tonemap", "tonemap_file"]

#: Operator names (:data:`OPERATORS`, from the shared option table
#: :mod:`hdrcl.core.params`); ``OP_CODES`` numbers the global ones for the kernel.
OP_CODES = {"reinhard": 0, "drago": 1, "filmic": 2}
#: Reinhard's "key": the log-average luminance is mapped to this.
KEY = 0.18
#: Percentile of the scaled luminance taken as white (reinhard's Lwhite, drago's Lmax).
WHITE_PERCENTILE = 99.9
#: The statistics read at most this many pixels (every k-th row and column).
STATS_MAX_PIXELS = 1 << 20
LUMA = np.array([0.2126, 0.7152, 0.0722])
DRAGO_BIAS = 0.85
#: Hable's curve: A shoulder, B linear strength, C linear angle, D toe, E/F toe
#: numerator/denominator, W linear white, and the exposure bias (colour-hdri's defaults).
HABLE = {"A": 0.22, "B": 0.30, "C": 0.10, "D": 0.20, "E": 0.01, "F": 0.30, "W": 11.2, "bias": 2.0}
#: reinhard-local: scales 1.6^i, i < 8; phi and the threshold of the activity.
LOCAL_SCALES, LOCAL_RATIO, LOCAL_PHI, LOCAL_EPS = 8, 1.6, 8.0, 0.05


@dataclass(frozen=True)
class ToneParams:
    """What the per-pixel stage needs: ``scale`` multiplies the radiance, ``white`` is
    the white point in scaled units (reinhard, drago), ``log_average`` the scene key."""

    operator: str
    scale: float
    white: float
    log_average: float
    exposure: float = 0.0


def luminance(radiance: np.ndarray) -> np.ndarray:
    """Rec.709 luminance of ``(H, W, C)`` radiance (C = 1: the channel), float64."""
    rad = np.asarray(radiance)
    if rad.shape[-1] == 1:
        return rad[..., 0].astype(np.float64)
    return rad[..., :3].astype(np.float64) @ LUMA


def _clean(radiance: np.ndarray) -> np.ndarray:
    """float64, NaN and infinities as 0, negatives as 0, (H, W, C)."""
    rad = np.asarray(radiance, np.float64)
    if rad.ndim == 2:
        rad = rad[:, :, None]
    return np.maximum(np.nan_to_num(rad, nan=0.0, posinf=0.0, neginf=0.0), 0.0)


def stats_stride(h: int, w: int, max_pixels: int = STATS_MAX_PIXELS) -> int:
    """k such that every k-th row and column is at most ``max_pixels`` pixels."""
    return max(1, int(math.ceil(math.sqrt(h * w / max(int(max_pixels), 1)))))


#: Largest exposure change (EV) accepted, :data:`hdrcl.core.params.MAX_EXPOSURE_EV`: a
#: factor of 1.8e19 either way is far beyond any useful brightening or darkening (and
#: ``2.0 ** 2000`` overflows).


def check_exposure(exposure, name: str = "exposure") -> float:
    """``exposure`` as a float; UsageError naming ``name`` unless it is a finite number
    of stops within +-:data:`MAX_EXPOSURE_EV` (``2.0 ** 2000`` overflows)."""
    from hdrcl.core.params import check

    try:
        return float(check("exposure", exposure))
    except Exception as exc:  # the table's words, with the caller's name for the option
        if exc.args and isinstance(exc.args[0], str) and exc.args[0].startswith("--exposure"):
            exc.args = (name + exc.args[0][len("--exposure"):],) + exc.args[1:]
        raise


def statistics(radiance: np.ndarray, operator: str = "reinhard", exposure: float = 0.0) -> ToneParams:
    """Scene statistics of ``radiance`` for ``operator``, with ``exposure`` EV.

    ``log_average = exp(mean(ln(eps + Lw)))``, ``eps = 1e-6 max(Lw)``, over the stats
    grid; ``scale`` is ``KEY / log_average * 2^EV`` (``2^EV / log_average`` for drago);
    ``white`` the 99.9th percentile of ``scale * Lw``.
    """
    if operator not in OPERATORS:
        raise ValueError(f"unknown tone-mapping operator '{operator}'")
    rad = np.asarray(radiance)
    if rad.ndim == 2:
        rad = rad[:, :, None]
    k = stats_stride(rad.shape[0], rad.shape[1])
    lum = luminance(_clean(rad[::k, ::k]))
    positive = lum[lum > 0]
    gain = 2.0 ** float(exposure)
    if positive.size == 0:
        return ToneParams(operator, 0.0, 1.0, 0.0, float(exposure))
    eps = 1e-6 * float(np.max(positive))
    log_avg = float(np.exp(np.mean(np.log(eps + lum))))
    scale = (1.0 if operator == "drago" else KEY) / log_avg * gain
    white = max(float(np.percentile(scale * lum, WHITE_PERCENTILE)), 1e-12)
    return ToneParams(operator, scale, white, log_avg, float(exposure))


def _hable(x):
    a, b, c, d, e, f = (HABLE[k] for k in "ABCDEF")
    return (x * (a * x + c * b) + d * e) / (x * (a * x + b) + d * f) - e / f


def display_global(radiance: np.ndarray, params: ToneParams) -> np.ndarray:
    """Display-linear ``(H, W, C)`` float64 in [0, 1] of a global operator (the twin of
    the kernel up to the encoding)."""
    rad = _clean(radiance)
    op = params.operator
    if op == "filmic":
        x = rad * params.scale
        out = _hable(x * HABLE["bias"]) / _hable(HABLE["W"])
        return np.clip(out, 0.0, 1.0)
    lw = luminance(rad)
    lum = params.scale * lw
    if op == "reinhard":
        ld = lum * (1.0 + lum / (params.white * params.white)) / (1.0 + lum)
    elif op == "drago":
        lmax = params.white
        expo = math.log(DRAGO_BIAS) / math.log(0.5)
        ld = np.log1p(lum) / (math.log10(lmax + 1.0) * np.log(2.0 + 8.0 * np.power(lum / lmax, expo)))
    else:
        raise ValueError(f"'{op}' is not a global operator")
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(lw > 0, ld / lw, 0.0)
    return np.clip(rad * ratio[..., None], 0.0, 1.0)


def reinhard_local(radiance: np.ndarray, exposure: float = 0.0, params: Optional[ToneParams] = None) -> np.ndarray:
    """Display-linear ``(H, W, C)`` of Reinhard 2002's local operator (see module notes).

    Float32 Gaussian blurs (SciPy, ``mode="nearest"``): memory is a few copies of the
    luminance, time grows with the pixel count (about nine blurs).
    """
    from scipy.ndimage import gaussian_filter

    rad = _clean(radiance)
    p = params or statistics(rad, "reinhard-local", exposure)
    lw = luminance(rad)
    lum = (p.scale * lw).astype(np.float32)
    alpha1 = 1.0 / (2.0 * math.sqrt(2.0))
    adapt = None
    done = np.zeros(lum.shape, bool)
    s = 1.0
    # R(x, y, s) ~ exp(-(x^2 + y^2) / (alpha s)^2): a Gaussian of sigma = alpha s / sqrt(2).
    v1 = gaussian_filter(lum, alpha1 * s / math.sqrt(2.0), mode="nearest", truncate=4.0)
    adapt = v1.copy()
    for _ in range(LOCAL_SCALES):
        v2 = gaussian_filter(lum, alpha1 * LOCAL_RATIO * s / math.sqrt(2.0), mode="nearest", truncate=4.0)
        activity = (v1 - v2) / (2.0 ** LOCAL_PHI * KEY / (s * s) + v1)
        stop = ~done & (np.abs(activity) >= LOCAL_EPS)
        done |= stop
        keep = ~done
        adapt[keep] = v1[keep]  # the largest scale so far with |V| < eps
        s *= LOCAL_RATIO
        v1 = v2
        if done.all():
            break
    ld = lum / (1.0 + adapt)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(lw > 0, ld.astype(np.float64) / lw, 0.0)
    return np.clip(rad * ratio[..., None], 0.0, 1.0)


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """sRGB transfer function (IEC 61966-2-1), [0, 1] in and out."""
    linear = np.asarray(linear, np.float64)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(np.maximum(linear, 0.0031308), 1 / 2.4)
                    - 0.055)


def quantize(encoded: np.ndarray, bits: int = 8) -> np.ndarray:
    """Round [0, 1] to ``uint8``/``uint16`` codes (half up)."""
    top = (1 << bits) - 1
    codes = np.floor(np.clip(encoded, 0.0, 1.0) * top + 0.5)
    return codes.astype(np.uint8 if bits == 8 else np.uint16)


def apply_global(radiance: np.ndarray, params: ToneParams, bits: int = 8) -> np.ndarray:
    """The float64 NumPy twin of ``kernels/tonemap.cl``: codes of a global operator."""
    return quantize(srgb_encode(display_global(radiance, params)), bits)


def tone_map_array(radiance: np.ndarray, operator: str = "reinhard", exposure: float = 0.0,
                   bits: int = 8) -> np.ndarray:
    """Codes ``(H, W, C)`` of ``operator`` on the NumPy path (any size; previews)."""
    params = statistics(radiance, operator, exposure)
    if operator == "reinhard-local":
        return quantize(srgb_encode(reinhard_local(radiance, exposure, params)), bits)
    return apply_global(radiance, params, bits)


def _check(operator: str, bits: int) -> int:
    """The operator and depth, by the shared option table; the depth as an int."""
    from hdrcl.core.params import check

    check("operator", operator)
    return check("bits", bits)


def _check_radiance(radiance) -> np.ndarray:
    """``radiance`` as an (H, W[, C]) array of finite numbers, C = 1 or 3 (UsageError
    naming the parameter otherwise), as :func:`hdrcl.core.exposure.virtual.render` wants it."""
    from hdrcl.errors import ParameterTypeError, UsageError

    try:
        rad = np.asarray(radiance)
    except Exception:  # ragged nested lists
        rad = None
    if rad is None or rad.dtype.kind not in "fiu":
        raise ParameterTypeError(f"radiance: expected an (H, W[, C]) array of numbers, not {type(radiance).__name__}")
    if rad.ndim not in (2, 3) or (rad.ndim == 3 and rad.shape[2] not in (1, 3)) or rad.size == 0:
        raise UsageError(f"radiance: expected a non-empty (H, W), (H, W, 1) or (H, W, 3) array, "
                         f"not shape {rad.shape}")
    bad = int(np.count_nonzero(~np.isfinite(rad)))
    if bad:
        raise UsageError(f"radiance: {bad} NaN or infinite value(s); a radiance map must be finite")
    return rad


def tonemap(radiance: np.ndarray, operator: str = "reinhard", *, exposure: float = 0.0, bits: int = 8,
            device: Optional[str] = None) -> np.ndarray:
    """Tone-map linear Rec.709 radiance to sRGB-encoded codes.

    Parameters
    ----------
    radiance : ndarray, (H, W, C) or (H, W)
        C = 1 (grey) or 3; finite (NaN or infinite values raise UsageError, as
        ``expose`` does); negative values count as 0.
    operator : {"reinhard", "reinhard-local", "drago", "filmic"}
        See the module notes.
    exposure : float
        Exposure change in stops (EV) applied to the scene before the operator.
    bits : {8, 16}
        Output depth.
    device : str, optional
        OpenCL device for the global operators (their kernel); the NumPy twin is used
        where OpenCL is off or unavailable, and for ``reinhard-local`` always.

    Returns
    -------
    ndarray, (H, W, C) uint8 or uint16
        sRGB-encoded (IEC 61966-2-1), the shape of ``radiance`` (grey stays grey).
    """
    from hdrcl.cl.backend import get_processor

    bits = _check(operator, bits)
    exposure = check_exposure(exposure)
    rad = _check_radiance(radiance)
    squeeze = rad.ndim == 2
    if squeeze:
        rad = rad[:, :, None]
    params = statistics(rad, operator, exposure)
    if operator == "reinhard-local":
        out = quantize(srgb_encode(reinhard_local(rad, exposure, params)), bits)
    else:
        proc = get_processor("tonemap", device)
        if proc is None:
            out = apply_global(rad, params, bits)
        else:
            out = proc.apply(np.asarray(rad, np.float32), OP_CODES[operator], params.scale, params.white, bits)
    return out[..., 0] if squeeze else out


def tonemap_file(radiance_path, output, operator: str = "reinhard", *, exposure: float = 0.0,
                 bits: Optional[int] = None, device: Optional[str] = None) -> np.ndarray:
    """Tone-map a radiance file (EXR, HDR, TIFF, PFM) into an sRGB JPEG, PNG or TIFF.

    A file tagged ACEScg (``oiio:ColorSpace``) is converted to Rec.709 first. ``bits``
    defaults to 8; JPEG holds 8 bits only. The picture records the operator, exposure
    and source in its metadata. Returns the codes written.
    """
    import os

    from hdrcl.errors import UsageError
    from hdrcl.io.radiance import read_radiance_colorspace
    from hdrcl.io.ldr import LDR_EXTENSIONS, write_ldr

    output, radiance_path = os.fsdecode(os.fspath(output)), os.fsdecode(os.fspath(radiance_path))
    ext = os.path.splitext(output)[1].lower()
    if ext not in LDR_EXTENSIONS:
        raise UsageError(f"{output}: unsupported output type '{ext or '(none)'}'; "
                         f"use one of {', '.join(LDR_EXTENSIONS)}")
    bits = _check(operator, 8 if bits is None else bits)
    exposure = check_exposure(exposure)
    if ext in (".jpg", ".jpeg") and bits == 16:
        raise UsageError(f"{output}: JPEG holds 8 bits; use .png or .tif for 16-bit output")
    rad, space = read_radiance_colorspace(radiance_path, require_float=True)  # no photo as radiance
    if space != "rec709":
        from hdrcl.io.colorspace import convert

        rad = convert(rad, space, "rec709")
    img = tonemap(rad, operator, exposure=exposure, bits=bits, device=device)
    write_ldr(output, img, metadata={"tonemap": operator, "exposureEV": float(exposure),
                                     "source": os.path.basename(os.fspath(radiance_path))})
    return img
