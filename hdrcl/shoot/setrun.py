"""Merging one set of a batch: reading its headers and digest (read stage), then fusing
and writing it (merge stage); :func:`process_set` runs both.
"""
from __future__ import annotations

import contextlib
import logging
import os
import time as _time
from dataclasses import dataclass, field
from typing import Dict, Iterator, List, Optional

from hdrcl.errors import HdrclError
from hdrcl.shoot.jobs import (
    _FUSE_LOCK,
    STATUS_DONE,
    STATUS_FAILED,
    STATUS_SKIPPED,
    BatchOptions,
    SetJob,
    SetResult,
    _Context,
    _reference_text,
)
from hdrcl.shoot.pooling import _open_set, _Opened, _response_of
from hdrcl.shoot.setquality import (
    REPORT_IMAGE_SIZE,
    _current_quality,
    _KeptFrames,
    _quality_for,
    _quality_stride,
    _rebuild_quality,
)
from hdrcl.shoot.state import (
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
                     response=job.group)


def _rebuild_preview(job: SetJob, digest: str, options: BatchOptions) -> None:
    """A lost or stale preview, made again from its (current) EXR."""
    from hdrcl.io.radiance import read_metadata, read_radiance
    from hdrcl.io.writers import write_ldr
    from hdrcl.report.preview import downscale, encode

    rad, _ = read_radiance(job.output)
    try:  # a stale preview of this very EXR (another size) still knows its counts
        old = read_metadata(job.preview)
        counts = _counts_of(old) if old.get(DIGEST_KEY) == digest else {}
    except HdrclError:
        counts = {}
    write_ldr(job.preview, encode(downscale(rad, options.preview_size), options.tonemap),
              metadata=_preview_metadata(digest, options, counts))


@contextlib.contextmanager
def _claimed(job: SetJob) -> Iterator[None]:
    """Hold the set's claim (:mod:`hdrcl.shoot.claims`) while writing any of its files,
    so that another batch's cleanup or ``--force`` never removes a file in flight."""
    from hdrcl.shoot.claims import claim_set

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
                from hdrcl.shoot.pooling import _calibration_grid, solve_deferred

                opened = _open_set(job)
                grid = _calibration_grid(job, opened, ctx.options.ignore_color)
                solve_deferred(entry, job, opened.infos, (grid.frames, grid.times, grid.valid_all), ctx.options)
            if exr_ok:
                res = SetResult(index=job.index, files=list(job.files), status=STATUS_SKIPPED, output=job.output,
                                preview=job.preview, seconds=seconds, digest=digest, response=job.group,
                                counts=_counts_of(pmeta), ev_offset=_float_or_none(meta.get("evOffset")))
                if not preview_ok:
                    t1 = _time.perf_counter()
                    with _claimed(job):  # its temporary file is the claim holder's
                        _rebuild_preview(job, digest, ctx.options)
                    seconds["preview"] = _time.perf_counter() - t1
                    res.warnings.append("preview was missing or stale: rebuilt from the EXR")
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


class _Tee:
    """Hands every strip to several sinks (the EXR writer, the preview)."""

    def __init__(self, *sinks):
        self.sinks = [s for s in sinks if s is not None]

    def write_rows(self, y0, y1, data):
        for s in self.sinks:
            s.write_rows(y0, y1, data)


def _merge_stage(step: _Opening, ctx: _Context, strict: bool = False) -> SetResult:
    """Claim the set, then merge it unless another process just did.

    The claim (:mod:`hdrcl.shoot.claims`) makes this process the set's only writer
    until it returns; a set another batch on the same folder merged while this one
    waited for the claim is skipped.
    """
    from hdrcl.shoot.claims import claim_set

    job = step.job
    try:
        claim = claim_set(os.path.dirname(job.output), os.path.splitext(os.path.basename(job.output))[0])
    except OSError as exc:
        return _failed(job, HdrclError(f"{job.output}: cannot claim the set ({exc.strerror or exc})"),
                       step.seconds, step.digest)
    try:
        if not ctx.force:
            exr_ok, preview_ok, meta, pmeta = _up_to_date(job, step.digest, ctx.options)
            if exr_ok and preview_ok and verify_exr(job.output):
                return SetResult(index=job.index, files=list(job.files), status=STATUS_SKIPPED, output=job.output,
                                 preview=job.preview, seconds=step.seconds, digest=step.digest,
                                 response=job.group, counts=_counts_of(pmeta),
                                 ev_offset=_float_or_none(meta.get("evOffset")),
                                 warnings=["merged meanwhile by another process on this folder"])
        return _merge_claimed(step, ctx, strict)
    finally:
        claim.release()


def _merge_claimed(step: _Opening, ctx: _Context, strict: bool = False) -> SetResult:
    """Decode, fuse and write the set strip by strip; preview; commit the EXR.

    Memory stays bounded by the strip height whatever the image size: decoding the
    next strip, fusing the current one on the device and encoding the previous one
    overlap (:func:`hdrcl.core.pipeline.stream_merge`). With ``--align`` the frames are
    held in memory; ``--fit-exposures`` and ``--neutral`` are applied as ``merge`` does
    (:mod:`hdrcl.shoot.setopts`).
    """
    from hdrcl.cl.backend import get_processor
    from hdrcl.core.encode import fuse_to_file, radiance_opener, reference_for
    from hdrcl.core.merge import MergeResult, _provenance
    from hdrcl.core.pipeline import stream_merge
    from hdrcl.io.reader import BracketReader
    from hdrcl.io.outmeta import camera_from_infos
    from hdrcl.io.writers import write_ldr
    from hdrcl.core.radiometry import ScaledSink
    from hdrcl.report.preview import AreaAverage, encode
    from hdrcl.shoot.setopts import aligned_grid, aligned_source, fitted_times, white_balance

    job, opened, opts = step.job, step.opened, ctx.options
    seconds = step.seconds
    try:
        entry = ctx.responses[job.group]
        first = opened.infos[0]
        h, w = first.height, first.width
        t0 = _time.perf_counter()
        with _FUSE_LOCK, BracketReader(job.files, opened.infos) as reader:
            nch = reader.nch
            grid = None
            source, shifts, alignment = reader, None, None
            if opts.align:  # warped first: the solve and the exposure fit read the aligned frames
                source, shifts, _box, alignment = aligned_source(job, opened, opts, opened.times)
                h, w = source.height, source.width
                if entry.deferred or opts.fit_exposures != "off":
                    grid = aligned_grid(job, opened, source)
            elif entry.deferred or opts.fit_exposures != "off":
                # One streaming pass decodes every frame once: its sampling grid serves the
                # response solve and the exposure fit, its decoded codes the fusion.
                from hdrcl.core.bracket import _grid_bracket

                grid = _grid_bracket(list(job.files), opened.infos, opened.times, opts.ignore_color,
                                     reader=reader, keep=True)
                seconds["decode"] = reader.decode_seconds
            if entry.deferred:
                from hdrcl.shoot.pooling import solve_deferred

                ts = _time.perf_counter()
                resp = solve_deferred(entry, job, opened.infos, (grid.frames, grid.times, grid.valid_all), opts)
                seconds["solve"] = _time.perf_counter() - ts
            else:
                resp = _response_of(entry)
            times, fit_notes = fitted_times(job, opened, opts, grid=grid, resp=resp)
            chain = opts.luminance_chain()  # a fisheye luminance map: this set's own accumulator
            if chain is not None:
                chain.bind(h, w, nch)  # the lens circle inside the (aligned, cropped) image
            factors, units = white_balance(job, opened, source, times, resp, opts, nch, h, w)
            work = h * w * len(job.files)  # a small set skips OpenCL's start-up
            backend = "numpy" if get_processor("fusion", opts.device, work=work) is None else "opencl"
            about = MergeResult(radiance=None, response=resp, counts={}, times=times, paths=list(job.files),
                                backend=backend, shape=(h, w, nch))
            meta = _provenance(about, os.path.basename(entry.file) if entry.file else entry.group)
            meta.update(units)
            meta.update({DIGEST_KEY: step.digest, "evOffset": round(opened.ev_offset, 6),
                         "exposureRef": _reference_text(job.reference)})
            if shifts is not None:
                from hdrcl.core.handheld import alignment_meta

                meta.update(alignment_meta(shifts, alignment))
            small = AreaAverage(h, w, nch, opts.preview_size) if job.preview is not None else None
            # The quality report keeps the frames (or their sampling grid) as they stream
            # past, and a reduced radiance map: the preview's, or its own without one.
            kept = _KeptFrames(reader, _quality_stride(len(job.files), h, w, nch, reader.dtype)) \
                if opts.report_dir and source is reader else None
            thumb = small if small is not None or not opts.report_dir else AreaAverage(h, w, nch, REPORT_IMAGE_SIZE)
            t_ref = reference_for(job.output, times, job.exposure_ref, units.get("units", "relative"))
            if units.get("units", "relative") == "relative":
                meta["referenceExposure"] = t_ref
            camera = camera_from_infos(opened.infos, reference=job.reference, units=units.get("units", "relative"),
                                       exposure_time=t_ref)
            has_valid = (opts.ignore_color is not None or any(i.nchannels in (2, 4) for i in opened.infos)
                         or source is not reader)

            open_writer = radiance_opener(job.output, w, h, nch, meta, camera, compression=opts.compression,
                                          timestamp=opened.stamp, colorspace=opts.colorspace)

            def run(file_sink, first_pass):
                sink = _Tee(file_sink, thumb) if first_pass else file_sink
                if factors is not None:
                    sink = ScaledSink(sink, factors)
                src = source if kept is None or not first_pass else kept
                if not first_pass and hasattr(src, "rewind"):
                    src.rewind()
                counts, _ = stream_merge(src, times, resp, sink, weight=opts.weight, ignore_color=opts.ignore_color,
                                         has_valid=has_valid, device=opts.device, deghost=opts.deghost,
                                         seconds=seconds, work=work)
                return counts

            # Half floats whenever the merged values fit (measured as they stream), else
            # fused again into float or rescaled half (hdrcl.core.encode).
            writer, counts, stored = fuse_to_file(open_writer, run, output=job.output, dtype=opts.dtype,
                                                  reference=t_ref, keep_units=units.get("units", "relative") != "relative",
                                                  chain=chain)
            try:
                t1 = _time.perf_counter()
                # Preview first: the EXR, moved into place last, marks the set complete.
                if small is not None:
                    write_ldr(job.preview, encode(small.result(), opts.tonemap),
                              metadata=_preview_metadata(step.digest, opts, counts))
                t2 = _time.perf_counter()
                warnings = writer.close()
            except BaseException:
                writer.abort()
                raise
            if stored.note:
                about.storage_note = stored.note
        seconds.update({"merge": t1 - t0, "preview": t2 - t1, "write": _time.perf_counter() - t2})
        notes = list(step.notes) + list(opened.notes) + fit_notes + list(resp.warnings) + list(warnings)
        if opts.report_dir and kept is None:
            notes.append("quality report not measured: aligned sets are not measured in a batch")
        if counts.get("no_data"):
            notes.append(f"{counts['no_data']} pixel-channels are invalid in every frame and were set to 0")
        keys = ("clipped_high", "clipped_low", "no_data") + (("ghost", "ghost_unresolved") if opts.deghost else ())
        res = SetResult(index=job.index, files=list(job.files), status=STATUS_DONE, output=job.output,
                        preview=job.preview, warnings=notes, seconds=seconds,
                        counts={k: int(counts.get(k, 0)) for k in keys},
                        ev_offset=round(opened.ev_offset, 6), digest=step.digest, response=job.group,
                        storage=about.storage_note)
        if alignment is not None:
            res.alignment = alignment  # per frame: hdrcl.core.handheld.describe
        if chain is not None and chain.vertical_illuminance is not None:
            res.vertical_illuminance = chain.vertical_illuminance
        if kept is not None:
            # After the EXR is committed: the report never holds back or spoils an output.
            t3 = _time.perf_counter()
            bracket = kept.bracket(job.files, opened.infos, opened.times, opts.ignore_color)
            del kept
            _quality_for(res, job, bracket, resp, times, thumb.result(), opts)
            seconds["quality"] = _time.perf_counter() - t3
        return res
    except Exception as exc:
        if strict and not isinstance(exc, HdrclError):
            raise
        return _failed(job, exc, seconds, step.digest)


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
