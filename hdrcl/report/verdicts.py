"""Pass / warn / fail verdicts on a set's quality figures, with the thresholds in one table.

Each check compares one figure of :class:`hdrcl.report.quality.QualityFigures` with two
limits: at or below ``warn_above`` it passes, at or below ``fail_above`` it warns,
above that it fails. The page shows the table as its legend (:func:`legend_rows`), so
what is stated there is what is applied.

Why these limits (8-bit code levels; 16-bit data is measured in the same 8-bit units):

* **Leave-one-out RMSE** (levels). Rounding to 8 bits alone leaves 1/sqrt(12) = 0.29
  levels; a digital camera's noise and JPEG compression at base ISO add about 1-3, so a
  sound merge of a good set measures about 1-3 levels, and film grain more (the paper's
  Memorial set, scanned film: 4.3). Through a gamma-2.2 curve mid-grey moves about 40
  levels per stop, so 5 levels is about 1/8 stop of disagreement between the frames,
  10 levels a quarter stop: beyond that an exposure time, the response or a moving
  scene is wrong, not the noise.
* **Clipped high / clipped low** (% of pixels no frame measures, each side). Up to
  0.1 % (a light source, speculars) the dynamic range figure (0.1th to 99.9th
  percentile) is still a measurement, not a lower bound; 1 % is a region about a tenth
  of the picture's width and height with no detail at all.
* **Thin coverage** (% of pixels that at most one frame measures). Fusion averages the
  frames' noise and can only check a measurement against another frame (deghosting
  needs two); a ladder whose steps overlap (2 EV or less) and that spans the scene
  leaves single-frame pixels only at its two ends. A quarter of the picture measured
  once means the steps are too far apart or the scene outruns the ladder.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, List, Optional

PASS, WARN, FAIL = "pass", "warn", "fail"
#: Verdicts from best to worst.
ORDER = (PASS, WARN, FAIL)


@dataclass(frozen=True)
class Threshold:
    """One check: ``value <= warn_above`` passes, ``<= fail_above`` warns, else fails."""

    key: str
    label: str
    unit: str
    warn_above: float
    fail_above: float
    meaning: str


#: The checks, in the order the page lists them. Percentages are of the valid pixels.
THRESHOLDS = (
    Threshold("loo", "Leave-one-out RMSE", "levels", 5.0, 10.0,
              "8-bit levels; noise and quantisation give about 1-3 (scanned film: 4.3); "
              "5 is about 1/8 stop at mid-grey, 10 about 1/4 stop"),
    Threshold("clipped", "Clipped high / low", "%", 0.1, 1.0,
              "pixels no frame measures, each side; up to 0.1 % the dynamic range is still measured"),
    Threshold("coverage", "Thin coverage", "%", 5.0, 25.0,
              "pixels at most one frame measures: no averaging, no cross-check"),
)

_BY_KEY = {t.key: t for t in THRESHOLDS}


def grade(key: str, value: Optional[float]) -> Optional[str]:
    """The verdict of check ``key`` (see :data:`THRESHOLDS`) for ``value``; None when
    the value is unknown (None or NaN). Each limit belongs to the better verdict."""
    t = _BY_KEY[key]
    if value is None or not math.isfinite(float(value)):
        return None
    v = float(value)
    if v <= t.warn_above:
        return PASS
    return WARN if v <= t.fail_above else FAIL


def thin_coverage_percent(figures) -> Optional[float]:
    """Percent of the valid pixels that at most one frame measures (coverage 0 or 1),
    from ``figures.coverage_histogram``; None when unknown."""
    hist = list(figures.coverage_histogram or [])
    if not hist or not figures.valid_pixels:
        return None
    return 100.0 * sum(hist[:2]) / figures.valid_pixels


def grade_figures(figures) -> Dict[str, Optional[str]]:
    """Verdicts of a :class:`~hdrcl.report.quality.QualityFigures`, keyed by the row
    labels of :func:`hdrcl.report.sheet.format_figures` they colour: ``Leave-one-out
    RMSE``, ``Clipped high``, ``Clipped low``, ``Thin coverage``."""
    return {
        "Leave-one-out RMSE": grade("loo", figures.loo_rmse),
        "Clipped high": grade("clipped", 100.0 * figures.clipped_high_fraction),
        "Clipped low": grade("clipped", 100.0 * figures.clipped_low_fraction),
        "Thin coverage": grade("coverage", thin_coverage_percent(figures)),
    }


def worst(verdicts) -> Optional[str]:
    """The worst of ``verdicts`` (None entries ignored), or None when there is none."""
    known = [v for v in verdicts if v is not None]
    return max(known, key=ORDER.index) if known else None


def _limit(v: float, unit: str) -> str:
    return f"{v:g} {unit}" if unit != "%" else f"{v:g} %"


def legend_rows() -> List[tuple]:
    """``(label, pass text, warn text, fail text, meaning)`` per check, for the page."""
    return [(t.label, f"≤ {_limit(t.warn_above, t.unit)}", f"≤ {_limit(t.fail_above, t.unit)}",
             f"> {_limit(t.fail_above, t.unit)}", t.meaning) for t in THRESHOLDS]
