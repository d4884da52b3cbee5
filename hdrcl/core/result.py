"""What a merge made: :class:`MergeResult`, and the provenance metadata its file records."""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from hdrcl.core.response import Response


@dataclass
class MergeResult:
    """A merged radiance map with what went into it."""

    radiance: Optional[np.ndarray]
    response: Response
    counts: dict
    times: np.ndarray
    paths: List[str]
    backend: str
    seconds: dict = field(default_factory=dict)
    warnings: List[str] = field(default_factory=list)
    output: Optional[str] = None
    shape: tuple = ()
    thumbnail: Optional[np.ndarray] = None
    shifts: Optional[list] = None  # (dy, dx) per frame when aligned: whole-pixel motion of its centre
    alignment: Optional[list] = None  # per frame when aligned: hdrcl.core.align.handheld.describe dicts
    nominal: Optional[np.ndarray] = None  # the set's own exposures before any refinement
    crop: Optional[tuple] = None  # (y0, y1, x0, x1) of the input kept, with align + crop
    storage_note: Optional[str] = None  # how an EXR was stored when half could not hold it
    stored: Optional[object] = None  # hdrcl.core.encode.Stored: type, reference exposure, measured range
    kept: Optional[tuple] = None  # (frames, valid, is_grid) with keep_frames: for the quality report
    stages: dict = field(default_factory=dict)  # seconds per stage (decode, solve, fuse, encode, write); overlapping
    vertical_illuminance: Optional[float] = None  # lux at the lens, with a fisheye luminance chain (-vta view)
    recorded: Optional[list] = None  # per frame, the shutter time its header records (None where it has none)
    findings: list = field(default_factory=list)  # hdrcl.core.findings.Finding: what the checks found

    def __post_init__(self):
        if not self.shape and self.radiance is not None:
            self.shape = tuple(self.radiance.shape)


def provenance(result: MergeResult, response_source: str) -> dict:
    """The hdrcl metadata of a merged file: sources, exposures, response, backend, counts."""
    from hdrcl.io.metadata import format_time

    r = result.response
    meta = {
        "sources": [os.path.basename(p) for p in result.paths],
        "exposures": [float(t) for t in result.times],
        "exposuresNominal": [float(t) for t in (result.nominal if result.nominal is not None else result.times)],
        # the shutter times as the frames record them; "exposures" are the merge's own (relative
        # to the reference f-number and ISO, refined where the pixels said so)
        "exposureText": ", ".join(format_time(t) for t in (
            result.recorded if result.recorded and all(result.recorded) else result.times)),
        "response": response_source,
        "responseSmoothness": float(r.smoothness),
        "responseSamples": int(r.samples),
        "weight": r.weight,
        "backend": result.backend,
    }
    if result.counts:  # a streamed file's header is written before the counts are known
        meta.update({"clippedHigh": int(result.counts.get("clipped_high", 0)),
                     "clippedLow": int(result.counts.get("clipped_low", 0)),
                     "noData": int(result.counts.get("no_data", 0))})
    if r.camera:
        meta["camera"] = " ".join(str(r.camera[k]) for k in ("make", "model") if k in r.camera)
    return meta


