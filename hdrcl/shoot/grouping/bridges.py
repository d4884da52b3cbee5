"""Runs joined back (passes 2 and 3 of :mod:`hdrcl.shoot.grouping.splitting`): a
repeat of the last exposure kept as a duplicate (:func:`_keep_duplicates`), and runs that
only a long gap, an auto / manual change or a hand ladder turning back separated bridged
when together they still form one exposure ladder and the scene does not say otherwise
(:func:`_bridge`), with the gaps each may span (:data:`BRIDGE_SEEN`, :data:`BRIDGE_UNSEEN`).
"""
from __future__ import annotations

from typing import List, Optional

from hdrcl.io.metadata import FrameInfo
from hdrcl.shoot.grouping.compare import _fmt_bias, _gap, _same_bias, _varies, format_exposure
from hdrcl.shoot.grouping.ladder import distinct_of, ladder_of
from hdrcl.shoot.grouping.runs import (Compare, _duplicate, _fmt_gap, _Group, _hard_reason, _joined, _mode_change,
                                       _nearest_pair, _soft, unique)


#: Longest gap (s) bridged when the frames' scene matches: a pause of a quarter of an
#: hour on one view, the ladder going on after it, is still one set.
BRIDGE_SEEN = 900.0


#: Gaps longer than this (s) are called a pause in the reasons.
PAUSE = 120.0


#: Longest gap (s) bridged when the scene cannot be compared (no thumbnail).
BRIDGE_UNSEEN = 60.0


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
