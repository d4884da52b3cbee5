"""Exposure fusion (hdrcl fuse) against OpenCV's MergeMertens: agreement, speed, memory.

    python scripts/mertens_bench.py compare [--data ../shared/data]
        code-level differences from OpenCV (same exponents, RGB order) on the Memorial
        set (all 16 frames, blue borders included, as OpenCV sees them) and window_e995
        (12 Nikon E995 JPEGs); enfuse's too where it is installed
    python scripts/mertens_bench.py speed [--mp 24] [--frames 7] [--repeat 3]
        seconds (medians) of hdrcl's fusion and OpenCV's on generated frames
    python scripts/mertens_bench.py memory [--mp 100] [--frames 5]
        peak resident memory of a fresh process fusing generated frames made band by band
        (nothing holds a whole frame: the frames would be 1.5 GB at 100 MP x 5)

Figures: docs/merge.md ("Exposure fusion"). The device is hdrcl's choice (PYOPENCL_CTX
picks another); OpenCV uses all cores (cv2.getNumThreads()).
"""
from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _cv2():
    try:
        import cv2
    except ImportError:
        sys.exit("OpenCV is needed: pip install opencv-python-headless (the bench extra)")
    return cv2


def _codes(x):
    from hdrcl.core.mertens import to_codes

    return to_codes(x).astype(np.int16)


def _levels(a, b) -> str:
    d = np.abs(_codes(a) - _codes(b))
    return (f"median {np.median(d):.0f}, mean {d.mean():.3f}, p99 {np.percentile(d, 99):.0f}, "
            f"max {d.max()} code levels; {100 * np.mean(d > 2):.3f}% of values differ by more than 2")


def _read(paths):
    from hdrcl.io.frames import read_images

    return [im.pixels for im in read_images(paths)]


def compare(args) -> None:
    cv2 = _cv2()
    from hdrcl.core.mertens import exposure_fusion

    data = Path(args.data)
    sets = {"memorial": sorted((data / "memorial").glob("memorial*.png")),
            "window_e995": sorted((data / "window_e995").glob("*.jpg"))}
    for name, paths in sets.items():
        if not paths:
            print(f"{name}: not found under {data}")
            continue
        frames = _read(paths)
        h, w = frames[0].shape[:2]
        for e in ((1.0, 1.0, 1.0), (1.0, 1.0, 0.0)):
            ours = exposure_fusion(frames, contrast=e[0], saturation=e[1], exposedness=e[2])
            theirs = cv2.createMergeMertens(*e).process([f.copy() for f in frames])  # RGB: its RGB2GRAY is ours
            print(f"{name} ({len(frames)} x {w}x{h}), exponents {e}: vs OpenCV {cv2.__version__}: "
                  f"{_levels(ours, theirs)}")
        print(f"{name}: normalising after the pyramids instead (one pass, sum_k Lap(I_k) G(W_k) / G(sum_k W_k)), "
              f"against the exact fusion: {_levels(_normalised_late(frames), exposure_fusion(frames))}")
        if shutil.which("enfuse"):
            with tempfile.TemporaryDirectory() as tmp:
                out = os.path.join(tmp, "enfuse.tif")
                subprocess.run(["enfuse", "--exposure-weight=1", "--saturation-weight=1", "--contrast-weight=1",
                                "-o", out] + [str(p) for p in paths], check=True, capture_output=True)
                ef = _read([out])[0][..., :3].astype(np.float32) / 255.0
            ours = exposure_fusion(frames)
            print(f"{name}: vs enfuse (its own pyramid and contrast window): {_levels(ours, ef)}")
        else:
            print(f"{name}: enfuse is not installed here (apt-get install enblend-enfuse): not compared")


def _normalised_late(frames) -> np.ndarray:
    """The one-pass alternative to OpenCV's order (float64): the weights normalised per
    level after their pyramids, ``sum_k Lap_l(I_k) G_l(W_k) / G_l(sum_k W_k)``."""
    from hdrcl.core.mertens import FusionWeights, to_unit, weights
    from hdrcl.core.pyramids import gaussian, max_level, pyr_up

    fw = FusionWeights()
    h, w = frames[0].shape[:2]
    top = max_level(h, w)
    num, wsum = None, None
    for f in frames:
        gi, gw = gaussian(to_unit(f), top), gaussian(weights(f, fw), top)
        lap = [gi[lv] - pyr_up(gi[lv + 1], *gi[lv].shape[:2]) for lv in range(top)] + [gi[top]]
        terms = [lap[lv] * gw[lv][..., None] for lv in range(top + 1)]
        num = terms if num is None else [a + b for a, b in zip(num, terms)]
        wsum = gw if wsum is None else [a + b for a, b in zip(wsum, gw)]
    res = num[top] / wsum[top][..., None]
    for lv in range(top - 1, -1, -1):
        res = num[lv] / wsum[lv][..., None] + pyr_up(res, *num[lv].shape[:2])
    return res.astype(np.float32)


class Scene:
    """A generated bracket whose rows are cheap to make again (the memory run makes every
    band's rows, halo included, twice): log10 radiance = f(x) + g(y) over about 4.5
    decades with texture and seeded grain on both axes, quantised to 1/1000 decade and
    turned into codes through a table per frame (a gamma-2.2 camera, one stop apart)."""

    def __init__(self, h: int, w: int, n: int, seed: int = 0):
        rng = np.random.default_rng(seed)
        u, v = np.arange(w) / w, np.arange(h) / h
        fx = 2.7 * u + 0.3 * np.sin(40 * u) + 0.05 * np.sin(900 * u) + rng.normal(0, 0.01, w)
        fy = 1.8 * v + 0.3 * np.cos(31 * v) + 0.05 * np.sin(700 * v) + rng.normal(0, 0.01, h)
        self.qx = np.rint(fx * 1000).astype(np.int32)
        self.qy = np.rint(fy * 1000).astype(np.int32)
        top = int(self.qx.max() + self.qy.max()) + 1
        lo = min(int(self.qx.min()), 0) + min(int(self.qy.min()), 0)
        self.base = -lo
        r = 10.0 ** ((np.arange(lo, top) / 1000.0) - 2.25)
        self.luts = []
        for k in range(n):
            e = r[:, None] * np.array([1.0, 0.9, 0.75]) * 2.0 ** (k - (n - 1) / 2.0)
            self.luts.append(np.clip(255 * (e / (1 + e)) ** (1 / 2.2) + 0.5, 0, 255).astype(np.uint8))

    def rows(self, k: int, a: int, b: int) -> np.ndarray:
        return self.luts[k][self.qy[a:b, None] + (self.qx[None, :] + self.base)]


def _size(mp: float):
    w = int(round((mp * 1e6 * 1.5) ** 0.5 / 16)) * 16
    return int(round(w / 1.5 / 16)) * 16, w


def speed(args) -> None:
    cv2 = _cv2()
    from hdrcl.cl.backend import get_processor
    from hdrcl.core.mertens import exposure_fusion

    h, w = _size(args.mp)
    scene = Scene(h, w, args.frames)
    frames = [scene.rows(k, 0, h) for k in range(args.frames)]
    del scene
    proc = get_processor("mertens")
    print(f"{args.frames} frames of {w}x{h} ({w * h / 1e6:.1f} MP); hdrcl on "
          f"{proc.name if proc else 'NumPy'}, OpenCV {cv2.__version__} on {cv2.getNumThreads()} threads")
    exposure_fusion([f[:64, :64] for f in frames])  # kernels built and cached before timing
    ours, theirs, ours_cpu, theirs_cpu = [], [], [], []
    for _ in range(args.repeat):  # interleaved, so that a busy machine slows both alike
        t, c = time.perf_counter(), time.process_time()
        a = exposure_fusion(frames)
        ours.append(time.perf_counter() - t)
        ours_cpu.append(time.process_time() - c)
        del a
        if not args.skip_opencv:
            t, c = time.perf_counter(), time.process_time()
            b = cv2.createMergeMertens(1.0, 1.0, 1.0).process(frames)
            theirs.append(time.perf_counter() - t)
            theirs_cpu.append(time.process_time() - c)
            del b
        print(f"  run: hdrcl {ours[-1]:.2f} s ({ours_cpu[-1]:.2f} s CPU)" +
              (f", OpenCV {theirs[-1]:.2f} s ({theirs_cpu[-1]:.2f} s CPU)" if theirs else ""), flush=True)
    med = statistics.median
    print(f"hdrcl median {med(ours):.2f} s ({med(ours_cpu):.2f} s CPU, all threads)")
    if theirs:
        print(f"OpenCV median {med(theirs):.2f} s ({med(theirs_cpu):.2f} s CPU): hdrcl is "
              f"{med(theirs) / med(ours):.1f}x faster in wall time, {med(theirs_cpu) / med(ours_cpu):.1f}x in CPU time; "
              f"{_levels(exposure_fusion(frames), cv2.createMergeMertens(1.0, 1.0, 1.0).process(frames))}")


def memory(args) -> None:
    if args.child:
        from hdrcl.core.mertens import FusionWeights, backend
        from hdrcl.core.mertens_bands import RowSource, fuse_bands, plan_bands

        h, w = _size(args.mp)
        n = args.frames
        scene = Scene(h, w, n)
        made = [0.0]

        def read(k, a, b):
            t0 = time.perf_counter()
            out = scene.rows(k, a, b)
            made[0] += time.perf_counter() - t0
            return out

        src = RowSource(h, w, 3, n, np.uint8, read)
        d, band, halo = plan_bands(src)
        t, c = time.perf_counter(), time.process_time()
        total = 0
        for _, _, rows in fuse_bands(src, FusionWeights(), backend(work=h * w * n)):
            total += int(_codes(rows[::97, ::97]).sum())
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"{n} frames of {w}x{h} ({w * h / 1e6:.1f} MP) in bands of {band} rows (halo {halo}, {d} levels "
              f"per band): {time.perf_counter() - t:.1f} s ({time.process_time() - c:.1f} s CPU, of which "
              f"{made[0]:.1f} s making the frames' rows), peak RSS {peak:.0f} MB (checksum {total})")
        return
    cmd = [sys.executable, __file__, "memory", "--child", "--mp", str(args.mp), "--frames", str(args.frames)]
    subprocess.run(cmd, check=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    c = sub.add_parser("compare")
    data = [p / "shared" / "data" for p in (ROOT.parent, ROOT.parent.parent)]
    c.add_argument("--data", default=str(next((p for p in data if p.is_dir()), data[0])))
    s = sub.add_parser("speed")
    s.add_argument("--mp", type=float, default=24.0)
    s.add_argument("--frames", type=int, default=7)
    s.add_argument("--repeat", type=int, default=3)
    s.add_argument("--skip-opencv", action="store_true")
    m = sub.add_parser("memory")
    m.add_argument("--mp", type=float, default=100.0)
    m.add_argument("--frames", type=int, default=5)
    m.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    {"compare": compare, "speed": speed, "memory": memory}[args.what](args)


if __name__ == "__main__":
    main()
