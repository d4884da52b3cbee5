"""The merge engine (hdrcl.core.engine): one backend decision per job, the batch's set
measured and checked as merge does it, the options object's rules."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest


def _bracket(folder, name, h, w, seed=0):
    """PNG frames of one smooth scene at 1/4, 1 and 4 s, with their times list."""
    from hdrcl.io.ldr import write_ldr

    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    scene = np.exp(3.0 * (xx / w) + 1.0 * (yy / h))[..., None] * np.array([1.0, 0.8, 0.6]) * 0.02
    scene *= np.exp(rng.normal(0, 0.05, scene.shape))
    paths, times = [], [0.25, 1.0, 4.0]
    os.makedirs(folder, exist_ok=True)
    for k, t in enumerate(times):
        z = np.clip(255 * (scene * t) ** (1 / 2.2), 0, 255).round().astype(np.uint8)
        p = os.path.join(folder, f"{name}{k}.png")
        write_ldr(p, z)
        paths.append(p)
    return paths, times


ORDER = """
import json, sys, hashlib
import hdrcl
from hdrcl.io.radiance import read_metadata
small, small_t, big, big_t, out = json.loads(sys.argv[1])
digests = []
for k, (paths, times) in enumerate([(small, small_t), (big, big_t), (small, small_t)]):
    target = f"{out}/m{k}.hdr"  # RGBE: byte for byte (EXR chunks may be written in any order)
    hdrcl.merge_files(paths, target, times=times)
    digests.append([hashlib.sha256(open(target, "rb").read()).hexdigest(), read_metadata(target).get("backend")])
print(json.dumps(digests))
"""


def test_the_same_set_gives_the_same_bytes_first_or_after_a_large_set(tmp_path, cl_device):
    """Issue 25 item 3: a small set merged first (NumPy: OpenCL not open yet) and again after
    a large set opened OpenCL in the same process gives the same file, same backend."""
    small = _bracket(str(tmp_path / "s"), "s", 48, 64)
    big = _bracket(str(tmp_path / "b"), "b", 480, 640, seed=1)  # 0.9 M pixel-samples: OpenCL
    env = {k: v for k, v in os.environ.items() if k not in ("HDRCL_REQUIRE_OPENCL", "PYOPENCL_CTX",
                                                             "HDRCL_SMALL_WORK", "HDRCL_OPENCL")}
    arg = json.dumps([small[0], small[1], big[0], big[1], str(tmp_path)])
    r = subprocess.run([sys.executable, "-c", ORDER, arg], capture_output=True, text=True, env=env, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    (first, big_one, again) = json.loads(r.stdout.strip().splitlines()[-1])
    assert big_one[1] == "opencl"
    assert first == again, (first, again)
    assert first[1] == "numpy"


def test_merge_options_are_checked_once_and_say_what_they_ignore():
    from hdrcl.core.options import MergeOptions
    from hdrcl.errors import UsageError

    with pytest.raises(UsageError, match="--crop needs --align"):
        MergeOptions(crop=True)
    with pytest.raises(UsageError, match="--align-model"):
        MergeOptions(align=True, align_model="affine")
    o = MergeOptions(align_model="Similarity", ignore_color="0,0,255", reference_exposure="1/125")
    assert o.align_model == "similarity" and o.ignore_color == (0, 0, 255) and o.reference_exposure == 0.008
    assert o.ignored() == ["--align-model similarity is ignored without --align"]
    assert len(MergeOptions(reference_exposure=0.01, absolute=True).ignored()) == 1
    assert MergeOptions(reference_exposure=0.01).ignored("x.pfm") == [
        "--reference-exposure is ignored: a .pfm file holds radiance relative to 1 s"]
    assert MergeOptions(reference_exposure=0.01).ignored("x.exr") == []
    assert MergeOptions(align=True, align_model="shift").ignored() == []


def test_batch_options_wrap_merge_options():
    from hdrcl.errors import UsageError
    from hdrcl.shoot.batch.jobs import BatchOptions

    assert BatchOptions(exposure_tolerance=2.0).merge.exposure_tolerance == 2.0
    from hdrcl.core.options import MergeOptions

    m = MergeOptions(align=True, align_model="shift", exposure_tolerance=1.0)
    assert BatchOptions.wrap(m, preview=False).merge == m
    # every merge option is a batch option too (one declaration, hdrcl.core.options)
    absolute = BatchOptions.wrap(MergeOptions(absolute=True))
    assert absolute.absolute and absolute.output_params()["absolute"] is True
    assert "absolute" not in BatchOptions().output_params()  # the digests of plain merges stay
    with pytest.raises(UsageError, match="--crop needs --align"):
        BatchOptions(crop=True)
    with pytest.raises(UsageError, match="--exposure-tolerance"):
        BatchOptions(exposure_tolerance=-1)


def _cli(*args):
    from click.testing import CliRunner

    from hdrcl.cli import main

    return CliRunner().invoke(main, [str(a) for a in args])


def test_batch_checks_exposures_with_a_given_response_as_merge_does(tmp_path, cl_device):
    """A frame labelled 1 s that was taken at 2 s: with a given response and
    --fit-exposures off, merge and batch say the same thing about it, and both take
    --exposure-tolerance (issue 25)."""
    from hdrcl.io.ldr import write_ldr

    shoot = tmp_path / "shoot"
    paths, times = _bracket(str(shoot), "f", 120, 160)
    resp = tmp_path / "r.json"
    assert _cli("calibrate", *paths, "--times", ",".join(map(str, times)), "-o", resp).exit_code == 0
    # The middle frame re-made at twice its labelled exposure.
    from hdrcl.io.frames import read_image

    hot = paths[1]
    img = read_image(hot).pixels.astype(np.float64) / 255
    write_ldr(hot, np.clip(255 * np.clip(img, 0, 1) * 2 ** (1 / 2.2), 0, 255).round().astype(np.uint8))
    (shoot / "times.txt").write_text("".join(f"{os.path.basename(p)} {t}\n" for p, t in zip(paths, times)))

    def merge_warnings(*extra):
        r = _cli("merge", *paths, "--response", resp, "--fit-exposures", "off", "-o", tmp_path / "m.exr", *extra)
        assert r.exit_code == 0, r.output
        return [ln for ln in r.output.splitlines() if os.path.basename(hot) in ln and "pixels say" in ln]

    def batch_warnings(*extra):
        out = tmp_path / ("o" + "".join(extra).replace("-", "").replace(".", ""))
        r = _cli("batch", shoot, "--response", resp, "--fit-exposures", "off", "-o", out, "--no-preview",
                 "--frames-per-set", 3, *extra)
        assert r.exit_code == 0, r.output
        rep = json.loads((out / "report.json").read_text())
        (entry,) = rep["sets"]
        return [w for w in entry["warnings"] if os.path.basename(hot) in w and "pixels say" in w]

    m, b = merge_warnings(), batch_warnings()
    assert m and b, (m, b)
    assert any(w in " ".join(m) for w in b), (m, b)
    assert merge_warnings("--exposure-tolerance", "3") == []
    assert batch_warnings("--exposure-tolerance", "3") == []


from test_align_merge import memorial_handheld_files  # noqa: E402,F401 (fixture)


def test_batch_align_report_measures_the_aligned_set_as_merge_does(memorial_handheld_files, tmp_path, cl_device):
    """``batch --align --report`` measures the frames it fused (warped), not the raw ones:
    its leave-one-out equals ``merge --align --report``'s within 0.5 level (issue 25)."""
    import shutil

    files, times, _mats, _d = memorial_handheld_files
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    for p in files["moved"]:
        shutil.copy(p, shoot)
    (shoot / "times.txt").write_text("".join(f"{os.path.basename(p)} {t}\n" for p, t in zip(files["moved"], times)))
    frames = sorted(str(p) for p in shoot.glob("*.png"))
    r = _cli("merge", *frames, "--align", "-o", tmp_path / "m.exr", "--report", tmp_path / "qm")
    assert r.exit_code == 0, r.output
    merged = json.loads((tmp_path / "qm" / "m.json").read_text())["figures"]["looRmse"]
    r = _cli("batch", shoot, "--align", "-o", tmp_path / "out", "--frames-per-set", len(frames),
             "--report", tmp_path / "qb")
    assert r.exit_code == 0, r.output
    (entry,) = json.loads((tmp_path / "out" / "report.json").read_text())["sets"]
    assert not any("not measured" in w for w in entry["warnings"]), entry["warnings"]
    batched = entry["quality"]["looRmse"]
    assert merged is not None and batched is not None
    assert abs(merged - batched) < 0.5, (merged, batched)
    # A rerun that finds the set up to date but its report gone measures it again, aligned too.
    import shutil as _sh

    _sh.rmtree(tmp_path / "qb")
    r = _cli("batch", shoot, "--align", "-o", tmp_path / "out", "--frames-per-set", len(frames),
             "--report", tmp_path / "qb")
    assert r.exit_code == 0, r.output
    (entry,) = json.loads((tmp_path / "out" / "report.json").read_text())["sets"]
    assert entry["status"] == "skipped"
    assert abs(entry["quality"]["looRmse"] - merged) < 0.5, (merged, entry["quality"]["looRmse"])


def _decided(shoot, out, cache=None):
    """The batch's response decision for ``shoot`` (pooling.decide_responses, as run_batch
    and its dry run make it), by group."""
    from hdrcl.shoot.batch.jobs import BatchOptions
    from hdrcl.shoot.batch.plan import _plan, load_source
    from hdrcl.shoot.batch.pooling import decide_responses

    opts = BatchOptions()
    plan = _plan(load_source(str(shoot)), str(out), opts, None)
    return plan, decide_responses(plan, str(out), opts, defer=True, cache=None if cache is None else str(cache))


def _dry_run_is_the_decision(decided, *args):
    """The dry run's response and calibration of every set are its group's decision, described."""
    r = _cli("batch", *args, "--dry-run", "--json")
    assert r.exit_code == 0, r.output
    rows = json.loads(r.output[r.output.index("{"):])["sets"]
    assert rows
    for row in rows:
        gp = decided[row["response"]["group"]]
        assert {"response": row["response"], "calibration": row["calibration"]} == gp.describe(), (row, gp)
    return rows


def test_a_damaged_cached_response_is_decided_calibrate(tmp_path, cl_device):
    """One decision says what the run does and the dry run says: a damaged curve in
    --response-cache is calibrated again (rewritten there), not called "cached" (issues 25, 33)."""
    from hdrcl.shoot.batch.pooling import CACHED, SOLVE

    shoot, cache = tmp_path / "shoot", tmp_path / "cache"
    assert _cli("sample-shoot", shoot).exit_code == 0
    assert _cli("batch", shoot, "-o", tmp_path / "out", "--response-cache", cache, "--no-preview").exit_code == 0
    damaged = sorted(cache.glob("*.response.json"))[0]
    damaged.write_text("garbage{")
    _, decided = _decided(shoot, tmp_path / "out2", cache)
    by_file = {gp.entry.file: gp for gp in decided.values()}
    assert by_file[str(damaged)].action == SOLVE and by_file[str(damaged)].entry.payload is None
    assert sorted(gp.action for gp in decided.values()) == [CACHED, SOLVE]
    rows = _dry_run_is_the_decision(decided, shoot, "-o", tmp_path / "out2", "--response-cache", cache)
    assert any(s["response"]["source"] == "calibrate" and s["calibration"]["kind"] != "cached"
               and s["response"]["file"] == str(damaged) for s in rows), rows
    assert any(s["response"]["source"] == "cached" for s in rows), rows
    # The run carries the decision out: the damaged curve solved and saved again, the other taken.
    assert _cli("batch", shoot, "-o", tmp_path / "out2", "--response-cache", cache, "--no-preview").exit_code == 0
    report = json.loads((tmp_path / "out2" / "report.json").read_text())["responses"]
    assert {r["file"]: r["source"] for r in report} == {
        gp.entry.file: {SOLVE: "calibrated", CACHED: "cached"}[gp.action] for gp in decided.values()}
    json.loads(damaged.read_text())  # rewritten whole


def test_the_response_decision_decodes_and_solves_nothing(tmp_path, cl_device, monkeypatch):
    """decide_responses only decides: no frame decoded, no curve solved; carrying the plan
    out solves the pool (and leaves the plan as decided); a camera's only set is deferred."""
    from hdrcl.shoot.batch import pooling
    from hdrcl.shoot.batch.jobs import BatchOptions

    shoot = tmp_path / "shoot"
    assert _cli("sample-shoot", shoot).exit_code == 0
    calls = []
    monkeypatch.setattr(pooling, "_calibration_grid", lambda *a, **k: calls.append("decode"))
    monkeypatch.setattr(pooling, "_solve_pool", lambda *a, **k: calls.append("solve"))
    plan, decided = _decided(shoot, tmp_path / "out")
    assert calls == []
    assert sorted(gp.action for gp in decided.values()) == [pooling.DEFERRED, pooling.SOLVE]
    _dry_run_is_the_decision(decided, shoot, "-o", tmp_path / "out")
    assert calls == [] and not (tmp_path / "out").exists()
    monkeypatch.undo()
    (tmp_path / "out").mkdir()  # as run_batch makes it before it carries the plans out
    solve = next(gp for gp in decided.values() if gp.action == pooling.SOLVE)
    assert len(solve.members) > 1 and solve.pool == tuple(solve.members) and solve.kind == "pooled"
    entry = pooling._carry_out(solve, BatchOptions())
    assert entry.source == "calibrated" and entry.payload and entry.error is None
    assert os.path.isfile(entry.file) and entry.file == solve.entry.file
    assert solve.entry.payload is None and solve.entry.source == ""  # the plan stays as decided
    deferred = next(gp for gp in decided.values() if gp.action == pooling.DEFERRED)
    assert deferred.kind == "deferred" and deferred.describe()["calibration"] == {"kind": "own"}
    later = pooling._carry_out(deferred, BatchOptions())
    assert later.deferred and later.payload is None and not os.path.exists(later.file)


def test_scan_and_batch_agree_on_two_frames_of_one_exposure(tmp_path, cl_device):
    """4 s at ISO 2500 and 2 s at ISO 5000 are one exposure: scan does not list them as a
    set, and batch says the same (nothing to merge, the reason named), issue 25."""
    import datetime as dt

    from hdrcl.core import synthetic
    from hdrcl.io.ldr import write_photo

    shoot = tmp_path / "shoot"
    shoot.mkdir()
    cam = synthetic.Camera(a=1.1, x0=(1.0, 1.15, 0.85))
    scene = synthetic.radiance_field(32, 48, decades=2.0, seed=3) * 0.05
    when = dt.datetime(2024, 6, 1, 21, 0, 0)
    for k, (t, iso) in enumerate(((4.0, 2500), (2.0, 5000))):
        (frame,) = synthetic.bracket(scene, [t * iso / 2500], cam, noise=0.5, seed=k)
        write_photo(str(shoot / f"DSC_{k + 1:04d}.jpg"), frame,
                    {"ExposureTime": t, "FNumber": 4.0, "Exif:PhotographicSensitivity": iso, "Exif:ExposureMode": 1,
                     "Make": "NIKON CORPORATION", "Model": "NIKON D750",
                     "Exif:DateTimeOriginal": (when + dt.timedelta(seconds=6 * k)).strftime("%Y:%m:%d %H:%M:%S")})
    r = _cli("scan", shoot, "--json")
    assert r.exit_code == 0, r.output
    scanned = json.loads(r.output[r.output.index("{"):])
    assert scanned["sets"] == [], scanned["sets"]
    assert any("exposure" in u["reason"] for u in scanned["unmerged"]), scanned["unmerged"]
    r = _cli("batch", shoot, "-o", tmp_path / "out")
    assert r.exit_code == 1, r.output
    assert "same exposure" in r.output or "share one exposure" in r.output, r.output
    assert "all 2 frames have the same exposure" not in r.output


def _shoot_one_set(tmp_path, w=96, h=64):
    """A folder with one bracket of JPEGs with EXIF (test_shoot_ux.write_set)."""
    import datetime as dt

    from test_shoot_ux import write_set

    shoot = tmp_path / "shoot"
    names = write_set(shoot, "IMG", 7, dt.datetime(2024, 6, 1, 9, 0, 0))
    return shoot, [str(shoot / n) for n in names]


def _same_up_to_scale(a, b, tol=1e-3):
    """Whether ``a`` is ``b`` times one factor (the recorded scale), pixel for pixel."""
    ok = (a > 1e-6) & (b > 1e-6)
    r = np.log(a[ok] / b[ok])
    err = float(np.max(np.abs(r - np.median(r))))
    same_support = np.mean((a > 1e-6) == (b > 1e-6)) > 0.999  # a luminance map is 0 outside the lens circle
    return bool(ok.mean() > 0.1 and same_support and err < tol), err


@pytest.mark.parametrize("extra", [[], ["--lens-circle", "48,32,60", "--resize", "32"]], ids=["response", "chain"])
def test_batch_and_merge_give_the_same_pixels_up_to_the_recorded_scale(tmp_path, cl_device, extra):
    """The same set with a given response (and with a fisheye luminance chain) through merge
    and through batch: the same pixels up to the scale each file records (issue 25)."""
    from hdrcl.io.radiance import read_radiance

    shoot, frames = _shoot_one_set(tmp_path)
    resp = tmp_path / "r.json"
    assert _cli("calibrate", *frames, "-o", resp).exit_code == 0
    r = _cli("merge", *frames, "--response", resp, "-o", tmp_path / "m.exr", *extra)
    assert r.exit_code == 0, r.output
    r = _cli("batch", shoot, "--response", resp, "-o", tmp_path / "out", "--no-preview", *extra)
    assert r.exit_code == 0, r.output
    a, _ = read_radiance(str(tmp_path / "m.exr"))
    (b_path,) = (tmp_path / "out").glob("*.exr")
    b, _ = read_radiance(str(b_path))
    assert a.shape == b.shape
    same, err = _same_up_to_scale(a.astype(np.float64), b.astype(np.float64), tol=2e-3)
    assert same, err


@pytest.mark.parametrize("args,word", [
    (["-o", "{d}/o.pfm", "--reference-exposure", "1e-3"], "--reference-exposure"),
    (["-o", "{d}/o.exr", "--absolute", "--reference-exposure", "1e-3"], "--reference-exposure"),
    (["-o", "{d}/o.exr", "--align-model", "shift"], "--align-model"),
])
def test_an_ignored_option_is_named_in_one_warning(tmp_path, cl_device, args, word):
    """Issue 29: an option the merge ignores is named in one warning line (exit 0)."""
    import subprocess

    shoot, frames = _shoot_one_set(tmp_path)
    cmd = [sys.executable, "-m", "hdrcl", "merge", *frames] + [a.format(d=tmp_path) for a in args]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if word in ln]
    assert len(lines) == 1 and "ignored" in lines[0], r.stderr


def test_batch_names_an_ignored_align_model(tmp_path, cl_device):
    import subprocess

    shoot, _frames = _shoot_one_set(tmp_path)
    r = subprocess.run([sys.executable, "-m", "hdrcl", "batch", str(shoot), "-o", str(tmp_path / "out"),
                        "--align-model", "shift", "--no-preview"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if "--align-model" in ln]
    assert len(lines) == 1 and "ignored" in lines[0], r.stderr


def test_a_times_list_in_reverse_order_of_brightness_is_refused_by_merge_and_batch(tmp_path, cl_device):
    """Issue 29: times.txt backwards (the brightest frame listed shortest): merge and
    batch both refuse the set, naming the list, and merge writes nothing."""
    import subprocess

    shoot = tmp_path / "shoot"
    paths, times = _bracket(str(shoot), "f", 96, 128)
    (shoot / "times.txt").write_text("".join(f"{os.path.basename(p)} {t}\n" for p, t in zip(paths, times[::-1])))
    r = subprocess.run([sys.executable, "-m", "hdrcl", "merge", *paths, "-o", str(tmp_path / "m.exr")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 3, r.stderr
    err = [ln for ln in r.stderr.splitlines() if "error" in ln]  # after the line naming the list used
    assert len(err) == 1 and "times.txt" in err[0] and "reverse order" in err[0], r.stderr
    assert not (tmp_path / "m.exr").exists()
    r = _cli("batch", shoot, "-o", tmp_path / "out", "--no-preview", "--frames-per-set", 3)
    assert r.exit_code == 1, r.output
    (entry,) = json.loads((tmp_path / "out" / "report.json").read_text())["sets"]
    assert entry["status"] == "failed" and "times.txt" in entry["error"] and "reverse order" in entry["error"], entry


def test_batch_name_is_limited_in_bytes_before_anything_runs(tmp_path):
    """Issue 29: ``--name "é×120{index}"`` (480 bytes) is refused at once, exit 2, one
    line, nothing written; a name of 200 characters but more bytes too."""
    import subprocess

    shoot, _frames = _shoot_one_set(tmp_path)
    for name in ("é×" * 120 + "{index}", "é" * 150 + "{index}"):
        out = tmp_path / "out"
        r = subprocess.run([sys.executable, "-m", "hdrcl", "batch", str(shoot), "-o", str(out), "--name", name],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 2, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and "bytes" in r.stderr, r.stderr
        assert not out.exists()
    r = subprocess.run([sys.executable, "-m", "hdrcl", "batch", str(shoot), "-o", str(tmp_path / "ok"), "--name",
                        "é" * 90 + "{index}", "--no-preview"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr


AFTER_WORK = """
import atexit, os, signal, sys
atexit.register(lambda: os.kill(os.getpid(), signal.SIGTERM))  # while the interpreter shuts down
sys.argv = ["hdrcl", "sample-shoot", sys.argv[1]]
from hdrcl.cli import main
main()
"""


def test_sigterm_after_the_work_is_committed_is_not_a_silent_143(tmp_path):
    """Issue 29: a SIGTERM that arrives once the command's work is committed (the process
    exiting) ends with the command's exit code, not a silent 143."""
    r = subprocess.run([sys.executable, "-c", AFTER_WORK, str(tmp_path / "s")], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0 or (r.returncode == 143 and len(r.stderr.strip().splitlines()) == 1), \
        (r.returncode, r.stderr)
    assert any((tmp_path / "s").rglob("*.jpg"))


def test_calibrate_16_bit_frames_to_rsp_is_refused_from_the_headers(tmp_path):
    """Issue 29: one line, exit 2, before any solve (no warnings of the solve first)."""
    from hdrcl.io.ldr import write_ldr

    paths = []
    for k, t in enumerate((0.25, 1.0, 4.0)):
        p = tmp_path / f"f{k}.tif"
        z = np.clip(np.linspace(0, 65535 * t / 4, 64 * 48 * 3), 0, 65535).reshape(48, 64, 3).astype(np.uint16)
        write_ldr(str(p), z)
        paths.append(str(p))
    r = subprocess.run([sys.executable, "-m", "hdrcl", "calibrate", *paths, "--times", "1/4,1,4", "-o",
                        str(tmp_path / "r.rsp")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and ".rsp" in r.stderr and "16-bit" in r.stderr, r.stderr
    assert not (tmp_path / "r.rsp").exists()


def test_a_stale_saved_response_is_decided_calibrate(tmp_path, cl_device):
    """One decision for the run and its dry run: a saved curve whose pooled frames changed
    since is solved again ("calibrate" in the dry run), the others loaded ("saved")."""
    from hdrcl.shoot.batch.pooling import LOADED, SOLVE

    shoot, out = tmp_path / "shoot", tmp_path / "out"
    assert _cli("sample-shoot", shoot).exit_code == 0
    assert _cli("batch", shoot, "-o", out, "--no-preview").exit_code == 0
    plan, before = _decided(shoot, out)
    assert {gp.action for gp in before.values()} == {LOADED}
    rows = _dry_run_is_the_decision(before, shoot, "-o", out, "--no-preview")
    assert all(s["response"]["source"] == "saved" for s in rows), rows
    job = plan.jobs[min(plan.jobs)]
    with open(job.files[0], "ab") as f:  # the same picture, other bytes: another calibration key
        f.write(b"\0")
    _, after = _decided(shoot, out)
    assert {g: gp.action for g, gp in after.items()} == {g: SOLVE if g == job.group else LOADED for g in before}
    rows = _dry_run_is_the_decision(after, shoot, "-o", out, "--no-preview")
    assert all(s["response"]["source"] == "calibrate" for s in rows if s["response"]["group"] == job.group), rows
    assert any(s["response"]["source"] == "saved" for s in rows if s["response"]["group"] != job.group), rows


def test_the_dry_run_of_a_given_response_object_names_it_given(tmp_path):
    """describe_batch with a Response object (the API's --response) plans "given" for every
    set, as run_batch does, without reading or solving anything (it raised TypeError)."""
    from hdrcl.api.batch import describe_batch
    from hdrcl.core.response import linear_response

    shoot = tmp_path / "shoot"
    assert _cli("sample-shoot", shoot).exit_code == 0
    plan = describe_batch(shoot, tmp_path / "out", response=linear_response())
    assert plan["sets"] and all(s["response"]["file"] == "given" and s["response"]["source"] == "given"
                                and s["calibration"] == {"kind": "given"} for s in plan["sets"]), plan
    assert not (tmp_path / "out").exists()
