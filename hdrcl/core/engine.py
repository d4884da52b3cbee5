"""The merge engine: one object holds a merge's state and runs its named stages.

    open -> (align) -> sample -> solve or take the response -> measure exposures
         -> scale -> fuse into the sinks -> commit

``hdrcl merge`` / :func:`hdrcl.merge_files` (:func:`hdrcl.core.merge.merge_files`), each set
of ``hdrcl batch`` (:class:`hdrcl.shoot.batch.setrun.SetMerge`, a subclass with the batch's
response source, preview and digest), the quality report (from the frames the fusion
saw, aligned ones included) all go through :class:`MergeJob`. Each stage is timed on the
:class:`Timed` base (``job.seconds``), not in dicts handed down.

The fusion backend is decided once per job, by its size and the device asked for
(:func:`fusion_processor`), never by what the process ran before: the same set gives the
same bytes first or after other sets.
"""
from __future__ import annotations

import contextlib
import logging
import os
import time
from dataclasses import dataclass, field, replace
from typing import List, Optional

import numpy as np

from hdrcl.core.agreement import check_job as check_agreement
from hdrcl.core.options import MergeOptions
from hdrcl.core.pipeline import fusion_processor
from hdrcl.core.sources import Inputs, ResponseSource, check_brightness_order

logger = logging.getLogger(__name__)


class Timed:
    """Stage timing: ``with self.timed("solve"): ...`` adds the seconds to
    ``self.seconds["solve"]`` (stages that run twice add up)."""

    def __init__(self):
        self.seconds: dict = {}

    @contextlib.contextmanager
    def timed(self, name: str):
        t = time.perf_counter()
        try:
            yield
        finally:
            self.add_time(name, time.perf_counter() - t)

    def add_time(self, name: str, value: float) -> None:
        self.seconds[name] = self.seconds.get(name, 0.0) + value


@dataclass
class Extras:
    """What a merge keeps or writes besides its radiance file."""

    keep_radiance: bool = False
    keep_frames: bool = False
    thumbnail: int = 0
    ghost_mask: Optional[str] = None
    clip_mask: Optional[str] = None
    owner: Optional[str] = None
    save_response: Optional[str] = None
    chain: object = None
    sinks: list = field(default_factory=list)  # more sinks of the scaled radiance (first pass)


class MergeJob(Timed):
    """One merge: ``run()`` runs the stages in order and returns a
    :class:`hdrcl.core.merge.MergeResult`. Subclasses (the batch's set) override the
    hooks :meth:`metadata`, :meth:`camera`, :meth:`tap` and :meth:`before_commit`."""

    def __init__(self, inputs: Inputs, options: MergeOptions, source: ResponseSource, output: str,
                 extras: Optional[Extras] = None):
        super().__init__()
        self.inputs, self.options, self.responses, self.output = inputs, options, source, output
        self.extras = extras or Extras()
        self.chain = self.extras.chain
        self.response = source.given()
        self.own = source.own and self.response is None  # calibrated here (or RAW: linear)
        self.source_name = source.name
        self.times = np.asarray(inputs.times, np.float64)
        self.nominal = self.times
        self.grid = None
        self.source = None
        self.ignore = options.ignore_color  # masked in the fusion; None once the valid masks hold it
        self.shifts = self.crop_box = self.alignment = None
        self.notes: List[str] = []  # on the exposures measured
        self.check_notes: List[str] = []  # on the exposures checked against a given response
        self.write_warnings: List[str] = []
        self.findings: list = []  # hdrcl.core.findings.Finding, from every stage (see find())
        self.factors, self.units = None, {"units": "relative"}
        self.processor = None

    # ------------------------------------------------------------------ stages
    def open(self) -> None:
        """Sizes and checks from the headers, the backend, the OpenCL warm-up."""
        from hdrcl.core.orientation import orientation_findings
        from hdrcl.core.params import check_image_size, check_response_fits

        o, first = self.options, self.inputs.infos[0]
        self.nch = 3 if first.nchannels >= 3 else 1
        self.h, self.w = first.height, first.width
        self.work = first.width * first.height * len(self.inputs.paths)
        self.warm = _warm_up(o.device, self.work)
        check_image_size(self.w, self.h, neutral=o.neutral, reference_patch=o.reference_patch)
        for finding in orientation_findings(self.inputs.infos, self.output):  # hdrcl.core.orientation
            self.find(finding)
        if self.chain is not None:
            self.chain.bind(self.h, self.w, self.nch)  # --lens-circle against the image, before any decoding
            if o.reference_patch is None and not (first.fnumber and first.iso) and self.inputs.reference is None:
                raise _usage(f"{self.inputs.paths[0]}: a luminance map (--lens-circle) is in cd/m^2 from the first "
                             "frame's f-number and ISO, which its EXIF does not give; use --reference-patch")
        if self.response is not None:
            check_response_fits(self.response, self.source_name, self.inputs.paths[0], first.bits, self.nch)
        elif self.responses.solves and self.responses.raw_linear and _all_raw(self.inputs.paths):
            from hdrcl.core.response import linear_response

            self.response, self.source_name = linear_response(self.nch), "linear (RAW input)"
            self.response.exposures = [{"file": os.path.basename(p), "nominal": float(t), "fitted": None,
                                        "used": float(t)} for p, t in zip(self.inputs.paths, self.times)]

    def load(self) -> None:
        """The frames as a strip source: streamed by a reader, or held and warped (align)."""
        from hdrcl.io.reader import BracketReader

        if not self.options.align:
            self.source = BracketReader(self.inputs.paths, self.inputs.infos)
            return
        from hdrcl.core.align.stream import aligned_source
        from hdrcl.core.align.unaligned import without

        # The frames decoded once and kept, sampled through their transforms strip by strip.
        self.source, al = aligned_source(self.inputs, self.options, find=self.find)
        self.add_time("decode", al.decode_seconds)
        self.add_time("align", al.align_seconds)
        if al.left_out:  # frames that cannot be aligned: merged without them (a finding names each)
            self.inputs = without(self.inputs, al.left_out)
            self.times = self.nominal = np.asarray(self.inputs.times, np.float64)
        self.shifts, self.crop_box, self.alignment = al.shifts, al.crop, al.alignment
        self.h, self.w = self.source.height, self.source.width
        self.ignore = None

    def sample(self) -> None:
        """The sampling grid, when the solve or the exposure measurement needs it: from the
        held frames, or from one streaming pass that also keeps the decoded codes for the
        fusion (each frame decoded once)."""
        o = self.options
        measure = not self.own and o.fit_exposures != "off"
        if not (measure or (self.response is None and self.responses.solves)):
            return
        from hdrcl.core.bracket import Bracket, _grid_bracket
        from hdrcl.core.sampling import grid_stride

        if hasattr(self.source, "frames"):
            k = grid_stride(self.h, self.w)
            src = self.source
            self.grid = Bracket(frames=[f[::k, ::k] for f in src.frames], times=self.times,
                                valid=[None if v is None else v[::k, ::k] for v in src.valid],
                                paths=self.inputs.paths, infos=self.inputs.infos, grid=True)
        else:
            self.grid = _grid_bracket(self.inputs.paths, self.inputs.infos, self.times, o.ignore_color,
                                      reader=self.source, keep=True)
            self.add_time("decode", self.source.decode_seconds)

    def respond(self) -> None:
        """Solve the response from the grid, or take the one given (after the exposures'
        order is checked against the frames' brightness)."""
        if self.grid is not None:
            check_brightness_order(self.grid, self.times, self.inputs)
        if self.response is None:
            with self.timed("solve"):
                self.response = self.responses.solve(self, self.grid)

    def measure(self) -> None:
        """Each frame's exposure measured through a known curve (``fit_exposures``), or the
        exposures the set's own calibration refined."""
        from hdrcl.core.calibrate import exposures_used

        o = self.options
        if not self.own and o.fit_exposures != "off" and len(self.inputs.paths) > 1:
            from hdrcl.core.exposure.known import exposures_for_merge

            used, notes = exposures_for_merge(self.grid.frames, self.times, self.response, mode=o.fit_exposures,
                                              valid=self.grid.valid, weight=o.weight,
                                              tolerance_stops=o.exposure_tolerance, names=self.inputs.paths,
                                              labels=self.inputs.labels())
            for note in notes:
                logger.warning("%s", note)
            self.times = np.asarray(used, np.float64)
            self.notes += notes
        self.times = exposures_used(self.response, self.times)

    def scale(self) -> None:
        """White balance and absolute scale: per-channel factors and the units."""
        from hdrcl.core.scale import radiometric_factors

        o = self.options
        absolute = o.absolute or (self.chain is not None and o.reference_patch is None)
        if self.chain is not None:
            self.chain.bind(self.h, self.w, self.nch)  # again: --crop may have made the image smaller
        self.factors, self.units = radiometric_factors(
            self.inputs.paths, self.inputs.infos, self.source, self.times, self.response,
            o.replace(absolute=absolute) if absolute != o.absolute else o, self.nch, self.h, self.w,
            exposure_reference=self.inputs.reference)

    def find(self, finding) -> None:
        """Record what a check found (:class:`hdrcl.core.findings.Finding`): logged as a
        warning now, and carried on the result (its ``findings`` and ``warnings``)."""
        if any(f.message == finding.message for f in self.findings):
            return
        logger.warning("%s", finding.message)
        self.findings.append(finding)

    # ------------------------------------------------------------------ hooks
    def metadata(self) -> dict:
        """The file's hdrcl metadata (provenance, units, reference exposure, alignment)."""
        from hdrcl.core.result import provenance

        meta = provenance(self.result, self.source_name)
        meta.update(self.units)
        if self.unit == "relative":
            meta["referenceExposure"] = self.t_ref
        meta["colorspace"] = self.options.colorspace
        meta.update(self.alignment_meta())
        return meta

    def alignment_meta(self) -> dict:
        if self.shifts is None:
            return {}
        from hdrcl.core.align.handheld import alignment_meta

        return alignment_meta(self.shifts, self.alignment)

    def camera(self) -> dict:
        from hdrcl.io.outmeta import camera_from_infos

        return camera_from_infos(self.inputs.infos, owner=self.extras.owner, reference=self.inputs.reference,
                                 units=self.unit, exposure_time=self.t_ref)

    def tap(self, source):
        """The source of the first fusion pass (a subclass may keep what streams past)."""
        return source

    def before_commit(self, counts: dict) -> None:
        """Called after the fusion, before the radiance file is moved into place."""

    # ------------------------------------------------------------------ fusion
    def _exposure_check(self):
        """A given response with ``fit_exposures=off``: the exposures are checked only."""
        if self.own or self.options.fit_exposures != "off":
            return None
        from hdrcl.core.exposure.fit import ExposureCheck
        from hdrcl.core.pipeline import fusion_tables

        order = np.argsort(self.times, kind="stable")
        tables = fusion_tables(self.response, self.source.dtype, self.nch, self.options.weight)[0]
        return ExposureCheck(np.log(self.times[order]), tables, [self.inputs.paths[i] for i in order])

    def _has_valid(self) -> bool:
        return (self.options.ignore_color is not None or any(i.nchannels in (2, 4) for i in self.inputs.infos)
                or any(v is not None for v in getattr(self.source, "valid", [])))

    def fuse(self) -> None:
        """Fuse into the file and the other sinks; the writer is left open for commit."""
        from hdrcl.core.encode import fuse_to_file, radiance_opener, reference_for
        from hdrcl.core.result import MergeResult
        from hdrcl.core.pipeline import ArraySink, FusionSpec, Thumbnail, stream_merge

        o, x, h, w, nch = self.options, self.extras, self.h, self.w, self.nch
        self.warm.join()
        self.processor = fusion_processor(o.device, self.work)
        self.result = MergeResult(radiance=None, response=self.response, counts={}, times=self.times,
                                  paths=self.inputs.paths, backend="numpy" if self.processor is None else "opencl",
                                  shape=(h, w, nch), warnings=list(self.response.warnings) + self.notes,
                                  output=self.output, shifts=self.shifts, nominal=self.nominal, crop=self.crop_box,
                                  alignment=self.alignment,
                                  recorded=[getattr(i, "exposure_time", None) for i in self.inputs.infos])
        self.unit = self.units.get("units", "relative")
        given_ref = self.inputs.reference_exposure if self.inputs.reference_exposure is not None \
            else o.reference_exposure
        self.t_ref = reference_for(self.output, self.times, given_ref, self.unit)
        self.thumb = Thumbnail(h, w, nch, x.thumbnail) if x.thumbnail else None
        self.keep = ArraySink(h, w, nch) if x.keep_radiance else None
        self.mask = np.zeros((h, w), bool) if x.ghost_mask is not None else None
        self.clips = np.zeros((h, w), np.uint8) if x.clip_mask is not None else None
        check = self._exposure_check()
        spec = FusionSpec(weight=o.weight, ignore_color=self.ignore, has_valid=self._has_valid(), device=o.device,
                          deghost=o.deghost, ghost_mask=self.mask, ghost_reference=o.ghost_reference,
                          ghost_threshold=o.ghost_threshold, seconds=self.seconds, work=self.work,
                          clip_mask=self.clips, processor=self.processor)
        open_writer = radiance_opener(self.output, w, h, nch, self.metadata(), self.camera(),
                                      compression=o.compression, timestamp=self.inputs.timestamp,
                                      colorspace=o.colorspace)

        def run(file_sink, first_pass):
            sinks = [file_sink] + ([s for s in [self.keep] + list(x.sinks) if s is not None] if first_pass else [])
            sink = sinks[0] if len(sinks) == 1 else Tee(*sinks)
            if self.factors is not None:
                from hdrcl.core.radiometry import ScaledSink

                sink = ScaledSink(sink, self.factors)
            src = self.tap(self.source) if first_pass else self.source
            if not first_pass and hasattr(src, "rewind"):
                src.rewind()
            run_spec = spec if first_pass else replace(spec)
            run_spec.exposure_check = check if first_pass else None
            run_spec.thumbnail = self.thumb if first_pass else None
            counts, backend = stream_merge(src, self.times, self.response, sink, run_spec)
            self.result.backend = backend
            if check is not None and first_pass:
                self.check_notes = _report_exposure_check(check, self.result, o.exposure_tolerance)
            return counts

        self.writer, self.counts, self.stored = fuse_to_file(open_writer, run, output=self.output, dtype=o.dtype,
                                                             reference=self.t_ref, keep_units=self.unit != "relative",
                                                             chain=self.chain)
        if self.chain is not None:  # --lens-circle against the image's dark border
            from hdrcl.core.luminance.border import lens_circle_finding

            found = lens_circle_finding(self.chain.border, self.chain.lens_circle, self.inputs.paths[0])
            if found is not None:
                self.find(found)

    def commit(self) -> None:
        """The hook, then the radiance file moved into place; masks and response after."""
        try:
            self.before_commit(self.counts)
            with self.timed("write"):
                self.write_warnings = list(self.writer.close())
            self.result.warnings += self.write_warnings
        except BaseException:
            self.writer.abort()
            raise
        res, x = self.result, self.extras
        res.stored = self.stored
        if self.chain is not None:
            res.vertical_illuminance = self.chain.vertical_illuminance
        if self.stored.note:
            res.warnings.append(f"{self.output}: {self.stored.note}")
            res.storage_note = self.stored.note
        if self.mask is not None:
            from hdrcl.io.ldr import write_ldr

            write_ldr(x.ghost_mask, (self.mask.astype(np.uint8) * 255)[..., None])
        if self.clips is not None:
            from hdrcl.io.ldr import write_ldr

            img = np.where(self.clips & 1, 255, np.where(self.clips & 2, 128, 0)).astype(np.uint8)
            write_ldr(x.clip_mask, img[..., None])

    # ------------------------------------------------------------------ driver
    def prepare(self) -> None:
        """The stages before the fusion: open, (align), sample, respond, measure. The
        caller closes ``self.source`` (:meth:`close`) unless :meth:`run` follows."""
        with self.timed("open"):
            self.open()
        t1 = time.perf_counter()
        self.load()
        self.sample()
        self.respond()
        self.measure()
        self.add_time("calibrate", time.perf_counter() - t1)

    def close(self) -> None:
        if hasattr(self.source, "close"):
            self.source.close()

    def run(self):
        """All stages; the sources are closed whatever happens."""
        t0 = time.perf_counter()
        staged = None
        try:
            self.prepare()
            check_agreement(self)  # do the frames agree? (findings; hdrcl.core.agreement)
            t2 = time.perf_counter()
            if self.extras.save_response is not None:
                # A second output is staged first: a full disk fails here, before the radiance exists.
                from hdrcl.io.atomic import stage_text

                staged = stage_text(self.extras.save_response, self.response.to_json())
            self.scale()
            self.fuse()
            self.commit()
            if staged is not None:
                staged.commit()
            if self.extras.keep_frames:
                self.result.kept = _kept_frames(self.source, self.grid)
        finally:
            if staged is not None:
                staged.discard()
            if hasattr(self.source, "close"):
                self.source.close()
        return self._finish(t0, t2)

    def _finish(self, t0: float, t2: float):
        res, counts = self.result, self.counts
        res.counts = counts
        res.findings = list(self.findings)
        res.warnings += [f.message for f in self.findings if f.message not in res.warnings]
        res.radiance = self.keep.array if self.keep is not None else None
        res.thumbnail = self.thumb.array if self.thumb is not None else None
        if counts.get("no_data"):
            msg = f"{self.output}: {counts['no_data']} pixel-channels are invalid in every frame and were set to 0"
            logger.warning(msg)
            res.warnings.append(msg)
        if self.options.deghost:
            logger.info("%s: ghost pixels %.2f %%", self.output,
                        100.0 * counts.get("ghost", 0) / max(self.h * self.w, 1))
        s = self.seconds
        res.stages = {k: s[k] for k in ("decode", "solve", "fuse", "encode", "write", "align") if k in s}
        res.seconds = {"open": s.get("open", 0.0), "calibrate": s.get("calibrate", 0.0),
                       "fuse_and_write": time.perf_counter() - t2}
        return res


def _usage(msg: str):
    from hdrcl.errors import UsageError

    return UsageError(msg)


def _all_raw(paths) -> bool:
    from hdrcl.core.bracket import _all_raw as all_raw

    return all_raw(paths)


class Tee:
    """Hands every strip to several sinks (the file writer, a kept map, a preview)."""

    def __init__(self, *sinks):
        self.sinks = [s for s in sinks if s is not None]

    def write_rows(self, y0, y1, data):
        for s in self.sinks:
            s.write_rows(y0, y1, data)


def _warm_up(device, work=None):
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


def _kept_frames(source, grid):
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

