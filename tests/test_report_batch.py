"""The batch's quality report over a generated two-camera shoot (``shootgen``): each
frame labelled in its own camera's terms, and a re-run's page saying "up to date" with
the figures of the run that made the outputs.
"""
from __future__ import annotations

import json
import os
import re
from html.parser import HTMLParser

import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.core.bracket import read_infos
from hdrcl.io.metadata import format_time
from hdrcl.report.pages import load_set_report

try:
    import shootgen
except ImportError:  # tests/ made a package
    from tests import shootgen


def _run(*args):
    res = CliRunner().invoke(main, [str(a) for a in args])
    return res


class _Text(HTMLParser):
    def __init__(self):
        super().__init__()
        self.text = []

    def handle_data(self, data):
        self.text.append(data)


def _cards(page):
    """``{set name: (status, label, card html)}`` of the contact sheet."""
    out = {}
    for m in re.finditer(r'<article class="set [^"]*" id="set-\d+" data-set="([^"]+)" data-status="([^"]+)" '
                         r'data-label="([^"]+)"(.*?)</article>', page, re.S):
        out[m.group(1)] = (m.group(2), m.group(3), m.group(4))
    return out


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """The shoot merged twice into one output and report folder: the second run skips
    every set (its outputs are current)."""
    root = tmp_path_factory.mktemp("mixed")
    shoot, out, rep = root / "shoot", root / "out", root / "rep"
    shoot.mkdir()
    truth = shootgen.make_shoot(shoot)
    res = _run("batch", shoot, "-o", out, "--report", rep)
    first_page = (rep / "index.html").read_text(encoding="utf-8")
    first = json.loads((out / "report.json").read_text())
    again = _run("batch", shoot, "-o", out, "--report", rep)
    second = json.loads((out / "report.json").read_text())
    return truth, (res, first, first_page), (again, second, (rep / "index.html").read_text(encoding="utf-8")), rep


def _stem(entry):
    return os.path.splitext(os.path.basename(entry["output"]))[0]


def test_frames_labelled_in_their_cameras_terms(batch):
    """Canon at f/8 and f/11 ISO 100 and a Nikon at f/5.6 ISO 200 in one batch: the
    exposures are rescaled to one shoot-wide aperture and ISO for the radiometry, but
    every frame's caption is its own shutter time, f-number and ISO."""
    truth, (res, rep, page), _again, folder = batch
    assert res.exit_code == 1, res.output  # the shoot's corrupt file
    sets = [s for s in rep["sets"] if s["status"] == "done"]
    assert len(sets) == len(truth["sets"])
    text = "".join(_feed(page))
    rescaled = 0
    for s in sets:
        entry = load_set_report(folder, _stem(s))
        by_file = {r["file"]: r for r in entry.inputs}
        for path, info in zip(s["files"], read_infos(s["files"])):
            shot = truth["frames"][os.path.basename(path)]
            # What the header holds (the generator's float times become EXIF rationals).
            assert info.exposure_time == pytest.approx(shot["time"], rel=1e-3)
            row = by_file[os.path.basename(path)]
            want = f"{format_time(info.exposure_time)} f/{shot['fnumber']:g} ISO {shot['iso']}"
            assert row["label"] == want and want in text
            rescaled += abs(row["time"] / shot["time"] - 1) > 0.01
    # The test means something: some sets' radiometric times are not the camera's.
    assert rescaled >= 6


def _feed(page):
    p = _Text()
    p.feed(page)
    return p.text


def test_rerun_page_says_up_to_date_with_the_figures(batch):
    """A re-run skips every set: the page calls them "up to date" (not "skipped") and
    shows each one's figures, those the first run measured for the same outputs."""
    _truth, (_res, first, first_page), (again, second, page), folder = batch
    assert again.exit_code == 1, again.output
    done = [s for s in first["sets"] if s["status"] == "done"]
    assert {s["status"] for s in second["sets"] if s["index"] in {d["index"] for d in done}} == {"skipped"}
    cards, before = _cards(page), _cards(first_page)
    for s in done:
        status, label, card = cards[_stem(s)]
        assert (status, label) == ("skipped", "up to date")
        assert before[_stem(s)][:2] == ("done", "merged")
        assert '<table class="figures">' in card and '<span class="status">up to date</span>' in card
        entry = load_set_report(folder, _stem(s))
        assert entry.figures.to_dict() == s["quality"]  # the first run's figures
        assert json.loads((folder / entry.files["json"]).read_text())["label"] in ("merged", "up to date")
    assert f"{len(done)} up to date" in "".join(_feed(page)) and ">skipped<" not in page
