"""Decoding the next set while the current one merges (hdrcl.io.ahead): the frames are the
same as a fresh decode, a batch's outputs are the same bytes with it and without it, a
changed file is decoded again, a bad frame still fails its own set, and nothing is left
behind."""
from __future__ import annotations

import glob
import os
import threading

import numpy as np
import pytest

from hdrcl.io import ahead
from hdrcl.io.frames import read_info
from hdrcl.io.reader import BracketReader

OPEN = lambda paths, infos: BracketReader(paths, infos, ahead=False)  # noqa: E731

try:
    from test_batch import make_clean_shoot, report_of, run, same_bytes
except ImportError:  # tests/ made a package
    from tests.test_batch import make_clean_shoot, report_of, run, same_bytes


@pytest.fixture
def one_set(tmp_path):
    make_clean_shoot(str(tmp_path / "shoot"), sets=1, frames=3, width=96, height=64)
    paths = sorted(glob.glob(str(tmp_path / "shoot" / "*.jpg")))
    return paths, [read_info(p) for p in paths]


def _helpers():
    return [t for t in threading.enumerate() if t.name == "hdrcl-decode-ahead"]


def test_frames_decoded_ahead_are_the_frames_a_reader_decodes(one_set):
    paths, infos = one_set
    with BracketReader(paths, infos, ahead=False) as fresh:
        want_grid = fresh.read_grid(2)
        want_strips = [(y0, y1, [f.copy() for f in fr]) for y0, y1, fr, _ in fresh.strips(16)]
    assert ahead.decode_ahead(paths, infos, OPEN)
    with BracketReader(paths, infos) as reader:
        assert ahead.pending() == 0 and reader.cache is not None and reader.cache.complete
        grid = reader.read_grid(2, keep=True)
        strips = [(y0, y1, fr) for y0, y1, fr, _ in reader.strips(16)]
    for a, b in zip(want_grid[0], grid[0]):
        assert np.array_equal(a, b)
    assert len(strips) == len(want_strips)
    for (a0, a1, fa), (b0, b1, fb) in zip(want_strips, strips):
        assert (a0, a1) == (b0, b1) and all(np.array_equal(x, y) for x, y in zip(fa, fb))
    assert not _helpers()


def test_a_file_changed_after_it_was_decoded_ahead_is_decoded_again(one_set):
    paths, infos = one_set
    assert ahead.decode_ahead(paths, infos, OPEN)
    ahead._pending[ahead._key(paths)].thread.join()
    os.utime(paths[1], ns=(1, 1))  # another mtime: the frames decoded ahead are not used
    with BracketReader(paths, infos) as reader:
        assert reader.cache is None
    assert ahead.pending() == 0


def test_only_one_set_ahead_and_cancel_leaves_nothing(one_set, monkeypatch):
    paths, infos = one_set
    assert ahead.decode_ahead(paths, infos, OPEN)
    assert not ahead.decode_ahead(list(reversed(paths)), infos, OPEN)  # one set at a time
    ahead.cancel_all()
    assert ahead.pending() == 0 and not _helpers()
    monkeypatch.setenv("HDRCL_MEMORY_MB", "0.01")  # does not fit the budget: not decoded ahead
    assert not ahead.decode_ahead(paths, infos, OPEN)
    monkeypatch.delenv("HDRCL_MEMORY_MB")
    monkeypatch.setenv("HDRCL_DECODE_AHEAD", "0")
    assert not ahead.decode_ahead(paths, infos, OPEN)


def test_batch_outputs_are_the_same_bytes_with_and_without_decoding_ahead(tmp_path, monkeypatch):
    folder = str(tmp_path / "shoot")
    make_clean_shoot(folder, sets=3, frames=3, width=96, height=64)
    taken = []
    real_take = ahead.take

    def counting_take(paths):
        got = real_take(paths)
        taken.append(got is not None)
        return got

    monkeypatch.setattr(ahead, "take", counting_take)
    # The pooled calibration would hold every set's frames for its merge (nothing left to
    # decode ahead): this test is about decoding ahead, so the pool keeps only its grids.
    monkeypatch.setattr(ahead, "read_and_hold", lambda reader, stride: reader.read_grid(stride))
    r = run("batch", folder, "-o", tmp_path / "with")
    assert r.exit_code == 0, r.output
    assert sum(taken) == 2  # the second and third sets were decoded ahead and used
    monkeypatch.setenv("HDRCL_DECODE_AHEAD", "0")
    r = run("batch", folder, "-o", tmp_path / "without")
    assert r.exit_code == 0, r.output
    names = sorted(n for n in os.listdir(tmp_path / "with") if n.endswith((".exr", ".jpg")))
    assert len([n for n in names if n.endswith(".exr")]) == 3
    for n in names:
        assert same_bytes(tmp_path / "with" / n, tmp_path / "without" / n), n
    assert ahead.pending() == 0 and not _helpers()


def test_a_damaged_frame_is_judged_the_same_with_and_without_decoding_ahead(tmp_path, monkeypatch):
    """A frame cut short (decoded ahead or not): the same statuses, errors and outputs;
    one bad set never takes the others down."""
    folder = str(tmp_path / "shoot")
    groups = make_clean_shoot(folder, sets=3, frames=3, width=96, height=64)
    bad = os.path.join(folder, groups[1][1])
    with open(bad, "r+b") as fh:
        fh.truncate(os.path.getsize(bad) // 3)
    seen = {}
    for mode in ("1", "0"):
        monkeypatch.setenv("HDRCL_DECODE_AHEAD", mode)
        out = tmp_path / f"out{mode}"
        r = run("batch", folder, "-o", out)
        rep = report_of(str(out))
        seen[mode] = (r.exit_code, sorted((e["index"], e["status"], e.get("error")) for e in rep["sets"]),
                      sorted(n for n in os.listdir(out) if n.endswith(".exr")))
        assert ahead.pending() == 0 and not _helpers()
    assert seen["1"] == seen["0"]
    assert sum(1 for _, status, _ in seen["1"][1] if status == "done") >= 2


def test_a_set_merged_elsewhere_does_not_hold_its_frames_or_block_the_next(one_set, tmp_path):
    """A set decoded ahead whose merge never opens it (another process merged it) is
    dropped, and the next set can be decoded ahead."""
    paths, infos = one_set
    assert ahead.decode_ahead(paths, infos, OPEN)
    ahead.discard(paths)
    assert ahead.pending() == 0 and not _helpers()
    assert ahead.decode_ahead(list(reversed(paths)), infos, OPEN)
    ahead.cancel_all()
    assert ahead.pending() == 0


def test_nothing_is_decoded_ahead_once_the_batch_stopped(tmp_path):
    """A read of the next set still running when the batch is cancelled must not start
    decoding it after cancel_all() (its frames would stay in memory, and decode-ahead be
    off for the rest of the process)."""
    import threading

    from hdrcl.io import ahead

    from types import SimpleNamespace

    info = SimpleNamespace(nchannels=3, width=4, height=4, bits=8)
    stop = threading.Event()
    stop.set()
    assert ahead.decode_ahead([str(tmp_path / "a.png")], [info], lambda *a: None, stop) is False
    assert ahead.pending() == 0
