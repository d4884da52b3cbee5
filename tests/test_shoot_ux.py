"""Shoots as people bring them (issue 19): one folder per set, output names, a dry run,
the same defaults in merge and batch, exposure lists beside the frames, response caches
and response files named after the camera or the folder."""
from __future__ import annotations

import datetime as dt
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.core import synthetic
from hdrcl.io.ldr import write_ldr, write_photo

MEMORIAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "memorial"
TIMES = [1 / 1000, 1 / 250, 1 / 60, 1 / 15]
CAM = synthetic.Camera(a=1.1, x0=(1.0, 1.15, 0.85))


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def frames_of(seed, times=TIMES, w=48, h=32):
    scene = synthetic.radiance_field(h, w, decades=3.0, seed=seed) * 60.0
    return synthetic.bracket(scene, list(times), CAM, noise=0.5, seed=seed + 1)


def write_set(folder, prefix, seed, when, model="Canon EOS R6"):
    """One hand bracket of JPEGs with EXIF in ``folder``; returns the file names."""
    os.makedirs(folder, exist_ok=True)
    names = []
    for k, (t, frame) in enumerate(zip(TIMES, frames_of(seed))):
        name = f"{prefix}_{k + 1:04d}.jpg"
        write_photo(os.path.join(folder, name), frame,
                    {"ExposureTime": float(t), "FNumber": 8.0, "Exif:PhotographicSensitivity": 100,
                     "Exif:ExposureMode": 1, "Make": "Canon", "Model": model,
                     "Exif:DateTimeOriginal": (when + dt.timedelta(seconds=2 * k)).strftime("%Y:%m:%d %H:%M:%S")})
        names.append(name)
    return names


@pytest.fixture(scope="module")
def per_set(tmp_path_factory):
    """A shoot copied as one folder per set: shoot/{hall,porch,stairs}/IMG_*.jpg."""
    root = tmp_path_factory.mktemp("pershoot") / "shoot"
    when = dt.datetime(2024, 6, 1, 9, 0, 0)
    for k, folder in enumerate(("hall", "porch", "stairs")):
        write_set(root / folder, "IMG", 10 * k, when + dt.timedelta(days=k, minutes=5))
    return root


def written(folder: Path) -> list:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*")) if folder.exists() else []


def write_pngs(folder: Path, times, seed=3, listing=None):
    """PNG frames without EXIF, and an ``image_list.txt`` beside them (``listing`` lines)."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k, frame in enumerate(frames_of(seed, times)):
        p = folder / f"f{k}.png"
        write_ldr(str(p), frame)
        paths.append(str(p))
    if listing is not None:
        (folder / "image_list.txt").write_text(listing)
    return paths


# --------------------------------------------------------------- folder per set
def test_scan_descends_into_set_folders_and_says_so(per_set):
    res = run("scan", per_set, "--json")
    assert res.exit_code == 0, res.output
    sets = json.loads(res.stdout)["sets"]
    assert [os.path.basename(os.path.dirname(s["files"][0])) for s in sets] == ["hall", "porch", "stairs"]
    assert all(len(s["files"]) == len(TIMES) for s in sets)
    note = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(note) == 1 and "no photographs at its top" in note[0] and "-r" in note[0]


def test_a_frame_at_the_top_keeps_the_scan_flat_and_says_add_r(per_set, tmp_path):
    shoot = tmp_path / "shoot"
    shutil.copytree(per_set, shoot)
    shutil.copy(shoot / "hall" / "IMG_0001.jpg", shoot / "stray.jpg")
    res = run("scan", shoot, "--json")
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["sets"] == []
    assert "add -r" in res.stderr and str(len(TIMES) * 3) in res.stderr
    res = run("-q", "scan", shoot, "--json")
    assert res.stderr == ""


def test_an_output_folder_inside_the_set_is_not_a_subfolder_left_out(per_set, tmp_path):
    shoot = tmp_path / "hall"
    shutil.copytree(per_set / "hall", shoot)
    for _ in range(2):  # the second run finds the first one's previews below the set
        res = run("batch", shoot, "-o", shoot / "out", "--no-preview" if _ else "--preview")
        assert res.exit_code == 0, res.output
        assert "-r" not in res.stderr, res.stderr
    assert [p.name for p in (shoot / "out").glob("*.exr")] == ["IMG_0001.exr"]  # one folder: {first}


def test_batch_names_sets_after_their_folders_and_reruns_up_to_date(per_set, tmp_path):
    out = tmp_path / "out"
    res = run("batch", per_set, "-o", out)
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.glob("*.exr")) == ["hall.exr", "porch.exr", "stairs.exr"]
    again = run("batch", per_set, "-o", out)
    assert again.exit_code == 0, again.output
    assert "3 up to date" in again.stdout and "skipped" not in again.stdout
    statuses = [s["status"] for s in json.loads((out / "report.json").read_text())["sets"]]
    assert statuses == ["skipped"] * 3  # report.json keeps its status values


# ------------------------------------------------------------------- --name
def test_name_template_fields_and_an_idempotent_rerun(per_set, tmp_path):
    out = tmp_path / "out"
    template = "{date}_{index}_{camera}_{folder}_{first}"
    res = run("batch", per_set, "-o", out, "--name", template, "--no-preview")
    assert res.exit_code == 0, res.output
    want = [f"2024-06-0{k + 1}_{k + 1}_Canon_EOS_R6_{f}_IMG_0001.exr"
            for k, f in enumerate(("hall", "porch", "stairs"))]
    assert sorted(p.name for p in out.glob("*.exr")) == want
    again = run("batch", per_set, "-o", out, "--name", template, "--no-preview")
    assert again.exit_code == 0 and "3 up to date" in again.stdout, again.output


def test_index_is_padded_to_the_count(tmp_path):
    from hdrcl.shoot.batch.manifest import BracketSet, Manifest
    from hdrcl.shoot.batch.setnames import output_stems

    sets = [BracketSet(index=i, files=[f"/x/IMG_{i:04d}.jpg", f"/x/IMG_{i:04d}b.jpg"], exposures=[], reason="")
            for i in range(12)]
    stems = output_stems(Manifest(sets=sets, root="/x"), "pano-{index}")
    assert stems[0] == "pano-01" and stems[11] == "pano-12"
    assert output_stems(Manifest(sets=sets, root="/x")) [3] == "IMG_0003"  # one folder: {first}


@pytest.mark.parametrize("template, words", [
    ("{camera}", ["sets 0 and 1", "named 'Canon_EOS_R6'"]),
    ("{place}", ["unknown field {place}", "{folder}"]),
    ("{index:03d}", ["takes no format"]),
    ("{folder", ["--name"]),
])
def test_bad_templates_are_usage_errors_before_anything_is_written(per_set, tmp_path, template, words):
    out = tmp_path / "out"
    res = run("batch", per_set, "-o", out, "--name", template)
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("hdrcl: error:")]
    assert len(errors) == 1 and all(w in errors[0] for w in words), res.stderr
    assert not out.exists()


def test_unsafe_characters_are_replaced(per_set, tmp_path):
    out = tmp_path / "out"
    res = run("batch", per_set, "-o", out, "--name", 'a:b/c?{index}', "--no-preview", "--sets", "0")
    assert res.exit_code == 0, res.output
    assert [p.name for p in out.glob("*.exr")] == ["a_b_c_1.exr"]


# ----------------------------------------------------------------- --dry-run
def test_dry_run_prints_the_plan_and_writes_nothing(per_set, tmp_path):
    before = written(per_set)
    out, rep, cache = tmp_path / "out", tmp_path / "rep", tmp_path / "cache"
    res = run("batch", per_set, "-o", out, "--dry-run", "--report", rep, "--response-cache", cache)
    assert res.exit_code == 0, res.output
    assert written(tmp_path) == [] and written(per_set) == before
    lines = res.stdout.splitlines()
    assert sum(line.startswith("set ") for line in lines) == 3
    assert f"{len(TIMES)} frames, IMG_0001.jpg .. IMG_{len(TIMES):04d}.jpg, 1/1000 s .. 1/15 s" in res.stdout
    assert str(out / "porch.exr") in res.stdout
    assert str(cache / "Canon_EOS_R6_ISO_100.response.json") in res.stdout
    assert "pooled over sets 0, 1, 2" in res.stdout
    assert lines[-1].startswith("dry run: 3 set(s)")


def test_dry_run_json(per_set, tmp_path):
    out = tmp_path / "out"
    res = run("batch", per_set, "-o", out, "--dry-run", "--json", "--sets", "1-")
    assert res.exit_code == 0, res.output
    plan = json.loads(res.stdout)
    assert [s["index"] for s in plan["sets"]] == [1, 2]
    s = plan["sets"][0]
    assert s["frames"] == len(TIMES) and s["exposures"] == pytest.approx([min(TIMES), max(TIMES)])
    assert s["output"] == str(out / "porch.exr") and s["calibration"] == {"kind": "pooled", "sets": [0, 1, 2]}
    assert s["response"]["source"] == "calibrate"
    assert not out.exists()


# ------------------------------------------------------- defaults and lists
def test_merge_and_batch_share_their_defaults():
    import hdrcl.cli.core  # noqa: F401  (registers the commands)
    import hdrcl.cli.shoot  # noqa: F401

    merge = {p.name: p for p in main.get_command(None, "merge").params}
    batch = {p.name: p for p in main.get_command(None, "batch").params}
    shared = sorted(set(merge) & set(batch))
    assert {"fit_exposures", "weight", "dtype", "compression", "colorspace", "samples"} <= set(shared)
    assert [k for k in shared if merge[k].default != batch[k].default] == []


def test_merge_reads_the_image_list_beside_the_frames(tmp_path, cl_device):
    times = [1 / 60, 1 / 15, 1 / 4]
    # f/8 throughout; the last frame 6 dB of gain: twice the exposure of its time alone.
    listing = "".join(f"f{k}.png {t!r} {1 / t!r} 8 {6.0206 if k == 2 else 0} 0\n" for k, t in enumerate(times))
    with_list = write_pngs(tmp_path / "a", times, listing=listing)
    res = run("merge", *with_list, "-o", tmp_path / "a.exr")
    assert res.exit_code == 0, res.output
    assert f"exposures from {tmp_path / 'a' / 'image_list.txt'}" in res.stderr
    explicit = run("merge", *with_list, "--times", f"{times[0]!r},{times[1]!r},{2 * times[2]!r}",
                   "-o", tmp_path / "b.exr")
    assert explicit.exit_code == 0, explicit.output
    from hdrcl.io.radiance import read_radiance

    a, b = read_radiance(str(tmp_path / "a.exr"))[0], read_radiance(str(tmp_path / "b.exr"))[0]
    assert np.allclose(a, b, rtol=1e-3)


def test_header_exposures_take_fnumber_and_gain_from_the_list(tmp_path):
    from hdrcl.io.frames import read_info
    from hdrcl.io.metadata import header_exposures, relative_exposures

    times = [1 / 60, 1 / 15]
    paths = write_pngs(tmp_path, times, listing=f"f0.png {times[0]!r} 60 8 0 0\nf1.png {times[1]!r} 15 4 6 0\n")
    exposures, used = header_exposures(paths, [read_info(p) for p in paths])
    assert used == [str(tmp_path / "image_list.txt")]
    assert [e.fnumber for e in exposures] == [8, 4] and exposures[1].gain_db == 6
    rel = relative_exposures(exposures)
    assert rel[1] / rel[0] == pytest.approx(4 * (8 / 4) ** 2 * 10 ** (6 / 20))


def test_scan_uses_the_list_for_frames_without_exif_only(tmp_path):
    folder = tmp_path / "s"
    write_set(folder, "IMG", 1, dt.datetime(2024, 6, 1, 9))
    (folder / "times.txt").write_text("".join(f"IMG_{k + 1:04d}.jpg 1\n" for k in range(len(TIMES))))
    sets = json.loads(run("scan", folder, "--json").stdout)["sets"]
    assert sets[0]["exposures"] == pytest.approx(TIMES)  # EXIF wins over a list beside the frames


# ---------------------------------------------------------------- responses
def test_merge_response_cache(tmp_path, cl_device):
    times = [1 / 60, 1 / 15, 1 / 4]
    paths = write_pngs(tmp_path / "f", times, listing="".join(f"f{k}.png {t!r}\n" for k, t in enumerate(times)))
    cache = tmp_path / "camera.json"
    first = run("merge", *paths, "-o", tmp_path / "1.exr", "--response-cache", cache)
    assert first.exit_code == 0 and cache.is_file() and "(cached)" not in first.stdout, first.output
    saved = cache.read_bytes()
    second = run("merge", *paths, "-o", tmp_path / "2.exr", "--response-cache", cache)
    assert second.exit_code == 0 and f"response: {cache} (cached)" in second.stdout, second.output
    assert cache.read_bytes() == saved
    other = tmp_path / "other"
    jpgs = [str(other / n) for n in write_set(other, "IMG", 5, dt.datetime(2024, 6, 1, 9), model="Other Z")]
    third = run("merge", *jpgs, "-o", tmp_path / "3.exr", "--response-cache", cache)
    assert third.exit_code == 0, third.output
    assert "replacing it" in third.stderr and json.loads(cache.read_text())["camera"]["model"] == "Other Z"
    both = run("merge", *paths, "-o", tmp_path / "4.exr", "--response-cache", cache, "--response", cache)
    assert both.exit_code == 2


def test_batch_response_cache_folder(per_set, tmp_path):
    cache = tmp_path / "cache"
    one = run("batch", per_set, "-o", tmp_path / "one", "--response-cache", cache, "--no-preview", "--sets", "0")
    assert one.exit_code == 0, one.output
    assert sorted(p.name for p in cache.iterdir()) == ["Canon_EOS_R6_ISO_100.response.json"]
    assert not list((tmp_path / "one").glob("*.response.json"))
    two = run("batch", per_set, "-o", tmp_path / "two", "--response-cache", cache, "--no-preview", "--sets", "0")
    assert two.exit_code == 0, two.output
    (resp,) = json.loads((tmp_path / "two" / "report.json").read_text())["responses"]
    assert resp["source"] == "cached" and resp["file"] == str(cache / "Canon_EOS_R6_ISO_100.response.json")
    # The same output folder again: the cached curve is the one its set was merged with.
    again = run("batch", per_set, "-o", tmp_path / "one", "--response-cache", cache, "--no-preview", "--sets", "0")
    assert again.exit_code == 0 and "1 up to date" in again.stdout, again.output
    both = run("batch", per_set, "-o", tmp_path / "three", "--response-cache", cache, "--response",
               cache / "Canon_EOS_R6_ISO_100.response.json")
    assert both.exit_code == 2 and not (tmp_path / "three").exists()


@pytest.mark.skipif(not (MEMORIAL / "image_list.txt").is_file(), reason="../shared/data/memorial is absent")
def test_memorial_in_a_shoot_uses_its_list_and_is_named_after_its_folder(tmp_path):
    shoot = tmp_path / "shoot"
    paths = sorted(MEMORIAL.glob("*.png"))[::5]  # 4 frames, 5 stops apart
    (shoot / "memorial").mkdir(parents=True)
    lines = [line for line in (MEMORIAL / "image_list.txt").read_text().splitlines()
             if line.split()[:1] and line.split()[0] in {p.name for p in paths}]
    for p in paths:
        shutil.copy(p, shoot / "memorial")
    (shoot / "memorial" / "image_list.txt").write_text("\n".join(lines) + "\n")
    write_set(shoot / "hall", "IMG", 4, dt.datetime(2024, 6, 1, 9))  # f/8 ISO 100 with EXIF
    out = tmp_path / "out"
    res = run("batch", shoot, "-o", out, "--ignore-color", "0,0,255", "--no-preview")
    assert res.exit_code == 0, res.output
    rep = json.loads((out / "report.json").read_text())
    memorial = next(s for s in rep["sets"] if s["output"].endswith("memorial.exr"))
    assert not any("f-number" in w for w in memorial["warnings"]), memorial["warnings"]
    # Frames naming no camera: one camera per size and bit depth (issue 32 item 7).
    assert memorial["response"] == "unknown camera 768x512 8-bit", memorial["response"]
    assert (out / "unknown_camera_768x512_8_bit.response.json").is_file()
    assert (out / "Canon_EOS_R6_ISO_100.response.json").is_file()


def test_response_cache_keeps_out_frames_that_name_no_camera(tmp_path, cl_device):
    """Sets whose frames name no camera are one camera per size and bit depth within a
    shoot, but nothing says another shoot's are the same camera, so such a group is
    calibrated each time and never taken from, nor written to, the response cache."""
    shoot = tmp_path / "shoot" / "set01"
    shoot.mkdir(parents=True)
    frames = frames_of(5)
    lines = []
    for j, (f, t) in enumerate(zip(frames, TIMES)):
        write_photo(str(shoot / f"f{j}.png"), f)
        lines.append(f"f{j}.png {t}")
    (shoot / "times.txt").write_text("\n".join(lines) + "\n")
    cache = tmp_path / "cache"
    for out in ("one", "two"):
        res = run("batch", tmp_path / "shoot", "-o", tmp_path / out, "--response-cache", cache, "--no-preview")
        assert res.exit_code == 0, res.output
        (resp,) = json.loads((tmp_path / out / "report.json").read_text())["responses"]
        assert resp["source"] != "cached"
    assert not cache.exists() or not list(cache.iterdir())


def test_merge_and_batch_refuse_the_same_cached_curves(per_set, tmp_path):
    """One rule decides whether a cached curve stands for calibrating (issue 33:
    hdrcl.core.response_cache): batch took a curve that names no camera for any camera's
    frames, which merge refused. Both now say the same reason and calibrate again."""
    cache = tmp_path / "cache"
    one = run("batch", per_set, "-o", tmp_path / "one", "--response-cache", cache, "--no-preview", "--sets", "0")
    assert one.exit_code == 0, one.output
    (path,) = cache.iterdir()
    doc = json.loads(path.read_text())
    doc["camera"] = None  # a curve that names no camera, in this camera's place
    doc.pop("calibration", None)
    path.write_text(json.dumps(doc))
    again = run("batch", per_set, "-o", tmp_path / "two", "--response-cache", cache, "--no-preview", "--sets", "0")
    assert again.exit_code == 0, again.output
    assert "a response of an unnamed camera, but" in again.stderr and "calibrating" in again.stderr, again.stderr
    (resp,) = json.loads((tmp_path / "two" / "report.json").read_text())["responses"]
    assert resp["source"] != "cached"
    frames = sorted(str(p) for p in (per_set / "hall").iterdir())
    path.write_text(json.dumps(doc))
    merged = run("merge", *frames, "-o", tmp_path / "m.exr", "--response-cache", path)
    assert merged.exit_code == 0 and "a response of an unnamed camera, but" in merged.stderr, merged.output
