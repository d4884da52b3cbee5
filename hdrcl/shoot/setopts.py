"""The options ``batch`` shares with ``merge``, applied to one set of a batch:
exposures measured from the pixels through the known curve (on by default: ``auto``),
hand-held frames aligned (and cropped), white balance on a neutral patch.
"""
from __future__ import annotations

import logging
import os
from typing import List, Optional, Tuple

import numpy as np

from hdrcl.shoot.jobs import BatchOptions, SetJob

logger = logging.getLogger(__name__)


def fitted_times(job: SetJob, opened, opts: BatchOptions, grid=None, resp=None) -> Tuple[np.ndarray, List[str]]:
    """The exposures to merge with under ``opts.fit_exposures`` and notes on them.

    The curve is known (the set's pooled or given response ``resp``), so each frame's
    exposure is measured from the set's sampling grid (``grid``, a grid
    :class:`~hdrcl.core.bracket.Bracket` read already from the decode that feeds the
    fusion, else read here): :func:`hdrcl.core.exposure_known.exposures_for_merge`;
    ``auto`` takes the measured value only for frames whose metadata the pixels clearly
    contradict, and says so per frame.
    """
    times = np.asarray(opened.times, np.float64)
    if opts.fit_exposures == "off" or len(job.files) < 2 or resp is None:
        return times, []
    from hdrcl.core.exposure_known import exposures_for_merge
    from hdrcl.shoot.pooling import _calibration_grid

    br = grid if grid is not None else _calibration_grid(job, opened, opts.ignore_color)
    used, notes = exposures_for_merge(br.frames, times, resp, mode=opts.fit_exposures, valid=br.valid,
                                      weight=opts.weight, names=job.files)
    return np.asarray(used, np.float64), notes


def aligned_source(job: SetJob, opened, opts: BatchOptions, times):
    """The set's frames in memory, warped onto the middle exposure (and cropped).

    The motion model is ``opts.align_model`` (``auto`` when the options have none; see
    :mod:`hdrcl.core.handheld`). Returns ``(source, shifts, box, alignment)``: an
    :class:`hdrcl.core.pipeline.ArraySource`, each frame's whole-pixel ``(dy, dx)``, the
    crop box ``(y0, y1, x0, x1)`` or None, and the per-frame alignment records.
    """
    from hdrcl.core.bracket import _with_ignore
    from hdrcl.core.handheld import align_bracket
    from hdrcl.core.pipeline import ArraySource
    from hdrcl.io.reader import BracketReader

    with BracketReader(job.files, opened.infos) as reader:
        frames, valid = reader.read_all()
    valid = _with_ignore(frames, valid, opts.ignore_color)
    model = getattr(opts, "align_model", "auto") or "auto"
    al = align_bracket(frames, valid, times, opts.device, bool(opts.crop), model, list(job.files), inplace=True)
    del frames, valid
    return ArraySource(al.frames, al.valid), al.shifts, al.crop, al.alignment


def aligned_grid(job: SetJob, opened, source):
    """The sampling grid (a grid :class:`~hdrcl.core.bracket.Bracket`) of an aligned
    set's warped frames (``source``, :func:`aligned_source`): what its response solve and
    its exposure measurement read, as ``merge --align`` does, so that both see the frames
    as they are fused."""
    from hdrcl.core.bracket import Bracket
    from hdrcl.core.sampling import grid_stride

    k = grid_stride(source.height, source.width)
    return Bracket(frames=[f[::k, ::k] for f in source.frames], times=np.asarray(opened.times, np.float64),
                   valid=[None if v is None else v[::k, ::k] for v in source.valid], paths=list(job.files),
                   infos=opened.infos, grid=True)


def white_balance(job: SetJob, opened, source, times, resp, opts: BatchOptions, nch: int, h: int,
                  w: int) -> Tuple[Optional[np.ndarray], dict]:
    """Per-channel factors that make ``opts.neutral`` grey, times the absolute scale
    (cd/m^2 from the first frame's f-number and ISO) that a fisheye luminance map
    (``opts.luminance``) implies; None with neither. Also the metadata that records them."""
    absolute = bool(opts.luminance)
    if opts.neutral is None and not absolute:
        return None, {}
    from hdrcl.core.scale import _radiometric_factors

    return _radiometric_factors(list(job.files), opened.infos, source, times, resp, opts.weight, opts.ignore_color,
                                opts.device, nch, opts.neutral, None, absolute, h, w,
                                exposure_reference=job.reference)  # the times are relative to the shoot's
