"""False-colour pictures of luminance maps, with a legend in cd/m^2 (NumPy only).

**Luminance.** ``L = 0.265 R + 0.670 G + 0.065 B`` of the values in cd/m^2 (Radiance's
weights, :data:`hdrcl.core.fisheye_math.RADIANCE_LUMA`): a ``.hdr`` file is read in
Radiance's convention (stored values x 179, after its ``EXPOSURE=``), an EXR must say
``hdrcl:units = cd/m2`` (a calibrated map, ``--absolute`` or ``--reference-patch``) or
carry OpenEXR's ``whiteLuminance`` (cd/m^2 of RGB 1, 1, 1).

**Scale.** ``linear``: ``t = (L - min) / (max - min)``; ``log``: ``t = (log10 L - log10
min) / (log10 max - log10 min)``; ``t`` clipped to 0..1 and mapped on a ramp from dark
blue (low) through cyan, green and yellow to red (high), as Radiance's falsecolor does.
Pixels of luminance 0 (outside the lens circle) stay black. Defaults: ``max`` is the
largest luminance rounded up to 1, 2 or 5 x 10^k; ``min`` is 0 (linear) or ``max /
10^4`` (log). The legend, right of the picture, has :data:`TICKS` labelled steps and the
unit; its text is drawn with a built-in 3 x 5 pixel font (no system font needed).
"""
from __future__ import annotations

import math
import os
from typing import Optional, Tuple

import numpy as np

from hdrcl.errors import InputError, UsageError

__all__ = ["read_luminance", "nice_max", "colour_index", "palette", "render", "falsecolor_file"]

TICKS = 8
#: Ramp stops (t, R, G, B), 0..1.
RAMP = np.array([(0.0, 0.0, 0.0, 0.45), (0.2, 0.0, 0.35, 1.0), (0.4, 0.0, 0.85, 0.85), (0.6, 0.25, 0.85, 0.1),
                 (0.8, 1.0, 0.85, 0.0), (1.0, 0.95, 0.0, 0.0)])

_FONT = {  # 3 x 5 glyphs: five rows of three columns, '#' = ink
    "0": ("###", "# #", "# #", "# #", "###"), "1": (" # ", "## ", " # ", " # ", "###"),
    "2": ("###", "  #", "###", "#  ", "###"), "3": ("###", "  #", " ##", "  #", "###"),
    "4": ("# #", "# #", "###", "  #", "  #"), "5": ("###", "#  ", "###", "  #", "###"),
    "6": ("###", "#  ", "###", "# #", "###"), "7": ("###", "  #", "  #", "  #", "  #"),
    "8": ("###", "# #", "###", "# #", "###"), "9": ("###", "# #", "###", "  #", "###"),
    ".": ("   ", "   ", "   ", "   ", " # "), "-": ("   ", "   ", "###", "   ", "   "),
    "+": ("   ", " # ", "###", " # ", "   "), "e": ("   ", "###", "###", "#  ", "###"),
    "c": ("   ", "   ", "###", "#  ", "###"), "d": ("  #", "  #", "###", "# #", "###"),
    "/": ("  #", "  #", " # ", "#  ", "#  "), "m": ("   ", "   ", "###", "###", "# #"),
    " ": ("   ",) * 5,
}


def _glyph(ch: str) -> np.ndarray:
    return np.array([[c == "#" for c in row] for row in _FONT.get(ch, _FONT[" "])], bool)


def text_mask(text: str, scale: int = 2) -> np.ndarray:
    """A boolean picture of ``text`` (3 x 5 glyphs, one column apart), ``scale`` x."""
    if not text:
        return np.zeros((5 * scale, 1), bool)
    cols = []
    for ch in text:
        cols.append(_glyph(ch))
        cols.append(np.zeros((5, 1), bool))
    mask = np.concatenate(cols[:-1], axis=1)
    return np.kron(mask, np.ones((scale, scale), bool))


def read_luminance(path) -> np.ndarray:
    """``(H, W)`` luminance in cd/m^2 (float64) of a ``.hdr`` or a calibrated EXR."""
    from hdrcl.core.fisheye_math import WHITE_EFFICACY, radiance_luminance
    from hdrcl.io.radiance import read_radiance, white_luminance

    name = os.fspath(path)
    pixels, meta = read_radiance(name, require_float=True)
    ext = os.path.splitext(name)[1].lower()
    units = str(meta.get("units", ""))
    if ext == ".hdr" and not units:
        # a foreign picture: Radiance's convention, 179 lm/W (hdrcl's own .hdr in cd/m^2
        # are read in cd/m^2 by read_radiance, older ones included)
        return radiance_luminance(pixels) * WHITE_EFFICACY
    if not units.startswith("cd/m2"):
        white = white_luminance(name)
        if white is None:
            raise InputError(f"{name}: not a luminance map (hdrcl wrote it in relative units); merge with "
                             "--absolute, --reference-patch or the luminance options (--lens-circle ...)")
        return radiance_luminance(pixels) * white
    return radiance_luminance(pixels)


def nice_max(value: float) -> float:
    """``value`` rounded up to 1, 2 or 5 x 10^k (1 for nothing positive)."""
    if not (value > 0 and math.isfinite(value)):
        return 1.0
    k = math.floor(math.log10(value))
    for m in (1.0, 2.0, 5.0, 10.0):
        if m * 10.0 ** k >= value * (1 - 1e-12):
            return m * 10.0 ** k
    return 10.0 ** (k + 1)


def scale_limits(lum: np.ndarray, scale: str, lo: Optional[float], hi: Optional[float]) -> Tuple[float, float]:
    """Checked ``(min, max)`` of the legend (UsageError names the option)."""
    if scale not in ("linear", "log"):
        raise UsageError(f"--scale: '{scale}' is not one of log, linear")
    finite = lum[np.isfinite(lum)]
    hi = nice_max(float(finite.max()) if finite.size else 0.0) if hi is None else float(hi)
    if not (hi > 0 and math.isfinite(hi)):
        raise UsageError(f"--max: expected a positive luminance in cd/m2, not {hi:g}")
    lo = (0.0 if scale == "linear" else hi / 1e4) if lo is None else float(lo)
    if not (math.isfinite(lo) and lo < hi and (lo > 0 or scale == "linear") and lo >= 0):
        raise UsageError(f"--min: expected 0 <= min < max ({hi:g}) (min > 0 for --scale log), not {lo:g}")
    return lo, hi


def colour_index(lum: np.ndarray, scale: str, lo: float, hi: float) -> np.ndarray:
    """``t`` in 0..1 of every pixel (0 for non-positive or non-finite luminance)."""
    lum = np.asarray(lum, np.float64)
    good = np.isfinite(lum) & (lum > 0)
    safe = np.where(good, lum, 1.0)
    if scale == "log":
        t = (np.log10(safe) - math.log10(lo)) / (math.log10(hi) - math.log10(lo))
    else:
        t = (safe - lo) / (hi - lo)
    return np.where(good, np.clip(t, 0.0, 1.0), 0.0)


def palette(t: np.ndarray) -> np.ndarray:
    """RGB 0..1 of ``t`` on :data:`RAMP` (linear between its stops)."""
    return np.stack([np.interp(t, RAMP[:, 0], RAMP[:, c]) for c in (1, 2, 3)], axis=-1)


def _label(v: float) -> str:
    """A short number: ``0.05``, ``316.2``, ``3162``, ``3.16e4``, ``1e6``."""
    if v == 0:
        return "0"
    if 0.01 <= abs(v) < 1e4:
        return f"{v:.4g}"
    mantissa, _, exponent = f"{v:.3g}".partition("e")
    return f"{mantissa}e{int(exponent)}" if exponent else mantissa


def _stamp(canvas: np.ndarray, mask: np.ndarray, y: int, x: int) -> None:
    h, w = mask.shape
    h, w = min(h, canvas.shape[0] - y), min(w, canvas.shape[1] - x)
    if h > 0 and w > 0:
        canvas[y:y + h, x:x + w][mask[:h, :w]] = 1.0


def legend(height: int, scale: str, lo: float, hi: float, text_scale: int = 2) -> np.ndarray:
    """``(height, width, 3)`` legend: colour bar, labels at :data:`TICKS` steps, the unit."""
    width = 30 * text_scale + 40
    pane = np.zeros((height, width, 3))
    top, bottom = 12 * text_scale, height - 6 * text_scale
    bar_h = max(bottom - top, 2)
    t = 1.0 - (np.arange(bar_h) + 0.5) / bar_h
    pane[top:top + bar_h, 4:20] = palette(t)[:, None, :]
    _stamp(pane, text_mask("cd/m2", text_scale), 2 * text_scale, 4)
    for k in range(TICKS + 1):
        f = k / TICKS
        if scale == "linear":
            v = lo + f * (hi - lo)
        else:
            v = 10.0 ** (math.log10(lo) + f * (math.log10(hi) - math.log10(lo)))
        y = int(round(top + (1.0 - f) * (bar_h - 1)))
        pane[max(y, 0):y + 1, 20:26] = 1.0
        _stamp(pane, text_mask(_label(v), text_scale), max(0, y - 2 * text_scale), 28)
    return pane


def render(lum: np.ndarray, *, scale: str = "linear", lo: Optional[float] = None, hi: Optional[float] = None):
    """8-bit ``(H, W + legend, 3)`` false-colour picture of ``lum`` and ``(min, max)``."""
    lo, hi = scale_limits(lum, scale, lo, hi)
    t = colour_index(lum, scale, lo, hi)
    rgb = palette(t)
    rgb[~(np.isfinite(lum) & (lum > 0))] = 0.0
    text_scale = max(1, min(4, lum.shape[0] // 200))
    pane = legend(lum.shape[0], scale, lo, hi, text_scale)
    out = np.concatenate([rgb, pane], axis=1)
    return np.clip(np.round(out * 255.0), 0, 255).astype(np.uint8), (lo, hi)


def falsecolor_file(path, output, *, scale: str = "linear", lo: Optional[float] = None,
                    hi: Optional[float] = None) -> Tuple[float, float]:
    """Read ``path``, write its false-colour picture to ``output`` (8-bit PNG, JPEG or
    TIFF, atomically); returns the legend's ``(min, max)`` in cd/m^2."""
    from hdrcl.io.writers import write_ldr

    lum = read_luminance(path)
    picture, limits = render(lum, scale=scale, lo=lo, hi=hi)
    write_ldr(output, picture, metadata={"falsecolor": f"{scale} {limits[0]:g}..{limits[1]:g} cd/m2"})
    return limits
