"""Output colour spaces of radiance maps, through OpenImageIO's colour management.

hdrcl merges in the camera's RGB, taken as linear Rec.709 / sRGB primaries (D65). A
radiance file can instead be written in ACEScg (ACES AP1 primaries, D60 white, linear),
the working space of most VFX pipelines. The conversion is a 3x3 matrix, and that matrix
is what OpenImageIO's built-in OCIO configuration computes (Rec.709 to ACEScg with its
chromatic adaptation): :func:`matrix` converts the three unit primaries with
``ImageBufAlgo.colorconvert`` once and applies the result to every strip, so a streamed
merge costs one small matrix product per strip. The primaries written into the file
(EXR ``chromaticities``, Radiance ``PRIMARIES``) and the colour-interop ID
(``oiio:ColorSpace``) come from the same configuration.
"""
from __future__ import annotations

import functools
from typing import Tuple

import numpy as np

from hdrcl.errors import ProcessingError, UsageError

__all__ = ["COLORSPACES", "check", "interop_id", "chromaticities", "matrix", "convert", "from_file_tag"]

#: ``--colorspace`` values and the OIIO/OCIO colour-space name of each.
COLORSPACES = {"rec709": "lin_rec709_scene", "acescg": "ACEScg"}
#: Space the merge computes in.
WORKING = "rec709"


def check(name: str) -> str:
    """The normalised ``--colorspace`` name; UsageError for an unknown one."""
    key = str(name).strip().lower()
    if key not in COLORSPACES:
        raise UsageError(f"--colorspace: '{name}' is not one of {', '.join(COLORSPACES)}")
    return key


def _config():
    import OpenImageIO as oiio  # lazy: keeps ``import hdrcl`` free of the OIIO load

    return oiio, oiio.ColorConfig()


@functools.lru_cache(maxsize=None)
def interop_id(name: str) -> str:
    """The colour-interop ID OIIO writes for ``name`` (``lin_rec709_scene``, ``lin_ap1_scene``)."""
    _oiio, cfg = _config()
    return cfg.get_color_interop_id(COLORSPACES[check(name)]) or COLORSPACES[check(name)]


@functools.lru_cache(maxsize=None)
def chromaticities(name: str) -> Tuple[float, ...]:
    """CIE xy of red, green, blue and white (8 floats) of ``name``, from OIIO's config."""
    _oiio, cfg = _config()
    return tuple(float(v) for v in cfg.get_chromaticities(COLORSPACES[check(name)]))


@functools.lru_cache(maxsize=None)
def matrix(src: str, dst: str) -> np.ndarray:
    """3x3 float64 ``M`` with ``dst_rgb = M @ src_rgb``, from OIIO's colour management."""
    src, dst = check(src), check(dst)
    if src == dst:
        return np.eye(3)
    oiio, _cfg = _config()
    buf = oiio.ImageBuf(oiio.ImageSpec(3, 1, 3, "float"))
    buf.set_pixels(oiio.ROI(), np.eye(3, dtype=np.float32).reshape(1, 3, 3))
    out = oiio.ImageBufAlgo.colorconvert(buf, COLORSPACES[src], COLORSPACES[dst])
    if out.has_error:
        raise ProcessingError(f"colour conversion {src} -> {dst}: {out.geterror()}")
    m = np.asarray(out.get_pixels(oiio.FLOAT), np.float64).reshape(3, 3).T
    if not np.all(np.isfinite(m)):
        raise ProcessingError(f"colour conversion {src} -> {dst} gave a non-finite matrix")
    return m


def convert(rgb: np.ndarray, src: str, dst: str) -> np.ndarray:
    """``(..., 3)`` linear RGB from ``src`` to ``dst`` (float32 out);
    grey ``(..., 1)`` data is returned as is (both spaces share the neutral axis)."""
    data = np.asarray(rgb, np.float32)
    if check(src) == check(dst) or data.shape[-1] != 3:
        return data
    # float64 arithmetic, float32 result: one rounding per value.
    return np.ascontiguousarray((data.astype(np.float64) @ matrix(src, dst).T).astype(np.float32))


def from_file_tag(tag) -> str:
    """``rec709`` or ``acescg`` for a file's ``oiio:ColorSpace`` (default rec709)."""
    if not tag:
        return WORKING
    _oiio, cfg = _config()
    for key, name in COLORSPACES.items():
        try:
            if str(tag) == name or cfg.equivalent(str(tag), name):
                return key
        except Exception:  # an unknown name in an odd file: not ours
            continue
    return WORKING
