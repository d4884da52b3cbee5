"""Smoke test of scripts/fusion_bench.py: a tiny generated bracket, one run; every figure
comes out positive and the JSON holds the rates the report quotes."""
import json
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "fusion_bench.py"


def test_fusion_bench_tiny(tmp_path, cl_device):
    out_json = tmp_path / "fb.json"
    r = subprocess.run([sys.executable, str(SCRIPT), "--mp", "0.2", "--frames", "3", "--runs", "1",
                        "--workdir", str(tmp_path / "work"), "--json", str(out_json)],
                       capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    out = r.stdout
    assert re.search(r"^cpu: \S.*; OpenCL: \S", out, re.M), out
    for label in ("decode (OIIO", "fuse (fuse_strip per strip)", "fuse (pipelined, depth"):
        m = re.search(re.escape(label) + r"[^\n]*?\s([0-9.]+) s\s+([0-9.]+) MP/s\s+([0-9.]+) s\s+([0-9.]+) MP/CPU-s",
                      out)
        assert m and float(m.group(1)) > 0 and float(m.group(2)) > 0, out
    assert re.search(r"fuse / decode rate \(median of runs\): [0-9.]+x wall, [0-9.]+x per CPU-second", out), out
    res = json.loads(out_json.read_text())
    assert res["frames"] == 3 and res["fuse_mp_s"] > 0 and res["decode_mp_s"] > 0
    assert res["fuse_over_decode"] > 0 and res["fuse_over_decode_cpu"] > 0
    assert res["pipelined_mp_s"] > 0 and res["pipelined_over_decode"] > 0
