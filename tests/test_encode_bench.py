"""Smoke test of scripts/encode_bench.py: a tiny map, one round; the EXR it writes through
hdrcl's encode path holds the same pixels as OpenImageIO's write of the prepared half data,
and every figure comes out positive."""
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "encode_bench.py"


def test_encode_bench_tiny(tmp_path):
    out_json = tmp_path / "eb.json"
    r = subprocess.run([sys.executable, str(SCRIPT), "--mp", "0.1", "--runs", "1", "--json", str(out_json)],
                       capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    res = json.loads(out_json.read_text())
    assert [x["format"] for x in res] == ["exr", "hdr"]
    exr = res[0]
    assert exr["file_equals_floor"] is True and exr["stored"] == {"dtype": "half", "passes": 1}
    for x in res:
        assert x["hdrcl_cpu_s"] > 0 and x["floor_wall_s"] > 0 and x["cpu_ratio"] > 0, x
    assert "OpenImageIO alone" in r.stdout
