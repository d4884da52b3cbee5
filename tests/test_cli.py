"""The command line, driven with CliRunner on small files written into tmp_path."""
import json

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.core import synthetic as s


@pytest.fixture()
def bracket_files(tmp_path):
    from hdrcl.io.ldr import write_ldr

    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
    rad = s.radiance_field(37, 53, decades=4.0, seed=5)
    times = s.stops(5, 2.0, centre=1.0 / float(np.median(rad)))
    frames = s.bracket(rad, times, cam, noise=0.5, seed=6)
    paths = []
    for k, f in enumerate(frames):
        p = tmp_path / f"f{k}.png"
        write_ldr(str(p), f)
        paths.append(str(p))
    tfile = tmp_path / "times.txt"
    tfile.write_text("".join(f"f{k}.png {float(t)!r}\n" for k, t in enumerate(times)))
    return {"paths": paths, "times": times, "times_file": str(tfile), "dir": tmp_path, "radiance": rad}


def run(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r


def test_calibrate_merge_expose(bracket_files, cl_device):
    d = bracket_files["dir"]
    r = run("calibrate", *bracket_files["paths"], "--times-file", bracket_files["times_file"], "-o", d / "r.json")
    assert r.exit_code == 0, r.output
    assert json.loads((d / "r.json").read_text())["format"] == "hdrcl-response"
    r = run("merge", *bracket_files["paths"], "--times-file", bracket_files["times_file"],
            "--response", d / "r.json", "-o", d / "out.exr", "--dtype", "float")
    assert r.exit_code == 0, r.output
    assert "OpenCL" in r.output
    from hdrcl.io.radiance import read_radiance

    rad, meta = read_radiance(str(d / "out.exr"))
    assert rad.shape == (37, 53, 3) and np.all(np.isfinite(rad)) and rad.min() > 0
    assert "f0.png" in str(meta.get("sources"))
    ratio = rad / bracket_files["radiance"]
    assert np.median(np.abs(ratio / np.median(ratio, axis=(0, 1)) - 1)) < 0.03
    t = bracket_files["times"][2]
    r = run("expose", d / "out.exr", "-o", d / "v.png", "--response", d / "r.json", "--time", repr(float(t)))
    assert r.exit_code == 0, r.output
    from hdrcl.io.frames import read_image

    v = read_image(str(d / "v.png")).pixels.astype(int)
    real = read_image(bracket_files["paths"][2]).pixels.astype(int)
    inner = (real > 10) & (real < 245)
    assert np.sqrt(np.mean((v - real)[inner] ** 2)) < 2.0


@pytest.mark.parametrize("ext", ["hdr", "tif", "pfm"])
def test_merge_other_formats_calibrating_from_the_set(bracket_files, ext, cl_device):
    d = bracket_files["dir"]
    times = ",".join(repr(float(t)) for t in bracket_files["times"])
    r = run("merge", *bracket_files["paths"], "--times", times, "-o", d / f"out.{ext}", "--weight", "gaussian")
    assert r.exit_code == 0, r.output
    assert (d / f"out.{ext}").stat().st_size > 0


def _no_output(d):
    return not list(d.glob("out*")) and not list(d.glob(".*tmp*"))


def test_single_frame_is_an_input_error(bracket_files):
    d = bracket_files["dir"]
    r = run("merge", bracket_files["paths"][0], "--times", "1", "-o", d / "out.exr")
    assert r.exit_code == 3
    assert "f0.png" in r.output and "at least two" in r.output
    assert len(r.output.strip().splitlines()) == 1 and "Traceback" not in r.output
    assert _no_output(d)


def test_size_mismatch(bracket_files, tmp_path):
    from hdrcl.io.ldr import write_ldr

    odd = tmp_path / "odd.png"
    write_ldr(str(odd), np.zeros((10, 10, 3), np.uint8))
    r = run("merge", *bracket_files["paths"][:2], odd, "--times", "1,2,4", "-o", tmp_path / "out.exr")
    assert r.exit_code == 3 and "odd.png" in r.output
    assert _no_output(tmp_path)


def test_duplicate_exposures(bracket_files):
    """Equal exposures merge (issue 9); fewer than two distinct ones are refused."""
    d = bracket_files["dir"]
    r = run("merge", *bracket_files["paths"][:3], "--times", "1,2,2", "-o", d / "out.exr")
    assert r.exit_code == 0, r.output
    r = run("merge", *bracket_files["paths"][:3], "--times", "2,2,2", "-o", d / "out2.exr")
    assert r.exit_code == 3 and "same exposure" in r.output and "f0.png" in r.output


def test_missing_exposure_time(bracket_files, tmp_path):
    import shutil

    d = bracket_files["dir"]
    bare = tmp_path / "bare"  # no times.txt beside these copies
    bare.mkdir()
    copies = [shutil.copy(p, bare) for p in bracket_files["paths"][:3]]
    r = run("merge", *copies, "-o", bare / "out.exr")
    assert r.exit_code == 3 and "f0.png" in r.output and "exposure time" in r.output
    assert not (bare / "out.exr").exists()
    r = run("merge", *bracket_files["paths"][:3], "--times", "1,2", "-o", d / "out.exr")
    assert r.exit_code == 2 and "--times" in r.output
    assert _no_output(d)


def test_truncated_file(bracket_files):
    d = bracket_files["dir"]
    p = d / "f1.png"
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    r = run("merge", *bracket_files["paths"], "--times-file", bracket_files["times_file"], "-o", d / "out.exr")
    assert r.exit_code == 3 and "f1.png" in r.output
    assert _no_output(d)


def test_bad_options(bracket_files):
    d = bracket_files["dir"]
    r = run("merge", *bracket_files["paths"][:2], "--times", "1,abc", "-o", d / "out.exr")
    assert r.exit_code == 2
    r = run("merge", *bracket_files["paths"][:2], "--times", "1,2", "-o", d / "out.jpg")
    assert r.exit_code == 2 and "out.jpg" in r.output
    r = run("merge", *bracket_files["paths"][:2], "--times", "1,2", "--ignore-color", "1,2", "-o", d / "o.exr")
    assert r.exit_code == 2
    r = run("merge", *bracket_files["paths"][:2], "--times", "1,2", "-o", d / "nofolder" / "o.exr")
    assert r.exit_code == 2


def test_debug_shows_traceback(bracket_files):
    r = CliRunner().invoke(main, ["--debug", "merge", bracket_files["paths"][0], "--times", "1", "-o", "x.exr"])
    assert r.exit_code != 0 and r.exception is not None


def test_demo(tmp_path, cl_device):
    r = run("demo", tmp_path / "demo", "--size", "96x64", "--frames", "5")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "demo" / "demo.exr").is_file() and (tmp_path / "demo" / "preview.jpg").is_file()
    err = float(r.output.split("response curve error:")[1].split()[0])
    assert err < 0.05
    assert "3 set(s) merged, 0 failed" in r.output  # the shoot job ran a batch
    assert (tmp_path / "demo" / "batch" / "report" / "index.html").is_file()
    assert len(list((tmp_path / "demo" / "batch").glob("*.exr"))) == 3


def test_devices_lists_the_selected_device(cl_device):
    r = run("devices")
    assert r.exit_code == 0 and "selected:" in r.output
    r = run("devices", "--json")
    assert json.loads(r.output)["selected"]


def test_numpy_path_gives_the_same_answer(bracket_files, monkeypatch, cl_device):
    import hdrcl

    kw = dict(times_file=bracket_files["times_file"])
    a = hdrcl.merge(bracket_files["paths"], **kw)
    monkeypatch.setenv("HDRCL_OPENCL", "0")
    monkeypatch.delenv("HDRCL_REQUIRE_OPENCL", raising=False)
    b = hdrcl.merge(bracket_files["paths"], **kw)
    np.testing.assert_allclose(a, b, rtol=2e-5)
