"""Comparing frames' headers: settings, cameras, capture times, and their display.

Shared by :mod:`hdrcl.shoot.grouping.rules` and the splitting (:mod:`hdrcl.shoot.grouping.runs`,
:mod:`hdrcl.shoot.grouping.bridges`).
"""
from __future__ import annotations

import datetime as _dt
import math
import os
from typing import Iterable, Optional, Sequence

from hdrcl.io.metadata import FrameInfo

#: Default largest end-to-start gap (seconds) between two frames of one set. Generous
#: enough for bracketing by hand; sets shot closer together are split by the pattern.
DEFAULT_GAP = 8.0


#: After an exposure this long (seconds) or longer the default gap limit grows by
#: :data:`NR_FACTOR` times the exposure time: long-exposure noise reduction takes a dark
#: frame of the same length, and the camera's processing of the pair grows with it
#: (a night ladder 1 s, 2 s, 0.5 s, then on down: 9.5-14 s between frames).
LONG_EXPOSURE = 0.5
NR_FACTOR = 2.0


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
    """Seconds from the end of ``prev``'s exposure to the start of ``f``'s, at least 0
    (capture times in whole seconds put the next start inside a long exposure)."""
    a, b = _time(prev), _time(f)
    if a is None or b is None:
        return None
    return max(0.0, (b - a).total_seconds() - (prev.exposure_time or 0.0))


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
