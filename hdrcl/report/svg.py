"""Small SVG charts for the quality report: lines, bars, shaded spans, marker lines.

The report's plots are vector drawings whose text the browser sets in its own fonts,
so they stay sharp and readable at any zoom and need no plotting library. Every text is
XML-escaped; numbers are written with fixed precision, so the same data always gives
the same bytes.
"""
from __future__ import annotations

import html
import math
from dataclasses import dataclass, field
from typing import List, Optional, Sequence, Tuple

import numpy as np

__all__ = ["Chart", "nice_ticks"]

FONT = 'font-family="system-ui,-apple-system,Segoe UI,Roboto,Helvetica,Arial,sans-serif"'
INK, GRID, SHADE = "#222", "#e2e2e2", "#f1f1f1"


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def nice_ticks(lo: float, hi: float, max_ticks: int = 7) -> List[float]:
    """Round tick values (1, 2, 5 x 10^k steps) covering ``[lo, hi]``."""
    span = max(hi - lo, 1e-9)
    raw = span / max(max_ticks - 1, 1)
    mag = 10.0 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 5, 10) if m * mag >= raw)
    first = math.ceil(lo / step - 1e-9) * step
    ticks = []
    v = first
    while v <= hi + 1e-9 * step:
        ticks.append(0.0 if abs(v) < 1e-12 * step else v)
        v += step
    return ticks


def _fmt(v: float) -> str:
    return f"{v:.0f}" if abs(v - round(v)) < 1e-9 else f"{v:g}"


@dataclass
class Chart:
    """An x-y chart; add series, bars, spans and markers, then :meth:`svg`."""

    title: str
    xlabel: str
    ylabel: str
    xlim: Tuple[float, float]
    ylim: Tuple[float, float]
    width: int = 560
    height: int = 360
    xticks: Optional[Sequence[float]] = None
    _items: List[str] = field(default_factory=list)
    _legend: List[Tuple[str, str]] = field(default_factory=list)
    _markers: List[Tuple[float, str, str]] = field(default_factory=list)
    _spans: List[Tuple[float, float]] = field(default_factory=list)

    left, right, top, bottom = 62, 16, 40, 52

    def _x(self, x):
        x0, x1 = self.xlim
        return self.left + (np.asarray(x, np.float64) - x0) / (x1 - x0) * (self.width - self.left - self.right)

    def _y(self, y):
        y0, y1 = self.ylim
        return self.height - self.bottom - (np.asarray(y, np.float64) - y0) / (y1 - y0) * (
            self.height - self.top - self.bottom)

    def line(self, x, y, colour: str, label: Optional[str] = None, width: float = 2.0) -> None:
        """A polyline through ``(x, y)`` (non-finite points break it)."""
        xs, ys = self._x(x), self._y(np.clip(y, *self.ylim))
        ok = np.isfinite(xs) & np.isfinite(ys)
        runs, cur = [], []
        for px, py, good in zip(xs, ys, ok):
            if good:
                cur.append(f"{px:.1f},{py:.1f}")
            elif cur:
                runs.append(cur)
                cur = []
        if cur:
            runs.append(cur)
        for r in runs:
            self._items.append(f'<polyline fill="none" stroke="{colour}" stroke-width="{width:g}" '
                               f'stroke-linejoin="round" points="{" ".join(r)}"/>')
        if label:
            self._legend.append((label, colour))

    def bars(self, edges, heights, colour: str, label: Optional[str] = None) -> None:
        """Bars between consecutive ``edges`` with the given ``heights``."""
        xs = self._x(edges)
        base = float(self._y(self.ylim[0]))
        for k, h in enumerate(heights):
            if h <= 0:
                continue
            top = float(self._y(min(h, self.ylim[1])))
            self._items.append(f'<rect x="{xs[k]:.1f}" y="{top:.1f}" width="{max(xs[k + 1] - xs[k], 0.5):.1f}" '
                               f'height="{base - top:.1f}" fill="{colour}"/>')
        if label:
            self._legend.append((label, colour))

    def span(self, x0: float, x1: float) -> None:
        """Shade the plot between ``x0`` and ``x1``."""
        self._spans.append((x0, x1))

    def marker(self, x: float, label: str, colour: str) -> None:
        """A dashed vertical line at ``x`` with a label at its top."""
        self._markers.append((x, label, colour))

    def svg(self, desc: str = "") -> str:
        w, h = self.width, self.height
        px0, px1 = self.left, w - self.right
        py0, py1 = self.top, h - self.bottom
        out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" '
               f'{FONT} font-size="13">',
               f"<title>{_e(self.title)}</title>" + (f"<desc>{_e(desc)}</desc>" if desc else ""),
               f'<rect width="{w}" height="{h}" fill="#fff"/>']
        for a, b in self._spans:
            xa, xb = float(self._x(max(a, self.xlim[0]))), float(self._x(min(b, self.xlim[1])))
            if xb > xa:
                out.append(f'<rect x="{xa:.1f}" y="{py0}" width="{xb - xa:.1f}" height="{py1 - py0}" fill="{SHADE}"/>')
        xt = list(self.xticks) if self.xticks is not None else nice_ticks(*self.xlim)
        for v in xt:
            x = float(self._x(v))
            out.append(f'<line x1="{x:.1f}" y1="{py0}" x2="{x:.1f}" y2="{py1}" stroke="{GRID}"/>')
            out.append(f'<text x="{x:.1f}" y="{py1 + 18}" text-anchor="middle" fill="{INK}">{_e(_fmt(v))}</text>')
        for v in nice_ticks(*self.ylim, max_ticks=6):
            y = float(self._y(v))
            out.append(f'<line x1="{px0}" y1="{y:.1f}" x2="{px1}" y2="{y:.1f}" stroke="{GRID}"/>')
            out.append(f'<text x="{px0 - 6}" y="{y + 4:.1f}" text-anchor="end" fill="{INK}">{_e(_fmt(v))}</text>')
        out.append(f'<clipPath id="plot"><rect x="{px0}" y="{py0}" width="{px1 - px0}" height="{py1 - py0}"/>'
                   f'</clipPath><g clip-path="url(#plot)">')
        out.extend(self._items)
        out.append("</g>")
        for x, label, colour in self._markers:
            xm = float(self._x(x))
            if not (px0 - 1 <= xm <= px1 + 1):
                continue
            out.append(f'<line x1="{xm:.1f}" y1="{py0 - 4}" x2="{xm:.1f}" y2="{py1}" stroke="{colour}" '
                       f'stroke-width="1.5" stroke-dasharray="5 3"/>')
            anchor = "end" if xm > (px0 + px1) / 2 else "start"
            dx = -4 if anchor == "end" else 4
            out.append(f'<text x="{xm + dx:.1f}" y="{py0 + 12}" text-anchor="{anchor}" font-size="12" '
                       f'fill="{colour}">{_e(label)}</text>')
        out.append(f'<rect x="{px0}" y="{py0}" width="{px1 - px0}" height="{py1 - py0}" fill="none" stroke="{INK}"/>')
        out.append(f'<text x="{px0}" y="22" font-size="15" font-weight="600" fill="{INK}">{_e(self.title)}</text>')
        x = px1
        for label, colour in reversed(self._legend):
            tw = 8 * len(label) + 4
            x -= tw
            out.append(f'<text x="{x:.0f}" y="22" fill="{INK}">{_e(label)}</text>')
            x -= 22
            out.append(f'<rect x="{x:.0f}" y="14" width="16" height="4" fill="{colour}"/>')
            x -= 10
        out.append(f'<text x="{(px0 + px1) / 2:.0f}" y="{h - 12}" text-anchor="middle" fill="{INK}">'
                   f'{_e(self.xlabel)}</text>')
        out.append(f'<text transform="translate(16 {(py0 + py1) / 2:.0f}) rotate(-90)" text-anchor="middle" '
                   f'fill="{INK}">{_e(self.ylabel)}</text>')
        out.append("</svg>")
        return "\n".join(out) + "\n"
