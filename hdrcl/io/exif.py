"""EXIF values as hdrcl reads them, whichever reader found them (OpenImageIO for image
files, hdrcl's own TIFF walk for camera RAW headers): one place for the rules that turn
recorded fields into exposure times and capture times, and what EXIF Orientation means.

**Orientation** (EXIF/TIFF tag 274, 1..8) says how the stored rows and columns are to be
shown: 1 as stored, 6 "rotate 90 degrees clockwise to view" (a camera held upright), 8
counter-clockwise, 3 half a turn, 2/4/5/7 the mirrored variants. hdrcl merges the pixels
as stored (every frame of a set alike) and writes the set's orientation into the output
(:func:`hdr_resolution` for Radiance files, the ``Orientation`` attribute elsewhere);
:func:`to_display` turns stored pixels into the upright picture (the batch's previews).
"""
from __future__ import annotations

import datetime as _dt
import logging
from typing import Iterable, Optional

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


#: What each EXIF Orientation asks of a viewer (stored pixels -> the picture as shot).
ORIENTATIONS = {
    1: "upright as stored",
    2: "mirror left-right to view",
    3: "rotate 180 degrees to view",
    4: "mirror top-bottom to view",
    5: "mirror along the main diagonal to view",
    6: "rotate 90 degrees clockwise to view",
    7: "mirror along the other diagonal to view",
    8: "rotate 90 degrees counter-clockwise to view",
}


def orientation_value(value) -> int:
    """EXIF Orientation as an int 1..8; 1 (as stored) when absent or not one of those."""
    try:
        o = int(value)
    except (TypeError, ValueError):
        return 1
    return o if o in ORIENTATIONS else 1


def common_orientation(tags: Iterable[int]) -> int:
    """The orientation a set's output takes: the tag most frames carry, the first
    frame's among equally common ones (1 for no frames)."""
    tags = [orientation_value(t) for t in tags]
    if not tags:
        return 1
    return max(dict.fromkeys(tags), key=tags.count)  # max keeps the first of equals


def to_display(a: np.ndarray, orientation: int) -> np.ndarray:
    """Stored pixels ``a`` (H, W[, C]) as a viewer shows them under EXIF ``orientation``
    (6: turned 90 degrees clockwise, so the stored top row becomes the right column)."""
    o = orientation_value(orientation)
    if o in (2, 3):
        a = a[:, ::-1]
    if o in (3, 4):
        a = a[::-1]
    if o >= 5:
        a = a.swapaxes(0, 1)  # 5: the transpose; 6, 7, 8 a transpose and a mirror
        if o in (6, 7):
            a = a[:, ::-1]
        if o in (7, 8):
            a = a[::-1]
    return np.ascontiguousarray(a)


def hdr_resolution(orientation: int, height: int, width: int) -> str:
    """Radiance's resolution line for ``height`` stored scanlines of ``width`` pixels
    shown under EXIF ``orientation``: ``-Y H +X W`` for 1 (top row first, left to
    right), ``-X H -Y W`` for 6 (the stored rows are the picture's columns, right to
    left, each top to bottom). Radiance's programs (pvalue, pfilt, ra_tiff, ximage)
    place the pixels by it."""
    o = orientation_value(orientation)
    y = "+Y" if o in (3, 4, 7, 8) else "-Y"
    x = "-X" if o in (2, 3, 6, 7) else "+X"
    return f"{y} {height} {x} {width}" if o <= 4 else f"{x} {height} {y} {width}"
