"""What a damaged photograph's header still says.

A JPEG cut short inside its EXIF block (a card pulled out while writing, a copy that
stopped) cannot be opened by OpenImageIO, yet its first bytes usually still hold the
capture time, the exposure and the camera. :func:`salvage_info` reads them tolerantly
(Pillow's EXIF parser on the bytes there are), so that the scan can place the damaged
frame in its set by its metadata and fail that set naming the file, instead of merging
the set from the frames left as if nothing were missing.
"""
from __future__ import annotations

import logging
import os
import warnings
from typing import Optional

from hdrcl.io.exif import capture_time, snap_reciprocal
from hdrcl.io.metadata import FrameInfo

logger = logging.getLogger(__name__)

__all__ = ["salvage_info"]

# EXIF tag numbers (IFD0 and the Exif IFD).
_MAKE, _MODEL, _EXIF_IFD, _DATETIME = 271, 272, 0x8769, 306
_TIME, _FNUMBER, _ISO, _ORIGINAL, _SUBSEC = 33434, 33437, 34855, 36867, 37521
_BIAS, _FOCAL, _WIDTH, _HEIGHT, _MODE = 37380, 37386, 40962, 40963, 41986
_SERIAL, _LENS = 42033, 42036
#: Bytes read from the start of the file: the APP1 block is at most 64 KiB.
_HEAD = 1 << 17


def _num(v) -> Optional[float]:
    if v is None:
        return None
    if isinstance(v, (tuple, list)):
        v = v[0] if v else None
    try:
        f = float(v)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return f if f == f and abs(f) != float("inf") else None


def _text(v) -> Optional[str]:
    if isinstance(v, bytes):
        v = v.decode("latin-1", "replace")
    if v is None:
        return None
    s = str(v).strip().strip("\x00").strip()
    return s or None


def salvage_info(path) -> Optional[FrameInfo]:
    """The header fields a damaged JPEG still carries, or None.

    Only a frame with a capture time and an exposure time is returned (what places it
    in its set); the image size is the EXIF one (0 where EXIF has none). Never raises.
    """
    path = os.fspath(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(_HEAD)
    except OSError:
        return None
    at = head.find(b"Exif\x00\x00")
    if not head.startswith(b"\xff\xd8") or at < 0:
        return None
    try:
        from PIL import Image

        with warnings.catch_warnings():  # Pillow warns of the very damage salvaged here
            warnings.simplefilter("ignore")
            exif = Image.Exif()
            exif.load(head[at:])
            sub = dict(exif.get_ifd(_EXIF_IFD))
            top = dict(exif)
    except Exception as exc:  # noqa: BLE001 - whatever the damage, nothing is salvaged
        logger.debug("%s: no EXIF salvaged: %s", path, exc)
        return None
    t = _num(sub.get(_TIME))
    make, model = _text(top.get(_MAKE)), _text(top.get(_MODEL))
    when = capture_time(_text(sub.get(_ORIGINAL)), _text(sub.get(_SUBSEC)), _text(top.get(_DATETIME)),
                        bool(make or model))
    if t is None or t <= 0 or when is None:
        return None
    mode = _num(sub.get(_MODE))
    both = {**top, **sub}  # writers put the serial and the lens in either IFD
    size = _frame_size(head) or (int(_num(sub.get(_WIDTH)) or 0), int(_num(sub.get(_HEIGHT)) or 0))
    return FrameInfo(path=path, width=size[0], height=size[1],
                     nchannels=3, channel_names=("R", "G", "B"), bits=8, exposure_time=snap_reciprocal(t),
                     fnumber=_num(sub.get(_FNUMBER)), iso=_num(sub.get(_ISO)), exposure_bias=_num(sub.get(_BIAS)),
                     exposure_mode=None if mode is None else int(mode), capture_time=when, make=make, model=model,
                     serial=_text(both.get(_SERIAL)), lens=_text(both.get(_LENS)), focal_length=_num(sub.get(_FOCAL)))


def _frame_size(head: bytes):
    """(width, height) from the JPEG's start-of-frame marker when the bytes reach it."""
    i = 2
    while i + 9 <= len(head) and head[i] == 0xFF:
        marker = head[i + 1]
        length = int.from_bytes(head[i + 2:i + 4], "big")
        if marker in (0xC0, 0xC1, 0xC2) and i + 9 <= len(head):
            h, w = int.from_bytes(head[i + 5:i + 7], "big"), int.from_bytes(head[i + 7:i + 9], "big")
            return (w, h) if w and h else None
        if marker == 0xDA or length < 2:
            return None
        i += 2 + length
    return None
