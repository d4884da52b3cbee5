"""The quality report: per-set files and the HTML contact sheet, checked in headless Chromium.

The browser test needs Debian's ``chromium`` (or ``chromium-browser``) on PATH. Without
it the test skips, unless ``HDRCL_REQUIRE_BROWSER=1``, which makes a missing browser a
failure (CI sets it, so the page is really opened).
"""
import html
import json
import os
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from hdrcl.core import synthetic as s
from hdrcl.core.bracket import load_bracket
from hdrcl.core.merge import merge_bracket
from hdrcl.report.pages import (
    INDEX_NAME,
    ReportEntry,
    format_figures,
    load_report_folder,
    load_set_report,
    write_contact_sheet,
    write_set_report,
)
from hdrcl.report.plots import clip_points, coverage_image, coverage_legend, histogram_svg, response_svg
from hdrcl.report.quality import measure

# (name, height, width, decades, frames): odd sizes; the last set is clipped at both ends.
SETS = [
    ("beach <sunset> & \"co\"", 47, 61, 4.0, 5),
    ("IMG_0100", 53, 71, 3.0, 5),
    ("café interior", 41, 59, 6.5, 3),
]
FAILED = ReportEntry(name="IMG_0200 <broken>", status="failed", error="IMG_0202.JPG: truncated file (3 of 6 MB)")
#: Per merged set: preview, response, histogram, coverage, and one thumbnail per frame.
FILES = {"response", "histogram", "coverage", "preview", "json"}


def _images(entries, unmerged_readable=0):
    return sum(4 + len(e.inputs) for e in entries if e.figures is not None) + unmerged_readable


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    from hdrcl.io.ldr import write_photo

    folder = tmp_path_factory.mktemp("report")
    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
    entries = []
    for k, (name, h, w, decades, n) in enumerate(SETS):
        rad = s.radiance_field(h, w, decades=decades, seed=10 + k)
        times = s.stops(n, 2.0, centre=1.0 / float(np.median(rad)))
        br = load_bracket(s.bracket(rad, times, cam, noise=0.5, seed=k), times)
        res = merge_bracket(br)
        fig = measure(br, res.response, res.radiance)
        entries.append(write_set_report(folder, name, fig, res.response, res.radiance,
                                        warnings=res.warnings + [f"note <{k}> & more"], bracket=br))
    entries.append(FAILED)
    # Frames a batch did not merge: one readable stray frame, one corrupt file.
    stray = folder.parent / (folder.name + "-in")
    stray.mkdir()
    write_photo(stray / "IMG_0300.png", np.full((20, 30, 3), 128, np.uint8))
    (stray / "IMG_0301 <bad>.jpg").write_bytes(b"not a jpeg")
    unmerged = [{"files": [str(stray / "IMG_0300.png")], "reason": "single frame"},
                {"files": [str(stray / "IMG_0301 <bad>.jpg")], "reason": "corrupt or unreadable"}]
    index = write_contact_sheet(folder, entries, unmerged=unmerged)
    return folder, index, entries


def test_set_files(report):
    folder, index, entries = report
    assert os.path.basename(index) == INDEX_NAME
    for e, (_name, h, w, _dec, n) in zip(entries[:-1], SETS):
        assert set(e.files) == FILES
        assert [r["thumb"] for r in e.inputs] == [f"{e.files['json'][:-5]}-frame-{k:02d}.jpg" for k in range(n)]
        assert [r["time"] for r in e.inputs] == sorted(r["time"] for r in e.inputs)  # shortest first
        for f in e.files.values():
            assert (folder / f).is_file() and not f.startswith(".")
        d = json.loads((folder / e.files["json"]).read_text())
        assert d["name"] == e.name and d["figures"]["frames"] == e.figures.frames
        again = load_set_report(folder, e.name)
        assert again.figures.to_dict() == e.figures.to_dict() and again.files == e.files
        assert again.inputs == e.inputs
    assert not [p for p in os.listdir(folder) if ".tmp-" in p]  # atomic writes left nothing behind
    assert load_set_report(folder, "no such set") is None


def test_plots():
    """The charts are well-formed SVG with their curves, labels and clip markers."""
    import xml.etree.ElementTree as ET

    from hdrcl.core.response import Response

    ns = {"svg": "http://www.w3.org/2000/svg"}
    g = np.stack([np.linspace(-5, 5, 256) + k * 0.1 for k in range(3)])
    resp = Response(bits=8, g=g, knots=np.arange(256.0))
    root = ET.fromstring(response_svg(resp))
    lines = root.findall(".//svg:polyline", ns)
    assert {ln.get("stroke") for ln in lines} == {"#cd2828", "#1e9632", "#2850d2"}  # R, G, B
    texts = [t.text for t in root.iter("{http://www.w3.org/2000/svg}text")]
    assert "g(z) = ln exposure" in texts and "R" in texts and "255" in texts
    # The clip points: the longest frame at the noise floor, the shortest at the clip
    # level (fusion's clip_levels, not codes 0 and 255).
    from hdrcl.core.weights import clip_levels

    zlo, zhi = clip_levels(256)
    lo, hi = clip_points(resp, [0.5, 2.0], 3)
    luma = np.array([0.2126, 0.7152, 0.0722])
    assert 0 < zlo < zhi < 255
    assert lo == pytest.approx(float(np.exp(g[:, zlo]) @ luma) / 2.0)
    assert hi == pytest.approx(float(np.exp(g[:, zhi]) @ luma) / 0.5)
    rad = np.exp(np.random.default_rng(0).normal(0, 1, (20, 30, 3)))
    root = ET.fromstring(histogram_svg(rad, resp, [0.5, 2.0]))
    texts = [t.text for t in root.iter("{http://www.w3.org/2000/svg}text")]
    assert "every frame clips above" in texts and "no frame reads below" in texts
    heights = [float(r.get("height")) for r in root.iter("{http://www.w3.org/2000/svg}rect")]
    assert len(heights) > 10  # bars
    cov = np.zeros((31, 47), np.uint8)
    cov[10:] = 3
    cov[:, :5] = 255  # no data
    out = coverage_image(cov, frames=3)
    assert out.dtype == np.uint8 and out.shape[1] >= 47 and out.shape[0] > 31
    assert len(np.unique(out.reshape(-1, 3), axis=0)) == 3  # 0, 3 and no data
    assert [label for label, _c in coverage_legend(3, no_data=True)] == ["0 (clipped)", "1", "2", "3", "no data"]


def test_wording():
    """No "median of 1 interior frames"; the figures say what they are."""
    from hdrcl.report.leaveoneout import LeaveOneOut

    br = load_bracket(s.bracket(s.radiance_field(20, 30, decades=3.0, seed=1), [0.25, 1.0, 4.0],
                                s.Camera(a=1.1, x0=(1.0, 1.2, 0.8)), noise=0.5, seed=0), [0.25, 1.0, 4.0])
    res = merge_bracket(br)
    fig = measure(br, res.response, res.radiance)
    assert len(fig.loo) == 1
    rows = dict(format_figures(fig))
    assert "the one interior frame" in rows["Leave-one-out RMSE"] and "median" not in rows["Leave-one-out RMSE"]
    assert rows["Frames"].endswith(f", ladder spans {np.log2(4.0 / 0.25):.1f} EV")  # shortest to longest used
    fig.loo = [fig.loo[0], LeaveOneOut(index=1, time=1.0, rmse=2.0, pixels=10)]
    assert "median over 2 interior frames" in dict(format_figures(fig))["Leave-one-out RMSE"]


class _Page(HTMLParser):
    def __init__(self):
        super().__init__()
        self.imgs, self.links, self.text = [], [], []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.imgs.append(a["src"])
        if tag == "a":
            self.links.append(a["href"])

    def handle_data(self, data):
        self.text.append(data)


def test_contact_sheet_html(report):
    folder, index, entries = report
    page = open(index, encoding="utf-8").read()
    assert "<sunset>" not in page and "<broken>" not in page  # every text escaped
    p = _Page()
    p.feed(page)
    text = "".join(p.text)
    for e in entries:
        assert e.name in text
    assert FAILED.error in text and "1 failed" in text
    assert len(p.imgs) == _images(entries, unmerged_readable=1)
    assert "images loaded" not in page  # no internal bookkeeping on the page
    for k in range(len(SETS)):  # camera settings: the synthetic frames carry none, so no empty line
        assert f'id="set-{k}"' in page
    # The frames not merged, with their reason; the corrupt one says why it has no thumbnail.
    assert "Not merged: 2 files in 2 groups" in text and "single frame" in text
    assert "IMG_0301 <bad>.jpg" in html.unescape(text) and "corrupt or unreadable" in text
    assert "unmerged-IMG_0300_png.jpg" in p.imgs
    from urllib.parse import unquote

    for ref in p.imgs + p.links:
        assert not re.match(r"^[a-z]+:", ref) and not ref.startswith("/")  # relative links only
        assert (folder / unquote(ref)).is_file(), ref


def _run_chromium(browser, tmp_path, *args):
    cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", f"--user-data-dir={tmp_path / 'profile'}",
           "--virtual-time-budget=5000", *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}"
    return proc.stdout


def test_contact_sheet_in_chromium(report, tmp_path, chromium_path):
    """Done when: the HTML report opens in headless Chromium and shows every set."""
    browser = chromium_path
    folder, index, entries = report
    url = "file://" + os.path.abspath(index)
    dom = _run_chromium(browser, tmp_path, "--dump-dom", url)

    p = _Page()
    p.feed(dom)
    text = html.unescape("".join(p.text))
    assert len(re.findall(r'<article class="set', dom)) == len(entries)
    for e in entries:
        assert e.name in text, f"set {e.name!r} missing from the rendered page"
        if e.figures is not None:
            for label, value in format_figures(e.figures):
                assert label in text and value in text, (e.name, label, value)
    assert FAILED.error in text
    assert "Not merged: 2 files in 2 groups" in text and "IMG_0300.png" in text and "IMG_0301 <bad>.jpg" in text
    assert len(re.findall(r'<article class="unmerged-group"', dom)) == 2
    # The page's own script counted the images that decoded (SVG charts included).
    m = re.search(r'id="image-check" data-loaded="(\d+)" data-total="(\d+)"', dom)
    assert m, "the page's load handler did not run: " + re.search(r'<p id="image-check"[^>]*>', dom).group(0)
    loaded, total = int(m.group(1)), int(m.group(2))
    assert total == len(p.imgs) == _images(entries, unmerged_readable=1)
    assert loaded == total, f"only {loaded} of {total} images loaded"
    assert re.search(r'<p id="image-check"[^>]*></p>', dom)  # says nothing when all is there

    shot = tmp_path / "sheet.png"
    _run_chromium(browser, tmp_path, "--hide-scrollbars", "--window-size=1280,1600", f"--screenshot={shot}", url)
    import OpenImageIO as oiio

    pixels = oiio.ImageBuf(str(shot)).get_pixels(oiio.UINT8)
    assert pixels.shape[:2] == (1600, 1280)
    rgb = pixels[..., :3].reshape(-1, 3)
    assert rgb.std() > 10  # not blank
    assert len(np.unique(rgb, axis=0)) > 500  # photographs and plots, not just text on a background


def test_missing_picture_is_reported(report, tmp_path, chromium_path):
    """A picture gone from the folder is named on the page (and only then)."""
    browser = chromium_path
    folder, index, entries = report
    moved = tmp_path / "copy"
    shutil.copytree(folder, moved)
    (moved / entries[0].files["histogram"]).unlink()
    dom = _run_chromium(browser, tmp_path, "--dump-dom", "file://" + str(moved / INDEX_NAME))
    m = re.search(r'<p id="image-check"[^>]*>([^<]*)</p>', dom)
    assert m and m.group(1).startswith("1 of ") and m.group(1).endswith("pictures are missing from this folder")


def test_report_folder_accumulates(tmp_path):
    """Two ``merge --report DIR`` runs into one folder: the page shows both sets."""
    from click.testing import CliRunner

    from hdrcl.cli import main
    from hdrcl.io.ldr import write_photo

    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
    folder = tmp_path / "rep"
    for k, name in enumerate(("first", "second")):
        rad = s.radiance_field(24, 32, decades=3.0, seed=k)
        times = s.stops(3, 2.0, centre=1.0 / float(np.median(rad)))
        paths = []
        for j, f in enumerate(s.bracket(rad, times, cam, noise=0.5, seed=k)):
            paths.append(str(tmp_path / f"{name}_{j}.png"))
            write_photo(paths[-1], f)
        res = CliRunner().invoke(main, ["merge", *paths, "--times", ",".join(f"{t:.6g}" for t in times),
                                        "-o", str(tmp_path / f"{name}.exr"), "--report", str(folder)])
        assert res.exit_code == 0, res.output
    assert [e.name for e in load_report_folder(folder)] == ["first", "second"]
    page = (folder / INDEX_NAME).read_text()
    assert 'data-set="first"' in page and 'data-set="second"' in page and "2 sets: 2 merged" in page


# ------------------------------------------------- status words, verdicts, one-set layout, labels


def _one_set(folder, name="solo", status="done"):
    rad = s.radiance_field(41, 59, decades=3.0, seed=5)
    times = s.stops(4, 2.0, centre=1.0 / float(np.median(rad)))
    br = load_bracket(s.bracket(rad, times, s.Camera(a=1.1, x0=(1.0, 1.2, 0.8)), noise=0.5, seed=3), times)
    res = merge_bracket(br)
    fig = measure(br, res.response, res.radiance)
    return write_set_report(folder, name, fig, res.response, res.radiance, bracket=br, status=status)


def test_up_to_date_status(tmp_path):
    """A batch's "skipped" (its output was current) reads "up to date" on the page and in
    the set's JSON ``label``; ``status`` keeps the batch's value."""
    from hdrcl.report.pages import STATUS_LABELS, status_label

    entry = _one_set(tmp_path, status="skipped")
    d = json.loads((tmp_path / entry.files["json"]).read_text())
    assert d["status"] == "skipped" and d["label"] == status_label("skipped") == "up to date"
    assert load_set_report(tmp_path, "solo").status == "skipped"
    page = open(write_contact_sheet(tmp_path, [entry]), encoding="utf-8").read()
    assert 'data-status="skipped" data-label="up to date"' in page
    assert '<span class="status">up to date</span>' in page and ">skipped<" not in page
    assert "1 set: 0 merged, 1 up to date, 0 failed" in page
    assert status_label("done") == STATUS_LABELS["done"] != "done" and status_label("odd") == "odd"


def test_verdicts_on_the_page(report):
    """Graded rows carry the verdict of :func:`grade_figures`, and the header lists every
    threshold of the table that made them."""
    from hdrcl.report.verdicts import THRESHOLDS, grade_figures, worst

    folder, index, entries = report
    page = open(index, encoding="utf-8").read()
    for t in THRESHOLDS:
        assert f"<th>{html.escape(t.label)}</th>" in page
        assert f"warn ≤ {t.fail_above:g}" in page and f"fail &gt; {t.fail_above:g}" in page
    for k, e in enumerate(entries[:-1]):
        card = page[page.index(f'id="set-{k}"'):]
        card = card[:card.index("</article>")]
        grades = grade_figures(e.figures)
        for label, v in grades.items():
            row = re.search(rf'<tr([^>]*)><th>{re.escape(label)}</th>', card).group(1)
            assert (f'data-verdict="{v}"' in row) if v else ("data-verdict" not in row), (label, row)
        assert f'data-verdict="{worst(grades.values())}"' in card[:card.index(">")]
    assert 'data-verdict' not in page[page.index('id="set-3"'):]  # the failed set has no figures


def test_one_set_layout(tmp_path):
    """One set: no grid of empty columns; the card's pictures and its figures sit side by
    side (checked in the HTML here, on screen in Chromium below)."""
    entry = _one_set(tmp_path)
    page = open(write_contact_sheet(tmp_path, [entry]), encoding="utf-8").read()
    assert '<main class="sets single">' in page
    body = re.search(r'<div class="body"><div class="look">(.*?)</div><div class="numbers">(.*?)</div></div>',
                     page, re.S)
    assert body and "preview" in body.group(1) and 'class="figures"' in body.group(2)
    many = open(write_contact_sheet(tmp_path, [entry, FAILED]), encoding="utf-8").read()
    assert '<main class="sets">' in many


def test_one_set_fills_the_width_in_chromium(tmp_path, chromium_path):
    """On a 1280 px wide window, the right half of a one-set page shows the set's
    figures and plots, not the empty background of a second grid column."""
    browser = chromium_path
    entry = _one_set(tmp_path)
    index = write_contact_sheet(tmp_path, [entry])
    shot = tmp_path / "one.png"
    _run_chromium(browser, tmp_path, "--hide-scrollbars", "--window-size=1280,1200", f"--screenshot={shot}",
                  "file://" + os.path.abspath(index))
    import OpenImageIO as oiio

    rgb = oiio.ImageBuf(str(shot)).get_pixels(oiio.UINT8)[..., :3].astype(int)
    background = np.array([0xF4, 0xF4, 0xF2])
    right = rgb[250:900, 700:1240]
    assert (np.abs(right - background).sum(axis=2) > 0).mean() > 0.5  # the card, not the page behind
    assert len(np.unique(right.reshape(-1, 3), axis=0)) > 20  # text and plots there


def test_frame_labels_in_each_cameras_terms(tmp_path):
    """Frames shot at different apertures and ISOs are labelled with their own settings,
    whatever relative exposures the merge used; times that the headers do not explain
    (typed or from a times file) are labelled as given."""
    from hdrcl.core.bracket import Bracket
    from hdrcl.io.metadata import FrameInfo, format_time
    from hdrcl.report.inputs import shot_settings, write_inputs

    shots = [(1 / 8, 8.0, 100), (1.0, 5.6, 200), (8.0, 11.0, 400)]
    infos = [FrameInfo(path=f"f{k}.jpg", width=8, height=6, nchannels=3, exposure_time=t, fnumber=n, iso=i)
             for k, (t, n, i) in enumerate(shots)]
    # What a shoot-wide reference of f/4 ISO 50 makes of them (not the camera's numbers).
    rel = np.array([t * (4.0 / n) ** 2 * (i / 50.0) for t, n, i in shots])
    frames = [np.full((6, 8, 3), v, np.uint8) for v in (40, 120, 200)]
    br = Bracket(frames=frames, times=rel, valid=[None] * 3, paths=[i.path for i in infos], infos=infos)
    rows = write_inputs(str(tmp_path), "x", br)
    want = [f"{format_time(t)} f/{n:g} ISO {i}" for t, n, i in shots]
    assert [r["label"] for r in rows] == want
    assert [r["shutter"] for r in rows] == [t for t, _n, _i in shots]
    assert [r["time"] for r in rows] == list(rel) and not np.allclose(rel, [t for t, _n, _i in shots])
    entry = ReportEntry(name="mixed", inputs=rows)
    page = open(write_contact_sheet(tmp_path, [entry]), encoding="utf-8").read()
    p = _Page()
    p.feed(page)
    text = "".join(p.text)
    for w in want:
        assert w in text
    assert format_time(rel[1]) not in text
    # Without a shutter time for every frame the nominal times label them.
    rows = write_inputs(str(tmp_path), "y", Bracket(frames=frames, times=rel, valid=[None] * 3))
    assert [r["label"] for r in rows] == [format_time(t) for t in rel] and rows[0]["shutter"] is None
    assert shot_settings(infos, rel) is not None and shot_settings(infos, rel * [1, 1, 1.5]) is None


FROBISHER = Path(__file__).resolve().parents[2] / "shared" / "data" / "frobisher_001"


@pytest.mark.parametrize("typed", [False, True])
def test_merge_report_labels_real_exif(tmp_path, typed):
    """``merge --report`` on the Canon frames of ``frobisher_001``: labelled with their
    EXIF settings; with ``--times`` the EXIF does not bear out, with the times given."""
    from click.testing import CliRunner

    from hdrcl.cli import main
    from hdrcl.core.bracket import read_infos
    from hdrcl.io.metadata import format_time

    paths = sorted(str(p) for p in FROBISHER.glob("*.jpg"))
    if len(paths) != 3:
        pytest.skip(f"frobisher_001 not found at {FROBISHER}")
    infos = read_infos(paths)
    given = [0.05, 1.0, 20.0]
    args = ["merge", *paths, "-o", str(tmp_path / "f.exr"), "--report", str(tmp_path / "rep")]
    res = CliRunner().invoke(main, args + (["--times", ",".join(map(str, given))] if typed else []))
    assert res.exit_code == 0, res.output
    rows = load_set_report(tmp_path / "rep", "f").inputs
    if typed:
        want = [format_time(t) for t in given]
    else:
        want = [f"{format_time(i.exposure_time)} f/{i.fnumber:g} ISO {i.iso:g}" for i in infos]
        assert want[0].endswith(" f/8 ISO 100") and want[0].startswith("1/8 s")  # the set's README
    assert [r["label"] for r in rows] == want
    assert all(w in (tmp_path / "rep" / INDEX_NAME).read_text(encoding="utf-8") for w in want)


def test_aligned_merge_report_shows_each_frames_motion(tmp_path, cl_device):
    """``merge --align --report``: every frame's thumbnail says how it was aligned (the
    tripod set frobisher_001: the reference and two frames found not to move)."""
    from click.testing import CliRunner

    from hdrcl.cli import main
    from hdrcl.report.pages import alignment_text

    paths = sorted(str(p) for p in FROBISHER.glob("*.jpg"))
    if len(paths) != 3:
        pytest.skip(f"frobisher_001 not found at {FROBISHER}")
    res = CliRunner().invoke(main, ["merge", *paths, "-o", str(tmp_path / "f.exr"), "--align",
                                    "--report", str(tmp_path / "rep")])
    assert res.exit_code == 0, res.output
    rows = load_set_report(tmp_path / "rep", "f").inputs
    assert sorted(r["align"] for r in rows) == ["not moved", "not moved", "reference"]
    page = (tmp_path / "rep" / INDEX_NAME).read_text(encoding="utf-8")
    assert page.count("<span>aligned: not moved</span>") == 2 and "<span>aligned: reference</span>" in page
    text = alignment_text({"model": "similarity", "rotation_deg": 0.5, "scale": 1.002, "shift_px": [1.0, -2.0],
                           "residual_px": 0.12})
    assert text == "similarity +0.50° ×1.0020 (+1.0, -2.0) px residual 0.12 px"
