#!/usr/bin/env python3
"""Fusion throughput against JPEG decoding of the same frames (issue 26, item 2).

Generates (once; cached in ``--workdir``) one bracket of camera-sized JPEGs
(``scripts/bench.py``'s scene and S-shaped camera, JPEG q92, frames two stops apart),
then measures in alternating rounds:

* **decode**: every frame decoded once with OpenImageIO into uint8, one frame per thread
  on ``os.cpu_count()`` threads (as ``../shared/tools/io_floor.py`` does);
* **fuse**: the decoded frames through ``FusionPlan.fuse_strip`` strip after strip, as
  the batch engine called it before issue 33 (copies to the device, the kernels, the fix-up pass where
  the fast path flags values, the float32 result copied back, the clip mask);
* **fuse, pipelined**: the same strips through ``FusionPlan.pipeline()`` (up to
  ``PIPELINE_DEPTH`` strips in flight, read-backs non-blocking), as the streaming merge
  calls it since issue 33;
* **kernel**: the ``fuse`` kernel alone on data already on the device (OpenCL profiling
  events, ``hdrcl.cl.fusion.profile_kernel``).

and prints frame-pixels per second (frames x pixels / seconds) for each, medians of the
runs, and fuse / decode per round (median): the issue's target is fuse >= 2x decode.

    python scripts/fusion_bench.py                          # 12 MP x 7, 5 runs, default driver
    PYOPENCL_CTX=pocl python scripts/fusion_bench.py --mp 24 --frames 7 --runs 7
    python scripts/fusion_bench.py --driver intel-cpu --json out.json
    python scripts/fusion_bench.py --folder SHOOT/DCIM/100CANON   # a bracket of JPEGs with EXIF times
"""
from __future__ import annotations

import argparse
import concurrent.futures
import json
import os
import statistics
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)

import benchbrackets  # noqa: E402  (scripts/benchbrackets.py: bench.py's generated brackets)
import benchlib  # noqa: E402  (scripts/benchlib.py: loadavg)


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    import platform

    return platform.processor() or "unknown"



def decode_all(paths, threads: int):
    """Every frame decoded once (uint8), one frame per thread."""
    import OpenImageIO as oiio

    def one(p):
        inp = oiio.ImageInput.open(p)
        if inp is None:
            raise RuntimeError(f"{p}: {oiio.geterror()}")
        try:
            return np.asarray(inp.read_image(0, 0, 0, inp.spec().nchannels, "uint8"))
        finally:
            inp.close()

    with concurrent.futures.ThreadPoolExecutor(threads) as pool:
        return list(pool.map(one, paths))


def folder_bracket(folder: str, first: int = 0):
    """Paths and EXIF exposure times of the JPEGs in ``folder`` (one bracket; the first
    ``first`` in name order if given)."""
    import OpenImageIO as oiio

    paths = sorted(os.path.join(folder, n) for n in os.listdir(folder) if n.lower().endswith((".jpg", ".jpeg")))
    paths = paths[:first] if first > 0 else paths
    times = []
    for p in paths:
        inp = oiio.ImageInput.open(p)
        if inp is None:
            raise SystemExit(f"{p}: {oiio.geterror()}")
        t = inp.spec().getattribute("ExposureTime")
        inp.close()
        if not t:
            raise SystemExit(f"{p}: no EXIF ExposureTime")
        times.append(float(t))
    if len(paths) < 2:
        raise SystemExit(f"{folder}: fewer than 2 JPEGs")
    return paths, times


def camera_tables(levels: int = 256) -> np.ndarray:
    """g of the generating camera per channel (ends clipped: a logistic is infinite there)."""
    cam = benchbrackets.camera()
    z = np.clip(np.arange(levels, dtype=np.float64), 0.5, levels - 1.5)
    return np.stack([cam.g(z, c) for c in range(3)])


def fuse_strips(plan, frames, out, mask) -> None:
    """The frames through the plan strip by strip, as the batch engine calls it."""
    h = frames[0].shape[0]
    for r0 in range(0, h, plan.rows):
        r1 = min(h, r0 + plan.rows)
        plan.fuse_strip([f[r0:r1] for f in frames], None, out[r0:r1], clip_mask=mask[r0:r1])


def fuse_pipelined(plan, frames, out, mask) -> None:
    """The same strips through the plan's pipeline (``hdrcl.cl.fusion.StripPipeline``:
    up to ``plan.depth`` in flight, read-backs non-blocking), as the streaming merge
    calls it since issue 33."""
    h = frames[0].shape[0]
    with plan.pipeline() as pipe:
        for r0 in range(0, h, plan.rows):
            r1 = min(h, r0 + plan.rows)
            pipe.put([f[r0:r1] for f in frames], None, out[r0:r1], mask[r0:r1])
        pipe.drain()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mp", type=float, default=12.0, help="megapixels per frame (default 12)")
    ap.add_argument("--frames", type=int, default=7, help="frames in the bracket (default 7)")
    ap.add_argument("--runs", type=int, default=5, help="measured rounds (default 5); medians are printed")
    ap.add_argument("--driver", default=None, help="OpenCL device (as hdrcl's --device; default PYOPENCL_CTX, "
                    "else hdrcl's choice)")
    ap.add_argument("--weight", default="gaussian", choices=("hat", "gaussian"))
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "hdrcl-fusion-bench"))
    ap.add_argument("--no-kernel", action="store_true", help="skip the kernel-alone figure")
    ap.add_argument("--folder", default=None, help="fuse the JPEGs of this folder (one bracket, EXIF exposure "
                    "times) instead of a generated one; the response is then the generating camera's of "
                    "scripts/bench.py, which only sets the tables' values, not the work")
    ap.add_argument("--first", type=int, default=0, help="with --folder: its first N JPEGs in name order (a shoot "
                    "folder holds several sets)")
    ap.add_argument("--json", default=None, help="also write the figures to this file")
    args = ap.parse_args(argv)

    from hdrcl.cl.fusion import FusionProcessor, profile_kernel
    from hdrcl.core.weights import weight_table

    if args.folder:
        paths, times = folder_bracket(args.folder, args.first)
        times = np.asarray(times, np.float64)
    else:
        info = benchbrackets.ensure_set(args.workdir, args.mp, args.frames)
        paths, times = info["paths"], np.asarray(info["times"], np.float64)
    threads = os.cpu_count() or 1
    load0 = benchlib.loadavg()
    frames = decode_all(paths, threads)  # warm-up: OIIO's JPEG plugin, page cache
    h, w, c = frames[0].shape
    order = np.argsort(times, kind="stable")
    frames = [frames[i] for i in order]
    log_t = np.log(times[order])
    tables = camera_tables()
    wts = weight_table(256, args.weight)
    proc = FusionProcessor(device=args.driver)
    plan = proc.plan(len(frames), w, c, np.uint8, log_t, tables, wts, False)
    out = np.empty((h, w, c), np.float32)
    mask = np.empty((h, w), np.uint8)
    fuse_strips(plan, frames, out, mask)  # warm-up: buffers, first-touch of out
    fuse_pipelined(plan, frames, out, mask)
    fpx = len(frames) * h * w  # frame pixels
    rows = {"decode": [], "fuse": [], "kernel": [], "ratio": [], "decode_cpu": [], "fuse_cpu": [], "ratio_cpu": [],
            "pipe": [], "pipe_cpu": [], "pipe_ratio": [], "pipe_ratio_cpu": []}
    for _ in range(max(1, args.runs)):
        c0, t0 = time.process_time(), time.perf_counter()
        decoded = decode_all(paths, threads)
        rows["decode"].append(time.perf_counter() - t0)
        rows["decode_cpu"].append(max(time.process_time() - c0, 1e-6))  # the clock ticks coarsely
        del decoded
        c0, t0 = time.process_time(), time.perf_counter()
        fuse_strips(plan, frames, out, mask)
        rows["fuse"].append(time.perf_counter() - t0)
        rows["fuse_cpu"].append(max(time.process_time() - c0, 1e-6))
        rows["ratio"].append(rows["decode"][-1] / rows["fuse"][-1])
        rows["ratio_cpu"].append(rows["decode_cpu"][-1] / rows["fuse_cpu"][-1])
        c0, t0 = time.process_time(), time.perf_counter()
        fuse_pipelined(plan, frames, out, mask)
        rows["pipe"].append(time.perf_counter() - t0)
        rows["pipe_cpu"].append(max(time.process_time() - c0, 1e-6))
        rows["pipe_ratio"].append(rows["decode"][-1] / rows["pipe"][-1])
        rows["pipe_ratio_cpu"].append(rows["decode_cpu"][-1] / rows["pipe_cpu"][-1])
        if not args.no_kernel:
            rows["kernel"].append(profile_kernel(proc, frames, log_t, tables, wts, repeats=1))
    flagged = float(np.count_nonzero(mask)) / mask.size
    med = {k: statistics.median(v) for k, v in rows.items() if v}
    res = {
        "cpu": cpu_model(), "cpus": threads, "driver": proc.ctx.name,
        "loadavg_before": load0, "loadavg_after": benchlib.loadavg(),
        "frames": len(frames), "size": f"{w}x{h}", "frame_mp": round(fpx / 1e6, 1), "runs": args.runs,
        "weight": args.weight, "strip_rows": plan.rows,
        "decode_s": med["decode"], "fuse_s": med["fuse"], "kernel_s": med.get("kernel"),
        "decode_mp_s": fpx / med["decode"] / 1e6, "fuse_mp_s": fpx / med["fuse"] / 1e6,
        "kernel_mp_s": fpx / med["kernel"] / 1e6 if rows["kernel"] else None,
        "fuse_over_decode": med["ratio"], "clip_mask_pixels": flagged,
        "decode_cpu_s": med["decode_cpu"], "fuse_cpu_s": med["fuse_cpu"],
        "decode_mp_per_cpu_s": fpx / med["decode_cpu"] / 1e6, "fuse_mp_per_cpu_s": fpx / med["fuse_cpu"] / 1e6,
        "fuse_over_decode_cpu": med["ratio_cpu"],
        "pipelined_s": med["pipe"], "pipelined_cpu_s": med["pipe_cpu"], "pipelined_mp_s": fpx / med["pipe"] / 1e6,
        "pipelined_over_decode": med["pipe_ratio"], "pipelined_over_decode_cpu": med["pipe_ratio_cpu"],
        "all": rows,
    }
    print(f"cpu: {res['cpu']} ({threads} cpus); OpenCL: {res['driver']}")
    print(f"load average before/after: {res['loadavg_before']} / {res['loadavg_after']}")
    print(f"bracket: {len(frames)} x {w}x{h} JPEG ({res['frame_mp']} frame-MP"
          + (f", {args.folder}" if args.folder else ", generated") + f"), weight {args.weight}, "
          f"strips of {plan.rows} rows, {args.runs} runs (medians)")
    print(f"  {'':34s} {'wall':>9s}  {'rate':>12s}  {'CPU':>9s}  {'per CPU-second':>18s}")
    for key, label in (("decode", "decode (OIIO, %d threads)" % threads), ("fuse", "fuse (fuse_strip per strip)"),
                       ("pipe", "fuse (pipelined, depth %d)" % plan.depth)):
        print(f"  {label:34s} {med[key]:7.3f} s  {fpx / med[key] / 1e6:7.0f} MP/s  {med[key + '_cpu']:7.3f} s"
              f"  {fpx / med[key + '_cpu'] / 1e6:7.0f} MP/CPU-s")
    if rows["kernel"]:
        print(f"  {'fuse kernel alone (events)':34s} {med['kernel']:7.3f} s  {res['kernel_mp_s']:7.0f} MP/s")
    print(f"  fuse / decode rate (median of runs): {res['fuse_over_decode']:.2f}x wall, "
          f"{res['fuse_over_decode_cpu']:.2f}x per CPU-second  (target >= 2x)")
    print(f"  pipelined fuse / decode rate: {res['pipelined_over_decode']:.2f}x wall, "
          f"{res['pipelined_over_decode_cpu']:.2f}x per CPU-second")
    print("  (per CPU-second: the rates with other processes' share of the cores taken out; on a")
    print("   shared machine the wall figures move with the load, the CPU ones much less)")
    print(f"  pixels with a clip flag: {100 * flagged:.1f} %")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
