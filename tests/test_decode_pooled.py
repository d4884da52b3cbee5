"""Issue 33: every frame decoded once for everything. The pooled calibration of a batch
keeps the frames it decodes (in memory, else spilled to a scratch file, within
HDRCL_MEMORY_MB) and each set's merge takes them instead of decoding its set again; the
outputs are the same bytes; a cancel drops everything held and leaves no scratch file."""
from __future__ import annotations

import os

import numpy as np
import pytest

from hdrcl.io import ahead
from hdrcl.io import reader as reader_mod

try:
    from test_batch import make_clean_shoot, same_bytes
except ImportError:  # tests/ made a package
    from tests.test_batch import make_clean_shoot, same_bytes

W, H = 96, 64


@pytest.fixture
def rows_decoded(monkeypatch):
    """Rows decoded per file (every BracketReader decode goes through ``_read``)."""
    rows = {}
    real = reader_mod.BracketReader._read

    def counting(self, k, y0, y1):
        out = real(self, k, y0, y1)
        rows[self.paths[k]] = rows.get(self.paths[k], 0) + (y1 - y0)
        return out

    monkeypatch.setattr(reader_mod.BracketReader, "_read", counting)
    return rows


@pytest.fixture(autouse=True)
def _stop_counting():
    yield
    reader_mod.count_full_decodes(False)


@pytest.fixture
def shoot(tmp_path, monkeypatch):
    monkeypatch.setenv("HDRCL_SCRATCH_DIR", str(tmp_path / "scratch"))
    monkeypatch.setattr(ahead, "MEMORY_FILE_SYSTEMS", (), raising=False)  # the spill tests run on a tmpfs /tmp too
    os.makedirs(tmp_path / "scratch")
    folder = str(tmp_path / "shoot")
    make_clean_shoot(folder, sets=3, frames=3, width=W, height=H)  # one camera: a pooled response
    return folder


def _batch(folder, out, **kw):
    from hdrcl.shoot.batch.run import run_batch

    return run_batch(folder, out, **kw)


def _spill_files():
    """This process's open spill files in the scratch folder (unlinked from the start:
    only /proc sees them)."""
    scratch = os.environ["HDRCL_SCRATCH_DIR"]
    out = []
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith(scratch + os.sep):
            out.append(target)
    return out


def _frames(folder):
    return sorted(os.path.join(folder, n) for n in os.listdir(folder) if n.endswith(".jpg"))


@pytest.mark.parametrize("memory_mb, where", [(None, "memory"), ("0.25", "memory and a scratch file")])
def test_each_frame_of_a_pooled_shoot_is_decoded_once_at_full_size(shoot, tmp_path, rows_decoded, monkeypatch,
                                                                   memory_mb, where):
    """3 sets of one camera, pooled: every frame decoded to its last row exactly once (the
    merges take what the pooled calibration decoded), whether the held sets stay in memory
    or (0.25 MB: two sets in memory, the third spilled) partly in a scratch file."""
    if memory_mb:
        monkeypatch.setenv("HDRCL_MEMORY_MB", memory_mb)
    reader_mod.count_full_decodes()
    seen = []
    real_take = ahead.take

    def take(paths):
        got = real_take(paths)
        seen.append(getattr(getattr(got, "cache", None), "in_memory", None))
        return got

    monkeypatch.setattr(ahead, "take", take)
    rep = _batch(shoot, tmp_path / "out")
    spilled = False in seen
    assert seen.count(True) == (2 if memory_mb else 3)
    assert [r.status for r in rep.results] == ["done"] * 3
    assert rep.responses[0].source == "calibrated" and rep.responses[0].sets == [0, 1, 2]
    frames = _frames(shoot)
    assert len(frames) == 9
    counts = reader_mod.full_decodes()
    assert {f: counts.get(f) for f in frames} == {f: 1 for f in frames}, where
    assert {f: rows_decoded.get(f) for f in frames} == {f: H for f in frames}  # no row twice
    assert ahead.held() == 0 and ahead.pending() == 0 and not _spill_files()
    assert os.listdir(tmp_path / "scratch") == []
    assert spilled == (memory_mb is not None)
    for r in rep.results:  # each set's decoding is counted in its own stage seconds
        assert r.seconds["decode"] > 0


def test_outputs_are_the_same_bytes_whether_frames_were_held_or_decoded_again(shoot, tmp_path, monkeypatch):
    held = _batch(shoot, tmp_path / "held")
    monkeypatch.setenv("HDRCL_DECODE_AHEAD", "0")
    monkeypatch.setattr(ahead, "read_and_hold", lambda reader, stride: reader.read_grid(stride))
    again = _batch(shoot, tmp_path / "again", jobs=1)
    assert [r.status for r in held.results] == [r.status for r in again.results] == ["done"] * 3
    names = sorted(n for n in os.listdir(tmp_path / "held") if n.endswith((".exr", ".jpg", ".response.json")))
    assert len([n for n in names if n.endswith(".exr")]) == 3
    for n in names:
        assert same_bytes(tmp_path / "held" / n, tmp_path / "again" / n), n


def test_beyond_the_budget_a_set_keeps_only_its_grid_and_is_decoded_again(shoot, tmp_path, monkeypatch):
    monkeypatch.setenv("HDRCL_MEMORY_MB", "0.01")  # not even the spill file's share fits a set
    reader_mod.count_full_decodes()
    rep = _batch(shoot, tmp_path / "out")
    assert [r.status for r in rep.results] == ["done"] * 3
    counts = reader_mod.full_decodes()
    assert sorted(counts.get(f) for f in _frames(shoot)) == [2] * 9  # grid pass, then the merge
    assert ahead.held() == 0


def test_a_batch_run_elsewhere_holds_nothing(shoot, tmp_path):
    """Calibrate only: nothing merges next, so nothing is held."""
    reader_mod.count_full_decodes()
    _batch(shoot, tmp_path / "out", calibrate_only=True)
    assert ahead.held() == 0 and not _spill_files()
    assert sorted(reader_mod.full_decodes().values()) == [1] * 9


@pytest.mark.parametrize("when", ["calibration", "first set"])
def test_a_cancel_drops_every_held_frame_and_leaves_no_scratch_file(shoot, tmp_path, monkeypatch, when):
    """Interrupted while the pool is read or after the first set: nothing stays held, no
    spill file stays open, the scratch folder is empty."""
    monkeypatch.setenv("HDRCL_MEMORY_MB", "0.25")  # the third set spilled
    if when == "calibration":
        import hdrcl.core.solve as solve

        def interrupted(*a, **k):
            assert ahead.held() == 3 and _spill_files()  # all read, one spilled
            raise KeyboardInterrupt

        monkeypatch.setattr(solve, "recover_response_pooled", interrupted)
        progress = None
    else:
        def progress(res, done, total):
            if res is not None:
                # the first set took its own; the second may have taken its own too (it starts
                # while the first commits: hdrcl.shoot.batch.overlap)
                assert ahead.held() in (1, 2)
                raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _batch(shoot, tmp_path / "out", progress=progress)
    assert ahead.held() == 0 and ahead.pending() == 0 and not _spill_files()
    assert os.listdir(tmp_path / "scratch") == []


def test_a_held_set_is_not_decoded_ahead_and_a_changed_file_is_decoded_again(shoot):
    from hdrcl.core.bracket import grid_bracket, read_infos

    paths = _frames(shoot)[:3]
    infos = read_infos(paths)
    br = grid_bracket(paths, infos, np.ones(3), None, hold=True)
    assert ahead.held() == 1
    assert not ahead.decode_ahead(paths, infos, lambda p, i: reader_mod.BracketReader(p, i, ahead=False))
    with reader_mod.BracketReader(paths, infos) as r:  # taken: the same grid, the frames cached
        assert ahead.held() == 0 and r.cache is not None and r.cache.complete
        assert all(a is b for a, b in zip(r.read_grid(_stride(r))[0], br.frames))
        with reader_mod.BracketReader(paths, infos, ahead=False) as fresh:
            for (y0, y1, fa, _), (z0, z1, fb, _) in zip(r.strips(16), fresh.strips(16)):
                assert (y0, y1) == (z0, z1) and all(np.array_equal(a, b) for a, b in zip(fa, fb))
    grid_bracket(paths, infos, np.ones(3), None, hold=True)
    os.utime(paths[1], ns=(1, 1))  # changed since it was decoded: not used
    with reader_mod.BracketReader(paths, infos) as r:
        assert r.cache is None
    assert ahead.held() == 0


def _stride(r):
    from hdrcl.core.sampling import grid_stride

    return grid_stride(r.height, r.width)


def test_a_full_scratch_folder_only_costs_a_second_decode(shoot, tmp_path, monkeypatch):
    """Holding is an optimisation: a set that should spill but cannot (the scratch folder
    full or gone) keeps only its grid and is decoded again by its merge; the batch goes on
    (it used to fail whole in the pooled calibration with the OSError)."""
    import errno

    from hdrcl.io import framecache

    monkeypatch.setenv("HDRCL_MEMORY_MB", "0.25")  # two sets in memory, the third to spill
    real_put = framecache.FrameCache.put

    def put(self, k, y0, rows, valid=None):
        if not self.in_memory:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_put(self, k, y0, rows, valid)

    monkeypatch.setattr(framecache.FrameCache, "put", put)
    reader_mod.count_full_decodes()
    rep = _batch(shoot, tmp_path / "out")
    assert [r.status for r in rep.results] == ["done"] * 3
    counts = sorted(reader_mod.full_decodes().get(f) for f in _frames(shoot))
    assert counts[:6] == [1] * 6 and min(counts[6:]) >= 2  # the held sets once; the third again (its
    # failed spill stopped at its first strip: here, 64 rows, the whole frame)
    assert ahead.held() == 0 and not _spill_files()
    assert os.listdir(tmp_path / "scratch") == []


@pytest.mark.parametrize("scratch", ["tmpfs", "full disk"])
def test_frames_are_not_spilled_where_the_scratch_folder_is_memory_or_full(shoot, tmp_path, monkeypatch, scratch):
    """A scratch folder on tmpfs holds its files in RAM: spilling held sets there would keep
    up to 4x HDRCL_MEMORY_MB of frames in memory beyond the budget; a disk without room for
    the set fails the spill. Either way the set keeps only its grid (decoded again by its
    merge) and no scratch file is made."""
    import shutil
    from collections import namedtuple

    from hdrcl.io import framecache

    monkeypatch.setenv("HDRCL_MEMORY_MB", "0.25")  # two sets in memory, the third would spill
    if scratch == "tmpfs":
        monkeypatch.setattr(ahead, "MEMORY_FILE_SYSTEMS", ("tmpfs",), raising=False)
        monkeypatch.setattr(ahead, "file_system", lambda folder: "tmpfs", raising=False)
    else:
        usage = namedtuple("usage", "total used free")
        monkeypatch.setattr(shutil, "disk_usage", lambda folder: usage(1 << 30, 1 << 30, 1 << 20))
    spills = []
    real_init = framecache.FrameCache.__init__

    def init(self, *a, **k):
        real_init(self, *a, **k)
        if not self.in_memory:
            spills.append(self)

    monkeypatch.setattr(framecache.FrameCache, "__init__", init)
    reader_mod.count_full_decodes()
    rep = _batch(shoot, tmp_path / "out")
    assert [r.status for r in rep.results] == ["done"] * 3
    assert spills == []
    assert sorted(reader_mod.full_decodes().get(f) for f in _frames(shoot)) == [1] * 6 + [2] * 3
    assert ahead.held() == 0


def test_an_error_before_the_first_set_drops_the_held_frames(shoot, tmp_path, monkeypatch):
    """The pooled calibration held the sets' frames; an error between it and the sets'
    loop (here the caller's progress callback, called once before the first set) drops
    them: a long-lived process keeps no frames (nor open scratch files) of a batch that
    ended."""
    monkeypatch.setenv("HDRCL_MEMORY_MB", "0.25")  # the third set spilled

    def progress(res, done, total):
        assert ahead.held() == 3
        raise RuntimeError("the caller's own error")

    with pytest.raises(RuntimeError):
        _batch(shoot, tmp_path / "out", progress=progress)
    assert ahead.held() == 0 and not _spill_files()


def test_a_ghost_reference_beyond_a_sets_frames_fails_that_set_first_naming_its_file(shoot, tmp_path, monkeypatch):
    """batch --deghost --ghost-reference 5 on sets of 3 frames: each set fails before its
    merge decodes or fuses anything, with a one-line error naming its first file (it
    used to fail inside the fusion, naming no file)."""
    import hdrcl.core.fusestage as fusestage
    from hdrcl.shoot.batch.jobs import BatchOptions

    fused = []
    real_fuse = fusestage.fuse
    monkeypatch.setattr(fusestage, "fuse", lambda run: fused.append(run) or real_fuse(run))
    rep = _batch(shoot, tmp_path / "out", options=BatchOptions(deghost=True, ghost_reference=5))
    assert [r.status for r in rep.results] == ["failed"] * 3
    for r in rep.results:
        assert r.error.startswith(r.files[0] + ": --ghost-reference: frame 5 does not exist")
        assert "\n" not in r.error
    assert fused == []
