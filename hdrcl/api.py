"""The operations of hdrcl for scripts and pipelines, on arrays and on files.

This is the public facade: it re-exports the library's entry points from the layers
below (:mod:`hdrcl.core`, :mod:`hdrcl.report`) and holds no engine of its own. The
command line is a thin layer over these functions::

    import hdrcl
    resp = hdrcl.calibrate(["a.jpg", "b.jpg", "c.jpg"], times=[1/250, 1/60, 1/15])
    radiance = hdrcl.merge(["a.jpg", "b.jpg", "c.jpg"], times=[1/250, 1/60, 1/15], response=resp)
    photo = hdrcl.expose(radiance, resp, time=1/30)          # uint8 (H, W, 3)
    picture = hdrcl.tonemap(radiance, "reinhard-local")      # sRGB uint8 (H, W, 3)
"""
from __future__ import annotations

import os
from typing import Optional, Sequence, Union

import numpy as np

from hdrcl.core.bracket import (
    Bracket,
    PathOrArray,
    load_bracket,
    memory_budget,
    read_infos,
)
from hdrcl.core.calibrate import calibrate, exposures_used
from hdrcl.core.exposure import expose, expose_file
from hdrcl.core.merge import MergeResult, merge_bracket, merge_files
from hdrcl.core.response import Response, _as_response
from hdrcl.report.merge_report import write_quality_report
from hdrcl.report.tonemap import tonemap, tonemap_file

__all__ = [
    "Bracket", "MergeResult", "Response", "calibrate", "expose", "expose_file", "exposures_used",
    "load_bracket", "memory_budget", "merge", "merge_bracket", "merge_files", "read_infos",
    "tonemap", "tonemap_file", "write_quality_report",
]


def merge(
    images: Sequence[PathOrArray],
    times: Optional[Sequence[float]] = None,
    response: Union[Response, str, os.PathLike, None] = None,
    *,
    times_file=None,
    weight: str = "hat",
    ignore_color=None,
    samples: Optional[int] = None,
    smoothness: Optional[float] = None,
    device: Optional[str] = None,
    fit_exposures: str = "auto",
) -> np.ndarray:
    """Merge a bracket into a float32 radiance map ``(H, W, C)``.

    ``response`` may be a :class:`Response`, a path to a response JSON file, or None to
    calibrate from the set itself. Radiance is relative: a pixel that reads ``Zmid``
    in a 1 s exposure (at the first frame's aperture and ISO) has radiance about 1.
    """
    br = load_bracket(images, times, times_file=times_file, ignore_color=ignore_color)
    return merge_bracket(br, _as_response(response), weight=weight, samples=samples, smoothness=smoothness,
                         device=device, fit_exposures=fit_exposures).radiance
