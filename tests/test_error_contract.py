"""The error contract, case by case (issue 12's audit): every bad input ends as exactly
one line on stderr, ``hdrcl: error: SUBJECT: problem``, with the README's exit code
(2 usage, 3 unreadable or inconsistent input, 1 processing failed), and leaves no output
file (nor a temporary one) behind.

Each row of CASES is (id, command line, exit code, pattern of the line, outputs that must
not exist, condition). Conditions that a test cannot create for real as root (an
unreadable file, a read-only folder, a full disk) are simulated at the system-call
level; ``test_real_read_only_and_full_disk`` repeats those on real mounts where it can.
"""
import errno
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.core import synthetic as s

TIMES = (1 / 60, 1 / 15, 1 / 4)
LINE = re.compile(r"^hdrcl: error: \S.*$")


# ----------------------------------------------------------------------------- files


@pytest.fixture(scope="module")
def fx(tmp_path_factory):
    """Small files for every case: brackets, responses, a radiance map, a shoot."""
    from hdrcl.core.response import Response, knot_positions
    from hdrcl.io.writers import write_radiance
    from hdrcl.io.ldr import write_ldr
    from hdrcl.shoot.batch.manifest import save_manifest
    from hdrcl.shoot.batch.plan import load_source
    from hdrcl.shoot.sample import write_sample_shoot

    d = tmp_path_factory.mktemp("contract")
    rad = s.radiance_field(24, 32, decades=3.0, seed=3)
    f = {"dir": d}
    for bits in (8, 16):
        cam = s.Camera(a=1.1, bits=bits)
        b = d / f"b{bits}"
        b.mkdir()
        for k, frame in enumerate(s.bracket(rad, TIMES, cam, noise=0.3, seed=4)):
            write_ldr(str(b / f"f{k}.png"), frame)
        (b / "times.txt").write_text("".join(f"f{k}.png {t!r}\n" for k, t in enumerate(TIMES)))
        z = knot_positions(bits)
        g = np.stack([cam.g(np.clip(z, 1, (1 << bits) - 2))] * 3)
        g -= g[:, [len(z) // 2]]
        Response(bits=bits, g=g, knots=z).save(d / f"resp{bits}.json")
        f[f"b{bits}"] = b
        f[f"f{bits}"] = [str(b / f"f{k}.png") for k in range(3)]
        f[f"t{bits}"] = str(b / "times.txt")
        f[f"r{bits}"] = str(d / f"resp{bits}.json")
    write_radiance(str(d / "rad.exr"), rad.astype(np.float32), dtype="float")
    f["rad"] = str(d / "rad.exr")
    data = Path(f["f8"][1]).read_bytes()
    (d / "trunc.png").write_bytes(data[: len(data) // 2])
    f["trunc"] = str(d / "trunc.png")
    resp = json.loads(Path(f["r8"]).read_text())
    bad = {"version_abc": {"version": "abc"}, "version_null": {"version": None},
           "samples_abc": {"samples": "abc"}, "camera_list": {"camera": [1, 2]},
           "exposure_no_nominal": {"exposures": [{"file": "a.png"}]},
           "knots_reversed": {"knots": resp["knots"][::-1]}, "version_2_0": {"version": 2.0},
           "version_1e300": {"version": 1e300}, "version_1_5": {"version": 1.5}}
    for name, change in bad.items():
        (d / f"{name}.json").write_text(json.dumps({**resp, **change}))
    (d / "deep.json").write_text('{"format": "hdrcl-response", "camera": ' + "[" * 100000 + "]" * 100000 + "}")
    (d / "bom.json").write_text("\ufeff" + Path(f["r8"]).read_text(), encoding="utf-8")
    (d / "mdeep.json").write_text('{"sets": ' + "[" * 50000 + "]" * 50000 + "}")
    gains = [0, 1e308, 0]
    (f["b8"] / "gain.txt").write_text("".join(f"f{k}.png {t!r} {1 / t!r} 8 {gains[k]} 0\n"
                                              for k, t in enumerate(TIMES)))
    for k in range(3):  # copies of the 16-bit frames: "-o" naming one of the inputs
        shutil.copy(f["f16"][k], d / f"t{k}.png")
    shoot = d / "shoot"
    write_sample_shoot(shoot, width=48, height=32)
    save_manifest(load_source(str(shoot)), shoot / "manifest.json")
    f["shoot"] = str(shoot)
    f["jpeg"] = str(sorted(shoot.glob("*.jpg"))[0])
    (d / "ro").mkdir()
    f["ro"] = str(d / "ro")
    os.mkfifo(d / "fifo")  # nobody ever writes it: a reader that opens it waits for ever
    f["fifo"] = str(d / "fifo")
    return f


# ------------------------------------------------------------------ system conditions


def _read_only(monkeypatch, fx):
    """The folder fx['ro'] behaves as on a read-only file system."""
    import hdrcl.io.atomic as atomic

    real = atomic._read_only_fs
    monkeypatch.setattr(atomic, "_read_only_fs",
                        lambda folder: os.path.abspath(folder).startswith(fx["ro"]) or real(folder))


def _unreadable(monkeypatch, fx):
    real = os.access
    victim = fx["f8"][0]
    monkeypatch.setattr(os, "access", lambda p, mode, *a, **k: (
        False if os.fspath(p) == victim and mode & os.R_OK else real(p, mode, *a, **k)))


def _disk_full(monkeypatch, fx):
    real = os.write

    def write(fd, data):
        if fd > 2:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd, data)

    monkeypatch.setattr(os, "write", write)


CONDITIONS = {"ro": _read_only, "unreadable": _unreadable, "full": _disk_full}


# --------------------------------------------------------------------------- the table


def _merge8(fx, *extra):
    return ["merge", *fx["f8"], "--times-file", fx["t8"], *extra]


CASES = [
    # click's own checks: one line, and exit 3 when an input cannot be read
    ("folder-as-image", lambda x: ["merge", str(x["b8"]), x["f8"][1], "--times-file", x["t8"], "-o", "{o}/a.exr"],
     3, r"b8: is a folder, not an image; give its images with a glob .*hdrcl batch", ["a.exr"], None),
    ("unreadable-image", lambda x: _merge8(x, "-o", "{o}/a.exr"), 3, r"f0.png: permission denied", ["a.exr"],
     "unreadable"),
    ("times-file-folder", lambda x: ["merge", *x["f8"], "--times-file", str(x["b8"]), "-o", "{o}/a.exr"],
     3, r"b8: is a folder, not a times file", ["a.exr"], None),
    ("response-folder", lambda x: _merge8(x, "--response", str(x["b8"]), "-o", "{o}/a.exr"),
     3, r"b8: is a folder, not a response file", ["a.exr"], None),
    *[(f"times-{k}", (lambda v: lambda x: ["merge", *x["f8"], "--times", v, "-o", "{o}/a.exr"])(v), 2,
       r"^hdrcl: error: --times: ", ["a.exr"], None)
      for k, v in enumerate(["abc", "1/0", "-1", "0", "", "nan", "1/30,,1/4", "inf"])],
    ("times-count", lambda x: ["merge", *x["f8"], "--times", "1,2", "-o", "{o}/a.exr"], 2,
     r"--times: 2 exposure time\(s\) given for 3 files", ["a.exr"], None),
    ("samples-0", lambda x: ["calibrate", *x["f8"], "--times-file", x["t8"], "--samples", "0", "-o", "{o}/r.json"],
     2, r"--samples: 0 is out of range \(1 <= samples", ["r.json"], None),
    ("missing-option", lambda x: ["merge", *x["f8"], "--times-file", x["t8"]], 2, r"-o/--output: missing", [],
     None),
    ("unknown-option", lambda x: _merge8(x, "--bogus", "-o", "{o}/a.exr"), 2, r"--bogus: no such option",
     ["a.exr"], None),
    ("no-such-command", lambda x: ["mergee", *x["f8"]], 2, r"^hdrcl: error: mergee: no such command", [], None),
    ("option-without-value", lambda x: ["merge", *x["f8"], "--times"], 2, r"^hdrcl: error: --times: needs a value",
     [], None),
    ("choice", lambda x: _merge8(x, "--weight", "bogus", "-o", "{o}/a.exr"), 2, r"^hdrcl: error: --weight: 'bogus'",
     ["a.exr"], None),
    ("truncated-png", lambda x: ["merge", x["f8"][0], x["trunc"], x["f8"][2], "--times", "1/60,1/15,1/4",
                                 "-o", "{o}/a.exr"], 3, r"trunc.png: truncated PNG data", ["a.exr"], None),
    # user-causable problems that were "internal error"
    *[(f"response-{n}", (lambda n: lambda x: _merge8(x, "--response", str(x["dir"] / f"{n}.json"), "-o",
                                                     "{o}/a.exr"))(n), 3, rf"{n}.json: {field}", ["a.exr"], None)
      for n, field in [("version_abc", r"version: expected an integer"), ("version_null", "version: expected"),
                       ("samples_abc", "samples: expected an integer"), ("camera_list", "camera: expected an object"),
                       ("exposure_no_nominal", r"exposures\[0\]: missing 'nominal'"),
                       ("knots_reversed", "knots: expected increasing"),
                       ("version_2_0", r"response file version 2 is newer than this hdrcl"),
                       ("version_1e300", r"response file version 1e\+300 is newer than this hdrcl"),
                       ("version_1_5", r"version: expected an integer, not 1.5")]],
    ("response-deep", lambda x: _merge8(x, "--response", str(x["dir"] / "deep.json"), "-o", "{o}/a.exr"),
     3, r"deep.json: response file nested too deeply", ["a.exr"], None),
    ("manifest-deep", lambda x: ["batch", str(x["dir"] / "mdeep.json"), "-o", "{o}/batch"], 3,
     r"mdeep.json: manifest file nested too deeply", ["batch"], None),
    ("gain-1e308", lambda x: ["merge", *x["f8"], "--times-file", str(x["b8"] / "gain.txt"), "-o", "{o}/a.exr"],
     3, r"gain.txt line 2: gain 1e\+308 dB is out of range", ["a.exr"], None),
    ("motion-blur-nan", lambda x: ["expose", x["rad"], "--response", x["r8"], "--time", "1/30", "--motion-blur",
                                   "nan,0", "-o", "{o}/p.jpg"], 2, r"--motion-blur: expected DX,DY", ["p.jpg"], None),
    ("motion-blur-huge", lambda x: ["expose", x["rad"], "--response", x["r8"], "--time", "1/30", "--motion-blur",
                                    "1e9,0", "-o", "{o}/p.jpg"], 2, r"--motion-blur: .* longer than the image",
     ["p.jpg"], None),
    ("save-response-read-only", lambda x: _merge8(x, "--save-response", x["ro"] + "/r.json", "-o", "{o}/a.exr"),
     2, r"ro/r.json: the output folder is on a read-only file system", ["a.exr"], "ro"),
    ("save-response-disk-full", lambda x: _merge8(x, "--save-response", "{o}/r.json", "-o", "{o}/a.exr"),
     1, r"r.json: cannot write \(no space left on the device\)", ["a.exr", "r.json"], "full"),
    ("batch-out-read-only", lambda x: ["batch", x["shoot"], "-o", x["ro"]], 2, r"ro: the output folder is not writable",
     [], "ro"),
    ("batch-out-under-read-only", lambda x: ["batch", x["shoot"], "-o", x["ro"] + "/a/b"], 2,
     r"ro/a/b: the output folder cannot be created in .*ro \(not writable\)", [], "ro"),
    ("pfm-read-only", lambda x: _merge8(x, "-o", x["ro"] + "/a.pfm"), 2, r"ro/a.pfm: the output folder is on a read",
     [], "ro"),
    # wrong or missing refusals
    ("output-is-input-png", lambda x: ["merge", *(str(x["dir"] / f"t{k}.png") for k in range(3)), "--times",
                                   "1/60,1/15,1/4", "-o", str(x["dir"] / "t2.png")], 2,
     r"a radiance map is written as", [], None),
    ("expose-ldr-as-radiance", lambda x: ["expose", x["f8"][1], "--response", x["r8"], "--time", "1/30", "-o",
                                          "{o}/p.jpg"], 3, r"f1.png: an 8-bit photograph, not a radiance map",
     ["p.jpg"], None),
    ("tonemap-ldr-as-radiance", lambda x: ["tonemap", x["f8"][1], "-o", "{o}/p.jpg"], 3,
     r"f1.png: an 8-bit photograph, not a radiance map", ["p.jpg"], None),
    ("tonemap-exposure-nan", lambda x: ["tonemap", x["rad"], "--exposure", "nan", "-o", "{o}/p.jpg"], 2,
     r"--exposure: nan is not a finite number of stops", ["p.jpg"], None),
    *[(f"tonemap-exposure-{v}", (lambda v: lambda x: ["tonemap", x["rad"], "--exposure", v, "-o", "{o}/p.jpg"])(v),
       2, r"^hdrcl: error: --exposure: .* out of range \(at most 64 either way\)", ["p.jpg"], None)
      for v in ("2000", "1e308", "-65")],
    ("sets-negative", lambda x: ["batch", x["shoot"] + "/manifest.json", "-o", "{o}/batch", "--sets=-1"], 2,
     r"--sets: '-1' reads as a negative index", ["batch"], None),
    ("response-16-on-8", lambda x: _merge8(x, "--response", x["r16"], "-o", "{o}/a.exr"), 3,
     r"resp16.json: a response for 16-bit frames, but .*f0.png is 8-bit", ["a.exr"], None),
    ("calibrate-to-exr", lambda x: ["calibrate", *x["f8"], "--times-file", x["t8"], "-o", "{o}/r.exr"], 2,
     r"r.exr: a response curve is written as .json, .rsp, not '.exr'", ["r.exr"], None),
    ("report-json-missing-folder", lambda x: ["batch", x["shoot"], "-o", "{o}/batch", "--report-json",
                                              "{o}/nope/r.json"], 2,
     r"nope/r.json: the output folder .*nope does not exist", ["batch", "nope"], None),
    # messages that leaked internals or named the wrong thing
    ("manifest-is-jpeg", lambda x: ["batch", x["jpeg"], "-o", "{o}/batch"], 3,
     r"PANO_0001.jpg: not a manifest file \(it is a JPEG image\)", ["batch"], None),
    ("scan-manifest-is-jpeg", lambda x: ["scan", x["jpeg"]], 3, r"not a manifest file \(it is a JPEG image\)", [],
     None),
    ("expose-time-wording", lambda x: ["expose", x["rad"], "--response", x["r8"], "--time", "abc", "-o",
                                       "{o}/p.jpg"], 2, r"^hdrcl: error: --time: 'abc' is not", ["p.jpg"], None),
    ("response-bom", lambda x: _merge8(x, "--response", str(x["dir"] / "bom.json"), "-o", "{o}/a.exr"), 0, None, [],
     None),
    # a FIFO or a device where a file is read: refused at once (a read would block for ever)
    ("fifo-times-file", lambda x: ["merge", *x["f8"], "--times-file", x["fifo"], "-o", "{o}/a.exr"], 3,
     r"fifo: not a regular file \(a FIFO\)", ["a.exr"], None),
    ("fifo-response", lambda x: _merge8(x, "--response", x["fifo"], "-o", "{o}/a.exr"), 3,
     r"fifo: not a regular file \(a FIFO\)", ["a.exr"], None),
    ("fifo-image", lambda x: ["merge", x["f8"][0], x["fifo"], "--times", "1/60,1/15", "-o", "{o}/a.exr"], 3,
     r"fifo: not a regular file \(a FIFO\)", ["a.exr"], None),
    ("device-image", lambda x: ["merge", x["f8"][0], "/dev/zero", "--times", "1/60,1/15", "-o", "{o}/a.exr"], 3,
     r"^hdrcl: error: /dev/zero: not a regular file \(a device\)$", ["a.exr"], None),
    ("fifo-scan", lambda x: ["scan", x["fifo"]], 3, r"fifo: not a regular file \(a FIFO\)", [], None),
    ("fifo-batch-manifest", lambda x: ["batch", x["fifo"], "-o", "{o}/batch"], 3,
     r"fifo: not a regular file \(a FIFO\)", ["batch"], None),
    ("fifo-batch-times-file", lambda x: ["batch", x["shoot"], "--times-file", x["fifo"], "-o", "{o}/batch"], 3,
     r"fifo: not a regular file \(a FIFO\)", ["batch"], None),
    ("fifo-scan-times-file", lambda x: ["scan", x["shoot"], "--times-file", x["fifo"]], 3,
     r"fifo: not a regular file \(a FIFO\)", [], None),
]


class _Hung(Exception):
    """A command still running after :data:`HANG_SECONDS` (a read blocked on a FIFO)."""


#: A case that takes longer than this hangs: it fails instead of blocking the test run.
HANG_SECONDS = 60


def _invoke(args, monkeypatch, fx, condition):
    import signal

    def hung(signum, frame):
        raise _Hung(f"still running after {HANG_SECONDS} s")

    if condition:
        CONDITIONS[condition](monkeypatch, fx)
    old = signal.signal(signal.SIGALRM, hung)
    signal.alarm(HANG_SECONDS)
    try:
        return CliRunner().invoke(main, args)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
        monkeypatch.undo()


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_error_contract(case, fx, tmp_path, monkeypatch, capfd):
    _id, argv, code, pattern, outputs, condition = case
    args = [a.replace("{o}", str(tmp_path)) for a in argv(fx)]
    before = {p.name: p.stat().st_mtime_ns for p in fx["dir"].iterdir() if p.is_file()}
    res = _invoke(args, monkeypatch, fx, condition)
    stray = capfd.readouterr().err  # what C libraries wrote on file descriptor 2
    err = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.exit_code == code, (res.exit_code, res.stderr, res.stdout)
    assert stray == "", f"stray stderr output: {stray!r}"
    if code == 0:
        assert not any(ln.startswith("hdrcl: error") for ln in err), res.stderr
        return
    assert len(err) == 1, res.stderr
    assert LINE.match(err[0]) and "Traceback" not in res.output and "Usage:" not in res.output, err[0]
    assert "internal error" not in err[0]
    assert re.search(pattern, err[0]), err[0]
    for name in outputs:
        assert not (tmp_path / name).exists(), f"{name} was written although the exit code is {code}"
    assert not [p for p in tmp_path.rglob(".*tmp*")], "temporary file left behind"
    after = {p.name: p.stat().st_mtime_ns for p in fx["dir"].iterdir() if p.is_file()}
    assert after == before, "an input file was changed"


def test_flat_curve_warning_reads_sensibly(fx, tmp_path):
    """Two copies of one frame make a curve with no rising step: no 'inf code levels'."""
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    shutil.copy(fx["f8"][1], a)
    shutil.copy(fx["f8"][1], b)
    res = CliRunner().invoke(main, ["merge", str(a), str(b), "--times", "1,2", "-o", str(tmp_path / "a.exr")])
    assert "not monotonic" in res.stderr or "does not rise" in res.stderr, (res.exit_code, res.stderr)
    assert "inf code levels" not in res.stderr and "nan" not in res.stderr, res.stderr
    assert "does not rise between codes 10 and 245" in res.stderr, res.stderr


def test_output_equal_to_an_input_is_refused_before_it_is_destroyed(fx, tmp_path):
    """The audit's data loss: ``-o`` naming an input TIFF replaced the photograph."""
    from hdrcl.io.ldr import write_ldr

    paths = []
    for k in range(3):
        p = tmp_path / f"in{k}.tif"
        write_ldr(str(p), np.full((8, 8, 3), 40 * (k + 1), np.uint8))
        paths.append(str(p))
    data = Path(paths[2]).read_bytes()
    res = CliRunner().invoke(main, ["merge", *paths, "--times", "1/60,1/15,1/4", "-o", paths[2]])
    assert res.exit_code == 2 and res.stderr.count("\n") == 1
    assert "in2.tif: is also an input; refusing to overwrite it" in res.stderr
    assert Path(paths[2]).read_bytes() == data


def test_files_are_written_with_the_umask(fx, tmp_path):
    """``scan -o`` and ``calibrate -o`` wrote 0600 (mkstemp); now 0666 less the umask."""
    old = os.umask(0o022)
    try:
        r1 = CliRunner().invoke(main, ["scan", fx["shoot"], "-o", str(tmp_path / "m.json")])
        r2 = CliRunner().invoke(main, ["calibrate", *fx["f8"], "--times-file", fx["t8"], "-o",
                                       str(tmp_path / "r.json")])
        os.umask(0o027)
        r3 = CliRunner().invoke(main, ["scan", fx["shoot"], "-o", str(tmp_path / "m2.json")])
    finally:
        os.umask(old)
    assert r1.exit_code == r2.exit_code == r3.exit_code == 0, (r1.output, r2.output, r3.output)
    assert (tmp_path / "m.json").stat().st_mode & 0o777 == 0o644
    assert (tmp_path / "r.json").stat().st_mode & 0o777 == 0o644
    assert (tmp_path / "m2.json").stat().st_mode & 0o777 == 0o640


def test_atomic_output_names_the_target_not_the_temporary_file(tmp_path):
    """A writer's error about its hidden temporary file is reported for the real name."""
    from hdrcl.errors import ProcessingError
    from hdrcl.io.atomic import atomic_output

    target = tmp_path / "out.pfm"
    with pytest.raises(ProcessingError) as err:
        with atomic_output(target) as tmp:
            raise ProcessingError(f"{tmp}: cannot write (Could not open file)")
    assert str(err.value) == f"{target}: cannot write (Could not open file)"
    with pytest.raises(ProcessingError, match=r"out.pfm: cannot write \(No space left on device\)"):
        with atomic_output(target) as tmp:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), tmp)
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------ -q, -v, devices


def test_quiet_and_verbose_after_the_command(fx, tmp_path):
    for args in (["-q", *_merge8(fx, "-o", str(tmp_path / "a.exr"))],
                 [*_merge8(fx, "-q", "-o", str(tmp_path / "b.exr"))],
                 [*_merge8(fx, "-o", str(tmp_path / "c.exr"), "--quiet")]):
        res = CliRunner().invoke(main, args)
        assert res.exit_code == 0, res.output
        assert res.stdout == "" and res.stderr == "", res.output
    res = CliRunner().invoke(main, [*_merge8(fx, "-v", "-o", str(tmp_path / "d.exr"))])
    assert res.exit_code == 0 and "wrote" in res.stdout
    assert any(ln.startswith("hdrcl: info:") for ln in res.stderr.splitlines())


def test_quiet_batch_prints_no_summary(fx, tmp_path):
    res = CliRunner().invoke(main, ["batch", fx["shoot"], "-o", str(tmp_path / "out"), "-q", "--no-preview"])
    assert res.exit_code == 0, res.output
    assert res.stdout == "" and res.stderr == ""


def test_debug_after_the_command_shows_the_traceback(fx, tmp_path):
    res = CliRunner().invoke(main, ["merge", fx["f8"][0], "--times", "1", "-o", str(tmp_path / "x.exr"), "--debug"])
    assert res.exit_code != 0 and res.exception is not None and not isinstance(res.exception, SystemExit)


@pytest.mark.parametrize("env, code", [({"PYOPENCL_CTX": "97:97"}, 1), ({"HDRCL_OPENCL": "0"}, 0)])
def test_devices_and_devices_json_share_the_exit_code(env, code, monkeypatch):
    """No usable device: both exit 1 (the JSON still says why); OpenCL off: both 0."""
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    codes = []
    for args in (["devices"], ["devices", "--json"]):
        res = CliRunner().invoke(main, args)
        codes.append(res.exit_code)
        assert res.stderr.count("\n") <= 1
    assert codes == [code, code], codes


def test_no_stray_decoder_line_in_a_real_process(fx, tmp_path):
    """libpng prints 'libpng error: ...' on fd 2 itself; the process shows one line only."""
    out = tmp_path / "a.exr"
    proc = subprocess.run([sys.executable, "-m", "hdrcl", "merge", fx["f8"][0], fx["trunc"], fx["f8"][2],
                           "--times", "1/60,1/15,1/4", "-o", str(out)], capture_output=True, text=True,
                          cwd=Path(__file__).resolve().parents[1], timeout=120)
    assert proc.returncode == 3
    assert proc.stderr.splitlines() == [f"hdrcl: error: {fx['trunc']}: truncated PNG data "
                                        "(Read error: hit end of file in png reader)"], proc.stderr
    assert not out.exists()


# ---------------------------------------------------------------------- the real thing


def _mount(*args) -> bool:
    if os.geteuid() != 0 or not shutil.which("mount"):
        return False
    return subprocess.run(["mount", *args], capture_output=True).returncode == 0


def test_real_read_only_and_full_disk(fx, tmp_path):
    """The audit's conditions on real mounts (root only): a read-only bind mount and a
    16 KiB tmpfs that is full."""
    ro, tiny = tmp_path / "ro", tmp_path / "tiny"
    ro.mkdir()
    tiny.mkdir()
    if not (_mount("--bind", "-o", "ro", str(ro), str(ro)) or _mount("-o", "bind,ro", str(ro), str(ro))):
        pytest.skip("cannot mount here (not root, or no mount permission); simulated in test_error_contract")
    try:
        assert _mount("-t", "tmpfs", "-o", "size=16k", "tmpfs", str(tiny))
        try:
            subprocess.run(["dd", "if=/dev/zero", f"of={tiny}/fill", "bs=1k", "count=64"], capture_output=True)
            for target, code in ((ro / "r.json", 2), (tiny / "r.json", 1)):
                out = tmp_path / f"a{code}.exr"
                res = CliRunner().invoke(main, _merge8(fx, "--save-response", str(target), "-o", str(out)))
                assert res.exit_code == code, res.output
                assert len(res.stderr.splitlines()) == 1 and "internal error" not in res.stderr
                assert not out.exists() and not target.exists()
            res = CliRunner().invoke(main, ["batch", fx["shoot"], "-o", str(ro)])
            assert res.exit_code == 2 and len(res.stderr.splitlines()) == 1
        finally:
            subprocess.run(["umount", str(tiny)], capture_output=True)
    finally:
        subprocess.run(["umount", str(ro)], capture_output=True)


# ------------------------------------------------------------------------- Python API


@pytest.fixture()
def library_logging():
    """The library's logging set-up (the CLI tests replace it with their stderr handler)."""
    import logging

    from hdrcl.errors import install_warnings_bridge

    log = logging.getLogger("hdrcl")
    saved = (log.handlers[:], log.level, log.propagate)
    log.handlers[:] = []
    log.setLevel(logging.NOTSET)
    log.propagate = True
    install_warnings_bridge()
    yield log
    log.handlers[:], log.level, log.propagate = saved


def test_api_takes_times_as_the_cli_does(fx):
    import hdrcl

    ref = hdrcl.load_bracket(fx["f8"], list(TIMES)).times
    for times in (["1/60", "1/15", "1/4"], "1/60,1/15,1/4", np.array(TIMES), ("1/60", 1 / 15, "0.25")):
        np.testing.assert_allclose(hdrcl.load_bracket(fx["f8"], times).times, ref, rtol=1e-12)


@pytest.mark.parametrize("call, message", [
    (lambda h, fx: h.load_bracket(fx["f8"], [1 / 60, 1 / 15]), r"^times: 2 exposure time\(s\) given for 3 files$"),
    (lambda h, fx: h.load_bracket(fx["f8"], ["1/60", "x", "1"]), r"^times: 'x' is not a positive exposure time$"),
    (lambda h, fx: h.load_bracket(fx["f8"], "1/60,,1"), r"^times: '' is not"),
    (lambda h, fx: h.load_bracket(fx["f8"], list(TIMES), ignore_color="1,2"), r"^ignore_color: expected R,G,B"),
    (lambda h, fx: h.merge(fx["f8"], list(TIMES), crop=True), r"^crop needs align$"),
    (lambda h, fx: h.merge_files(fx["f8"], fx["dir"] / "never.exr", times=list(TIMES), crop=True),
     r"^crop needs align$"),
    (lambda h, fx: h.expose(np.full((4, 4, 3), np.nan, np.float32), fx["r8"], 1 / 30),
     r"^radiance: 48 NaN or infinite value\(s\)"),
    (lambda h, fx: h.expose(np.ones((4, 4, 3), np.float32), fx["r8"], "soon"), r"^time: 'soon' is not"),
    (lambda h, fx: h.tonemap(np.ones((4, 4, 3), np.float32), exposure=2000), r"^exposure: 2000 stops is out of"),
    (lambda h, fx: h.tonemap(np.ones((4, 4, 3), np.float32), exposure=float("nan")), r"^exposure: nan is not a"),
    (lambda h, fx: h.tonemap_file(fx["rad"], fx["dir"] / "never.jpg", exposure=-1e308), r"^exposure: -1e\+?308"),
])
def test_api_errors_name_parameters(fx, call, message):
    import hdrcl

    with pytest.raises(hdrcl.HdrclError) as err:
        call(hdrcl, fx)
    assert re.search(message, str(err.value)), str(err.value)
    assert "--" not in str(err.value)


def test_api_warns_through_the_warnings_module(fx, tmp_path, library_logging, caplog):
    import logging

    import hdrcl

    t = tmp_path / "times.txt"  # exposure and 1/shutter columns disagree: a warning, not an error
    t.write_text("".join(f"f{k}.png {v!r} {3.0 / v!r} 8 0 0\n" for k, v in enumerate(TIMES)))
    with pytest.warns(hdrcl.HdrclWarning, match="1/shutter_speed columns disagree"):
        with caplog.at_level(logging.WARNING, logger="hdrcl"):
            hdrcl.load_bracket(fx["f8"], times_file=t)
    assert any("columns disagree" in r.getMessage() for r in caplog.records)  # and logged


def test_api_warnings_can_be_errors(fx, tmp_path, library_logging):
    import warnings

    import hdrcl

    t = tmp_path / "times.txt"
    t.write_text("".join(f"f{k}.png {v!r} {3.0 / v!r} 8 0 0\n" for k, v in enumerate(TIMES)))
    with warnings.catch_warnings():
        warnings.simplefilter("error", hdrcl.HdrclWarning)
        with pytest.raises(hdrcl.HdrclWarning):
            hdrcl.load_bracket(fx["f8"], times_file=t)


def test_dir_lists_the_public_api_and_import_stays_cheap():
    out = subprocess.run([sys.executable, "-c", "import sys, hdrcl; names = dir(hdrcl); "
                          "print(sorted(m for m in ('numpy', 'OpenImageIO', 'pyopencl', 'scipy', 'click') "
                          "if m in sys.modules)); print(names)"],
                         capture_output=True, text=True, cwd=Path(__file__).resolve().parents[1], check=True)
    loaded, names = out.stdout.splitlines()
    assert loaded == "[]"
    for name in ("calibrate", "merge", "expose", "merge_files", "expose_file", "load_bracket", "Response",
                 "HdrclError", "HdrclWarning", "UsageError", "InputError", "__version__"):
        assert f"'{name}'" in names


def test_merge_has_the_options_of_merge_files(fx, tmp_path, cl_device):
    """``hdrcl.merge`` aligns, deghosts and white-balances like ``merge_files``."""
    import hdrcl

    opts = dict(times=list(TIMES), response=fx["r8"], neutral="4,4,8,8")
    arr = hdrcl.merge(fx["f8"], **opts)
    res = hdrcl.merge_files(fx["f8"], tmp_path / "a.exr", keep_radiance=True, **opts)
    np.testing.assert_allclose(arr, res.radiance, rtol=1e-5, atol=1e-7)
    patch = arr[4:12, 4:12].reshape(-1, 3).mean(axis=0)
    assert np.ptp(patch) < 1e-3 * patch.mean()
    aligned = hdrcl.merge(fx["f8"], list(TIMES), fx["r8"], align=True, crop=True, deghost=True)
    ref = hdrcl.merge_files(fx["f8"], tmp_path / "b.exr", times=list(TIMES), response=fx["r8"], align=True,
                            crop=True, deghost=True, keep_radiance=True)
    assert aligned.shape == ref.radiance.shape
    np.testing.assert_allclose(aligned, ref.radiance, rtol=1e-5, atol=1e-7)


# ------------------------------------------------------------------------------ signals


@pytest.fixture(scope="module")
def big_bracket(tmp_path_factory):
    """Three 2400x3600 frames (a small synthetic bracket tiled): a merge takes seconds."""
    from hdrcl.io.ldr import write_ldr

    d = tmp_path_factory.mktemp("big")
    rad = s.radiance_field(200, 300, decades=3.0, seed=3)
    paths = []
    for k, frame in enumerate(s.bracket(rad, TIMES, s.Camera(a=1.1, bits=8), noise=0.3, seed=4)):
        paths.append(str(d / f"big{k}.tif"))
        write_ldr(paths[-1], np.tile(frame, (12, 12, 1)))
    return paths


@pytest.mark.parametrize("command", ["merge", "tonemap"])
def test_sigterm_removes_the_temporary_file(big_bracket, tmp_path, command):
    """SIGTERM while the output is being written: exit 143, one line, no temporary file."""
    import signal
    import time

    out = tmp_path / "out"
    out.mkdir()
    if command == "merge":
        args = ["merge", *big_bracket, "--times", "1/60,1/15,1/4", "-o", str(out / "m.exr")]
    else:
        rad = tmp_path / "r.exr"
        done = subprocess.run([sys.executable, "-m", "hdrcl", "merge", *big_bracket, "--times", "1/60,1/15,1/4",
                               "-o", str(rad), "-q"], cwd=Path(__file__).resolve().parents[1], timeout=300)
        assert done.returncode == 0
        args = ["tonemap", str(rad), "--operator", "reinhard-local", "-o", str(out / "m.tif"), "--bits", "16"]
    proc = subprocess.Popen([sys.executable, "-m", "hdrcl", *args], cwd=Path(__file__).resolve().parents[1],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not list(out.glob(".*tmp*")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert proc.poll() is None, "finished before its temporary file could be seen"
        assert list(out.glob(".*tmp*")), "no temporary file appeared"
        proc.send_signal(signal.SIGTERM)
        _stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 143, (proc.returncode, stderr)
    assert stderr.splitlines() == ["hdrcl: terminated"], stderr
    assert list(out.iterdir()) == [], "output or temporary file left behind"


def test_import_does_not_load_logging_and_the_bridge_comes_with_the_api(fx, tmp_path):
    """``import hdrcl`` stays ~1 ms (no logging); the warnings bridge is installed on first
    use of the API, and its warnings still arrive as HdrclWarning."""
    t = tmp_path / "times.txt"
    t.write_text("".join(f"f{k}.png {v!r} {3.0 / v!r} 8 0 0\n" for k, v in enumerate(TIMES)))
    code = ("import sys, warnings, hdrcl\n"
            "print('logging' in sys.modules)\n"
            "with warnings.catch_warnings(record=True) as w:\n"
            "    warnings.simplefilter('always')\n"
            f"    hdrcl.load_bracket({fx['f8']!r}, times_file={str(t)!r})\n"
            "print([str(x.message) for x in w if issubclass(x.category, hdrcl.HdrclWarning)])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=Path(__file__).resolve().parents[1], timeout=120)
    assert out.returncode == 0, out.stderr
    loaded, warned = out.stdout.splitlines()
    assert loaded == "False", "import hdrcl imported logging"
    assert "columns disagree" in warned, (warned, out.stderr)
    assert out.stderr == "", out.stderr  # no bare last-resort lines
