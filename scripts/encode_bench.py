#!/usr/bin/env python3
"""The encode stage against OpenImageIO's own encode of the same data (issue 26).

A float32 radiance map of ``--mp`` megapixels (``scripts/bench.py``'s scene, with 1 %
noise, capped at 40000 in the file's units, values relative to 1 s, median about 60) is written as the merge writes it:
strips of 256 K pixels (the fusion's strips) through :func:`hdrcl.core.encode.fuse_to_file`
(reference exposure 2^-6, so the file's values have a median of about 1: the range
measurement, the half/float decision, the scale, the conversion and the encoder), and,
as the floor, by OpenImageIO alone from data already prepared (scaled and converted to
half for the EXR, scaled float32 for the ``.hdr``) in one ``write_image`` call, on all
cores, as ``../shared/tools/io_floor.py`` does. Rounds alternate (hdrcl, floor); the
medians of wall and process CPU seconds are printed, with hdrcl / floor, and the
machine's load (``/proc/loadavg``: the machine may be shared).

Each strip is copied into one reused buffer before it is handed over (in a merge the
fusion has just written it, so it is in cache); the time of these copies alone is
measured too (``copy``) and is part of the hdrcl figures.

    python scripts/encode_bench.py                      # 12 and 24 MP, .exr and .hdr, 5 rounds
    python scripts/encode_bench.py --mp 12 --formats exr --runs 9 --json out.json
"""
from __future__ import annotations

import argparse
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

import benchbrackets  # noqa: E402  (scripts/benchbrackets.py: bench.py's generated scene)
import benchlib  # noqa: E402  (scripts/benchlib.py: loadavg)

REFERENCE = 2.0 ** -6
CAP = 40000.0  # the brightest value in the file: half floats hold it (a first pass is enough)
STRIP_PIXELS = 1 << 18



def radiance_map(mp: float, seed: int = 3, cap: float = CAP) -> np.ndarray:
    """Float32 ``(H, W, 3)`` radiance (relative to 1 s) of ``mp`` megapixels."""
    w, h = benchbrackets.dims(mp)
    scene = benchbrackets.Scene(w, h, seed=seed)
    rng = np.random.default_rng(seed)
    out = np.empty((h, w, 3), np.float32)
    for r0, r1 in scene.strips():
        s = np.power(np.float32(10), scene.log10_strip(r0, r1))
        s *= 1 + np.float32(0.01) * rng.standard_normal(s.shape, np.float32)
        np.minimum(s, np.float32(cap), out=s)
        out[r0:r1] = s / np.float32(REFERENCE)
    return out


def _strips(img: np.ndarray, sink, buf: np.ndarray) -> None:
    h, w, _ = img.shape
    rows = buf.shape[0]
    for y0 in range(0, h, rows):
        y1 = min(h, y0 + rows)
        strip = buf[:y1 - y0]
        np.copyto(strip, img[y0:y1])
        sink.write_rows(y0, y1, strip)


def hdrcl_encode(img: np.ndarray, path: str) -> dict:
    from hdrcl.core.encode import fuse_to_file, radiance_opener

    h, w, nch = img.shape
    buf = np.empty((max(1, STRIP_PIXELS // w), w, nch), np.float32)
    opener = radiance_opener(path, w, h, nch, {}, {}, compression="piz", timestamp=None, colorspace="rec709")

    def run(sink, first):
        _strips(img, sink, buf)
        return {}

    writer, _, stored = fuse_to_file(opener, run, output=path, dtype="auto", reference=REFERENCE, keep_units=False)
    writer.close()
    return {"dtype": stored.dtype, "passes": stored.passes}


def copy_only(img: np.ndarray, path: str) -> dict:
    class Null:
        def write_rows(self, y0, y1, data):
            pass

    h, w, nch = img.shape
    _strips(img, Null(), np.empty((max(1, STRIP_PIXELS // w), w, nch), np.float32))
    return {}


def oiio_encode(prepared: np.ndarray, path: str) -> dict:
    import OpenImageIO as oiio

    h, w, nch = prepared.shape
    fmt = "half" if prepared.dtype == np.float16 else "float"
    spec = oiio.ImageSpec(w, h, nch, fmt)
    if path.endswith(".exr"):
        spec.attribute("compression", "piz")
    out = oiio.ImageOutput.create(path)
    if not (out.open(path, spec) and out.write_image(prepared) and out.close()):
        raise SystemExit(f"{path}: OpenImageIO failed: {out.geterror()}")
    return {}


def timed(fn, *args) -> tuple:
    c, t = time.process_time(), time.perf_counter()
    fn(*args)
    return time.perf_counter() - t, time.process_time() - c


def measure(mp: float, fmt: str, runs: int, folder: str, cap: float = CAP) -> dict:
    import OpenImageIO as oiio

    img = radiance_map(mp, cap=cap)
    scaled = img * np.float32(REFERENCE)
    prepared = scaled.astype(np.float16) if fmt == "exr" else scaled
    del scaled
    h, w, _ = img.shape
    path = os.path.join(folder, f"bench.{fmt}")
    floor_path = os.path.join(folder, f"floor.{fmt}")
    figures = {"hdrcl": [], "floor": [], "copy": []}
    info = hdrcl_encode(img, path)  # warm-up: imports, pages, thread pools
    oiio_encode(prepared, floor_path)
    for _ in range(runs):
        figures["hdrcl"].append(timed(hdrcl_encode, img, path))
        figures["floor"].append(timed(oiio_encode, prepared, floor_path))
        figures["copy"].append(timed(copy_only, img, path))
    check = oiio.ImageBuf(path)
    got = check.get_pixels(oiio.FLOAT)
    want = oiio.ImageBuf(floor_path).get_pixels(oiio.FLOAT)
    same = bool(np.array_equal(got, want)) if fmt == "exr" else None
    res = {"mp": round(w * h / 1e6, 1), "size": f"{w}x{h}", "format": fmt, "runs": runs, "stored": info,
           "file_equals_floor": same, "bytes": os.path.getsize(path), "floor_bytes": os.path.getsize(floor_path)}
    for key, vals in figures.items():
        res[f"{key}_wall_s"] = round(statistics.median(v[0] for v in vals), 4)
        res[f"{key}_cpu_s"] = round(statistics.median(v[1] for v in vals), 4)
    res["wall_ratio"] = round(res["hdrcl_wall_s"] / res["floor_wall_s"], 3)
    res["cpu_ratio"] = round(res["hdrcl_cpu_s"] / res["floor_cpu_s"], 3)
    # without the bench's own strip copies (in a merge the fusion has just written the strip)
    res["cpu_ratio_less_copies"] = round((res["hdrcl_cpu_s"] - res["copy_cpu_s"]) / res["floor_cpu_s"], 3)
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mp", type=float, nargs="+", default=[12, 24])
    ap.add_argument("--formats", nargs="+", default=["exr", "hdr"], choices=["exr", "hdr"])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--json", help="also write the figures here")
    ap.add_argument("--cap", type=float, default=CAP, help="brightest file value (beyond 65504: float, two passes)")
    args = ap.parse_args(argv)
    results = []
    import hdrcl

    print(f"hdrcl from {os.path.dirname(hdrcl.__file__)}  load before: {benchlib.loadavg()}  cpus: {os.cpu_count()}")
    with tempfile.TemporaryDirectory(prefix="hdrcl-encode-bench-") as folder:
        for mp in args.mp:
            for fmt in args.formats:
                r = measure(mp, fmt, args.runs, folder, args.cap)
                r["load"] = benchlib.loadavg()
                results.append(r)
                print(f"{r['size']} {fmt}: hdrcl {r['hdrcl_wall_s']:.3f} s wall {r['hdrcl_cpu_s']:.3f} s CPU | "
                      f"OpenImageIO alone {r['floor_wall_s']:.3f} s wall {r['floor_cpu_s']:.3f} s CPU | "
                      f"ratio wall {r['wall_ratio']:.2f} CPU {r['cpu_ratio']:.2f} ({r['cpu_ratio_less_copies']:.2f} less copies) | "
                      f"strip copies "
                      f"{r['copy_wall_s']:.3f} s | same pixels {r['file_equals_floor']} | load {r['load']}",
                      flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
