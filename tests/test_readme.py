"""The examples of the README and of the docs/ pages, executed: a wrong example fails the tests.

Every ```bash block of README.md and of docs/*.md is checked for shell syntax. Those
preceded by an HTML comment ``<!-- runnable -->`` are run as written, with ``bash -e``, in
a temporary folder beside a link to ``../shared`` (so the Memorial set is
``../shared/data/memorial`` as the pages say), with this interpreter's ``hdrcl`` first on
``PATH``. Heavy examples (installing, the whole test suite) carry no marker.
``<!-- runnable: no-warnings -->`` also requires an empty stderr, for the blocks whose
text promises no warning; ``<!-- runnable: skip-install -->`` runs the block with its
``pip install`` lines left out (the environment under test is installed already), so the
README's set-up commands stay runnable as written.
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


PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
INSTALL = re.compile(r"^\s*pip install\b.*$", re.M)


def blocks():
    """(where, body, options) of every ```bash block; options None where not runnable."""
    out = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        name = page.relative_to(REPO).as_posix()
        for m in BLOCK.finditer(text):
            line = text.count("\n", 0, m.start("body"))
            opts = m.group("opts")
            out.append((f"{name}:{line}", m.group("body"), None if opts is None else opts.strip(": ").split()))
    return out


ALL = blocks()
RUNNABLE = [b for b in ALL if b[2] is not None]


def test_the_readme_has_runnable_examples():
    readme = [b for b in RUNNABLE if b[0].startswith("README.md:")]
    assert len(readme) >= 2, "the README's examples are no longer marked <!-- runnable -->"
    assert any("skip-install" in b[2] and "hdrcl demo" in b[1] for b in readme), \
        "the README's set-up commands are no longer marked <!-- runnable: skip-install -->"


def test_the_docs_pages_are_scanned():
    if not (REPO / "docs").is_dir():
        pytest.skip("no docs/ folder beside the README (an sdist without it)")
    pages = {b[0].split(":")[0] for b in RUNNABLE}
    assert len(pages) >= 2, f"no runnable example found outside the README: {sorted(pages)}"


def test_runnable_markers_sit_on_bash_blocks():
    """A marker (at the start of a line) before anything else than a ```bash block would be
    silently ignored."""
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for m in re.finditer(r"^<!--\s*runnable[^>]*-->", text, re.M):
            assert text[m.end():].lstrip(" \t").startswith("\n```bash\n"), \
                f"{page.name}:{text.count(chr(10), 0, m.start()) + 1}: the marker is not followed by a ```bash block"


def _anchors(page):
    """GitHub's heading anchors: lower case, punctuation dropped, spaces as hyphens."""
    heads = re.findall(r"^#+\s+(.*?)\s*$", page.read_text(encoding="utf-8"), re.M)
    return {re.sub(r"[^\w\- ]", "", h.lower()).replace(" ", "-") for h in heads}


def test_local_links_resolve():
    """Every relative link and image of the README and the docs pages names a file that
    exists, and a #section of a page a heading it has."""
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue
            path, _, anchor = target.partition("#")
            dest = page.parent / path if path else page
            if not (REPO / "docs").is_dir() and path.startswith("docs/"):
                continue  # an sdist without docs/
            assert dest.exists(), f"{page.name}: broken link {target}"
            if anchor and dest.suffix == ".md":
                assert anchor in _anchors(dest), f"{page.name}: no section #{anchor} in {dest.name}"


@pytest.mark.parametrize("block", ALL, ids=[b[0] for b in ALL])
def test_every_bash_block_is_valid_shell(block):
    res = subprocess.run(["bash", "-n"], input=block[1], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr


@pytest.mark.parametrize("block", RUNNABLE, ids=[b[0] for b in RUNNABLE])
def test_runnable_example(block, tmp_path):
    line, body, opts = block
    if "skip-install" in opts:
        body = INSTALL.sub(":", body)
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
    assert res.returncode == 0, f"{line}: exit {res.returncode}\n{res.stderr[-3000:]}"
    if "no-warnings" in opts:
        assert res.stderr == "", f"{line} promises no warning:\n{res.stderr}"
    assert took < 60, f"{line} took {took:.0f} s: mark it not runnable"


SCRATCH = ("example-out/", "demo-out/", "$O/", "$O")


def test_readme_examples_write_into_a_scratch_folder():
    """A new user running the README in the project's root must not litter it with files
    that git does not ignore (issue 29): every output of a README example goes under a
    folder that .gitignore lists."""
    ignored = (REPO / ".gitignore").read_text(encoding="utf-8").split()
    assert "example-out/" in ignored and "demo-out/" in ignored
    outs = re.compile(r"(?:^|\s)(?:-o|--output|--report|--save-response|--clip-mask)\s+(\S+)")
    for where, body, opts in ALL:
        if not where.startswith("README.md:") or opts is None:
            continue
        for m in outs.finditer(body):
            assert m.group(1).startswith(SCRATCH), f"{where}: writes {m.group(1)} outside a scratch folder"
        for m in re.finditer(r"^hdrcl (?:demo|sample-shoot)\s+(\S+)", body, re.M):
            assert m.group(1).startswith(SCRATCH), f"{where}: writes {m.group(1)} outside a scratch folder"


def test_readme_says_where_the_sample_data_comes_from():
    text = (REPO / "README.md").read_text(encoding="utf-8")
    i = text.index("../shared/data/memorial")
    near = text[max(0, i - 800): i + 800]
    assert "Debevec" in near and "hdrcl demo" in near, "the README must say how to get or replace the sample data"
