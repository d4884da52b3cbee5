"""The stages of a merge before the fusion, as plain functions of the run state
(:class:`hdrcl.core.runstate.RunState`); the executor (:mod:`hdrcl.core.executor`) alone
calls them, in its order:

    open -> load (align) -> sample -> respond -> measure -> agreement -> scale

The fusion and the commit are in :mod:`hdrcl.core.fusestage`. Each stage reads the plan
(``run.plan``) and writes what it found on ``run``.
"""
from __future__ import annotations

import logging
import os

import numpy as np

from hdrcl.core.pipeline import fusion_processor
from hdrcl.core.plan import HELD, MEMORY
from hdrcl.core.sources import check_brightness_order

logger = logging.getLogger(__name__)


def open_frames(run) -> None:
    """Sizes and checks from the headers (or the arrays), the backend, the OpenCL warm-up."""
    plan, o = run.plan, run.options
    if plan.frames == MEMORY:
        frames = plan.bracket.frames
        run.h, run.w = frames[0].shape[:2]
        run.nch = frames[0].shape[2] if frames[0].ndim == 3 else 1
        run.work = run.h * run.w * len(frames)
        run.warm = warm_up(o.device, run.work)
        return
    from hdrcl.core.orientation import orientation_findings
    from hdrcl.core.params import check_image_size, check_response_fits

    first = run.inputs.infos[0]
    run.nch = 3 if first.nchannels >= 3 else 1
    run.h, run.w = first.height, first.width
    run.work = first.width * first.height * len(run.inputs.paths)
    run.warm = warm_up(o.device, run.work)
    check_image_size(run.w, run.h, neutral=o.neutral, reference_patch=o.reference_patch)
    for finding in orientation_findings(run.inputs.infos, run.output):  # hdrcl.core.orientation
        run.find(finding)
    for finding in plan.findings:  # known before the merge (a batch's scan: hdrcl.shoot.grouping.strays)
        run.find(finding)
    if run.chain is not None:
        run.chain.bind(run.h, run.w, run.nch)  # --lens-circle against the image, before any decoding
        if o.reference_patch is None and not (first.fnumber and first.iso) and run.inputs.reference is None:
            from hdrcl.errors import UsageError

            raise UsageError(f"{run.inputs.paths[0]}: a luminance map (--lens-circle) is in cd/m^2 from the first "
                             "frame's f-number and ISO, which its EXIF does not give; use --reference-patch")
    if run.response is not None:
        check_response_fits(run.response, run.source_name, run.inputs.paths[0], first.bits, run.nch)
    elif run.responses.solves and run.responses.raw_linear and _all_raw(run.inputs.paths):
        from hdrcl.core.response import linear_response

        run.response, run.source_name = linear_response(run.nch), "linear (RAW input)"
        run.response.exposures = [{"file": os.path.basename(p), "nominal": float(t), "fitted": None,
                                   "used": float(t)} for p, t in zip(run.inputs.paths, run.times)]


def load(run) -> None:
    """The frames as a strip source: streamed by a reader, held (and aligned: one call
    into :mod:`hdrcl.core.align`), or the arrays in memory."""
    from hdrcl.core.pipeline import ArraySource

    plan, o = run.plan, run.options
    if plan.frames == MEMORY:
        br = plan.bracket
        frames, valid = list(br.frames), list(br.valid)
        if o.align:
            from hdrcl.core.align.handheld import align_bracket

            with run.timed("align"):
                al = align_bracket(frames, valid, run.times, o.device, o.crop, o.align_model, br.paths or None,
                                   find=run.find)
            frames, valid = al.frames, al.valid
            _aligned(run, al)
        run.source = ArraySource(frames, valid)
        run.ignore = None  # the bracket's masks hold the ignore colour already
        return
    from hdrcl.io.reader import BracketReader

    if plan.frames != HELD:
        run.source = BracketReader(run.inputs.paths, run.inputs.infos)
        return
    from hdrcl.core.align.stream import aligned_source

    # The frames decoded once and kept, sampled through their transforms strip by strip
    # (no warped copies held: hdrcl.core.align.stream).
    run.source, al = aligned_source(run.inputs, o, find=run.find)
    run.add_time("decode", al.decode_seconds)
    run.add_time("align", al.align_seconds)
    _aligned(run, al, (run.source.height, run.source.width))
    run.ignore = None


def _aligned(run, al, size=None) -> None:
    """What an alignment leaves: frames it could not align left out (a finding names each),
    the shifts, the crop box and the image's size after it."""
    if al.left_out:
        from dataclasses import replace

        from hdrcl.core.align.unaligned import without

        n = len(run.times)
        keep = [i for i in range(n) if i not in set(al.left_out)]
        if len(run.inputs.paths) == n and len(run.inputs.infos) == n:
            run.inputs = without(run.inputs, al.left_out)
        else:  # arrays without headers
            run.inputs = replace(run.inputs, times=np.asarray(run.times, np.float64)[keep])
        run.times = run.nominal = np.asarray(run.inputs.times, np.float64)
    run.shifts, run.crop_box, run.alignment = al.shifts, al.crop, al.alignment
    run.h, run.w = size if size is not None else al.frames[0].shape[:2]


def sample(run) -> None:
    """The sampling grid, when the solve or the exposure measurement needs it: from the
    held frames, or from one streaming pass that also keeps the decoded codes for the
    fusion (each frame decoded once). In memory: the whole frames."""
    from hdrcl.core.bracket import Bracket

    plan, o, src = run.plan, run.options, run.source
    if plan.frames == MEMORY:
        run.grid = Bracket(frames=list(src.frames), times=run.times, valid=list(src.valid),
                           paths=run.inputs.paths, infos=run.inputs.infos)
        return
    measure = not run.own and o.fit_exposures != "off"
    if not (measure or (run.response is None and run.responses.solves)):
        return
    from hdrcl.core.bracket import _grid_bracket
    from hdrcl.core.sampling import grid_stride

    if plan.frames == HELD:
        k = grid_stride(run.h, run.w)
        run.grid = Bracket(frames=[f[::k, ::k] for f in src.frames], times=run.times,
                           valid=[None if v is None else v[::k, ::k] for v in src.valid],
                           paths=run.inputs.paths, infos=run.inputs.infos, grid=True)
    else:
        run.grid = _grid_bracket(run.inputs.paths, run.inputs.infos, run.times, o.ignore_color,
                                 reader=src, keep=True)
        run.add_time("decode", src.decode_seconds)


def respond(run) -> None:
    """Solve the response from the grid, or take the one given (after the exposures'
    order is checked against the frames' brightness); then what the response's pool says
    of the set's exposures (a batch's trust findings)."""
    if run.grid is not None and run.plan.checks:
        check_brightness_order(run.grid, run.times, run.inputs)
    if run.response is None:
        with run.timed("solve"):
            run.response = run.responses.solve(run, run.grid)
    trust = run.plan.response.trust
    if trust is not None:
        for finding in trust(run.grid):
            run.find(finding)


def measure(run) -> None:
    """Each frame's exposure measured through a known curve (``fit_exposures``), or the
    exposures the set's own calibration refined."""
    from hdrcl.core.calibrate import exposures_used

    o = run.options
    if not run.own and o.fit_exposures != "off" and len(run.inputs.paths) > 1:
        from hdrcl.core.exposure.known import exposures_for_merge

        used, notes = exposures_for_merge(run.grid.frames, run.times, run.response, mode=o.fit_exposures,
                                          valid=run.grid.valid, weight=o.weight,
                                          tolerance_stops=o.exposure_tolerance, names=run.inputs.paths,
                                          labels=run.inputs.labels())
        for note in notes:
            logger.warning("%s", note)
        run.times = np.asarray(used, np.float64)
        run.notes += notes
    run.times = exposures_used(run.response, run.times)


def agreement(run) -> None:
    """Do the frames agree? Findings on the run (:func:`hdrcl.core.agreement.check_job`)."""
    from hdrcl.core.agreement import check_job

    check_job(run)


def scale(run) -> None:
    """White balance and absolute scale: per-channel factors and the units."""
    from hdrcl.core.scale import radiometric_factors

    o = run.options
    absolute = o.absolute or (run.chain is not None and o.reference_patch is None)
    if run.chain is not None:
        run.chain.bind(run.h, run.w, run.nch)  # again: --crop may have made the image smaller
    run.factors, run.units = radiometric_factors(
        run.inputs.paths, run.inputs.infos, run.source, run.times, run.response,
        o.replace(absolute=absolute) if absolute != o.absolute else o, run.nch, run.h, run.w,
        exposure_reference=run.inputs.reference)


def _all_raw(paths) -> bool:
    from hdrcl.core.bracket import _all_raw as all_raw

    return all_raw(paths)


def warm_up(device, work=None):
    """Open the OpenCL device on a helper thread while the frames decode (a few tenths of
    a second that need not add up); the job's own size decides whether it needs one."""
    import threading

    def warm():
        try:
            fusion_processor(device, work)
        except Exception:  # the main thread meets the same error and reports it
            pass

    t = threading.Thread(target=warm, name="hdrcl-warm-up", daemon=False)  # exit waits: a build cut crashes
    t.start()
    return t
