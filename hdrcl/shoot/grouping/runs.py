"""What ends a run of frames, in one camera's stream (pass 1 of
:mod:`hdrcl.shoot.grouping.splitting`), and the runs themselves.

A run (:class:`_Group`) keeps its frames, the reason it ended and why each frame after
the first joined it. The reasons: lens, focal length or image size changed
(:func:`_camera_reason`); exposure mode or aperture changed, an exposure (or exposure
bias) repeats, a hand ladder turns back or an auto bracket's pattern restarts
(:func:`_pattern_reason`); the scene changed (:func:`_content_reason`); a gap longer than
:func:`_gap_limit`. A frame that repeats the frame before is a duplicate (:func:`unique`).
The passes that join runs back are :mod:`hdrcl.shoot.grouping.bridges` and
:mod:`hdrcl.shoot.grouping.strays`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, List, Optional

from hdrcl.io.metadata import FrameInfo
from hdrcl.shoot.grouping.compare import (DEFAULT_GAP, LONG_EXPOSURE, NR_FACTOR, _BIAS_TOL, _MODE_NAMES, _STOP_TOL, _fmt_bias, _fmt_f,
                                 _gap, _norm, _same_bias, _same_settings, _same_stops, _varies)
from hdrcl.shoot.grouping.ladder import MAX_STEP, MIN_STEP, exposure_value, ladder_of


# compare(a, b) -> hdrcl.shoot.grouping.scene.Verdict, or None: no content signal.
Compare = Optional[Callable[[FrameInfo, FrameInfo], object]]


@dataclass
class _Group:
    frames: List[FrameInfo]
    reason: str
    gaps: list
    joins: list = field(default_factory=list)  # why each frame after the first joined
    left: list = field(default_factory=list)  # frames left out of it (hdrcl.shoot.grouping.strays)


def _gap_limit(prev: FrameInfo, override: Optional[float]) -> float:
    if override is not None:
        return override
    limit = DEFAULT_GAP
    if (prev.exposure_time or 0.0) >= LONG_EXPOSURE:
        limit += NR_FACTOR * prev.exposure_time  # the dark frame, and processing that grows with it
    return limit


def _hard_reason(cur: List[FrameInfo], f: FrameInfo) -> Optional[str]:
    """What ends the set whatever the gap and the scene: settings, repeats, an auto
    bracket's pattern broken (a hand ladder turning back is not: the bridges decide)."""
    return _camera_reason(cur[-1], f) or _pattern_reason(cur, f, turns=False)


def _camera_reason(prev: FrameInfo, f: FrameInfo) -> Optional[str]:
    """Lens, focal length or image size changed."""
    if _norm(prev.lens) != _norm(f.lens):
        return f"lens changed ({prev.lens or '?'} -> {f.lens or '?'})"
    if (prev.focal_length is None) != (f.focal_length is None) or (
            prev.focal_length is not None
            and abs(prev.focal_length - f.focal_length) > 0.005 * prev.focal_length):
        a, b = (f"{v:g}" if v is not None else "?" for v in (prev.focal_length, f.focal_length))
        return f"focal length changed ({a} -> {b} mm)"
    if (prev.width, prev.height) != (f.width, f.height):
        return f"image size changed ({prev.width}x{prev.height} -> {f.width}x{f.height})"
    return None


def _pattern_reason(cur: List[FrameInfo], f: FrameInfo, turns: bool = True) -> Optional[str]:
    """Exposure mode or aperture changed, an exposure repeats, the ladder restarts (a
    hand ladder turning back only with ``turns``)."""
    prev = cur[-1]
    if _mode_change(prev, f) and 2 in (prev.exposure_mode, f.exposure_mode):
        return _mode_change(prev, f)
    compensated = _compensation_duplicate(cur, f)
    for k, g in enumerate(cur):
        if _same_settings(g, f) and not compensated:
            return ("exposure repeats first frame" if k == 0
                    else f"exposure repeats frame {k + 1} of the set")
    biases = [g.exposure_bias for g in cur]
    if f.exposure_bias is not None and _varies(biases, _same_bias):
        if any(_same_bias(b, f.exposure_bias) for b in biases):
            return f"exposure bias repeats ({_fmt_bias(f.exposure_bias)} EV)"
    times = [g.exposure_time for g in cur]
    if (len(cur) >= 2 and f.fnumber is not None and None not in times
            and _varies(times, _same_stops)
            and not _varies([g.fnumber for g in cur], lambda a, b: _same_stops(a, b, 2.0))
            and not _same_stops(prev.fnumber, f.fnumber, 2.0)):
        return f"aperture changed ({_fmt_f(prev.fnumber)} -> {_fmt_f(f.fnumber)})"
    cur = unique(cur)  # a duplicate kept in the set (pass 2) is no step of its ladder
    if turns and _ladder_turns(cur, f):
        return "exposure ladder restarts"
    if _bias_pattern_breaks(cur, f):
        return ("bracket pattern restarts (" + (f"{_fmt_bias(f.exposure_bias)} EV" if f.exposure_bias is not None
                                                 else "exposure") + " off the set's steps)")
    return None


def _compensation_duplicate(cur: List[FrameInfo], f: FrameInfo) -> bool:
    """``f`` repeats the settings of the frame before with a new exposure compensation
    that carries the set's compensation on one way: a phone in auto mode whose metering
    gives two neighbouring compensation steps one (shutter, ISO) pair. A duplicate."""
    prev = cur[-1]
    if f.exposure_bias is None or not _same_settings(prev, f):
        return False
    biases = [g.exposure_bias for g in cur] + [f.exposure_bias]
    if any(b is None for b in biases):
        return False
    steps = [b - a for a, b in zip(biases, biases[1:])]
    return all(d >= _BIAS_TOL for d in steps) or all(d <= -_BIAS_TOL for d in steps)


def _mode_change(prev: FrameInfo, f: FrameInfo) -> Optional[str]:
    """``"exposure mode changed (auto -> manual)"`` and the like, or None."""
    a, b = prev.exposure_mode, f.exposure_mode
    if a is None or b is None or a == b:
        return None
    return f"exposure mode changed ({_MODE_NAMES.get(a, a)} -> {_MODE_NAMES.get(b, b)})"


def _soft(reason: str) -> bool:
    """A run ended by a long gap, by a change between auto and manual exposure or by a
    hand ladder turning back: the bridges (pass 3) may join it with the next when the
    ladder and the scene continue."""
    return (reason.startswith("gap ") or reason.startswith("exposure mode changed")
            or reason == "exposure ladder restarts")


def unique(frames: List[FrameInfo]) -> List[FrameInfo]:
    """``frames`` without the frames that repeat the exposure of the frame before."""
    out = frames[:1]
    for f in frames[1:]:
        if not _duplicate(out[-1], f):
            out.append(f)
    return out


def _duplicate(a: FrameInfo, b: FrameInfo) -> bool:
    """``b`` repeats ``a``: the same settings (and bias), or, in auto exposure with
    compensation (time and ISO follow the metering), the same bias within half a stop."""
    known = a.exposure_bias is not None and b.exposure_bias is not None
    if known and not _same_bias(a.exposure_bias, b.exposure_bias):
        return False
    if _same_settings(a, b):
        return True
    if not known or a.exposure_mode != 0 or b.exposure_mode != 0:
        return False
    va, vb = exposure_value(a), exposure_value(b)
    return va is not None and vb is not None and abs(va - vb) < 0.5


def _ladder_turns(cur: List[FrameInfo], f: FrameInfo) -> bool:
    """A hand-made monotonic ladder of 3+ frames that ``f`` walks back on.

    Auto-bracketing orders such as ``0, -1, -2, +1, +2`` are not monotonic, so this only
    applies when no frame is marked as auto bracketed and the bias does not vary.
    """
    if len(cur) < 3:
        return False
    frames = cur + [f]
    if any(g.exposure_mode == 2 for g in frames):
        return False
    if _varies([g.exposure_bias for g in frames], lambda a, b: abs(a - b) < _BIAS_TOL):
        return False
    values = [exposure_value(g) for g in frames]
    if any(v is None for v in values):
        return False
    steps = [b - a for a, b in zip(values, values[1:])]
    ladder, last = steps[:-1], steps[-1]
    if all(s > _STOP_TOL for s in ladder):
        return last < -_STOP_TOL
    if all(s < -_STOP_TOL for s in ladder):
        return last > _STOP_TOL
    return False


def _bias_pattern_breaks(cur: List[FrameInfo], f: FrameInfo) -> bool:
    """An auto bracket of 3+ frames (an exact pattern) that ``f`` does not extend.

    ``0, -2, +2, -4, +4`` followed by ``-1``: the camera started the next bracket with
    another step. Only when the set so far is a clean ladder in the exposure bias, or
    (auto bracketing that records no bias) in the exposure itself: ``1/100, 1/200, 1/50``
    followed by ``1/125`` is the next bracket, metered a third of a stop darker.
    """
    if len(cur) < 3:
        return False
    lad = ladder_of(cur)
    if lad is None:
        return False
    if lad.axis != "bias" and not all(g.exposure_mode == 2 for g in cur + [f]):
        return False
    if lad.axis == "bias" and f.exposure_bias is None:
        return False
    if _extends(lad, cur, f):
        return False
    return ladder_of(cur + [f]) is None


def _extends(lad, cur: List[FrameInfo], f: FrameInfo) -> bool:
    """``f`` carries a one-way ladder on past its end by a plausible step (a phone that
    reaches its longest shutter time and goes on in ISO from its own table of values
    steps unevenly): no new bracket starts there."""
    if lad.order not in ("ascending", "descending"):
        return False
    if lad.axis == "bias":
        a, b = cur[-1].exposure_bias, f.exposure_bias
    else:
        a, b = exposure_value(cur[-1]), exposure_value(f)
    if a is None or b is None:
        return False
    step = (b - a) if lad.order == "ascending" else (a - b)
    return MIN_STEP <= step <= MAX_STEP


def _content_reason(cur: List[FrameInfo], f: FrameInfo, compare: Compare):
    """The scene verdict of ``f`` against the frame of ``cur`` nearest in exposure."""
    if compare is None:
        return None
    ref = _nearest(cur, f)
    return compare(ref, f)


def _nearest(cur: List[FrameInfo], f: FrameInfo) -> FrameInfo:
    v = exposure_value(f)
    if v is None:
        return cur[-1]
    best = min(cur[::-1], key=lambda g: abs((exposure_value(g) or 1e9) - v))
    return best


def _fmt_gap(g: Optional[float]) -> str:
    return "no capture time" if g is None else f"gap {g:.1f} s"


def _joined(a: _Group, b: _Group, why: str) -> _Group:
    return _Group(a.frames + b.frames, b.reason, a.gaps + [_gap(a.frames[-1], b.frames[0])] + b.gaps,
                  a.joins + [why] + b.joins, a.left + b.left)


def _nearest_pair(a: List[FrameInfo], b: List[FrameInfo]):
    """The frame of ``a`` and the frame of ``b`` nearest each other in exposure (the
    latest of ``a`` and the earliest of ``b`` on ties): the pair whose thumbnails have
    the most cells well exposed in both."""
    best, pair = None, (a[-1], b[0])
    for j, y in enumerate(b):
        vy = exposure_value(y)
        for i in range(len(a) - 1, -1, -1):
            vx = exposure_value(a[i])
            if vx is None or vy is None:
                continue
            d = abs(vx - vy)
            if best is None or d < best - 1e-9:
                best, pair = d, (a[i], y)
    return pair
