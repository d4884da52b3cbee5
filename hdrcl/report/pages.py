"""The quality report: figures and pictures per merged set, and an HTML contact sheet.

For each set, :func:`write_set_report` writes into a report folder::

    <name>-response.png   the response curves g(z) per channel, with the working range
    <name>-coverage.png   how many frames measure each pixel, with a legend strip
    <name>-preview.jpg    a tone-mapped preview (Reinhard 2002, :mod:`hdrcl.report.preview`)
    <name>.json           the figures of :func:`hdrcl.report.quality.measure`

and :func:`write_contact_sheet` writes ``index.html``: one card per set (failed sets
too, with their reason) showing the preview, the figures and the two plots. The page is
static and self-contained (inline CSS, relative links; the folder can be moved or
served as is), every text is HTML-escaped, and every file is written atomically.

The plots are rasterised here with NumPy (lines, ticks and a 3x5 pixel font) and
written with :func:`hdrcl.io.writers.write_ldr`, so the report needs no plotting library.
"""
from __future__ import annotations

import html
import json
import logging
import os
import re
import urllib.parse
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Union

import numpy as np

from hdrcl.core.response import Response
from hdrcl.report.plots import IMAGE_SIZE, coverage_image, response_plot
from hdrcl.report.quality import QualityFigures

logger = logging.getLogger(__name__)


#: File name of the contact sheet.
INDEX_NAME = "index.html"


#: ``format`` of the per-set JSON files.
REPORT_FORMAT = "hdrcl-quality"


REPORT_VERSION = 1


STATUS_DONE, STATUS_SKIPPED, STATUS_FAILED = "done", "skipped", "failed"


@dataclass
class ReportEntry:
    """One set of the contact sheet.

    ``files`` maps ``response``, ``coverage``, ``preview``, ``json`` to file names
    relative to the report folder (those written). A failed set has ``status`` "failed",
    its ``error`` and usually no figures.
    """

    name: str
    status: str = STATUS_DONE
    figures: Optional[QualityFigures] = None
    files: Dict[str, str] = field(default_factory=dict)
    warnings: List[str] = field(default_factory=list)
    error: Optional[str] = None

    def to_dict(self) -> dict:
        return {"format": REPORT_FORMAT, "version": REPORT_VERSION, "name": self.name, "status": self.status,
                "error": self.error, "warnings": list(self.warnings), "files": dict(self.files),
                "figures": None if self.figures is None else self.figures.to_dict()}


def file_stem(name: str) -> str:
    """A file-name-safe stem for a set name (letters, digits, ``._-``; no leading dot)."""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", str(name)).lstrip(".")
    return stem or "set"


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
        The curve the merge used (None: no response plot).
    preview : ndarray, optional
        Either the radiance map (or a decimated copy such as ``MergeResult.thumbnail``),
        float: tone-mapped here with :func:`hdrcl.report.preview.preview`; or a ready 8-bit
        preview, uint8, written as is.
    coverage : ndarray (H, W) uint8, optional
        Default ``figures.coverage``; none: no coverage map.
    warnings : sequence of str
        Shown on the set's card (the merge's warnings).
    """
    from hdrcl.io.writers import write_ldr

    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    stem = file_stem(name)
    files: Dict[str, str] = {}
    if response is not None:
        files["response"] = stem + "-response.png"
        write_ldr(os.path.join(folder, files["response"]), response_plot(response))
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
    files["json"] = stem + ".json"
    entry = ReportEntry(name=name, status=status, figures=figures, files=files, warnings=list(warnings))
    _write_json(os.path.join(folder, files["json"]), entry.to_dict())
    return entry


def load_set_report(folder: Union[str, os.PathLike], name: str) -> Optional[ReportEntry]:
    """The entry :func:`write_set_report` wrote for ``name`` earlier, or None if absent
    or unreadable (for sets a batch skipped because their output was current)."""
    path = os.path.join(os.fspath(folder), file_stem(name) + ".json")
    try:
        with open(path, encoding="utf-8") as f:
            d = json.load(f)
        if d.get("format") != REPORT_FORMAT:
            return None
        figs = None if d.get("figures") is None else QualityFigures.from_dict(d["figures"])
        files = {k: v for k, v in (d.get("files") or {}).items()
                 if os.path.isfile(os.path.join(os.fspath(folder), v))}
        return ReportEntry(name=d.get("name", name), status=d.get("status", STATUS_DONE), figures=figs,
                           files=files, warnings=list(d.get("warnings") or []), error=d.get("error"))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        logger.debug("no usable report for %s at %s: %s", name, path, exc)
        return None


# --------------------------------------------------------------------------- contact sheet
def _fmt_time(t: Optional[float]) -> str:
    if t is None:
        return "–"
    from hdrcl.io.metadata import format_time

    return format_time(float(t))


def _fmt_fitted(fitted: Optional[float], nominal: Optional[float]) -> str:
    if fitted is None:
        return "–"
    if not nominal:
        return _fmt_time(fitted)
    return f"{_fmt_time(fitted)} ({np.log2(float(fitted) / float(nominal)):+.2f} EV)"


def format_ev(value: float, side: str) -> str:
    """``extra_ev_high`` / ``extra_ev_low`` in words: "at least -2.3 EV from the shortest
    frame" (they are bounds, see :func:`hdrcl.report.quality.measure`)."""
    if value == 0:
        return "none needed"
    frame = "shortest" if side == "high" else "longest"
    return f"at least {value:+.1f} EV from the {frame} frame"


def format_figures(figures: QualityFigures) -> List[tuple]:
    """``(label, text)`` rows of a set's figures, as the contact sheet shows them."""
    f = figures
    if f.loo_rmse is None or not np.isfinite(f.loo_rmse):
        loo = "not measured" if f.frames >= 3 else "not measured (fewer than 3 frames)"
    else:
        per = ", ".join("–" if not np.isfinite(r.rmse) else f"{r.rmse:.2f}" for r in f.loo)
        grid = "every pixel" if f.loo_stride == 1 else f"every {f.loo_stride}th pixel"
        loo = f"{f.loo_rmse:.2f} levels (median of {len(f.loo)} interior frames: {per}; {grid})"
    if f.dynamic_range_stops is None:
        dr = "–"
    else:
        p0, p1 = f.dynamic_range_percentiles
        dr = (f"{'at least ' if f.dynamic_range_is_lower_bound else ''}{f.dynamic_range_stops:.1f} stops "
              f"(luminance P{p0:g} to P{p1:g})")
    return [
        ("Leave-one-out RMSE", loo),
        ("Dynamic range", dr),
        ("Clipped high", f"{100 * f.clipped_high_fraction:.2f} % of pixels"),
        ("Clipped low", f"{100 * f.clipped_low_fraction:.2f} % of pixels"),
        ("Extra exposure for highlights", format_ev(f.extra_ev_high, "high")),
        ("Extra exposure for shadows", format_ev(f.extra_ev_low, "low")),
        ("Frames", f"{f.frames} × {f.shape[1]}×{f.shape[0]}, {f.bits}-bit, {f.weight} weights"),
    ]


_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0;background:#f4f4f2;color:#222}
header{padding:16px 24px;background:#fff;border-bottom:1px solid #ddd}
h1{font-size:1.4em;margin:0 0 4px}
.summary,#image-check{margin:2px 0;color:#555}
main{display:grid;grid-template-columns:repeat(auto-fill,minmax(420px,1fr));gap:16px;padding:16px 24px}
article{background:#fff;border:1px solid #ddd;border-radius:6px;padding:12px 14px}
article.failed{border-color:#d33;background:#fff6f6}
h2{font-size:1.1em;margin:0 0 8px;word-break:break-all}
.status{font-size:.8em;padding:1px 6px;border-radius:3px;background:#e6f2e6;margin-left:6px;vertical-align:middle}
article.failed .status{background:#f8d0d0}
.thumb{display:block;width:100%;max-width:512px;height:auto;margin:0 0 8px;background:#000}
table{border-collapse:collapse;font-size:.9em;width:100%}
th,td{text-align:left;vertical-align:top;padding:2px 6px 2px 0}
th{font-weight:600;white-space:nowrap;color:#444}
.plots{display:flex;gap:8px;flex-wrap:wrap;margin-top:8px}
figure{margin:0;flex:1 1 180px}
figure img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{font-size:.8em;color:#666}
.error{color:#a00;white-space:pre-wrap}
.warnings{color:#8a5a00;font-size:.85em;padding-left:18px}
details{margin-top:6px;font-size:.9em}
img.broken{outline:3px solid #d33}
""".strip()


# Counts the images that really decoded once the page has loaded: the count is shown
# in the header (a moved or incomplete report folder is spotted at a glance) and kept
# in data-loaded / data-total, which the browser test reads back.
_SCRIPT = """
window.addEventListener("load", function () {
  var imgs = document.images, n = 0;
  for (var i = 0; i < imgs.length; i++) {
    if (imgs[i].complete && imgs[i].naturalWidth > 0) { n++; } else { imgs[i].classList.add("broken"); }
  }
  var el = document.getElementById("image-check");
  el.setAttribute("data-loaded", String(n));
  el.setAttribute("data-total", String(imgs.length));
  el.textContent = n + " of " + imgs.length + " images loaded";
});
""".strip()


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def _href(filename: str) -> str:
    return _e(urllib.parse.quote(filename))


def _card(entry: ReportEntry, index: int) -> str:
    status = entry.status or STATUS_DONE
    out = [f'<article class="set {_e(status)}" id="set-{index}" data-set="{_e(entry.name)}" '
           f'data-status="{_e(status)}">',
           f'<h2>{_e(entry.name)}<span class="status">{_e(status)}</span></h2>']
    files = entry.files or {}
    if "preview" in files:
        out.append(f'<a href="{_href(files["preview"])}"><img class="thumb" src="{_href(files["preview"])}" '
                   f'alt="{_e(entry.name)}: tone-mapped preview (Reinhard 2002)"></a>')
    if entry.error:
        out.append(f'<p class="error">{_e(entry.error)}</p>')
    f = entry.figures
    if f is not None:
        out.append('<table class="figures">')
        for label, text in format_figures(f):
            out.append(f"<tr><th>{_e(label)}</th><td>{_e(text)}</td></tr>")
        out.append("</table>")
    plots = []
    if "response" in files:
        plots.append(f'<figure><a href="{_href(files["response"])}"><img src="{_href(files["response"])}" '
                     f'alt="{_e(entry.name)}: response curves"></a><figcaption>Response g(z) = ln exposure '
                     f'per channel</figcaption></figure>')
    if "coverage" in files:
        plots.append(f'<figure><a href="{_href(files["coverage"])}"><img src="{_href(files["coverage"])}" '
                     f'alt="{_e(entry.name)}: coverage map"></a><figcaption>Frames measuring each pixel '
                     f'(red: none, clipped)</figcaption></figure>')
    if plots:
        out.append('<div class="plots">' + "".join(plots) + "</div>")
    if f is not None and f.exposures:
        out.append("<details><summary>Exposures (relative seconds)</summary><table>"
                   "<tr><th>frame</th><th>nominal</th><th>fitted</th><th>used</th></tr>")
        for k, ex in enumerate(f.exposures):
            cells = (ex.get("file", k), _fmt_time(ex.get("nominal")),
                     _fmt_fitted(ex.get("fitted"), ex.get("nominal")), _fmt_time(ex.get("used")))
            out.append("<tr>" + "".join(f"<td>{_e(v)}</td>" for v in cells) + "</tr>")
        out.append("</table></details>")
    if entry.warnings:
        out.append('<ul class="warnings">' + "".join(f"<li>{_e(w)}</li>" for w in entry.warnings) + "</ul>")
    if "json" in files:
        out.append(f'<p><a href="{_href(files["json"])}">figures (JSON)</a></p>')
    out.append("</article>")
    return "\n".join(out)


def _unmerged_html(unmerged) -> str:
    """The frames no set holds, each group with its reason."""
    if not unmerged:
        return ""
    items = []
    for u in unmerged:
        files = [os.path.basename(f) for f in u.get("files", [])]
        more = f" (+{len(files) - 1} more)" if len(files) > 1 else ""
        items.append(f"<li>{_e(files[0] if files else '?')}{_e(more)}: {_e(u.get('reason', ''))}</li>")
    return (f'<section class="unmerged" id="unmerged"><h2>Not merged ({len(unmerged)})</h2><ul>'
            + "".join(items) + "</ul></section>\n")


def contact_sheet_html(entries: Sequence[ReportEntry], title: str = "hdrcl quality report",
                       unmerged: Sequence[dict] = ()) -> str:
    """The contact sheet page for ``entries`` (see :func:`write_contact_sheet`)."""
    from hdrcl.version import __version__

    entries = list(entries)
    failed = sum(1 for e in entries if e.status == STATUS_FAILED)
    merged = sum(1 for e in entries if e.status == STATUS_DONE)
    skipped = sum(1 for e in entries if e.status == STATUS_SKIPPED)
    other = len(entries) - failed - merged - skipped
    summary = (f"{len(entries)} set{'s' if len(entries) != 1 else ''}: {merged} merged, "
               + (f"{skipped} skipped (up to date), " if skipped else "") + f"{failed} failed"
               + (f", {other} pending" if other else "")
               + (f"; {sum(len(u.get('files', [])) for u in unmerged)} frame(s) not merged" if unmerged else ""))
    cards = "\n".join(_card(e, i) for i, e in enumerate(entries))
    return (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
        f"<title>{_e(title)}</title>\n<style>\n{_CSS}\n</style>\n</head>\n<body>\n"
        f"<header><h1>{_e(title)}</h1><p class=\"summary\">{_e(summary)} · hdrcl {_e(__version__)}</p>"
        f"<p id=\"image-check\" data-loaded=\"\" data-total=\"\"></p></header>\n"
        f"<main>\n{cards}\n{_unmerged_html(list(unmerged))}</main>\n<script>\n{_SCRIPT}\n</script>\n</body>\n</html>\n")


def write_contact_sheet(folder: Union[str, os.PathLike], entries: Sequence[ReportEntry],
                        title: str = "hdrcl quality report", unmerged: Sequence[dict] = ()) -> str:
    """Write ``index.html`` into ``folder``: one card per entry, in the order given.

    Each card shows the preview, the figures (:func:`format_figures`), the response and
    coverage plots, the exposures and the warnings, or a failed set's error. Images
    are linked relative to the folder. Returns the page's path.
    """
    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, INDEX_NAME)
    _write_text(path, contact_sheet_html(entries, title, unmerged))
    return path
