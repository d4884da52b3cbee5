"""When a cached response may stand for calibrating: one rule for ``hdrcl merge
--response-cache FILE`` and ``hdrcl batch --response-cache FOLDER``.

A curve from the cache is used as it is only when it fits the frames it would merge: the
same bit depth and channel count (:func:`hdrcl.core.params.check_response_fits`) and the
same camera model (names compared with their spacing normalised; a curve that names no
camera fits only frames that name none). Otherwise the caller warns with the reason and
calibrates from the frames, replacing the cached file.
"""
from __future__ import annotations

from typing import Optional

from hdrcl.errors import HdrclError


def _model(name) -> str:
    return " ".join(str(name or "").split())


def misfit(resp, source: str, image: str, info) -> Optional[str]:
    """Why ``resp`` (read from ``source``) cannot stand for the frames whose first is
    ``image`` with header ``info``, in one line; None when it fits."""
    from hdrcl.core.params import check_response_fits

    try:
        check_response_fits(resp, source, image, info.bits, 3 if info.nchannels >= 3 else 1)
    except HdrclError as exc:
        return str(exc).splitlines()[0]
    cached, taken = _model((resp.camera or {}).get("model")), _model(getattr(info, "model", None))
    if cached != taken:
        return (f"{source}: a response of {cached or 'an unnamed camera'}, but {image} is from "
                f"{taken or 'an unnamed camera'}")
    return None
