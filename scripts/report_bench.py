#!/usr/bin/env python3
"""What ``--report`` costs a batch: wall time and peak memory with and without it.

Generates (once; cached) a shoot of camera-like JPEGs with ``scripts/benchshoots.py`` (the
shoot benchmark's generator: real scenes from ``../shared/data``, one set per camera by default: 5 sets,
63 frames, like the real shoot of issue 26), then runs, in rounds that alternate the
two so drift hits both alike,

* ``hdrcl batch SHOOT -r -o OUT`` (defaults), and
* ``hdrcl batch SHOOT -r -o OUT --report REPORT``,

each a separate process into fresh folders, and prints per run the wall time and the
process's peak resident memory (``ru_maxrss`` of that child), then the medians, the
ratios (target: ``--report`` at most 1.3x the wall time and no more peak memory than
the batch without it), the summed per-set ``quality`` seconds of ``report.json``, and
``/proc/loadavg`` before and after (the machine may be shared: quote medians).

    python scripts/report_bench.py                           # 5 sets, 63 frames of 6 MP, 3 rounds
    python scripts/report_bench.py --mp 12 --runs 5 --workdir /tmp/rb
    python scripts/report_bench.py --frames 7,5,9 --sets 3 --mp 4 --runs 3
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

if HERE not in sys.path:
    sys.path.insert(0, HERE)
import benchlib  # noqa: E402  (scripts/benchlib.py: loadavg, timed_child)



def run_batch(photos: str, out: str, report: str = None) -> dict:
    """One ``hdrcl batch`` in a child process: wall seconds, peak RSS (MB), quality seconds."""
    for d in (out, report):
        if d:
            shutil.rmtree(d, ignore_errors=True)
    cmd = [sys.executable, "-m", "hdrcl", "batch", photos, "-r", "-o", out] + (["--report", report] if report else [])
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _pid, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode(errors="replace")
    proc.stderr.close()
    rc = os.waitstatus_to_exitcode(status)
    if rc != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({rc}):\n{err[-2000:]}")
    quality = 0.0
    try:
        with open(os.path.join(out, "report.json")) as f:
            doc = json.load(f)
        quality = sum(float((s.get("seconds") or {}).get("quality", 0.0)) for s in doc.get("sets", []))
    except (OSError, ValueError):
        pass
    return {"wall": wall, "rss_mb": usage.ru_maxrss / 1024.0, "quality": quality,
            "cpu": usage.ru_utime + usage.ru_stime}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shape", choices=("one-camera", "per-camera"), default="per-camera")
    ap.add_argument("--mp", type=float, default=6.0, help="frame size in megapixels [default: 6]")
    ap.add_argument("--sets", type=int, default=5, help="sets in the shoot [default: 5]")
    ap.add_argument("--frames", default="13,13,13,12,12", help="frames per set, cycled [default: 13,13,13,12,12]")
    ap.add_argument("--runs", type=int, default=3, help="rounds (one run of each) [default: 3]")
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "hdrcl-report-bench"))
    ap.add_argument("--data", default=os.path.join(os.path.dirname(ROOT), "shared", "data"))
    a = ap.parse_args(argv)
    sys.path.insert(0, HERE)
    import benchshoots

    frames = [int(v) for v in a.frames.split(",") if v.strip()]
    info = benchshoots.generate_shoot(a.workdir, a.data, a.shape, a.mp, a.sets, frames)
    photos = info["photos"]
    print(f"shoot: {info['frames']} frames in {len(info['sets'])} sets, {info['megapixels']:.0f} MP ({photos})")
    print(f"load before: {benchlib.loadavg()}  (cores: {os.cpu_count()})")
    # Own folders: the workdir may be shoot_bench.py's (its shoots reused), whose out/ it keeps.
    out, rep = os.path.join(a.workdir, "report-bench", "out"), os.path.join(a.workdir, "report-bench", "report")
    plain, reported = [], []
    run_batch(photos, out)  # warm the page cache and the OpenCL program cache
    for k in range(a.runs):
        p = run_batch(photos, out)
        r = run_batch(photos, out, rep)
        plain.append(p)
        reported.append(r)
        print(f"round {k + 1}: batch {p['wall']:.2f} s {p['cpu']:.2f} CPU-s {p['rss_mb']:.0f} MB | --report "
              f"{r['wall']:.2f} s {r['cpu']:.2f} CPU-s {r['rss_mb']:.0f} MB (quality {r['quality']:.2f} s) | "
              f"load {benchlib.loadavg()}")

    def med(rows, key):
        return statistics.median(x[key] for x in rows)

    ratios = [r["wall"] / p["wall"] for p, r in zip(plain, reported)]
    print(f"median batch:    {med(plain, 'wall'):.2f} s, peak {med(plain, 'rss_mb'):.0f} MB")
    print(f"median --report: {med(reported, 'wall'):.2f} s, peak {med(reported, 'rss_mb'):.0f} MB, "
          f"quality stage {med(reported, 'quality'):.2f} s summed over sets")
    print(f"--report / batch: wall {statistics.median(ratios):.2f}x (median of each round's ratio; target <= 1.30), "
          f"peak memory {med(reported, 'rss_mb') / med(plain, 'rss_mb'):.2f}x (target <= 1.00)")
    cpu = [r["cpu"] / p["cpu"] for p, r in zip(plain, reported)]
    print(f"--report / batch CPU-seconds: {statistics.median(cpu):.2f}x (median of each round's ratio; the steadier "
          f"figure on a shared machine)")
    print(f"load after: {benchlib.loadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
