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

import numpy as np
import pytest

from hdrcl.core import synthetic as s
from hdrcl.core.bracket import load_bracket
from hdrcl.core.merge import merge_bracket
from hdrcl.report.pages import (
    INDEX_NAME,
    ReportEntry,
    format_figures,
    load_set_report,
    write_contact_sheet,
    write_set_report,
)
from hdrcl.report.plots import coverage_image, response_plot
from hdrcl.report.quality import measure

# (name, height, width, decades, frames): odd sizes; the last set is clipped at both ends.
SETS = [
    ("beach <sunset> & \"co\"", 47, 61, 4.0, 5),
    ("IMG_0100", 53, 71, 3.0, 5),
    ("café interior", 41, 59, 6.5, 3),
]
FAILED = ReportEntry(name="IMG_0200 <broken>", status="failed", error="IMG_0202.JPG: truncated file (3 of 6 MB)")


@pytest.fixture(scope="module")
def report(tmp_path_factory):
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
                                        warnings=res.warnings + [f"note <{k}> & more"]))
    entries.append(FAILED)
    index = write_contact_sheet(folder, entries)
    return folder, index, entries


def test_set_files(report):
    folder, index, entries = report
    assert os.path.basename(index) == INDEX_NAME
    for e in entries[:-1]:
        assert set(e.files) == {"response", "coverage", "preview", "json"}
        for f in e.files.values():
            assert (folder / f).is_file() and not f.startswith(".")
        d = json.loads((folder / e.files["json"]).read_text())
        assert d["name"] == e.name and d["figures"]["frames"] == e.figures.frames
        again = load_set_report(folder, e.name)
        assert again.figures.to_dict() == e.figures.to_dict() and again.files == e.files
    assert not [p for p in os.listdir(folder) if ".tmp-" in p]  # atomic writes left nothing behind
    assert load_set_report(folder, "no such set") is None


def test_plots_are_images():
    from hdrcl.core.response import Response

    g = np.stack([np.linspace(-5, 5, 256) + k * 0.1 for k in range(3)])
    img = response_plot(Response(bits=8, g=g, knots=np.arange(256.0)))
    assert img.shape == (400, 560, 3) and img.dtype == np.uint8
    for colour in ((205, 40, 40), (30, 150, 50), (40, 80, 210)):  # every channel's curve is drawn
        assert (img == colour).all(axis=2).sum() > 200
    cov = np.zeros((31, 47), np.uint8)
    cov[10:] = 3
    cov[:, :5] = 255  # no data
    out = coverage_image(cov, frames=3)
    assert out.dtype == np.uint8 and out.shape[1] >= 47 and out.shape[0] > 31
    assert len(np.unique(out.reshape(-1, 3), axis=0)) >= 5  # 0..3, no data, ink


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
    assert len(p.imgs) == 3 * len(SETS)
    from urllib.parse import unquote

    for ref in p.imgs + p.links:
        assert not re.match(r"^[a-z]+:", ref) and not ref.startswith("/")  # relative links only
        assert (folder / unquote(ref)).is_file(), ref


def _chromium() -> str:
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    if os.environ.get("HDRCL_REQUIRE_BROWSER", "") not in ("", "0"):
        pytest.fail("HDRCL_REQUIRE_BROWSER is set but neither chromium nor chromium-browser is on PATH "
                    "(Debian: apt-get install chromium)")
    pytest.skip("headless Chromium not found (Debian: apt-get install chromium); "
                "set HDRCL_REQUIRE_BROWSER=1 to make this an error")


def _run_chromium(browser, tmp_path, *args):
    cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", f"--user-data-dir={tmp_path / 'profile'}",
           "--virtual-time-budget=5000", *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}"
    return proc.stdout


def test_contact_sheet_in_chromium(report, tmp_path):
    """Done when: the HTML report opens in headless Chromium and shows every set."""
    browser = _chromium()
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
    # The page's own script counted the images that decoded, after the load event.
    m = re.search(r'id="image-check" data-loaded="(\d+)" data-total="(\d+)"', dom)
    assert m, "the page's load handler did not run: " + re.search(r'<p id="image-check"[^>]*>', dom).group(0)
    loaded, total = int(m.group(1)), int(m.group(2))
    assert total == len(p.imgs) == 3 * len(SETS)
    assert loaded == total, f"only {loaded} of {total} images loaded"

    shot = tmp_path / "sheet.png"
    _run_chromium(browser, tmp_path, "--hide-scrollbars", "--window-size=1280,1600", f"--screenshot={shot}", url)
    import OpenImageIO as oiio

    pixels = oiio.ImageBuf(str(shot)).get_pixels(oiio.UINT8)
    assert pixels.shape[:2] == (1600, 1280)
    rgb = pixels[..., :3].reshape(-1, 3)
    assert rgb.std() > 10  # not blank
    assert len(np.unique(rgb, axis=0)) > 500  # photographs and plots, not just text on a background
