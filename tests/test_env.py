"""One rule for every HDRCL_* variable (hdrcl/env.py): unset or empty is the default, a
value the variable does not take is exit 2 with one line naming it. Before,
HDRCL_MEMORY_MB=abc ran silently with 1024 MB, HDRCL_SMALL_WORK=abc warned and went on
and HDRCL_MAX_PIXELS=abc exited 2."""
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl import env
from hdrcl.errors import UsageError

ROOT = Path(__file__).resolve().parents[1]


def test_every_variable_the_package_reads_is_declared_and_documented():
    read = set()
    for path in (ROOT / "hdrcl").rglob("*.py"):
        read |= set(re.findall(r"HDRCL_[A-Z_]*[A-Z](?![A-Z_*])", path.read_text()))
    assert read <= set(env.VARIABLES), sorted(read - set(env.VARIABLES))
    doc = (ROOT / "docs" / "cli.md").read_text()
    table = set(re.findall(r"^\| `(HDRCL_[A-Z_]+)` \|", doc, re.M))
    assert table == set(env.VARIABLES)


def _tiny_map(path):
    from hdrcl.io.writers import write_radiance

    write_radiance(path, np.full((8, 8, 3), 0.5, np.float32), metadata={"units": "cd/m2"},
                   camera={"units": "cd/m2", "view": "-vta -vh 180 -vv 180"})


@pytest.mark.parametrize("name,value", [("HDRCL_MEMORY_MB", "abc"), ("HDRCL_MEMORY_MB", "0"),
                                        ("HDRCL_SMALL_WORK", "abc"), ("HDRCL_MAX_PIXELS", "abc"),
                                        ("HDRCL_OPENCL", "maybe"), ("HDRCL_REPORT_THREADS", "-2"),
                                        ("HDRCL_DECODE_AHEAD", "2"), ("HDRCL_SCRATCH_DIR", "/no/such/folder")])
def test_a_value_the_variable_does_not_take_is_exit_2_naming_it(tmp_path, monkeypatch, name, value):
    import hdrcl.cli.glare  # noqa: F401
    from hdrcl.cli.group import main

    _tiny_map(tmp_path / "m.hdr")
    monkeypatch.setenv(name, value)
    r = CliRunner().invoke(main, ["glare", str(tmp_path / "m.hdr")])
    assert r.exit_code == 2, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"hdrcl: error: {name}={value!r} is not"), r.output


def test_the_library_applies_the_same_rule_where_it_reads(monkeypatch):
    from hdrcl.cl import backend
    from hdrcl.io.framecache import memory_budget_bytes

    monkeypatch.setenv("HDRCL_MEMORY_MB", "abc")
    with pytest.raises(UsageError, match="HDRCL_MEMORY_MB"):
        memory_budget_bytes()
    monkeypatch.setenv("HDRCL_SMALL_WORK", "abc")
    with pytest.raises(UsageError, match="HDRCL_SMALL_WORK"):
        backend.small_work()


@pytest.mark.parametrize("name,value,want", [("HDRCL_MEMORY_MB", "0.01", 0.01), ("HDRCL_MEMORY_MB", "", 1024.0),
                                             ("HDRCL_SMALL_WORK", "600_000", 600000), ("HDRCL_SMALL_WORK", "0", 0),
                                             ("HDRCL_MAX_PIXELS", "1e9", 10 ** 9), ("HDRCL_OPENCL", "Off", False),
                                             ("HDRCL_OPENCL", " 1 ", True), ("HDRCL_DECODE_AHEAD", "0", False)])
def test_values_the_variables_take(monkeypatch, name, value, want):
    monkeypatch.setenv(name, value)
    assert env.check(name) == want
