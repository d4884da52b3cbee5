"""``hdrcl batch``: a generated shoot end to end, failures kept local, reruns, chunks, kills.

Everything runs on small JPEGs with real EXIF (``shootgen`` and :func:`make_clean_shoot`)
through the command line, in process with ``CliRunner`` except where a real process
must be killed.
"""
from __future__ import annotations

import datetime as dt
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from click.testing import CliRunner

import hdrcl
from hdrcl.cli import main
from hdrcl.errors import UsageError
from hdrcl.io.radiance import read_metadata, read_radiance
from hdrcl.io.ldr import write_photo
from hdrcl.shoot.batch.jobs import BatchOptions, SetResult
from hdrcl.shoot.batch.manifest import BracketSet, Manifest
from hdrcl.shoot.batch.plan import parse_sets, select_sets
from hdrcl.shoot.batch.setnames import output_stems

try:
    import shootgen
except ImportError:  # tests/ made a package
    from tests import shootgen

REPO = os.path.dirname(os.path.dirname(os.path.abspath(hdrcl.__file__)))


# ------------------------------------------------------------------------ helpers


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def make_clean_shoot(folder, sets=3, frames=3, width=64, height=48, seed=0):
    """A shoot with no bad files: ``sets`` hand brackets of ``frames`` frames, 60 s apart."""
    from hdrcl.core import synthetic

    os.makedirs(folder, exist_ok=True)
    cam = synthetic.Camera(a=1.1, x0=(1.0, 1.15, 0.85))
    rng = np.random.default_rng(seed)
    when = dt.datetime(2024, 6, 1, 9, 0, 0)
    times = [1 / 1000, 1 / 250, 1 / 60, 1 / 15, 1 / 4][:frames]
    groups, n = [], 0
    for s in range(sets):
        scene = synthetic.radiance_field(height, width, decades=3.0, seed=seed * 100 + s) * 60.0
        group = []
        for t in times:
            frame = synthetic.bracket(scene, [t], cam, noise=0.5, seed=int(rng.integers(1 << 30)))[0]
            n += 1
            path = os.path.join(folder, f"IMG_{n:04d}.jpg")
            write_photo(path, frame, {"ExposureTime": float(t), "FNumber": 8.0, "Exif:PhotographicSensitivity": 100,
                                      "Exif:ExposureMode": 1, "Make": "Canon", "Model": "Canon EOS R6",
                                      "Exif:DateTimeOriginal": when.strftime("%Y:%m:%d %H:%M:%S")})
            group.append(os.path.basename(path))
            when += dt.timedelta(seconds=t + 2.0)
        groups.append(group)
        when += dt.timedelta(seconds=60)
    return groups


def report_of(out):
    with open(os.path.join(out, "report.json")) as fh:
        return json.load(fh)


def outputs(out, ext):
    return sorted(n for n in os.listdir(out) if n.endswith(ext) and not n.startswith("."))


def same_bytes(a, b):
    with open(a, "rb") as fa, open(b, "rb") as fb:
        return fa.read() == fb.read()


# ----------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def shoot(tmp_path_factory):
    folder = tmp_path_factory.mktemp("shoot")
    truth = shootgen.make_shoot(folder)
    return str(folder), truth


@pytest.fixture(scope="module")
def manifest(shoot, tmp_path_factory):
    folder, _ = shoot
    path = tmp_path_factory.mktemp("manifest") / "manifest.json"
    assert run("scan", folder, "-o", path).exit_code == 0
    return str(path)


@pytest.fixture(scope="module")
def full(shoot, tmp_path_factory):
    """The whole generated shoot (with its corrupt file) merged once."""
    folder, _ = shoot
    out = str(tmp_path_factory.mktemp("full"))
    res = run("batch", folder, "-o", out)
    return out, res


@pytest.fixture
def clean(tmp_path):
    folder = tmp_path / "clean"
    groups = make_clean_shoot(folder)
    return str(folder), groups


# -------------------------------------------------------------- the whole shoot


def test_shoot_every_output_and_the_failure_reported(shoot, full):
    folder, truth = shoot
    out, res = full
    assert res.exit_code == 1, res.output  # the corrupt file is a failure of this run
    expected = sorted(os.path.splitext(s[0])[0] for s in truth["sets"])
    assert [os.path.splitext(n)[0] for n in outputs(out, ".exr")] == expected
    assert [os.path.splitext(n)[0] for n in outputs(out, ".jpg")] == expected
    rep = report_of(out)
    assert [s["status"] for s in rep["sets"]] == ["done"] * len(truth["sets"])
    bad = [u for u in rep["unmerged"] if u["reason"].startswith("corrupt")]
    assert [os.path.basename(f) for u in bad for f in u["files"]] == ["IMG_0016.jpg"]
    assert rep["summary"]["unreadable_files"] == 1
    assert "IMG_0016.jpg" in res.stdout and "8 done" in res.stdout
    # One response per camera body and ISO, saved beside the outputs.
    resp = sorted(n for n in os.listdir(out) if n.endswith(".response.json"))
    assert len(resp) == 2 and any("Canon" in n for n in resp) and any("NIKON" in n for n in resp)


def test_report_contract(shoot, full):
    folder, truth = shoot
    out, _ = full
    rep = report_of(out)
    for entry, files in zip(rep["sets"], truth["sets"]):
        assert {"index", "files", "status", "output", "error"} <= set(entry)
        assert [os.path.basename(f) for f in entry["files"]] == files
        assert os.path.dirname(entry["output"]) == os.path.abspath(out)
        assert os.path.isfile(entry["output"]) and entry["error"] is None
        assert set(entry["counts"]) == {"clipped_high", "clipped_low", "no_data"}
        assert {"hash", "open", "merge", "preview", "write", "total"} <= set(entry["seconds"])
    assert [s["index"] for s in rep["sets"]] == list(range(len(truth["sets"])))


def test_exr_carries_identity_scale_and_capture_time(shoot, full):
    folder, truth = shoot
    out, _ = full
    rep = report_of(out)
    entry = rep["sets"][0]
    meta = read_metadata(entry["output"])
    assert meta["inputHash"] == entry["hash"]
    # Four of the eight sets are shot at f/11, ISO 100: that is the shoot's reference.
    assert meta["exposureRef"] == "f/11 ISO 100"
    assert meta["evOffset"] == pytest.approx(np.log2((11 / 8) ** 2), abs=1e-4)  # set 0: f/8
    assert read_metadata(rep["sets"][-1]["output"])["evOffset"] == pytest.approx(0.0)
    nikon = next(s for s in rep["sets"] if os.path.basename(s["files"][0]).startswith("DSC"))
    # Camera B shot at f/5.6, ISO 200: (11 / 5.6)^2 * 2 more light per second.
    assert read_metadata(nikon["output"])["evOffset"] == pytest.approx(np.log2((11 / 5.6) ** 2 * 2), abs=1e-4)
    import OpenImageIO as oiio  # the capture time, not the time of writing: reproducible bytes

    inp = oiio.ImageInput.open(entry["output"])
    assert inp.spec().getattribute("DateTime") == "2024:06:01 10:00:00"
    inp.close()
    pmeta = read_metadata(entry["preview"])
    assert pmeta["inputHash"] == entry["hash"]


def test_rerun_skips_everything(shoot, full):
    folder, _ = shoot
    out, _ = full
    before = {n: os.stat(os.path.join(out, n)).st_mtime_ns for n in outputs(out, ".exr") + outputs(out, ".jpg")}
    res = run("batch", folder, "-o", out)
    assert res.exit_code == 1  # still the corrupt file
    assert [s["status"] for s in report_of(out)["sets"]] == ["skipped"] * 8
    after = {n: os.stat(os.path.join(out, n)).st_mtime_ns for n in before}
    assert after == before


# ------------------------------------------------------------- local failures


def test_bad_set_fails_alone(shoot, tmp_path):
    folder, truth = shoot
    copy = tmp_path / "copy"
    shutil.copytree(folder, copy)
    man = tmp_path / "manifest.json"
    assert run("scan", copy, "-o", man).exit_code == 0
    # After the scan: one frame of set 2 is truncated, one of set 1 disappears.
    victim = copy / truth["sets"][2][3]
    data = victim.read_bytes()
    victim.write_bytes(data[: len(data) // 2])
    os.remove(copy / truth["sets"][1][1])
    os.remove(copy / truth["sets"][5][0])  # a first frame: the set's camera is unknown too
    out = tmp_path / "out"
    res = run("batch", man, "-o", out)
    assert res.exit_code == 1, res.output
    rep = report_of(out)
    status = {s["index"]: s for s in rep["sets"]}
    assert status[1]["status"] == "failed" and "no such file" in status[1]["error"]
    assert status[2]["status"] == "failed" and "Premature end of JPEG file" in status[2]["error"]
    assert truth["sets"][2][3] in status[2]["error"]
    assert status[5]["status"] == "failed" and "no such file" in status[5]["error"]
    assert truth["sets"][5][0] in status[5]["error"]
    assert all(s["status"] == "done" for i, s in status.items() if i not in (1, 2, 5))
    assert len(outputs(out, ".exr")) == len(truth["sets"]) - 3
    assert "failed: set 2" in res.stdout
    # The pooled calibration left the broken sets out, and says so.
    canon = next(r for r in rep["responses"] if r["group"].startswith("Canon"))
    assert 1 not in canon["pooled_sets"] and 2 not in canon["pooled_sets"]


def test_missing_exposure_and_wrong_size_fail_alone(tmp_path):
    from hdrcl.core import synthetic

    scene = synthetic.radiance_field(48, 64, decades=3.0, seed=3) * 60.0
    cam = synthetic.Camera()
    times = [1 / 250, 1 / 60, 1 / 15]
    frames = synthetic.bracket(scene, times, cam, seed=1)
    big = synthetic.bracket(synthetic.radiance_field(60, 80, seed=4) * 60.0, times, cam, seed=2)
    files = {}
    for name in ("a", "b", "c"):
        for k in range(3):
            p = str(tmp_path / f"{name}{k}.jpg")
            exif = {"Make": "Canon", "Model": "Canon EOS R6"}  # no ExposureTime
            write_photo(p, big[k] if (name == "c" and k == 2) else frames[k], exif)
            files.setdefault(name, []).append(p)
    man = tmp_path / "m.json"
    man.write_text(json.dumps({"sets": [
        {"files": files["a"]},                                # exposure missing
        {"files": files["b"], "exposures": times},            # exposures by hand: fine
        {"files": files["c"], "exposures": times},            # a frame of another size
    ]}))
    out = tmp_path / "out"
    res = run("batch", man, "-o", out)
    assert res.exit_code == 1, res.output
    rep = {s["index"]: s for s in report_of(out)["sets"]}
    assert rep[0]["status"] == "failed" and "no exposure time" in rep[0]["error"]
    assert rep[1]["status"] == "done"
    assert rep[2]["status"] == "failed" and "differs" in rep[2]["error"]


# ------------------------------------------------------------ one exposure scale


def test_sample_shoot_panorama_matches(tmp_path):
    shoot_dir, out = tmp_path / "shoot", tmp_path / "out"
    res = run("sample-shoot", shoot_dir)
    assert res.exit_code == 0, res.output
    d = json.loads(run("scan", shoot_dir, "--json").stdout)
    assert [len(s["files"]) for s in d["sets"]] == [3, 3, 5] and len(d["unmerged"]) == 1
    res = run("batch", shoot_dir, "-o", out)
    assert res.exit_code == 0, res.output
    v1, _ = read_radiance(out / "PANO_0004.exr")
    v2, meta = read_radiance(out / "PANO_0007.exr")
    # View 3 was shot at f/5.6, ISO 200; on the shoot's scale it matches view 2 where
    # they overlap (the right half of view 2 is the left half of view 3).
    half = v1.shape[1] // 2
    ratio = np.median(v2[:, 8:half - 8] / v1[:, half + 8:-8])
    assert ratio == pytest.approx(1.0, abs=0.03)
    assert meta["evOffset"] == pytest.approx(np.log2((8 / 5.6) ** 2 * 2), abs=1e-4)


def test_ev_offset_relates_batch_to_merge(tmp_path):
    """``hdrcl merge`` of a set with the same response = batch radiance * 2**evOffset."""
    shoot_dir, out = tmp_path / "shoot", tmp_path / "out"
    assert run("sample-shoot", shoot_dir, "--size", "64x48").exit_code == 0
    assert run("batch", shoot_dir, "-o", out, "--dtype", "float", "--no-preview").exit_code == 0
    resp = next(n for n in os.listdir(out) if "ISO_200" in n)
    frames = [shoot_dir / f"PANO_{k:04d}.jpg" for k in range(7, 12)]
    res = run("merge", *frames, "-o", tmp_path / "m.exr", "--response", out / resp, "--dtype", "float")
    assert res.exit_code == 0, res.output
    batch, meta = read_radiance(out / "PANO_0007.exr")
    merged, _ = read_radiance(tmp_path / "m.exr")
    assert meta["evOffset"] == pytest.approx(2.029, abs=1e-3)
    assert np.allclose(merged, batch * 2.0 ** meta["evOffset"], rtol=1e-5)
    assert not outputs(out, ".jpg")


# ------------------------------------------------------------ idempotence


def test_parameters_are_part_of_the_identity(clean, tmp_path):
    folder, groups = clean
    out = tmp_path / "out"
    assert run("batch", folder, "-o", out).exit_code == 0
    exr = out / f"{os.path.splitext(groups[0][0])[0]}.exr"
    stamp = exr.stat().st_mtime_ns
    res = run("batch", folder, "-o", out)
    assert res.exit_code == 0 and "3 up to date" in res.stdout
    assert exr.stat().st_mtime_ns == stamp
    res = run("batch", folder, "-o", out, "--compression", "zip")
    assert res.exit_code == 0 and "3 done" in res.stdout
    res = run("batch", folder, "-o", out, "--compression", "zip", "--force")
    assert res.exit_code == 0 and "3 done" in res.stdout
    res = run("batch", folder, "-o", out, "--compression", "zip", "--weight", "gaussian", "--deghost")
    assert "3 done" in res.stdout  # new response, fusion weights and deghosting
    assert set(report_of(out)["sets"][0]["counts"]) >= {"ghost", "ghost_unresolved"}
    res = run("batch", folder, "-o", out, "--compression", "zip", "--weight", "gaussian")
    assert "3 done" in res.stdout
    # A lost preview is rebuilt from its EXR; the EXR stays.
    preview = out / f"{os.path.splitext(groups[1][0])[0]}.jpg"
    preview.unlink()
    exr1 = preview.with_suffix(".exr")
    stamp = exr1.stat().st_mtime_ns
    res = run("batch", folder, "-o", out, "--compression", "zip", "--weight", "gaussian")
    assert res.exit_code == 0 and "3 up to date" in res.stdout
    assert preview.is_file() and exr1.stat().st_mtime_ns == stamp
    entry = report_of(out)["sets"][1]
    assert any("preview" in w for w in entry["warnings"])


def test_killed_run_is_finished_by_the_next(tmp_path):
    """SIGKILL part-way, run again: every output complete; a third run does nothing."""
    folder, out = tmp_path / "shoot", tmp_path / "out"
    groups = make_clean_shoot(folder, sets=8, frames=3, width=800, height=600)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (REPO, os.environ.get("PYTHONPATH")) if p))
    cmd = [sys.executable, "-m", "hdrcl", "batch", str(folder), "-o", str(out)]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline:
        if out.is_dir() and outputs(out, ".exr"):
            break
        time.sleep(0.002)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL, "the first run finished before it could be killed"
    finished_before = set(outputs(out, ".exr"))
    assert 0 < len(finished_before) < len(groups)

    second = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert second.returncode == 0, second.stderr
    rep = report_of(out)
    status = {os.path.basename(s["output"]): s["status"] for s in rep["sets"]}
    assert all(status[n] == "skipped" for n in finished_before)
    assert sum(v == "done" for v in status.values()) == len(groups) - len(finished_before)
    for entry in rep["sets"]:  # complete, readable, and what the report says
        pixels, meta = read_radiance(entry["output"])
        assert pixels.shape == (600, 800, 3) and np.isfinite(pixels).all()
        assert meta["inputHash"] == entry["hash"]
        assert read_metadata(entry["preview"])["inputHash"] == entry["hash"]
        assert read_radiance(entry["preview"])[0].shape == (384, 512, 3)
    stamps = {n: os.stat(out / n).st_mtime_ns for n in outputs(out, ".exr")}

    third = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert third.returncode == 0, third.stderr
    assert {s["status"] for s in report_of(out)["sets"]} == {"skipped"}
    assert {n: os.stat(out / n).st_mtime_ns for n in outputs(out, ".exr")} == stamps
    assert not [n for n in os.listdir(out) if ".tmp" in n]  # the killed run's litter is gone


# --------------------------------------------------- chunks and processes agree


def test_chunks_and_processes_give_identical_files(manifest, full, tmp_path):
    ref, _ = full
    chunks = tmp_path / "chunks"
    for sel, mine in (("0-2", [0, 1, 2]), ("3-5", [3, 4, 5]), ("6-99", [6, 7])):  # 6-99: clamped to the real sets
        res = run("batch", manifest, "-o", chunks, "--sets", sel, "--json")
        assert res.exit_code == 0, res.output  # chunks do not own the unreadable file
        said = json.loads(res.stdout)  # a chunk's --json is its own sets (issue 34)
        assert [s["index"] for s in said["sets"]] == mine
        assert said["summary"]["sets"] == said["summary"]["done"] == len(mine)
    procs = tmp_path / "procs"
    res = run("batch", manifest, "-o", procs, "--jobs", "2")
    assert res.exit_code == 1  # the whole manifest: the corrupt file counts
    for name in outputs(ref, ".exr") + outputs(ref, ".jpg") + outputs(ref, ".response.json"):
        assert same_bytes(os.path.join(ref, name), chunks / name), name
        assert same_bytes(os.path.join(ref, name), procs / name), name
    rep = report_of(chunks)  # the chunks' reports merged into one
    assert [s["index"] for s in rep["sets"]] == list(range(8))
    assert {s["status"] for s in rep["sets"]} == {"done"}


def test_calibrate_only_then_given_response(manifest, tmp_path):
    out = tmp_path / "out"
    res = run("batch", manifest, "-o", out, "--calibrate-only")
    assert res.exit_code == 0, res.output
    saved = sorted(n for n in os.listdir(out) if n.endswith(".response.json"))
    assert len(saved) == 2 and not outputs(out, ".exr")
    res = run("batch", manifest, "-o", out, "--sets", "0")
    assert res.exit_code == 0
    assert {r["source"] for r in report_of(out)["responses"]} == {"loaded"}

    given = tmp_path / "given"
    res = run("batch", manifest, "-o", given, "--sets", "0-1", "--response", out / saved[0], "--json")
    assert res.exit_code == 0, res.output
    rep = json.loads(res.stdout)
    assert [r["source"] for r in rep["responses"]] == ["given"]
    assert not [n for n in os.listdir(given) if n.endswith(".response.json")]


# ------------------------------------------------------------------ selection


def test_parse_sets():
    assert parse_sets("3-7") == [(3, 7)]
    assert parse_sets("5") == [(5, 5)]
    assert parse_sets("10-") == [(10, None)]
    assert parse_sets("-2, 4,6-8") == [(0, 2), (4, 4), (6, 8)]
    for bad in ("", "a-b", "7-3", "1-2-3", "-"):
        with pytest.raises(UsageError):
            parse_sets(bad)
    sets = [BracketSet(index=i, files=[f"f{i}"], exposures=[], reason="") for i in (0, 1, 2, 5, 9)]
    assert [s.index for s in select_sets(sets, parse_sets("1-5"))] == [1, 2, 5]
    assert [s.index for s in select_sets(sets, parse_sets("8-1000"))] == [9]
    assert select_sets(sets, parse_sets("50-60")) == []


def test_sets_beyond_the_end_do_nothing(manifest, tmp_path):
    res = run("batch", manifest, "-o", tmp_path / "o", "--sets", "40-49")
    assert res.exit_code == 0 and "no bracket sets" in res.stdout


def test_output_names_are_unique_and_stable():
    def bs(i, path):
        return BracketSet(index=i, files=[path, path + "x"], exposures=[], reason="")

    m = Manifest(sets=[bs(0, "/x/day1/IMG_0001.jpg"), bs(1, "/x/day2/IMG_0001.jpg"),
                       bs(2, "/x/day2/IMG_0001.tif"), bs(3, "/x/a/img_0005.jpg"), bs(4, "/x/a/IMG_0005.JPG"),
                       bs(5, "/x/day1/IMG_0002.jpg")])
    names = output_stems(m)
    assert names[0] == "day1_IMG_0001" and names[5] == "IMG_0002"
    assert names[1] == "day2_IMG_0001_jpg" and names[2] == "day2_IMG_0001_tif"
    assert len({n.casefold() for n in names.values()}) == 6
    # Selecting sets does not rename anything: names come from the whole manifest.
    assert output_stems(m) == names


# ----------------------------------------------------------- previews, progress


def test_preview_tone_map():
    from hdrcl.report.preview import AreaAverage, downscale, preview, tone_map

    rng = np.random.default_rng(0)
    rad = np.exp(rng.normal(0, 2, (31, 47, 3))).astype(np.float32)
    small = downscale(rad, 16)
    assert small.shape == (11, 16, 3)
    assert downscale(np.full((31, 47, 1), 2.5), 16) == pytest.approx(np.full((11, 16, 1), 2.5))
    assert downscale(rad, 512).shape == rad.shape  # never enlarged
    acc = AreaAverage(31, 47, 3, 16)  # the same reduction from strips, as batch streams them
    for y0 in range(0, 31, 4):
        acc.write_rows(y0, min(31, y0 + 4), rad[y0:y0 + 4])
    assert np.allclose(acc.result(), small, rtol=1e-12)
    mapped = tone_map(rad)
    assert mapped.min() >= 0 and mapped.max() <= 1
    inside = (mapped < 1).all(axis=2)  # colour ratios kept where nothing clips
    assert np.allclose(mapped[inside][:, 0] / mapped[inside][:, 1], rad[inside][:, 0] / rad[inside][:, 1],
                       rtol=1e-6)
    grey = tone_map(rad[..., :1]).ravel()
    order = np.argsort(rad[..., 0].ravel(), kind="stable")
    assert np.all(np.diff(grey[order]) >= 0)  # monotonic in luminance
    grey = preview(np.repeat(rad[..., :1], 3, axis=2), 16)
    assert grey.dtype == np.uint8 and (grey[..., 0] == grey[..., 2]).all()
    assert np.array_equal(preview(rad), preview(rad))


def test_progress_bar_and_plain_lines():
    from hdrcl.cli.shoot import _Progress

    ok = SetResult(index=0, files=["a.jpg"], status="done", output="/o/a.exr", seconds={"total": 0.5})
    bad = SetResult(index=1, files=["b.jpg"], status="failed", output="/o/b.exr", error="b.jpg: truncated")
    tty = io.StringIO()
    bar = _Progress(tty, tty=True, quiet=False)
    bar(None, 0, 2)
    bar(ok, 1, 2)
    bar(bad, 2, 2)
    bar.close()
    text = tty.getvalue()
    assert "\r" in text and "2/2 sets" in text and "set 1 (b.exr) failed: b.jpg: truncated\n" in text
    log = io.StringIO()
    lines = _Progress(log, tty=False, quiet=False)
    lines(None, 0, 2)
    lines(ok, 1, 2)
    lines(bad, 2, 2)
    assert log.getvalue().splitlines() == ["hdrcl: [1/2] set 0 a.exr: done (0.50 s)",
                                           "hdrcl: [2/2] set 1 b.exr: failed (0.00 s): b.jpg: truncated"]
    assert "\r" not in log.getvalue()


def test_progress_lines_in_cli_logs(clean, tmp_path):
    folder, _ = clean
    res = run("batch", folder, "-o", tmp_path / "o")
    assert res.exit_code == 0
    assert [ln.split("]")[0] for ln in res.stderr.splitlines() if ln.startswith("hdrcl: [")] == \
        ["hdrcl: [1/3", "hdrcl: [2/3", "hdrcl: [3/3"]


# ----------------------------------------------------------------- exit codes


@pytest.mark.parametrize("args, code", [
    (["batch", "{missing}", "-o", "{out}"], 3),
    (["batch", "{bad_json}", "-o", "{out}"], 3),
    (["batch", "{folder}", "-o", "{out}", "--response", "{missing}"], 3),
    (["batch", "{folder}", "-o", "{out}", "--jobs", "0"], 2),
    (["batch", "{folder}", "-o", "{out}", "--jobs", "2", "--scheduler", "tcp://127.0.0.1:1"], 2),
    (["batch", "{folder}", "-o", "{out}", "--compression", "lzma"], 2),
    (["batch", "{folder}", "-o", "{out}", "--sets", "a-b"], 2),
    (["batch", "{manifest}", "-o", "{out}", "--gap", "3"], 2),
    (["batch", "{folder}", "-o", "{a_file}"], 2),
])
def test_exit_codes(clean, tmp_path, args, code):
    folder, _ = clean
    bad = tmp_path / "bad.json"
    bad.write_text("[1, 2")
    man = tmp_path / "m.json"
    man.write_text(json.dumps({"sets": []}))
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    paths = {"missing": tmp_path / "nope", "bad_json": bad, "folder": folder, "manifest": man,
             "out": tmp_path / "out", "a_file": a_file}
    res = CliRunner().invoke(main, [a.format(**paths) for a in args])
    assert res.exit_code == code, res.output


def test_library_entry_point(clean, tmp_path):
    from hdrcl.shoot.batch.run import run_batch

    folder, groups = clean
    seen = []
    rep = run_batch(folder, tmp_path / "o", options=BatchOptions(preview=False, dtype="float"),
                    progress=lambda r, n, total: seen.append((r.status if r else None, n, total)))
    assert rep.exit_code == 0 and [r.status for r in rep.results] == ["done"] * 3
    assert seen[0] == (None, 0, 3) and seen[-1][1:] == (3, 3)
    assert not outputs(tmp_path / "o", ".jpg")
    assert read_radiance(rep.results[0].output)[0].dtype == np.float32


# ------------------------------------------------------------- quality report


def _statuses(page):
    return dict(re.findall(r'data-set="([^"]+)" data-status="([^"]+)"', page))


def test_quality_report_in_chromium(tmp_path, chromium_path):
    """Done when: the batch's HTML report opens in headless Chromium and shows every set.

    A farm chunk first (the sheet lists the whole manifest, the other sets pending),
    then the rest in worker processes; the EXRs are those of a run without a report.
    """
    from html.parser import HTMLParser

    from hdrcl.report.pages import format_figures, load_set_report
    from hdrcl.shoot.batch.plan import load_source

    browser = chromium_path
    shoot_dir, out, rep_dir, plain = (tmp_path / n for n in ("shoot", "out", "rep", "plain"))
    assert run("sample-shoot", shoot_dir).exit_code == 0
    stems = [output_stems(load_source(shoot_dir))[i] for i in range(3)]
    assert stems == ["PANO_0001", "PANO_0004", "PANO_0007"]

    res = run("batch", shoot_dir, "-o", out, "--report", rep_dir, "--sets", "0", "--report-json", out / "chunk.json")
    assert res.exit_code == 0, res.output
    assert (out / "chunk.json").is_file() and not (out / "report.json").exists()
    assert _statuses((rep_dir / "index.html").read_text()) == {stems[0]: "done", stems[1]: "pending",
                                                               stems[2]: "pending"}
    res = run("batch", shoot_dir, "-o", out, "--report", rep_dir, "--jobs", "2")
    assert res.exit_code == 0, res.output
    assert f"quality report: {rep_dir / 'index.html'}" in res.stdout
    assert run("batch", shoot_dir, "-o", plain).exit_code == 0
    for name in outputs(plain, ".exr") + outputs(plain, ".jpg"):
        assert same_bytes(plain / name, out / name), name  # the report adds files, changes none

    sets = report_of(out)["sets"]
    assert [s["status"] for s in sets] == ["skipped", "done", "done"]
    entries = [load_set_report(rep_dir, stem) for stem in stems]
    for s, e in zip(sets, entries):
        assert set(e.files) == {"response", "histogram", "coverage", "preview", "json"}
        assert len(e.inputs) == len(s["files"]) and e.camera.get("camera")
        assert s["quality"] == e.figures.to_dict()  # report.json carries the same figures
        assert e.figures.frames == len(s["files"]) and e.figures.loo_rmse is not None

    url = "file://" + os.path.abspath(rep_dir / "index.html")
    cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", f"--user-data-dir={tmp_path / 'profile'}",
           "--virtual-time-budget=5000", "--dump-dom", url]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}"
    dom = proc.stdout

    class Page(HTMLParser):
        def __init__(self):
            super().__init__()
            self.imgs, self.text = 0, []

        def handle_starttag(self, tag, attrs):
            self.imgs += tag == "img"

        def handle_data(self, data):
            self.text.append(data)

    p = Page()
    p.feed(dom)
    text = "".join(p.text)
    assert _statuses(dom) == {stems[0]: "skipped", stems[1]: "done", stems[2]: "done"}
    for e in entries:
        assert e.name in text, f"set {e.name} missing from the rendered page"
        for label, value in format_figures(e.figures):
            assert label in text and value in text, (e.name, label, value)
    # The page's own script counted the images that decoded, after the load event.
    m = re.search(r'id="image-check" data-loaded="(\d+)" data-total="(\d+)"', dom)
    assert m, "the page's load handler did not run"
    # per set: preview, response, histogram, coverage map and a thumbnail per frame; the stray frame
    assert int(m.group(2)) == p.imgs == sum(4 + len(e.inputs) for e in entries) + 1
    assert "Not merged: 1 file in 1 group" in text
    assert m.group(1) == m.group(2), f"only {m.group(1)} of {m.group(2)} images loaded"
