"""The quality report: figures and pictures per merged set, and an HTML contact sheet.

For each set, :func:`write_set_report` writes into a report folder::

    <name>-preview.jpg      a tone-mapped preview (Reinhard 2002, :mod:`hdrcl.report.tonemap`)
    <name>-frame-NN.jpg     thumbnails of the input frames, shortest exposure first
    <name>-response.svg     the response curves g(z) per channel, with the working range
    <name>-histogram.svg    the luminance histogram with the clip points
    <name>-coverage.png     how many frames measure each pixel (legend on the page)
    <name>.json             the figures of :func:`hdrcl.report.quality.measure`, the camera
                            settings and the frames

and :func:`write_contact_sheet` writes ``index.html`` (:mod:`hdrcl.report.sheet`): one
card per set (failed sets too, with their reason) and the frames a batch did not merge,
with theirs. Each card's figures are coloured pass / warn / fail by the thresholds of
:mod:`hdrcl.report.verdicts` (listed in the page's header); a set a batch skipped
because its output was current is "up to date", with the figures measured for that
output. A folder accumulates sets: ``merge --report DIR`` run twice shows both sets
(:func:`load_report_folder`). The page is static and self-contained (inline CSS,
relative links; the folder can be moved or served as is), every text is HTML-escaped,
and every file is written atomically.

The plots are SVG (:mod:`hdrcl.report.svg`): the browser sets their text in its own
fonts, so the report needs no plotting library.
"""
from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Union

import numpy as np

from hdrcl.core.response import Response
from hdrcl.report.inputs import file_stem
from hdrcl.report.plots import IMAGE_SIZE, coverage_image, histogram_svg, response_svg
from hdrcl.report.quality import QualityFigures
from hdrcl.report.sheet import (
    STATUS_DONE,
    STATUS_FAILED,
    STATUS_LABELS,
    STATUS_SKIPPED,
    format_ev,
    format_figures,
    status_label,
)

__all__ = ["ReportEntry", "file_stem", "write_set_report", "load_set_report", "load_report_folder",
           "write_contact_sheet", "format_figures", "format_ev", "INDEX_NAME", "REPORT_FORMAT",
           "STATUS_DONE", "STATUS_SKIPPED", "STATUS_FAILED", "STATUS_LABELS", "status_label"]

logger = logging.getLogger(__name__)


#: File name of the contact sheet.
INDEX_NAME = "index.html"


#: ``format`` of the per-set JSON files.
REPORT_FORMAT = "hdrcl-quality"


REPORT_VERSION = 1


@dataclass
class ReportEntry:
    """One set of the contact sheet.

    ``files`` maps ``preview``, ``response``, ``histogram``, ``coverage``, ``json`` to
    file names relative to the report folder (those written). ``camera`` holds the
    settings of :func:`hdrcl.report.inputs.camera_summary`, ``inputs`` one row per frame
    with its thumbnail (:func:`hdrcl.report.inputs.write_inputs`). A failed set has
    ``status`` "failed", its ``error`` and usually no figures. ``status`` keeps the
    batch's values (``done``, ``skipped``, ``failed``, ``pending``); the JSON adds
    ``label``, the words the page shows (:func:`status_label`: ``skipped`` is "up to
    date").
    """

    name: str
    status: str = STATUS_DONE
    figures: Optional[QualityFigures] = None
    files: Dict[str, str] = field(default_factory=dict)
    warnings: List[str] = field(default_factory=list)
    error: Optional[str] = None
    camera: Dict[str, str] = field(default_factory=dict)
    inputs: List[dict] = field(default_factory=list)
    #: ``--deliver`` pictures beside the set's map: ``kind``, ``file`` (relative to the report
    #: folder), ``bytes``.
    deliverables: List[dict] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"format": REPORT_FORMAT, "version": REPORT_VERSION, "name": self.name, "status": self.status,
                "label": status_label(self.status), "error": self.error, "warnings": list(self.warnings),
                "files": dict(self.files),
                "camera": dict(self.camera), "inputs": [dict(r) for r in self.inputs],
                "deliverables": [dict(d) for d in self.deliverables],
                "figures": None if self.figures is None else self.figures.to_dict()}


# --------------------------------------------------------------------------- files
def _write_json(path: str, obj) -> None:
    from hdrcl.io.atomic import atomic_output

    with atomic_output(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(obj, f, indent=2, allow_nan=False)
            f.write("\n")


def _write_text(path: str, text: str) -> None:
    from hdrcl.io.atomic import atomic_output

    with atomic_output(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)


def alignment_text(a: dict) -> str:
    """A frame's alignment in a few words: ``similarity 0.42° ×1.003, residual 0.08 px``."""
    model = a.get("model", "?")
    if model in ("reference", "none"):
        return "reference" if model == "reference" else "not moved"
    res = a.get("residual_px")
    parts = [model]
    if model in ("similarity", "homography"):
        parts.append(f"{float(a.get('rotation_deg', 0.0)):+.2f}° ×{float(a.get('scale', 1.0)):.4f}")
    dy, dx = a.get("shift_px") or (0.0, 0.0)
    parts.append(f"({float(dy):+.1f}, {float(dx):+.1f}) px")
    parts.append("residual ?" if res is None else f"residual {float(res):.2f} px")
    return " ".join(parts)


def write_set_report(
    folder: Union[str, os.PathLike],
    name: str,
    figures: QualityFigures,
    response: Optional[Response],
    preview: Optional[np.ndarray] = None,
    coverage: Optional[np.ndarray] = None,
    *,
    warnings: Sequence[str] = (),
    status: str = STATUS_DONE,
    preview_size: int = IMAGE_SIZE,
    bracket=None,
    alignment=None,
    deliverables: Sequence[dict] = (),
) -> ReportEntry:
    """Write one set's report files into ``folder`` and return its contact-sheet entry.

    Parameters
    ----------
    folder : path
        Report folder (created if missing).
    name : str
        The set's name; files are named after :func:`file_stem` of it.
    figures : QualityFigures
        From :func:`hdrcl.report.quality.measure`.
    response : Response or None
        The curve the merge used (None: no response plot, no clip points).
    preview : ndarray, optional
        Either the radiance map (or a decimated copy such as ``MergeResult.thumbnail``),
        float: tone-mapped here with :func:`hdrcl.report.preview.preview`, and its
        luminance histogram drawn; or a ready 8-bit preview, uint8, written as is.
    coverage : ndarray (H, W) uint8, optional
        Default ``figures.coverage``; none: no coverage map.
    warnings : sequence of str
        Shown on the set's card (the merge's warnings).
    bracket : Bracket, optional
        The frames measured: their thumbnails and camera settings go on the card.
    alignment : list of dict, optional
        ``MergeResult.alignment`` of an aligned merge: each frame's motion model and
        residual misalignment go under its thumbnail.
    deliverables : sequence of dict, optional
        The ``--deliver`` records (``kind``, ``path``, ``bytes``): linked from the card.
    """
    from hdrcl.io.ldr import write_ldr
    from hdrcl.report.inputs import camera_summary, write_inputs

    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    stem = file_stem(name)
    files: Dict[str, str] = {}
    if response is not None:
        files["response"] = stem + "-response.svg"
        _write_text(os.path.join(folder, files["response"]), response_svg(response))
    if preview is not None and np.asarray(preview).dtype.kind == "f":
        used = [e.get("used") for e in figures.exposures] if figures.exposures else None
        files["histogram"] = stem + "-histogram.svg"
        _write_text(os.path.join(folder, files["histogram"]),
                    histogram_svg(preview, response, used if used and None not in used else None))
    cov = figures.coverage if coverage is None else coverage
    if cov is not None:
        files["coverage"] = stem + "-coverage.png"
        write_ldr(os.path.join(folder, files["coverage"]), coverage_image(cov, figures.frames))
    if preview is not None:
        img = np.asarray(preview)
        if img.dtype != np.uint8:
            from hdrcl.report.preview import preview as tone_mapped

            img = tone_mapped(img, preview_size)
        files["preview"] = stem + "-preview.jpg"
        write_ldr(os.path.join(folder, files["preview"]), img, metadata={"tonemap": "reinhard"})
    camera, inputs = {}, []
    if bracket is not None:
        camera = camera_summary(getattr(bracket, "infos", None) or [])
        inputs = write_inputs(folder, stem, bracket)
        moved = {os.path.basename(a["file"]): a for a in (alignment or []) if isinstance(a, dict) and "file" in a}
        for row in inputs:
            if row.get("file") in moved:
                row["align"] = alignment_text(moved[row["file"]])
    files["json"] = stem + ".json"
    delivered = [{"kind": d["kind"], "file": os.path.relpath(d["path"], folder), "bytes": int(d.get("bytes", 0))}
                 for d in deliverables if d.get("path")]
    entry = ReportEntry(name=name, status=status, figures=figures, files=files, warnings=list(warnings),
                        camera=camera, inputs=inputs, deliverables=delivered)
    _write_json(os.path.join(folder, files["json"]), entry.to_dict())
    return entry


def _entry_from_dict(d: dict, folder: str, name: str) -> ReportEntry:
    figs = None if d.get("figures") is None else QualityFigures.from_dict(d["figures"])
    files = {k: v for k, v in (d.get("files") or {}).items() if os.path.isfile(os.path.join(folder, v))}
    inputs = [r for r in (d.get("inputs") or []) if isinstance(r, dict)]
    for r in inputs:
        if r.get("thumb") and not os.path.isfile(os.path.join(folder, r["thumb"])):
            r["thumb"] = None
    return ReportEntry(name=d.get("name", name), status=d.get("status", STATUS_DONE), figures=figs,
                       files=files, warnings=list(d.get("warnings") or []), error=d.get("error"),
                       camera=dict(d.get("camera") or {}), inputs=inputs,
                       deliverables=[x for x in (d.get("deliverables") or []) if isinstance(x, dict)
                                     and isinstance(x.get("file"), str) and isinstance(x.get("kind"), str)])


#: What a damaged entry can raise while it is rebuilt or drawn (it is then skipped).
_DAMAGED = (KeyError, TypeError, ValueError, AttributeError, IndexError, OverflowError)


def _load_entry(path: str, folder: str, name: str) -> Optional[ReportEntry]:
    """The entry stored at ``path``, or None when it is absent, another kind of JSON or
    damaged in any way (read through :func:`hdrcl.io.jsondoc.read_state`; logged, never
    an error: the page is drawn without it)."""
    from hdrcl.io.jsondoc import read_state
    from hdrcl.report.sheet import _card

    d = read_state(path, "set report")
    if d is None or d.get("format") != REPORT_FORMAT:
        return None
    try:
        if not isinstance(d.get("name", name), str) or not isinstance(d.get("status", STATUS_DONE), str) \
                or not isinstance(d.get("error") or "", str) \
                or not all(isinstance(w, str) for w in d.get("warnings") or []):
            raise TypeError("name, status, error and warnings must be text")
        entry = _entry_from_dict(d, folder, name)
        _card(entry, 0)  # an entry the page cannot draw is as good as absent
    except _DAMAGED as exc:
        logger.info("%s: damaged set report (%s: %s); left out", path, type(exc).__name__,
                    str(exc).splitlines()[0] if str(exc) else "")
        return None
    return entry


def load_set_report(folder: Union[str, os.PathLike], name: str) -> Optional[ReportEntry]:
    """The entry :func:`write_set_report` wrote for ``name`` earlier, or None if absent
    or unreadable (for sets a batch skipped because their output was current)."""
    folder = os.fspath(folder)
    return _load_entry(os.path.join(folder, file_stem(name) + ".json"), folder, name)


def load_report_folder(folder: Union[str, os.PathLike]) -> List[ReportEntry]:
    """Every set report in ``folder`` (any run's), sorted by name; unreadable or damaged
    ones skipped (logged)."""
    folder = os.fspath(folder)
    out = []
    try:
        names = sorted(os.listdir(folder))
    except OSError:
        return out
    for fn in names:
        if not fn.endswith(".json") or fn.startswith("."):
            continue
        entry = _load_entry(os.path.join(folder, fn), folder, fn[:-5])
        if entry is not None:
            out.append(entry)
    return sorted(out, key=lambda e: e.name)


def write_contact_sheet(folder: Union[str, os.PathLike], entries: Sequence[ReportEntry],
                        title: str = "hdrcl quality report", unmerged: Optional[Sequence[dict]] = None) -> str:
    """Write ``index.html`` into ``folder``: one card per entry, in the order given, then
    the frames that were not merged.

    Each card shows the preview, the camera settings, the input frames, the figures
    (:func:`format_figures`), the response, histogram and coverage plots, the exposures
    and the warnings, or a failed set's error. ``unmerged`` lists groups of files a
    batch did not merge (``{"files": [...], "reason": ...}``); they are shown with
    thumbnails and the reason (:func:`hdrcl.report.inputs.write_unmerged`). Images are
    linked relative to the folder. Returns the page's path.
    """
    from hdrcl.report.inputs import write_unmerged
    from hdrcl.report.sheet import contact_sheet_html

    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, INDEX_NAME)
    groups = write_unmerged(folder, unmerged or [])
    _write_text(path, contact_sheet_html(entries, title, groups))
    return path
