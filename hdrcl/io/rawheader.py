"""The EXIF fields of a RAW file, read from the file's own TIFF structures.

rawpy exposes only shutter time, aperture, ISO, focal length and a whole-second capture
time, and not the camera's make and model (see :mod:`hdrcl.io.raw`). Most RAW formats
carry a TIFF/EXIF header (CR2, NEF, ARW, DNG, PEF, SRW, ORF, RW2; CR3's ``CMT1``/``CMT2``
boxes; RAF's embedded JPEG): :func:`header_fields` reads the wanted tags of its IFD0 and
EXIF IFD directly, best effort, for exact rational exposure times, sub-second capture
times, make, model, serial number, exposure bias and mode. A malformed structure gives
fewer fields (or none), never an error.
"""
from __future__ import annotations

import logging
import struct
from typing import Optional

logger = logging.getLogger(__name__)

__all__ = ["header_fields"]

_TAGS = {
    271: "make", 272: "model", 306: "datetime", 33434: "exposure_time", 33437: "fnumber",
    34855: "iso", 36867: "datetime_original", 37521: "subsec_original", 37380: "exposure_bias",
    37386: "focal_length", 41986: "exposure_mode", 42033: "serial", 42036: "lens",
}
_EXIF_POINTER = 34665
#: TIFF field type: (struct code per value, bytes per value)
_TYPES = {1: ("B", 1), 2: ("s", 1), 3: ("H", 2), 4: ("I", 4), 5: ("I", 8), 6: ("b", 1),
          7: ("B", 1), 8: ("h", 2), 9: ("i", 4), 10: ("i", 8), 11: ("f", 4), 12: ("d", 8)}
_HEAD_SCAN = 1 << 19  # bytes searched for an embedded TIFF (CR3 boxes, RAF's JPEG)


class _Bad(Exception):
    """Malformed TIFF structure; the EXIF reader gives up quietly."""


def _read_at(fh, base: int, off: int, n: int) -> bytes:
    fh.seek(base + off)
    data = fh.read(n)
    if len(data) != n:
        raise _Bad("short read")
    return data


def _tiff_value(fh, base: int, e: str, typ: int, count: int, field: bytes):
    code, size = _TYPES[typ]
    total = size * count
    if count == 0 or count > 4096:
        return None
    data = field[:total] if total <= 4 else _read_at(fh, base, struct.unpack(e + "I", field)[0], total)
    if typ == 2:
        return data.split(b"\0", 1)[0].decode("latin-1").strip() or None
    if typ in (5, 10):
        num, den = struct.unpack_from(e + code * 2, data)
        return num / den if den else None
    return struct.unpack_from(e + code, data)[0]


def _tiff_ifd(fh, base: int, e: str, off: int, out: dict) -> Optional[int]:
    """Read the wanted tags of the IFD at ``off`` into ``out``; return the EXIF IFD offset."""
    (n,) = struct.unpack(e + "H", _read_at(fh, base, off, 2))
    if n > 1000:
        raise _Bad(f"{n} entries")
    table = _read_at(fh, base, off + 2, 12 * n)
    exif = None
    for k in range(n):
        tag, typ, count = struct.unpack_from(e + "HHI", table, 12 * k)
        field = table[12 * k + 8:12 * k + 12]
        if tag == _EXIF_POINTER:
            exif = struct.unpack(e + "I", field)[0]
        elif tag in _TAGS and typ in _TYPES:
            try:
                value = _tiff_value(fh, base, e, typ, count, field)
            except (_Bad, struct.error):
                continue
            if value is not None:
                out[_TAGS[tag]] = value
    return exif


def _tiff_fields(fh, base: int) -> dict:
    """Wanted tags of IFD0 and its EXIF IFD, for a TIFF header at ``base`` in ``fh``."""
    out: dict = {}
    head = _read_at(fh, base, 0, 8)
    e = {b"II": "<", b"MM": ">"}.get(head[:2])
    if e is None:
        return out
    # The magic number varies (42 TIFF, 0x4F52 ORF, 0x55 RW2): trust the structure instead.
    exif = _tiff_ifd(fh, base, e, struct.unpack(e + "I", head[4:8])[0], out)
    if exif:
        try:
            _tiff_ifd(fh, base, e, exif, out)  # EXIF values win over IFD0's copies
        except (_Bad, struct.error) as exc:
            logger.debug("unreadable EXIF IFD (%s); keeping IFD0's fields", exc)
    return out


def header_fields(name: str) -> dict:
    """Best-effort EXIF fields from a RAW file's TIFF structures; {} when none are found."""
    try:
        with open(name, "rb") as fh:
            head = fh.read(16)
            if head[:2] in (b"II", b"MM"):
                return _tiff_fields(fh, 0)
            fh.seek(0)
            blob = fh.read(_HEAD_SCAN)
            out: dict = {}
            if head[4:8] == b"ftyp":  # CR3: CMT1 holds IFD0, CMT2 the EXIF IFD, as TIFFs
                for box in (b"CMT1", b"CMT2"):
                    pos = blob.find(box)
                    if pos >= 0:
                        try:
                            out.update(_tiff_fields(fh, pos + 4))
                        except (_Bad, struct.error) as exc:
                            logger.debug("%s: unreadable %s box (%s)", name, box.decode(), exc)
                return out
            pos = blob.find(b"Exif\x00\x00")  # RAF and others: an embedded JPEG's APP1
            if pos >= 0:
                return _tiff_fields(fh, pos + 6)
            return out
    except (OSError, _Bad, struct.error, ValueError, KeyError, OverflowError) as exc:
        logger.debug("%s: no readable EXIF header (%s)", name, exc)
        return {}
