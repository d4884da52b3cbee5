"""Merging one set of a batch: reading its headers and digest (read stage), then fusing
and writing it (merge stage); :func:`process_set` runs both.
"""
from __future__ import annotations

import contextlib
import json
import logging
import os
import time as _time
from dataclasses import dataclass, field
from typing import Dict, Iterator, List, Optional

import numpy as np

from hdrcl.core.findings import Finding
from hdrcl.core.fusestage import FINDINGS_KEY
from hdrcl.core.sources import Inputs, ResponseSource
from hdrcl.errors import HdrclError, InputError
from hdrcl.shoot.batch.jobs import (
    _FUSE_LOCK,
    STATUS_CHECK,
    STATUS_DONE,
    STATUS_FAILED,
    STATUS_SKIPPED,
    BatchOptions,
    SetJob,
    SetResult,
    _Context,
    _reference_text,
)
from hdrcl.shoot.batch.pooling import EntryResponse, _open_set, _Opened
from hdrcl.shoot.batch.setquality import (
    REPORT_IMAGE_SIZE,
    _current_quality,
    _KeptFrames,
    _quality_for,
    _quality_stride,
)
from hdrcl.shoot.batch.state import (
    DIGEST_KEY,
    _counts_of,
    _preview_metadata,
    _up_to_date,
    set_digest,
    verify_exr,
)

logger = logging.getLogger(__name__)




# ------------------------------------------------------------------------ stages
@dataclass
class _Opening:
    """A set that needs merging: its digest and headers, read ahead of the merge."""

    job: SetJob
    digest: str
    opened: _Opened
    seconds: Dict[str, float]
    notes: List[str] = field(default_factory=list)


def _failed(job: SetJob, exc: BaseException, seconds=None, digest=None) -> SetResult:
    if isinstance(exc, HdrclError):
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    else:
        first = str(exc).splitlines()[0] if str(exc) else ""
        msg = f"internal error: {type(exc).__name__}: {first}"
        logger.debug("set %d failed", job.index, exc_info=exc)
    return SetResult(index=job.index, files=list(job.files), status=STATUS_FAILED, output=job.output,
                     preview=job.preview, error=msg, seconds=dict(seconds or {}), digest=digest,
                     response=job.group, findings=[dict(f) for f in job.findings])


def _rebuild_preview(job: SetJob, digest: str, options: BatchOptions) -> None:
    """A lost or stale preview, made again from its (current) EXR."""
    from hdrcl.io.radiance import read_metadata, read_radiance
    from hdrcl.io.ldr import write_ldr
    from hdrcl.report.preview import downscale, encode

    rad, _ = read_radiance(job.output)
    try:  # a stale preview of this very EXR (another size) still knows its counts
        old = read_metadata(job.preview)
        counts = _counts_of(old) if old.get(DIGEST_KEY) == digest else {}
    except HdrclError:
        counts = {}
    from hdrcl.io.exif import to_display
    from hdrcl.io.outmeta import orientation_after_reading

    write_ldr(job.preview, to_display(encode(downscale(rad, options.preview_size), options.tonemap),
                                      orientation_after_reading(job.output)),  # upright, as the output says
              metadata=_preview_metadata(digest, options, counts))


def _current_deliverables(job: SetJob, options: BatchOptions, warnings: list, radiance=None,
                          recorded: Optional[str] = None) -> list:
    """The deliverables of an up-to-date set: those on disk as they are when the EXR says
    they were made with these settings (``recorded``, its :data:`DELIVER_KEY`), the missing
    or stale ones made from its EXR (``radiance``: when the caller read it already)."""
    import dataclasses

    from hdrcl.report.deliver import deliver, paths_for

    opts = options.deliver_options
    paths = paths_for(job.output, opts)
    stale = recorded != opts.identity()  # other settings, or an EXR merged without --deliver
    missing = tuple(k for k, p in paths.items() if stale or not os.path.isfile(p))
    out = [{"kind": k, "path": p, "bytes": os.path.getsize(p)} for k, p in paths.items() if k not in missing]
    if missing:
        from hdrcl.io.outmeta import orientation_after_reading
        from hdrcl.io.radiance import read_radiance

        rad = radiance if radiance is not None else read_radiance(job.output)[0]
        from hdrcl.core.mertens import read_frames

        out += deliver(job.output, rad, dataclasses.replace(opts, kinds=missing), orientation_after_reading(job.output),
                       frames=lambda: read_frames(job.files, options.ignore_color))
        why = "made with other settings" if stale else "missing"
        for source, kinds in (("the EXR", [k for k in missing if k != "fusion"]),
                              ("the frames", [k for k in missing if k == "fusion"])):
            if kinds:
                warnings.append(f"{', '.join(kinds)} {why}: made from {source}")
    return sorted(out, key=lambda d: list(paths).index(d["kind"]))


#: EXR attributes of a batch set (``hdrcl:`` names): the findings its merge knew when the
#: file was opened (:data:`hdrcl.core.fusestage.FINDINGS_KEY`: the scan's, the exposure
#: trust, alignment, agreement, orientation), and the settings its deliverables were made with.
DELIVER_KEY = "deliver"


def _recorded_findings(job: SetJob, meta: dict) -> List[dict]:
    """The findings of an up-to-date set: the scan's (``job.findings``) and those its merge
    recorded in the EXR (:data:`FINDINGS_KEY`), each once."""
    out = [dict(f) for f in job.findings]
    try:
        recorded = json.loads(meta.get(FINDINGS_KEY) or "[]")
    except (TypeError, ValueError):
        recorded = []
    for f in recorded if isinstance(recorded, list) else []:
        if isinstance(f, dict) and isinstance(f.get("message"), str) and \
                all(f["message"] != g.get("message") for g in out):
            out.append(Finding.from_dict(f).to_dict())
    return out


@contextlib.contextmanager
def _claimed(job: SetJob) -> Iterator[None]:
    """Hold the set's claim (:mod:`hdrcl.shoot.batch.claims`) while writing any of its files,
    so that another batch's cleanup or ``--force`` never removes a file in flight."""
    from hdrcl.shoot.batch.claims import claim_set

    claim = claim_set(os.path.dirname(job.output), os.path.splitext(os.path.basename(job.output))[0])
    try:
        yield
    finally:
        claim.release()


def _read_stage(job: SetJob, ctx: _Context, strict: bool = False):
    """Hash the set, skip it if its outputs are current, else read its headers."""
    seconds: Dict[str, float] = {}
    digest = None
    try:
        if job.damaged:  # the scan could not decode it: the set fails naming the file, first
            name, cause = job.damaged[0]
            path = next((f for f in job.files if os.path.basename(f) == name), name)
            raise InputError(f"{path}: {cause}")
        entry = ctx.responses.get(job.group)
        if entry is None or (entry.payload is None and not entry.deferred):
            # A set's own problem (its first frame is missing...) explains this best.
            _open_set(job)
            why = entry.error if entry is not None else "no response"
            raise HdrclError(f"no response for {job.group}: {why}")
        t0 = _time.perf_counter()
        digest = set_digest(job, ctx.options, entry.digest)
        seconds["hash"] = _time.perf_counter() - t0
        if not ctx.force:
            exr_ok, preview_ok, meta, pmeta = _up_to_date(job, digest, ctx.options)
            radiance = None
            if exr_ok and ctx.options.report_dir and _current_quality(ctx.options.report_dir, job, digest) is None:
                # Its report will need the radiance: reading it whole verifies every pixel too
                # (the EXR is decoded once, not verified and then read again).
                from hdrcl.io.radiance import read_radiance

                try:
                    radiance = read_radiance(job.output)[0]
                    damaged = False
                except HdrclError:
                    damaged = True
            else:
                damaged = exr_ok and not verify_exr(job.output)
            if damaged:  # the header is right, the pixels are not (truncated, damaged)
                logger.warning("%s: damaged output (its pixels cannot be read): merging the set again",
                               job.output)
                exr_ok = False
            if exr_ok and entry.deferred:
                # Up to date, but its camera's response file (this set alone calibrates it)
                # is gone: solve and save it again, as report.json names it.
                from hdrcl.shoot.batch.pooling import _calibration_grid, solve_deferred

                opened = _open_set(job)
                grid = _calibration_grid(job, opened, ctx.options.ignore_color)
                solve_deferred(entry, job, opened.infos, (grid.frames, grid.times, grid.valid_all), ctx.options)
            if exr_ok:
                res = SetResult(index=job.index, files=list(job.files), status=STATUS_SKIPPED, output=job.output,
                                preview=job.preview, seconds=seconds, digest=digest, response=job.group,
                                counts=_counts_of(pmeta), ev_offset=_float_or_none(meta.get("evOffset")),
                                findings=_recorded_findings(job, meta))
                res.warnings += [f["message"] for f in res.findings]
                if not preview_ok:
                    t1 = _time.perf_counter()
                    with _claimed(job):  # its temporary file is the claim holder's
                        _rebuild_preview(job, digest, ctx.options)
                    seconds["preview"] = _time.perf_counter() - t1
                    res.warnings.append("preview was missing or stale: rebuilt from the EXR")
                if ctx.options.deliver_options:
                    t1 = _time.perf_counter()
                    with _claimed(job):
                        res.deliverables = _current_deliverables(job, ctx.options, res.warnings, radiance,
                                                                 meta.get(DELIVER_KEY))
                    seconds["deliver"] = _time.perf_counter() - t1
                if ctx.options.report_dir:
                    res.quality = _current_quality(ctx.options.report_dir, job, digest)
                    if res.quality is None:
                        t1 = _time.perf_counter()
                        with _claimed(job):
                            _rebuild_quality(res, job, ctx, radiance=radiance)
                        seconds["quality"] = _time.perf_counter() - t1
                return res
        t1 = _time.perf_counter()
        opened = _open_set(job)
        seconds["open"] = _time.perf_counter() - t1
        step = _Opening(job, digest, opened, seconds)
        if not ctx.force and damaged:
            step.notes.append("the earlier output was damaged (truncated or unreadable): rebuilt")
        return step
    except Exception as exc:
        if strict and not isinstance(exc, HdrclError):
            raise
        return _failed(job, exc, seconds, digest)


def _merge_stage(step: _Opening, ctx: _Context, strict: bool = False) -> SetResult:
    """Claim the set, then merge it unless another process just did: :func:`_merge_begin`,
    then :func:`_commit_set` on this thread (a batch in this process commits on its own
    thread instead: :mod:`hdrcl.shoot.batch.overlap`)."""
    begun = _merge_begin(step, ctx, strict)
    return _commit_set(begun, ctx, strict) if isinstance(begun, _Started) else begun


@dataclass
class _Started:
    """A set fused, its writer open and its claim held, awaiting :func:`_commit_set`."""

    step: _Opening
    run: object  # hdrcl.core.runstate.RunState
    claim: object  # hdrcl.shoot.batch.claims.SetClaim, released by the commit
    seconds: float  # the start's own seconds (the set's "merge" time, with the commit's)


class _Stopped(BaseException):
    """The batch was cancelled while this set committed: nothing of it is left."""


def _merge_begin(step: _Opening, ctx: _Context, strict: bool = False):
    """Claim the set and run its merge up to the commit (on this thread, the OpenCL queue's).

    The claim (:mod:`hdrcl.shoot.batch.claims`) makes this process the set's only writer
    until its commit returns; a set another batch on the same folder merged while this
    one waited for the claim is skipped. Returns a :class:`_Started` (the claim held),
    else the set's result (skipped, failed; the claim released).
    """
    from hdrcl.core.executor import start
    from hdrcl.shoot.batch.claims import claim_set

    job = step.job
    try:
        claim = claim_set(os.path.dirname(job.output), os.path.splitext(os.path.basename(job.output))[0])
    except OSError as exc:
        return _failed(job, HdrclError(f"{job.output}: cannot claim the set ({exc.strerror or exc})"),
                       step.seconds, step.digest)
    started = None
    try:
        if not ctx.force:
            exr_ok, preview_ok, meta, pmeta = _up_to_date(job, step.digest, ctx.options)
            if exr_ok and preview_ok and verify_exr(job.output):
                return SetResult(index=job.index, files=list(job.files), status=STATUS_SKIPPED, output=job.output,
                                 preview=job.preview, seconds=step.seconds, digest=step.digest,
                                 response=job.group, counts=_counts_of(pmeta),
                                 ev_offset=_float_or_none(meta.get("evOffset")),
                                 findings=_recorded_findings(job, meta),
                                 warnings=["merged meanwhile by another process on this folder"])
        try:
            plan = set_plan(step, ctx)
            t0 = _time.perf_counter()
            with _FUSE_LOCK:
                run = start(plan)
            started = _Started(step, run, claim, _time.perf_counter() - t0)
            return started
        except Exception as exc:
            if strict and not isinstance(exc, HdrclError):
                raise
            return _failed(job, exc, step.seconds, step.digest)
    finally:
        if started is None:
            claim.release()


def _commit_set(started: _Started, ctx: _Context, strict: bool = False, stop=None) -> SetResult:
    """A started set's tail: the preview and the deliverables (:func:`_before_commit`), the
    EXR encoded to its end and moved into place (it marks the set complete), the set's
    record, its quality report; the claim released. A failure fails this set alone (its
    temporary files removed); ``stop`` (a :class:`threading.Event`) set before the EXR is
    moved into place undoes the set and raises :class:`_Stopped`.
    """
    from hdrcl.core.executor import abort, finish

    step, run = started.step, started.run
    job, opts, seconds = step.job, ctx.options, step.seconds
    try:
        t0 = _time.perf_counter()
        made: list = []  # the preview and deliverables written for this commit
        try:
            _check_stop(stop)
            delivered = _before_commit(run, step, opts, made)
            _check_stop(stop)
        except BaseException:
            abort(run)
            _remove(made)
            raise
        try:
            res = finish(run)
        except BaseException:
            _remove(made)  # no picture of a map that was not written
            raise
        seconds["merge"] = started.seconds + _time.perf_counter() - t0 - run.seconds.get("preview", 0.0) \
            - run.seconds.get("write", 0.0) - run.seconds.get("deliver", 0.0)
        for k, v in run.seconds.items():
            if k not in ("open", "calibrate"):
                seconds[k] = seconds.get(k, 0.0) + v
        out = _set_result(step, opts, run, res, delivered)
        if opts.report_dir and not (stop is not None and stop.is_set()):
            # After the EXR is committed: the report never holds back or spoils an output.
            t3 = _time.perf_counter()
            reduced = run.sinks["preview"] if "preview" in run.sinks else run.sinks["reduced"]
            _quality_for(out, job, _quality_bracket(run, step, opts), res.response, res.times, reduced.result(),
                         opts)
            seconds["quality"] = _time.perf_counter() - t3
        return out
    except Exception as exc:
        if strict and not isinstance(exc, HdrclError):
            raise
        return _failed(job, exc, seconds, step.digest)
    finally:
        started.claim.release()


def _remove(paths) -> None:
    """Remove the pictures a set wrote beside an EXR that was not committed (a failed or
    cancelled commit leaves no preview or deliverable of a map that is not there)."""
    for path in paths:
        try:
            os.unlink(path)
        except OSError:
            pass


def _check_stop(stop) -> None:
    if stop is not None and stop.is_set():
        raise _Stopped()


class DeferredResponse(ResponseSource):
    """The response of a camera with one set in the manifest: solved by that set's merge
    from the sampling grid of the decode that feeds its fusion, and saved
    (:func:`hdrcl.shoot.batch.pooling.solve_deferred`); the exposures are then measured through it."""

    own = False
    raw_linear = False

    def __init__(self, entry, job: SetJob, infos, options):
        self.entry, self.job, self.infos, self.opts = entry, job, infos, options
        self.name = os.path.basename(entry.file) if entry.file else entry.group

    def solve(self, merge, grid):
        from hdrcl.shoot.batch.pooling import solve_deferred

        return solve_deferred(self.entry, self.job, merge.inputs.infos, (grid.frames, grid.times, grid.valid_all),
                              self.opts, paths=merge.inputs.paths)


def response_source_of(entry, job: SetJob, infos, options) -> ResponseSource:
    """The set's response source: deferred (its camera's only set), else the group's curve."""
    if entry.deferred:
        return DeferredResponse(entry, job, infos, options)
    return EntryResponse(entry)  # the curve read when the merge asks (a dry run's plan never does)


def set_plan(step: _Opening, ctx: _Context):
    """The set's :class:`hdrcl.core.plan.MergePlan`: the shoot's exposure reference, its
    camera's response (deferred, cached, given or pooled) with what the pool says of the
    set's exposures, the preview (or the quality report's reduced map) and the full map
    for the deliverables as sinks, the quality report's frames kept as they stream past,
    the scan's findings, and the set's digest and settings in the metadata."""
    from hdrcl.core.plan import Extras, plan_merge, response_plan
    from hdrcl.report.preview import AreaAverage
    from hdrcl.shoot.batch.pooling import trust_findings

    job, opened, opts = step.job, step.opened, ctx.options
    try:  # a frame number beyond this set's frames: the set fails here, before anything is decoded
        opts.merge.check_frames(len(job.files))
    except HdrclError as exc:
        raise type(exc)(f"{job.files[0]}: {exc}") from None
    entry = ctx.responses[job.group]
    inputs = Inputs(list(job.files), opened.infos, np.asarray(opened.times, np.float64), reference=job.reference,
                    reference_exposure=job.exposure_ref, timestamp=opened.stamp)
    kind = "deferred" if entry.deferred else {"cached": "cached", "given": "given"}.get(entry.source, "pooled")
    response = response_plan(response_source_of(entry, job, opened.infos, opts), kind,
                             trust=lambda grid: trust_findings(entry, job, grid, opts))
    sinks = []
    if job.preview is not None:  # the preview's reduced map (the quality report's too)
        sinks.append(("preview", lambda h, w, nch: AreaAverage(h, w, nch, opts.preview_size)))
    elif opts.report_dir:  # the quality report's own
        sinks.append(("reduced", lambda h, w, nch: AreaAverage(h, w, nch, REPORT_IMAGE_SIZE)))
    if opts.deliver_options:  # the deliverables need the map at full size
        from hdrcl.core.pipeline import ArraySink

        sinks.append(("full", ArraySink))
    meta = {DIGEST_KEY: step.digest, "evOffset": round(opened.ev_offset, 6),
            "exposureRef": _reference_text(job.reference)}
    if opts.deliver_options:  # what the deliverables beside it are made with
        meta[DELIVER_KEY] = opts.deliver_options.identity()
    tap = None
    if opts.report_dir:  # the quality report keeps the frames (or their grid) as they stream past
        def tap(source, h, w, nch):
            return _KeptFrames(source, _quality_stride(len(inputs.paths), h, w, nch, source.dtype))
    return plan_merge(inputs, opts.merge, response, job.output, extras=Extras(chain=opts.luminance_chain()),
                      sinks=tuple(sinks), tap=tap, metadata=tuple(meta.items()), record_findings=True,
                      findings=tuple(Finding.from_dict(d) for d in job.findings),
                      reference_from_exposures=bool(job.exposure_ref_own))


def _before_commit(run, step: _Opening, opts: BatchOptions, made=None) -> list:
    """Between the fusion and the commit: the preview, then the deliverables (returned);
    each file written is added to ``made`` as soon as it exists."""
    made = [] if made is None else made
    from hdrcl.io.exif import common_orientation

    small, full = run.sinks.get("preview"), run.sinks.pop("full", None)
    if small is not None:
        from hdrcl.io.exif import to_display
        from hdrcl.io.ldr import write_ldr
        from hdrcl.report.preview import encode

        with run.timed("preview"):  # upright: turned as the frames' EXIF Orientation says
            upright = to_display(encode(small.result(), opts.tonemap),
                                 common_orientation(i.orientation for i in run.inputs.infos))
            write_ldr(step.job.preview, upright, metadata=_preview_metadata(step.digest, opts, run.counts))
            made.append(step.job.preview)
    if full is None:
        return []
    from hdrcl.report.deliver import deliver

    with run.timed("deliver"), _FUSE_LOCK:  # its tone mapping runs on the process's OpenCL device
        delivered = deliver(step.job.output, full.array, opts.deliver_options,
                            common_orientation(i.orientation for i in run.inputs.infos),
                            device=opts.device, frames=lambda: _fusion_frames(run, opts))
    made.extend(d["path"] for d in delivered)
    del full  # the map's memory, before the EXR is closed
    return delivered


def _fusion_frames(run, opts: BatchOptions):
    """The photographs for ``--deliver fusion``: the aligned (and cropped) frames the
    merge holds, else decoded again from the merged files."""
    if hasattr(run.source, "frames"):
        valid = list(run.source.valid)
        return list(run.source.frames), (None if all(v is None for v in valid) else valid)
    from hdrcl.core.mertens import read_frames

    return read_frames(run.inputs.paths, opts.ignore_color)


def _quality_bracket(run, step: _Opening, opts: BatchOptions):
    """The frames the fusion saw, for the quality report: kept as they streamed, or
    the aligned (and cropped) frames themselves."""
    from hdrcl.core.bracket import Bracket

    job, opened = step.job, step.opened
    if run.tapped is not None:
        return run.tapped.bracket(job.files, opened.infos, opened.times, opts.ignore_color)
    inp = run.inputs  # the frames merged: an alignment may have left some out
    return Bracket(frames=list(run.source.frames), times=np.asarray(inp.times, np.float64),
                   valid=list(run.source.valid), paths=list(inp.paths), infos=list(inp.infos))


def _set_result(step: _Opening, opts: BatchOptions, run, res, delivered) -> SetResult:
    """The batch's record of the merged set."""
    job, counts = step.job, res.counts
    notes = (list(step.notes) + list(step.opened.notes) + run.notes + list(res.response.warnings)
             + run.check_notes + run.write_warnings)
    if counts.get("no_data"):
        notes.append(f"{counts['no_data']} pixel-channels are invalid in every frame and were set to 0")
    notes += [f.message for f in res.findings if f.message not in notes]
    keys = ("clipped_high", "clipped_low", "no_data") + (("ghost", "ghost_unresolved") if opts.deghost else ())
    out = SetResult(index=job.index, files=list(job.files), status=STATUS_DONE, output=job.output,
                    preview=job.preview, warnings=notes, seconds=step.seconds,
                    counts={k: int(counts.get(k, 0)) for k in keys},
                    ev_offset=round(step.opened.ev_offset, 6), digest=step.digest, response=job.group,
                    storage=res.storage_note, findings=[f.to_dict() for f in res.findings])
    out.deliverables = list(delivered)
    if out.needs_check:
        out.status = STATUS_CHECK
    if res.alignment is not None:
        out.alignment = res.alignment  # per frame: hdrcl.core.align.handheld.describe
    if res.vertical_illuminance is not None:  # a fisheye luminance map with a -vta/-vth view
        out.vertical_illuminance = res.vertical_illuminance
        out.glare = _glare_figures(job.output, notes)
    return out


def _glare_figures(path: str, notes: list) -> Optional[dict]:
    """What ``hdrcl glare`` says of the written map (the same file, the same figures): its
    vertical illuminance, DGP, DGI, UGR and the number of glare sources; None, with a note,
    where the map cannot be rated."""
    from hdrcl.core.luminance.glare import glare_of_file

    try:
        g = glare_of_file(path)
    except HdrclError as exc:
        notes.append(f"glare metrics: {exc}")
        return None
    return {"vertical_illuminance": round(g.vertical_illuminance, 4), "dgp": round(g.dgp, 5),
            "dgi": round(g.dgi, 4), "ugr": round(g.ugr, 4), "sources": len(g.sources),
            "threshold": g.threshold}


def _rebuild_quality(res: SetResult, job: SetJob, ctx: _Context, radiance=None) -> None:
    """The report of a skipped set that has none (or a stale one): the set is prepared by
    the merge engine as its merge was (aligned frames, the exposures it measured), the
    frames read (whole or the sampling grid) and the radiance from its EXR
    (``radiance``, when the caller read it already)."""
    from hdrcl.core.bracket import Bracket, with_ignore
    from hdrcl.io.radiance import read_radiance
    from hdrcl.report.preview import downscale

    from hdrcl.core.executor import prepare

    opts = ctx.options
    try:
        merge = prepare(set_plan(_Opening(job, res.digest, _open_set(job), {}), ctx))
        try:
            src = merge.source
            if hasattr(src, "frames"):  # aligned: the frames as merged
                frames, valid, stride = list(src.frames), list(src.valid), 1
            else:
                stride = _quality_stride(len(job.files), merge.h, merge.w, src.nch, src.dtype)
                if stride > 1:
                    src.rewind()
                frames, valid = src.read_all() if stride == 1 else src.read_grid(stride)
                valid = with_ignore(frames, valid, opts.ignore_color)
        finally:
            merge.close()
        bracket = Bracket(frames=frames, times=merge.inputs.times, valid=valid, paths=list(merge.inputs.paths),
                          infos=merge.inputs.infos, grid=stride > 1)
        rad = radiance if radiance is not None else read_radiance(job.output)[0]
        small = downscale(rad, opts.preview_size if job.preview is not None else REPORT_IMAGE_SIZE)
        del rad
    except Exception as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        res.warnings.append(f"quality report not written: {first}")
        return
    _quality_for(res, job, bracket, merge.response, merge.times, small, opts)


def _float_or_none(v) -> Optional[float]:
    try:
        return None if v is None else float(v)
    except (TypeError, ValueError):
        return None


def process_set(job: SetJob, ctx: _Context, strict: bool = False) -> SetResult:
    """Hash, open, merge and write one set in the calling process.

    The task that worker processes and Dask workers run. With ``strict``, errors
    that are not :class:`~hdrcl.errors.HdrclError` (a bug, a lost mount, a device
    fault) are raised so that the scheduler retries the task; a set's own problems
    (corrupt frame, missing exposure) always come back as a failed result.
    """
    t0 = _time.perf_counter()
    step = _read_stage(job, ctx, strict)
    if isinstance(step, _Opening):
        step = _merge_stage(step, ctx, strict)
    step.seconds["total"] = _time.perf_counter() - t0
    return step
