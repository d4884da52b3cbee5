"""hdrcl's own state files, damaged: a batch's ``report.json``, the pooled
``<camera>_ISO_<n>.response.json``, the quality report's per-set JSON and a ``merge
--report`` folder's JSON. Each is read through :func:`hdrcl.io.jsondoc.read_json` and
type-checked; a damaged one counts as absent or stale (rebuilt), never as an error.
"""
import json

import pytest
from click.testing import CliRunner

from hdrcl.cli import main

#: Damaged contents: nesting that overflows a recursive reader, wrong types at every level.
DAMAGE = {
    "deep": "[" * 100000 + "]" * 100000,
    "deep-in-object": '{"sets": ' + "[" * 100000 + "]" * 100000 + "}",
    "list": "[1, 2]",
    "wrong-types": json.dumps({"format": "hdrcl-set-report", "sets": 5, "calibration": 5, "figures": [1],
                               "files": [1], "inputs": 7, "warnings": 3, "camera": "x", "name": 5}),
    "wrong-items": json.dumps({"sets": [5, None, {"index": "x"}, {"index": 0, "files": 7},
                                        {"index": 1, "files": [3, None]}],
                               "calibration": {"key": [], "warnings": 5}}),
    "binary": "\x00\x01\x02",
}


def _run(args):
    res = CliRunner().invoke(main, args)
    assert "internal error" not in res.stderr, res.stderr
    assert res.exit_code == 0, (res.exit_code, res.stderr, res.stdout)
    return res


@pytest.fixture(scope="module")
def shoot(tmp_path_factory):
    from hdrcl.shoot.sample import write_sample_shoot

    d = tmp_path_factory.mktemp("damaged") / "shoot"
    write_sample_shoot(d, width=48, height=32)
    return d


@pytest.mark.parametrize("damage", sorted(DAMAGE))
def test_damaged_batch_state_is_rebuilt(shoot, tmp_path, damage):
    out, rep = tmp_path / "out", tmp_path / "rep"
    _run(["batch", str(shoot), "-o", str(out), "--report", str(rep), "--no-preview", "-q"])
    victims = [out / "report.json", *out.glob("*.response.json"),
               *(p for p in rep.glob("*.json") if not p.name.startswith("."))]
    assert len(victims) >= 3, victims  # the report, a pooled response, a set's quality JSON
    for p in victims:
        p.write_text(DAMAGE[damage])
    _run(["batch", str(shoot), "-o", str(out), "--report", str(rep), "--no-preview", "-q"])
    report = json.loads((out / "report.json").read_text())
    assert report["sets"] and all(s["status"] in ("done", "skipped") for s in report["sets"]), report["sets"]
    assert (rep / "index.html").is_file()


@pytest.mark.parametrize("damage", sorted(DAMAGE))
def test_merge_report_skips_a_damaged_entry(tmp_path, damage):
    from hdrcl.core import synthetic as s
    from hdrcl.io.ldr import write_ldr

    times = (1 / 60, 1 / 15, 1 / 4)
    rad = s.radiance_field(24, 32, decades=2.0, seed=3)
    files = []
    for k, frame in enumerate(s.bracket(rad, times, s.Camera(a=1.1, bits=8), noise=0.3, seed=4)):
        files.append(str(tmp_path / f"f{k}.png"))
        write_ldr(files[-1], frame)
    rep = tmp_path / "rep"
    rep.mkdir()
    (rep / "old.json").write_text(DAMAGE[damage])
    out = tmp_path / "m.exr"
    _run(["merge", *files, "--times", "1/60,1/15,1/4", "-o", str(out), "--report", str(rep), "-q"])
    assert out.is_file() and (rep / "index.html").is_file() and (rep / "m.json").is_file()
