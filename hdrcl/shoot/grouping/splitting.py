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
   gaps up to :data:`~hdrcl.shoot.grouping.bridges.BRIDGE_UNSEEN` seconds are bridged;
   with a matching scene, up to :data:`~hdrcl.shoot.grouping.bridges.BRIDGE_SEEN` seconds
   (plus the exposure time). Thumbnails compared over much of the frame that match
   neither well nor badly (:attr:`hdrcl.shoot.grouping.scene.Verdict.doubtful`) bridge
   nothing.

With a ``--gap`` override the limit is exact and nothing is bridged.

Pass 1's reasons are :mod:`hdrcl.shoot.grouping.runs`; passes 2 and 3
:mod:`hdrcl.shoot.grouping.bridges`.
"""
from __future__ import annotations

import logging
from typing import List, Optional

from hdrcl.io.metadata import FrameInfo
from hdrcl.shoot.grouping.bridges import _bridge, _keep_duplicates
from hdrcl.shoot.grouping.compare import _fmt_bias, _gap, _same_settings, format_exposure
from hdrcl.shoot.grouping.runs import (Compare, _camera_reason, _compensation_duplicate, _content_reason, _fmt_gap,
                                       _gap_limit, _Group, _mode_change, _pattern_reason)

logger = logging.getLogger(__name__)

#: Auto-bracket frames closer than this (s) are one burst: the scene does not split them.
BURST_GAP = 0.5


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
