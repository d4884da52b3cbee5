"""Shared fixtures.

OpenCL tests use the ``cl_device`` fixture: it skips only when no OpenCL device can be
used *and* ``HDRCL_REQUIRE_OPENCL`` is unset; CI sets it, so there a missing device
fails the run instead of passing silently. ``HDRCL_REQUIRE_DRIVER`` (a driver's short
name, ``intel-cpu`` or ``pocl``, or a piece of its platform name) also makes the run
fail unless the kernels run on that driver: CI runs the kernel tests once per driver.
"""
import os
from pathlib import Path

import numpy as np
import pytest

MEMORIAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "memorial"


@pytest.fixture(scope="session")
def cl_device():
    from hdrcl.cl.backend import get_processor, opencl_required

    try:
        proc = get_processor("fusion")
    except Exception as exc:  # required and broken: fail loudly
        pytest.fail(f"OpenCL required but unavailable: {exc}")
    want = (os.environ.get("HDRCL_REQUIRE_DRIVER") or "").strip()
    if proc is None:
        if opencl_required() or want:
            pytest.fail("HDRCL_REQUIRE_OPENCL/HDRCL_REQUIRE_DRIVER is set but no OpenCL device could be used: "
                        + _why_no_device())
        pytest.skip("no usable OpenCL device (set HDRCL_REQUIRE_OPENCL=1 to make this an error)")
    if want:
        from hdrcl.cl.drivers import DRIVER_ALIASES

        platform = DRIVER_ALIASES.get(want.lower(), want)
        if platform.lower() not in proc.ctx.device.platform.name.lower():
            pytest.fail(f"HDRCL_REQUIRE_DRIVER={want}, but the kernels would run on {proc.ctx.name}")
    return proc.ctx


def _why_no_device() -> str:
    """The reason OpenCL could not be used, e.g. PoCL's "unknown target CPU 'generic'"
    on a processor the PyPI PoCL (LLVM 14) does not know."""
    from hdrcl.cl.backend import opencl_enabled

    if not opencl_enabled():
        return "OpenCL is disabled (HDRCL_OPENCL=0)"
    try:
        from hdrcl.cl.context import get_context

        get_context(None)
    except Exception as exc:  # the reason is the point
        why = " ".join(str(exc).split()) or type(exc).__name__
        if "unknown target CPU" in why:
            why += (" -- the PyPI PoCL (LLVM 14) cannot compile for this processor; run the kernel tests on "
                    "Intel's CPU runtime only (CI reports the PoCL run as not done)")
        return why
    return "the device opened on a second try (a transient failure?)"


@pytest.fixture(scope="session")
def memorial():
    if not (MEMORIAL / "image_list.txt").is_file():
        pytest.skip(f"Memorial set not found at {MEMORIAL} (expected ../shared/data/memorial beside the repo)")
    return MEMORIAL


@pytest.fixture(scope="session")
def memorial_bracket(memorial):
    import hdrcl

    paths = sorted(memorial.glob("memorial*.png"))
    return hdrcl.load_bracket(paths, times_file=memorial / "image_list.txt", ignore_color=(0, 0, 255))


@pytest.fixture(scope="session")
def scene():
    """A synthetic scene with known truth: radiance, camera, times, 8-bit bracket."""
    from hdrcl.core import synthetic as s

    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
    rad = s.radiance_field(120, 160, decades=4.5, seed=1)
    times = s.stops(7, 2.0, centre=1.0 / float(np.median(rad)))
    frames = s.bracket(rad, times, cam, noise=0.5, seed=2)
    return {"camera": cam, "radiance": rad, "times": times, "frames": frames}


@pytest.fixture(scope="session")
def radiance_bin():
    """The folder of Radiance's own programs (pcomb, pvalue, getinfo, evalglare, ...) from
    the ``pyradiance`` wheel: the oracle for hdrcl's Radiance conventions. Skips with the
    reason when it is missing, unless ``HDRCL_REQUIRE_RADIANCE`` is set (CI), where that is
    a failure."""
    import os
    import shutil

    why, folder = None, None
    try:
        import pyradiance
    except Exception as exc:  # not installed, or a wheel that does not load here
        why = f"pyradiance is not importable ({exc}); pip install '.[radiance]'"
    if why is None:
        from pathlib import Path

        folder = Path(pyradiance.__file__).parent / "bin"
        if not (folder / "pcomb").exists():
            found = shutil.which("pcomb")
            folder = Path(found).parent if found else None
        if folder is None:
            why = "pyradiance is installed but its Radiance programs (pcomb) were not found"
    if why is not None:
        if os.environ.get("HDRCL_REQUIRE_RADIANCE", "") not in ("", "0"):
            pytest.fail(f"HDRCL_REQUIRE_RADIANCE is set but {why}")
        pytest.skip(f"{why}; set HDRCL_REQUIRE_RADIANCE=1 to make this an error")
    return folder


@pytest.fixture(scope="session")
def chromium_path():
    """Headless Chromium for the report's HTML checks: its path; skips with the reason
    when neither ``chromium`` nor ``chromium-browser`` is on PATH, unless
    ``HDRCL_REQUIRE_BROWSER`` is set (CI), where that is a failure."""
    import os
    import shutil

    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    if os.environ.get("HDRCL_REQUIRE_BROWSER", "") not in ("", "0"):
        pytest.fail("HDRCL_REQUIRE_BROWSER is set but neither chromium nor chromium-browser is on PATH "
                    "(Debian: apt-get install chromium)")
    pytest.skip("headless Chromium not found (Debian: apt-get install chromium); "
                "set HDRCL_REQUIRE_BROWSER=1 to make this an error")


def _write_pngs(folder, frames, names=None, prefix="f"):
    import os

    from hdrcl.io.ldr import write_ldr

    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    paths = []
    for k, f in enumerate(frames):
        paths.append(os.path.join(folder, names[k] if names else f"{prefix}{k}.png"))
        write_ldr(paths[-1], f)
    return paths


@pytest.fixture(scope="session")
def write_frames():
    """``write_frames(folder, frames, names=None, prefix="f")``: the frames as PNG files
    (``f0.png``, ``f1.png``, ... or ``names``) in ``folder`` (made if missing); their
    paths as strings, in order."""
    return _write_pngs
