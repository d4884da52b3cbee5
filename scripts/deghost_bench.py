#!/usr/bin/env python3
"""--deghost on a generated night scene (issue 32 item 6): harm and cost.

A moon that saturates the longer frames above a dim sky, behind leaves that sway 1-3 px
between frames (:func:`hdrcl.core.synthetic.night_scene`), merged through a response
wrong in the toe and shoulder the way calibrated curves are (``--toe``, ``--shoulder``,
ln units at code 10 and at the top). It prints

* darker blotches: pixels where the deghosted merge is darker than both the middle
  frame's true radiance and the plain merge by more than ``--darker`` (any channel);
* moon steps: pairs of neighbouring pixels inside the disc whose error (ln, green)
  differs by more than 0.1, plain and deghosted;
* the time of ``merge`` and ``merge --deghost`` (files in, EXR out, response given) on a
  ``--mp`` MP x 5 set, median of ``--repeat``, and their ratio (target: at most 2).

    python scripts/deghost_bench.py                 # 12 MP x 5, median of 3
    python scripts/deghost_bench.py --mp 2 --repeat 1
    python scripts/deghost_bench.py --pythonpath /other/checkout   # time another copy

The merges run in child processes under ``--pythonpath`` (default: this checkout), so
another version of hdrcl can be measured on the same files.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

CHILD = r"""
import json, sys, time
import numpy as np
from hdrcl.core.response import Response, knot_positions
a = json.loads(sys.argv[1])
resp = Response(bits=8, g=np.load(a["g"]), knots=knot_positions(8))
if a["kind"] == "quality":
    from hdrcl.core.fusion import fuse_frames
    d = np.load(a["frames"])
    frames = [d[f"f{k}"] for k in range(len(a["times"]))]
    out = {}
    for dg in (False, True):
        out["deghost" if dg else "plain"] = fuse_frames(frames, a["times"], resp, deghost=dg).radiance
    np.savez(a["out"], **out)
else:
    import hdrcl
    t = time.perf_counter()
    hdrcl.merge_files(a["paths"], a["out"], times=a["times"], response=resp, deghost=a["deghost"])
    print(json.dumps({"seconds": time.perf_counter() - t}))
"""


def response_error(toe: float, shoulder: float) -> np.ndarray:
    z = np.arange(256.0)
    return toe * np.clip((60 - z) / 50, 0, 1) ** 2 + shoulder * np.clip((z - 180) / 75, 0, 1) ** 2


def save_g(work, cam, toe, shoulder) -> str:
    z = np.clip(np.arange(256.0), 0.5, 254.5)
    g = np.stack([cam.g(z, c) for c in range(3)]) + response_error(toe, shoulder)
    path = os.path.join(work, f"g_{toe:g}_{shoulder:g}.npy")
    np.save(path, g)
    return path


def child(args, spec: dict) -> str:
    env = dict(os.environ, PYTHONPATH=args.pythonpath)
    # cwd: "python -c" puts the working folder first on sys.path, ahead of PYTHONPATH
    res = subprocess.run([sys.executable, "-c", CHILD, json.dumps(spec)], env=env, capture_output=True, text=True,
                         cwd=args.work)
    if res.returncode:
        sys.exit(f"child failed: {res.stderr.strip().splitlines()[-1:]}")
    return res.stdout


def quality(args, work) -> dict:
    from hdrcl.core import synthetic as s

    sc = s.night_scene(args.height, args.width, seed=args.seed)
    g = save_g(work, sc.camera, args.toe, args.shoulder)
    fpath, out = os.path.join(work, "small.npz"), os.path.join(work, "small_out.npz")
    np.savez(fpath, **{f"f{k}": f for k, f in enumerate(sc.frames)})
    child(args, {"kind": "quality", "g": g, "frames": fpath, "times": [float(t) for t in sc.times], "out": out})
    r = np.load(out)
    plain, dg = r["plain"], r["deghost"]
    truth = sc.truth[len(sc.frames) // 2]
    dark = (dg < (1 - args.darker) * np.minimum(truth, plain)).any(axis=2)
    pair = sc.moon[:, 1:] & sc.moon[:, :-1]
    steps = {}
    for name, x in (("plain", plain), ("deghost", dg)):
        e = np.log(x[..., 1] / truth[..., 1])
        steps[name] = int((np.abs(np.diff(e, axis=1))[pair] > 0.1).sum())
    return {"darker_blotches": int(dark.sum()), "moon_steps": steps, "moon_pairs": int(pair.sum()),
            "pixels": int(dark.size)}


def ensure_big(work, mp, seed) -> tuple:
    """A ``mp`` MP x 5 set: a 1/4-size night scene tiled 2 x 2 (uncompressed TIFF)."""
    from hdrcl.core import synthetic as s

    h = int(round(np.sqrt(mp * 1e6 * 3 / 4) / 2))
    w = int(round(h * 4 / 3))
    folder = os.path.join(work, f"night_{mp:g}mp_{seed}")
    paths = [os.path.join(folder, f"f{k}.tif") for k in range(5)]
    meta = os.path.join(folder, "times.json")
    if not os.path.isfile(meta):
        import OpenImageIO as oiio

        os.makedirs(folder, exist_ok=True)
        sc = s.night_scene(h, w, seed=seed)
        for p, f in zip(paths, sc.frames):
            big = np.ascontiguousarray(np.tile(f, (2, 2, 1)))
            out = oiio.ImageOutput.create(p)
            out.open(p, oiio.ImageSpec(big.shape[1], big.shape[0], 3, "uint8"))
            out.write_image(big)
            out.close()
        with open(meta, "w") as fh:
            json.dump({"times": [float(t) for t in sc.times]}, fh)
    with open(meta) as fh:
        sc_times = json.load(fh)["times"]
    from hdrcl.core.synthetic import Camera

    return paths, sc_times, Camera(a=1.1, x0=(1.0, 1.0, 1.0))


def timing(args, work) -> dict:
    paths, times, cam = ensure_big(work, args.mp, args.seed)
    g = save_g(work, cam, args.toe, args.shoulder)
    out = {}
    runs = {False: [], True: []}
    for _ in range(args.repeat):
        for dg in (False, True):  # interleaved, so load changes hit both alike
            r = child(args, {"kind": "merge", "g": g, "paths": paths, "times": times, "deghost": dg,
                             "out": os.path.join(work, "out.exr")})
            runs[dg].append(json.loads(r.strip().splitlines()[-1])["seconds"])
    out["merge_s"] = statistics.median(runs[False])
    out["deghost_s"] = statistics.median(runs[True])
    out["ratio"] = out["deghost_s"] / out["merge_s"]
    out["runs"] = {"merge": runs[False], "deghost": runs[True]}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mp", type=float, default=12.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--height", type=int, default=360, help="quality scene height [360]")
    ap.add_argument("--width", type=int, default=480, help="quality scene width [480]")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--toe", type=float, default=-0.3)
    ap.add_argument("--shoulder", type=float, default=0.4)
    ap.add_argument("--darker", type=float, default=0.2)
    ap.add_argument("--work", default="/tmp/hdrcl-deghost-bench")
    ap.add_argument("--pythonpath", default=ROOT)
    ap.add_argument("--skip-timing", action="store_true")
    args = ap.parse_args(argv)
    os.makedirs(args.work, exist_ok=True)
    q = quality(args, args.work)
    print(f"darker blotches (> {100 * args.darker:g} % below truth and plain): {q['darker_blotches']} of "
          f"{q['pixels']} px")
    print(f"moon steps > 0.1 ln: plain {q['moon_steps']['plain']}, deghost {q['moon_steps']['deghost']} "
          f"(of {q['moon_pairs']} pairs)")
    if not args.skip_timing:
        t = timing(args, args.work)
        print(f"{args.mp:g} MP x 5: merge {t['merge_s']:.2f} s, --deghost {t['deghost_s']:.2f} s, "
              f"ratio {t['ratio']:.2f} (target <= 2; median of {args.repeat})")
        q.update(t)
    print(json.dumps(q))
    return 0


if __name__ == "__main__":
    sys.exit(main())
