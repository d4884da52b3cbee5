"""hdrcl's own metadata as file attributes: ``hdrcl:*`` header attributes (EXR) or JSON
in ImageDescription (TIFF), for :mod:`hdrcl.io.writers`."""
from __future__ import annotations

import json
from typing import Mapping, Optional

import numpy as np

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
