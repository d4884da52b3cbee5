"""Damaged frames placed in their sets by their metadata, so that the set fails.

A frame whose pixels (or thumbnail) do not decode, or whose header OpenImageIO cannot
open while its EXIF still reads (:func:`hdrcl.io.salvage.salvage_info`), is no scene
the grouping can compare: left to the scene test it became a "single frame" and cut its
set in two, or (header unreadable) the set was merged from the frames left, "done".
Here the grouping runs without such frames, then each one joins the set its camera,
capture time and exposure place it in (inside the set's time span or within the gap
limit of its ends, its exposure repeating none of the set's). The set records it in
``extra["damaged"]`` (file name -> cause), the scan lists it, and the batch fails the
set with the one line naming the file and counts it among the unreadable files
(:func:`hdrcl.shoot.batch.plan.damaged_files`). A frame no set takes stays in
``unmerged`` as ``"corrupt: ..."``.
"""
from __future__ import annotations

import logging
import os
from typing import Dict, List, Sequence, Tuple

from hdrcl.io.metadata import FrameInfo
from hdrcl.shoot.batch.manifest import BracketSet, Manifest, Unmerged
from hdrcl.shoot.grouping.compare import _camera_key, _gap, _norm, _same_settings, _sort_key, _time
from hdrcl.shoot.grouping.runs import _gap_limit

logger = logging.getLogger(__name__)

#: Key of :attr:`BracketSet.extra` naming a set's damaged frames (file name -> cause).
DAMAGED = "damaged"


def _fits(s_infos: List[FrameInfo], d: FrameInfo) -> float:
    """How far (seconds) ``d`` lies outside the set's time span; -1: it does not fit."""
    first = s_infos[0]
    if _camera_key(first) != _camera_key(d) or _time(d) is None or _time(first) is None:
        return -1.0
    if d.lens and first.lens and _norm(d.lens) != _norm(first.lens):
        return -1.0
    if d.width and (d.width, d.height) != (first.width, first.height):
        return -1.0
    if any(_same_settings(g, d) for g in s_infos):
        return -1.0
    last = s_infos[-1]
    before = _gap(d, first)  # end of d to the start of the set
    after = _gap(last, d)  # end of the set to the start of d
    if _time(d) < _time(first):
        return before if before <= _gap_limit(d, None) else -1.0
    if _time(d) > _time(last):
        return after if after <= _gap_limit(last, None) else -1.0
    return 0.0


def _insert(s: BracketSet, infos: List[FrameInfo], d: FrameInfo, cause: str) -> None:
    """``d`` into ``s`` in capture order, with its own join line."""
    k = sum(1 for g in infos if _sort_key(g) <= _sort_key(d))
    infos.insert(k, d)
    s.files.insert(k, os.fspath(d.path))
    if len(s.exposures) == len(s.files) - 1:
        s.exposures.insert(k, float(d.exposure_time))
    for name, value in (("iso", d.iso), ("ev", d.exposure_bias)):
        seq = getattr(s, name)
        if len(seq) == len(s.files) - 1:
            seq.insert(k, value)
    s.gaps = [None if g is None else round(g, 3) for g in (_gap(a, b) for a, b in zip(infos, infos[1:]))]
    why = f"damaged ({cause}): placed by its capture time and exposure"
    if s.joins is not None and len(s.joins) == len(s.files) - 2:
        s.joins.insert(max(0, k - 1), why)
    if k == 0:
        s.start = _time(d).isoformat(timespec="milliseconds")
    s.extra.setdefault(DAMAGED, {})[os.path.basename(os.fspath(d.path))] = cause


def place_damaged(manifest: Manifest, infos: Sequence[FrameInfo], damaged: Sequence[Tuple[FrameInfo, str]]) -> None:
    """Put each damaged frame (its header, the cause without the path) into the set of
    ``manifest`` it belongs to, or into ``unmerged`` as ``"corrupt: <cause>"``.

    ``infos``: the headers of the frames grouped (the sets' files)."""
    by_path: Dict[str, FrameInfo] = {os.fspath(i.path): i for i in infos}
    members = []
    for s in manifest.sets:
        got = [by_path.get(os.fspath(f)) for f in s.files]
        members.append(None if None in got else sorted(got, key=_sort_key))
    for d, cause in damaged:
        best, where = None, None
        for k, s_infos in enumerate(members):
            if not s_infos:
                continue
            far = _fits(s_infos, d)
            if far >= 0 and (best is None or far < best):
                best, where = far, k
        if where is None:
            manifest.unmerged.append(Unmerged(files=[os.fspath(d.path)], reason=f"corrupt: {cause}"))
            continue
        logger.info("%s: damaged (%s); in set %d by its capture time and exposure", d.path, cause,
                    manifest.sets[where].index)
        _insert(manifest.sets[where], members[where], d, cause)


def mark_damaged(manifest: Manifest, damaged: Dict[str, str]) -> None:
    """Record on each set the damaged frames it already holds (path -> cause)."""
    for s in manifest.sets:
        for f in s.files:
            cause = damaged.get(os.fspath(f))
            if cause is not None:
                s.extra.setdefault(DAMAGED, {})[os.path.basename(os.fspath(f))] = cause
