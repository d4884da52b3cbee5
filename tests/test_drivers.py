"""OpenCL drivers from PyPI: the private ICD list naming Intel's CPU runtime, and the
selection passing over a driver that cannot build the kernels (AMD Zen 5 emulated)."""
import json
import os
import subprocess
import sys

import pytest

from hdrcl.cl import drivers


@pytest.fixture()
def fresh_state(monkeypatch, tmp_path):
    """A process state as before the first OpenCL call, with a fake environment prefix."""
    monkeypatch.setattr(drivers, "_state", {})
    for var in ("OCL_ICD_VENDORS", "OCL_ICD_FILENAMES", "HDRCL_ICD_VENDORS", "HDRCL_ICD_SETUP"):
        monkeypatch.setenv(var, "")  # recorded, so what the test sets is undone
        monkeypatch.delenv(var)
    prefix = tmp_path / "prefix"
    (prefix / "lib").mkdir(parents=True)
    system = tmp_path / "system-vendors"
    system.mkdir()
    monkeypatch.setattr(drivers, "_prefixes", lambda: [str(prefix)])
    monkeypatch.setenv("OPENCL_VENDOR_PATH", str(system))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    return prefix, system


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the ICD list is set up on Linux only")
def test_icd_list_names_the_real_library_and_keeps_the_system_drivers(fresh_state):
    prefix, system = fresh_state
    lib = prefix / "lib" / "libintelocl.so"
    lib.write_bytes(b"")
    for n in ("libimf.so", "libsvml.so", "libirng.so", "libintlc.so.5", "libtbb.so.12"):
        (prefix / "lib" / n).write_bytes(b"")
    (system / "nvidia.icd").write_text("libnvidia-opencl.so.1\n")
    st = drivers.prepare_icd_environment()
    assert st["set_by"] == "hdrcl" and st["note"] is None, st
    d = os.environ["OCL_ICD_VENDORS"]
    assert d == st["vendors"] and os.path.isdir(d)
    assert sorted(os.listdir(d)) == ["hdrcl-intel-cpu.icd", "nvidia.icd"]
    with open(os.path.join(d, "hdrcl-intel-cpu.icd")) as f:
        assert f.read().strip() == os.path.realpath(str(lib))
    with open(os.path.join(d, "nvidia.icd")) as f:
        assert f.read() == "libnvidia-opencl.so.1\n"
    assert drivers.prepare_icd_environment() == st  # once per process


def test_partial_intel_install_is_reported(fresh_state):
    prefix, _ = fresh_state
    (prefix / "lib" / "libintelocl.so").write_bytes(b"")
    st = drivers.prepare_icd_environment()
    if sys.platform.startswith("linux"):
        assert "libimf.so" in st["note"] and "intel-cmplr-lib-rt" in st["note"]


def test_users_own_icd_settings_stand(fresh_state, monkeypatch):
    prefix, _ = fresh_state
    (prefix / "lib" / "libintelocl.so").write_bytes(b"")
    monkeypatch.setenv("OCL_ICD_VENDORS", "/somewhere/vendors")
    st = drivers.prepare_icd_environment()
    assert st["set_by"] == "user" and os.environ["OCL_ICD_VENDORS"] == "/somewhere/vendors"


def test_nothing_to_do_without_the_intel_runtime(fresh_state):
    st = drivers.prepare_icd_environment()
    assert st["set_by"] is None and "OCL_ICD_VENDORS" not in os.environ


def test_cpu_driver_order(monkeypatch):
    monkeypatch.delenv("HDRCL_CPU_DRIVERS", raising=False)
    assert drivers.cpu_driver_order()[0] == "Intel(R) OpenCL"
    monkeypatch.setenv("HDRCL_CPU_DRIVERS", "pocl")
    assert drivers.cpu_driver_order() == ["Portable Computing Language", "Intel(R) OpenCL"]
    assert drivers.driver_rank("Portable Computing Language") == 0
    assert drivers.driver_rank("Some Vendor") == 2


def _devices_json(env_extra, drop=("PYOPENCL_CTX", "HDRCL_OPENCL")):
    env = {k: v for k, v in os.environ.items() if k not in drop}
    env.update(env_extra)
    r = subprocess.run([sys.executable, "-m", "hdrcl", "devices", "--json"], capture_output=True, text=True,
                       env=env, timeout=300)
    return r.returncode, json.loads(r.stdout), r.stderr


def _both_drivers_or_skip():
    if drivers.find_intel_cpu_runtime() is None and not os.environ.get("HDRCL_REQUIRE_TWO_DRIVERS"):
        pytest.skip("Intel's OpenCL CPU runtime is not installed here (pip install '.[cpu]')")
    rc, out, err = _devices_json({})
    platforms = {r["platform"] for r in out["devices"]}
    missing = {"Intel(R) OpenCL", "Portable Computing Language"} - platforms
    if missing:
        if os.environ.get("HDRCL_REQUIRE_OPENCL") or os.environ.get("HDRCL_REQUIRE_TWO_DRIVERS"):
            pytest.fail(f"OpenCL drivers missing: {sorted(missing)}; hdrcl devices: {out} {err[-1000:]}")
        pytest.skip(f"OpenCL drivers missing: {sorted(missing)}")
    return out


def test_pip_drivers_are_both_visible_and_intel_is_the_default():
    out = _both_drivers_or_skip()
    if any("GPU" in r["type"] for r in out["devices"]):
        pytest.skip("a GPU is the default here")
    assert out["selected"].startswith("Intel(R) OpenCL"), out
    pocl = [r for r in out["devices"] if r["platform"] == "Portable Computing Language"]
    assert all(r["status"] in ("not preferred", "failed") and r["reason"] for r in pocl), pocl


def test_zen5_emulated_pocl_is_passed_over_for_intel():
    """PyPI PoCL cannot build kernels on AMD Zen 5. Emulated: PoCL is preferred
    (HDRCL_CPU_DRIVERS=pocl) and made to fail every build (a build option it rejects);
    the selection must fall to Intel's runtime and ``hdrcl devices`` must say why."""
    _both_drivers_or_skip()
    rc, out, err = _devices_json({"HDRCL_CPU_DRIVERS": "pocl,intel-cpu",
                                  "POCL_EXTRA_BUILD_FLAGS": "-hdrcl-emulated-unknown-target-cpu",
                                  "POCL_KERNEL_CACHE": "0", "PYOPENCL_NO_CACHE": "1"})
    assert rc == 0, err[-2000:]
    assert out["selected"].startswith("Intel(R) OpenCL") and out["problem"] is None, out
    rows = {r["platform"]: r for r in out["devices"]}
    pocl = rows["Portable Computing Language"]
    assert pocl["status"] == "failed"
    assert "hdrcl-emulated-unknown-target-cpu" in pocl["reason"] or "unknown target CPU" in pocl["reason"]
    assert rows["Intel(R) OpenCL"]["status"] == "selected"
    # the plain listing says the same, and exits 0
    env = {k: v for k, v in os.environ.items() if k not in ("PYOPENCL_CTX", "HDRCL_OPENCL")}
    env.update({"HDRCL_CPU_DRIVERS": "pocl", "POCL_EXTRA_BUILD_FLAGS": "-hdrcl-emulated-unknown-target-cpu",
                "POCL_KERNEL_CACHE": "0", "PYOPENCL_NO_CACHE": "1"})
    r = subprocess.run([sys.executable, "-m", "hdrcl", "devices"], capture_output=True, text=True, env=env,
                       timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "passed over: cannot build hdrcl's kernels" in r.stdout and "selected: Intel(R) OpenCL" in r.stdout


def test_devices_exit_code_agrees_with_json():
    """No usable device: both forms exit non-zero and say why."""
    env = {"PYOPENCL_CTX": "no-such-driver"}
    rc, out, err = _devices_json(env, drop=("HDRCL_OPENCL",))
    assert rc != 0 and out["problem"] and out["selected"] is None
    env2 = {k: v for k, v in os.environ.items() if k != "HDRCL_OPENCL"}
    env2.update(env)
    r = subprocess.run([sys.executable, "-m", "hdrcl", "devices"], capture_output=True, text=True, env=env2,
                       timeout=300)
    assert r.returncode == rc and "problem:" in r.stdout

