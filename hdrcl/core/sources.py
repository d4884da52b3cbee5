"""What a merge starts from: its inputs (:class:`Inputs`: frames, headers, exposures and
where they came from) and where its response comes from (:class:`ResponseSource`: solved
from the frames, or given), for a merge's plan (:mod:`hdrcl.core.plan`)."""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import List, Optional

import numpy as np


@dataclass
class Inputs:
    """The frames of one merge: paths, headers and each frame's exposure relative to a
    reference f-number and ISO (the first frame's, or a batch's shoot reference)."""

    paths: List[str]
    infos: list
    times: np.ndarray
    reference: Optional[tuple] = None  # (f-number, ISO) the times are relative to; None: the first frame's
    reference_exposure: Optional[float] = None  # seconds that 1.0 stands for; None: the options'
    timestamp: Optional[str] = None
    times_from: Optional[str] = None  # where the times came from, when not the frames' EXIF (a list, --times)

    def labels(self) -> Optional[List[str]]:
        """Each frame's settings as its camera recorded them (``1/4000 s f/1.4 ISO 1600``),
        for messages, where ``times`` are equivalents on another reference (a batch's
        shoot-wide f-number and ISO); None where the times are the frames' own."""
        from hdrcl.io.metadata import format_time

        if self.reference is None or not all(i.exposure_time for i in self.infos):
            return None
        return [" ".join([format_time(float(i.exposure_time))] + ([f"f/{float(i.fnumber):g}"] if i.fnumber else [])
                         + ([f"ISO {float(i.iso):g}"] if i.iso else [])) for i in self.infos]

    @classmethod
    def open(cls, paths, times=None, times_file=None) -> "Inputs":
        """Headers and exposures of ``paths`` (EXIF, ``times`` or a times file)."""
        from hdrcl.core.bracket import _open_files

        paths, infos, rel = _open_files(paths, times, times_file)
        first = infos[0]
        stamp = first.capture_time.strftime("%Y:%m:%d %H:%M:%S") if first.capture_time else None
        return cls(list(paths), list(infos), np.asarray(rel, np.float64), timestamp=stamp,
                   times_from=times_source(paths, infos, times, times_file))


def times_source(paths, infos, times=None, times_file=None) -> Optional[str]:
    """Where a set's exposure times come from when not from its frames' EXIF: the times
    file, ``--times``, or the exposure list found beside the frames; None for EXIF."""
    if times_file is not None:
        return os.fspath(times_file)
    if times is not None:
        return "--times"
    try:
        from hdrcl.io.metadata import header_exposures

        used = header_exposures(paths, infos)[1]
    except Exception:  # the lists were read already: whatever went wrong was said then
        return None
    return used[0] if used else None


def check_brightness_order(grid, times, inputs: "Inputs") -> None:
    """InputError naming the list when the frames' brightness falls as their exposure
    times rise (a times list given backwards): no curve makes that a bracket."""
    from hdrcl.errors import InputError

    times = np.asarray(times, np.float64)
    if times.size < 2 or np.unique(times).size != times.size:
        return
    ok = None
    for v in grid.valid:
        if v is not None:
            ok = v.copy() if ok is None else ok & v
    means = []
    use = ok is not None and bool(ok.any())
    for f in grid.frames:
        # Exact integer sums (no float64 copy of the frame): the mean over pixels of the channels' sum.
        z = f[ok] if use else f.reshape(-1, f.shape[-1])
        means.append(float(z.sum(dtype=np.uint64 if z.dtype.kind in "ub" else np.float64)) / max(z.shape[0], 1))
    order = np.argsort(times, kind="stable")
    if np.all(np.diff(np.asarray(means)[order]) < 0):
        where = inputs.times_from
        if where is None:  # a batch's set: the list beside its frames, if they have no EXIF times
            from hdrcl.core.bracket import read_infos

            where = times_source(inputs.paths, read_infos(inputs.paths))
        where = where or os.path.basename(inputs.paths[int(order[-1])])
        raise InputError(f"{where}: the exposure times run in reverse order of the frames' brightness "
                         f"(the {len(times)} frames get darker as their times grow); check the times")


class ResponseSource:
    """Where a merge's response comes from. This one: calibrated from the frames themselves
    (:func:`hdrcl.core.calibrate.calibrate` on the sampling grid, exposures refined)."""

    name = "calibrated from these frames"
    #: The curve comes from a solve on this set's grid.
    solves = True
    #: The solve also fitted the set's exposures (no separate measurement after it).
    own = True
    #: RAW frames (linear already) take a linear response instead of a solve.
    raw_linear = True

    def given(self):
        return None

    def solve(self, job: "RunState", grid):
        from hdrcl.core.calibrate import calibrate

        o = job.options
        return calibrate(grid, samples=o.samples, smoothness=o.smoothness, weight=o.weight, seed=o.seed,
                         fit_exposures=o.fit_exposures, exposure_tolerance=o.exposure_tolerance)


class GivenResponse(ResponseSource):
    """A response given as an object or file (or a batch's pooled or cached curve): its
    exposures are measured through it, or checked against it with ``fit_exposures=off``."""

    solves = False
    own = False

    def __init__(self, response, name: str):
        self.response, self.name = response, name

    def given(self):
        return self.response


def response_source(response) -> ResponseSource:
    """The source for a ``response`` argument: None (calibrate), a Response or a path."""
    from hdrcl.core.response import as_response

    resp = as_response(response)
    if resp is None:
        return ResponseSource()
    name = os.fspath(response) if isinstance(response, (str, os.PathLike)) else "given"
    return GivenResponse(resp, name)
