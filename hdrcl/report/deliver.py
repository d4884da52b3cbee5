"""Pictures for HDR screens rendered from a radiance map (``--deliver``; docs/deliver.md).

One :class:`Rendering` per map: the radiance scaled so that 1.0 is reference (diffuse)
white, the SDR rendering (the previews' tone map at full size) and, per deliverable, the
HDR signal. Reference white is where the previews' tone map puts it: the scene's
log-average luminance becomes 18 % of white (Reinhard's key,
:data:`hdrcl.report.tonemap.KEY`), so midtones look alike on SDR and HDR screens. The HDR
renderings keep ``headroom`` stops above white and clip each channel there.

:data:`DELIVERABLES` is the registry, name -> suffix and writer; a new deliverable (an
exposure fusion, say) is one more :class:`Deliverable`. Pixels are computed in strips of
:data:`STRIP_ROWS` rows (float64 temporaries of a strip, whatever the image size); what
is whole is the radiance given (float32) and the 8/16-bit outputs handed to the codecs,
which take whole images.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from typing import Callable, Dict, List, Optional, Tuple

import numpy as np

from hdrcl.core.options import DeliverOptions
from hdrcl.report.tonemap import KEY, apply_global, statistics, tone_map_array

logger = logging.getLogger(__name__)

#: Rows per strip of the per-pixel work.
STRIP_ROWS = 256
#: Offsets of the gain map (ISO 21496-1's base and alternate offsets), as libultrahdr's.
GAIN_OFFSET = 1.0 / 64.0
#: The HLG headroom above reference white, stops: scene-linear 1.0 over BT.2408's 0.26496.
HLG_HEADROOM = float(np.log2(1.0 / 0.26496))


@dataclass(frozen=True)
class Deliverable:
    """One kind of picture: its name (``--deliver``), the file's ending (after the
    radiance map's stem), a line for the docs, and its writer ``write(path, rendering) ->
    record`` (a dict for report.json)."""

    name: str
    suffix: str
    what: str
    write: Callable[[str, "Rendering"], dict]


class Rendering:
    """What the deliverables of one radiance map are made from.

    Parameters
    ----------
    radiance : ndarray, (H, W, C)
        Linear radiance as stored (C = 1 or 3; more channels: the first three), any scale.
    options : DeliverOptions
    orientation : int
        EXIF orientation: the pictures are written upright, as the previews.
    """

    def __init__(self, radiance: np.ndarray, options: DeliverOptions, orientation: int = 1,
                 device: Optional[str] = None, frames=None):
        rad = np.asarray(radiance)
        if rad.ndim == 2:
            rad = rad[:, :, None]
        self.radiance = rad[:, :, :3]
        self.options, self.orientation, self.device = options, orientation, device
        #: ``frames()`` -> ``(frames, valid)``: the photographs themselves, for exposure
        #: fusion (decoded again, or the aligned frames a merge holds); None: not at hand.
        self.frames = frames
        self.h, self.w = rad.shape[:2]
        self.params = statistics(self.radiance, "reinhard" if options.tonemap == "reinhard-local" else options.tonemap)
        #: Multiplier to reference-white units (0 for a black map).
        self.white_scale = KEY / self.params.log_average if self.params.log_average > 0 else 0.0
        self._base: Optional[np.ndarray] = None

    # ---------------------------------------------------------------- pixels
    def strips(self, rows: int = STRIP_ROWS):
        for y0 in range(0, self.h, rows):
            yield y0, min(self.h, y0 + rows)

    def _rgb(self, y0: int, y1: int, dtype=np.float64) -> np.ndarray:
        s = np.asarray(self.radiance[y0:y1], dtype)
        s = np.where(np.isfinite(s), np.maximum(s, 0), 0).astype(dtype, copy=False)
        return np.repeat(s, 3, axis=2) if s.shape[2] == 1 else s

    def hdr(self, y0: int, y1: int, headroom: Optional[float] = None, dtype=np.float64) -> np.ndarray:
        """Rows ``y0:y1`` in reference-white units, each channel clipped at 2^headroom
        (float32 for the files: 2^-24 relative is far below any code step)."""
        top = 2.0 ** (self.options.headroom if headroom is None else headroom)
        return np.minimum(self._rgb(y0, y1, dtype) * dtype(self.white_scale), dtype(top))

    def base(self) -> np.ndarray:
        """The SDR rendering, ``(H, W, 3)`` sRGB uint8, stored orientation: the previews'
        operator with the full map's statistics."""
        if self._base is None:
            from hdrcl.cl.backend import get_processor
            from hdrcl.report.tonemap import OP_CODES

            op = self.options.tonemap
            proc = None if op == "reinhard-local" else get_processor("tonemap", self.device)
            if op == "reinhard-local":  # a local operator needs the whole map
                out = tone_map_array(self._rgb(0, self.h), op)
            elif proc is not None:  # the kernel of apply_global (within a code of its twin)
                out = np.empty((self.h, self.w, 3), np.uint8)
                for y0, y1 in self.strips(4096):
                    out[y0:y1] = proc.apply(self._rgb(y0, y1, np.float32), OP_CODES[op], self.params.scale,
                                            self.params.white, 8)
            else:
                out = np.empty((self.h, self.w, 3), np.uint8)
                for y0, y1 in self.strips():
                    out[y0:y1] = apply_global(self._rgb(y0, y1), self.params)
            self._base = out
        return self._base

    def signal(self, transfer: str, bits: int) -> Tuple[np.ndarray, float, Dict[str, float]]:
        """PQ or HLG codes ``(H, W, 3)`` uint16 (0 .. 2^bits-1), the headroom they keep and
        their content light level (CTA-861.3): ``max_cll``, the brightest pixel's largest
        channel, and ``max_fall``, the mean of that over the picture, cd/m^2."""
        from hdrcl.io.hdrdisplay import REFERENCE_WHITE_NITS, hlg_encode, pq_encode

        top = (1 << bits) - 1
        headroom = self.options.headroom if transfer == "pq" else min(self.options.headroom, HLG_HEADROOM)
        out = np.empty((self.h, self.w, 3), np.uint16)
        peak, total = 0.0, 0.0
        for y0, y1 in self.strips():
            x = self.hdr(y0, y1, headroom, np.float32)
            m = x.max(axis=2)
            peak, total = max(peak, float(m.max(initial=0.0))), total + float(m.sum(dtype=np.float64))
            sig = pq_encode(x * np.float32(REFERENCE_WHITE_NITS)) if transfer == "pq" else hlg_encode(
                x * np.float32(0.26496))
            out[y0:y1] = np.floor(sig * top + 0.5).astype(np.uint16)
        level = {"max_cll": round(peak * REFERENCE_WHITE_NITS, 1),
                 "max_fall": round(total * REFERENCE_WHITE_NITS / max(self.h * self.w, 1), 1)}
        return out, headroom, level

    def gain_map(self):
        """The Ultra HDR gain map of :meth:`base`: ``(H, W, 3)`` uint8 codes and its
        :class:`hdrcl.io.hdrdisplay.GainMapMeta` (log2 gains, per channel, from the base to
        the radiance clipped at the headroom)."""
        from hdrcl.io.hdrdisplay import GainMapMeta

        base = self.base()
        lut = (_srgb_decode_lut() + GAIN_OFFSET).astype(np.float32)
        off = np.float32(GAIN_OFFSET)
        # log2 gains held as float16 (6 bytes a pixel; steps of 0.008 stops at most, a
        # tenth of a code) between the pass that finds their range and the quantisation
        gains = np.empty((self.h, self.w, 3), np.float16)
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for y0, y1 in self.strips():
            g = np.log2((self.hdr(y0, y1, dtype=np.float32) + off) / lut[base[y0:y1]])
            gains[y0:y1] = g
            lo, hi = np.minimum(lo, g.min(axis=(0, 1))), np.maximum(hi, g.max(axis=(0, 1)))
        lo, hi = lo.astype(np.float16).astype(np.float64), hi.astype(np.float16).astype(np.float64)
        hi = np.maximum(hi, lo + 1e-3)  # a flat map still has a range
        codes = np.empty((self.h, self.w, 3), np.uint8)
        scale = (255.0 / (hi - lo)).astype(np.float32)
        for y0, y1 in self.strips():
            q = (gains[y0:y1].astype(np.float32) - lo.astype(np.float32)) * scale
            codes[y0:y1] = np.floor(np.clip(q, 0, 255) + 0.5).astype(np.uint8)
        del gains
        meta = GainMapMeta(gain_min=[float(v) for v in lo], gain_max=[float(v) for v in hi],
                           base_offset=GAIN_OFFSET, alternate_offset=GAIN_OFFSET,
                           base_headroom=0.0, alternate_headroom=self.options.headroom)
        return codes, meta

    def upright(self, a: np.ndarray) -> np.ndarray:
        from hdrcl.io.exif import to_display

        return to_display(a, self.orientation)


def _srgb_decode_lut() -> np.ndarray:
    c = np.arange(256) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


# ------------------------------------------------------------------------ writers
def _write_uhdr(path: str, r: Rendering) -> dict:
    from hdrcl.io.hdrdisplay import write_ultrahdr

    codes, meta = r.gain_map()
    size = write_ultrahdr(path, r.upright(r.base()), r.upright(codes), meta)
    return {"headroom": r.options.headroom, "base": f"{r.options.tonemap} (as the preview)", "bytes": size,
            "gain_min": [round(v, 4) for v in meta.gain_min], "gain_max": [round(v, 4) for v in meta.gain_max]}


def _signal_writer(kind: str):
    def write(path: str, r: Rendering) -> dict:
        from hdrcl.io import hdrdisplay

        codes, headroom, level = r.signal(r.options.transfer, r.options.bits)
        writer = hdrdisplay.write_avif if kind == "avif" else hdrdisplay.write_jxl
        size = writer(path, r.upright(codes), r.options.bits, r.options.transfer)
        return {"headroom": round(headroom, 4), "transfer": r.options.transfer, "bits": r.options.bits,
                "primaries": "bt709", "bytes": size, **level}

    return write


#: Name -> deliverable.
def _write_fusion(path: str, r: Rendering) -> dict:
    """Exposure fusion of the photographs (Mertens 2007, :func:`hdrcl.core.mertens.exposure_fusion`,
    exponents 1, 1, 1), 8-bit JPEG, upright as the previews; no radiance step."""
    from hdrcl.core.mertens import exposure_fusion, to_codes
    from hdrcl.io.exif import to_display
    from hdrcl.io.ldr import write_ldr

    if r.frames is None:
        from hdrcl.errors import UsageError

        raise UsageError("--deliver fusion: the frames are not at hand for this map")
    frames, valid = r.frames()
    codes = to_codes(exposure_fusion(frames, valid, device=r.device), 8)
    del frames, valid
    write_ldr(path, to_display(codes, r.orientation), metadata={"fusion": "Mertens 2007"})
    return {"bytes": os.path.getsize(path), "method": "Mertens 2007, exponents 1, 1, 1"}


DELIVERABLES: Dict[str, Deliverable] = {d.name: d for d in (
    Deliverable("uhdr", ".uhdr.jpg", "Ultra HDR JPEG: the SDR rendering plus an ISO 21496-1 gain map",
                _write_uhdr),
    Deliverable("avif", ".avif", "AVIF, PQ or HLG, 10/12-bit, BT.709 primaries", _signal_writer("avif")),
    Deliverable("jxl", ".jxl", "JPEG XL, PQ or HLG, 10/12-bit, BT.709 primaries", _signal_writer("jxl")),
    Deliverable("fusion", ".fusion.jpg", "exposure fusion of the frames (Mertens 2007), 8-bit JPEG, no radiance "
                "step", _write_fusion),
)}

#: Deliverables that need no HDR codec (imagecodecs).
PLAIN = ("fusion",)


def paths_for(output: str, options: DeliverOptions) -> Dict[str, str]:
    """Where each deliverable of the radiance map ``output`` goes: beside it, its stem
    plus the deliverable's suffix."""
    stem = os.path.splitext(os.fspath(output))[0]
    return {k: stem + DELIVERABLES[k].suffix for k in options.kinds}


def deliver(output: str, radiance: np.ndarray, options: DeliverOptions, orientation: int = 1,
            device: Optional[str] = None, frames=None) -> List[dict]:
    """Write every deliverable of ``options`` beside ``output`` (each atomically); one
    record per file: ``kind``, ``path``, ``bytes`` and what the writer reports (headroom,
    transfer, light level, gain range)."""
    if not options:
        return []
    from hdrcl.io.hdrdisplay import codecs_available

    why = codecs_available() if any(k not in PLAIN for k in options.kinds) else None
    if why:
        from hdrcl.errors import UsageError

        raise UsageError(f"--deliver: {why}")
    r = Rendering(radiance, options, orientation, device, frames)
    out = []
    for kind, path in paths_for(output, options).items():
        rec = DELIVERABLES[kind].write(path, r)
        out.append({"kind": kind, "path": path, **rec})
    return out


def deliver_beside(output: str, radiance: np.ndarray, options: DeliverOptions, frames=None) -> List[dict]:
    """:func:`deliver` for a radiance map just written at ``output`` (``hdrcl merge``), upright
    as that file's orientation says; ``frames()``: the photographs, for exposure fusion."""
    from hdrcl.io.outmeta import read_orientation

    return deliver(output, radiance, options, read_orientation(output), frames=frames) if options else []
