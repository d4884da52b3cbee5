"""A batch set's quality report: frames kept while they stream past, figures measured
after the EXR is committed, reports of skipped sets kept or rebuilt, the contact sheet.
"""
from __future__ import annotations

import logging
import os
from typing import List, Optional

import numpy as np

from hdrcl.core.response import Response
from hdrcl.errors import HdrclError
from hdrcl.shoot.batch.jobs import (
    _FUSE_LOCK,
    STATUS_FAILED,
    BatchOptions,
    SetJob,
    SetResult,
)
from hdrcl.shoot.batch.plan import _Plan
from hdrcl.shoot.batch.state import DIGEST_KEY, _atomic_json

logger = logging.getLogger(__name__)


# ----------------------------------------------------------------- quality report

#: Long side of the reduced radiance map the report is made from when no preview is written.
REPORT_IMAGE_SIZE = 512


def _quality_stride(n: int, h: int, w: int, nch: int, dtype) -> int:
    """The stride of the grid the set's quality figures are measured on
    (:func:`hdrcl.report.quality.report_stride`: at most half a megapixel a frame, as for
    ``hdrcl merge --report``): the frames are kept at that grid as they stream past, a few
    megabytes a set whatever the frame size, never whole."""
    from hdrcl.report.quality import report_stride

    return report_stride(h, w)


class _KeptFrames:
    """A :class:`hdrcl.io.reader.BracketReader` whose strips pass through unchanged while every
    ``stride``-th row and column of each frame (all of it for stride 1) is kept, so the
    quality figures need no second decode. Same grid as ``BracketReader.read_grid``."""

    def __init__(self, reader, stride: int):
        self._reader = reader
        self.stride = s = max(1, int(stride))
        hh, ww = len(range(0, reader.height, s)), len(range(0, reader.width, s))
        self._shape = (hh, ww)
        self.kept = [np.empty((hh, ww, reader.nch), reader.dtype) for _ in reader.paths]
        self.kept_valid: list = [None] * len(reader.paths)

    def __getattr__(self, name):
        return getattr(self._reader, name)

    def strips(self, rows: int):
        s = self.stride
        for y0, y1, frames, valid in self._reader.strips(rows):
            first = (-y0) % s
            g0 = (y0 + first) // s
            for k, (f, v) in enumerate(zip(frames, valid)):
                part = f[first::s, ::s]
                self.kept[k][g0:g0 + part.shape[0]] = part
                if v is not None:
                    if self.kept_valid[k] is None:
                        self.kept_valid[k] = np.ones(self._shape, bool)
                    self.kept_valid[k][g0:g0 + part.shape[0]] = v[first::s, ::s]
            yield y0, y1, frames, valid

    def bracket(self, files, infos, times, ignore_color):
        from hdrcl.core.bracket import Bracket, with_ignore

        return Bracket(frames=self.kept, times=np.asarray(times, np.float64),
                       valid=with_ignore(self.kept, self.kept_valid, ignore_color), paths=list(files),
                       infos=list(infos), grid=self.stride > 1)


def _report_stem(job: SetJob) -> str:
    return os.path.splitext(os.path.basename(job.output))[0]


def _quality_for(res: SetResult, job: SetJob, bracket, resp: Response, times, radiance, opts: BatchOptions) -> None:
    """Measure the set, write its report files and put the figures into ``res``.

    ``bracket`` is the frames merged or (``bracket.grid``) every k-th row and column of
    them, k found from the frames' width (:func:`_stride_of`).

    The figures' JSON is stamped with the set's digest, so that a later run that skips
    the set knows whether they describe its current output. A failure here is a
    warning: the merge itself succeeded.
    """
    from hdrcl.report.pages import file_stem, write_set_report
    from hdrcl.report.quality import decimate, measure

    try:
        stride = _stride_of(bracket)
        if stride == 1:  # whole frames (an aligned set's, as merged): measured on the report's grid all the same
            shape = bracket.frames[0].shape
            bracket, stride = decimate(bracket)
        else:
            info = bracket.infos[0]
            shape = (info.height, info.width, bracket.frames[0].shape[2])
        with _FUSE_LOCK:  # leave-one-out fuses on the process's OpenCL device
            fig = measure(bracket, resp, radiance, weight=opts.weight, times=times, device=opts.device,
                          stride=stride, shape=shape)
        stem = _report_stem(job)
        entry = write_set_report(opts.report_dir, stem, fig, resp, radiance, fig.coverage, warnings=res.warnings,
                                 bracket=bracket, deliverables=res.deliverables)
        payload = entry.to_dict()
        payload[DIGEST_KEY] = res.digest
        _atomic_json(os.path.join(opts.report_dir, file_stem(stem) + ".json"), payload)
        res.quality = fig.to_dict()
    except Exception as exc:
        if not isinstance(exc, (HdrclError, OSError, ValueError)):
            logger.debug("set %d: quality report failed", job.index, exc_info=exc)
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        res.warnings.append(f"quality report not written: {first}")


def _stride_of(bracket) -> int:
    """Every how many rows and columns of the frames merged ``bracket`` holds: 1 for whole
    frames, else from the frames' width in their headers and the grid's (``range(0, W, k)``
    has ``ceil(W / k)`` columns)."""
    if not getattr(bracket, "grid", False):
        return 1
    infos = getattr(bracket, "infos", None) or []
    width = getattr(infos[0], "width", None) if infos else None
    height = getattr(infos[0], "height", None) if infos else None
    gw = bracket.frames[0].shape[1]
    if not width or gw <= 0:
        return 1
    if height:
        from hdrcl.report.quality import report_stride

        k = report_stride(height, width)
        if -(-width // k) == gw:
            return k
    for k in range(max(1, width // gw - 1), width // gw + 2):
        if k >= 1 and -(-width // k) == gw:
            return k
    return max(1, round(width / gw))


def _current_quality(folder: str, job: SetJob, digest: Optional[str]) -> Optional[dict]:
    """The figures of a report written for this very output (same digest, every file
    present), or None."""
    from hdrcl.io.jsondoc import read_state
    from hdrcl.report.pages import REPORT_FORMAT, file_stem

    if digest is None:
        return None
    d = read_state(os.path.join(folder, file_stem(_report_stem(job)) + ".json"), "set report")
    if d is None or d.get("format") != REPORT_FORMAT or d.get(DIGEST_KEY) != digest:
        return None  # absent, damaged or stale: rebuilt
    files = d.get("files") or {}
    if not isinstance(files, dict) or not isinstance(d.get("figures"), dict) or not all(
            isinstance(f, str) and os.path.isfile(os.path.join(folder, f)) for f in files.values()):
        return None
    return d["figures"]


def _contact_sheet(plan: "_Plan", entries: List[dict], folder: str, unmerged: Optional[List[dict]] = None) -> str:
    """``index.html`` over every set of the manifest, in index order.

    ``entries`` are the report's (this run's and earlier runs' into the same folder).
    A set's figures and pictures come from the report folder when they describe its
    current output; failed sets show their reason; sets no run has handled yet are
    "pending"; ``unmerged`` (the manifest's groups that are no set) close the page.
    """
    from hdrcl.report.pages import ReportEntry, load_set_report, write_contact_sheet

    known = {e.get("index"): e for e in entries}
    cards = []
    for i in sorted(plan.jobs):
        job = plan.jobs[i]
        stem = _report_stem(job)
        e = known.get(i) or {}
        status = e.get("status")
        if status == STATUS_FAILED:
            cards.append(ReportEntry(stem, STATUS_FAILED, error=e.get("error") or "failed",
                                     warnings=list(e.get("warnings") or [])))
            continue
        card = None
        if status is None or _current_quality(folder, job, e.get("hash")) is not None:
            card = load_set_report(folder, stem)
        if card is None:
            card = ReportEntry(stem, status or "pending", warnings=list(e.get("warnings") or []))
            if status is not None:
                card.warnings.append("no quality figures for this output: run the batch again with --report")
        elif status is not None:
            card.status = status
        cards.append(card)
    return write_contact_sheet(folder, cards, unmerged=unmerged)
