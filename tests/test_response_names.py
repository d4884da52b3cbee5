"""Issue 34: files named after a camera follow the outputs' style (underscores, as the
frames' own names: ``Canon_EOS_R6_ISO_100.response.json`` beside ``IMG_0001.exr``), and a
curve an older version saved under the hyphenated name is still found: in the
``--response-cache`` folder and beside the outputs; what is written takes the new name."""
from __future__ import annotations

import datetime as dt
import json

import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.shoot.batch.names import legacy_slug, response_path, response_to_read, slug

try:
    from test_shoot_ux import write_set
except ImportError:  # tests/ made a package
    from tests.test_shoot_ux import write_set

NEW, OLD = "Canon_EOS_R6_ISO_100.response.json", "Canon-EOS-R6-ISO-100.response.json"


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def shoot(tmp_path_factory):
    root = tmp_path_factory.mktemp("names") / "shoot"
    write_set(root, "IMG", 3, dt.datetime(2024, 6, 1, 9, 0, 0))
    return root


def test_slugs_join_words_by_underscores():
    assert slug("Canon EOS R6 ISO 100") == "Canon_EOS_R6_ISO_100"
    assert slug("Canon EOS R6 #0123 ISO 100") == "Canon_EOS_R6_0123_ISO_100"
    assert slug("unknown camera 1600x1200 8-bit") == "unknown_camera_1600x1200_8_bit"
    assert slug("  #  ") == "camera"
    assert legacy_slug("unknown camera 1600x1200 8-bit") == "unknown-camera-1600x1200-8-bit"


def test_response_to_read_prefers_the_new_name_then_the_old(tmp_path):
    group = "Canon EOS R6 ISO 100"
    assert response_to_read(group, str(tmp_path)) == response_path(group, str(tmp_path)) == str(tmp_path / NEW)
    (tmp_path / OLD).write_text("{}")
    assert response_to_read(group, str(tmp_path)) == str(tmp_path / OLD)
    (tmp_path / NEW).write_text("{}")
    assert response_to_read(group, str(tmp_path)) == str(tmp_path / NEW)


def test_batch_writes_the_response_with_underscores_beside_the_outputs(shoot, tmp_path):
    out = tmp_path / "out"
    res = run("batch", shoot, "-o", out, "--no-preview")
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir() if p.name.endswith(".json")) == [NEW, "report.json"]
    assert (out / "IMG_0001.exr").is_file()


def test_an_old_hyphenated_cache_file_is_found_and_nothing_new_written(shoot, tmp_path):
    cache = tmp_path / "cache"
    first = run("batch", shoot, "-o", tmp_path / "one", "--response-cache", cache, "--no-preview")
    assert first.exit_code == 0, first.output
    (cache / NEW).rename(cache / OLD)  # as a version before issue 34 left it
    before = (cache / OLD).read_bytes()
    plan = run("batch", shoot, "-o", tmp_path / "two", "--response-cache", cache, "--dry-run", "--json")
    assert plan.exit_code == 0, plan.output
    (row,) = json.loads(plan.stdout)["sets"]
    assert row["response"]["source"] == "cached" and row["response"]["file"] == str(cache / OLD), row
    two = run("batch", shoot, "-o", tmp_path / "two", "--response-cache", cache, "--no-preview")
    assert two.exit_code == 0, two.output
    (resp,) = json.loads((tmp_path / "two" / "report.json").read_text())["responses"]
    assert resp["source"] == "cached" and resp["file"] == str(cache / OLD), resp
    assert sorted(p.name for p in cache.iterdir()) == [OLD] and (cache / OLD).read_bytes() == before
    # A curve that no longer fits (another bit depth) is calibrated again: written under the new name.
    doc = json.loads(before)
    doc["bits"] = 16
    (cache / OLD).write_text(json.dumps(doc))
    three = run("batch", shoot, "-o", tmp_path / "three", "--response-cache", cache, "--no-preview")
    assert three.exit_code == 0, three.output
    assert (cache / NEW).is_file()
    (resp,) = json.loads((tmp_path / "three" / "report.json").read_text())["responses"]
    assert resp["file"] == str(cache / NEW), resp


def test_an_old_hyphenated_curve_beside_the_outputs_keeps_its_sets_up_to_date(shoot, tmp_path):
    out = tmp_path / "out"
    assert run("batch", shoot, "-o", out, "--no-preview").exit_code == 0
    (out / NEW).rename(out / OLD)
    again = run("batch", shoot, "-o", out, "--no-preview")
    assert again.exit_code == 0 and "1 up to date" in again.stdout, again.output
    assert not (out / NEW).exists()
    (resp,) = json.loads((out / "report.json").read_text())["responses"]
    assert resp["file"] == str(out / OLD), resp
