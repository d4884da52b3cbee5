"""Grouping photographs into bracket sets (the ``hdrcl scan`` logic) and manifests.

A folder of bracketed shots is a sequence of frames; this module decides where one
bracket set ends and the next begins, using several signals together:

* **Exposure lists**: the frames an ``image_list.txt`` or ``times.txt`` beside them
  names (their exposures come from it) are exactly one set, in the list's order: one
  folder per set (``listed`` of :func:`group_frames`).
* **Camera**: frames are first split into one stream per camera body (Make, Model,
  serial), so two photographers shooting side by side do not break each other's sets;
  camera RAW files and the JPEGs shot with them (RAW+JPEG) are separate streams too.
  Frames of different folders share a stream only when they come from one camera
  with capture times: frames that name no camera, or carry no capture time, are a
  stream per folder (folders only name outputs, but nothing else says such frames
  belong together).
* **Lens, focal length, image size**: each lens is a stream of its own too, so a phone
  that flips between its lenses inside one sequence gives one set per lens (not single
  frames); a set that ends where the camera moved to another lens says so.
* **Time gap**, measured from the *end* of one exposure to the *start* of the next:
  ``gap = start(i+1) - (start(i) + exposure_time(i))``. Within a set gaps are short
  (a burst: ~0.1-1 s; by hand: a few seconds). The default limit is
  :data:`DEFAULT_GAP` seconds plus, after exposures of 0.5 s or longer, twice the exposure
  time (cameras with long-exposure noise reduction take a dark frame that long, and
  their processing grows with it: 9.5-14 s between the 1 s, 2 s and 0.5 s frames of a
  night ladder).
* **Exposure pattern**: a set is a ladder of different exposures. A frame whose
  settings (time, aperture, ISO) equal those of a frame already in the set starts a new
  set, which splits sets shot back to back even when the gap between them is shorter
  than the longest exposure. With auto bracketing the exposure bias sequence (``0, -2,
  +2`` or ``-2, 0, +2``...) is the ladder: a repeated bias value starts a new set. A
  repeated (time, aperture, ISO) with a new exposure bias that carries the bias on one
  way (a phone in auto mode with 0.25-0.5 EV compensation steps) is a duplicate, not a
  repeat. A hand-made monotonic ladder of three or more frames that turns back ends
  the run (the bridges join it back when the scene matches and nothing repeats), and an
  auto-bracket pattern (``0, -2, +2, -4, +4``) that the next frame breaks ends the set.
  A frame that carries a one-way ladder on past its end by a plausible step (0.45-4.5
  stops, even when uneven: a phone going on in ISO from its own table) continues it.
  A frame that repeats the exposure of the frame just before, with the ladder going on
  after it on the same scene, is kept in the set as a duplicate (pass 2 of
  :mod:`hdrcl.shoot.grouping.splitting`). A change to or from auto bracketing, or of the
  aperture in the middle of a shutter-speed ladder, ends the set; a change between
  auto and manual exposure (a compact's first frame metered in P, the rest in M) ends
  the run, and the bridges below join it back when the ladder continues.
* **The scene** (with ``compare``, which ``scan_directory`` gives by default): small
  exposure-normalised thumbnails of a frame and of the set's frame nearest in exposure
  (:mod:`hdrcl.shoot.grouping.scene`); a changed scene ends the set.
* **Long gaps bridged**: runs that only a long gap (an auto / manual change, a hand
  ladder turning back) separates are joined when the scene matches and no exposure
  repeats, in any order and with any step (:func:`hdrcl.shoot.grouping.ladder.distinct_of`: a
  compact's third-stop ladder, a ladder shot 1, 2, 1/2 s then on down, a moon ladder
  1/4 -> 1/250 s then 1/2 -> 8 s); where the scene cannot be compared, when they form
  one evenly spaced exposure ladder in an order people shoot
  (:func:`hdrcl.shoot.grouping.ladder.ladder_of`), or carry on one way a ladder the scene vouched
  for (the darkest frames of a night ladder). Hand-made brackets with 5-80 s between
  frames, and pauses of up to a quarter of an hour on one view while the ladder goes
  on (:mod:`hdrcl.shoot.grouping.splitting`).

The rule behind all of these: frames belong together when the scene matches and
together they form one plausible bracket (every exposure once, a span of stops),
whatever the gaps, the order or the step. One shutter time with the ISO stepping is a ladder in ``t * ISO``
(the merge uses it), so it is a set.

No fixed set size is guessed: sets may differ in size. Every set records why it ended
(:attr:`BracketSet.reason`) and why each frame joined it (:attr:`BracketSet.joins`).
Groups that cannot be merged are reported in :attr:`Manifest.unmerged`: single frames,
frames that all share one exposure (time and ISO), aperture bracketing, mixed cameras (possible with
``frames_per_set``), frames without an exposure time, unreadable files.

A :class:`Manifest` is the result; it is written to and read from JSON so a user can
hand-edit the grouping and feed it back (:func:`load_manifest`).

This module imports neither OpenImageIO nor click; :func:`hdrcl.shoot.scan.scan_directory`
reads headers through :func:`hdrcl.io.frames.read_info`, imported when it is called.
"""
from __future__ import annotations

import logging
import math
import os
from typing import Iterable, List, Optional, Sequence

from hdrcl.errors import UsageError
from hdrcl.io.metadata import FrameInfo
from hdrcl.shoot.grouping.compare import (DEFAULT_GAP, LONG_EXPOSURE, _camera_desc, _camera_key, _camera_label,  # noqa: F401
                                 _exposure_range, _fmt_bias, _fmt_f, _gap, _norm, _same_stops, _sort_key, _time,
                                 _varies, format_exposure)
from hdrcl.shoot.batch.manifest import BracketSet, Manifest, Unmerged, _is_number, add_finding
from hdrcl.shoot.grouping.runs import _camera_reason, _Group
from hdrcl.shoot.grouping.splitting import chunk, split_stream
from hdrcl.shoot.grouping.strays import foreign_cameras, left_findings, skip_strays

logger = logging.getLogger(__name__)

_RAW_EXTENSIONS = (".cr2", ".cr3", ".nef", ".nrw", ".arw", ".dng", ".raf", ".rw2", ".orf", ".pef", ".srw", ".3fr",
                   ".iiq", ".erf", ".kdc", ".mos", ".mrw", ".x3f")


# ---------------------------------------------------------------------- classifying
def unmergeable_reason(infos: Sequence[FrameInfo]) -> Optional[str]:
    """Why these frames cannot be merged into one radiance map, or None if they can.

    Parameters
    ----------
    infos : sequence of FrameInfo
        The frames of one set (for example a set of a hand-edited manifest).

    Returns
    -------
    str or None
        ``"single frame"``, ``"mixed cameras (...)"``, ``"mixed image sizes (...)"``,
        ``"mixed lenses (...)"``, ``"no exposure time (...)"``, ``"aperture bracketing
        (...)"``, ``"aperture varies (...)"``, ``"all frames share one exposure (...)"``.
    """
    infos = list(infos)
    if len(infos) < 2:
        return "single frame"
    cams = _distinct(_camera_key(f) for f in infos)
    if len(cams) > 1:
        labels = _distinct(_camera_desc(f) for f in infos)
        return f"mixed cameras ({', '.join(labels)})"
    sizes = _distinct(f"{f.width}x{f.height}" for f in infos)
    if len(sizes) > 1:
        return f"mixed image sizes ({', '.join(sizes)})"
    lenses = _distinct(_norm(f.lens) for f in infos)
    if len(lenses) > 1:
        names = _distinct(f.lens or "?" for f in infos)
        return f"mixed lenses ({', '.join(names)})"
    if _varies([f.focal_length for f in infos], lambda a, b: abs(a - b) <= 0.005 * a):
        names = _distinct(f"{f.focal_length:g} mm" for f in infos if f.focal_length)
        return f"mixed focal lengths ({', '.join(names)})"
    missing = [os.path.basename(f.path) for f in infos if f.exposure_time is None]
    if missing:
        return f"no exposure time ({', '.join(missing)})"
    times = [f.exposure_time for f in infos]
    time_varies = _varies(times, _same_stops)
    fnums = [f.fnumber for f in infos]
    if _varies(fnums, lambda a, b: _same_stops(a, b, 2.0)):
        known = [n for n in fnums if n is not None]
        span = f"{_fmt_f(min(known))} .. {_fmt_f(max(known))}"
        if not time_varies:
            return f"aperture bracketing ({span} at {format_exposure(times[0])} s)"
        return f"aperture varies ({span}): depth of field differs between frames"
    # One shutter time with the ISO stepping (a phone in pro mode) is a ladder in
    # t * ISO, which the merge uses (hdrcl.io.metadata.relative_exposures).
    if not time_varies and not _varies([f.iso for f in infos], _same_stops):
        return (f"all frames share one exposure ({format_exposure(times[0])} s, "
                f"{_fmt_f(infos[0].fnumber)})")
    return None


def _distinct(values: Iterable) -> list:
    out = []
    for v in values:
        if v not in out:
            out.append(v)
    return out


def _make_set(grp: _Group) -> BracketSet:
    first = grp.frames[0]
    t0 = _time(first)
    return BracketSet(
        index=-1,
        files=[os.fspath(f.path) for f in grp.frames],
        exposures=[float(f.exposure_time) for f in grp.frames],
        reason=grp.reason,
        start=None if t0 is None else t0.isoformat(timespec="milliseconds"),
        camera=_camera_label(first),
        serial=first.serial,
        lens=first.lens,
        focal_length=first.focal_length,
        fnumber=first.fnumber,
        iso=[f.iso for f in grp.frames],
        ev=[f.exposure_bias for f in grp.frames],
        gaps=[None if g is None else round(g, 3) for g in grp.gaps],
        width=first.width,
        height=first.height,
        joins=list(grp.joins),
    )


def _stream_key(f: FrameInfo) -> tuple:
    """One stream per camera body, per kind of file (RAW+JPEG cards hold two files per
    capture), with and without capture times; frames that name no camera or carry no
    capture time, per folder too."""
    raw = os.path.splitext(os.fspath(f.path))[1].lower() in _RAW_EXTENSIONS
    cam = _camera_key(f)
    timeless = _time(f) is None
    folder = os.path.dirname(os.path.abspath(os.fspath(f.path))) if timeless or not any(cam) else None
    return (cam, timeless, raw, folder)


def _listed_groups(frames: List[FrameInfo], listed) -> tuple:
    """The groups the exposure lists make (one per list, its frames in its order) and
    the frames left to group."""
    groups, taken = [], set()
    for lst, named in (listed or {}).items():
        named = [f for f in named if id(f) not in taken]
        if not named:
            continue
        taken.update(id(f) for f in named)
        base = os.path.basename(os.fspath(lst))
        groups.append(_Group(list(named), f"end of the frames {base} lists",
                             [_gap(a, b) for a, b in zip(named, named[1:])],
                             [f"listed in {base}" for _ in named[1:]]))
    return groups, [f for f in frames if id(f) not in taken]


def _split_by_lens(stream: List[FrameInfo], gap, compare) -> List[_Group]:
    """Group one camera's frames, each lens (lens, focal length, image size) apart.

    A phone that flips between its lenses inside one sequence gives one set per lens,
    not single frames. A set that ends where the camera moved to another lens says so
    (``"focal length changed (5.11 -> 2.67 mm)"``), as it did before.
    """
    lenses: List[List[FrameInfo]] = []
    for f in stream:
        for frames in lenses:
            if _camera_reason(frames[0], f) is None:
                frames.append(f)
                break
        else:
            lenses.append([f])
    if len(lenses) == 1:
        return split_stream(stream, gap, compare, skip_strays)
    position = {id(f): i for i, f in enumerate(stream)}
    groups = []
    for frames in lenses:
        for grp in split_stream(frames, gap, compare, skip_strays):
            for k, (a, b) in enumerate(zip(grp.frames, grp.frames[1:])):
                between = position[id(b)] - position[id(a)] - 1
                if between:
                    grp.joins[k] += f", after {between} frame(s) with another lens"
            i = position[id(grp.frames[-1])]
            if grp.reason == "end of files" and i + 1 < len(stream):
                grp.reason = _camera_reason(grp.frames[-1], stream[i + 1]) or grp.reason
            groups.append(grp)
    return groups


def _say_left_out(manifest: Manifest, groups: List[_Group], made: dict, others: dict) -> None:
    """Frames that did not belong to their run (:mod:`hdrcl.shoot.grouping.strays`): each
    unmerged with its reason, and its set's finding in :data:`FINDINGS`."""
    by_file: dict = {}  # single files unmerged, indexed once (a walk of them all per hit was quadratic)
    for u in manifest.unmerged:
        if len(u.files) == 1:
            by_file.setdefault(u.files[0], []).append(u)
    for grp in groups:
        for f, reason, finding in left_findings(grp):
            u = Unmerged(files=[os.fspath(f.path)], reason=reason, ended=grp.reason)
            manifest.unmerged.append(u)
            by_file.setdefault(u.files[0], []).append(u)
            if id(grp) in made:
                add_finding(made[id(grp)], finding)
        hit = others.get(id(grp))
        if hit is not None and id(hit[0]) in made:
            run, reason, finding = hit
            for u in by_file.get(os.fspath(grp.frames[0].path), ()):
                u.reason = reason
            add_finding(made[id(run)], finding)


# --------------------------------------------------------------------------- entry
def group_frames(infos: Sequence[FrameInfo], *, frames_per_set: Optional[int] = None,
                 gap: Optional[float] = None, compare=None, listed=None) -> Manifest:
    """Group frames into bracket sets.

    Frames are sorted by capture time, then path. Frames without a capture time come
    after all timed ones, sorted by path, and are grouped among themselves by the
    exposure pattern alone (no gap is known for them).

    Parameters
    ----------
    infos : sequence of FrameInfo
        Headers of the frames, in any order.
    frames_per_set : int, optional
        Override: cut the capture-ordered frames into sets of exactly this many (the
        last one may be shorter). The exposure pattern and the camera are then not used
        to split, but each set is still checked (mixed cameras, one exposure...).
    gap : float, optional
        Override: the largest end-to-start gap in seconds within a set, instead of the
        default (:data:`DEFAULT_GAP`, plus twice the exposure time after exposures of 0.5 s or more);
        long gaps are then never bridged.
    compare : callable, optional
        ``compare(a, b)`` -> :class:`hdrcl.shoot.grouping.scene.Verdict` for two frames: the
        content signal (:class:`hdrcl.shoot.grouping.scene.SceneCache.compare`). Without it the
        grouping uses the headers alone.
    listed : dict, optional
        Exposure list (path) -> the frames of ``infos`` it names, in its order: each
        is one set (a folder per set), whatever the rest says; the other frames are
        grouped as usual. Not used with ``frames_per_set``.

    Returns
    -------
    Manifest
        Sets and unmerged groups in capture order; ``root`` is None.

    Raises
    ------
    UsageError
        ``frames_per_set`` is below 1 or ``gap`` is negative.
    """
    if frames_per_set is not None:
        if (not isinstance(frames_per_set, int) or isinstance(frames_per_set, bool)
                or frames_per_set < 1):
            raise UsageError(f"frames per set must be a whole number >= 1, "
                             f"got {frames_per_set!r}")
    if gap is not None:
        if not _is_number(gap) or not gap >= 0 or not math.isfinite(gap):
            raise UsageError(f"gap must be a number of seconds >= 0, got {gap!r}")
        gap = float(gap)

    frames = sorted(infos, key=_sort_key)
    groups: List[_Group] = []
    if frames_per_set is not None:
        groups = chunk(frames, frames_per_set, gap)
    else:
        groups, rest = _listed_groups(frames, listed)
        streams: dict = {}
        for f in rest:
            streams.setdefault(_stream_key(f), []).append(f)
        for stream in streams.values():
            groups.extend(_split_by_lens(stream, gap, compare))
        groups.sort(key=lambda g: _sort_key(g.frames[0]))

    others = foreign_cameras(groups, compare) if frames_per_set is None else {}
    manifest, made = Manifest(), {}
    for grp in groups:
        why = unmergeable_reason(grp.frames)
        if why is None:
            s = _make_set(grp)
            s.index = len(manifest.sets)
            manifest.sets.append(s)
            made[id(grp)] = s
        else:
            manifest.unmerged.append(
                Unmerged(files=[os.fspath(f.path) for f in grp.frames], reason=why, ended=grp.reason,
                         joins=list(grp.joins)))
    _say_left_out(manifest, groups, made, others)
    logger.info("%d frames: %d bracket sets, %d groups not merged",
                len(frames), len(manifest.sets), len(manifest.unmerged))
    return manifest
