"""The README's examples, executed: a wrong example fails the tests.

Every ```bash block of README.md is checked for shell syntax. Those preceded by an
HTML comment ``<!-- runnable -->`` are run as written, with ``bash -e``, in a temporary
folder beside a link to ``../shared`` (so the Memorial set is ``../shared/data/memorial``
as the README says), with this interpreter's ``hdrcl`` first on ``PATH``. Heavy examples
(installing, the whole test suite) carry no marker. ``<!-- runnable: no-warnings -->``
also requires an empty stderr, for the blocks whose text promises no warning.
"""
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
BLOCK = re.compile(r"(?:<!--\s*runnable(?P<opts>[^>]*?)\s*-->\s*\n)?```bash\n(?P<body>.*?)```", re.S)


def blocks():
    text = (REPO / "README.md").read_text(encoding="utf-8")
    out = []
    for m in BLOCK.finditer(text):
        line = text.count("\n", 0, m.start("body"))
        opts = m.group("opts")
        out.append((line, m.group("body"), None if opts is None else opts.strip(": ").split()))
    return out


ALL = blocks()
RUNNABLE = [b for b in ALL if b[2] is not None]


def test_the_readme_has_runnable_examples():
    assert len(RUNNABLE) >= 2, "the README's examples are no longer marked <!-- runnable -->"


@pytest.mark.parametrize("block", ALL, ids=[f"line-{b[0]}" for b in ALL])
def test_every_bash_block_is_valid_shell(block):
    res = subprocess.run(["bash", "-n"], input=block[1], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr


@pytest.mark.parametrize("block", RUNNABLE, ids=[f"line-{b[0]}" for b in RUNNABLE])
def test_runnable_example(block, tmp_path):
    line, body, opts = block
    if "../shared/" in body and not (SHARED / "data").is_dir():
        pytest.skip(f"{SHARED / 'data'} not found")
    work = tmp_path / "work"
    work.mkdir()
    if SHARED.is_dir():
        (tmp_path / "shared").symlink_to(SHARED)
    exe = shutil.which("hdrcl", path=os.path.dirname(sys.executable))
    env = dict(os.environ, PATH=os.pathsep.join([os.path.dirname(sys.executable), os.environ.get("PATH", "")]),
               PYTHONPATH=os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH")) if p))
    if exe is None:  # hdrcl not installed as a command: run the package
        shim = tmp_path / "bin"
        shim.mkdir()
        (shim / "hdrcl").write_text(f'#!/bin/sh\nexec "{sys.executable}" -m hdrcl "$@"\n')
        (shim / "hdrcl").chmod(0o755)
        env["PATH"] = os.pathsep.join([str(shim), env["PATH"]])
    t0 = time.monotonic()
    res = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", body], cwd=work, env=env, capture_output=True,
                         text=True, timeout=300)
    took = time.monotonic() - t0
    assert res.returncode == 0, f"README line {line}: exit {res.returncode}\n{res.stderr[-3000:]}"
    if "no-warnings" in opts:
        assert res.stderr == "", f"README line {line} promises no warning:\n{res.stderr}"
    assert took < 60, f"README line {line} took {took:.0f} s: mark it not runnable"
