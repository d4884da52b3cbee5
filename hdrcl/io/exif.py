"""EXIF values as hdrcl reads them, whichever reader found them (OpenImageIO for image
files, hdrcl's own TIFF walk for camera RAW headers): one place for the rules that turn
recorded fields into exposure times and capture times.
"""
from __future__ import annotations

import datetime as _dt
import logging
from typing import Optional

import numpy as np

logger = logging.getLogger(__name__)


def snap_reciprocal(t: float) -> float:
    """EXIF rationals and LibRaw's shutter speeds arrive as float32: turn 0.0333333 back
    into exactly 1/30 (the shortest decimal that round-trips the float32, then the exact
    reciprocal of a whole number where it is one to 1e-4)."""
    t = float(str(np.float32(t)))
    if 0.0 < t < 1.0:
        n = round(1.0 / t)
        if n >= 1 and abs(1.0 / t - n) <= 1e-4 * n:
            return 1.0 / n
    return t


def parse_datetime(text: Optional[str], subsec: Optional[str] = None) -> Optional[_dt.datetime]:
    """``YYYY:MM:DD HH:MM:SS`` (EXIF; ISO 8601 also taken) with the optional sub-second
    digits (``"25"`` is 0.25 s); None when absent or unparsable."""
    if not isinstance(text, str) or not text.strip():
        return None
    text = text.strip()
    try:
        when = _dt.datetime.strptime(text[:19], "%Y:%m:%d %H:%M:%S")
    except ValueError:
        try:
            when = _dt.datetime.fromisoformat(text)
        except ValueError:
            logger.debug("unparsable capture time %r", text)
            return None
    digits = "".join(ch for ch in str(subsec or "") if ch.isdigit())
    if digits:
        when = when.replace(microsecond=int(round(float("0." + digits) * 1e6)) % 1000000)
    return when


def capture_time(original: Optional[str], subsec: Optional[str], container: Optional[str],
                 camera: bool) -> Optional[_dt.datetime]:
    """When the frame was shot, or None when nothing says so.

    ``original`` is EXIF's DateTimeOriginal (the shutter's moment, with ``subsec``);
    ``container`` the file's own DateTime (TIFF tag 306, PNG's tIME chunk), which is when
    the file was last written: a camera writes it at capture, a converter at conversion
    (a folder of PNGs converted together all carry one stamp). It counts only for a file
    that a camera wrote (``camera``: the file names its make or model)."""
    when = parse_datetime(original, subsec)
    if when is None and camera:
        when = parse_datetime(container)
    return when
