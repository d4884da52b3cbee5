#!/usr/bin/env python3
"""One merge, two checkouts, interleaved: is a change faster on a shared machine?

Runs ``hdrcl merge`` of the bench's generated bracket (``scripts/bench.py``'s set, made
once in ``--work``) calibrating to ``.hdr`` and to ``--dtype half`` ``.exr``, with this
checkout and with ``--before`` (another checkout of hdrcl), the two alternating in every
round (the first to run swaps each round), and OpenCV's calibrate + merge (the bench's
script) once a round. Prints each run's wall and CPU seconds (the process's user +
system) and peak memory, then the medians and OpenCV's time over each: figures taken in
the same minutes share the machine's load, so their ratios hold where absolute times do
not. The outputs of the two checkouts are compared byte for byte.

    python scripts/merge_ab.py --before /tmp/base --rounds 4
    python scripts/merge_ab.py --before /tmp/base --size 12x7 --work /tmp/hdrcl-bench
"""
from __future__ import annotations

import argparse
import filecmp
import json
import os
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import bench  # noqa: E402  (the generated set and OpenCV's script)


def _run(cmd, env):
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    err = p.stderr.read().decode(errors="replace").strip()
    p.stderr.close()
    if status != 0:
        raise SystemExit(f"failed: {' '.join(cmd[:5])} ...: {err[-500:]}")
    return {"wall_s": wall, "cpu_s": ru.ru_utime + ru.ru_stime, "rss_mb": ru.ru_maxrss / 1024}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", required=True, help="the other checkout (its root: hdrcl/ inside)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--size", default="24x7", help="megapixels x frames [default: 24x7]")
    ap.add_argument("--work", default=os.path.join(os.environ.get("TMPDIR", "/tmp"), "hdrcl-bench"))
    ap.add_argument("--skip-opencv", action="store_true")
    a = ap.parse_args(argv)
    (mp, frames), = bench.parse_sizes(a.size)
    info = bench.ensure_set(a.work, mp, frames)
    out = os.path.join(a.work, "ab")
    os.makedirs(out, exist_ok=True)
    roots = {"before": os.path.abspath(a.before), "after": os.path.dirname(HERE)}
    env0 = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    runs: dict = {}
    for r in range(a.rounds):
        for kind in ("hdr", "exr"):
            for who in ("before", "after") if r % 2 == 0 else ("after", "before"):
                target = os.path.join(out, f"{who}.{kind}")
                cmd = [sys.executable, "-m", "hdrcl", "merge", *info["paths"], "-o", target]
                res = _run(cmd + (["--dtype", "half"] if kind == "exr" else []), dict(env0, PYTHONPATH=roots[who]))
                runs.setdefault(f"{who} .{kind}", []).append(res)
                print(f"round {r + 1} {who:6s} .{kind}: {res['wall_s']:6.2f} s wall {res['cpu_s']:5.2f} CPU-s "
                      f"{res['rss_mb']:4.0f} MB (load {os.getloadavg()[0]:.1f})", flush=True)
        if not a.skip_opencv and bench.have_opencv():
            res = _run([sys.executable, "-c", bench.OPENCV_SCRIPT, os.path.join(out, "opencv.hdr"),
                        json.dumps(info["times"]), *info["paths"]], env0)
            runs.setdefault("opencv", []).append(res)
            print(f"round {r + 1} OpenCV: {res['wall_s']:6.2f} s wall {res['cpu_s']:5.2f} CPU-s", flush=True)
    med = {k: {m: statistics.median(x[m] for x in v) for m in ("wall_s", "cpu_s")} | {"rss_mb": max(x["rss_mb"] for x in v)}
           for k, v in runs.items()}
    print(f"medians of {a.rounds} rounds ({bench.size_label(mp, frames)}):")
    cv = med.get("opencv")
    for k, m in med.items():
        ratio = "" if cv is None or k == "opencv" else \
            f"   OpenCV / this: {cv['wall_s'] / m['wall_s']:.2f}x wall, {cv['cpu_s'] / m['cpu_s']:.2f}x CPU"
        print(f"  {k:12s} {m['wall_s']:6.2f} s wall {m['cpu_s']:5.2f} CPU-s peak {m['rss_mb']:4.0f} MB{ratio}")
    for kind in ("hdr", "exr"):
        same = filecmp.cmp(os.path.join(out, f"before.{kind}"), os.path.join(out, f"after.{kind}"), shallow=False)
        print(f"  .{kind} of the two checkouts: {'the same bytes' if same else 'DIFFERENT bytes'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
