"""The merge engine on a bracket held in memory (:class:`MemoryJob`): :func:`hdrcl.merge`
and :func:`hdrcl.merge_bracket` run the same stages as a file merge
(:mod:`hdrcl.core.engine`) on an array source into an array sink."""
from __future__ import annotations

import time

import numpy as np

from hdrcl.core.agreement import check_job as check_agreement
from hdrcl.core.engine import Extras, MergeJob, _report_exposure_check, _warm_up
from hdrcl.core.options import MergeOptions
from hdrcl.core.pipeline import fusion_processor
from hdrcl.core.sources import Inputs, ResponseSource


class MemoryJob(MergeJob):
    """A merge of a loaded :class:`hdrcl.core.bracket.Bracket` into an array (no file): the
    same stages on an in-memory source (:class:`hdrcl.core.pipeline.ArraySource`) and an
    array sink. :func:`hdrcl.merge`, :func:`hdrcl.merge_bracket` run on it. The response
    is solved from the whole frames (they are in memory), as
    :func:`hdrcl.core.calibrate.calibrate` does with a bracket."""

    def __init__(self, bracket, options: MergeOptions, source: ResponseSource):
        inputs = Inputs(list(bracket.paths), list(bracket.infos), np.asarray(bracket.times, np.float64))
        super().__init__(inputs, options, source, None, Extras(keep_radiance=True))
        self.bracket = bracket

    def open(self) -> None:
        frames = self.bracket.frames
        self.h, self.w = frames[0].shape[:2]
        self.nch = frames[0].shape[2] if frames[0].ndim == 3 else 1
        self.work = self.h * self.w * len(frames)
        self.warm = _warm_up(self.options.device, self.work)

    def load(self) -> None:
        from hdrcl.core.pipeline import ArraySource

        br, o = self.bracket, self.options
        frames, valid = list(br.frames), list(br.valid)
        if o.align:
            from hdrcl.core.align.handheld import align_bracket

            with self.timed("align"):
                al = align_bracket(frames, valid, self.times, o.device, o.crop, o.align_model, br.paths or None,
                                   find=self.find)
            frames, valid = al.frames, al.valid
            if al.left_out:  # as the file merge does: merged without them, a finding names each
                self._leave_out(al.left_out)
            self.shifts, self.crop_box, self.alignment = al.shifts, al.crop, al.alignment
            self.h, self.w = frames[0].shape[:2]
        self.source = ArraySource(frames, valid)
        self.ignore = None  # the bracket's masks hold the ignore colour already

    def _leave_out(self, left_out) -> None:
        from dataclasses import replace

        from hdrcl.core.align.unaligned import without

        n = len(self.times)
        keep = [i for i in range(n) if i not in set(left_out)]
        if len(self.inputs.paths) == n and len(self.inputs.infos) == n:
            self.inputs = without(self.inputs, left_out)
        else:
            self.inputs = replace(self.inputs, times=np.asarray(self.times, np.float64)[keep])
        self.times = self.nominal = np.asarray(self.inputs.times, np.float64)

    def sample(self) -> None:
        from hdrcl.core.bracket import Bracket

        src = self.source
        self.grid = Bracket(frames=list(src.frames), times=self.times, valid=list(src.valid),
                            paths=self.inputs.paths, infos=self.inputs.infos)

    def fuse(self) -> None:
        from hdrcl.core.pipeline import ArraySink, FusionSpec, stream_merge
        from hdrcl.core.result import MergeResult

        o = self.options
        self.warm.join()
        self.processor = fusion_processor(o.device, self.work)
        self.keep, self.thumb = ArraySink(self.h, self.w, self.nch), None
        sink = self.keep
        if self.factors is not None:
            from hdrcl.core.radiometry import ScaledSink

            sink = ScaledSink(sink, self.factors)
        check = self._exposure_check()
        spec = FusionSpec(weight=o.weight, has_valid=self._has_valid(), device=o.device, deghost=o.deghost,
                          ghost_reference=o.ghost_reference, ghost_threshold=o.ghost_threshold,
                          seconds=self.seconds, work=self.work, processor=self.processor, exposure_check=check)
        self.counts, backend = stream_merge(self.source, self.times, self.response, sink, spec)
        self.result = MergeResult(radiance=None, response=self.response, counts=self.counts, times=self.times,
                                  paths=self.inputs.paths, backend=backend, shape=(self.h, self.w, self.nch),
                                  warnings=list(self.response.warnings) + self.notes, shifts=self.shifts,
                                  nominal=self.nominal, crop=self.crop_box, alignment=self.alignment)
        if check is not None:
            self.check_notes = _report_exposure_check(check, self.result, o.exposure_tolerance)

    def _has_valid(self) -> bool:
        return any(v is not None for v in self.source.valid)

    def run(self):
        t0 = time.perf_counter()
        self.prepare()
        check_agreement(self)
        self.scale()
        self.fuse()
        res = self.result
        res.findings = list(self.findings)
        res.warnings += [f.message for f in self.findings if f.message not in res.warnings]
        res.radiance = self.keep.array
        if self.counts.get("no_data"):
            res.warnings.append(f"{self.counts['no_data']} pixel-channels are invalid in every frame and were set to 0")
        res.stages = {k: v for k, v in self.seconds.items() if k in ("solve", "fuse", "align")}
        res.seconds = {"calibrate": self.seconds.get("calibrate", 0.0), "fuse": time.perf_counter() - t0}
        return res
