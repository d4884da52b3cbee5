"""Helpers the benchmark scripts share: the checkout on the import path, a process
launcher that measures wall time, CPU seconds and the child's own peak RSS, load and
background CPU, machine facts, one OpenImageIO frame decode.

Every script under ``scripts/`` that measures processes imports this module; it imports
no other script, so the benchmarks form no import circle (``bench.py`` and
``shoot_bench.py`` both build on it; ``bench.py --shoot`` starts ``shoot_bench.py`` as a
process). The benchmarks' other parts are modules of their own that import no
benchmark: ``benchbrackets.py`` (bench.py's generated brackets), ``benchworkers.py`` (its
in-process measurements), ``benchreport.py`` (its targets and report),
``benchshoots.py`` (shoot_bench.py's generated shoots), ``benchshootreport.py`` (its
report).
"""
from __future__ import annotations

import json
import os
import platform
import re
import signal
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
MB = 1e6  # peak RSS and bandwidths are reported in decimal units (MB, GB/s)


def loadavg() -> str:
    """The 1, 5 and 15-minute load averages (``/proc/loadavg``), or ``n/a``: printed beside
    every figure of the benchmarks, since a busy neighbour on 2 cores halves a figure."""
    try:
        with open("/proc/loadavg") as f:
            return " ".join(f.read().split()[:3])
    except OSError:
        return "n/a"


def timed_child(cmd, env=None):
    """``(wall seconds, CPU seconds of the child, CompletedProcess)`` of one run of
    ``cmd``; SystemExit with its stderr's tail when it fails."""
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(map(str, cmd[:4]))} ... failed ({r.returncode}):\n{r.stderr[-2000:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), r


def ensure_importable() -> None:
    """Make ``import hdrcl`` find the checkout this script belongs to (in this process and
    in every child, workers included), so that the CLI processes (``python -m hdrcl``)
    and the in-process workers measure the same code even where another checkout is
    installed in the environment; other installs are used only without a checkout."""
    if os.environ.get("PYTHONPATH"):  # absolute, so children started in other folders see it too
        os.environ["PYTHONPATH"] = os.pathsep.join(os.path.abspath(p) if p else p
                                                   for p in os.environ["PYTHONPATH"].split(os.pathsep))
    root = ROOT
    if os.path.isdir(os.path.join(root, "hdrcl")):
        sys.path.insert(0, root)
        os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p)


# --------------------------------------------------------------------------------------
# Running processes: wall time and the child's own peak RSS
# --------------------------------------------------------------------------------------

# A small launcher between the benchmark and each measured process. Linux charges a
# child's ru_maxrss with the high-water mark of the address space it replaced at exec:
# spawned straight from this (large) benchmark process, every child would report at
# least the benchmark's own RSS. The launcher is small, so its child's figure is clean.
LAUNCHER = r"""
import json, os, subprocess, sys, time
spec = json.loads(sys.argv[1])
with open(spec["stdout"], "wb") as out, open(spec["stderr"], "wb") as err:
    t0 = time.perf_counter()
    p = subprocess.Popen(spec["cmd"], stdout=out, stderr=err, cwd=spec.get("cwd"))
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
p.returncode = os.waitstatus_to_exitcode(status)
me = __import__("resource").getrusage(__import__("resource").RUSAGE_SELF)
print(json.dumps({"wall_s": wall, "maxrss_kib": ru.ru_maxrss, "user_s": ru.ru_utime,
                  "sys_s": ru.ru_stime, "rc": p.returncode, "launcher_cpu_s": me.ru_utime + me.ru_stime}))
"""


def cpu_seconds():
    """Busy and stolen CPU seconds of the whole machine so far (from /proc/stat)."""
    try:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    hz = os.sysconf("SC_CLK_TCK")
    user, nice, system, _idle, _iowait, irq, softirq, steal = v + [0] * (8 - len(v))
    return (user + nice + system + irq + softirq) / hz, steal / hz


#: --wait-idle: seconds to wait, before each measured run, for other processes to calm down.
WAIT_IDLE = {"max_s": 0.0, "waited_s": 0.0}


def wait_idle() -> None:
    """Wait (at most WAIT_IDLE["max_s"]) until other processes use < 15 % of the CPU."""
    deadline = time.perf_counter() + WAIT_IDLE["max_s"]
    t_start = time.perf_counter()
    while time.perf_counter() < deadline:
        c0, t0 = cpu_seconds(), time.perf_counter()
        time.sleep(0.5)
        c1, t1 = cpu_seconds(), time.perf_counter()
        if c0 is None or (c1[0] - c0[0]) / ((t1 - t0) * (os.cpu_count() or 1)) < 0.15:
            break
    WAIT_IDLE["waited_s"] += time.perf_counter() - t_start


def run_measured(cmd, logdir: str, tag: str, timeout: float = 3600, cwd=None) -> dict:
    """Run ``cmd`` once; wall seconds, peak RSS (MB) of that process, exit code, output."""
    if WAIT_IDLE["max_s"] > 0:
        wait_idle()
    os.makedirs(logdir, exist_ok=True)
    out_p = os.path.join(logdir, f"{tag}.out")
    err_p = os.path.join(logdir, f"{tag}.err")
    spec = json.dumps({"cmd": [str(c) for c in cmd], "stdout": out_p, "stderr": err_p, "cwd": cwd})
    cpu0, t0 = cpu_seconds(), time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", LAUNCHER, spec], stdout=subprocess.PIPE,
                            start_new_session=True)
    try:
        raw, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)  # the launcher's own session: it and the child
        proc.communicate()
        return {"rc": None, "error": f"timed out after {timeout:.0f} s", "cmd": short_cmd(cmd)}
    try:
        res = json.loads(raw.decode().strip().splitlines()[-1])
    except (ValueError, IndexError):
        return {"rc": None, "error": f"launcher failed (rc {proc.returncode})", "cmd": short_cmd(cmd)}
    with open(out_p, errors="replace") as f:
        res["stdout"] = f.read()
    with open(err_p, errors="replace") as f:
        res["stderr"] = f.read()
    res["rss_mb"] = res.pop("maxrss_kib") * 1024 / MB
    res["cmd"] = short_cmd(cmd)
    cpu1, elapsed = cpu_seconds(), time.perf_counter() - t0
    if cpu0 and cpu1:
        # CPU that other processes (other users, other jobs) used meanwhile, as a
        # fraction of the machine: a measurement disturbed by them is flagged.
        ours = res["user_s"] + res["sys_s"] + res.get("launcher_cpu_s", 0.0)
        res["background_cpu"] = max(0.0, cpu1[0] - cpu0[0] - ours) / (elapsed * (os.cpu_count() or 1))
        res["steal_cpu"] = (cpu1[1] - cpu0[1]) / (elapsed * (os.cpu_count() or 1))
    if res["rc"] != 0:
        tail = (res["stderr"].strip().splitlines() or ["(no output)"])[-1]
        res["error"] = f"exit {res['rc']}: {tail}"
    return res


def short_cmd(cmd) -> str:
    """A command line for the report, with long file lists shortened."""
    parts = [os.path.basename(str(c)) if os.sep in str(c) else str(c) for c in cmd]
    if parts and parts[0].startswith("python"):
        parts[0] = "python"
    return " ".join(parts)


def hdrcl_cmd(*args) -> list:
    """The CLI as ``python -m hdrcl`` (the same code as the installed ``hdrcl`` script)."""
    return [sys.executable, "-m", "hdrcl", *[str(a) for a in args]]



def read_frame(path: str) -> np.ndarray:
    """Decode one frame with OpenImageIO in its native integer type (as hdrcl does)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise RuntimeError(f"{path}: {oiio.geterror()}")
    try:
        spec = inp.spec()
        fmt = "uint8" if spec.format.basetype == oiio.UINT8 else "uint16"
        px = inp.read_image(0, 0, 0, spec.nchannels, fmt)
    finally:
        inp.close()
    if px is None:
        raise RuntimeError(f"{path}: decode failed")
    return np.asarray(px)


def machine_facts(logdir: str) -> dict:
    facts = {"python": platform.python_version(), "platform": platform.platform(),
             "cpu_count": os.cpu_count(), "numpy": np.__version__}
    try:
        with open("/proc/cpuinfo") as f:
            m = re.search(r"^model name\s*:\s*(.+)$", f.read(), re.M)
        facts["cpu"] = m.group(1).strip() if m else platform.processor()
    except OSError:
        facts["cpu"] = platform.processor()
    try:
        with open("/proc/meminfo") as f:
            m = re.search(r"^MemTotal:\s*(\d+) kB", f.read(), re.M)
        facts["memory_gb"] = round(int(m.group(1)) * 1024 / 1e9, 1)
    except (OSError, AttributeError):
        pass
    res = run_measured(hdrcl_cmd("devices", "--json"), logdir, "devices", timeout=300)
    if res.get("rc") == 0:
        d = json.loads(res["stdout"])
        facts["opencl_device"] = d.get("selected")
        facts["opencl_devices"] = [f"{r['id']} {r['platform']} / {r['device']}" for r in d.get("devices", [])]
        facts["opencl_problem"] = d.get("problem")
    else:
        facts["opencl_device"] = None
        facts["opencl_problem"] = res.get("error")
    try:
        import OpenImageIO as oiio

        facts["openimageio"] = oiio.__version__
    except ImportError:
        pass
    try:
        import hdrcl

        facts["hdrcl"] = getattr(hdrcl, "__version__", None)
        top = os.path.dirname(os.path.dirname(os.path.abspath(hdrcl.__file__)))
        rev = subprocess.run(["git", "-C", top, "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
        if rev.returncode == 0:
            dirty = subprocess.run(["git", "-C", top, "status", "--porcelain", "--untracked-files=no"],
                                   capture_output=True, text=True).stdout.strip()
            facts["hdrcl_git"] = rev.stdout.strip() + ("+uncommitted changes" if dirty else "")
    except Exception:
        pass
    for var in ("PYOPENCL_CTX", "HDRCL_OPENCL", "OMP_NUM_THREADS"):
        if os.environ.get(var):
            facts[var] = os.environ[var]
    return facts


def have_opencv() -> str:
    r = subprocess.run([sys.executable, "-c", "import cv2; print(cv2.__version__)"], capture_output=True, text=True)
    return r.stdout.strip() if r.returncode == 0 else ""
