#!/usr/bin/env python3
"""The floors a batch is measured against, each in its own process (``shoot_bench.py``
starts them; ``python scripts/floors.py KIND SPEC.json`` prints one JSON line).

* ``decode``: every frame decoded once (OpenImageIO, native uint8), nothing else, on
  ``os.cpu_count()`` threads;
* ``encode``: each of a batch's outputs read back, then encoded once more in its own
  format (pixel type, EXR compression) with OpenImageIO, one output after another, each
  on all cores (OpenEXR compresses blocks in parallel);
* ``fusion``: each set's frames decoded (not timed), then fused once on the OpenCL device
  (``FusionProcessor.fuse``: strips to the device, the kernel, the float32 map back), as
  the merge engine does, with the default weight and a plain log response (the response's
  values do not change the work).

Each reports the wall seconds and the CPU seconds (``time.process_time``: every thread of
the process, the OpenCL runtime's included) of the timed part only, so the floors add up
to what a batch cannot do with less: decode + encode + fusion.
"""
from __future__ import annotations

import json
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)

import benchlib  # noqa: E402  (scripts/benchlib.py: read_frame, the checkout on the path)


def outputs(folder: str) -> list:
    """The radiance maps a batch wrote under ``folder`` (.exr and .hdr), sorted."""
    found = []
    for root, _, names in os.walk(folder):
        found += [os.path.join(root, n) for n in names if n.lower().endswith((".exr", ".hdr"))]
    return sorted(found)


def decode(spec: dict) -> dict:
    """The decode floor of ``spec["files"]``."""
    from multiprocessing.pool import ThreadPool

    import OpenImageIO  # noqa: F401  (imported before the clock starts)

    files = spec["files"]
    threads = os.cpu_count() or 1
    c0, t0 = time.process_time(), time.perf_counter()
    with ThreadPool(threads) as pool:
        pixels = sum(pool.map(lambda p: benchlib.read_frame(p).size // 3, files, chunksize=1))
    return {"decode_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0, "threads": threads,
            "frames": len(files), "megapixels": pixels / 1e6}


def encode(spec: dict) -> dict:
    """The encode floor of the outputs under ``spec["dir"]``."""
    import OpenImageIO as oiio

    threads = os.cpu_count() or 1
    maps = []
    for p in outputs(spec["dir"]):
        inp = oiio.ImageInput.open(p)
        if inp is None:
            raise RuntimeError(f"{p}: {oiio.geterror()}")
        sp = inp.spec()
        maps.append((p, sp, inp.read_image(sp.format)))
        inp.close()
    oiio.attribute("threads", threads)
    oiio.attribute("exr_threads", threads)
    kinds = set()
    with tempfile.TemporaryDirectory(dir=spec.get("tmp")) as tmp:
        c0, t0 = time.process_time(), time.perf_counter()
        for k, (p, sp, px) in enumerate(maps):
            dst = os.path.join(tmp, f"{k}{os.path.splitext(p)[1]}")
            out_spec = oiio.ImageSpec(sp.width, sp.height, sp.nchannels, sp.format)
            comp = sp.get_string_attribute("compression")
            if comp:
                out_spec.attribute("compression", comp)
            kinds.add(f"{os.path.splitext(p)[1].lower()} {sp.format} {comp or ''}".strip())
            o = oiio.ImageOutput.create(dst)
            if o is None or not o.open(dst, out_spec) or not o.write_image(px) or not o.close():
                raise RuntimeError(f"{dst}: encode failed ({oiio.geterror()})")
        encode_s, cpu_s = time.perf_counter() - t0, time.process_time() - c0
    return {"encode_s": encode_s, "cpu_s": cpu_s, "threads": threads, "outputs": len(maps),
            "output_mp": sum(sp.width * sp.height for _, sp, _ in maps) / 1e6, "formats": sorted(kinds)}


def fusion(spec: dict) -> dict:
    """The fusion floor of ``spec["sets"]`` (each ``{"files": [...], "times": [...]}``)."""
    from concurrent.futures import ThreadPoolExecutor

    from hdrcl.cl.fusion import FusionProcessor
    from hdrcl.core.weights import DEFAULT_WEIGHT, weight_table

    proc = FusionProcessor(device=spec.get("device"))
    wts = weight_table(256, DEFAULT_WEIGHT)
    wall = cpu = 0.0
    pixels = 0
    warm = True
    with ThreadPoolExecutor(os.cpu_count() or 1) as pool:
        for s in spec["sets"]:
            frames = list(pool.map(benchlib.read_frame, s["files"]))
            order = np.argsort(np.asarray(s["times"], np.float64), kind="stable")
            frames = [frames[i] for i in order]
            log_t = np.log(np.asarray(s["times"], np.float64)[order])
            nch = frames[0].shape[2]
            z = np.arange(256, dtype=np.float64)
            tables = np.tile(np.log((z + 0.5) / 256.0), (nch, 1))
            if warm:  # the kernel build and first buffers: not part of the floor
                proc.fuse([f[:8] for f in frames], log_t, tables, wts)
                warm = False
            out = np.empty(frames[0].shape, np.float32)
            c0, t0 = time.process_time(), time.perf_counter()
            proc.fuse(frames, log_t, tables, wts, out=out)
            wall += time.perf_counter() - t0
            cpu += time.process_time() - c0
            pixels += frames[0].shape[0] * frames[0].shape[1] * len(frames)
            del frames, out
    return {"fusion_s": wall, "cpu_s": cpu, "device": proc.ctx.name, "sets": len(spec["sets"]),
            "megapixels": pixels / 1e6}


KINDS = {"decode": decode, "encode": encode, "fusion": fusion}


def main(argv=None) -> int:
    args = sys.argv[1:] if argv is None else list(argv)
    if len(args) != 2 or args[0] not in KINDS:
        raise SystemExit(f"usage: floors.py {{{','.join(KINDS)}}} SPEC.json")
    benchlib.ensure_importable()
    with open(args[1]) as f:
        print(json.dumps(KINDS[args[0]](json.load(f))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
