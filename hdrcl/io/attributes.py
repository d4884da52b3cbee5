"""Image files as OpenImageIO writes them, for the radiance writers (:mod:`hdrcl.io.writers`)
and the LDR ones (:mod:`hdrcl.io.ldr`): hdrcl's own metadata as file attributes
(``hdrcl:*`` header attributes, or JSON in ImageDescription for formats without custom
attributes), and one atomic whole-image write (:func:`write_image`)."""
from __future__ import annotations

import json
from typing import Mapping, Optional

import numpy as np

from hdrcl.errors import ProcessingError, UsageError
from hdrcl.io.atomic import atomic_output
from hdrcl.io.frames import _clean_error

METADATA_PREFIX = "hdrcl:"


# OpenEXR before 2.0 (and some tools still) limit attribute names to 31 characters.
MAX_ATTRIBUTE_NAME = 31


def metadata_attributes(metadata: Optional[Mapping]) -> list:
    """``(name, value)`` pairs with the ``hdrcl:`` prefix and OIIO-friendly types."""
    out = []
    for key, value in (metadata or {}).items():
        name = METADATA_PREFIX + str(key)
        if len(name) > MAX_ATTRIBUTE_NAME:
            raise ValueError(
                f"metadata key '{key}' is too long: '{name}' has {len(name)} characters, "
                f"at most {MAX_ATTRIBUTE_NAME}"
            )
        if isinstance(value, np.generic):
            value = value.item()
        if isinstance(value, bool):
            value = int(value)
        if isinstance(value, int) and not -(2**31) <= value < 2**31:
            value = str(value)  # OIIO ints are 32-bit
        elif isinstance(value, (int, float, str)):
            pass
        else:
            value = json.dumps(value, default=str)
        out.append((name, value))
    return out


def description(metadata: Optional[Mapping]) -> Optional[str]:
    """Metadata as JSON for formats that keep ImageDescription but not custom attributes."""
    if not metadata:
        return None
    plain = {str(k): (v.item() if isinstance(v, np.generic) else v) for k, v in metadata.items()}
    return json.dumps({"hdrcl": plain}, default=str, sort_keys=True)


def _oiio():
    import OpenImageIO as oiio  # lazy: keeps ``import hdrcl`` free of the OIIO load

    return oiio


def write_image(path: str, pixels: np.ndarray, fmt: str, attributes: list, channelnames=None):
    """Write ``pixels`` (H, W, C) to ``path`` atomically with OIIO in the given format."""
    oiio = _oiio()
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, fmt)
    if channelnames is not None:
        spec.channelnames = tuple(channelnames)
    if c in (2, 4):
        spec.alpha_channel = c - 1
    for attr in attributes:
        spec.attribute(*attr)
    with atomic_output(path) as tmp:
        out = oiio.ImageOutput.create(tmp)
        if out is None:
            raise UsageError(f"{path}: no writer for this format ({oiio.geterror()})")
        try:
            ok = out.open(tmp, spec) and out.write_image(pixels)
        finally:
            closed = out.close()
        if not (ok and closed) or out.has_error:
            detail = _clean_error(out.geterror() or oiio.geterror(), tmp)
            raise ProcessingError(f"{path}: cannot write ({detail or 'unknown error'})")
