#!/usr/bin/env python3
"""Cost of the calibrated fisheye luminance chain inside a merge (issue 21).

Generates a fisheye bracket (JPEG q=95 with EXIF exposure, f-number and ISO: an
equisolid sky of known luminance with a sun and texture, black outside the lens
circle), writes the camera's curve as an hdrgen ``.rsp`` and merges it twice with the
same machinery ``merge_files`` uses (decode, fusion on OpenCL when there is a device,
absolute scale from EXIF, :func:`hdrcl.core.encode.fuse_to_file`):

* **plain**: the whole merged map in cd/m^2 written as EXR (PIZ), ``--dtype auto`` (the
  sun exceeds half floats: a second fusion pass into float, as ``merge`` does) and
  ``--dtype float`` (one pass);
* **chain**: the same fusion streamed into :class:`hdrcl.core.luminance.fisheye.LuminanceChain`
  (lens circle, resize to 1000, projection, vignetting, ND, calibration factor, VIEW=,
  vertical illuminance) and the 1000 x 1000 map written as Radiance ``.hdr``.

It prints the best of ``--repeat`` runs of each, the ratio to the faster plain merge
(target: chain within 20 %), the chain's own time (its sink and its end steps) and the vertical
illuminance against the sky's analytic value.

    python scripts/luminance_bench.py                 # 12 MP x 5
    python scripts/luminance_bench.py --mp 24 --frames 7
    python scripts/luminance_bench.py --mp 12 --frames 5 --batch 4   # also whole batch processes
"""
from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

SKY_A, SKY_B = 2000.0, 6000.0  # L = A + B cos(theta), cd/m^2
FNUMBER, ISO = 8.0, 100.0


def srgb_g() -> np.ndarray:
    """ln exposure per 8-bit code of an sRGB-decoding camera, g(128) = 0."""
    z = np.arange(256.0) / 255.0
    lin = np.where(z <= 0.04045, z / 12.92, ((z + 0.055) / 1.055) ** 2.4)
    g = np.log(np.maximum(lin, 1e-4))
    return g - g[128]


def write_set(folder: str, mp: float, frames: int, seed: int = 1):
    """The bracket's JPEG files, the lens circle and the times."""
    from hdrcl.core.radiometry import METER_K
    from hdrcl.io.ldr import write_photo

    h = int(round(math.sqrt(mp * 1e6 / 1.5)))
    w = int(round(h * 1.5))
    cx, cy, d = w / 2.0, h / 2.0, 0.96 * h
    rng = np.random.default_rng(seed)
    texture = rng.uniform(0.85, 1.15, (h // 8 + 1, w // 8 + 1)).astype(np.float32)
    times = [1.0 / 4000.0 * 4.0 ** k for k in range(frames)]
    g = srgb_g()
    lin = np.exp(g)  # relative exposure at each code
    unit = METER_K * FNUMBER ** 2 / ISO  # cd/m^2 of radiance 1 (hdrcl's absolute scale)
    paths = []
    rows = 256
    codes = [np.empty((h, w, 3), np.uint8) for _ in times]
    for y0 in range(0, h, rows):
        y1 = min(h, y0 + rows)
        yy, xx = np.mgrid[y0:y1, 0:w].astype(np.float32) + 0.5
        r = np.hypot(xx - cx, yy - cy) / d
        theta = 2.0 * np.arcsin(np.clip(math.sqrt(2.0) * r, 0.0, 1.0))
        lum = (SKY_A + SKY_B * np.cos(theta)) * texture[(yy // 8).astype(int), (xx // 8).astype(int)]
        lum = np.where(r <= 0.5, lum, 0.0)
        lum = np.where(np.hypot(xx - cx * 1.2, yy - cy * 0.8) < h / 100, 2e6, lum)  # a sun
        radiance = (lum / unit)[..., None] * np.array([1.05, 1.0, 0.9], np.float32)
        for j, t in enumerate(times):
            x = radiance * t  # relative exposure, 1 at code 128 for radiance 1 / t
            codes[j][y0:y1] = np.searchsorted(lin, x).clip(0, 255).astype(np.uint8)
    for j, t in enumerate(times):
        p = os.path.join(folder, f"fish{j:02d}.jpg")
        write_photo(p, codes[j], {"ExposureTime": float(t), "FNumber": FNUMBER,
                                  "Exif:PhotographicSensitivity": int(ISO), "Make": "hdrcl-bench", "Model": "fisheye"})
        paths.append(p)
    return paths, (cx, cy, d)


def merge(paths, response, output, chain=None, device=None, dtype="auto") -> dict:
    """merge_files' given-response path (no alignment) with an optional chain."""
    from hdrcl.core.bracket import _open_files
    from hdrcl.core.encode import fuse_to_file
    from hdrcl.core.pipeline import stream_merge
    from hdrcl.core.radiometry import ScaledSink, exif_scale
    from hdrcl.io.reader import BracketReader
    from hdrcl.io.writers import RadianceWriter

    t0 = time.perf_counter()
    paths, infos, rel = _open_files(paths, None, None)
    h, w = infos[0].height, infos[0].width
    factors = np.full(3, exif_scale(infos[0].fnumber, infos[0].iso))
    meta = {"units": "cd/m2 (approximate)"}
    source = BracketReader(paths, infos)
    if chain is not None:
        chain.bind(h, w, 3)
    spent = {"chain": 0.0}

    class Timed:
        def __init__(self, sink):
            self.sink = sink

        def write_rows(self, y0, y1, data):
            ts = time.perf_counter()
            self.sink.write_rows(y0, y1, data)
            spent["chain"] += time.perf_counter() - ts

    def open_writer(dt, half_scale, ch=None):
        m, cam, ww, hh = (meta, {}, w, h) if ch is None else ch.writer_args(meta, {})
        return RadianceWriter(output, ww, hh, 3, dtype=dt, metadata=m, camera=cam)

    def run(file_sink, first):
        sink = ScaledSink(Timed(file_sink) if chain is not None else file_sink, factors)
        counts, _ = stream_merge(source, rel, response, sink, device=device, work=h * w * len(paths))
        return counts

    try:
        writer, counts, stored = fuse_to_file(open_writer, run, output=output, dtype=dtype, reference=1.0,
                                              keep_units=True, chain=chain)
        writer.close()
    finally:
        source.close()
    return {"seconds": time.perf_counter() - t0, "chain_sink": spent["chain"], "stored": stored}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mp", type=float, default=12.0, help="megapixels per frame (default 12)")
    ap.add_argument("--frames", type=int, default=5, help="frames per bracket (default 5)")
    ap.add_argument("--repeat", type=int, default=2, help="runs of each, the best is kept (default 2)")
    ap.add_argument("--resize", type=int, default=1000)
    ap.add_argument("--work", default=None, help="folder for the generated set (default: a temporary one)")
    ap.add_argument("--batch", type=int, default=0, metavar="SETS",
                    help="also time whole 'hdrcl batch' processes over SETS such sets: plain EXR, plain .hdr "
                         "and the whole chain (.hdr)")
    args = ap.parse_args(argv)

    from hdrcl.core.luminance.fisheye import LuminanceChain
    from hdrcl.core.response import Response
    from hdrcl.cl.backend import device_name

    folder = args.work or tempfile.mkdtemp(prefix="hdrcl-lumbench-")
    os.makedirs(folder, exist_ok=True)
    t = time.perf_counter()
    paths, (cx, cy, d) = write_set(folder, args.mp, args.frames)
    print(f"generated {len(paths)} frames of {args.mp:g} MP in {time.perf_counter() - t:.1f} s ({folder})")
    rsp = os.path.join(folder, "camera.rsp")
    fit = Response(bits=8, g=np.stack([srgb_g()] * 3), knots=np.arange(256.0)).save(rsp)
    print(f"camera.rsp: orders {fit.orders}, largest ln error {max(fit.max_error):.4f} (codes 10..245)")
    response = Response.load(rsp)
    print(f"processor: {platform.processor() or platform.machine()}; device: {device_name()}")

    def chain():
        return LuminanceChain.from_options(lens_circle=(cx, cy, d), resize=args.resize,
                                           projection="equisolid-to-equidistant",
                                           vignetting="0.02,-0.15,0.05,-0.1", nd_filter="1,1,1",
                                           calibration_factor="1.0")

    runs = {"plain": [], "plain-float": [], "chain": []}
    for k in range(args.repeat):
        runs["plain"].append(merge(paths, response, os.path.join(folder, "plain.exr")))
        runs["plain-float"].append(merge(paths, response, os.path.join(folder, "plain-float.exr"), dtype="float"))
        c = chain()
        r = merge(paths, response, os.path.join(folder, "chain.hdr"), chain=c)
        r["ev"] = c.vertical_illuminance
        runs["chain"].append(r)
    best = {k: min(v, key=lambda r: r["seconds"]) for k, v in runs.items()}
    p, f, c = best["plain"], best["plain-float"], best["chain"]
    size = f"{args.mp:g} MP x {args.frames}"
    print(f"plain merge, --dtype auto ({size}, EXR {p['stored'].dtype}, {p['stored'].passes} pass(es)): "
          f"{p['seconds']:.2f} s")
    print(f"plain merge, --dtype float ({size}, one pass):                 {f['seconds']:.2f} s")
    print(f"chain merge ({size} -> {args.resize}x{args.resize} .hdr, one pass):      {c['seconds']:.2f} s "
          f"(of which the chain's sink {c['chain_sink']:.2f} s)")
    ratio = c["seconds"] / min(p["seconds"], f["seconds"])
    print(f"ratio chain / fastest plain: {ratio:.3f} ({'ok' if ratio <= 1.2 else 'MISSED'}: target <= 1.20)")
    ev_true = math.pi * SKY_A + 2.0 * math.pi * SKY_B / 3.0
    print(f"vertical illuminance: {c['ev']:.0f} lx (sky without texture and sun: {ev_true:.0f} lx; "
          "the texture averages 1, the sun adds its share)")
    if args.batch:
        batch_bench(folder, args, (cx, cy, d), rsp)
    return 0


def batch_bench(folder, args, circle, rsp) -> None:
    """Whole ``hdrcl batch`` processes (the checkout's hdrcl) over ``args.batch`` sets:
    the median of ``--repeat`` runs each, ``--force`` so that every run merges."""
    import shutil
    import statistics
    import subprocess

    shoot = os.path.join(folder, "shoot")
    for k in range(args.batch):
        sub = os.path.join(shoot, f"dome{k + 1:02d}")
        if not os.path.isdir(sub):
            os.makedirs(sub)
            write_set(sub, args.mp, args.frames, seed=k + 1)
    cx, cy, d = circle
    chain = ["--lens-circle", f"{cx},{cy},{d}", "--resize", str(args.resize), "--fisheye-projection",
             "equisolid-to-equidistant", "--vignetting", "0.02,-0.15,0.05,-0.1", "--nd-filter", "1,1,1",
             "--calibration-factor", "1.0"]
    kinds = {"plain EXR": ["--format", "exr"], "plain .hdr": ["--format", "hdr"],
             "chain .hdr": ["--format", "hdr"] + chain}
    env = dict(os.environ, PYTHONPATH=os.path.join(os.path.dirname(os.path.abspath(__file__)), "..") +
               os.pathsep + os.environ.get("PYTHONPATH", ""))
    times = {k: [] for k in kinds}
    for _ in range(args.repeat):
        for kind, extra in kinds.items():
            out = os.path.join(folder, "batch-" + kind.replace(" ", "-").replace(".", ""))
            shutil.rmtree(out, ignore_errors=True)
            cmd = [sys.executable, "-m", "hdrcl", "-q", "batch", shoot, "-o", out, "--response", rsp,
                   "--no-preview", "--force"] + extra
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, env=env)
            times[kind].append(time.perf_counter() - t0)
    med = {k: statistics.median(v) for k, v in times.items()}
    size = f"{args.batch} sets of {args.mp:g} MP x {args.frames}"
    for kind, s in med.items():
        print(f"hdrcl batch, {kind} ({size}): {s:.2f} s (median of {args.repeat})")
    ratio = med["chain .hdr"] / min(med["plain EXR"], med["plain .hdr"])
    print(f"batch ratio chain / faster plain: {ratio:.3f} ({'ok' if ratio <= 1.2 else 'MISSED'}: target <= 1.20)")


if __name__ == "__main__":
    sys.exit(main())
