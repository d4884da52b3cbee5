"""Writers of pictures for HDR screens: Ultra HDR (gain-map) JPEG, AVIF and JPEG XL with
PQ or HLG (what :mod:`hdrcl.report.deliver` renders; ``docs/deliver.md``).

The codecs are libraries': libjpeg-turbo (``imagecodecs.jpeg8_encode``) for the two
JPEG images of an Ultra HDR file, libavif (``imagecodecs.avif_encode``) for AVIF and
libjxl through OpenImageIO for JPEG XL (imagecodecs' libjxl binding has no colour
encoding parameter; OpenImageIO's writes the CICP triplet we give it). Only the Ultra HDR
*container* is written here: libultrahdr's binding (``imagecodecs.ultrahdr_encode``)
takes the HDR image alone, tone-maps its own base and always states a 5.62-stop headroom
(measured with libultrahdr 1.4: its ``nits`` argument changes nothing for linear input),
so neither our SDR rendering nor the headroom asked could be the file's. The container is
the one libultrahdr itself writes and reads: a primary JPEG with an ISO 21496-1 version
segment and an MPF index (CIPA DC-007), followed by the gain-map JPEG carrying the
ISO 21496-1 metadata, plus the Adobe/Google ``hdrgm`` XMP (Ultra HDR 1.0) that older
Android and Chromium read. Every file is written atomically.
"""
from __future__ import annotations

import math
import os
import struct
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from hdrcl.errors import HdrclError, UsageError
from hdrcl.io.atomic import atomic_output

__all__ = ["REFERENCE_WHITE_NITS", "HLG_REFERENCE_SCENE", "PQ_PEAK_NITS", "GainMapMeta", "pq_encode", "pq_decode",
           "hlg_encode", "hlg_decode", "write_ultrahdr", "write_avif", "write_jxl", "codecs_available"]

#: Diffuse (graphics) white of PQ and HLG pictures, cd/m^2 (ITU-R BT.2408).
REFERENCE_WHITE_NITS = 203.0
#: PQ's peak, cd/m^2 (SMPTE ST 2084).
PQ_PEAK_NITS = 10000.0
#: HLG's scene-linear value of reference white (signal 0.75, BT.2408): 0.26496.
HLG_REFERENCE_SCENE = 0.26496
#: ISO 21496-1 namespace of its APP2 segments.
ISO_URN = b"urn:iso:std:iso:ts:21496:-1\x00"
#: Fractions of the ISO 21496-1 metadata are written over this denominator (as libultrahdr).
_DEN = 1 << 20
#: CICP codes (ITU-T H.273): BT.709 primaries, PQ and HLG transfers, BT.709 matrix.
CICP_PRIMARIES_BT709, CICP_PQ, CICP_HLG, CICP_MATRIX_BT709 = 1, 16, 18, 1

_M1, _M2 = 2610 / 16384, 2523 / 4096 * 128
_C1, _C2, _C3 = 3424 / 4096, 2413 / 4096 * 32, 2392 / 4096 * 32
_HA = 0.17883277
_HB = 1 - 4 * _HA
_HC = 0.5 - _HA * math.log(4 * _HA)


def _float(x) -> np.ndarray:
    """float32 stays float32 (the files' path), anything else becomes float64."""
    a = np.asarray(x)
    return a if a.dtype in (np.float32, np.float64) else a.astype(np.float64)


def pq_encode(nits: np.ndarray) -> np.ndarray:
    """SMPTE ST 2084 inverse EOTF: cd/m^2 (0..10000) to a signal in [0, 1]."""
    y = np.clip(_float(nits) / PQ_PEAK_NITS, 0.0, 1.0) ** _M1
    return ((_C1 + _C2 * y) / (1.0 + _C3 * y)) ** _M2


def pq_decode(signal: np.ndarray) -> np.ndarray:
    """SMPTE ST 2084 EOTF: a signal in [0, 1] to cd/m^2."""
    e = np.clip(np.asarray(signal, np.float64), 0.0, 1.0) ** (1.0 / _M2)
    return PQ_PEAK_NITS * (np.maximum(e - _C1, 0.0) / (_C2 - _C3 * e)) ** (1.0 / _M1)


def hlg_encode(scene: np.ndarray) -> np.ndarray:
    """ITU-R BT.2100 HLG OETF: scene-linear [0, 1] to a signal in [0, 1]."""
    e = np.clip(_float(scene), 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        log = _HA * np.log(np.maximum(12.0 * e - _HB, 1e-12)) + _HC
    return np.where(e <= 1.0 / 12.0, np.sqrt(3.0 * e), log)


def hlg_decode(signal: np.ndarray) -> np.ndarray:
    """The HLG inverse OETF: a signal in [0, 1] to scene-linear [0, 1]."""
    s = np.clip(np.asarray(signal, np.float64), 0.0, 1.0)
    return np.where(s <= 0.5, s * s / 3.0, (np.exp((s - _HC) / _HA) + _HB) / 12.0)


def _imagecodecs():
    try:
        import imagecodecs
    except ImportError:
        raise UsageError("HDR-screen outputs need imagecodecs 2026.3 or later: "
                         "pip install 'hdrcl[hdr-display]'") from None
    return imagecodecs


def codecs_available() -> Optional[str]:
    """None when every writer here can run, else why not (one line)."""
    try:
        ic = _imagecodecs()
    except UsageError as exc:
        return str(exc)
    missing = [n for n in ("JPEG8", "AVIF") if not getattr(getattr(ic, n, None), "available", False)]
    return f"imagecodecs lacks {', '.join(missing)}" if missing else None


# ------------------------------------------------------------------------ Ultra HDR
@dataclass(frozen=True)
class GainMapMeta:
    """The gain map's meaning (ISO 21496-1 / Ultra HDR 1.0), per channel where a list.

    ``HDR = (SDR + base_offset) * 2^G - alternate_offset`` with ``G = gain_min + (gain_max
    - gain_min) * code^(1/gamma)`` (log2 units, ``code`` in [0, 1]), applied fully on a
    display with ``alternate_headroom`` stops of headroom and not at all at
    ``base_headroom`` (both log2)."""

    gain_min: Sequence[float]
    gain_max: Sequence[float]
    gamma: float = 1.0
    base_offset: float = 1 / 64
    alternate_offset: float = 1 / 64
    base_headroom: float = 0.0
    alternate_headroom: float = 3.0


def _frac(v: float, signed: bool = True) -> bytes:
    n = int(round(float(v) * _DEN))
    return struct.pack(">iI" if signed else ">II", n, _DEN)


def _iso_metadata(meta: GainMapMeta, channels: int) -> bytes:
    """The ISO 21496-1 gain-map metadata (version 0, one fraction per value)."""
    flags = (0x80 if channels == 3 else 0) | 0x40  # multichannel; gain applied in the base's colour space
    out = struct.pack(">HHB", 0, 0, flags)
    out += _frac(meta.base_headroom, False) + _frac(meta.alternate_headroom, False)
    for c in range(channels):
        out += (_frac(meta.gain_min[c]) + _frac(meta.gain_max[c]) + _frac(meta.gamma, False)
                + _frac(meta.base_offset) + _frac(meta.alternate_offset))
    return out


def _xmp_gainmap(meta: GainMapMeta, channels: int) -> bytes:
    def seq(values):
        if channels == 1:
            return f'"{values[0]:.6f}"'
        return None

    attrs = {"Version": '"1.0"', "GainMapMin": seq(meta.gain_min), "GainMapMax": seq(meta.gain_max),
             "Gamma": f'"{meta.gamma:.6f}"', "OffsetSDR": f'"{meta.base_offset:.6f}"',
             "OffsetHDR": f'"{meta.alternate_offset:.6f}"', "HDRCapacityMin": f'"{meta.base_headroom:.6f}"',
             "HDRCapacityMax": f'"{meta.alternate_headroom:.6f}"', "BaseRenditionIsHDR": '"False"'}
    inline = " ".join(f"hdrgm:{k}={v}" for k, v in attrs.items() if v is not None)
    lists = ""
    if channels == 3:
        for key, vals in (("GainMapMin", meta.gain_min), ("GainMapMax", meta.gain_max)):
            items = "".join(f"<rdf:li>{v:.6f}</rdf:li>" for v in vals)
            lists += f"<hdrgm:{key}><rdf:Seq>{items}</rdf:Seq></hdrgm:{key}>"
    return _xmp_packet(f'<rdf:Description rdf:about="" xmlns:hdrgm="http://ns.adobe.com/hdr-gain-map/1.0/" '
                       f"{inline}>{lists}</rdf:Description>")


def _xmp_primary(gainmap_length: int) -> bytes:
    return _xmp_packet(
        '<rdf:Description rdf:about="" xmlns:Container="http://ns.google.com/photos/1.0/container/" '
        'xmlns:Item="http://ns.google.com/photos/1.0/container/item/" '
        'xmlns:hdrgm="http://ns.adobe.com/hdr-gain-map/1.0/" hdrgm:Version="1.0">'
        "<Container:Directory><rdf:Seq>"
        '<rdf:li rdf:parseType="Resource"><Container:Item Item:Semantic="Primary" Item:Mime="image/jpeg"/></rdf:li>'
        '<rdf:li rdf:parseType="Resource"><Container:Item Item:Semantic="GainMap" Item:Mime="image/jpeg" '
        f'Item:Length="{gainmap_length}"/></rdf:li>'
        "</rdf:Seq></Container:Directory></rdf:Description>")


def _xmp_packet(description: str) -> bytes:
    body = ('<x:xmpmeta xmlns:x="adobe:ns:meta/" x:xmptk="hdrcl">'
            '<rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
            f"{description}</rdf:RDF></x:xmpmeta>")
    return b"http://ns.adobe.com/xap/1.0/\x00" + body.encode("utf-8")


def _segment(marker: int, payload: bytes) -> bytes:
    if len(payload) + 2 > 0xFFFF:
        raise HdrclError("Ultra HDR: a metadata segment exceeds 64 KiB")
    return struct.pack(">BBH", 0xFF, marker, len(payload) + 2) + payload


def _mpf(primary_size: int, gainmap_size: int, gainmap_offset: int) -> bytes:
    """The MPF APP2 payload (CIPA DC-007, big endian) indexing the two images;
    ``gainmap_offset`` is counted from the TIFF header that follows ``MPF\\0``."""
    entries_offset = 8 + 2 + 3 * 12 + 4
    ifd = struct.pack(">H", 3)
    ifd += struct.pack(">HHI4s", 0xB000, 7, 4, b"0100")
    ifd += struct.pack(">HHII", 0xB001, 4, 1, 2)
    ifd += struct.pack(">HHII", 0xB002, 7, 32, entries_offset)
    ifd += struct.pack(">I", 0)
    entries = struct.pack(">IIIHH", 0x030000, primary_size, 0, 0, 0)
    entries += struct.pack(">IIIHH", 0, gainmap_size, gainmap_offset, 0, 0)
    return b"MPF\x00" + b"MM\x00\x2a" + struct.pack(">I", 8) + ifd + entries


def _strip_soi(jpeg: bytes) -> bytes:
    if jpeg[:2] != b"\xff\xd8":
        raise HdrclError("Ultra HDR: the JPEG encoder returned no JPEG")
    return jpeg[2:]


def ultrahdr_bytes(base: np.ndarray, gain: np.ndarray, meta: GainMapMeta, quality: int = 95,
                   gain_quality: int = 95) -> bytes:
    """An Ultra HDR JPEG: ``base`` (``(H, W, 3)`` uint8 sRGB) with the gain map ``gain``
    (``(h, w)`` or ``(h, w, 3)`` uint8 codes, the meaning in ``meta``)."""
    ic = _imagecodecs()
    channels = 1 if gain.ndim == 2 or gain.shape[2] == 1 else 3
    primary_jpeg = _strip_soi(bytes(ic.jpeg8_encode(np.ascontiguousarray(base), level=quality)))
    gain_jpeg = _strip_soi(bytes(ic.jpeg8_encode(np.ascontiguousarray(gain if channels == 3 else
                                                                       gain.reshape(gain.shape[:2])),
                                                 level=gain_quality)))
    second = (b"\xff\xd8" + _segment(0xE1, _xmp_gainmap(meta, channels))
              + _segment(0xE2, ISO_URN + _iso_metadata(meta, channels)) + gain_jpeg)
    head = b"\xff\xd8" + _segment(0xE1, _xmp_primary(len(second))) + _segment(0xE2, ISO_URN + struct.pack(">HH", 0, 0))
    mpf_len = len(_segment(0xE2, _mpf(0, 0, 0)))
    primary_size = len(head) + mpf_len + len(primary_jpeg)
    tiff_at = len(head) + 4 + 4  # marker and length, then "MPF\0"
    mpf = _segment(0xE2, _mpf(primary_size, len(second), primary_size - tiff_at))
    return head + mpf + primary_jpeg + second


def write_ultrahdr(path, base: np.ndarray, gain: np.ndarray, meta: GainMapMeta, quality: int = 95) -> int:
    """Write :func:`ultrahdr_bytes` atomically; the file's size in bytes."""
    return _write_bytes(path, ultrahdr_bytes(base, gain, meta, quality))


# ------------------------------------------------------------------------ AVIF, JPEG XL
def _transfer_code(transfer: str) -> int:
    if transfer not in ("pq", "hlg"):
        raise UsageError(f"HDR transfer '{transfer}': use pq or hlg")
    return CICP_PQ if transfer == "pq" else CICP_HLG


#: libavif's speed (0 slowest .. 10): 8 took 1.07 s for a 12 MP map where 6 took 4.6 s
#: and its default 100 s or so; the error is the same (1.5 MP: 0.013 stops median, 0.05 at
#: the 99th percentile, quality 90).
AVIF_SPEED = 8
#: libjxl's effort (1 .. 9; 7 its default): 3 takes 0.06 s for 1.5 MP where 7 takes 0.85 s,
#: 0.008 stops median error instead of 0.005.
JXL_EFFORT = 3


def write_avif(path, codes: np.ndarray, bits: int, transfer: str, quality: int = 90) -> int:
    """An AVIF of ``codes`` (``(H, W, 3)`` uint16, 0 .. 2^bits-1, PQ or HLG signal of BT.709
    primaries), YUV 4:4:4, its CICP (nclx) saying so; the size in bytes."""
    ic = _imagecodecs()
    try:
        data = ic.avif_encode(np.ascontiguousarray(codes), quality, bitspersample=int(bits), pixelformat="444", speed=AVIF_SPEED,
                              primaries=CICP_PRIMARIES_BT709, transfer=_transfer_code(transfer),
                              matrix=CICP_MATRIX_BT709, numthreads=os.cpu_count() or 1)
    except Exception as exc:
        raise HdrclError(f"{path}: AVIF encoding failed ({type(exc).__name__})") from None
    return _write_bytes(path, bytes(data))


def write_jxl(path, codes: np.ndarray, bits: int, transfer: str, distance: float = 1.0) -> int:
    """A JPEG XL of ``codes`` (as :func:`write_avif`) through OpenImageIO's libjxl writer,
    the CICP triplet as its colour encoding, lossy at Butteraugli ``distance`` (1.0: visually
    lossless); the size in bytes."""
    import OpenImageIO as oiio

    h, w, c = codes.shape
    top = (1 << int(bits)) - 1
    full = np.round(codes.astype(np.float64) * (65535.0 / top)).astype(np.uint16)  # OIIO's uint16 is full range
    spec = oiio.ImageSpec(w, h, c, "uint16")
    spec.attribute("CICP", "int[4]", (CICP_PRIMARIES_BT709, _transfer_code(transfer), 0, 1))
    spec.attribute("oiio:BitsPerSample", int(bits))
    spec.attribute("jpegxl:distance", float(distance))
    spec.attribute("jpegxl:effort", JXL_EFFORT)
    with atomic_output(path) as tmp:
        out = oiio.ImageOutput.create(tmp)
        if out is None or not out.open(tmp, spec):
            raise HdrclError(f"{path}: cannot write JPEG XL ({_first(oiio.geterror())})")
        try:
            if not out.write_image(full):
                raise HdrclError(f"{path}: cannot write JPEG XL ({_first(out.geterror())})")
        finally:
            out.close()
    return os.path.getsize(path)


def _first(msg: str) -> str:
    return (msg or "unknown error").strip().splitlines()[0] if (msg or "").strip() else "unknown error"


def _write_bytes(path, data: bytes) -> int:
    with atomic_output(path) as tmp:
        try:
            with open(tmp, "wb") as f:
                f.write(data)
        except OSError as exc:
            raise HdrclError(f"{path}: cannot write ({exc.strerror or exc})") from None
    return len(data)
