"""Where one bracket set ends and the next begins, in one camera's stream of frames.

Three passes, every decision kept with its reason:

1. **Runs.** Consecutive frames stay together unless something ends the set: a change
   of lens, focal length, image size, to or from auto bracketing, or of the aperture (in
   a time ladder); an exposure (or exposure bias) that repeats one already in the set; a
   ladder that restarts (a monotonic hand ladder walking back, an auto-bracket pattern
   broken; a one-way ladder carried on past its end by a plausible step is not broken);
   the *scene* changing (:mod:`hdrcl.shoot.grouping.scene`); a gap longer than the default limit
   (:data:`DEFAULT_GAP`, plus twice the exposure time after long exposures); a change between
   auto and manual exposure (a run end that pass 3 may undo). A frame that repeats the
   (shutter, aperture, ISO) of the frame before with a *new* exposure compensation that
   carries the set's compensation on one way (a phone in auto mode with 0.25-0.5 EV
   steps, whose metering table gives neighbouring steps one setting) is a duplicate, not
   a repeat: it stays in the set.
1b. **Foreign frames.** A single frame whose scene matches neither run around it, while
   they match each other and the timing and the ladder run on through it (another view,
   a mirrored frame), is left out and the two runs are one
   (:func:`hdrcl.shoot.grouping.strays.skip_strays`, passed in as ``strays``).
2. **Duplicates.** A run that ended because the next frame repeated its *last* exposure
   is joined with the next run when, without the repeat, the two form one ladder and
   the scene has not changed: the shutter pressed twice before the dial moved. The
   repeat stays in the set (``"repeats the frame before (1/500 s): kept as a
   duplicate"``); a repeat of an earlier frame still starts a new set.
3. **Bridges.** A run that ended only by a long gap, an auto / manual change or a hand
   ladder turning back is joined with the next when the two together still form one
   exposure ladder (:func:`hdrcl.shoot.grouping.ladder.ladder_of`: evenly spaced in ``t``, ``t *
   ISO`` or the exposure bias, in an order people shoot) and the scene does not say
   otherwise; when the scene *matches* (the two runs' frames nearest in exposure),
   order and step size no longer matter: no exposure may repeat
   (:func:`hdrcl.shoot.grouping.ladder.distinct_of`). Hand-made ladders with 5-80 s between
   frames, third-stop steps, a ladder shot 1, 2, 1/2 s then on down, pauses of minutes
   on one view while the ladder goes on. Without a thumbnail the scene cannot vouch, and
   gaps up to :data:`BRIDGE_UNSEEN` seconds are bridged; with a matching scene, up to
   :data:`BRIDGE_SEEN` seconds (plus the exposure time). Thumbnails compared over much of
   the frame that match neither well nor badly (:attr:`hdrcl.shoot.grouping.scene.Verdict.doubtful`)
   bridge nothing.

With a ``--gap`` override the limit is exact and nothing is bridged.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Callable, List, Optional

from hdrcl.io.metadata import FrameInfo
from hdrcl.shoot.grouping.compare import (DEFAULT_GAP, LONG_EXPOSURE, NR_FACTOR, _BIAS_TOL, _MODE_NAMES, _STOP_TOL, _fmt_bias, _fmt_f,
                                 _gap, _norm, _same_bias, _same_settings, _same_stops, _varies, format_exposure)
from hdrcl.shoot.grouping.ladder import MAX_STEP, MIN_STEP, distinct_of, exposure_value, ladder_of

logger = logging.getLogger(__name__)

#: Longest gap (s) bridged when the frames' scene matches: a pause of a quarter of an
#: hour on one view, the ladder going on after it, is still one set.
BRIDGE_SEEN = 900.0
#: Gaps longer than this (s) are called a pause in the reasons.
PAUSE = 120.0
#: Longest gap (s) bridged when the scene cannot be compared (no thumbnail).
BRIDGE_UNSEEN = 60.0
#: Auto-bracket frames closer than this (s) are one burst: the scene does not split them.
BURST_GAP = 0.5

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


def split_stream(frames: List[FrameInfo], gap: Optional[float], compare: Compare = None,
                 strays=None) -> List[_Group]:
    """Split one camera's frames (capture order) into groups, with reasons; ``strays``
    (``strays(groups, compare, gap)``) rejoins runs a foreign frame cut after pass 1."""
    groups: List[_Group] = []
    cur, cur_gaps, joins = [frames[0]], [], []
    for f in frames[1:]:
        g = _gap(cur[-1], f)
        reason = _camera_reason(cur[-1], f)
        if reason is None and g is not None and g > _gap_limit(cur[-1], gap):
            reason = f"gap {g:.1f} s"
        reason = reason or _pattern_reason(cur, f) or _mode_change(cur[-1], f)
        verdict = None
        if reason is None:
            verdict = _content_reason(cur, f, compare)
            # Within an auto-bracket burst nobody re-aims: there a low match is the
            # exposures, not the scene.
            burst = g is not None and g < BURST_GAP and f.exposure_mode == 2
            if verdict is not None and verdict.kind == "changed" and not burst:
                reason = verdict.describe()
        if reason is None:
            note = _fmt_gap(g)
            if _compensation_duplicate(cur, f):
                note += (f", repeats the settings of the frame before ({format_exposure(f.exposure_time)} s) with a "
                         f"new compensation ({_fmt_bias(f.exposure_bias)} EV): kept as a duplicate")
            if verdict is not None and verdict.kind != "unknown":
                note += f", {verdict.describe()}"
            cur.append(f)
            cur_gaps.append(g)
            joins.append(note)
        else:
            logger.debug("split before %s: %s", f.path, reason)
            groups.append(_Group(cur, reason, cur_gaps, joins))
            cur, cur_gaps, joins = [f], [], []
    groups.append(_Group(cur, "end of files", cur_gaps, joins))
    groups = _coalesce_repeats(groups)
    if strays is not None:  # pass 1b: hdrcl.shoot.grouping.strays.skip_strays (it builds on this module)
        groups = strays(groups, compare, gap)
    groups = _keep_duplicates(groups, compare)
    if gap is None:
        groups = _bridge(groups, compare)
    return groups


def _keep_duplicates(groups: List[_Group], compare: Compare) -> List[_Group]:
    """Join a run that ended because its next frame repeated its *last* exposure (pass 2).

    The shutter pressed twice before the dial moved: when the frames after the repeat go
    on with the ladder and the scene has not changed, the set keeps the repeat as a
    duplicate (it merges like any frame) instead of being cut in two. A repeat of an
    earlier frame (the ladder shot again) still starts a new set.
    """
    out: List[_Group] = []
    for grp in groups:
        why = _duplicate_reason(out[-1], grp, compare) if out else None
        if why is None:
            out.append(grp)
        else:
            out[-1] = _joined(out[-1], grp, why)
    return out


def _duplicate_reason(p: _Group, grp: _Group, compare: Compare) -> Optional[str]:
    if not (p.reason.startswith("exposure repeats") or p.reason.startswith("exposure bias repeats")):
        return None
    last, f = p.frames[-1], grp.frames[0]
    if len(unique(p.frames)) != len(p.frames) or not _duplicate(last, f):
        return None
    verdict = None if compare is None else compare(last, f)
    if verdict is not None and verdict.kind == "changed":
        return None
    same = verdict is not None and verdict.kind == "same"
    frames = unique(p.frames + grp.frames)
    if ladder_of(frames, even=not same) is None and not (same and _any_order(frames)):
        return None  # the frames after the repeat walk back over the ladder: a new set
    what = (f"{_fmt_bias(f.exposure_bias)} EV" if f.exposure_bias is not None
            and _varies([g.exposure_bias for g in p.frames], _same_bias) else format_exposure(f.exposure_time) + " s")
    note = f"{_fmt_gap(_gap(last, f))}, repeats the frame before ({what}): kept as a duplicate"
    if verdict is not None and verdict.kind != "unknown":
        note += f", {verdict.describe()}"
    return note


def _bridge(groups: List[_Group], compare: Compare) -> List[_Group]:
    """Join runs that only a long gap separated and that form one ladder (pass 3).

    Runs linked by long gaps form a chain; of the ways to cut a chain into ladders the
    one with the largest sum of squared set sizes wins, so a stray frame before a hand
    ladder stays alone instead of taking the ladder's first frame with it; of two cuts as
    good, the later (a ladder, then some of it shot again: the first set keeps its frames).
    """
    out: List[_Group] = []
    i = 0
    while i < len(groups):
        e = i
        while e + 1 < len(groups) and _soft(groups[e].reason):
            e += 1
        out.extend(_bridge_chain(groups[i:e + 1], compare))
        i = e + 1
    return out


def _joined(a: _Group, b: _Group, why: str) -> _Group:
    return _Group(a.frames + b.frames, b.reason, a.gaps + [_gap(a.frames[-1], b.frames[0])] + b.gaps,
                  a.joins + [why] + b.joins, a.left + b.left)


def _bridge_chain(runs: List[_Group], compare: Compare) -> List[_Group]:
    m = len(runs)
    if m == 1:
        return runs
    valid = {}
    for i in range(m):
        acc = _Group(list(runs[i].frames), runs[i].reason, list(runs[i].gaps), list(runs[i].joins),
                     list(runs[i].left))
        valid[(i, i)] = acc
        for j in range(i + 1, m):
            why = _bridge_reason(acc, runs[j], compare)
            if why is None:
                break  # a union that is no ladder never becomes one by growing
            acc = _joined(acc, runs[j], why)
            valid[(i, j)] = acc
    best, choice = [0] * (m + 1), [0] * (m + 1)
    for j in range(1, m + 1):
        best[j] = -1
        for i in range(j):
            g = valid.get((i, j - 1))
            # ">=": of two cuts as good, the later one (the set shot first keeps the frame)
            if g is not None and best[i] + len(g.frames) ** 2 >= best[j]:
                best[j], choice[j] = best[i] + len(g.frames) ** 2, i
    parts, j = [], m
    while j > 0:
        parts.append(valid[(choice[j], j - 1)])
        j = choice[j]
    parts.reverse()
    for a, b in zip(parts, parts[1:]):
        a.reason += _no_bridge_note(a, b, compare)
    return parts


def _bridge_parts(p: _Group, grp: _Group, compare: Compare):
    g = _gap(p.frames[-1], grp.frames[0])
    if g is None:
        return None, None, None
    verdict = None if compare is None else compare(*_nearest_pair(p.frames, grp.frames))
    # A scene that matches vouches for a hand-turned ladder whose steps are uneven, in
    # any order, as long as no exposure repeats.
    same = verdict is not None and verdict.kind == "same"
    frames = unique(p.frames + grp.frames)
    lad = ladder_of(frames, even=not same) or (_any_order(frames) if same else None)
    return g, lad, verdict


def _any_order(frames: List[FrameInfo]):
    """:func:`distinct_of` where one exposure mode shot every frame; a frame metered in
    auto before (or after) a manual ladder joins it only by continuing it (a test shot
    inside the ladder's span stays alone)."""
    if len({f.exposure_mode for f in frames if f.exposure_mode is not None}) > 1:
        return None
    return distinct_of(frames)


def _goes_on(p: _Group, frames: List[FrameInfo]):
    """The one-way ladder ``frames`` form when they carry on, in its direction and by
    plausible steps (:data:`MIN_STEP` to :data:`MAX_STEP` stops), a one-way ladder of 3+
    frames the scene vouched for (``p``); or None. The darkest frames of a night ladder
    show too little to compare: the ladder going on, at its own pace, vouches for them."""
    before = unique(p.frames)
    if len(before) < 3 or not any("same scene" in j for j in p.joins):
        return None
    a, b = ladder_of(before, even=False), ladder_of(frames, even=False)
    if a is None or b is None:
        return None
    way = a.order.split(",")[0]
    return b if way in ("ascending", "descending") and b.order.split(",")[0] == way else None


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


def _bridge_reason(p: _Group, grp: _Group, compare: Compare) -> Optional[str]:
    f = grp.frames[0]
    if _hard_reason(p.frames, f) is not None:
        return None
    g, lad, verdict = _bridge_parts(p, grp, compare)
    if getattr(verdict, "doubtful", False):
        return None
    seen = verdict is not None and verdict.kind != "unknown"
    limit = BRIDGE_SEEN + (p.frames[-1].exposure_time or 0.0) if seen else BRIDGE_UNSEEN
    scene = verdict.describe() if seen else "scene not compared"
    if g is not None and verdict is not None and verdict.kind == "unknown":
        goes_on = _goes_on(p, unique(p.frames + grp.frames))
        if goes_on is not None and (lad is None or g > limit):
            # at the ladder's own pace (its gaps short of a pause), never after a pause
            lad, limit = goes_on, max([BRIDGE_UNSEEN] + [x for x in p.gaps if x is not None and x <= PAUSE])
            scene = f"{verdict.describe()}, the ladder the scene vouched for goes on one way"
    if g is None or lad is None:
        return None
    if seen and verdict.kind != "same":
        return None
    if g > limit:
        return None
    what = f"gap {g:.1f} s" if g <= PAUSE else f"pause of {g / 60:.1f} min ({g:.1f} s)"
    if p.reason == "exposure ladder restarts":
        what = (f"ladder turns back ({format_exposure(p.frames[-1].exposure_time)} -> "
                f"{format_exposure(f.exposure_time)} s), {what}")
    mode = _mode_change(p.frames[-1], f)
    if mode:
        what += f", {mode}"
    return f"{what} bridged: {lad.describe()}, {scene}"


def _no_bridge_note(p: _Group, grp: _Group, compare: Compare) -> str:
    """Why a long gap was not bridged, for ``--explain`` (appended to the reason)."""
    if _hard_reason(p.frames, grp.frames[0]) is not None:
        return ""
    g, lad, verdict = _bridge_parts(p, grp, compare)
    if g is None:
        return ""
    if lad is None:
        return ""
    if verdict is not None and verdict.kind == "changed":
        return f"; {verdict.describe()}"
    if _bridge_reason(p, grp, compare) is not None:
        return "; the next frames form a ladder of their own"
    return "; too long to bridge"


def _coalesce_repeats(groups: List[_Group]) -> List[_Group]:
    """Join runs of single frames split only because they repeat one exposure.

    A burst at one setting would otherwise show up as many "single frame" entries; it
    is reported once as "all frames share one exposure".
    """
    out: List[_Group] = []
    for grp in groups:
        if out and len(grp.frames) == 1:
            p = out[-1]
            f = grp.frames[0]
            if (p.reason.startswith("exposure repeats")
                    and all(_same_settings(x, f) for x in p.frames)):
                g = _gap(p.frames[-1], f)
                p.gaps.append(g)
                p.joins.append(f"{_fmt_gap(g)}, same exposure")
                p.frames.append(f)
                p.reason = grp.reason
                continue
        out.append(grp)
    return out


def chunk(frames: List[FrameInfo], n: int, gap: Optional[float]) -> List[_Group]:
    """Fixed-size sets of ``n`` frames in capture order (``--frames-per-set``)."""
    groups: List[_Group] = []
    cur, cur_gaps, joins = [], [], []
    for f in frames:
        if cur:
            g = _gap(cur[-1], f)
            if gap is not None and g is not None and g > gap:
                groups.append(_Group(cur, f"gap {g:.1f} s", cur_gaps, joins))
                cur, cur_gaps, joins = [], [], []
            else:
                cur_gaps.append(g)
                joins.append(f"{_fmt_gap(g)}, frames-per-set {n}")
        cur.append(f)
        if len(cur) == n:
            groups.append(_Group(cur, f"frames-per-set {n}", cur_gaps, joins))
            cur, cur_gaps, joins = [], [], []
    if cur:
        groups.append(_Group(cur, "end of files", cur_gaps, joins))
    elif groups and groups[-1].reason.startswith("frames-per-set"):
        groups[-1].reason = "end of files"
    return groups


