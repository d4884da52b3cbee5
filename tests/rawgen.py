"""Write small, valid DNG files of a synthetic linear scene (test helper for RAW input).

A DNG here is one uncompressed 16-bit RGGB Bayer mosaic in IFD0 with the tags LibRaw needs
(DNGVersion, CFA layout, BlackLevel, WhiteLevel, AsShotNeutral, ColorMatrix1 and its
illuminant) and the EXIF exposure fields in IFD0, where LibRaw also reads them for DNG.
ColorMatrix1 is the XYZ -> linear sRGB matrix, so the camera's primaries *are* sRGB and
LibRaw's colour conversion is the identity: the decoded channel ``c`` is proportional to
``radiance[..., c]``.

A frame is ``black + radiance * t * gain`` digital numbers (DN) plus seeded read noise,
clipped where the sensor clips (``clip``, default the file's WhiteLevel), exactly what a
linear sensor records.

Also :func:`exif_tiff`, a minimal TIFF with IFD0 and an EXIF IFD, for testing the EXIF
reader on headers embedded in non-TIFF containers.

Imports NumPy and tifffile only.
"""
from __future__ import annotations

import os
import struct
from fractions import Fraction
from typing import Optional, Sequence

import numpy as np

__all__ = ["BLACK", "WHITE", "XYZ_TO_SRGB", "mosaic", "write_dng", "write_bracket", "exif_tiff"]

BLACK = 512
WHITE = 15000
#: XYZ (D65) -> linear sRGB; as a DNG ColorMatrix it declares sRGB camera primaries.
XYZ_TO_SRGB = np.array([[3.2404542, -1.5371385, -0.4985314],
                        [-0.9692660, 1.8760108, 0.0415560],
                        [0.0556434, -0.2040259, 1.0572252]])
#: Colour of each site of the 2 x 2 RGGB pattern (0 R, 1 G, 2 B).
RGGB = np.array([[0, 1], [1, 2]])


def mosaic(radiance: np.ndarray, t: float, *, gain: float = 1000.0, black: int = BLACK,
           white: int = WHITE, clip: Optional[int] = None, noise: float = 2.0,
           seed: int = 0) -> np.ndarray:
    """RGGB mosaic ``(H, W)`` uint16 of ``radiance`` ``(H, W, 3)`` exposed for ``t``.

    ``black + radiance[site colour] * t * gain + N(0, noise)``, rounded, clipped to
    ``[0, clip]`` (``clip`` defaults to ``white``; a lower value models a sensor that
    clips below its nominal white level).
    """
    h, w = radiance.shape[:2]
    colour = np.tile(RGGB, ((h + 1) // 2, (w + 1) // 2))[:h, :w]
    rad = np.take_along_axis(radiance, colour[..., None], axis=2)[..., 0]
    rng = np.random.default_rng(seed)
    dn = black + rad * t * gain + rng.normal(0.0, noise, (h, w))
    top = white if clip is None else clip
    return np.clip(np.floor(dn + 0.5), 0, top).astype(np.uint16)


def _rationals(values):
    out = []
    for v in np.ravel(values):
        f = Fraction(float(v)).limit_denominator(1000000)
        out += [f.numerator, f.denominator]
    return tuple(out)


def write_dng(path, cfa: np.ndarray, *, black: int = BLACK, white: int = WHITE,
              exposure_time: Optional[float] = None, fnumber: Optional[float] = 8.0,
              iso: Optional[int] = 100, neutral: Sequence[float] = (1.0, 1.0, 1.0),
              orientation: int = 1, make: str = "hdrcl", model: str = "Synthetic DNG",
              capture: Optional[str] = None, subsec: Optional[str] = None,
              bias: Optional[float] = None, serial: Optional[str] = None) -> str:
    """Write ``cfa`` (RGGB, uint16) as a DNG at ``path``; returns the path.

    ``capture`` is an EXIF date ``"YYYY:MM:DD HH:MM:SS"``; ``orientation`` the TIFF
    Orientation (1 upright, 6 rotate 90 degrees clockwise to view...).
    """
    import tifffile

    tags = [
        (33421, "H", 2, (2, 2), True),                        # CFARepeatPatternDim
        (33422, "B", 4, (0, 1, 1, 2), True),                  # CFAPattern RGGB
        (50706, "B", 4, (1, 4, 0, 0), True),                  # DNGVersion
        (50707, "B", 4, (1, 1, 0, 0), True),                  # DNGBackwardVersion
        (50708, "s", 0, f"{make} {model}", True),             # UniqueCameraModel
        (50710, "B", 3, (0, 1, 2), True),                     # CFAPlaneColor
        (50711, "H", 1, (1,), True),                          # CFALayout: rectangular
        (50714, "I", 1, (int(black),), True),                 # BlackLevel
        (50717, "I", 1, (int(white),), True),                 # WhiteLevel
        (50721, 10, 9, _rationals(XYZ_TO_SRGB), True),        # ColorMatrix1 (SRATIONAL)
        (50728, 5, 3, _rationals(neutral), True),             # AsShotNeutral
        (50778, "H", 1, (21,), True),                         # CalibrationIlluminant1: D65
        (271, "s", 0, make, True),
        (272, "s", 0, model, True),
        (274, "H", 1, (int(orientation),), True),
    ]
    if exposure_time is not None:
        tags.append((33434, 5, 1, _rationals([exposure_time]), True))
    if fnumber is not None:
        tags.append((33437, 5, 1, _rationals([fnumber]), True))
    if iso is not None:
        tags.append((34855, "H", 1, (int(iso),), True))
    if capture is not None:
        tags.append((306, "s", 0, capture, True))
        tags.append((36867, "s", 0, capture, True))
    if subsec is not None:
        tags.append((37521, "s", 0, subsec, True))
    if bias is not None:
        tags.append((37380, 10, 1, _rationals([bias]), True))
    if serial is not None:
        tags.append((42033, "s", 0, serial, True))
    tifffile.imwrite(os.fspath(path), np.ascontiguousarray(cfa, np.uint16), photometric=32803,
                     extratags=tags, metadata=None, subfiletype=0, software=False)
    return os.fspath(path)


def write_bracket(folder, radiance: np.ndarray, times: Sequence[float], *, gain: float = 1000.0,
                  noise: float = 2.0, seed: int = 0, prefix: str = "IMG_", **kw) -> list:
    """One DNG per exposure time in ``folder`` (``IMG_0001.dng``...), EXIF time included."""
    paths = []
    for k, t in enumerate(times):
        cfa = mosaic(radiance, t, gain=gain, noise=noise, seed=seed + k,
                     black=kw.get("black", BLACK), white=kw.get("white", WHITE), clip=kw.get("clip"))
        extra = {key: v for key, v in kw.items() if key != "clip"}
        paths.append(write_dng(os.path.join(os.fspath(folder), f"{prefix}{k + 1:04d}.dng"), cfa,
                               exposure_time=t, **extra))
    return paths


def exif_tiff(ifd0: Sequence[tuple], exif: Sequence[tuple]) -> bytes:
    """A little-endian TIFF with ``ifd0`` and an EXIF IFD (pointer tag 34665) holding ``exif``.

    Entries are ``(tag, kind, value)`` with kind ``"ascii"``, ``"short"``, ``"long"``,
    ``"rational"`` or ``"srational"`` (value ``(num, den)``).
    """
    codes = {"ascii": 2, "short": 3, "long": 4, "rational": 5, "srational": 10}

    def payload(kind, value):
        if kind == "ascii":
            b = value.encode("latin-1") + b"\0"
            return b, len(b)
        if kind == "short":
            return struct.pack("<H", value), 1
        if kind == "long":
            return struct.pack("<I", value), 1
        return struct.pack("<ii" if kind == "srational" else "<II", *value), 1

    ifd0 = list(ifd0) + ([(34665, "long", 0)] if exif else [])
    n0, n1 = len(ifd0), len(exif)
    off0 = 8
    off1 = off0 + 2 + 12 * n0 + 4
    data_at = off1 + 2 + 12 * n1 + 4
    data = bytearray()

    def table(entries):
        out = bytearray(struct.pack("<H", len(entries)))
        for tag, kind, value in sorted(entries, key=lambda e: e[0]):
            if tag == 34665:
                value = off1
            raw, count = payload(kind, value)
            out += struct.pack("<HHI", tag, codes[kind], count)
            if len(raw) <= 4:
                out += raw.ljust(4, b"\0")
            else:
                out += struct.pack("<I", data_at + len(data))
                data.extend(raw + (b"\0" if len(raw) % 2 else b""))
        return out + struct.pack("<I", 0)

    t0 = table(ifd0)
    t1 = table(list(exif))
    return b"II*\0" + struct.pack("<I", off0) + bytes(t0) + bytes(t1) + bytes(data)
