"""Cost of hand-held alignment: ``merge --align`` against the plain merge of the same
bracket, time and peak memory (issue 20: 24 MP x 7; issue 33: 12 MP x 13, the default).

Generates (once, cached under the work folder) a bracket from a real
Memorial Church frame: the scene upscaled (24 MP: 6000 x 4000), exposures one stop
apart through an approximately linear camera (``z = 255 (x)^(1/2.2)``), read noise, and
every frame but the middle one moved by a known similarity (rotation <= 1.5 degrees,
shift <= 20 px, scale <= 1 %), written as JPEG. Then merges it twice, each in its own
process: plainly and with ``--align`` (model ``auto``), ``--repeat`` times each,
interleaved, and prints the median wall times and the median peak RSS of each (each merge
its own process), both ratios, the stages (decode, estimate, fuse), the corner error
of the recovered transforms, and the processor.

    python scripts/align_bench.py [--work /tmp/hdrcl-align-bench] [--mp 12] [--frames 13] [--repeat 3]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: The scene: ``shared/data`` beside the checkout (a worktree one level deeper: above it).
MEMORIAL = next((p for p in (os.path.join(d, "shared", "data", "memorial", "memorial0066.png")
                             for d in (os.path.dirname(ROOT), os.path.dirname(os.path.dirname(ROOT))))
                 if os.path.isfile(p)), os.path.join(os.path.dirname(ROOT), "shared", "data", "memorial",
                                                      "memorial0066.png"))


def similarity(rot_deg, scale, dy, dx, h, w):
    c, s = math.cos(math.radians(rot_deg)) * scale, math.sin(math.radians(rot_deg)) * scale
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    a = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    t0 = np.array([[1.0, 0.0, -cx], [0.0, 1.0, -cy], [0.0, 0.0, 1.0]])
    t1 = np.array([[1.0, 0.0, cx + dx], [0.0, 1.0, cy + dy], [0.0, 0.0, 1.0]])
    return t1 @ a @ t0


def generate(folder: str, mp: float, frames: int) -> dict:
    """The bracket's JPEGs, times and true matrices (cached in ``set.json``)."""
    import imageio.v3 as iio
    from scipy import ndimage

    marker = os.path.join(folder, "set.json")
    if os.path.isfile(marker):
        with open(marker) as f:
            return json.load(f)
    os.makedirs(folder, exist_ok=True)
    small = iio.imread(MEMORIAL)[..., :3].astype(np.float64)
    small = np.where(np.all(small == (0, 0, 255), axis=2)[..., None], np.median(small, axis=(0, 1)), small)
    lin = (small / 255.0) ** 2.2
    lin = np.swapaxes(lin, 0, 1)  # landscape
    sh, sw = lin.shape[:2]
    w = int(round(math.sqrt(mp * 1e6 * 1.5)))
    h = int(round(w / 1.5))
    k = sw / w  # output pixel -> small-frame pixel
    rng = np.random.default_rng(7)
    stops = [1.0 * (j - frames // 2) for j in range(frames)]
    times = [float(2.0 ** s / 64.0) for s in stops]
    mats, paths = [], []
    for j, st in enumerate(stops):
        if j == frames // 2:
            m = np.eye(3)
        else:
            m = similarity(rng.uniform(-1.5, 1.5), 1 + rng.uniform(-0.01, 0.01), rng.uniform(-20, 20),
                           rng.uniform(-20, 20), h, w)
        inv = np.linalg.inv(m)
        out = np.empty((h, w, 3), np.uint8)
        for r0 in range(0, h, 500):
            ys, xs = np.mgrid[r0:min(h, r0 + 500), 0:w].astype(np.float64)
            p = np.stack([xs, ys, np.ones_like(xs)], -1) @ inv.T
            sx, sy = (p[..., 0] + 0.5) * k - 0.5, (p[..., 1] + 0.5) * k - 0.5
            for c in range(3):
                v = ndimage.map_coordinates(lin[..., c], [sy, sx], order=1, mode="nearest") * 2.0 ** st
                v += rng.normal(0.0, 0.002, v.shape)
                out[r0:r0 + 500, :, c] = np.round(np.clip(v, 0, 1) ** (1 / 2.2) * 255)
        path = os.path.join(folder, f"frame{j:02d}.jpg")
        iio.imwrite(path, out, quality=92)
        paths.append(path)
        mats.append(m.tolist())
    info = {"paths": paths, "times": times, "matrices": mats, "size": [h, w]}
    with open(marker, "w") as f:
        json.dump(info, f)
    return info


WORKER = r"""
import json, resource, sys, time
import numpy as np
import hdrcl
spec = json.loads(sys.argv[1])
t = time.perf_counter()
r = hdrcl.merge_files(spec["paths"], spec["out"], times=spec["times"], align=spec["align"], dtype="half")
wall = time.perf_counter() - t
rec = {"wall": wall, "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
       "align_s": r.stages.get("align"), "backend": r.backend, "stages": r.stages}
if r.alignment:
    rec["alignment"] = r.alignment
print("RESULT " + json.dumps(rec))
"""


def run(spec: dict) -> dict:
    p = subprocess.run([sys.executable, "-c", WORKER, json.dumps(spec)], capture_output=True, text=True, cwd=ROOT)
    for line in p.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    raise RuntimeError(p.stderr[-3000:])


def processor() -> str:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
        for line in out.splitlines():
            if line.startswith("Model name"):
                return line.split(":", 1)[1].strip() + f", {os.cpu_count()} cores"
    except OSError:
        pass
    return platform.processor() or "unknown"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="/tmp/hdrcl-align-bench")
    ap.add_argument("--mp", type=float, default=12.0)
    ap.add_argument("--frames", type=int, default=13)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    sys.path.insert(0, ROOT)
    from hdrcl.core.align.warp import corner_distance

    t = time.perf_counter()
    info = generate(os.path.join(a.work, f"{a.mp:g}mp-x{a.frames}"), a.mp, a.frames)
    print(f"inputs: {len(info['paths'])} frames {info['size'][1]}x{info['size'][0]} "
          f"({time.perf_counter() - t:.0f} s to generate or load)")
    base = {"paths": info["paths"], "times": info["times"]}
    plain, aligned = [], []
    for _ in range(a.repeat):  # interleaved: a shared machine's load falls on both alike
        plain.append(run(dict(base, out=os.path.join(a.work, "plain.exr"), align=False)))
        aligned.append(run(dict(base, out=os.path.join(a.work, "aligned.exr"), align=True)))

    def median(runs, key="wall"):
        return sorted(runs, key=lambda r: r[key])[len(runs) // 2]

    p, q = median(plain), median(aligned)
    p_mb, q_mb = median(plain, "rss_mb")["rss_mb"], median(aligned, "rss_mb")["rss_mb"]
    h, w = info["size"]
    errs = [corner_distance(np.asarray(al["matrix"]), np.asarray(m), h, w)
            for al, m in zip(q["alignment"], info["matrices"])]

    def stages(r):
        return ", ".join(f"{k} {v:.2f}" for k, v in sorted(r.get("stages", {}).items()))

    print(f"processor: {processor()}; backend {p['backend']}")
    print(f"plain merge:        {p['wall']:.2f} s, peak RSS {p_mb:.0f} MB (stages: {stages(p)} s)")
    print(f"merge with --align: {q['wall']:.2f} s, peak RSS {q_mb:.0f} MB (stages: {stages(q)} s; "
          f"align: decoded frames to transforms)")
    if a.repeat > 1:
        print(f"(medians of {a.repeat} runs each; plain " + ", ".join(f"{r['wall']:.2f}" for r in plain)
              + " s, " + ", ".join(f"{r['rss_mb']:.0f}" for r in plain) + " MB; aligned "
              + ", ".join(f"{r['wall']:.2f}" for r in aligned) + " s, "
              + ", ".join(f"{r['rss_mb']:.0f}" for r in aligned) + " MB)")
    ratio = q["wall"] / p["wall"]
    print(f"ratio aligned / plain: time {ratio:.2f}, peak memory {q_mb / p_mb:.2f}")
    print("models: " + ", ".join(al["model"] for al in q["alignment"]))
    print("corner error of the recovered transforms (px): " + ", ".join(f"{e:.2f}" for e in errs))


if __name__ == "__main__":
    main()
