"""The wheel ships the kernels; importing hdrcl stays cheap."""
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_wheel_contains_the_kernels(tmp_path):
    pytest.importorskip("hatchling")
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                        "-w", str(tmp_path), str(ROOT)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    wheel = next(tmp_path.glob("hdrcl-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    for cl in sorted(p.name for p in (ROOT / "kernels").glob("*.cl")):
        assert f"hdrcl/kernels/{cl}" in names, f"{cl} missing from {wheel.name}"
    assert "hdrcl/cl/fusion.py" in names


def test_kernel_dir_finds_sources():
    from hdrcl.cl.resources import kernel_dir

    assert (kernel_dir() / "fusion.cl").is_file() and (kernel_dir() / "exposure.cl").is_file()


def test_import_is_cheap():
    code = ("import sys, hdrcl; hdrcl.__version__; "
            "bad = [m for m in ('pyopencl', 'OpenImageIO', 'scipy', 'click') if m in sys.modules]; "
            "print(','.join(bad))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "", f"import hdrcl loaded {out}"


def test_click_floor_gives_result_stderr():
    """The tests read ``CliRunner().invoke(...).stderr`` apart from stdout: click 8.2+."""
    import re

    text = (ROOT / "pyproject.toml").read_text()
    m = re.search(r'"click>=(\d+)\.(\d+)', text)
    assert m and (int(m.group(1)), int(m.group(2))) >= (8, 2), m and m.group(0)


@pytest.mark.parametrize("given", [False, True])
def test_ci_removes_the_venv_it_created(tmp_path, given):
    """``.ci/run`` makes its venv under ``mktemp -d`` and removes it on exit (here it fails
    at once: ``python3`` is a stub); a venv given by HDRCL_CI_VENV is left alone."""
    import os
    import shutil

    bash = shutil.which("bash")
    if bash is None:
        pytest.skip("no bash")
    stub = tmp_path / "bin"
    stub.mkdir()
    (stub / "python3").write_text('#!/bin/sh\nmkdir -p "$3/bin"\nexit 7\n')  # python3 -m venv DIR
    (stub / "python3").chmod(0o755)
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {**os.environ, "PATH": f"{stub}:{os.environ['PATH']}", "TMPDIR": str(tmp)}
    if given:
        env["HDRCL_CI_VENV"] = str(tmp / "mine")
    r = subprocess.run([bash, str(ROOT / ".ci" / "run")], env=env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 7, r.stderr
    assert sorted(p.name for p in tmp.iterdir()) == (["mine"] if given else []), list(tmp.iterdir())
