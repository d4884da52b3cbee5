"""What a running merge has found so far: the executor's :class:`RunState`, handed to each
stage (:mod:`hdrcl.core.stages`, :mod:`hdrcl.core.fusestage`). The plan it runs
(:class:`hdrcl.core.plan.MergePlan`) never changes; this does."""
from __future__ import annotations

import contextlib
import logging
import time
from typing import List

import numpy as np

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


class RunState(Timed):
    """One merge in progress. Set by the stages in order: the image's size and backend
    warm-up (open), the frame source and alignment (load), the sampling grid (sample), the
    response (respond), the exposures used (measure), the radiometric factors (scale), the
    result, writer and sinks (fuse). ``inputs`` is the plan's unless an alignment left
    frames out."""

    def __init__(self, plan):
        super().__init__()
        self.t0 = time.perf_counter()
        self.plan = plan
        self.inputs, self.options, self.output = plan.inputs, plan.options, plan.output
        self.responses = plan.response.source
        self.chain = plan.extras.chain
        self.response = self.responses.given()
        self.own = self.responses.own and self.response is None  # calibrated here (or RAW: linear)
        self.source_name = self.responses.name
        self.times = self.nominal = np.asarray(self.inputs.times, np.float64)
        self.h = self.w = self.nch = self.work = None
        self.warm = self.grid = self.source = None
        self.ignore = self.options.ignore_color  # masked in the fusion; None once the valid masks hold it
        self.shifts = self.crop_box = self.alignment = None
        self.notes: List[str] = []  # on the exposures measured
        self.check_notes: List[str] = []  # on the exposures checked against a given response
        self.write_warnings: List[str] = []
        self.findings: list = []  # hdrcl.core.findings.Finding, from every stage (see find())
        self.factors, self.units = None, {"units": "relative"}
        self.processor = self.result = self.writer = self.stored = self.staged = None
        self.counts: dict = {}
        self.sinks: dict = {}  # the plan's named sinks, made by the fusion stage
        self.keep = self.thumb = self.mask = self.clips = self.tapped = None
        self.unit, self.t_ref, self.t_fuse = "relative", None, None

    def find(self, finding) -> None:
        """Record what a check found (:class:`hdrcl.core.findings.Finding`): logged as a
        warning now, and carried on the result (its ``findings`` and ``warnings``)."""
        if any(f.message == finding.message for f in self.findings):
            return
        logger.warning("%s", finding.message)
        self.findings.append(finding)

    def close(self) -> None:
        """The frame source closed (its reader, its scratch file)."""
        if hasattr(self.source, "close"):
            self.source.close()
