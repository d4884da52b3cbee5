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

Every verdict states its cause (:class:`Verdict`, :func:`verdicts`): the figure, its value
and the limit it passed or stayed within (``"Clipped high 4.7 % > 1 %: ..."``), with what
the figure means for the set and what to try. The set page and the contact sheet show the
causes of a set's warn and fail verdicts under its badge, and ``report.json`` (the
``quality`` block) and the set's JSON carry them as ``verdicts``.
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
    #: What a figure over ``warn_above`` means and what to try, in a few words.
    remedy: str = ""


#: The checks, in the order the page lists them. Percentages are of the valid pixels.
THRESHOLDS = (
    Threshold("loo", "Leave-one-out RMSE", "levels", 5.0, 10.0,
              "8-bit levels; noise and quantisation give about 1-3 (scanned film: 4.3); "
              "5 is about 1/8 stop at mid-grey, 10 about 1/4 stop",
              "the frames disagree with each other: a wrong exposure time, the response, or movement "
              "(see the warnings; try --align or --deghost)"),
    Threshold("clipped", "Clipped high / low", "%", 0.1, 1.0,
              "pixels no frame measures, each side; up to 0.1 % the dynamic range is still measured",
              "no frame measures them: the bracket needs a {side} exposure"),
    Threshold("coverage", "Thin coverage", "%", 5.0, 25.0,
              "pixels at most one frame measures: no averaging, no cross-check",
              "the exposure steps are too far apart or the scene outruns the ladder"),
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


@dataclass(frozen=True)
class Verdict:
    """A graded figure and why: ``label`` (the row), ``verdict``, ``value`` in ``unit``,
    and the ``limit`` that decided it (the pass limit for pass and warn, the fail limit
    for fail)."""

    key: str
    label: str
    verdict: str
    value: float
    unit: str
    limit: float
    remedy: str = ""

    @property
    def why(self) -> str:
        """``"Clipped high 4.70 % > 1 %: no frame measures them: ..."``: the figure, its value,
        the limit it passed (or stayed within, for pass) and, unless it passed, what it means."""
        over = self.verdict != PASS
        text = f"{self.label} {_value(self.value, self.unit)} {'>' if over else '≤'} {_limit(self.limit, self.unit)}"
        return f"{text}: {self.remedy}" if over and self.remedy else text

    def to_dict(self) -> dict:
        return {"check": self.key, "figure": self.label, "verdict": self.verdict, "value": round(self.value, 4),
                "unit": self.unit, "limit": self.limit, "why": self.why}


def verdict(key: str, label: str, value: Optional[float], **fmt) -> Optional[Verdict]:
    """The :class:`Verdict` of check ``key`` for ``value`` (row ``label``); None when
    the value is unknown. ``fmt`` fills the remedy's fields (``side``)."""
    v = grade(key, value)
    if v is None:
        return None
    t = _BY_KEY[key]
    return Verdict(key, label, v, float(value), t.unit, t.fail_above if v == FAIL else t.warn_above,
                   t.remedy.format(**fmt) if fmt else t.remedy)


def verdicts(figures) -> Dict[str, Optional[Verdict]]:
    """:class:`Verdict` per graded row of a :class:`~hdrcl.report.quality.QualityFigures`
    (the keys of :func:`grade_figures`; None where the figure is unknown)."""
    return {
        "Leave-one-out RMSE": verdict("loo", "Leave-one-out RMSE", figures.loo_rmse),
        "Clipped high": verdict("clipped", "Clipped high", 100.0 * figures.clipped_high_fraction, side="shorter"),
        "Clipped low": verdict("clipped", "Clipped low", 100.0 * figures.clipped_low_fraction, side="longer"),
        "Thin coverage": verdict("coverage", "Thin coverage", thin_coverage_percent(figures)),
    }


def causes(figures) -> List[Verdict]:
    """The verdicts that make the set's worst one (warn or fail), worst first: why the
    set is not a pass. Empty when it passes or nothing was graded."""
    graded = [v for v in verdicts(figures).values() if v is not None and v.verdict != PASS]
    top = worst(v.verdict for v in graded)
    return sorted((v for v in graded if v.verdict == top), key=lambda v: -v.value / max(v.limit, 1e-12))


def verdicts_dict(figures) -> dict:
    """JSON of the verdicts (``report.json``'s ``quality`` block, the set's JSON): the
    worst, the causes' lines and every graded figure with its value and limit."""
    vs = [v for v in verdicts(figures).values() if v is not None]
    return {"verdict": worst(v.verdict for v in vs), "causes": [v.why for v in causes(figures)],
            "figures": [v.to_dict() for v in vs]}


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


def _value(v: float, unit: str) -> str:
    return f"{v:.2f} {unit}" if unit != "%" else f"{v:.2f} %"


def legend_rows() -> List[tuple]:
    """``(label, pass text, warn text, fail text, meaning)`` per check, for the page."""
    return [(t.label, f"≤ {_limit(t.warn_above, t.unit)}", f"≤ {_limit(t.fail_above, t.unit)}",
             f"> {_limit(t.fail_above, t.unit)}", t.meaning) for t in THRESHOLDS]
