"""Does ``--lens-circle`` fit the image's dark border?

A circular fisheye leaves the sensor black outside its circle (vignetting takes the rim
down, but the border beyond it is near black). A circle measured on another camera, or
given in another convention, is off by a few per cent of its radius, and the map then
silently holds black border or loses sky (the documentation's example circle on another
camera gives +9 % luminance). :class:`BorderMeter` watches the fused strips on their way
into the chain: the mean of a ring just outside the circle (1.02-1.05 of its radius)
against a ring just inside it (0.95-0.98). Outside more than
:data:`MAX_OUTSIDE_SHARE` of inside (not dark, or the rim inside dark) says the circle
does not fit, as a finding of severity ``check`` (:func:`lens_circle_finding`).

Only the pixels of the image count; a ring with fewer than :data:`MIN_PIXELS` pixels in
the image (a circle larger than the frame) is not judged. Rows and columns are taken
every ``step`` pixels (about 500 samples across the radius), so the cost is small.
"""
from __future__ import annotations

import logging
import math
import os
from typing import Optional, Tuple

import numpy as np

from hdrcl.core.findings import CHECK, Finding

logger = logging.getLogger(__name__)

#: The rings, in units of the circle's radius.
INSIDE, OUTSIDE = (0.95, 0.98), (1.02, 1.05)
#: Outside mean above this share of the inside mean: the circle does not fit the border.
MAX_OUTSIDE_SHARE = 0.2
#: Fewest pixels of a ring within the image for a verdict.
MIN_PIXELS = 20


class BorderMeter:
    """Sums of the fused values in the two rings, strip by strip."""

    def __init__(self, cx: float, cy: float, diameter: float, height: int, width: int):
        self.cx, self.cy, self.radius = float(cx), float(cy), diameter / 2.0
        self.step = max(1, int(self.radius // 500))
        reach = OUTSIDE[1] * self.radius + 1.0
        self.rows = (max(0, int(math.floor(self.cy - reach))), min(height, int(math.ceil(self.cy + reach))))
        self.cols = (max(0, int(math.floor(self.cx - reach))), min(width, int(math.ceil(self.cx + reach))))
        self.sums = np.zeros(2)
        self.counts = np.zeros(2, np.int64)

    def add(self, y0: int, data: np.ndarray) -> None:
        """Take the rows ``y0 ..`` of the fused image (``(rows, width, channels)``)."""
        a, b = max(y0, self.rows[0]), min(y0 + data.shape[0], self.rows[1])
        a += (-a) % self.step  # the same sample rows whatever the strips
        c0, c1 = self.cols
        if a >= b or c0 >= c1:
            return
        block = np.asarray(data[a - y0:b - y0:self.step, c0:c1:self.step], np.float64)
        v = block.mean(axis=2) if block.ndim == 3 else block
        ys = np.arange(a, b, self.step, dtype=np.float64)[:v.shape[0]] + 0.5 - self.cy
        xs = np.arange(c0, c1, self.step, dtype=np.float64)[:v.shape[1]] + 0.5 - self.cx
        rr = np.hypot(ys[:, None], xs[None, :]) / self.radius
        ok = np.isfinite(v)
        for k, (lo, hi) in enumerate((INSIDE, OUTSIDE)):
            ring = (rr >= lo) & (rr <= hi) & ok
            self.sums[k] += float(v[ring].sum())
            self.counts[k] += int(ring.sum())

    def means(self) -> Optional[Tuple[float, float]]:
        """``(outside, inside)`` means, or None when a ring has too few pixels in the image."""
        if self.counts.min() < MIN_PIXELS:
            return None
        inside, outside = self.sums / self.counts
        return float(outside), float(inside)

    def fits(self) -> Optional[bool]:
        """False when the outside ring is not dark against the inside one; None: not judged."""
        m = self.means()
        if m is None:
            return None
        outside, inside = m
        return bool(inside > 0 and outside <= MAX_OUTSIDE_SHARE * inside)


def lens_circle_finding(meter: Optional[BorderMeter], circle, file) -> Optional[Finding]:
    """A ``check`` finding when the circle does not fit the dark border of ``file``'s
    merged image (one line: the option's value, the file, both means, what to try)."""
    if meter is None or meter.means() is None:
        return None
    outside, inside = meter.means()
    logger.info("--lens-circle: mean just outside the circle %.3g cd/m^2, just inside %.3g", outside, inside)
    if meter.fits():
        return None
    cx, cy, d = circle
    share = 100.0 * outside / inside if inside > 0 else None
    name = os.path.basename(os.fspath(file))
    said = f", {share:.0f} % of inside" if share is not None else ", the rim inside dark"
    return Finding("lens-circle",
                   f"--lens-circle {cx:g},{cy:g},{d:g} does not fit the dark border of {name} (mean outside the "
                   f"circle {outside:.3g} cd/m^2, inside {inside:.3g}{said}): check the circle for this camera "
                   f"(docs/luminance.md, 'The lens circle')",
                   severity=CHECK, file=name, figure=share)
