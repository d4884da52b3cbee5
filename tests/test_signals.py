"""Issue 34: SIGTERM at any moment of ``hdrcl merge`` and ``hdrcl batch`` keeps the
contract (README "Errors and exit codes"): exit 143 with exactly one ``hdrcl: terminated``
line, or, when the work is committed, the command's own exit code; never a traceback,
never a nonzero code with nothing said.

Each point is reached by state, not by time: a driver named ``hdrcl`` (so the process is
the command, as the console script is) patches the call it stops at and sends the
SIGTERM to itself there; the loop waits for the output file to appear.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (REPO, os.environ.get("PYTHONPATH")) if p))

pytestmark = pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="POSIX signals")

# Stops the command at one point (SIGHOOK) by sending SIGTERM to itself there.
DRIVER = r'''
import os, signal, sys, threading

HOOK = os.environ["SIGHOOK"]


def term():
    os.kill(os.getpid(), signal.SIGTERM)


class WhileImporting:  # SIGTERM while click loads (before the command's handler is up)
    def find_spec(self, name, path=None, target=None):
        if name == "click" and HOOK == "click-import":
            term()
        return None


sys.meta_path.insert(0, WhileImporting())
if HOOK in ("after-rename", "twice"):
    real_replace = os.replace

    def replace(a, b, *args, **kw):
        real_replace(a, b, *args, **kw)
        if str(b).endswith((".exr", ".json")):
            term()
    os.replace = replace
if HOOK in ("first-line", "twice"):
    import click
    real_echo = click.echo

    def echo(*args, **kw):
        term()
        return real_echo(*args, **kw)
    click.echo = echo
if HOOK == "thread-join-at-exit":  # where the non-daemon threads (warm-up, prefetch) are joined
    real_shutdown = threading._shutdown

    def shutdown():
        term()
        return real_shutdown()
    threading._shutdown = shutdown
if HOOK == "atexit":
    import atexit
    atexit.register(term)
sys.argv = ["hdrcl", *sys.argv[1:]]
from hdrcl.cli import main
main()
'''

HOOKS = ["click-import", "after-rename", "first-line", "twice", "thread-join-at-exit", "atexit"]


def check_contract(rc: int, stderr: str, what: str) -> None:
    lines = stderr.splitlines()
    assert "Traceback" not in stderr, (what, stderr)
    assert rc in (0, 143), (what, rc, stderr)
    if rc == 143:
        said = [ln for ln in lines if ln.startswith("hdrcl: terminated")]
        assert len(said) == 1, (what, stderr)
        assert lines[-1].startswith("hdrcl: terminated"), (what, stderr)


@pytest.fixture(scope="module")
def driver(tmp_path_factory):
    path = tmp_path_factory.mktemp("driver") / "hdrcl"  # the console script's name
    path.write_text(DRIVER)
    return str(path)


@pytest.fixture(scope="module")
def bracket(tmp_path_factory, write_frames):
    from hdrcl.core import synthetic as s

    rad = s.radiance_field(61, 87, decades=3.0, seed=3)
    frames = s.bracket(rad, np.array([1, 4, 16.0]), s.Camera(a=1.1), noise=0.3, seed=4)
    return write_frames(tmp_path_factory.mktemp("bracket"), frames)


@pytest.fixture(scope="module")
def shoot(tmp_path_factory):
    folder = tmp_path_factory.mktemp("shoot") / "s"
    r = subprocess.run([sys.executable, "-m", "hdrcl", "sample-shoot", str(folder)], env=ENV, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return str(folder)


def _merge_args(bracket, out):
    return ["merge", *bracket, "--times", "1/16,1/4,1", "-o", str(out / "m.exr")]


@pytest.mark.parametrize("hook", HOOKS)
@pytest.mark.parametrize("command", ["merge", "batch"])
def test_sigterm_at_each_point_keeps_the_contract(driver, bracket, shoot, tmp_path, command, hook):
    out = tmp_path / "out"
    out.mkdir()
    args = _merge_args(bracket, out) if command == "merge" else ["batch", shoot, "-o", str(out), "--no-preview"]
    r = subprocess.run([sys.executable, driver, *args], env=dict(ENV, SIGHOOK=hook), capture_output=True,
                       text=True, timeout=300)
    check_contract(r.returncode, r.stderr, f"{command} {hook}")
    if hook == "click-import":  # nothing ran yet: said, and nothing written
        assert r.returncode == 143 and r.stderr.splitlines() == ["hdrcl: terminated"], r.stderr
        assert not list(out.iterdir())
    if r.returncode == 0 and command == "merge":
        assert (out / "m.exr").is_file()
    assert not [n for n in os.listdir(out) if ".tmp" in n or n.endswith(".claim")], os.listdir(out)


def test_importing_the_cli_leaves_sigterm_alone():
    """Only the command takes SIGTERM at import; a program importing hdrcl.cli keeps its own."""
    code = "import signal, hdrcl.cli; print(signal.getsignal(signal.SIGTERM) is signal.SIG_DFL)"
    r = subprocess.run([sys.executable, "-c", code], env=ENV, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "True", (r.stdout, r.stderr)


def _sigterm_caught(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith(("SigCgt:", "SigIgn:")) and int(line.split()[1], 16) >> (signal.SIGTERM - 1) & 1:
                    return True
    except OSError:
        return True  # gone: nothing left to wait for
    return False


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads /proc")
@pytest.mark.parametrize("command", ["merge", "batch"])
def test_sigterm_loop_from_start_to_after_the_output(bracket, shoot, tmp_path, command):
    """SIGTERM once the process has taken SIGTERM, then once its output appeared, at a few
    increasing steps after that: every run keeps the contract."""
    for k in range(8):
        out = tmp_path / f"o{k}"
        out.mkdir()
        if command == "merge":
            args, target = _merge_args(bracket, out), out / "m.exr"
        else:
            args, target = ["batch", shoot, "-o", str(out), "--no-preview"], out / "report.json"
        proc = subprocess.Popen([sys.executable, "-m", "hdrcl", *args], env=ENV, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 120
            while proc.poll() is None and not _sigterm_caught(proc.pid) and time.monotonic() < deadline:
                time.sleep(0.0005)
            if k:  # k = 0: as soon as the handler is up; then after the output appeared
                while proc.poll() is None and not target.exists() and time.monotonic() < deadline:
                    time.sleep(0.0005)
                time.sleep(0.002 * (k - 1))
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
            _, stderr = proc.communicate(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        check_contract(proc.returncode, stderr, f"{command} step {k}")
