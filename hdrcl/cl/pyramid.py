"""Grey pyramids shared by the alignment kernels and their NumPy twin.

Plain data, no OpenCL: :class:`hdrcl.cl.align.AlignProcessor` fills ``dev`` and
:class:`hdrcl.core.align.mtb.NumpyAligner` only ``host``; both size levels with
:func:`level_shapes`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, List, Optional, Tuple

import numpy as np


def level_shapes(h: int, w: int, levels: int) -> List[Tuple[int, int]]:
    """``(h, w)`` of each pyramid level, finest first."""
    if levels < 1:
        raise ValueError(f"levels must be at least 1, not {levels}")
    shapes = [(h, w)]
    for _ in range(levels - 1):
        h, w = h // 2, w // 2
        shapes.append((h, w))
    if min(shapes[-1]) < 2:
        raise ValueError(
            f"{levels} pyramid levels are too many for a {shapes[0][0]}x{shapes[0][1]} frame "
            f"(the coarsest would be {h}x{w}); use fewer levels"
        )
    return shapes


@dataclass
class GreyPyramid:
    """Grey levels of one frame, finest first: on the host (``host``, uint16) and, for
    the OpenCL path, on the device (``dev``, buffers of ``slot``)."""

    slot: str
    shapes: List[Tuple[int, int]]
    host: List[np.ndarray]
    dev: Optional[List[Any]] = None

    @property
    def levels(self) -> int:
        return len(self.shapes)
