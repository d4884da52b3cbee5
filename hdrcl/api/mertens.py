"""Exposure fusion for scripts and ``hdrcl fuse``: frames in, one display image out, with
no radiance step (Mertens, Kautz & Van Reeth 2007; OpenCV's ``MergeMertens``, ``enfuse``).

- :func:`exposure_fusion` -- arrays in, a float32 image about [0, 1] out
  (:func:`hdrcl.core.mertens.exposure_fusion`);
- :func:`fuse_files` -- image files in, an 8- or 16-bit JPEG, PNG or TIFF out.
"""
from __future__ import annotations

import logging
import os
import time
from typing import Optional, Sequence

import numpy as np

from hdrcl.core.mertens import FusionWeights, exposure_fusion, read_frames, to_codes
from hdrcl.errors import UsageError

__all__ = ["exposure_fusion", "fuse_files", "read_frames", "FusionWeights"]

logger = logging.getLogger(__name__)


def fuse_files(paths: Sequence, output, *, contrast: float = 1.0, saturation: float = 1.0,
               exposedness: float = 1.0, sigma: float = 0.2, align: bool = False, align_model: str = "auto",
               ignore_color=None, device: Optional[str] = None) -> dict:
    """Fuse the photographs ``paths`` into ``output`` (``.jpg``, ``.png`` or ``.tif``).

    Frames are RGB (or grey) 8- or 16-bit files of one size, in any order; alpha and
    ``ignore_color`` (R, G, B in 8-bit units) mark pixels that weigh nothing. With
    ``align`` the frames are first registered to the middle exposure (frames ordered by
    brightness) as ``hdrcl merge --align`` does. The output has 8 bits for JPEG, else the
    frames' depth: ``clip(round(fused * (2^bits - 1)))``, written atomically.

    Returns a summary: ``{"output", "frames", "width", "height", "bits", "seconds"}``.

    Raises
    ------
    UsageError
        Fewer than 2 frames, a bad exponent or output path.
    InputError
        A frame cannot be read, or the frames differ in size, channels or depth.
    """
    from hdrcl.core.bracket import parse_ignore_color
    from hdrcl.io.atomic import check_output
    from hdrcl.io.ldr import LDR_EXTENSIONS, write_ldr

    paths = [os.fspath(p) for p in paths]
    output = check_output(output, paths, what="fused image")
    ext = os.path.splitext(output)[1].lower()
    if ext not in LDR_EXTENSIONS:
        raise UsageError(f"{output}: unsupported output type '{ext or '(none)'}'; use one of "
                         f"{', '.join(LDR_EXTENSIONS)}")
    if len(paths) < 2:
        raise UsageError(f"exposure fusion needs at least 2 frames, not {len(paths)}")
    FusionWeights(contrast, saturation, exposedness, sigma)  # checked before any decoding
    rgb = parse_ignore_color(ignore_color)
    t0 = time.perf_counter()
    frames, valid = read_frames(paths, rgb)
    if align:
        frames, valid = _aligned(frames, valid or [None] * len(frames), paths, align_model, device)
        if all(v is None for v in valid):
            valid = None
    fused = exposure_fusion(frames, valid, contrast=contrast, saturation=saturation, exposedness=exposedness,
                            device=device, sigma=sigma)
    bits = 8 if ext in (".jpg", ".jpeg") or frames[0].dtype == np.uint8 else 16
    h, w = fused.shape[:2]
    n = len(frames)
    del frames, valid
    codes = to_codes(fused, bits)
    del fused
    write_ldr(output, codes, metadata={"fusion": "Mertens 2007", "sources": [os.path.basename(p) for p in paths]})
    secs = time.perf_counter() - t0
    logger.info("fused %d frames of %dx%d into %s in %.2f s", n, w, h, output, secs)
    return {"output": output, "frames": n, "width": w, "height": h, "bits": bits, "seconds": secs}


def _aligned(frames, valid, paths, model: str, device):
    """Frames and masks registered to the middle exposure (ordered by mean code: fusion
    has no exposure times); a frame that cannot be aligned is refused."""
    from hdrcl.core.align.handheld import align_bracket

    shape = frames[0].shape[:2]
    valid = [np.ones(shape, bool) if v is None else v for v in valid]
    brightness = [float(np.mean(f[::8, ::8])) for f in frames]
    al = align_bracket(frames, valid, brightness, device=device, crop=True, model=model, names=paths)
    return list(al.frames), list(al.valid)
