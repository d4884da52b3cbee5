"""Frames that do not belong to the run they were shot in: said, never silent.

Three patterns a card shows (issue 32), each found by the scan and carried to the set's
result as a :class:`hdrcl.core.findings.Finding` (``check="frames"``, kept in the set's
``findings`` of the manifest, :data:`hdrcl.shoot.batch.manifest.FINDINGS`):

* **A foreign frame inside a run** (:func:`skip_strays`): one frame whose scene matches
  neither the frames before nor those after it, while those match each other, the
  timing runs on within the gap limit, the camera and its settings stay and its exposure
  repeats none of the run's (another view shot in the middle, a frame mirrored). Left to
  the scene test it cut the run in two sets, itself a "single frame". The run is kept
  whole; the frame is left out (merged in, it would paint another scene into the radiance
  map) and the set says so, severity ``check``: one rung of the ladder is missing, and
  only a person can say which view was meant.
* **A duplicated frame** (:func:`split_duplicates`): the same file twice in one folder (the
  same bytes), or the same camera, capture time, settings and thumbnail: a copy on the card. The later
  one (by name) is left out, severity ``note``: nothing is lost.
* **A frame of another camera inside a run** (:func:`foreign_cameras`): its Make, Model or
  serial differ from the frames it was shot among, while its image size, the scene and
  the exposure fit them (a file whose tags were rewritten, cards mixed). Each camera's
  frames are grouped apart (a response belongs to one camera), so it stays out; the set
  says so, severity ``check``. A second photographer's own bracket (several frames) is
  no such frame.
"""
from __future__ import annotations

import hashlib
import logging
import os
from typing import Dict, List, Optional, Sequence, Tuple

from hdrcl.core.findings import CHECK, NOTE, Finding
from hdrcl.io.metadata import FrameInfo
from hdrcl.shoot.grouping.compare import (_camera_desc, _camera_key, _gap, _same_bias, _same_settings, _sort_key,
                                          _time)
from hdrcl.shoot.grouping.ladder import exposure_value
from hdrcl.shoot.grouping.runs import (_camera_reason, _fmt_gap, _gap_limit, _Group, _joined, _nearest, _nearest_pair,
                                      _pattern_reason)

logger = logging.getLogger(__name__)

#: Thumbnails of two frames closer than this (largest difference of a cell, code values
#: 0..1) are one picture: a copy re-encoded. Two shots at one setting differ by their noise
#: and the scene's own changes, far above it even when area-averaged.
SAME_PIXELS = 0.004


def _name(f: FrameInfo) -> str:
    return os.path.basename(os.fspath(f.path))


# ------------------------------------------------------------------ foreign frame
def skip_strays(groups: List[_Group], compare, gap: Optional[float]) -> List[_Group]:
    """Join runs that a single frame of another scene cut in two (pass 1b of
    :func:`hdrcl.shoot.grouping.splitting.split_stream`); the frame is left out and
    recorded in the joined group's ``left``."""
    if compare is None or len(groups) < 3:
        return groups
    out: List[_Group] = [groups[0]]
    i = 1
    while i < len(groups):
        if i + 1 < len(groups):
            why = _stray(out[-1], groups[i], groups[i + 1], compare, gap)
            if why is not None:
                note, left = why
                joined = _joined(out[-1], groups[i + 1], note)
                joined.left = out[-1].left + [left] + groups[i + 1].left
                out[-1] = joined
                i += 2
                continue
        out.append(groups[i])
        i += 1
    return out


def _stray(a: _Group, x: _Group, b: _Group, compare, gap: Optional[float]):
    """``(join note, left-out record)`` when ``x`` (one frame) is a foreign frame between
    ``a`` and ``b``, else None."""
    if len(x.frames) != 1 or not a.reason.startswith("scene changed") or not x.reason.startswith("scene changed"):
        return None
    f, last, first = x.frames[0], a.frames[-1], b.frames[0]
    g1, g2 = _gap(last, f), _gap(f, first)
    if g1 is None or g2 is None or g1 > _gap_limit(last, gap) or g2 > _gap_limit(f, gap):
        return None  # the timing does not run on through it
    if _camera_reason(last, f) or _camera_reason(last, first):
        return None
    frames = list(a.frames)
    for g in b.frames:  # the two runs, without it, are one run of one ladder
        if _pattern_reason(frames, g, turns=False):
            return None
        frames.append(g)
    if any(_same_settings(g, f) for g in frames):
        return None  # its exposure repeats one of the run's: not a rung of this ladder
    both = compare(*_nearest_pair(a.frames, b.frames))
    if both is None or both.kind != "same":
        return None
    odd = compare(_nearest(frames, f), f)
    if odd is None or odd.kind != "changed":
        return None
    note = (f"{_fmt_gap(_gap(last, first))}, {_name(f)} between them left out (scene changed, match "
            f"{odd.rho:.2f}), {both.describe()}")
    return note, ("scene", f, odd.rho, both.rho)


def left_findings(grp: _Group) -> List[Tuple[FrameInfo, str, dict]]:
    """For each frame left out of ``grp``: the frame, the unmerged reason and the
    finding (as a dict) its set carries."""
    out = []
    for kind, f, rho, rho_set in grp.left:
        if kind != "scene":
            continue
        name = _name(f)
        msg = (f"{name}: does not match the scene of the other frames (match {rho:.2f} against {rho_set:.2f}); "
               f"left out of the set: check the file (another view, mirrored or rotated)")
        reason = f"left out of a set: does not match its scene (match {rho:.2f} against {rho_set:.2f})"
        out.append((f, reason, Finding("frames", msg, CHECK, file=name, figure=rho).to_dict()))
    return out


# ------------------------------------------------------------------ duplicates
def split_duplicates(infos: Sequence[FrameInfo], thumb=None) -> Tuple[List[FrameInfo], List[tuple]]:
    """The frames without their duplicates, and ``(copy, original, how)`` for each one
    left out. ``thumb(info)`` gives a frame's thumbnail (:class:`hdrcl.shoot.grouping.scene.Thumb`)
    or None; without it only identical bytes count."""
    buckets: Dict[tuple, List[FrameInfo]] = {}
    for f in sorted(infos, key=_sort_key):
        # Frames without a capture time are grouped by folder (a folder, a set): the same
        # file in another folder is another set's, never taken out of its set. A camera's
        # frame copied into another folder is the same shot twice.
        folder = os.path.dirname(os.path.abspath(os.fspath(f.path))) if _time(f) is None else None
        key = (folder, _camera_key(f), _time(f), f.width, f.height)
        buckets.setdefault(key, []).append(f)
    dups: List[tuple] = []
    gone = set()
    for frames in buckets.values():
        for k, f in enumerate(frames):
            if id(f) in gone:
                continue
            for g in frames[k + 1:]:
                if id(g) in gone or not _same_settings(f, g):
                    continue
                if (f.exposure_bias is None) != (g.exposure_bias is None) or (
                        f.exposure_bias is not None and not _same_bias(f.exposure_bias, g.exposure_bias)):
                    continue
                how = _same_picture(f, g, thumb)
                if how:
                    gone.add(id(g))
                    dups.append((g, f, how))
    return [f for f in infos if id(f) not in gone], dups


def _same_picture(a: FrameInfo, b: FrameInfo, thumb) -> Optional[str]:
    if _digest(a.path) is not None and _digest(a.path) == _digest(b.path):
        return "the same bytes"
    if thumb is None or _time(a) is None:
        return None
    ta, tb = thumb(a), thumb(b)
    if ta is None or tb is None or ta.lum.shape != tb.lum.shape:
        return None
    if float(abs(ta.lum - tb.lum).max()) < SAME_PIXELS:
        return "the same capture time, settings and pixels"
    return None


_DIGESTS: Dict[str, Optional[str]] = {}


def _digest(path) -> Optional[str]:
    p = os.path.abspath(os.fspath(path))
    try:
        st = os.stat(p)
    except OSError:
        return None
    key = f"{p}\0{st.st_size}\0{st.st_mtime_ns}"
    if key not in _DIGESTS:
        h = hashlib.sha256()
        try:
            with open(p, "rb") as fh:
                for block in iter(lambda: fh.read(1 << 20), b""):
                    h.update(block)
        except OSError:
            return None
        _DIGESTS[key] = f"{st.st_size}:{h.hexdigest()}"
    return _DIGESTS[key]


def duplicate_findings(dups: Sequence[tuple]) -> List[Tuple[FrameInfo, FrameInfo, str, dict]]:
    """For each duplicate: the copy, its original, the unmerged reason and the finding
    (a dict, severity ``note``) the original's set carries."""
    out = []
    for copy, orig, how in dups:
        a, b = _name(copy), _name(orig)
        msg = f"{a}: a duplicate of {b} ({how}); left out of the set, {b} merged once"
        out.append((copy, orig, f"duplicate of {b} ({how})", Finding("frames", msg, NOTE, file=a).to_dict()))
    return out


# ------------------------------------------------------------------ other camera
def foreign_cameras(groups: List[_Group], compare) -> Dict[int, tuple]:
    """Single frames of another camera shot inside a run they fit: ``id(single group)``
    -> ``(the run's group, unmerged reason, finding dict)``."""
    out: Dict[int, tuple] = {}
    if compare is None:
        return out
    runs = [g for g in groups if len(g.frames) >= 2]
    for x in groups:
        if len(x.frames) != 1 or _time(x.frames[0]) is None:
            continue
        f = x.frames[0]
        for run in runs:
            hit = _fits_run(run.frames, f, compare)
            if hit is not None:
                cam, other = _camera_desc(f), _camera_desc(run.frames[0])
                name = _name(f)
                msg = (f"{name}: names another camera ({cam}) than the frames it was shot among ({other}) but shows "
                       f"their scene (match {hit.rho:.2f}) at an exposure of their ladder; left out of the set: "
                       f"check its camera tags (Make, Model)")
                reason = f"other camera ({cam}) inside a set of {other} frames: left out (match {hit.rho:.2f})"
                out[id(x)] = (run, reason, Finding("frames", msg, CHECK, file=name, figure=hit.rho).to_dict())
                break
    return out


def _fits_run(frames: List[FrameInfo], f: FrameInfo, compare):
    """The scene verdict when ``f`` (another camera) was shot inside the span of
    ``frames`` (capture times), at their image size and at an exposure none of them has,
    and shows their scene; else None."""
    first, last = frames[0], frames[-1]
    if _camera_key(first) == _camera_key(f) or None in (_time(first), _time(last)):
        return None
    if not _time(first) < _time(f) < _time(last) or (f.width, f.height) != (first.width, first.height):
        return None
    if any(_same_settings(g, f) for g in frames):
        return None
    values = [exposure_value(g) for g in frames]
    v = exposure_value(f)
    if v is None or None in values or not min(values) < v < max(values):
        return None  # not a rung inside their ladder
    v = compare(_nearest(frames, f), f)
    return v if v is not None and v.kind == "same" else None


def place_duplicates(manifest, dups: Sequence[tuple]) -> None:
    """Each duplicate left out: unmerged with its reason, and a note on the set that
    holds its original (:func:`split_duplicates`)."""
    from hdrcl.shoot.batch.manifest import Unmerged, add_finding

    set_of = {os.fspath(f): s for s in manifest.sets for f in s.files}  # one index, not a walk per copy
    for copy, orig, reason, finding in duplicate_findings(dups):
        manifest.unmerged.append(Unmerged(files=[os.fspath(copy.path)], reason=reason))
        s = set_of.get(os.fspath(orig.path))
        if s is not None:
            add_finding(s, finding)
            logger.info("%s: %s", copy.path, reason)
