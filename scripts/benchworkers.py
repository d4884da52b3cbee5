#!/usr/bin/env python3
"""The in-process measurements of ``scripts/bench.py``, each run in a process of its own
(``bench.py --worker KIND SPEC``): decode-only, the response solve, the fusion kernel
alone and encode-only on one set (:func:`worker_inproc`), and memory-copy bandwidth
(:func:`worker_copy`). Imports no other script but ``benchlib`` and ``benchbrackets``.
"""
from __future__ import annotations

import concurrent.futures
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)

from benchlib import cpu_seconds, read_frame  # noqa: E402
from benchbrackets import bracket_arrays  # noqa: E402


def _best(fn, repeat: int, out: dict = None, key: str = None):
    """Best wall time of ``repeat`` calls and the last result.

    With ``out`` and ``key``: ``out[key + "_s"]`` (best), ``out[key + "_all"]`` and
    ``out[key + "_background"]`` (CPU other processes used during the best call, as a
    fraction of the machine) are filled in.
    """
    import resource

    times, bgs, result = [], [], None
    for _ in range(max(1, repeat)):
        result = None  # free the previous result before the next run
        c0, r0 = cpu_seconds(), resource.getrusage(resource.RUSAGE_SELF)
        t0 = time.perf_counter()
        result = fn()
        dt = time.perf_counter() - t0
        c1, r1 = cpu_seconds(), resource.getrusage(resource.RUSAGE_SELF)
        times.append(dt)
        if c0 and c1 and dt >= 0.25:  # /proc/stat counts in 10 ms ticks: too coarse below
            own = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
            bgs.append(max(0.0, c1[0] - c0[0] - own) / (dt * (os.cpu_count() or 1)))
        else:
            bgs.append(None)
    i = int(np.argmin(times))
    if out is not None:
        out[key + "_s"], out[key + "_all"] = times[i], times
        if bgs[i] is not None:
            out[key + "_background"] = bgs[i]
    return times[i], times, result


def _exr_encoder(path: str, radiance: np.ndarray):
    """A function writing ``radiance`` as EXR (half, zip) the way hdrcl merge does, and
    a description of it: strip by strip through ``RadianceWriter`` where hdrcl has it,
    else whole through ``write_radiance``, else plain OpenImageIO."""
    h, w, c = radiance.shape
    try:
        from hdrcl.io.writers import RadianceWriter
    except ImportError:
        RadianceWriter = None
    if RadianceWriter is not None:
        try:
            from hdrcl.cl.processing import STRIP_PIXELS
        except ImportError:
            STRIP_PIXELS = 1 << 20
        rows = max(1, STRIP_PIXELS // w)

        def encode():
            with RadianceWriter(path, w, h, c, dtype="half", compression="zip") as wr:
                for y0 in range(0, h, rows):
                    wr.write_rows(y0, min(h, y0 + rows), radiance[y0:y0 + rows])
        return encode, f"hdrcl.io.writers.RadianceWriter, strips of {rows} rows (half, zip)"
    try:
        from hdrcl.io.writers import write_radiance

        return (lambda: write_radiance(path, radiance, dtype="half", compression="zip"),
                "hdrcl.io.writers.write_radiance (half, zip)")
    except ImportError:
        import OpenImageIO as oiio

        def encode():
            spec = oiio.ImageSpec(w, h, c, "half")
            spec.attribute("compression", "zip")
            o = oiio.ImageOutput.create(path)
            o.open(path, spec)
            o.write_image(radiance)
            o.close()
        return encode, "OpenImageIO ImageOutput (half, zip)"


def worker_inproc(spec: dict) -> dict:
    """Decode-only, response solve, fusion kernel alone, encode-only, on one set."""
    paths, times, repeat = spec["paths"], spec["times"], spec["repeat"]
    out = {}
    read_frame(paths[0])  # load OIIO and its JPEG plugin outside the timing
    workers = max(1, min(len(paths), os.cpu_count() or 1))
    _, _, frames = _best(lambda: [read_frame(p) for p in paths], repeat, out, "decode_serial")
    frames = None

    def parallel():
        with concurrent.futures.ThreadPoolExecutor(max_workers=workers) as pool:
            return list(pool.map(read_frame, paths))

    _, _, frames = _best(parallel, repeat, out, "decode_parallel")
    out["decode_threads"] = workers
    h, w, c = frames[0].shape

    from hdrcl.core.solve import recover_response

    resp = recover_response(frames, times)  # warm-up (scipy imports, first allocations)
    _, _, resp = _best(lambda: recover_response(frames, times), repeat, out, "solve_8bit")
    out["solve_8bit_samples"] = int(resp.samples)

    radiance = None
    try:
        from hdrcl.core.fusion import fuse_frames

        res = fuse_frames(frames, times, resp)  # warm-up: device, program build, buffers
        kr = max(3, repeat)
        _, _, res = _best(lambda: fuse_frames(frames, times, resp), kr, out, "kernel")
        out["kernel_backend"] = res.backend
        nbytes = len(frames) * h * w * c * frames[0].dtype.itemsize + h * w * c * 4
        out["kernel_bytes"] = nbytes
        # Host path: strips copied to the device and back, counts read, fix-up pass.
        out["kernel_host_s"] = out["kernel_s"]
        out["kernel_host_gbps"] = nbytes / out["kernel_s"] / 1e9
        radiance = res.radiance
        if res.backend == "opencl":
            # The kernel alone: data already on the device, timed by profiling events.
            import numpy as _np

            from hdrcl.cl.backend import get_processor
            from hdrcl.cl.fusion import profile_kernel
            from hdrcl.core.weights import weight_table

            order = _np.argsort(times)
            out["kernel_s"] = profile_kernel(get_processor("fusion"), [frames[i] for i in order],
                                             _np.log(_np.asarray(times, _np.float64)[order]), resp.tables(),
                                             weight_table(resp.levels), repeats=kr)
        out["kernel_gbps"] = nbytes / out["kernel_s"] / 1e9
    except Exception as exc:  # an internal API under change must not stop the benchmark
        out["kernel_error"] = f"{type(exc).__name__}: {exc}"
    frames = None
    if radiance is None:  # stand-in content of the right size for the encode figure
        radiance = np.repeat(np.logspace(-2, 2, w, dtype=np.float32)[None, :, None], h, 0).repeat(c, 2)

    enc_path = os.path.join(spec["tmpdir"], "encode-only.exr")
    encode, out["encode_via"] = _exr_encoder(enc_path, radiance)
    encode()  # warm-up: OpenEXR plugin
    _best(encode, repeat, out, "encode_exr")
    out["encode_exr_bytes"] = os.path.getsize(enc_path)
    os.remove(enc_path)
    radiance = None

    if spec.get("solve16"):
        f16 = bracket_arrays(w, h, len(paths), seed=spec.get("seed", 1), bits=16)
        recover_response(f16, times)
        _, _, r16 = _best(lambda: recover_response(f16, times), repeat, out, "solve_16bit")
        out["solve_16bit_samples"] = int(r16.samples)
        out["solve_16bit_size"] = f"{w}x{h} x {len(paths)}"
    return out


def worker_copy(spec: dict) -> dict:
    """Memory-copy bandwidth: NumPy (1 and 2 threads) and an OpenCL buffer-to-buffer copy.

    Bandwidth counts bytes read plus bytes written (2 x buffer size, the STREAM "copy"
    convention), like the kernel figure (frames in + radiance out).
    """
    n = int(spec["mib"]) << 20
    reps = int(spec.get("reps", 5))
    out = {"buffer_mib": n >> 20, "convention": "bytes read + bytes written"}
    src = np.empty(n, np.uint8)
    src[:] = 1
    dst = np.empty_like(src)
    dst[:] = 0
    t, _, _ = _best(lambda: np.copyto(dst, src), reps, out, "numpy_1thread")
    out["numpy_1thread_gbps"] = 2 * n / t / 1e9
    half = n // 2
    pool = concurrent.futures.ThreadPoolExecutor(max_workers=2)

    def two():
        list(pool.map(lambda s: np.copyto(dst[s], src[s]), (slice(0, half), slice(half, n))))
    two()
    t, _, _ = _best(two, reps, out, "numpy_2threads")
    pool.shutdown()
    out["numpy_2threads_gbps"] = 2 * n / t / 1e9
    src = dst = None
    try:
        import pyopencl as cl

        try:
            from hdrcl.cl.context import get_context

            dctx = get_context()
            ctx, queue, name = dctx.context, dctx.queue, dctx.name
        except ImportError:
            ctx = cl.create_some_context(interactive=False)
            queue = cl.CommandQueue(ctx)
            name = ctx.devices[0].name
        a = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, n)
        b = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, n)
        cl.enqueue_fill_buffer(queue, a, np.uint8(1), 0, n)
        cl.enqueue_fill_buffer(queue, b, np.uint8(0), 0, n)
        queue.finish()

        def clcopy():
            cl.enqueue_copy(queue, b, a)
            queue.finish()
        clcopy()
        t, _, _ = _best(clcopy, reps, out, "opencl")
        out["opencl_gbps"] = 2 * n / t / 1e9
        out["opencl_device"] = name
        dev = ctx.devices[0]
        out["opencl_driver"] = (f"{dev.platform.name} {dev.platform.version.strip()}, "
                                f"device {dev.version.strip()}, driver {dev.driver_version.strip()}")
    except Exception as exc:
        out["opencl_error"] = f"{type(exc).__name__}: {exc}"
    cands = {k: v for k, v in out.items() if k.endswith("_gbps")}
    out = {k: v for k, v in out.items() if not k.endswith("_all")}
    out["reference"] = max(cands, key=cands.get)
    out["reference_gbps"] = cands[out["reference"]]
    return out
