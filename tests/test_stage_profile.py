"""scripts/stage_profile.py (issue 33): ``hdrcl batch`` in-process with every thread
sampled; each phase of the batch gets wall and CPU seconds, and the main thread's waits
are listed. Run on the generated sample shoot."""
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "stage_profile.py"


def test_stage_profile_names_the_phases(tmp_path, cl_device):
    from hdrcl.shoot.sample import write_sample_shoot

    shoot = tmp_path / "shoot"
    write_sample_shoot(shoot, width=192, height=128)
    out_json = tmp_path / "prof.json"
    r = subprocess.run([sys.executable, str(SCRIPT), str(shoot), "--interval", "2", "--json", str(out_json),
                        "--keep", str(tmp_path / "out")], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    res = json.loads(out_json.read_text())
    assert res["exit"] == 0 and res["summary"]["done"] >= 1 and res["samples"] > 10
    assert (tmp_path / "out" / "report.json").is_file()

    phases = {(p["context"], p["stage"]): p for p in res["phases"]}
    contexts = {c for c, _ in phases}
    assert {"scan", "set merge"} <= contexts, sorted(phases)
    merge_stages = {s for c, s in phases if c == "set merge"}
    assert {"decode", "encode"} <= merge_stages, sorted(merge_stages)
    assert merge_stages & {"fuse", "fuse (host)", "OpenCL (other)"}, sorted(merge_stages)
    for p in res["phases"]:
        assert min(p["main_wall"], p["main_cpu"], p["py_cpu"], p["native_cpu"]) >= 0, p

    # The threads' CPU adds up to the process's (getrusage), less what the sampler misses
    # (threads that ended between two samples) and its own share.
    cpu = sum(p["main_cpu"] + p["py_cpu"] + p["native_cpu"] for p in res["phases"])
    assert 0.6 * res["cpu_s"] <= cpu + res["sampler_cpu_s"] <= 1.05 * res["cpu_s"] + 0.05, (cpu, res["cpu_s"])
    wall = sum(p["main_wall"] for p in res["phases"])
    assert abs(wall - res["wall_s"]) <= 0.1 * res["wall_s"] + 0.05, (wall, res["wall_s"])
    assert res["threads"]["MainThread"]["cpu"] > 0

    out = r.stdout
    assert "main thread's top waits" in out and "set merge" in out and "CPU per thread" in out
