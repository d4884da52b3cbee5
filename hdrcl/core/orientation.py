"""EXIF Orientation of a set: what the merge does with it, as findings.

hdrcl merges the frames' pixels as stored and gives the output the set's orientation
(:func:`hdrcl.io.exif.common_orientation`: the tag most frames carry), written where the
format can say it (:func:`hdrcl.io.outmeta.orientation_carrier`); ``hdrcl batch`` also
turns its previews upright. Two findings (check ``orientation``):

``note``
    Every frame carries the same orientation other than 1: what the output says.
``check``
    The frames' tags differ (some rotated by a tool, some only tagged): which frames,
    and what the output says. Their pixels are merged as stored, which is right only
    where they line up as stored.
"""
from __future__ import annotations

import os
from typing import List, Sequence

from hdrcl.core.findings import CHECK, NOTE, Finding

__all__ = ["orientation_findings"]


def _names(paths: Sequence[str], limit: int = 3) -> str:
    names = [os.path.basename(os.fspath(p)) for p in paths]
    return ", ".join(names[:limit]) + (f" and {len(names) - limit} more" if len(names) > limit else "")


def orientation_findings(infos: Sequence, output: str) -> List[Finding]:
    """What a merge of the frames ``infos`` (:class:`hdrcl.io.metadata.FrameInfo`) into
    ``output`` does with their EXIF Orientation: no finding where every frame is upright
    (1, or no tag), a note where all share another one, a check where they differ."""
    from hdrcl.io.exif import ORIENTATIONS, common_orientation, orientation_value
    from hdrcl.io.outmeta import orientation_carrier

    if not infos:
        return []
    tags = [orientation_value(getattr(i, "orientation", 1)) for i in infos]
    o = common_orientation(tags)
    carrier = orientation_carrier(output, o)
    odd = [i.path for i, t in zip(infos, tags) if t != o]
    if odd:
        k = tags.index(next(t for t in tags if t != o))
        return [Finding(
            "orientation",
            f"{_names(odd)}: EXIF Orientation {tags[k]} ({ORIENTATIONS[tags[k]]}), but {len(tags) - len(odd)} of "
            f"the {len(tags)} frames have {o}; merged as stored, {carrier}: check that the frames line up, "
            f"and give the odd ones the set's orientation (rotate their pixels or rewrite the tag)",
            CHECK, file=os.path.basename(odd[0]), figure=float(len(odd)))]
    if o == 1:
        return []
    return [Finding(
        "orientation",
        f"{os.path.basename(infos[0].path)}: EXIF Orientation {o} ({ORIENTATIONS[o]}) on all {len(tags)} "
        f"frames; merged as stored, {carrier}",
        NOTE, file=os.path.basename(infos[0].path), figure=float(o))]
