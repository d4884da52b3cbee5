"""A batch you can cancel, kill and requeue: workers die with it, SIGTERM and Ctrl-C stop
it within seconds, two batches on one folder share the work, FIFOs and damaged outputs
are handled. Every test runs ``python -m hdrcl batch`` as a real process.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import psutil
import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.io.radiance import read_radiance

try:
    from test_batch import make_clean_shoot
except ImportError:  # tests/ made a package
    from tests.test_batch import make_clean_shoot

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (REPO, os.environ.get("PYTHONPATH")) if p))


def batch_cmd(folder, out, *extra):
    return [sys.executable, "-m", "hdrcl", "batch", str(folder), "-o", str(out), "--no-preview", *map(str, extra)]


def report_of(out):
    with open(os.path.join(out, "report.json"), encoding="utf-8") as fh:
        return json.load(fh)


def litter(out):
    return [n for n in os.listdir(out) if ".tmp" in n or n.endswith(".claim")]


def alive(pids):
    out = []
    for pid in pids:
        try:
            if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                out.append(pid)
        except psutil.NoSuchProcess:
            pass
    return out


def start_busy(folder, out, *extra):
    """Start a --jobs 2 batch and return once both workers are merging."""
    proc = subprocess.Popen(batch_cmd(folder, out, "--jobs", 2, *extra), env=ENV, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline:
        if out.is_dir() and [n for n in os.listdir(out) if n.endswith(".claim")]:
            kids = psutil.Process(proc.pid).children(recursive=True)
            if len(kids) >= 2:
                return proc, [k.pid for k in kids]
        time.sleep(0.005)
    proc.kill()
    pytest.fail(f"the batch never got busy: {proc.stderr.read().decode()[-2000:]}")


@pytest.fixture
def shoot8(tmp_path):
    folder = tmp_path / "shoot"
    groups = make_clean_shoot(folder, sets=8, frames=3, width=640, height=480)
    return folder, groups


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_signal_leaves_no_process_and_a_rerun_completes(shoot8, tmp_path, sig):
    folder, groups = shoot8
    out = tmp_path / "out"
    proc, kids = start_busy(folder, out)
    t0 = time.monotonic()
    proc.send_signal(sig)
    proc.wait(timeout=30)
    stopped = time.monotonic() - t0
    if sig == signal.SIGTERM:
        err = proc.stderr.read().decode()
        assert proc.returncode == 143, err
        lines = [ln for ln in err.splitlines() if not ln.startswith("hdrcl: [")]  # progress lines aside
        assert len(lines) == 1 and lines[0].startswith("hdrcl: terminated ("), err
        assert stopped < 2.0, f"SIGTERM took {stopped:.2f} s"
        rep = report_of(out)  # the report of what finished
        assert rep["summary"]["cancelled"] == "SIGTERM"
        assert all(s["status"] in ("done", "skipped") for s in rep["sets"])
    else:
        assert proc.returncode == -signal.SIGKILL
    deadline = time.monotonic() + 3.0
    while alive(kids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert alive(kids) == [], f"processes of the batch still alive 3 s after {sig.name}"
    proc.stderr.close()

    again = subprocess.run(batch_cmd(folder, out), env=ENV, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    rep = report_of(out)
    assert len(rep["sets"]) == len(groups)
    assert {s["status"] for s in rep["sets"]} <= {"done", "skipped"}
    for s in rep["sets"]:
        assert read_radiance(s["output"])[0].shape == (480, 640, 3)
    assert litter(out) == []


def test_ctrl_c_with_jobs_exits_130_within_2_s(shoot8, tmp_path):
    out = tmp_path / "out"
    proc, kids = start_busy(shoot8[0], out)
    t0 = time.monotonic()
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=30)
    took = time.monotonic() - t0
    err = proc.stderr.read().decode()
    proc.stderr.close()
    assert proc.returncode == 130, err
    assert took < 2.0, f"Ctrl-C took {took:.2f} s"
    lines = [ln for ln in err.splitlines() if not ln.startswith("hdrcl: [")]  # progress lines aside
    assert len(lines) == 1 and lines[0].startswith("hdrcl: interrupted ("), err  # one line, the README's word
    time.sleep(0.5)
    assert alive(kids) == []
    assert litter(out) == []


def test_two_batches_on_one_folder_share_the_work(tmp_path):
    folder, out = tmp_path / "shoot", tmp_path / "out"
    groups = make_clean_shoot(folder, sets=6, frames=3, width=320, height=240)
    procs = [subprocess.Popen(batch_cmd(folder, out), env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    outs = [p.communicate(timeout=300) for p in procs]
    for p, (so, se) in zip(procs, outs):
        assert p.returncode == 0, se
    done = 0
    for so, _ in outs:
        line = next(ln for ln in so.splitlines() if " set(s): " in ln)
        done += int(line.split(": ")[1].split(" done")[0])
    assert done == len(groups), [o[0] for o in outs]  # every set merged exactly once
    rep = report_of(out)
    assert len(rep["sets"]) == len(groups) and {s["status"] for s in rep["sets"]} <= {"done", "skipped"}
    assert litter(out) == []


def test_fifo_in_a_manifest_fails_its_set_alone(tmp_path):
    folder, out = tmp_path / "shoot", tmp_path / "out"
    groups = make_clean_shoot(folder, sets=3, frames=3)
    fifo = folder / "pipe.jpg"
    os.mkfifo(fifo)
    sets = [{"files": [str(folder / f) for f in g]} for g in groups]
    sets[1]["files"][1] = str(fifo)
    shutil.copy(folder / groups[0][0], tmp_path / "copy.jpg")
    sets.append({"files": [str(tmp_path / "copy.jpg"), "/dev/zero"]})
    man = tmp_path / "m.json"
    man.write_text(json.dumps({"sets": sets}))
    t0 = time.monotonic()
    res = subprocess.run(batch_cmd(man, out), env=ENV, capture_output=True, text=True, timeout=120)
    assert time.monotonic() - t0 < 60
    assert res.returncode == 1, res.stderr
    by = {s["index"]: s for s in report_of(out)["sets"]}
    assert by[1]["status"] == "failed" and "not a regular file (a FIFO)" in by[1]["error"]
    assert by[3]["status"] == "failed" and "not a regular file (a device)" in by[3]["error"]
    assert by[0]["status"] == by[2]["status"] == "done"


def test_truncated_output_is_rebuilt(tmp_path):
    folder, out = tmp_path / "shoot", tmp_path / "out"
    make_clean_shoot(folder, sets=2, frames=3, width=256, height=192)
    assert CliRunner().invoke(main, ["batch", str(folder), "-o", str(out)]).exit_code == 0
    first = report_of(out)["sets"]
    victim = first[0]["output"]
    size = os.path.getsize(victim)
    with open(victim, "r+b") as fh:
        fh.truncate(size * 2 // 3)  # the header (and its digest) intact
    res = CliRunner().invoke(main, ["batch", str(folder), "-o", str(out)])
    assert res.exit_code == 0, res.output
    status = {s["output"]: s for s in report_of(out)["sets"]}
    assert status[victim]["status"] == "done"
    assert any("damaged" in w for w in status[victim]["warnings"])
    assert status[first[1]["output"]]["status"] == "skipped"
    assert read_radiance(victim)[0].shape == (192, 256, 3)


def test_symlinks_in_the_output_folder_are_never_written_through(tmp_path):
    """The report's lock is an flock on the folder (no lock file), but the claim file and
    the report are opened by name: a symbolic link planted there must not redirect a
    write outside the output folder."""
    folder, out = tmp_path / "shoot", tmp_path / "out"
    make_clean_shoot(folder, sets=1, frames=3)
    out.mkdir()
    claim_victim, report_victim = tmp_path / "claim-victim", tmp_path / "report-victim.json"
    report_victim.write_text('{"keep": true}')
    os.symlink(claim_victim, out / ".IMG_0001.claim")  # dangling: O_CREAT through it would make the victim
    os.symlink(report_victim, out / "report.json")
    res = subprocess.run(batch_cmd(folder, out), env=ENV, capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert not claim_victim.exists()
    assert report_victim.read_text() == '{"keep": true}'
    assert not os.path.islink(out / "report.json") and report_of(out)["sets"][0]["status"] == "done"


def test_a_killed_worker_loses_no_other_set(shoot8, tmp_path):
    """kill -9 of one worker mid-merge (an OOM kill): its set is run again in a fresh
    pool, every other set completes."""
    folder, groups = shoot8
    out = tmp_path / "out"
    proc, kids = start_busy(folder, out)
    victim, deadline = None, time.monotonic() + 30
    while victim is None and time.monotonic() < deadline:
        for n in os.listdir(out):
            if n.endswith(".claim"):
                try:
                    pid = int((out / n).read_text().strip() or 0)
                except (OSError, ValueError):
                    continue
                if pid in kids:
                    victim = pid
                    break
        time.sleep(0.005)
    assert victim is not None, "no worker held a claim"
    os.kill(victim, signal.SIGKILL)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err.decode()[-3000:]
    rep = report_of(out)
    assert len(rep["sets"]) == len(groups)
    assert {s["status"] for s in rep["sets"]} == {"done"}
    for s in rep["sets"]:
        assert read_radiance(s["output"])[0].shape == (480, 640, 3)
    assert litter(out) == []


def test_memorial_merges_with_no_options(memorial, tmp_path):
    res = CliRunner().invoke(main, ["batch", str(memorial), "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    assert "1 set(s): 1 done" in res.output
    rad, _ = read_radiance(report_of(tmp_path / "out")["sets"][0]["output"])
    assert rad.shape == (768, 512, 3)


def test_nothing_to_merge_exits_non_zero(tmp_path):
    folder = tmp_path / "one"
    make_clean_shoot(folder, sets=1, frames=1)
    res = CliRunner().invoke(main, ["batch", str(folder), "-o", str(tmp_path / "out")])
    assert res.exit_code == 1
    assert "no bracket sets to merge" in res.output and "single frame" in res.output


def test_contact_sheet_lists_unmerged_frames_and_skipped_sets(tmp_path):
    folder, out = tmp_path / "shoot", tmp_path / "out"
    make_clean_shoot(folder, sets=3, frames=3)
    for n in ("IMG_0005.jpg", "IMG_0006.jpg"):  # the third set is left a stray frame
        os.remove(folder / n)
    args = ["batch", str(folder), "-o", str(out), "--report", str(out / "report")]
    assert CliRunner().invoke(main, args).exit_code == 0
    page = (out / "report" / "index.html").read_text()
    assert "Not merged: 1 file in 1 group" in page and 'data-reason="single frame"' in page
    assert "<figcaption>IMG_0004.jpg</figcaption>" in page
    assert "2 sets: 2 merged, 0 failed" in page
    assert CliRunner().invoke(main, args).exit_code == 0
    page = (out / "report" / "index.html").read_text()
    assert "2 sets: 0 merged, 2 up to date, 0 failed" in page


def test_demo_twice_says_skipped(tmp_path, cl_device):
    args = ["demo", str(tmp_path / "demo"), "--size", "64x48", "--frames", "3"]
    assert "3 set(s) merged, 0 failed" in CliRunner().invoke(main, args).output
    again = CliRunner().invoke(main, args)
    assert again.exit_code == 0, again.output
    assert "0 set(s) merged, 3 up to date, 0 failed" in again.output


def test_batch_has_merges_options(tmp_path):
    folder, out = tmp_path / "shoot", tmp_path / "out"
    make_clean_shoot(folder, sets=1, frames=3, width=96, height=64)
    plain = CliRunner().invoke(main, ["batch", str(folder), "-o", str(out / "plain")])
    assert plain.exit_code == 0, plain.output
    args = ["batch", str(folder), "-o", str(out / "opts"), "--align", "--crop", "--neutral", "10,10,8,8",
            "--fit-exposures", "on"]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
    a, b = report_of(out / "plain")["sets"][0], report_of(out / "opts")["sets"][0]
    assert a["hash"] != b["hash"]  # the options are part of the output's identity
    rad, meta = read_radiance(b["output"])
    assert "alignShifts" in meta and rad.shape[2] == 3 and rad.shape[0] <= 64
    assert CliRunner().invoke(main, ["batch", str(folder), "-o", str(out / "x"), "--crop"]).exit_code == 2


def test_times_file_for_frames_without_exif(tmp_path, memorial):
    folder = tmp_path / "m"
    folder.mkdir()
    for k in range(61, 64):
        shutil.copy(memorial / f"memorial00{k}.png", folder / f"memorial00{k}.png")
    (tmp_path / "t.txt").write_text("memorial0061.png 32\nmemorial0062.png 16\nmemorial0063.png 8\n")
    res = CliRunner().invoke(main, ["scan", str(folder)])
    assert "no exposure time" in res.output
    res = CliRunner().invoke(main, ["batch", str(folder), "-o", str(tmp_path / "o"), "--times-file",
                                    str(tmp_path / "t.txt"), "--ignore-color", "0,0,255"])
    assert res.exit_code == 0 and "1 set(s): 1 done" in res.output, res.output


def test_scan_of_a_manifest_with_a_fifo_does_not_hang(tmp_path):
    folder = tmp_path / "shoot"
    groups = make_clean_shoot(folder, sets=1, frames=3)
    os.mkfifo(folder / "pipe.jpg")
    man = tmp_path / "m.json"
    man.write_text(json.dumps({"sets": [{"files": [str(folder / groups[0][0]), str(folder / "pipe.jpg")]}]}))
    res = subprocess.run([sys.executable, "-m", "hdrcl", "scan", str(man)], env=ENV, capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 1 and "not a regular file (a FIFO)" in res.stdout
    res = subprocess.run([sys.executable, "-m", "hdrcl", "scan", str(folder)], env=ENV, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 0 and "1 set(s)" in res.stdout


def test_watchdog_kills_a_worker_whose_parent_died_without_pdeathsig(tmp_path):
    """The fallback for systems without PR_SET_PDEATHSIG: the parent-pid watchdog."""
    pidfile = tmp_path / "grandchild.pid"
    grandchild = ("import os, sys, time; from hdrcl.shoot.batch import claims; claims._pdeathsig = lambda: False; "
                  "claims.tie_to_parent(os.getppid()); open(sys.argv[1], 'w').write(str(os.getpid())); "
                  "time.sleep(60)")
    child = ("import subprocess, sys, time; subprocess.Popen([sys.executable, '-c', sys.argv[1], sys.argv[2]]); "
             "time.sleep(60)")
    proc = subprocess.Popen([sys.executable, "-c", child, grandchild, str(pidfile)], env=ENV)
    deadline = time.monotonic() + 30
    while not (pidfile.exists() and pidfile.read_text()) and time.monotonic() < deadline:
        time.sleep(0.02)
    pid = int(pidfile.read_text())
    assert alive([pid]) == [pid]
    proc.kill()
    proc.wait()
    deadline = time.monotonic() + 3.0
    while alive([pid]) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert alive([pid]) == []


class _Job:
    def __init__(self, index):
        self.index = index


def _dies_on_set_zero(job, ctx):
    """A set that kills its worker every time (too big for memory, say)."""
    if job.index == 0:
        time.sleep(0.2)  # the other sets are running or queued when it goes
        os._exit(9)
    time.sleep(0.5)
    return ("done", job.index)


def test_a_set_that_kills_its_worker_fails_alone():
    """Only the set that takes its worker down fails ("died twice"); the sets that were
    merely queued in the broken pool complete."""
    from hdrcl.shoot.batch.executors import run_processes

    results = []
    run_processes([_Job(i) for i in range(4)], None, results.append, task=_dies_on_set_zero,
                  failed=lambda job, exc: ("failed", job.index, str(exc)), jobs=2)
    by_index = {r[1]: r for r in results}
    assert sorted(by_index) == [0, 1, 2, 3]
    assert by_index[0][0] == "failed" and "died twice" in by_index[0][2]
    assert all(by_index[i] == ("done", i) for i in (1, 2, 3))
