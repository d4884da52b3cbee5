"""The fusion and commit stages of a merge (plain functions of the run state,
:class:`hdrcl.core.runstate.RunState`, called by :mod:`hdrcl.core.executor`): fuse into the
file's writer (left open) and the plan's other sinks, or into an array for a merge in
memory; then move the file into place and write the masks. The file's metadata is made
here, once, from the plan and what the stages found (:func:`metadata`).
"""
from __future__ import annotations

import dataclasses
import json
import logging

import numpy as np

from hdrcl.core.pipeline import fusion_processor
from hdrcl.core.plan import MEMORY

logger = logging.getLogger(__name__)

#: The file's attribute (``hdrcl:findings``) that holds the findings known when it was
#: opened, where the plan asks (``record_findings``: a batch set, so a rerun that skips it
#: says them again).
FINDINGS_KEY = "findings"


def _spec(run, **more):
    """The :class:`hdrcl.core.pipeline.FusionSpec` of the run: the options' fields it shares
    taken from the options, the rest from the run."""
    from hdrcl.core.pipeline import FusionSpec

    opts = run.options.asdict()
    shared = {f.name: opts[f.name] for f in dataclasses.fields(FusionSpec) if f.name in opts}
    return FusionSpec(**{**shared, **more})


def _result(run, **more):
    from hdrcl.core.result import MergeResult

    return MergeResult(radiance=None, response=run.response, counts={}, times=run.times, paths=run.inputs.paths,
                       backend="numpy" if run.processor is None else "opencl", shape=(run.h, run.w, run.nch),
                       warnings=list(run.response.warnings) + run.notes, shifts=run.shifts, nominal=run.nominal,
                       crop=run.crop_box, alignment=run.alignment, **more)


def fuse_to_array(run) -> None:
    """A merge in memory: every strip into an array (``run.keep``), no file."""
    from hdrcl.core.pipeline import ArraySink, stream_merge

    run.warm.join()
    run.processor = fusion_processor(run.options.device, run.work)
    run.keep, run.thumb = ArraySink(run.h, run.w, run.nch), None
    sink = run.keep
    if run.factors is not None:
        from hdrcl.core.radiometry import ScaledSink

        sink = ScaledSink(sink, run.factors)
    check = _exposure_check(run)
    spec = _spec(run, ignore_color=None, has_valid=any(v is not None for v in run.source.valid),
                 seconds=run.seconds, work=run.work, processor=run.processor, exposure_check=check)
    run.counts, backend = stream_merge(run.source, run.times, run.response, sink, spec)
    run.result = _result(run)
    run.result.backend = backend
    if check is not None:
        run.check_notes = _report_exposure_check(check, run.result, run.options.exposure_tolerance)


def fuse(run) -> None:
    """Fuse into the file and the plan's other sinks; the writer is left open for
    :func:`commit`."""
    from hdrcl.core.encode import default_reference, fuse_to_file, radiance_opener, reference_for
    from hdrcl.core.pipeline import ArraySink, Thumbnail, stream_merge

    plan = run.plan
    if plan.frames == MEMORY:
        return fuse_to_array(run)
    o, x, h, w, nch = run.options, plan.extras, run.h, run.w, run.nch
    run.warm.join()
    run.processor = fusion_processor(o.device, run.work)
    run.result = _result(run, output=run.output,
                         recorded=[getattr(i, "exposure_time", None) for i in run.inputs.infos])
    run.unit = run.units.get("units", "relative")
    if plan.reference_from_exposures:
        # A batch camera's reference from this set's labels alone: taken from the exposures
        # measured, as `hdrcl merge` does, so one wrong label does not move the map (issue 32).
        given_ref = default_reference(run.times)
    else:
        given_ref = run.inputs.reference_exposure if run.inputs.reference_exposure is not None \
            else o.reference_exposure
    run.t_ref = reference_for(run.output, run.times, given_ref, run.unit)
    run.thumb = Thumbnail(h, w, nch, x.thumbnail) if x.thumbnail else None
    run.keep = ArraySink(h, w, nch) if x.keep_radiance else None
    run.mask = np.zeros((h, w), bool) if x.ghost_mask is not None else None
    run.clips = np.zeros((h, w), np.uint8) if x.clip_mask is not None else None
    run.sinks = {name: make(h, w, nch) for name, make in plan.sinks}
    more = [s for s in [run.keep] + list(x.sinks) + list(run.sinks.values()) if s is not None]
    check = _exposure_check(run)
    spec = _spec(run, ignore_color=run.ignore, has_valid=_has_valid(run), ghost_mask=run.mask,
                 seconds=run.seconds, work=run.work, clip_mask=run.clips, processor=run.processor)
    open_writer = radiance_opener(run.output, w, h, nch, metadata(run), _camera(run), compression=o.compression,
                                  timestamp=run.inputs.timestamp, colorspace=o.colorspace)

    def one_pass(file_sink, first_pass):
        sinks = [file_sink] + (more if first_pass else [])
        sink = sinks[0] if len(sinks) == 1 else Tee(*sinks)
        if run.factors is not None:
            from hdrcl.core.radiometry import ScaledSink

            sink = ScaledSink(sink, run.factors)
        src = run.source
        if first_pass and plan.tap is not None and not hasattr(src, "frames"):
            src = run.tapped = plan.tap(src, h, w, nch)
        if not first_pass and hasattr(src, "rewind"):
            src.rewind()
        run_spec = spec if first_pass else dataclasses.replace(spec)
        run_spec.exposure_check = check if first_pass else None
        run_spec.thumbnail = run.thumb if first_pass else None
        counts, backend = stream_merge(src, run.times, run.response, sink, run_spec)
        run.result.backend = backend
        if check is not None and first_pass:
            run.check_notes = _report_exposure_check(check, run.result, o.exposure_tolerance)
        return counts

    run.writer, run.counts, run.stored = fuse_to_file(open_writer, one_pass, output=run.output, dtype=o.dtype,
                                                      reference=run.t_ref, keep_units=run.unit != "relative",
                                                      chain=run.chain)
    if run.chain is not None:  # --lens-circle against the image's dark border
        from hdrcl.core.luminance.border import lens_circle_finding

        found = lens_circle_finding(run.chain.border, run.chain.lens_circle, run.inputs.paths[0])
        if found is not None:
            run.find(found)


def commit(run) -> None:
    """The radiance file moved into place; masks after. The writer is aborted if it fails."""
    if run.writer is None:
        return
    try:
        with run.timed("write"):
            run.write_warnings = list(run.writer.close())
        run.result.warnings += run.write_warnings
    except BaseException:
        run.writer.abort()
        raise
    res, x = run.result, run.plan.extras
    res.stored = run.stored
    if run.chain is not None:
        res.vertical_illuminance = run.chain.vertical_illuminance
    if run.stored.note:
        res.warnings.append(f"{run.output}: {run.stored.note}")
        res.storage_note = run.stored.note
    if run.mask is not None:
        from hdrcl.io.ldr import write_ldr

        write_ldr(x.ghost_mask, (run.mask.astype(np.uint8) * 255)[..., None])
    if run.clips is not None:
        from hdrcl.io.ldr import write_ldr

        img = np.where(run.clips & 1, 255, np.where(run.clips & 2, 128, 0)).astype(np.uint8)
        write_ldr(x.clip_mask, img[..., None])


def metadata(run) -> dict:
    """The file's hdrcl metadata: provenance, units, reference exposure, colour space,
    alignment, the plan's own (a batch's digest...) and, where the plan asks, the
    findings known when the file is opened."""
    from hdrcl.core.result import provenance

    meta = provenance(run.result, run.source_name)
    meta.update(run.units)
    if run.unit == "relative":
        meta["referenceExposure"] = run.t_ref
    meta["colorspace"] = run.options.colorspace
    if run.shifts is not None:
        from hdrcl.core.align.handheld import alignment_meta

        meta.update(alignment_meta(run.shifts, run.alignment))
    meta.update(dict(run.plan.metadata))
    if run.plan.record_findings and run.findings:  # a rerun that skips the set says them again
        meta[FINDINGS_KEY] = json.dumps([f.to_dict() for f in run.findings], sort_keys=True)
    return meta


def _camera(run) -> dict:
    from hdrcl.io.outmeta import camera_from_infos

    return camera_from_infos(run.inputs.infos, owner=run.plan.extras.owner, reference=run.inputs.reference,
                             units=run.unit, exposure_time=run.t_ref)


def _exposure_check(run):
    """A given response with ``fit_exposures=off``: the exposures are checked only."""
    if run.own or run.options.fit_exposures != "off":
        return None
    from hdrcl.core.exposure.fit import ExposureCheck
    from hdrcl.core.pipeline import fusion_tables

    order = np.argsort(run.times, kind="stable")
    tables = fusion_tables(run.response, run.source.dtype, run.nch, run.options.weight)[0]
    return ExposureCheck(np.log(run.times[order]), tables, [run.inputs.paths[i] for i in order])


def _has_valid(run) -> bool:
    return (run.options.ignore_color is not None or any(i.nchannels in (2, 4) for i in run.inputs.infos)
            or any(v is not None for v in getattr(run.source, "valid", [])))


class Tee:
    """Hands every strip to several sinks (the file writer, a kept map, a preview)."""

    def __init__(self, *sinks):
        self.sinks = [s for s in sinks if s is not None]

    def write_rows(self, y0, y1, data):
        for s in self.sinks:
            s.write_rows(y0, y1, data)


def kept_frames(source, grid):
    """``(frames, valid, is_grid)`` the merge holds already: an aligned set's frames, the
    decoded-frame cache when it is in memory, else the sampling grid; None otherwise."""
    if hasattr(source, "kept"):  # aligned through the fusion: the frames as merged, warped whole now
        return source.kept()
    if hasattr(source, "frames"):  # aligned (and cropped): what was merged
        return list(source.frames), list(source.valid), False
    cache = getattr(source, "cache", None)
    if cache is not None and cache.complete and cache.in_memory:
        frames, valid = cache.rows(0, cache.height)
        return frames, valid, False
    if grid is not None:
        return list(grid.frames), list(grid.valid), True
    return None


def _report_exposure_check(check, result, tolerance):
    """Warn about exposures the pixels contradict; refuse a set whose exposures run in
    reverse order of its brightness (raised inside the writer: no output is left)."""
    from hdrcl.core.exposure.fit import EXPOSURE_TOLERANCE_STOPS
    from hdrcl.errors import InputError

    msgs, backwards = check.problems(EXPOSURE_TOLERANCE_STOPS if tolerance is None else float(tolerance))
    if backwards:
        raise InputError(f"{check.names[-1]}: the exposure times run in reverse order of the frames' "
                         "brightness with this response; check the times")
    for m in msgs:
        logger.warning("%s", m)
        result.warnings.append(m)
    return list(msgs)
