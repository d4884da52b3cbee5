"""False-colour pictures of luminance maps as Radiance's ``falsecolor`` draws them.

**Luminance.** ``L = 0.265 R + 0.670 G + 0.065 B`` of the values in cd/m^2 (Radiance's
weights): a ``.hdr`` is read in Radiance's convention (stored values x 179, after its
``EXPOSURE=`` lines; hdrcl's own maps in cd/m^2, older ones included, as
:func:`hdrcl.io.radiance.read_radiance` reads them), an EXR must say ``hdrcl:units =
cd/m2`` or carry OpenEXR's ``whiteLuminance``. ``multiplier`` scales it (Radiance's
``-m``, whose 179 is already in hdrcl's cd/m^2) and ``label`` names the unit (``-l``).

**Mapping** (Radiance's ``falsecolor.pl``, its ``pc0.cal``/``pc1.cal``): ``v = L / max``
(linear; ``(L - min) / (max - min)`` when a minimum is given) or ``v = log10(L / max) /
decades + 1`` (log; ``decades = log10(max / min)``, 0 below ``min``), then the palette's
``clip(red(v))``, ``clip(green(v))``, ``clip(blue(v))``: ``def`` (Radiance's default,
its 23-entry table interpolated), ``spec`` (the older spectral ramp), ``hot``, ``pm3d``,
``eco``. As in Radiance, no luminance is ``v = 0``, the palette's first colour, and the
picture's colours are linear values shown with gamma 2.2 (as ``ra_tiff``/``ra_ppm``
write them: code ``min(255, floor(256 c^(1/2.2)))``).

**Contours** (``-cl``, ``-cb``): ``lines`` keeps the colour only where a pixel's rounded
division ``floor(ndivs v + 0.5)`` differs from its left/right or upper/lower neighbour's,
``bands`` where ``frac(ndivs v)`` lies in 0.4..0.6; black elsewhere, and outside ``0 <= v
< 1``. **Extrema** (``-e``): the smallest and largest luminance are labelled at their
pixels (``pextrem``: the first in scan order). **Legend**: ``ndivs`` colour steps labelled
with the value at their middle (Radiance's ``(ndivs - 0.5 - i) / ndivs``), the unit on
top, right of the picture; a picture lower than the legend is padded with black below.

**Default range** (Radiance's is a fixed 1000 cd/m^2, which shows an outdoor map as one
colour): linear, ``max`` = the 99th percentile of the positive luminance rounded up to 1,
2 or 5 x 10^k (a sun of a few pixels does not make the rest one colour); log, ``max`` =
the largest rounded up to a power of ten and ``min`` that many decades lower which reach
the 1st percentile (1 to 8 decades).
"""
from __future__ import annotations

import math
import os
from typing import Optional, Tuple

import numpy as np

from hdrcl.errors import InputError, UsageError

__all__ = ["read_luminance", "nice_max", "colour_index", "palette", "render", "falsecolor_file", "PALETTES",
           "default_limits", "scale_limits", "display_codes", "extrema"]

PALETTES = ("def", "spec", "hot", "pm3d", "eco")
DEFAULT_DIVISIONS = 8
GAMMA = 2.2
#: Radiance's default palette (falsecolor.pl: def_redp, def_grnp, def_blup).
DEF_TABLE = np.array([
    (0.18848, 0.0009766, 0.2666), (0.05468174, 2.35501e-05, 0.3638662), (0.00103547, 0.0008966244, 0.4770437),
    (8.311144e-08, 0.0264977, 0.5131397), (7.449763e-06, 0.1256843, 0.5363797),
    (0.0004390987, 0.2865799, 0.5193677), (0.001367254, 0.4247083, 0.4085123), (0.003076, 0.4739468, 0.1702815),
    (0.01376382, 0.4402732, 0.05314236), (0.06170773, 0.3671876, 0.05194055),
    (0.1739422, 0.2629843, 0.08564082), (0.2881156, 0.1725325, 0.09881395), (0.3299725, 0.1206819, 0.08324373),
    (0.3552663, 0.07316644, 0.06072902), (0.372552, 0.03761026, 0.0391076), (0.3921184, 0.01612362, 0.02315354),
    (0.4363976, 0.004773749, 0.01284458), (0.6102754, 6.830967e-06, 0.005184709),
    (0.7757267, 0.00803605, 0.001691774), (0.9087369, 0.1008085, 2.432735e-05),
    (1.0, 0.3106831, 1.212949e-05), (1.0, 0.6447838, 0.006659406), (0.9863, 0.9707, 0.02539)])

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
    " ": ("   ",) * 5, "a": ("   ", "###", "  #", "###", "###"), "x": ("   ", "# #", " # ", " # ", "# #"),
    "i": (" # ", "   ", " # ", " # ", " # "), "n": ("   ", "   ", "## ", "# #", "# #"),
    "l": ("## ", " # ", " # ", " # ", "###"), "u": ("   ", "   ", "# #", "# #", "###"),
    "s": ("   ", " ##", "## ", " ##", "## "), "N": ("# #", "###", "###", "###", "# #"),
    "t": (" # ", "###", " # ", " # ", " ##"), "r": ("   ", "   ", "###", "#  ", "#  "),
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
    from hdrcl.core.luminance.fisheye_math import WHITE_EFFICACY, radiance_luminance
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
            # near the largest float (a --multiplier of 1e308) the rounded value overflows
            return m * 10.0 ** k if math.isfinite(m * 10.0 ** k) else value
    return value


def default_limits(lum: np.ndarray, scale: str) -> Tuple[float, float]:
    """The default ``(min, max)`` (see the module's text)."""
    pos = lum[np.isfinite(lum) & (lum > 0)]
    if not pos.size:
        return (0.0, 1.0) if scale == "linear" else (1e-4, 1.0)
    if scale == "linear":
        return 0.0, nice_max(float(np.percentile(pos, 99)))
    top = math.ceil(math.log10(float(pos.max())) - 1e-12)
    hi = 10.0 ** top if top <= 308 else float(pos.max())
    decades = int(np.clip(math.ceil(math.log10(hi / float(np.percentile(pos, 1))) - 1e-12), 1, 8))
    return hi / 10.0 ** decades, hi


def scale_limits(lum: np.ndarray, scale: str, lo: Optional[float], hi: Optional[float]) -> Tuple[float, float]:
    """Checked ``(min, max)`` of the legend (UsageError names the option)."""
    if scale not in ("linear", "log"):
        raise UsageError(f"--scale: '{scale}' is not one of log, linear")
    dlo, dhi = default_limits(lum, scale)
    if hi is None:
        hi = dhi if lo is None or lo < dhi else nice_max(float(lo) * 10.0)
    hi = float(hi)
    if not (hi > 0 and math.isfinite(hi)):
        raise UsageError(f"--max: expected a positive luminance in cd/m2, not {hi:g}")
    lo = (dlo if dlo < hi else (0.0 if scale == "linear" else max(hi / 1e4, 5e-324))) if lo is None else float(lo)
    if not (math.isfinite(lo) and lo < hi and (lo > 0 or scale == "linear") and lo >= 0):
        raise UsageError(f"--min: expected 0 <= min < max ({hi:g}) (min > 0 for --scale log), not {lo:g}")
    return lo, hi


def colour_index(lum: np.ndarray, scale: str, lo: float, hi: float) -> np.ndarray:
    """Radiance's ``v`` of every pixel (not clipped: above 1 beyond ``max``; 0 for no,
    negative or non-finite luminance, and below ``min`` on a log scale)."""
    lum = np.asarray(lum, np.float64)
    good = np.isfinite(lum) & (lum > 0)
    safe = np.where(good, lum, 1.0)
    if scale == "log":
        # in logarithms: max / min of 1e200 / 1e-200 overflowed, and every pixel got the top colour
        decades = log_decades(lo, hi)
        x = np.log10(safe) - math.log10(hi)
        v = np.where(x > -decades, x / decades + 1.0, 0.0)
    else:
        with np.errstate(over="ignore"):  # a --max of 1e-320 (subnormal) takes v past the largest float
            v = np.maximum((safe - lo) / (hi - lo), 0.0)
    return np.where(good, np.minimum(v, V_LIMIT), 0.0)


#: ``v`` is capped here (far above 1, the top of the scale): no infinity reaches the palette.
V_LIMIT = 1e6


def log_decades(lo: float, hi: float) -> float:
    """``log10(max / min)`` computed as a difference (no overflow for 1e-200 .. 1e200)."""
    return math.log10(hi) - math.log10(lo)


def _clip(x):
    return np.clip(x, 0.0, 1.0)


def _def(v: np.ndarray) -> np.ndarray:
    """Radiance's ``interp_arr(v/0.0454545 + 1, def_*p)``: table entries 1..23, linear."""
    x = np.asarray(v, np.float64) / 0.0454545 + 1.0
    i = np.clip(np.floor(x), 1, 22).astype(np.int64)
    f = (x - i)[..., None]
    out = DEF_TABLE[i - 1] * (1 - f) + DEF_TABLE[i] * f
    out = np.where((x >= 23)[..., None], DEF_TABLE[22], out)
    return np.where((x <= 1)[..., None], DEF_TABLE[0], out)


def palette(v: np.ndarray, name: str = "def") -> np.ndarray:
    """Linear RGB 0..1 of ``v`` in Radiance's palette ``name`` (``clip`` of each channel)."""
    v = np.asarray(v, np.float64)
    g = GAMMA
    with np.errstate(invalid="ignore"):
        if name == "def":
            rgb = _def(v)
        elif name == "spec":
            rgb = np.stack([1.6 * v - 0.6, np.where(v > 0.375, 1.6 - 1.6 * v, 8.0 / 3.0 * v), 1 - 8.0 / 3.0 * v], -1)
        elif name == "hot":
            rgb = np.stack([_clip(3 * v) ** g, _clip(3 * v - 1) ** g, _clip(3 * v - 2) ** g], -1)
        elif name == "pm3d":
            rgb = np.stack([np.sqrt(np.maximum(v, 0)) ** g, v * v * np.maximum(v, 0) ** g,
                            _clip(np.sin(2 * math.pi * v)) ** g], -1)
        elif name == "eco":
            rgb = np.stack([_clip(2 * v) ** g, _clip(2 * (v - 0.5)) ** g, _clip(2 * (0.5 - v)) ** g], -1)
        else:
            raise UsageError(f"--palette: '{name}' is not one of {', '.join(PALETTES)}")
    return _clip(np.nan_to_num(rgb))


def display_codes(rgb: np.ndarray) -> np.ndarray:
    """8-bit codes of linear colours as Radiance's converters write them (gamma 2.2)."""
    c = np.floor(256.0 * np.power(np.clip(rgb, 0.0, None), 1.0 / GAMMA))
    return np.clip(c, 0, 255).astype(np.uint8)


def contour_mask(v: np.ndarray, kind: str, ndivs: int) -> np.ndarray:
    """Where Radiance's ``-cl`` (``lines``) or ``-cb`` (``bands``) keeps the colour."""
    inside = (v >= 0) & (v < 1)
    if kind == "bands":
        f = ndivs * v - np.floor(ndivs * v)
        return inside & (f > 0.4) & (f < 0.6)
    if kind != "lines":
        raise UsageError(f"--contour: '{kind}' is not one of lines, bands")
    k = np.floor(ndivs * np.pad(v, 1, mode="edge") + 0.5)
    c = k[1:-1, 1:-1]
    edge = (k[1:-1, :-2] != k[1:-1, 2:]) | (k[:-2, 1:-1] != k[2:, 1:-1])
    return inside & edge & np.isfinite(c)


def extrema(lum: np.ndarray):
    """``((row, col, L_min), (row, col, L_max))``: the first in scan order (``pextrem``)."""
    flat = np.where(np.isfinite(lum), lum, 0.0)
    lo, hi = int(np.argmin(flat)), int(np.argmax(flat))
    w = lum.shape[1]
    return (lo // w, lo % w, float(flat.flat[lo])), (hi // w, hi % w, float(flat.flat[hi]))


def _label(v: float) -> str:
    """A short number: ``0.05``, ``316.2``, ``3162``, ``3.16e4``, ``1e6``."""
    if v == 0:
        return "0"
    if 0.01 <= abs(v) < 1e4:
        return f"{v:.4g}"
    mantissa, _, exponent = f"{v:.3g}".partition("e")
    return f"{mantissa}e{int(exponent)}" if exponent else mantissa


def _stamp(canvas: np.ndarray, mask: np.ndarray, y: int, x: int, colour=1.0) -> None:
    y, x = max(y, 0), max(x, 0)
    h, w = mask.shape
    h, w = min(h, canvas.shape[0] - y), min(w, canvas.shape[1] - x)
    if h > 0 and w > 0:
        canvas[y:y + h, x:x + w][mask[:h, :w]] = colour


def legend_height(ndivs: int, text_scale: int) -> int:
    """Rows the legend needs: its unit line and ``ndivs`` labelled steps."""
    return 12 * text_scale + ndivs * (6 * text_scale + 2) + 4 * text_scale


def legend(height: int, scale: str, lo: float, hi: float, text_scale: int = 2, *, ndivs: int = DEFAULT_DIVISIONS,
           name: str = "def", label: str = "cd/m2") -> np.ndarray:
    """``(height, width, 3)`` linear-colour legend: ``ndivs`` steps, labelled at their
    middles, the unit on top (``height`` at least :func:`legend_height`)."""
    width = 30 * text_scale + 40
    pane = np.zeros((height, width, 3))
    top = 12 * text_scale
    step = (height - top - 4 * text_scale) / ndivs
    _stamp(pane, text_mask(label, text_scale), 2 * text_scale, 4)
    for i in range(ndivs):
        imap = (ndivs - 0.5 - i) / ndivs
        y0, y1 = int(round(top + i * step)), int(round(top + (i + 1) * step))
        rows = np.arange(y0, y1)
        v = 1.0 - (rows - top + 0.5) / (ndivs * step)
        pane[y0:y1, 4:24] = palette(v, name)[:, None, :]
        value = lo + imap * (hi - lo) if scale == "linear" else 10.0 ** (math.log10(hi) + (imap - 1) * log_decades(lo, hi))
        _stamp(pane, text_mask(_label(value), text_scale), (y0 + y1) // 2 - 2 * text_scale, 28)
    return pane


def render(lum: np.ndarray, *, scale: str = "linear", lo: Optional[float] = None, hi: Optional[float] = None,
           palette_name: str = "def", contour: Optional[str] = None, ndivs: int = DEFAULT_DIVISIONS,
           show_extrema: bool = False, label: str = "cd/m2"):
    """8-bit ``(max(H, legend), W + legend, 3)`` picture of ``lum`` and ``(min, max)``."""
    if not (isinstance(ndivs, int) and 1 <= ndivs <= 100):
        raise UsageError(f"--divisions: expected a whole number 1..100, not {ndivs}")
    lo, hi = scale_limits(lum, scale, lo, hi)
    v = colour_index(lum, scale, lo, hi)
    rgb = palette(v, palette_name)
    if contour is not None:
        rgb[~contour_mask(v, contour, ndivs)] = 0.0
    h, w = lum.shape
    text_scale = max(1, min(4, h // 200))
    if show_extrema:
        for row, col, value in extrema(lum):
            mask = text_mask(_label(value), text_scale)
            y, x = min(row, max(h - mask.shape[0], 0)), min(col, max(w - mask.shape[1], 0))
            box = (slice(max(y - 1, 0), y + mask.shape[0] + 1), slice(max(x - 1, 0), x + mask.shape[1] + 1))
            rgb[box] = 0.0
            _stamp(rgb, mask, y, x)
    rows = max(h, legend_height(ndivs, text_scale))
    canvas = np.zeros((rows, w, 3))
    canvas[:h] = rgb
    pane = legend(rows, scale, lo, hi, text_scale, ndivs=ndivs, name=palette_name, label=label)
    return display_codes(np.concatenate([canvas, pane], axis=1)), (lo, hi)


def scaled_luminance(lum: np.ndarray, multiplier: float, path="map") -> np.ndarray:
    """``lum x multiplier``, refused (UsageError naming ``--multiplier``) where a finite
    luminance would become infinite (``--multiplier 1e308`` blamed a ``--max`` never given,
    after a raw NumPy warning)."""
    with np.errstate(over="ignore"):
        out = lum * multiplier
    over = np.isfinite(lum) & ~np.isfinite(out)
    if over.any():
        raise UsageError(f"--multiplier: {multiplier:g} takes {int(over.sum())} luminance(s) of {os.fspath(path)} (up "
                         f"to {float(np.max(lum[over])):.4g} cd/m2) past the largest number (1.8e308); use a "
                         "smaller multiplier")
    return out


def falsecolor_file(path, output, *, scale: str = "linear", lo: Optional[float] = None,
                    hi: Optional[float] = None, palette_name: str = "def", contour: Optional[str] = None,
                    ndivs: int = DEFAULT_DIVISIONS, show_extrema: bool = False, multiplier: float = 1.0,
                    label: str = "cd/m2") -> Tuple[float, float]:
    """Read ``path``, write its false-colour picture to ``output`` (8-bit PNG, JPEG or
    TIFF, atomically); returns the legend's ``(min, max)``."""
    from hdrcl.io.ldr import write_ldr

    if not (multiplier > 0 and math.isfinite(multiplier)):
        raise UsageError(f"--multiplier: expected a positive factor, not {multiplier:g}")
    if palette_name not in PALETTES:
        raise UsageError(f"--palette: '{palette_name}' is not one of {', '.join(PALETTES)}")
    lum = scaled_luminance(read_luminance(path), multiplier, path)
    picture, limits = render(lum, scale=scale, lo=lo, hi=hi, palette_name=palette_name, contour=contour,
                             ndivs=ndivs, show_extrema=show_extrema, label=label)
    write_ldr(output, picture, metadata={"falsecolor": f"{scale} {limits[0]:g}..{limits[1]:g} {label}, "
                                                      f"palette {palette_name}"})
    return limits
