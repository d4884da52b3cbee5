"""Exposure ladders: is a run of frames one bracket, walked in a way people shoot?

A bracket set is a *ladder* of exposures: the values, sorted, are evenly spaced
(one step, in stops) with no value twice. The axis of the ladder is

* the **exposure bias** (``ExposureBiasValue``) when it varies across the frames:
  auto bracketing, and phone auto mode with exposure compensation (time and ISO both
  follow the metering; only the bias steps exactly);
* otherwise the **exposure value** ``log2(t * ISO/100 / N**2)``: a manual ladder in the
  shutter time, or an auto-ISO ladder where ``t * ISO`` is what steps.

The order may be ascending, descending, or any order in which every prefix already is
an unbroken piece of the grid: the auto-bracketing orders ``0, -, +`` and ``0, -2, +2,
-4, +4`` (centre out), ``0, -1, -2, +1, +2``, ``-, 0, +``. A manual ladder (no auto
bracketing, no bias) must be monotonic or centre out.

:func:`ladder_of` is used to *join* runs that a long gap separated (a hand-made ladder
with 5-60 s between frames) and to explain the join. It never splits by itself.

Where the scene vouches for the frames (their thumbnails match), the order and the step
size no longer matter: :func:`distinct_of` accepts any run in which no exposure repeats
(a compact's third-stop ladder, a last step of a third of a stop, a ladder shot 1, 2,
1/2 s then on down, a moon ladder 1/4 -> 1/250 s then 1/2 -> 8 s).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import List, Optional, Sequence

from hdrcl.io.metadata import FrameInfo

__all__ = ["Ladder", "exposure_value", "ladder_of", "distinct_of", "MIN_STEP", "MAX_STEP"]

#: Smallest ladder step (stops) taken as a bracket: a third of a stop is noise in the
#: metering of phone auto mode, not a bracket.
MIN_STEP = 0.45
#: Largest ladder step (stops).
MAX_STEP = 4.5
# Nominal shutter speeds and ISO values are rounded (1/60 is 2**-5.9): values closer
# than this many stops are the same.
_TOL = 0.22
# Two exposures closer than this (stops) repeat each other (as ``_STOP_TOL`` of
# hdrcl.shoot.grouping.compare: nominal third stops such as 1/15 and 1/13 s are 0.21 stops apart);
# two exposure bias values closer than _BIAS_REPEAT EV repeat each other.
_REPEAT = 0.15
_BIAS_REPEAT = 0.1


@dataclass(frozen=True)
class Ladder:
    """A run of frames that forms one exposure ladder.

    Attributes
    ----------
    axis : str
        ``"bias"`` or ``"exposure"`` (``t * ISO / N**2``).
    step : float
        Spacing of the ladder in stops.
    order : str
        ``"ascending"``, ``"descending"`` or ``"bracket order"`` (centre out and the
        other auto-bracketing orders).
    values : tuple of float
        The frames' positions on the axis, relative to the first frame.
    """

    axis: str
    step: float
    order: str
    values: tuple

    def describe(self) -> str:
        """``"exposure ladder, 1 EV steps, descending"`` and the like."""
        what = "bias ladder" if self.axis == "bias" else "exposure ladder"
        return f"{what}, {self.step:.2g} EV steps, {self.order}"


def exposure_value(f: FrameInfo) -> Optional[float]:
    """``log2(t * ISO/100 / N**2)``; unknown ISO or f-number count as constant."""
    t = f.exposure_time
    if t is None or not t > 0:
        return None
    v = math.log2(t)
    if f.iso and f.iso > 0:
        v += math.log2(f.iso / 100.0)
    if f.fnumber and f.fnumber > 0:
        v -= 2.0 * math.log2(f.fnumber)
    return v


def _axis(frames: Sequence[FrameInfo]):
    biases = [f.exposure_bias for f in frames]
    if all(b is not None for b in biases) and max(biases) - min(biases) > 0.1:
        return "bias", [float(b) for b in biases]
    values = [exposure_value(f) for f in frames]
    if any(v is None for v in values):
        return None, None
    return "exposure", values


def _positions(frames: List[FrameInfo]):
    """``(axis, values, sorted values, their differences)`` of two or more frames at one
    aperture; ``(None, None, None, None)`` otherwise."""
    none = (None, None, None, None)
    if len(frames) < 2:
        return none
    fn = [f.fnumber for f in frames if f.fnumber]
    if fn and any(abs(2 * math.log2(n / fn[0])) > 0.3 for n in fn):
        return none
    axis, values = _axis(frames)
    if axis is None:
        return none
    s = sorted(values)
    return axis, values, s, [b - a for a, b in zip(s, s[1:])]


def _even(sorted_vals: List[float], step: float) -> bool:
    tol = max(_TOL, 0.15 * step)
    return all(abs((b - a) - step) <= tol for a, b in zip(sorted_vals, sorted_vals[1:]))


def ladder_of(frames: Sequence[FrameInfo], even: bool = True) -> Optional[Ladder]:
    """The ladder ``frames`` (capture order, one camera) form, or None.

    None when: fewer than two frames, the aperture changes, a value is missing or
    repeats, the sorted values are not evenly spaced, the step is below
    :data:`MIN_STEP` or above :data:`MAX_STEP` stops, or the order is not one people
    shoot (see the module docstring). With ``even=False`` a monotonic run whose every
    step lies between those limits also counts (a hand-turned dial is not always even;
    used when the scene vouches for the frames), with ``order`` ``"ascending, uneven"``
    or ``"descending, uneven"``.
    """
    frames = list(frames)
    axis, values, s, diffs = _positions(frames)
    if axis is None or min(diffs) < _TOL:
        return None  # no ladder, or a value repeats
    step = sorted(diffs)[len(diffs) // 2]
    if not even and not _even(s, step):
        return _uneven(axis, values)
    if not MIN_STEP <= step <= MAX_STEP or not _even(s, step):
        return None
    # Every prefix must be an unbroken piece of the grid.
    for k in range(2, len(values)):
        if not _even(sorted(values[:k]), step):
            return None
    steps = [b - a for a, b in zip(values, values[1:])]
    if all(d > 0 for d in steps):
        order = "ascending"
    elif all(d < 0 for d in steps):
        order = "descending"
    else:
        order = "bracket order"
        auto = axis == "bias" or any(f.exposure_mode == 2 for f in frames)
        if not auto and not _centre_out(values, step):
            return None
    v0 = values[0]
    return Ladder(axis=axis, step=round(step, 2), order=order,
                  values=tuple(round(v - v0, 2) for v in values))


def distinct_of(frames: Sequence[FrameInfo]) -> Optional[Ladder]:
    """The frames as one ladder in any order and with any step, or None: what the scene
    vouches for (see the module docstring).

    None when: fewer than two frames, the aperture changes, a value is missing, two
    values repeat each other (closer than 0.15 stops, or 0.1 EV of exposure bias), the
    sorted values leave a hole wider than :data:`MAX_STEP` stops (no frame overlaps the
    next), or, in auto exposure without a varying bias, two values lie closer than
    :data:`MIN_STEP` (the metering's drift, not a bracket). ``order`` is
    ``"ascending"``, ``"descending"`` or ``"any order"``; ``step`` the median spacing.
    """
    frames = list(frames)
    axis, values, s, diffs = _positions(frames)
    if axis is None:
        return None
    least = _BIAS_REPEAT if axis == "bias" else _REPEAT
    if axis == "exposure" and all(f.exposure_mode == 0 for f in frames):
        least = MIN_STEP
    if min(diffs) < least or max(diffs) > MAX_STEP:
        return None
    steps = [b - a for a, b in zip(values, values[1:])]
    order = ("ascending" if all(d > 0 for d in steps) else "descending" if all(d < 0 for d in steps)
             else "any order")
    v0 = values[0]
    return Ladder(axis=axis, step=round(sorted(diffs)[len(diffs) // 2], 2), order=order,
                  values=tuple(round(v - v0, 2) for v in values))


def _uneven(axis: str, values: Sequence[float]) -> Optional[Ladder]:
    """A monotonic run with every step within [MIN_STEP, MAX_STEP] stops, or None."""
    steps = [b - a for a, b in zip(values, values[1:])]
    if all(MIN_STEP <= d <= MAX_STEP for d in steps):
        order = "ascending, uneven"
    elif all(MIN_STEP <= -d <= MAX_STEP for d in steps):
        order = "descending, uneven"
    else:
        return None
    mags = sorted(abs(d) for d in steps)
    v0 = values[0]
    return Ladder(axis=axis, step=round(mags[len(mags) // 2], 2), order=order,
                  values=tuple(round(v - v0, 2) for v in values))


def _centre_out(values: Sequence[float], step: float) -> bool:
    """``0, -s, +s, -2s, +2s...`` or ``0, +s, -s, ...`` (by hand, imitating AEB)."""
    v0 = values[0]
    rel = [(v - v0) / step for v in values]
    for k, r in enumerate(rel[1:], start=1):
        want = (k + 1) // 2
        if abs(abs(r) - want) > 0.3:
            return False
        if k % 2 == 0 and (rel[k - 1] > 0) == (r > 0):
            return False
    return True
