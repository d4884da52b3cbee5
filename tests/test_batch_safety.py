"""A batch never writes over its inputs, leaves an embedding application's signal
handlers alone, and rebuilds previews and reports only under the set's claim."""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import textwrap
import time

import pytest
from click.testing import CliRunner

from hdrcl.cli import main

try:
    from test_batch import make_clean_shoot
except ImportError:  # tests/ made a package
    from tests.test_batch import make_clean_shoot

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (REPO, os.environ.get("PYTHONPATH")) if p))


def digests(folder):
    return {n: hashlib.md5((folder / n).read_bytes()).hexdigest() for n in sorted(os.listdir(folder))
            if (folder / n).is_file()}


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "hdrcl", *map(str, args)], env=ENV, capture_output=True, text=True,
                          timeout=300)


# ------------------------------------------------------------ outputs over inputs
def test_batch_into_its_source_folder_is_refused_and_touches_nothing(tmp_path):
    shoot = tmp_path / "S"
    assert run_cli("sample-shoot", shoot).returncode == 0
    before = digests(shoot)
    res = run_cli("batch", shoot, "-o", shoot)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hdrcl: error: ") and "input" in lines[0], res.stderr
    assert digests(shoot) == before  # not a byte changed, nothing added


def test_hard_linked_input_in_the_output_folder_is_refused(tmp_path):
    shoot, out = tmp_path / "S", tmp_path / "out"
    groups = make_clean_shoot(shoot, sets=2, frames=3)
    out.mkdir()
    os.link(shoot / groups[1][0], out / (os.path.splitext(groups[1][0])[0] + ".jpg"))  # same file, other name
    before = digests(shoot)
    res = run_cli("batch", shoot, "-o", out)
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert digests(shoot) == before
    assert not (out / "report.json").exists()


@pytest.mark.parametrize("where", ["report-json", "report-dir"])
def test_report_files_over_an_input_are_refused(tmp_path, where):
    shoot, out = tmp_path / "S", tmp_path / "out"
    groups = make_clean_shoot(shoot, sets=2, frames=3)
    if where == "report-json":  # the JSON report over the manifest it reads
        man = shoot / "m.json"
        man.write_text(json.dumps({"sets": [{"files": [str(shoot / f) for f in g]} for g in groups]}))
        args = [man, "-o", out, "--report-json", man]
    else:  # set 0's quality report writes IMG_0001-frame-00.jpg: a frame of set 1 here
        os.rename(shoot / groups[1][1], shoot / "IMG_0001-frame-00.jpg")
        args = [shoot, "-o", out, "--report", shoot]
    before = digests(shoot)
    res = run_cli("batch", *args)
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert digests(shoot) == before


def test_no_preview_into_the_source_folder_is_allowed(tmp_path):
    """Nothing the batch writes is an input: .exr beside .jpg frames is fine."""
    shoot = tmp_path / "S"
    make_clean_shoot(shoot, sets=1, frames=3)
    before = digests(shoot)
    res = CliRunner().invoke(main, ["batch", str(shoot), "-o", str(shoot), "--no-preview"])
    assert res.exit_code == 0, res.output
    after = digests(shoot)
    assert {n: after[n] for n in before} == before


# ------------------------------------------------------------------ signals, API
SCRIPT = textwrap.dedent("""
    import os, signal, sys, time
    from hdrcl.shoot.batch.run import run_batch
    from hdrcl.shoot.batch.jobs import BatchOptions

    def mine(signum, frame):
        print("caller-handler", signum, flush=True)

    if __name__ == "__main__":
        mode, shoot, out, jobs = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
        if mode == "custom":
            signal.signal(signal.SIGTERM, mine)
        def progress(res, done, total):
            if res is not None and done == 1:
                print("first-set", flush=True)
                os.kill(os.getpid(), signal.SIGTERM if mode == "custom" else signal.SIGINT)
                time.sleep(0.5)
        try:
            rep = run_batch(shoot, out, jobs=jobs, options=BatchOptions(preview=False), progress=progress)
        except KeyboardInterrupt:
            print("caller-got-KeyboardInterrupt", flush=True)
            sys.exit(7)
        print("returned", rep.cancelled, len(rep.results), flush=True)
""")


@pytest.mark.parametrize("jobs", [1, 2])
def test_run_batch_leaves_the_callers_sigterm_handler(tmp_path, jobs):
    shoot, out = tmp_path / "S", tmp_path / "out"
    make_clean_shoot(shoot, sets=3, frames=3, width=96, height=64)
    script = tmp_path / "embed.py"
    script.write_text(SCRIPT)
    res = subprocess.run([sys.executable, str(script), "custom", shoot, out, str(jobs)], env=ENV,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert f"caller-handler {int(__import__('signal').SIGTERM)}" in res.stdout
    assert "returned None 3" in res.stdout, res.stdout  # not cancelled: the caller's handler decided


@pytest.mark.parametrize("jobs", [1, 2])
def test_ctrl_c_reaches_the_caller_as_keyboardinterrupt_after_cleanup(tmp_path, jobs):
    import psutil

    shoot, out = tmp_path / "S", tmp_path / "out"
    make_clean_shoot(shoot, sets=6, frames=3, width=320, height=240)
    script = tmp_path / "embed.py"
    script.write_text(SCRIPT)
    proc = subprocess.Popen([sys.executable, str(script), "default", shoot, out, str(jobs)], env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    kids, deadline = set(), time.monotonic() + 300
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            kids |= {k.pid for k in psutil.Process(proc.pid).children(recursive=True)}
        except psutil.NoSuchProcess:
            break
        time.sleep(0.05)
    so, se = proc.communicate(timeout=60)
    assert proc.returncode == 7 and "caller-got-KeyboardInterrupt" in so, (so, se)
    assert "returned" not in so
    def alive(p):
        try:
            return psutil.Process(p).status() != psutil.STATUS_ZOMBIE
        except psutil.NoSuchProcess:
            return False

    # Children that were killed or told to stop (the workers, multiprocessing's resource
    # tracker, which ends when its parent's pipe closes) may still be on their way out on a
    # loaded machine: wait for that state, bounded, instead of looking once.
    deadline = time.monotonic() + 120
    while (left := [p for p in kids if alive(p)]) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert left == [], [psutil.Process(p).cmdline() for p in left if alive(p)]
    assert [n for n in os.listdir(out) if ".tmp" in n or n.endswith(".claim")] == []


# ------------------------------------------------------- rebuilds hold the claim
def test_preview_and_quality_rebuilds_hold_the_sets_claim(tmp_path, monkeypatch):
    from hdrcl.shoot.batch import setrun
    from hdrcl.shoot.batch.claims import SetClaim
    from hdrcl.shoot.batch.jobs import BatchOptions
    from hdrcl.shoot.batch.run import run_batch

    shoot, out, rdir = tmp_path / "S", tmp_path / "out", tmp_path / "report"
    make_clean_shoot(shoot, sets=1, frames=3)
    opts = BatchOptions(report_dir=str(rdir))
    assert run_batch(shoot, out, options=opts).exit_code == 0
    os.remove(out / "IMG_0001.jpg")
    for n in os.listdir(rdir):
        if n.startswith("IMG_0001"):
            os.remove(rdir / n)
    free = {}

    def spy(name, real):
        def wrapped(*args, **kwargs):
            c = SetClaim(str(out), "IMG_0001")
            got = c.acquire(wait=False)  # another open file: fails while the claim is held
            if got:
                c.release()
            free[name] = got
            return real(*args, **kwargs)
        return wrapped

    monkeypatch.setattr(setrun, "_rebuild_preview", spy("preview", setrun._rebuild_preview))
    monkeypatch.setattr(setrun, "_rebuild_quality", spy("quality", setrun._rebuild_quality))
    rep = run_batch(shoot, out, options=opts)
    assert rep.exit_code == 0 and rep.results[0].status == "skipped"
    assert free == {"preview": False, "quality": False}
    assert (out / "IMG_0001.jpg").is_file() and (rdir / "IMG_0001.json").is_file()
    assert [n for n in os.listdir(out) if ".tmp" in n or n.endswith(".claim")] == []


def test_stale_temp_cleanup_spares_a_set_another_process_holds(tmp_path):
    from hdrcl.shoot.batch.claims import SetClaim
    from hdrcl.shoot.batch.state import STALE_TEMP_SECONDS, _remove_stale_temps

    out = tmp_path / "out"
    out.mkdir()
    held, orphan = out / ".B.tmp-0123abcd.exr", out / ".C.tmp-89abcdef.exr"
    for p in (held, orphan):
        p.write_bytes(b"x")
    old = time.time() - 2 * STALE_TEMP_SECONDS
    for p in (held, orphan):  # old, like a long merge of another chunk's set
        os.utime(p, (old, old))
    claim = SetClaim(str(out), "B")
    assert claim.acquire(wait=False)
    try:
        _remove_stale_temps(str(out), ["A"])  # this run's sets: A only
        assert held.exists()  # B's writer is alive
        assert not orphan.exists()  # nobody holds C: its writer is gone
    finally:
        claim.release()
