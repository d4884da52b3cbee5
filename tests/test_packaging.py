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
