"""Grouping photographs into bracket sets (the ``hdrcl scan`` logic) and manifests.

A folder of bracketed shots is a sequence of frames; this module decides where one
bracket set ends and the next begins, using several signals together:

* **Camera**: frames are first split into one stream per camera body (Make, Model,
  serial), so two photographers shooting side by side do not break each other's sets.
* **Lens, focal length, image size**: a change ends the set.
* **Time gap**, measured from the *end* of one exposure to the *start* of the next:
  ``gap = start(i+1) - (start(i) + exposure_time(i))``. Within a set gaps are short
  (a burst: ~0.1-1 s; by hand: a few seconds). The default limit is
  :data:`DEFAULT_GAP` seconds plus, after exposures of 1 s or longer, the exposure time
  again (cameras with long-exposure noise reduction take a dark frame that long).
* **Exposure pattern**: a set is a ladder of different exposures. A frame whose
  settings (time, aperture, ISO) equal those of a frame already in the set starts a new
  set, which splits sets shot back to back even when the gap between them is shorter
  than the longest exposure. With auto bracketing the exposure bias sequence (``0, -2,
  +2`` or ``-2, 0, +2``...) is the ladder: a repeated bias value starts a new set. A
  hand-made monotonic ladder of three or more frames that turns back also restarts.
  A change of exposure mode (manual / auto bracket) or of the aperture in the middle of
  a shutter-speed ladder ends the set.

No fixed set size is guessed: sets may differ in size. Every set records why it ended.
Groups that cannot be merged are reported in :attr:`Manifest.unmerged`: single frames,
frames that all share one exposure, aperture bracketing, mixed cameras (possible with
``frames_per_set``), frames without an exposure time, unreadable files.

A :class:`Manifest` is the result; it is written to and read from JSON so a user can
hand-edit the grouping and feed it back (:func:`load_manifest`).

This module imports neither OpenImageIO nor click; :func:`scan_directory` reads headers
through :func:`hdrcl.io.frames.read_info`, imported when it is called.
"""
from __future__ import annotations

import datetime as _dt
import logging
import math
import os
from dataclasses import dataclass
from typing import Iterable, List, Optional, Sequence

from hdrcl.errors import UsageError
from hdrcl.io.metadata import FrameInfo
from hdrcl.shoot.manifest import BracketSet, Manifest, Unmerged, _is_number

logger = logging.getLogger(__name__)


#: Default largest end-to-start gap (seconds) between two frames of one set. Generous
#: enough for bracketing by hand; sets shot closer together are split by the pattern.
DEFAULT_GAP = 8.0


#: After an exposure this long (seconds) or longer the default gap limit grows by the
#: exposure time: long-exposure noise reduction takes a dark frame of the same length.
LONG_EXPOSURE = 1.0


# Two settings closer than this (in stops) are the same: below half a third-stop step,
# above the rounding of EXIF rationals (1/60 written as 0.016666...).
_STOP_TOL = 0.15


# Exposure bias values are written in thirds or halves of a stop.
_BIAS_TOL = 0.05


# ------------------------------------------------------------------ frame comparisons
def _same_stops(a, b, stops_per_doubling: float = 1.0) -> bool:
    """Equal within :data:`_STOP_TOL` stops; an unknown value matches anything."""
    if a is None or b is None:
        return True
    if a <= 0 or b <= 0:
        return a == b
    return abs(stops_per_doubling * math.log2(a / b)) < _STOP_TOL


def _same_settings(f: FrameInfo, g: FrameInfo) -> bool:
    """Same exposure time, aperture and ISO (unknown aperture/ISO match anything)."""
    if f.exposure_time is None or g.exposure_time is None:
        return False
    return (_same_stops(f.exposure_time, g.exposure_time)
            and _same_stops(f.fnumber, g.fnumber, 2.0)  # f-number: 2 stops per doubling
            and _same_stops(f.iso, g.iso))


def _varies(values: Iterable, same) -> bool:
    known = [v for v in values if v is not None]
    return any(not same(known[0], v) for v in known[1:])


def _same_bias(a, b) -> bool:
    return a is not None and b is not None and abs(a - b) < _BIAS_TOL


def _norm(s: Optional[str]) -> Optional[str]:
    if s is None:
        return None
    s = " ".join(str(s).split()).lower()
    return s or None


def _camera_key(f: FrameInfo) -> tuple:
    return (_norm(f.make), _norm(f.model), _norm(f.serial))


def _camera_label(f: FrameInfo) -> Optional[str]:
    make = " ".join((f.make or "").split())
    model = " ".join((f.model or "").split())
    if not make and not model:
        return None
    # "Canon" + "Canon EOS R5": do not repeat the brand.
    if make and model.lower().startswith(make.split()[0].lower()):
        return model
    return f"{make} {model}".strip()


def _camera_desc(f: FrameInfo) -> str:
    label = _camera_label(f) or "unknown camera"
    return f"{label} #{f.serial}" if f.serial else label


def _time(f: FrameInfo) -> Optional[_dt.datetime]:
    t = f.capture_time
    if t is not None and t.tzinfo is not None:
        t = t.replace(tzinfo=None)  # capture times are compared as local clock readings
    return t


def _sort_key(f: FrameInfo):
    t = _time(f)
    return (t is None, t or _dt.datetime.min, os.fspath(f.path))


def _gap(prev: FrameInfo, f: FrameInfo) -> Optional[float]:
    """Seconds from the end of ``prev``'s exposure to the start of ``f``'s."""
    a, b = _time(prev), _time(f)
    if a is None or b is None:
        return None
    return (b - a).total_seconds() - (prev.exposure_time or 0.0)


def format_exposure(t: Optional[float]) -> str:
    """Exposure time without unit: ``"1/60"``, ``"4"``, ``"0.4"``, ``"?"`` if unknown."""
    if t is None:
        return "?"
    if 0 < t < 1:
        n = 1.0 / t
        if abs(n - round(n)) <= 0.02 * n:
            return f"1/{round(n)}"
        return f"{t:.2g}"
    return f"{t:g}"


def _fmt_f(n: Optional[float]) -> str:
    return "f/?" if n is None else f"f/{n:g}"


def _fmt_bias(b: Optional[float]) -> str:
    if b is None:
        return "?"
    return "0" if abs(b) < 1e-9 else f"{b:+.3g}"


def _exposure_range(times: Sequence) -> str:
    known = [t for t in times if t is not None]
    if not known:
        return "?"
    lo, hi = min(known), max(known)
    if lo == hi:
        return f"{format_exposure(lo)} s"
    return f"{format_exposure(lo)} .. {format_exposure(hi)} s"


_MODE_NAMES = {0: "auto", 1: "manual", 2: "auto bracket"}


# ------------------------------------------------------------------------- splitting
def _split_reason(cur: List[FrameInfo], f: FrameInfo, gap_s: Optional[float],
                  gap_limit: Optional[float]) -> Optional[str]:
    """Why ``f`` cannot join the set ``cur`` (same camera), or None if it can."""
    prev = cur[-1]
    if _norm(prev.lens) != _norm(f.lens):
        return f"lens changed ({prev.lens or '?'} -> {f.lens or '?'})"
    if (prev.focal_length is None) != (f.focal_length is None) or (
            prev.focal_length is not None
            and abs(prev.focal_length - f.focal_length) > 0.005 * prev.focal_length):
        a, b = (f"{v:g}" if v is not None else "?" for v in (prev.focal_length, f.focal_length))
        return f"focal length changed ({a} -> {b} mm)"
    if (prev.width, prev.height) != (f.width, f.height):
        return f"image size changed ({prev.width}x{prev.height} -> {f.width}x{f.height})"
    if gap_s is not None:
        if gap_limit is not None:
            limit = gap_limit
        else:
            limit = DEFAULT_GAP
            if (prev.exposure_time or 0.0) >= LONG_EXPOSURE:
                limit += prev.exposure_time
        if gap_s > limit:
            return f"gap {gap_s:.1f} s"
    if (prev.exposure_mode is not None and f.exposure_mode is not None
            and prev.exposure_mode != f.exposure_mode):
        return ("exposure mode changed ("
                f"{_MODE_NAMES.get(prev.exposure_mode, prev.exposure_mode)} -> "
                f"{_MODE_NAMES.get(f.exposure_mode, f.exposure_mode)})")
    for k, g in enumerate(cur):
        if _same_settings(g, f):
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
    if _ladder_turns(cur, f):
        return "exposure ladder restarts"
    return None


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
    times = [g.exposure_time for g in frames]
    if any(t is None or t <= 0 for t in times):
        return False
    steps = [math.log2(b / a) for a, b in zip(times, times[1:])]
    ladder, last = steps[:-1], steps[-1]
    if all(s > _STOP_TOL for s in ladder):
        return last < -_STOP_TOL
    if all(s < -_STOP_TOL for s in ladder):
        return last > _STOP_TOL
    return False


@dataclass
class _Group:
    frames: List[FrameInfo]
    reason: str
    gaps: list


def _split_stream(frames: List[FrameInfo], gap: Optional[float]) -> List[_Group]:
    groups: List[_Group] = []
    cur, cur_gaps = [frames[0]], []
    for f in frames[1:]:
        g = _gap(cur[-1], f)
        reason = _split_reason(cur, f, g, gap)
        if reason is None:
            cur.append(f)
            cur_gaps.append(g)
        else:
            logger.debug("split before %s: %s", f.path, reason)
            groups.append(_Group(cur, reason, cur_gaps))
            cur, cur_gaps = [f], []
    groups.append(_Group(cur, "end of files", cur_gaps))
    return _coalesce_repeats(groups)


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
                p.gaps.append(_gap(p.frames[-1], f))
                p.frames.append(f)
                p.reason = grp.reason
                continue
        out.append(grp)
    return out


def _chunk(frames: List[FrameInfo], n: int, gap: Optional[float]) -> List[_Group]:
    """Fixed-size sets of ``n`` frames in capture order (``--frames-per-set``)."""
    groups: List[_Group] = []
    cur, cur_gaps = [], []
    for f in frames:
        if cur:
            g = _gap(cur[-1], f)
            if gap is not None and g is not None and g > gap:
                groups.append(_Group(cur, f"gap {g:.1f} s", cur_gaps))
                cur, cur_gaps = [], []
            else:
                cur_gaps.append(g)
        cur.append(f)
        if len(cur) == n:
            groups.append(_Group(cur, f"frames-per-set {n}", cur_gaps))
            cur, cur_gaps = [], []
    if cur:
        groups.append(_Group(cur, "end of files", cur_gaps))
    elif groups and groups[-1].reason.startswith("frames-per-set"):
        groups[-1].reason = "end of files"
    return groups


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
    if not time_varies:
        if _varies([f.iso for f in infos], _same_stops):
            return (f"all frames share one exposure time ({format_exposure(times[0])} s; "
                    "only ISO varies)")
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
    )


# --------------------------------------------------------------------------- entry
def group_frames(infos: Sequence[FrameInfo], *, frames_per_set: Optional[int] = None,
                 gap: Optional[float] = None) -> Manifest:
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
        default (:data:`DEFAULT_GAP`, plus the exposure time after long exposures).

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
        groups = _chunk(frames, frames_per_set, gap)
    else:
        streams: dict = {}
        for f in frames:
            streams.setdefault((_camera_key(f), _time(f) is None), []).append(f)
        for stream in streams.values():
            groups.extend(_split_stream(stream, gap))
        groups.sort(key=lambda g: _sort_key(g.frames[0]))

    manifest = Manifest()
    for grp in groups:
        why = unmergeable_reason(grp.frames)
        if why is None:
            s = _make_set(grp)
            s.index = len(manifest.sets)
            manifest.sets.append(s)
        else:
            manifest.unmerged.append(
                Unmerged(files=[os.fspath(f.path) for f in grp.frames], reason=why))
    logger.info("%d frames: %d bracket sets, %d groups not merged",
                len(frames), len(manifest.sets), len(manifest.unmerged))
    return manifest
