"""Smoke test of the shoot benchmark (scripts/shoot_bench.py): generate a tiny shoot,
run every measurement once on it, and check that the figures come out positive.

OpenCV is measured only where ``cv2`` imports (the ``bench`` extra); otherwise the test
runs with ``--skip-opencv``.
"""
import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "shoot_bench.py"
DATA = ROOT.parent / "shared" / "data"

NUMBER = r"([0-9]+(?:\.[0-9]+)?)"


def _figure(out: str, label: str):
    """Median seconds and MP/s of a figure's row (the first two numbers after the label)."""
    m = re.search(re.escape(label) + r"[^\n]*?\s" + NUMBER + r"\s+" + NUMBER + r"\s", out)
    assert m, f"no figures for {label!r} in:\n{out}"
    return float(m.group(1)), float(m.group(2))


def test_shoot_bench_tiny(tmp_path):
    have_cv2 = importlib.util.find_spec("cv2") is not None
    work = tmp_path / "work"
    cmd = [sys.executable, str(SCRIPT), "--shape", "one-camera", "--sets", "2", "--frames", "3", "--mp", "0.3",
           "--runs", "1", "--startup-runs", "1", "--workdir", str(work)]
    if not have_cv2:
        cmd.append("--skip-opencv")
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    out = r.stdout

    assert re.search(r"processor: \S", out)
    assert "2 sets x 3/3 frames" in out
    assert "hdrcl scan reads it back: 2 sets, EXIF as written" in out, out
    rows = ["hdrcl batch SHOOT -r -o OUT (defaults)", "hdrcl batch SHOOT -r -o OUT --jobs 2", "decode floor",
            "encode floor", "I/O floor (decode + encode floor)"]
    if have_cv2:
        rows.append("OpenCV loop")
    for label in rows:
        seconds, mp_s = _figure(out, label)
        assert seconds > 0 and mp_s > 0, label
    ratios = re.findall(r"hdrcl / (OpenCV|decode floor)\s+" + NUMBER, out)
    assert {name for name, _ in ratios} == ({"OpenCV", "decode floor"} if have_cv2 else {"decode floor"}), out
    assert all(float(v) > 0 for _, v in ratios)
    assert ">= 35 %" in out and (">= 5x" in out)
    # The I/O floor (issue 26): decode + encode of the batch's own outputs, and batch wall / floor.
    dec, _ = _figure(out, "decode floor")
    enc, _ = _figure(out, "encode floor")
    floor, _ = _figure(out, "I/O floor (decode + encode floor)")
    assert abs(floor - (dec + enc)) <= 0.016, out  # three figures rounded to 0.01 s
    assert re.search(r"encode floor: 2 outputs, [0-9.]+ MP, \.exr half \w+", out), out
    m = re.search(r"batch wall / I/O floor\s+" + NUMBER + r"x \[", out)
    assert m and float(m.group(1)) > 1, out  # nothing runs faster than its own decode and encode
    # The CPU floor (issue 33): batch CPU-seconds beside decode + encode + fusion CPU-seconds.
    seconds, _ = _figure(out, "fusion floor (OpenCL, decoded frames)")
    assert seconds > 0, out
    m = re.search(r"batch CPU-seconds " + NUMBER + r" \(user \+ system of the batch process\); decode \+ encode \+ "
                  r"fusion CPU-seconds " + NUMBER + r" \+ " + NUMBER + r" \+ " + NUMBER + r" = " + NUMBER, out)
    assert m, out
    batch_cpu, d, e, f, total = map(float, m.groups())
    assert batch_cpu > 0 and f > 0 and abs(total - (d + e + f)) <= 0.016, out
    m = re.search(r"batch CPU-s / floors\s+" + NUMBER + r"x \[.*target <= 1.3x", out)
    assert m and float(m.group(1)) > 0, out

    # Per-stage seconds from OUT/report.json: whatever keys hdrcl records, each >= 0.
    table = out.split("summed over sets (median of runs):", 1)[1].split("batch wall", 1)[0]
    stages = re.findall(r"^\s{4}(\w+)\s+" + NUMBER + r"\s+" + NUMBER + r"\s*$", table, re.M)
    assert stages, out
    if DATA.joinpath("frobisher_001").is_dir():
        for label in ("hdrcl --version", "hdrcl merge frobisher_001"):
            m = re.search(re.escape(label) + r"[^\n]*?\s" + NUMBER + " s", out)
            assert m and float(m.group(1)) > 0, out

    res = json.loads((work / "shoot-bench-results.json").read_text())
    fig = res["shapes"][0]["result"]["figures"]
    assert fig["hdrcl"]["mp_per_s"]["median"] > 0 and fig["decode"]["mp_per_s"]["median"] > 0
    assert fig["encode"]["outputs"] == 2 and fig["io_floor"]["seconds"]["median"] > 0
    assert res["shapes"][0]["result"]["ratios"]["io_floor"]["median"] > 1
    cpu = res["shapes"][0]["result"]["ratios"]["cpu_floor"]
    assert cpu["median"] > 0 and cpu["fusion_cpu_s"] > 0 and fig["fusion"]["timed_cpu_s"]["median"] > 0
    info = res["shapes"][0]["info"]
    assert info["frames"] == 6 and info["scan"]["ok"]
    assert all(os.path.isfile(p) for s in info["sets"] for p in s["files"])


def test_shoot_plan_shapes():
    """The two shapes: one camera for every set; one camera per set, 5-13 frames."""
    sys.path.insert(0, str(SCRIPT.parent))
    try:
        import benchshoots
        import shoot_bench as sb
    finally:
        sys.path.remove(str(SCRIPT.parent))
    one = benchshoots.shoot_plan("one-camera", 6, sb.parse_frames(sb.DEFAULT_FRAMES["one-camera"]))
    assert len({p["camera"]["model"] for p in one}) == 1 and all(p["frames"] == 7 for p in one)
    per = benchshoots.shoot_plan("per-camera", 6, sb.parse_frames(sb.DEFAULT_FRAMES["per-camera"]))
    assert len({(p["camera"]["make"], p["camera"]["model"]) for p in per}) == 6
    assert min(p["frames"] for p in per) == 5 and max(p["frames"] for p in per) == 13
    for p in per:  # every ladder fits the camera's shutter range, distinct and increasing
        times, _ = benchshoots.ladder(p["frames"], p["t_mid"])
        assert times == sorted(set(times)) and 1 / 8000 <= times[0] and times[-1] <= 30
    with pytest.raises(SystemExit):
        sb.parse_frames("1")
