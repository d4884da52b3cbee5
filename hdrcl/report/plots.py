"""Report pictures drawn with NumPy alone: the response-curve plot and the coverage map."""
from __future__ import annotations

import numpy as np

from hdrcl.core.response import Response
from hdrcl.report.quality import NO_DATA, WORKING_HIGH, WORKING_LOW

#: Long side of the preview and of the coverage map, in pixels.
IMAGE_SIZE = 512


# --------------------------------------------------------------------------- raster drawing

# 3x5 pixel glyphs, one string of 15 bits (rows top to bottom) per character.
_GLYPHS = {
    "0": "111101101101111", "1": "010110010010111", "2": "111001111100111", "3": "111001111001111",
    "4": "101101111001001", "5": "111100111001111", "6": "111100111101111", "7": "111001001010010",
    "8": "111101111101111", "9": "111101111001111", "-": "000000111000000", ".": "000000000000010",
    "+": "000010111010000", "=": "000111000111000", "(": "010100100100010", ")": "010001001001010",
    "/": "001001010100100", ":": "000010000010000", "%": "101001010100101", " ": "000000000000000",
    "A": "010101111101101", "B": "110101110101110", "C": "011100100100011", "D": "110101101101110",
    "E": "111100110100111", "F": "111100110100100", "G": "011100101101011", "H": "101101111101101",
    "I": "111010010010111", "J": "001001001101010", "K": "101101110101101", "L": "100100100100111",
    "M": "101111111101101", "N": "110101101101101", "O": "010101101101010", "P": "110101110100100",
    "Q": "010101101110011", "R": "110101110101101", "S": "011100010001110", "T": "111010010010010",
    "U": "101101101101111", "V": "101101101101010", "W": "101101111111101", "X": "101101010101101",
    "Y": "101101010010010", "Z": "111001010100111",
}


_FONT_SCALE = 2


_ADVANCE = 4 * _FONT_SCALE  # glyph width 3 + 1 spacing


_TEXT_HEIGHT = 5 * _FONT_SCALE


_BLACK = (0, 0, 0)


_GRID = (225, 225, 225)


_SHADE = (242, 242, 242)


_CURVE_COLOURS = {"R": (205, 40, 40), "G": (30, 150, 50), "B": (40, 80, 210)}


_GREY_CURVE = (60, 60, 60)


def _text_width(s: str) -> int:
    return len(s) * _ADVANCE - _FONT_SCALE


def _text(img: np.ndarray, x: int, y: int, s: str, colour=_BLACK) -> None:
    """Draw ``s`` (upper-cased) with its top-left corner at ``(x, y)``, clipped to ``img``."""
    h, w = img.shape[:2]
    k = _FONT_SCALE
    for i, ch in enumerate(s.upper()):
        bits = _GLYPHS.get(ch, _GLYPHS[" "])
        gx = x + i * _ADVANCE
        for r in range(5):
            for col in range(3):
                if bits[3 * r + col] == "1":
                    y0, x0 = y + r * k, gx + col * k
                    if 0 <= y0 and y0 + k <= h and 0 <= x0 and x0 + k <= w:
                        img[y0:y0 + k, x0:x0 + k] = colour


def _hline(img, y, x0, x1, colour, width=1):
    img[max(y, 0):y + width, max(min(x0, x1), 0):max(x0, x1) + 1] = colour


def _vline(img, x, y0, y1, colour, width=1):
    img[max(min(y0, y1), 0):max(y0, y1) + 1, max(x, 0):x + width] = colour


def _polyline(img: np.ndarray, xs: np.ndarray, ys: np.ndarray, colour, width: int = 2) -> None:
    """Connect points one pixel column apart: each column gets the span to the next point."""
    h = img.shape[0]
    ys = np.clip(np.round(ys).astype(np.int64), 0, h - 1)
    for i in range(len(xs)):
        y_next = ys[i + 1] if i + 1 < len(xs) else ys[i]
        lo, hi = min(ys[i], y_next), max(ys[i], y_next)
        img[max(lo - width // 2, 0):hi + (width + 1) // 2, xs[i]:xs[i] + 1] = colour


def _nice_step(span: float, max_ticks: int = 8) -> float:
    for step in (0.5, 1, 2, 5, 10, 20, 50):
        if span / step <= max_ticks:
            return float(step)
    return float(10 ** np.ceil(np.log10(span / max_ticks)))


def _fmt_tick(v: float) -> str:
    return f"{v:.0f}" if abs(v - round(v)) < 1e-9 else f"{v:.1f}"


def response_plot(response: Response, width: int = 560, height: int = 400) -> np.ndarray:
    """The response curves as an RGB uint8 image ``(height, width, 3)``.

    x: pixel code z from 0 to ``Zmax``; y: ``g(z) = ln exposure``. One line per channel
    (red, green, blue; dark grey for a grey response), light grey grid at the ticks,
    the codes outside the working range (below 10, above 245 in 8-bit units) shaded.
    """
    img = np.full((height, width, 3), 255, np.uint8)
    tables = response.tables()
    levels = response.levels
    left, right, top, bottom = 64, 16, 34, 48
    x0, x1, y0, y1 = left, width - right - 1, top, height - bottom - 1
    finite = tables[np.isfinite(tables)]
    gmin, gmax = (float(finite.min()), float(finite.max())) if finite.size else (-1.0, 1.0)
    step = _nice_step(max(gmax - gmin, 1e-6))
    lo, hi = np.floor(gmin / step) * step, np.ceil(gmax / step) * step
    if hi <= lo:
        hi = lo + step

    def px(z):
        return x0 + np.asarray(z, np.float64) / (levels - 1) * (x1 - x0)

    def py(g):
        return y1 - (np.asarray(g, np.float64) - lo) / (hi - lo) * (y1 - y0)

    # Shade the codes outside the working range; grid and tick labels.
    scale = (levels - 1) / 255.0
    zlo, zhi = int(round(px(WORKING_LOW * scale))), int(round(px(WORKING_HIGH * scale)))
    img[y0:y1 + 1, x0:zlo + 1] = _SHADE
    img[y0:y1 + 1, zhi:x1 + 1] = _SHADE
    for quarter in range(5):
        z = min(quarter * levels // 4, levels - 1)  # 0, 64, 128, 192, 255 for 8-bit
        x = int(round(px(z)))
        _vline(img, x, y0, y1, _GRID)
        _vline(img, x, y1, y1 + 5, _BLACK)
        label = str(z)
        _text(img, min(max(x - _text_width(label) // 2, 0), width - _text_width(label)), y1 + 9, label)
    for g in np.arange(lo, hi + step / 2, step):
        y = int(round(py(g)))
        _hline(img, y, x0, x1, _GRID)
        _hline(img, y, x0 - 5, x0, _BLACK)
        label = _fmt_tick(g)
        _text(img, x0 - 8 - _text_width(label), y - _TEXT_HEIGHT // 2, label)
    _hline(img, y1, x0, x1, _BLACK)
    _vline(img, x0, y0, y1, _BLACK)
    # Curves, sampled once per pixel column.
    cols = np.arange(x0, x1 + 1)
    z = (cols - x0) / (x1 - x0) * (levels - 1)
    codes = np.arange(levels, dtype=np.float64)
    names = list(response.channels)[:tables.shape[0]]
    for c in range(tables.shape[0]):
        colour = _CURVE_COLOURS.get(names[c].upper(), _GREY_CURVE) if tables.shape[0] > 1 else _GREY_CURVE
        _polyline(img, cols, py(np.interp(z, codes, tables[c])), colour)
    # Titles and legend.
    _text(img, 8, 10, "G(Z) = LN EXPOSURE")
    xl = "PIXEL CODE Z (SHADED: OUTSIDE WORKING RANGE)"
    _text(img, max((x0 + x1 - _text_width(xl)) // 2, 0), height - _TEXT_HEIGHT - 6, xl)
    if tables.shape[0] > 1:
        x = x1 - 8
        for c in reversed(range(tables.shape[0])):
            label = names[c]
            x -= _text_width(label) + 22
            colour = _CURVE_COLOURS.get(label.upper(), _GREY_CURVE)
            _hline(img, 14, x, x + 14, colour, 3)
            _text(img, x + 18, 10, label)
    return img


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
    """The coverage map colour-mapped, with a legend strip below, RGB uint8.

    The map is reduced to a long side of at most ``size`` by block minimum (the worst
    pixel of each block shows) and enlarged by whole factors when small.
    """
    cov = _block_min(np.asarray(coverage, np.uint8), size)
    h, w = cov.shape
    k = max(1, min(size // max(h, w), 8))
    cov = np.repeat(np.repeat(cov, k, axis=0), k, axis=1)
    h, w = cov.shape
    lut = coverage_colours(frames)
    values = list(range(frames + 1)) + ([NO_DATA] if (cov == NO_DATA).any() else [])
    sw = 30
    title = "FRAMES MEASURING THE PIXEL"
    legend_w = max(len(values) * sw, _text_width(title)) + 16
    width = max(w, legend_w)
    strip = 2 * _TEXT_HEIGHT + 30
    img = np.full((h + strip, width, 3), 255, np.uint8)
    xm = (width - w) // 2
    img[:h, xm:xm + w] = lut[cov]
    y = h + 6
    _text(img, 8, y, title)
    y += _TEXT_HEIGHT + 4
    for i, v in enumerate(values):
        x = 8 + i * sw
        img[y:y + 14, x:x + sw - 4] = lut[v]
        label = "NA" if v == NO_DATA else str(v)
        _text(img, x + (sw - 4 - _text_width(label)) // 2, y + 17, label)
    return img
