"""The contact sheet's HTML (``index.html``) and the figures in words.

One card per set: name, status (in words: a batch's "skipped" is "up to date") and the
worst verdict of its figures with its causes (each figure, its value and the limit it passed),
camera settings, the tone-mapped preview, the input frames
with each one's settings as its camera recorded them, the figures coloured pass / warn /
fail (:mod:`hdrcl.report.verdicts`, whose thresholds the header lists), the response and
histogram charts and the coverage map, the exposures, the warnings; failed sets with
their error; then the frames a batch did not merge, with the reason. A page of one set
lays the card out across the page's width. Every text is HTML-escaped and every link
relative.
"""
from __future__ import annotations

import html
import urllib.parse
from typing import List, Optional, Sequence

import numpy as np

from hdrcl.report.plots import coverage_legend
from hdrcl.report.quality import QualityFigures
from hdrcl.report.verdicts import causes, grade_figures, legend_rows, thin_coverage_percent, verdicts, worst

STATUS_DONE, STATUS_SKIPPED, STATUS_FAILED, STATUS_CHECK = "done", "skipped", "failed", "check"
#: What the page calls each status (a batch's internal "skipped" is an up-to-date output,
#: not a problem; "check" a merged output a check could not vouch for); unknown statuses
#: are shown as they are.
STATUS_LABELS = {STATUS_DONE: "merged", STATUS_SKIPPED: "up to date", STATUS_FAILED: "failed",
                 STATUS_CHECK: "merged: check it", "pending": "pending"}


def status_label(status: Optional[str]) -> str:
    """The words the report uses for a set's ``status`` (:data:`STATUS_LABELS`)."""
    status = status or STATUS_DONE
    return STATUS_LABELS.get(status, status)


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


def _ladder_span(f: QualityFigures) -> str:
    """``", ladder spans 6.0 EV"``: shortest to longest exposure used; empty if unknown."""
    used = [e.get("used") for e in f.exposures or []]
    if len(used) < 2 or not all(isinstance(u, (int, float)) and u > 0 for u in used):
        return ""
    return f", ladder spans {np.log2(max(used) / min(used)):.1f} EV"


def _ordinal(n: int) -> str:
    n = int(n)
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def fraction_precision(fraction: float, pixels: int) -> float:
    """Sampling precision (95 %, as for independent samples) of a pixel fraction measured
    on ``pixels`` grid pixels: ``2 sqrt(p (1 - p) / n)``, with p at least ``1 / n`` so
    that a fraction of 0 on the grid reads as "below about 2 / n"."""
    n = max(int(pixels), 1)
    p = min(max(float(fraction), 1.0 / n), 1.0)
    return 2.0 * float(np.sqrt(p * (1.0 - p) / n))


def _precision(f: QualityFigures, fraction: float) -> str:
    """``" (± 0.01, every 3rd row and column)"`` when the figure was measured on a grid."""
    if int(getattr(f, "grid_stride", 1)) <= 1:
        return ""
    return (f" (± {100 * fraction_precision(fraction, f.valid_pixels):.2g}, measured on every "
            f"{_ordinal(f.grid_stride)} row and column)")


def format_figures(figures: QualityFigures) -> List[tuple]:
    """``(label, text)`` rows of a set's figures, as the contact sheet shows them."""
    f = figures
    if f.loo_rmse is None or not np.isfinite(f.loo_rmse):
        loo = "not measured" if f.frames >= 3 else "not measured (fewer than 3 frames)"
    else:
        per = ", ".join("–" if not np.isfinite(r.rmse) else f"{r.rmse:.2f}" for r in f.loo)
        grid = "every pixel" if f.loo_stride == 1 else f"every {_ordinal(f.loo_stride)} row and column"
        n = len(f.loo)
        which = "the one interior frame" if n == 1 else f"median over {n} interior frames: {per}"
        loo = f"{f.loo_rmse:.2f} levels ({which}; {grid})"
    if f.dynamic_range_stops is None:
        dr = "–"
    else:
        p0, p1 = f.dynamic_range_percentiles
        dr = (f"{'at least ' if f.dynamic_range_is_lower_bound else ''}{f.dynamic_range_stops:.1f} stops "
              f"(luminance P{p0:g} to P{p1:g})")
    thin = thin_coverage_percent(f)
    none = 100.0 * f.coverage_histogram[0] / f.valid_pixels if thin is not None else None
    return [
        ("Leave-one-out RMSE", loo),
        ("Dynamic range", dr),
        ("Clipped high", f"{100 * f.clipped_high_fraction:.2f} % of pixels" + _precision(f, f.clipped_high_fraction)),
        ("Clipped low", f"{100 * f.clipped_low_fraction:.2f} % of pixels" + _precision(f, f.clipped_low_fraction)),
        ("Thin coverage", "–" if thin is None else
         f"{thin:.2f} % of pixels measured by at most one frame ({none:.2f} % by none)"),
        ("Extra exposure for highlights", format_ev(f.extra_ev_high, "high")),
        ("Extra exposure for shadows", format_ev(f.extra_ev_low, "low")),
        ("Frames", f"{f.frames} × {f.shape[1]}×{f.shape[0]}, {f.bits}-bit, {f.weight} weights"
                   + _ladder_span(f)),
    ]


_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,Helvetica,Arial,sans-serif;margin:0;background:#f4f4f2;
color:#222;font-size:15px;line-height:1.4}
header{padding:16px 24px;background:#fff;border-bottom:1px solid #ddd}
h1{font-size:1.5em;margin:0 0 4px}
.summary{margin:2px 0;color:#555}
#image-check{margin:2px 0;color:#a00}
#image-check:empty{display:none}
main{display:grid;grid-template-columns:repeat(auto-fit,minmax(540px,1fr));gap:16px;padding:16px 24px}
main.single{display:block}
main.single .body{display:grid;grid-template-columns:minmax(0,1fr) minmax(0,1fr);gap:0 24px;align-items:start}
main.single .plots{display:grid;grid-template-columns:repeat(auto-fit,minmax(300px,1fr));align-items:start}
article{background:#fff;border:1px solid #ddd;border-radius:6px;padding:12px 16px}
article.failed{border-color:#d33;background:#fff6f6}
h2{font-size:1.2em;margin:0 0 6px;word-break:break-all}
h3{font-size:1em;margin:12px 0 4px;color:#444}
.status{font-size:.75em;padding:1px 7px;border-radius:3px;background:#e6f2e6;margin-left:8px;vertical-align:middle;
font-weight:600}
article.failed .status{background:#f8d0d0}
article.skipped .status{background:#e3ecf7}
.verdict{font-size:.75em;padding:1px 7px;border-radius:3px;margin-left:6px;vertical-align:middle;font-weight:600}
.v-pass{background:#e6f4e8;color:#1e6b2a}
.v-warn{background:#fff1cc;color:#7a4d00}
.v-fail{background:#fbdcdc;color:#a00}
.why{margin:4px 0 6px;padding:4px 8px;border-radius:4px;font-size:.9em}
.why ul{margin:2px 0 0;padding-left:18px}
table.figures td.mark{white-space:nowrap;font-weight:600;font-size:.85em;text-align:right;padding:3px 6px}
table.figures tr.v-pass td,table.figures tr.v-pass th,table.figures tr.v-warn td,table.figures tr.v-warn th,
table.figures tr.v-fail td,table.figures tr.v-fail th{background:inherit}
.thresholds{margin:6px 0 0;font-size:.85em;color:#333}
.thresholds table{width:auto}
.thresholds td,.thresholds th{padding:1px 10px 1px 0}
.camera{margin:0 0 8px;color:#333}
.thumb{display:block;max-width:100%;max-height:460px;width:auto;height:auto;margin:0 auto 8px;background:#000}
.frames{display:flex;flex-wrap:wrap;gap:6px}
.frames figure{margin:0;flex:0 0 auto;width:96px}
.frames img{width:96px;height:auto;display:block;border:1px solid #ddd;background:#000}
.frames figcaption{font-size:.8em;color:#444;text-align:center;white-space:nowrap;overflow:hidden;
text-overflow:ellipsis;line-height:1.25}
.frames figcaption.shot{white-space:normal}
.frames figcaption.shot span{white-space:nowrap}
table{border-collapse:collapse;width:100%}
th,td{text-align:left;vertical-align:top;padding:3px 8px 3px 0}
th{font-weight:600;white-space:nowrap;color:#444}
.plots{display:flex;flex-direction:column;gap:10px;margin-top:10px}
.plots figure{margin:0}
.plots img{width:100%;height:auto;border:1px solid #eee}
.plots img.map{width:auto;max-width:100%;max-height:320px}
figcaption{font-size:.85em;color:#555}
.legend{display:flex;flex-wrap:wrap;gap:4px 10px;font-size:.85em;color:#333;margin-top:4px}
.legend span::before{content:"";display:inline-block;width:14px;height:10px;margin-right:4px;
background:var(--c);border:1px solid #999;vertical-align:baseline}
.error{color:#a00;white-space:pre-wrap}
.warnings{color:#8a5a00;padding-left:18px}
details{margin-top:8px}
section.unmerged{padding:0 24px 24px}
section.unmerged article{margin-bottom:10px}
.problem{color:#a00;font-size:.8em}
img.broken{outline:3px solid #d33}
""".strip()


# Counts the images that really decoded once the page has loaded and keeps the count in
# data-loaded / data-total (the browser test reads them back); says something only when
# an image is missing (a moved or incomplete report folder).
_SCRIPT = """
window.addEventListener("load", function () {
  var imgs = document.images, n = 0;
  for (var i = 0; i < imgs.length; i++) {
    if (imgs[i].complete && imgs[i].naturalWidth > 0) { n++; } else { imgs[i].classList.add("broken"); }
  }
  var el = document.getElementById("image-check");
  el.setAttribute("data-loaded", String(n));
  el.setAttribute("data-total", String(imgs.length));
  if (n < imgs.length) {
    el.textContent = (imgs.length - n) + " of " + imgs.length + " pictures are missing from this folder";
  }
});
""".strip()


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def _href(filename: str) -> str:
    return _e(urllib.parse.quote(filename))


def _img(filename: str, alt: str, cls: str = "") -> str:
    c = f' class="{cls}"' if cls else ""
    return f'<a href="{_href(filename)}"><img{c} src="{_href(filename)}" alt="{_e(alt)}"></a>'


def _camera_line(camera: dict) -> Optional[str]:
    parts = [camera.get(k) for k in ("camera", "lens", "focal_length", "iso", "fnumber", "captured")]
    parts = [str(p) for p in parts if p]
    return " · ".join(parts) if parts else None


def _caption_parts(row: dict, vary_f: bool, vary_iso: bool) -> List[str]:
    """A frame's caption: its settings as the camera recorded them when the report has
    them (``shutter``), else the nominal time and the settings that differ in the set."""
    from hdrcl.report.inputs import setting_parts

    align = [f"aligned: {row['align']}"] if row.get("align") else []
    if row.get("shutter"):
        return setting_parts(row["shutter"], row.get("fnumber"), row.get("iso")) + align
    return (setting_parts(row.get("time"), row.get("fnumber") if vary_f else None,
                          row.get("iso") if vary_iso else None) or ["–"]) + align


def _inputs(entry) -> List[str]:
    rows = [r for r in (entry.inputs or []) if isinstance(r, dict)]
    if not rows:
        return []
    vary_f = len({r.get("fnumber") for r in rows}) > 1
    vary_iso = len({r.get("iso") for r in rows}) > 1
    out = [f"<h3>Input frames ({len(rows)}, shortest exposure first)</h3>", '<div class="frames">']
    for r in rows:
        cap = " ".join(f"<span>{_e(p)}</span>" for p in _caption_parts(r, vary_f, vary_iso))
        thumb = (_img(r["thumb"], f"{r.get('file', '')}: input frame") if r.get("thumb")
                 else "<div>(no thumbnail)</div>")
        out.append(f'<figure title="{_e(r.get("file", ""))}">{thumb}<figcaption class="shot">{cap}'
                   f"</figcaption></figure>")
    out.append("</div>")
    return out


def _plots(entry) -> List[str]:
    files, f = entry.files or {}, entry.figures
    plots = []
    if "response" in files:
        plots.append(f'<figure>{_img(files["response"], entry.name + ": response curves")}'
                     "<figcaption>Recovered response g(z) per channel.</figcaption></figure>")
    if "histogram" in files:
        plots.append(f'<figure>{_img(files["histogram"], entry.name + ": luminance histogram")}'
                     "<figcaption>Luminance of the radiance map; the dashed lines are the clip points of the "
                     "bracket (below: the longest frame is at its noise floor; above: the shortest frame clips)."
                     "</figcaption></figure>")
    if "coverage" in files:
        frames = f.frames if f is not None else 0
        k = max(1, int(getattr(f, "grid_stride", 1))) if f is not None else 1
        no_data = f is not None and f.valid_pixels < -(-f.shape[0] // k) * -(-f.shape[1] // k)
        legend = "".join(f'<span style="--c:{c}">{_e(label)}</span>'
                         for label, c in coverage_legend(frames, no_data=no_data))
        plots.append(f'<figure>{_img(files["coverage"], entry.name + ": coverage map", "map")}'
                     f'<figcaption>Frames measuring each pixel (its least-measured channel).</figcaption>'
                     f'<div class="legend">{legend}</div></figure>')
    return ['<div class="plots">' + "".join(plots) + "</div>"] if plots else []


def _figures_table(f: QualityFigures) -> str:
    """The figures, the graded ones coloured by their verdict (:mod:`hdrcl.report.verdicts`)."""
    graded = verdicts(f)
    out = ['<h3>Figures</h3><table class="figures">']
    for label, text in format_figures(f):
        g = graded.get(label)
        v = g.verdict if g is not None else None
        attrs = f' class="v-{v}" data-verdict="{v}" title="{_e(g.why)}"' if v else ""
        out.append(f"<tr{attrs}><th>{_e(label)}</th><td>{_e(text)}</td>"
                   f'<td class="mark">{_e(v or "")}</td></tr>')
    out.append("</table>")
    return "\n".join(out)


def _why(f: QualityFigures) -> str:
    """The causes of a set's warn or fail verdict, one line each (empty when it passes):
    the figure, its value, the limit it passed and what that means."""
    lines = causes(f)
    if not lines:
        return ""
    v = lines[0].verdict
    items = "".join(f'<li data-check="{_e(c.key)}">{_e(c.why)}</li>' for c in lines)
    return f'<div class="why v-{v}" data-verdict="{v}"><b>{_e(v)}</b> because:<ul>{items}</ul></div>'


def _badge_title(f: Optional[QualityFigures]) -> str:
    lines = causes(f) if f is not None else []
    return "; ".join(c.why for c in lines) if lines else "every graded figure passes"


def _exposures_table(entry) -> List[str]:
    f = entry.figures
    if f is None or not f.exposures:
        return []
    shot = {r.get("file"): r for r in entry.inputs or [] if isinstance(r, dict) and r.get("shutter")}
    out = ["<details><summary>Exposures (as shot; nominal, fitted and used in relative seconds)</summary><table>"
           "<tr><th>frame</th><th>as shot</th><th>nominal</th><th>fitted</th><th>used</th></tr>"]
    for k, ex in enumerate(f.exposures):
        r = shot.get(ex.get("file"))
        as_shot = " ".join(_caption_parts(r, False, False)) if r else "–"
        cells = (ex.get("file", k), as_shot, _fmt_time(ex.get("nominal")),
                 _fmt_fitted(ex.get("fitted"), ex.get("nominal")), _fmt_time(ex.get("used")))
        out.append("<tr>" + "".join(f"<td>{_e(v)}</td>" for v in cells) + "</tr>")
    out.append("</table></details>")
    return out


def _card(entry, index: int) -> str:
    status = entry.status or STATUS_DONE
    f = entry.figures
    verdict = worst(grade_figures(f).values()) if f is not None else None
    badge = f'<span class="verdict v-{verdict}" title="{_e(_badge_title(f))}">{verdict}</span>' \
        if verdict else ""
    out = [f'<article class="set {_e(status)}" id="set-{index}" data-set="{_e(entry.name)}" '
           f'data-status="{_e(status)}" data-label="{_e(status_label(status))}"'
           + (f' data-verdict="{verdict}"' if verdict else "") + ">",
           f'<h2>{_e(entry.name)}<span class="status">{_e(status_label(status))}</span>{badge}</h2>',
           '<div class="body"><div class="look">']
    cam = _camera_line(entry.camera or {})
    if cam:
        out.append(f'<p class="camera">{_e(cam)}</p>')
    files = entry.files or {}
    if "preview" in files:
        out.append(_img(files["preview"], f"{entry.name}: tone-mapped preview (Reinhard 2002)", "thumb"))
    if entry.error:
        out.append(f'<p class="error">{_e(entry.error)}</p>')
    out += _inputs(entry)
    out.append('</div><div class="numbers">')
    if f is not None:
        why = _why(f)
        if why:
            out.append(why)
        out.append(_figures_table(f))
    out += _exposures_table(entry)
    if entry.warnings:
        out.append('<h3>Warnings</h3><ul class="warnings">'
                   + "".join(f"<li>{_e(w)}</li>" for w in entry.warnings) + "</ul>")
    if entry.deliverables:  # --deliver: the pictures beside the map
        out.append('<p class="deliverables">Deliverables: ' + ", ".join(
            f'<a href="{_href(d["file"])}" data-kind="{_e(d["kind"])}">{_e(d["kind"])}</a> '
            f'({int(d.get("bytes", 0)) / 1e6:.2f} MB)' for d in entry.deliverables) + "</p>")
    if "json" in files:
        out.append(f'<p><a href="{_href(files["json"])}">figures (JSON)</a></p>')
    out.append("</div></div>")
    out += _plots(entry)
    out.append("</article>")
    return "\n".join(out)


def _thresholds_legend() -> str:
    """The verdicts' thresholds, as :data:`hdrcl.report.verdicts.THRESHOLDS` applies them."""
    rows = "".join(f"<tr><th>{_e(label)}</th><td class=\"v-pass\">pass {_e(p)}</td>"
                   f"<td class=\"v-warn\">warn {_e(w)}</td><td class=\"v-fail\">fail {_e(x)}</td>"
                   f"<td>{_e(meaning)}</td></tr>" for label, p, w, x, meaning in legend_rows())
    return f'<details class="thresholds" open><summary>Verdicts</summary><table>{rows}</table></details>'


def _unmerged_section(groups: Sequence[dict]) -> str:
    if not groups:
        return ""
    nfiles = sum(len(g["files"]) for g in groups)
    out = [f'<section class="unmerged"><h2>Not merged: {nfiles} file{"s" if nfiles != 1 else ""} in '
           f'{len(groups)} group{"s" if len(groups) != 1 else ""}</h2>']
    for k, g in enumerate(groups):
        out.append(f'<article class="unmerged-group" id="unmerged-{k}" data-reason="{_e(g["reason"])}">'
                   f'<p><b>Reason:</b> {_e(g["reason"])}</p><div class="frames">')
        for f in g["files"]:
            pic = _img(f["thumb"], f"{f['file']}: not merged") if f.get("thumb") else ""
            prob = f'<div class="problem">{_e(f["problem"])}</div>' if f.get("problem") else ""
            out.append(f'<figure title="{_e(f["file"])}">{pic}<figcaption>{_e(f["file"])}</figcaption>{prob}'
                       "</figure>")
        out.append("</div></article>")
    out.append("</section>")
    return "\n".join(out)


def contact_sheet_html(entries: Sequence, title: str = "hdrcl quality report",
                       unmerged: Sequence[dict] = ()) -> str:
    """The contact sheet page for ``entries`` and the ``unmerged`` groups of
    :func:`hdrcl.report.inputs.write_unmerged` (see
    :func:`hdrcl.report.pages.write_contact_sheet`)."""
    from hdrcl.version import __version__

    entries = list(entries)
    failed = sum(1 for e in entries if e.status == STATUS_FAILED)
    merged = sum(1 for e in entries if e.status == STATUS_DONE)
    skipped = sum(1 for e in entries if e.status == STATUS_SKIPPED)
    check = sum(1 for e in entries if e.status == STATUS_CHECK)
    other = len(entries) - failed - merged - skipped - check
    summary = (f"{len(entries)} set{'s' if len(entries) != 1 else ''}: {merged} merged, "
               + (f"{check} to check, " if check else "")
               + (f"{skipped} {STATUS_LABELS[STATUS_SKIPPED]}, " if skipped else "") + f"{failed} failed"
               + (f", {other} pending" if other else ""))
    graded = [worst(grade_figures(e.figures).values()) for e in entries if e.figures is not None]
    counted = [f"{graded.count(v)} {v}" for v in ("pass", "warn", "fail") if v in graded]
    if counted:
        summary += "; verdicts: " + ", ".join(counted)
    nfiles = sum(len(g["files"]) for g in unmerged)
    if nfiles:
        summary += f"; {nfiles} file{'s' if nfiles != 1 else ''} not merged"
    cards = "\n".join(_card(e, i) for i, e in enumerate(entries))
    return (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
        f"<title>{_e(title)}</title>\n<style>\n{_CSS}\n</style>\n</head>\n<body>\n"
        f"<header><h1>{_e(title)}</h1><p class=\"summary\">{_e(summary)} · hdrcl {_e(__version__)}</p>"
        f"<p id=\"image-check\" data-loaded=\"\" data-total=\"\"></p>"
        f"{_thresholds_legend() if graded else ''}</header>\n"
        # One set: the card takes the page's width and lays its parts side by side.
        f"<main class=\"sets{' single' if len(entries) == 1 else ''}\">\n{cards}\n</main>\n"
        f"{_unmerged_section(list(unmerged))}\n"
        f"<script>\n{_SCRIPT}\n</script>\n</body>\n</html>\n")
