"""Sets overlap in a batch run in this process (issue 33 item 4, :mod:`hdrcl.shoot.batch.overlap`):
set n's commit runs on its own thread while set n+1 starts; one commit at a time, within the
memory budget; results in set order and the same bytes as one set after another; a failing
commit fails its set alone; a cancel during a commit leaves no temporary file and no thread.

Every ordering is shown with events, never with timings (a wait's bound only keeps a broken
run from hanging).
"""
from __future__ import annotations

import json
import os
import signal
import threading

import pytest

from hdrcl.errors import ProcessingError
from hdrcl.shoot.batch import overlap, setrun
from hdrcl.shoot.batch.claims import Cancelled
from hdrcl.shoot.batch.jobs import BatchOptions
from hdrcl.shoot.batch.run import run_batch

try:
    from test_batch import make_clean_shoot
except ImportError:  # tests/ made a package
    from tests.test_batch import make_clean_shoot

BOUND = 60.0  # seconds: only a broken run ever waits this long


@pytest.fixture
def shoot(tmp_path):
    folder = tmp_path / "shoot"
    make_clean_shoot(folder, sets=3, frames=3, width=64, height=48)
    return folder


def _index(step) -> int:
    return step.job.index


def _litter(out):
    return sorted(n for n in os.listdir(out) if ".tmp" in n or n.endswith(".claim") or n.startswith(".hdrcl"))


def _commit_threads():
    return [t.name for t in threading.enumerate() if t.name.startswith("hdrcl-commit")]


def _run(folder, out, **kw):
    order = []
    rep = run_batch(folder, out, options=BatchOptions(), progress=lambda r, n, t: r and order.append(r.index), **kw)
    return rep, order


def test_commit_of_a_set_overlaps_the_start_of_the_next(shoot, tmp_path, monkeypatch, cl_device):
    started = {i: threading.Event() for i in range(3)}
    seen, released = {}, {}
    plan, before = setrun.set_plan, setrun._before_commit

    def set_plan(step, ctx):
        started[_index(step)].set()
        return plan(step, ctx)

    def before_commit(run, step, opts, *made):
        i = _index(step)
        if i + 1 in started:  # set i commits: set i+1 starts meanwhile, on the main thread
            seen[i] = started[i + 1].wait(BOUND), threading.current_thread() is threading.main_thread()
        released[i] = run.source.cache is None  # its decoded frames let go before the commit
        return before(run, step, opts, *made)

    held, release = {}, overlap.release_frames

    def release_frames(run):
        held[len(held)] = run.source.cache is not None and run.source.cache.in_memory
        release(run)

    monkeypatch.setattr(setrun, "set_plan", set_plan)
    monkeypatch.setattr(setrun, "_before_commit", before_commit)
    monkeypatch.setattr(overlap, "release_frames", release_frames)
    rep, order = _run(shoot, tmp_path / "out")
    assert [r.status for r in rep.results] == ["done"] * 3
    assert held == {0: True, 1: True, 2: True}  # each set's frames in memory once fused...
    assert seen == {0: (True, False), 1: (True, False)}
    assert released == {0: True, 1: True, 2: True}
    assert order == [0, 1, 2]  # progress in set order
    assert not _commit_threads() and not _litter(tmp_path / "out")


def test_same_bytes_and_records_as_one_set_after_another(shoot, tmp_path, monkeypatch, cl_device):
    from hdrcl.shoot.batch import run as batch_run

    rep, order = _run(shoot, tmp_path / "overlapped")

    def serial(jobs, ctx, emit):  # the sets one after another, each merged whole on this thread
        for job in jobs:
            emit(setrun.process_set(job, ctx))

    monkeypatch.setattr(batch_run, "_run_pipelined", serial)
    ref, ref_order = _run(shoot, tmp_path / "serial")
    assert order == ref_order == [0, 1, 2]
    for a, b in zip(rep.results, ref.results):
        for path_a, path_b in ((a.output, b.output), (a.preview, b.preview)):
            with open(path_a, "rb") as fa, open(path_b, "rb") as fb:
                assert fa.read() == fb.read(), path_a
        da, db = a.to_dict(), b.to_dict()
        for d in (da, db):
            d.pop("seconds"), d.pop("output"), d.pop("preview")
        assert da == db
    entries = json.load(open(tmp_path / "overlapped" / "report.json"))["sets"]
    assert [e["index"] for e in entries] == [0, 1, 2]
    assert all(e["seconds"]["merge"] > 0 and "total" in e["seconds"] for e in entries)  # per set


def test_a_failing_commit_fails_its_set_alone(shoot, tmp_path, monkeypatch, cl_device):
    from hdrcl.io.writers import RadianceWriter

    close = RadianceWriter.close
    where = {}

    def failing_close(self):
        if os.path.basename(self.path) == "IMG_0004.exr":  # set 1: its EXR cannot be finished
            where["thread"] = threading.current_thread() is threading.main_thread()
            raise ProcessingError(f"{self.path}: cannot write (No space left on device)")
        return close(self)

    monkeypatch.setattr(RadianceWriter, "close", failing_close)
    rep, order = _run(shoot, tmp_path / "out")
    assert [r.status for r in rep.results] == ["done", "failed", "done"] and order == [0, 1, 2]
    assert where == {"thread": False}  # it failed in the commit, on the commit thread
    assert "IMG_0004.exr: cannot write (No space left on device)" in rep.results[1].error
    out = tmp_path / "out"
    assert not (out / "IMG_0004.exr").exists() and (out / "IMG_0007.exr").exists()
    # nor the failed set's preview (written before its EXR was to be committed)
    assert not (out / "IMG_0004.jpg").exists() and (out / "IMG_0007.jpg").exists()
    assert not _litter(out) and not _commit_threads()
    assert rep.exit_code != 0


def test_cancel_during_a_commit_leaves_nothing(shoot, tmp_path, monkeypatch, cl_device):
    committers = []
    init = overlap.Committer.__init__

    def spy(self, *a, **kw):
        init(self, *a, **kw)
        committers.append(self)

    in_commit = threading.Event()
    plan, before = setrun.set_plan, setrun._before_commit

    def before_commit(run, step, opts, *made):
        if _index(step) == 0:  # set 0 commits until the batch is cancelled
            in_commit.set()
            assert committers[0].stop.wait(BOUND)
        return before(run, step, opts, *made)

    def set_plan(step, ctx):
        if _index(step) == 1:  # SIGTERM arrives while set 1 starts and set 0 commits
            assert in_commit.wait(BOUND)
            raise Cancelled(signal.SIGTERM)
        return plan(step, ctx)

    monkeypatch.setattr(overlap.Committer, "__init__", spy)
    monkeypatch.setattr(setrun, "set_plan", set_plan)
    monkeypatch.setattr(setrun, "_before_commit", before_commit)
    out = tmp_path / "out"
    rep, order = _run(shoot, out)
    assert rep.cancelled == signal.SIGTERM
    assert rep.results == [] and order == []  # set 0 stopped before its EXR was moved into place
    assert not [n for n in os.listdir(out) if n.endswith(".exr")]
    assert not _litter(out) and not _commit_threads()


def test_the_next_set_waits_when_both_would_not_fit(shoot, tmp_path, monkeypatch, cl_device):
    events = []
    plan, result = setrun.set_plan, setrun._set_result

    def set_plan(step, ctx):
        events.append(("start", _index(step)))
        return plan(step, ctx)

    def set_result(step, *a):
        events.append(("committed", _index(step)))
        return result(step, *a)

    from hdrcl.io.framecache import memory_budget_bytes

    monkeypatch.setattr(setrun, "set_plan", set_plan)
    monkeypatch.setattr(setrun, "_set_result", set_result)
    monkeypatch.setattr(overlap, "held_bytes", lambda run: memory_budget_bytes())  # the commit holds it all
    rep, order = _run(shoot, tmp_path / "out")
    assert [r.status for r in rep.results] == ["done"] * 3 and order == [0, 1, 2]
    assert events == [("start", 0), ("committed", 0), ("start", 1), ("committed", 1), ("start", 2),
                      ("committed", 2)]


def test_held_and_needed_bytes_count_the_frames(shoot, tmp_path, monkeypatch):
    """The memory rule's figures: a set's codes (capped at the in-memory share) and what a
    fused run holds."""
    from types import SimpleNamespace

    import numpy as np

    from hdrcl.io.framecache import FrameCache

    info = SimpleNamespace(width=100, height=50, nchannels=3, bits=8)
    step = SimpleNamespace(opened=SimpleNamespace(infos=[info] * 4))
    monkeypatch.setenv("HDRCL_MEMORY_MB", "1")
    assert overlap.need_bytes(step) == 4 * 100 * 50 * 3
    monkeypatch.setenv("HDRCL_MEMORY_MB", "0.1")
    assert overlap.need_bytes(step) == int(0.1 * (1 << 20)) // 4
    cache = FrameCache(4, 50, 100, 3, np.uint8, in_memory=True)
    run = SimpleNamespace(source=SimpleNamespace(cache=cache), sinks={"full": SimpleNamespace(array=np.zeros(10))},
                          keep=None, tapped=None)
    assert overlap.held_bytes(run) == 4 * 100 * 50 * 3 + 80
    cache.close()


def test_a_signal_while_a_set_is_handed_over_undoes_it_once(shoot, tmp_path, monkeypatch, cl_device):
    """SIGTERM landing in the hand-over itself (the set queued on the commit thread, the
    main thread not yet told: the thread start inside submit is a wait a signal can
    interrupt): the set is undone by one thread only, never while the other commits it
    (it was aborted on the main thread while the commit thread wrote its preview)."""
    from concurrent.futures import ThreadPoolExecutor

    seen = []
    before = setrun._before_commit

    def before_commit(run, step, opts, *made):
        seen.append(run.writer is not None)  # the main thread must not have aborted it
        return before(run, step, opts, *made)

    class Interrupted(ThreadPoolExecutor):
        def submit(self, fn, *a, **kw):
            super().submit(fn, *a, **kw)
            raise Cancelled(signal.SIGTERM)  # after the task is queued

    monkeypatch.setattr(overlap, "ThreadPoolExecutor", Interrupted)
    monkeypatch.setattr(setrun, "_before_commit", before_commit)
    out = tmp_path / "out"
    rep, order = _run(shoot, out)
    assert rep.cancelled == signal.SIGTERM and rep.results == [] and order == []
    assert seen in ([], [True])  # dropped before it started, or committed whole
    assert not [n for n in os.listdir(out) if n.endswith((".exr", ".jpg"))]
    assert not _litter(out) and not _commit_threads()
