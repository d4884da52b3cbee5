"""The on-disk cache of built OpenCL programs (:mod:`hdrcl.cl.context`).

A second process loads every program it needs from the cache and builds none from
source; a damaged or rejected cache file, a folder that cannot be written and
``HDRCL_PROGRAM_CACHE=0`` all still give working kernels.
"""
import json
import os
import subprocess
import sys

import pytest

#: Builds the kernels a merge, an exposure, a tone map and an alignment use; prints the
#: process's build counts.
SCRIPT = """
import json
from hdrcl.cl.context import build_counts, get_context
ctx = get_context()  # builds the fusion probe
ctx.kernel("exposure", "expose", ("-DOUT_T=uchar",))
ctx.kernel("tonemap", "tonemap_global", ("-DOUT_T=uchar",))
ctx.kernel("align", "threshold")
print(json.dumps(build_counts))
"""
PROGRAMS = 4  # fusion, exposure, tonemap, align


def _run(cache, **env):
    full = {k: v for k, v in os.environ.items() if k not in ("HDRCL_PROGRAM_CACHE", "HDRCL_OPENCL")}
    full.update({"HDRCL_CACHE_DIR": str(cache)}, **env)
    r = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=full, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def _binaries(cache):
    folder = cache / "programs"
    return sorted(p for p in folder.iterdir() if p.suffix == ".bin") if folder.is_dir() else []


def test_a_second_process_builds_nothing(cl_device, tmp_path):
    cache = tmp_path / "cache"
    first = _run(cache)
    assert first["source"] == PROGRAMS and first["stored"] == PROGRAMS and first["cached"] == 0, first
    assert len(_binaries(cache)) == PROGRAMS
    second = _run(cache)
    assert second["source"] == 0 and second["cached"] == PROGRAMS, second
    assert second["damaged"] == 0 and second["rejected"] == 0 and second["stored"] == 0, second


def test_damaged_and_rejected_files_fall_back_to_source(cl_device, tmp_path):
    import hashlib

    from hdrcl.cl import context

    cache = tmp_path / "cache"
    _run(cache)
    bins = _binaries(cache)
    assert len(bins) == PROGRAMS
    # on-disk damage: flipped bytes, a truncated file, an empty file (the checksum catches it)
    data = bins[0].read_bytes()
    bins[0].write_bytes(data[:-10] + bytes(b ^ 0xFF for b in data[-10:]))
    bins[1].write_bytes(data[: len(data) // 2])
    bins[2].write_bytes(b"")
    # intact file, but not a program the driver accepts
    junk = b"\x7fELF not a program binary" * 50
    bins[3].write_bytes(context._MAGIC + hashlib.sha256(junk).digest() + junk)
    counts = _run(cache)
    assert counts["source"] == PROGRAMS and counts["cached"] == 0, counts
    assert counts["damaged"] == 3 and counts["rejected"] == 1 and counts["stored"] == PROGRAMS, counts
    again = _run(cache)  # replaced by good binaries
    assert again["source"] == 0 and again["cached"] == PROGRAMS, again


def _make_read_only(folder):
    """Make ``folder`` unwritable for this process; True if a subprocess sees it so too
    (not when running as root, whom permission bits do not stop)."""
    for root, dirs, files in os.walk(folder):
        for n in files:
            os.chmod(os.path.join(root, n), 0o444)
        os.chmod(root, 0o555)
    probe = folder / ".probe"
    try:
        probe.write_text("x")
    except OSError:
        return True
    probe.unlink()
    return False


def _restore(folder):
    for root, dirs, files in os.walk(folder):
        os.chmod(root, 0o755)


def test_read_only_cache_folder(cl_device, tmp_path, monkeypatch):
    from hdrcl.cl import context

    cache = tmp_path / "cache"
    _run(cache)
    (cache / "programs").mkdir(exist_ok=True)
    empty = tmp_path / "empty"
    (empty / "programs").mkdir(parents=True)
    try:
        really = _make_read_only(cache) and _make_read_only(empty)
        if really:
            loaded = _run(cache)  # what is there still loads
            assert loaded["source"] == 0 and loaded["cached"] == PROGRAMS, loaded
            built = _run(empty)  # nothing there and nothing can be stored: built, no error
            assert built["source"] == PROGRAMS and built["stored"] == 0, built
        else:  # root: make the writes fail in this process instead
            def refuse(*a, **k):
                raise PermissionError(13, "Permission denied")

            monkeypatch.setenv("HDRCL_CACHE_DIR", str(empty))
            monkeypatch.setattr(context.tempfile, "mkstemp", refuse)
            before = dict(context.build_counts)
            ctx = context.DeviceContext(cl_device.device)
            ctx.kernel("exposure", "expose", ("-DOUT_T=uchar",))
            assert context.build_counts["source"] == before["source"] + 1
            assert context.build_counts["stored"] == before["stored"]
            monkeypatch.setenv("HDRCL_CACHE_DIR", str(cache))
            ctx = context.DeviceContext(cl_device.device)
            ctx.kernel("exposure", "expose", ("-DOUT_T=uchar",))
            assert context.build_counts["cached"] == before["cached"] + 1
        assert sorted(p.name for p in (empty / "programs").iterdir()) == []
    finally:
        _restore(cache)
        _restore(empty)


def test_cache_folder_that_cannot_be_made(cl_device, tmp_path, monkeypatch):
    from hdrcl.cl import context

    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("HDRCL_CACHE_DIR", str(blocker / "cache"))
    before = dict(context.build_counts)
    ctx = context.DeviceContext(cl_device.device)
    ctx.kernel("tonemap", "tonemap_global", ("-DOUT_T=uchar",))
    assert context.build_counts["source"] == before["source"] + 1
    assert context.build_counts["stored"] == before["stored"]


def test_cache_off(cl_device, tmp_path):
    cache = tmp_path / "cache"
    counts = _run(cache, HDRCL_PROGRAM_CACHE="0")
    assert counts["source"] == PROGRAMS and counts["stored"] == 0 and counts["cached"] == 0, counts
    assert not (cache / "programs").exists()


def test_cache_location(monkeypatch, tmp_path):
    from hdrcl.cl.context import program_cache_dir

    monkeypatch.delenv("HDRCL_CACHE_DIR", raising=False)
    monkeypatch.delenv("HDRCL_PROGRAM_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert program_cache_dir() == str(tmp_path / "xdg" / "hdrcl" / "programs")
    monkeypatch.setenv("HDRCL_CACHE_DIR", str(tmp_path / "own"))
    assert program_cache_dir() == str(tmp_path / "own" / "programs")
    for off in ("0", "off", "false"):
        monkeypatch.setenv("HDRCL_PROGRAM_CACHE", off)
        assert program_cache_dir() is None


def test_key_tells_sources_options_and_compiler_settings_apart(cl_device, monkeypatch, tmp_path):
    from hdrcl.cl.context import _cache_path

    monkeypatch.setenv("HDRCL_CACHE_DIR", str(tmp_path))
    dev = cl_device.device
    base = _cache_path(dev, "kernel void f() {}", ["-DA=1"])
    assert base == _cache_path(dev, "kernel void f() {}", ["-DA=1"])
    assert base != _cache_path(dev, "kernel void f() { }", ["-DA=1"])
    assert base != _cache_path(dev, "kernel void f() {}", ["-DA=2"])
    monkeypatch.setenv("POCL_EXTRA_BUILD_FLAGS", "-O0")  # changes what PoCL compiles
    assert base != _cache_path(dev, "kernel void f() {}", ["-DA=1"])


def test_prune_keeps_the_most_recent(tmp_path):
    from hdrcl.cl.context import _prune

    for i in range(6):
        p = tmp_path / f"{i:064x}.bin"
        p.write_bytes(b"x")
        os.utime(p, (1000 + i, 1000 + i))
    _prune(str(tmp_path), keep=4)
    assert sorted(p.name[-5:] for p in tmp_path.iterdir()) == [f"{i}.bin" for i in (2, 3, 4, 5)]
