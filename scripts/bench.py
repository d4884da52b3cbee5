#!/usr/bin/env python3
"""hdrcl benchmark: speed, bandwidth and memory against the targets of issues 4 and 11.

One command generates its own inputs (textured JPEG brackets, quality 92, with EXIF
exposure data), then measures on the same files, in one run:

* decode-only (OpenImageIO, serial and in parallel threads) and encode-only (EXR, half,
  zip: hdrcl's default);
* ``hdrcl merge`` end to end (CLI processes; response given, and calibrating), with the
  peak resident memory of every ``hdrcl`` process;
* OpenCV's pipeline (imread, CalibrateDebevec, MergeDebevec, imwrite), both tools
  writing Radiance ``.hdr`` (OpenCV's PyPI wheel writes no EXR);
* the fusion kernel alone in bytes per second, beside memory-copy bandwidth (NumPy and
  OpenCL buffer copies) measured in the same run;
* the response solve (8- and 16-bit), a second small ``hdrcl merge`` process (warm
  caches), and ``hdrcl batch`` throughput (megapixels per second) against a loop of
  OpenCV merges over the same sets.

It prints every figure with its target (ok / MISSED by how much) and writes JSON.

    python scripts/bench.py                      # 24 MP x 7 and 100 MP x 5 (several minutes)
    python scripts/bench.py --quick              # 2 MP x 5 and 4 MP x 5 (a minute or two)
    python scripts/bench.py --sizes 24x7,100x5 --work /tmp/hdrcl-bench --json out.json

OpenCV is an optional benchmark dependency (``pip install opencv-python-headless``);
without it, or with ``--skip-opencv``, that comparison is reported as not measured.
docs/bench.md explains each figure and its caveats.
"""
from __future__ import annotations

import argparse
import concurrent.futures
import datetime as _dt
import json
import math
import os
import re
import shutil
import statistics
import subprocess
import sys
import time

import numpy as np

SCRIPT = os.path.abspath(__file__)
HERE = os.path.dirname(SCRIPT)
if HERE not in sys.path:
    sys.path.insert(0, HERE)

from benchlib import (MB, WAIT_IDLE, cpu_seconds, ensure_importable, have_opencv, hdrcl_cmd,  # noqa: E402
                      machine_facts, read_frame, run_measured)
#: Bump when the generated scenes change, so cached inputs are regenerated.
GEN_VERSION = 1
JPEG_QUALITY = 92

# Targets of issues 4 and 11 (value, direction): "min" means the figure must be >= value.
TARGETS = {
    "kernel_vs_copy": (0.25, "min"),
    "vs_opencv": (5.0, "min"),
    "vs_decode_encode": (1.3, "max"),
    "rss_calibrating_mb": (500.0, "max"),
    "rss_largest_mb": (700.0, "max"),
    "rss_growth": (0.15, "max"),
    "batch_vs_opencv": (None, "info"),
    "solve_8bit_s": (0.3, "max"),
    "solve_16bit_s": (2.0, "max"),
    "second_process_s": (1.5, "max"),
}



def _log(msg: str) -> None:
    print(f"[bench {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)



# --------------------------------------------------------------------------------------
# Sizes
# --------------------------------------------------------------------------------------

def parse_sizes(text: str):
    """``"24x7,100x5"`` -> [(24.0, 7), (100.0, 5)]; a bare ``24`` means 7 frames below
    50 MP and 5 from 50 MP (the issue's two sets)."""
    out = []
    for part in text.split(","):
        part = part.strip().lower()
        if not part:
            continue
        mp, _, frames = part.partition("x")
        mp = float(mp)
        n = int(frames) if frames else (7 if mp < 50 else 5)
        if mp <= 0 or n < 2:
            raise SystemExit(f"--sizes: bad entry '{part}' (megapixels x frames, frames >= 2)")
        out.append((mp, n))
    if not out:
        raise SystemExit("--sizes: nothing to measure")
    return out


def dims(mp: float):
    """Width and height (3:2, multiples of 16) of an ``mp`` megapixel frame."""
    w = int(round(math.sqrt(mp * 1e6 * 1.5) / 16.0)) * 16
    h = int(round(mp * 1e6 / w / 16.0)) * 16
    return max(w, 16), max(h, 16)


def size_label(mp: float, frames: int) -> str:
    return f"{mp:g} MP x {frames}"


# --------------------------------------------------------------------------------------
# Synthetic inputs: textured scenes through an S-curve camera, JPEG with EXIF
# --------------------------------------------------------------------------------------

class Scene:
    """A photographic-looking HDR scene, evaluated in horizontal strips.

    Log10 radiance = a smooth low-resolution field (``hdrcl.core.synthetic.radiance_field``,
    about 4 decades) upsampled bilinearly, plus hard-edged "buildings" with rows of
    windows (sharp colour edges), plus two tiled band-limited textures (fine and medium
    grain). Nothing is white noise except the camera's read noise (0.5 codes). Any strip
    can be computed on its own, so 100 MP frames never exist whole in memory.
    """

    def __init__(self, width: int, height: int, seed: int = 0, decades: float = 4.0):
        from scipy.ndimage import gaussian_filter

        from hdrcl.core.synthetic import radiance_field

        self.width, self.height = width, height
        rng = np.random.default_rng(seed)
        h0 = 120
        w0 = max(2, int(round(h0 * width / height)))
        base = np.log10(radiance_field(h0, w0, decades=decades, channels=1, seed=seed)[..., 0])
        self.base = base.astype(np.float32)
        self._x = self._bilinear(width, w0)
        self._h0 = h0
        # Tiled textures of coprime periods (no visible repeat), in decades.
        self.tex = []
        for period, sigma, amp in ((509, 0.8, 0.12), (1021, 5.0, 0.12)):
            t = gaussian_filter(rng.standard_normal((period, period)), sigma, mode="wrap")
            self.tex.append(((amp / t.std()) * t).astype(np.float32))
        self.cols = [np.arange(width) % t.shape[1] for t in self.tex]
        # Buildings: rectangles (pixel coordinates) with a colour offset, some with windows.
        self.rects = []
        for _ in range(28):
            rw = int(rng.uniform(0.04, 0.30) * width) + 1
            rh = int(rng.uniform(0.05, 0.45) * height) + 1
            x0 = int(rng.uniform(0, width - rw))
            y0 = int(rng.uniform(0.2, 1.0) * (height - rh))
            amp = (rng.uniform(-0.7, 0.5) + rng.normal(0.0, 0.04, 3)).astype(np.float32)
            windows = None
            if rng.uniform() < 0.35:
                period = int(rng.uniform(0.006, 0.02) * width) + 4
                windows = (period, float(rng.uniform(0.6, 1.4)))
            self.rects.append((y0, y0 + rh, x0, x0 + rw, amp, windows))
        self.tint = np.log10(np.array([1.0, 0.9, 0.75], np.float32))

    @staticmethod
    def _bilinear(n: int, n0: int):
        s = np.clip((np.arange(n) + 0.5) * n0 / n - 0.5, 0, n0 - 1)
        i = np.minimum(np.floor(s).astype(np.int64), n0 - 2)
        return i, (s - i).astype(np.float32)

    def log10_strip(self, r0: int, r1: int) -> np.ndarray:
        """Log10 radiance of rows ``r0:r1``, float32 ``(rows, W, 3)``, median about 0."""
        iy, fy = self._bilinear(self.height, self._h0)
        iy, fy = iy[r0:r1], fy[r0:r1, None]
        b = self.base[iy] * (1 - fy) + self.base[iy + 1] * fy  # (rows, w0)
        ix, fx = self._x
        lum = b[:, ix] * (1 - fx) + b[:, ix + 1] * fx  # (rows, W)
        rows = np.arange(r0, r1)
        for t, cols in zip(self.tex, self.cols):
            lum += t[rows % t.shape[0]][:, cols]
        out = np.empty((r1 - r0, self.width, 3), np.float32)
        out[...] = lum[..., None] + self.tint
        for y0, y1, x0, x1, amp, windows in self.rects:
            a, b_ = max(y0, r0), min(y1, r1)
            if a >= b_:
                continue
            out[a - r0:b_ - r0, x0:x1] += amp
            if windows:
                period, bright = windows
                wx = ((np.arange(x0, x1) - x0) % period) < period // 2
                wy = ((np.arange(a, b_) - y0) % period) < period // 2
                out[a - r0:b_ - r0, x0:x1] += (bright * np.outer(wy, wx))[..., None].astype(np.float32)
        return out

    def strips(self, target_pixels: int = 1 << 21):
        rows = max(8, target_pixels // self.width)
        for r0 in range(0, self.height, rows):
            yield r0, min(self.height, r0 + rows)


def camera():
    from hdrcl.core.synthetic import Camera

    return Camera(a=1.1, x0=(1.0, 0.95, 1.08))


def exposure_times(frames: int) -> list:
    """Exposure ladder two stops apart, exact binary fractions of a second (1/4096 .. 1)."""
    from hdrcl.core.synthetic import stops

    return [float(t) for t in stops(frames, 2.0, 1.0 / 64.0)]


def expose_strip(log10: np.ndarray, t: float, cam, bits: int, rng) -> np.ndarray:
    """Codes of one frame for a strip: ``Camera.forward`` (a logistic in log exposure)
    in float32, scaled so that the ladder's centre (1/64 s) sees the scene's median at
    the curve's midpoint, plus Gaussian read noise of 0.5 codes (8-bit units)."""
    levels = (1 << bits) - 1
    lnx = log10 * np.float32(np.log(10.0)) + np.float32(np.log(t * 64.0))
    lnx -= np.log(np.asarray(cam.x0, np.float32))
    y = 1.0 / (1.0 + np.exp(-np.float32(cam.a) * lnx))
    y *= np.float32(levels)
    y += rng.standard_normal(y.shape, dtype=np.float32) * np.float32(0.5 * (levels + 1) / 256.0)
    np.clip(np.rint(y, out=y), 0, levels, out=y)
    return y.astype(np.uint8 if bits == 8 else np.uint16)


def write_bracket_jpegs(folder: str, width: int, height: int, frames: int, seed: int,
                        start: _dt.datetime, prefix: str = "frame") -> list:
    """Write one bracket as JPEG q=92 with EXIF exposure data, strip by strip."""
    import OpenImageIO as oiio

    scene = Scene(width, height, seed=seed)
    cam = camera()
    times = exposure_times(frames)
    paths, outs = [], []
    for j, t in enumerate(times):
        path = os.path.join(folder, f"{prefix}{j:02d}.jpg")
        tmp = os.path.join(folder, f".{prefix}{j:02d}.tmp.jpg")
        spec = oiio.ImageSpec(width, height, 3, "uint8")
        spec.attribute("Compression", f"jpeg:{JPEG_QUALITY}")
        spec.attribute("ExposureTime", float(t))
        spec.attribute("FNumber", 8.0)
        spec.attribute("Exif:PhotographicSensitivity", 100)
        spec.attribute("Exif:DateTimeOriginal", (start + _dt.timedelta(seconds=2 * j)).strftime("%Y:%m:%d %H:%M:%S"))
        spec.attribute("Make", "hdrcl-bench")
        spec.attribute("Model", "synthetic S-curve camera")
        out = oiio.ImageOutput.create(tmp)
        if out is None or not out.open(tmp, spec):
            raise RuntimeError(f"{tmp}: cannot write JPEG ({oiio.geterror()})")
        paths.append((tmp, path))
        outs.append(out)

    def one(job):
        j, r0, r1, log10 = job
        rng = np.random.default_rng([seed, j, r0])
        codes = expose_strip(log10, times[j], cam, 8, rng)
        if not outs[j].write_scanlines(r0, r1, 0, codes):
            raise RuntimeError(f"{paths[j][0]}: write failed ({outs[j].geterror()})")

    # Frames of one strip in parallel (NumPy and libjpeg release the GIL); each
    # ImageOutput is written strip after strip, in order.
    with concurrent.futures.ThreadPoolExecutor(max_workers=min(frames, os.cpu_count() or 1)) as pool:
        for r0, r1 in scene.strips():
            log10 = scene.log10_strip(r0, r1)
            list(pool.map(one, [(j, r0, r1, log10) for j in range(frames)]))
    for out, (tmp, path) in zip(outs, paths):
        if not out.close():
            raise RuntimeError(f"{tmp}: close failed")
        os.replace(tmp, path)
    return [p for _, p in paths]


def bracket_arrays(width: int, height: int, frames: int, seed: int, bits: int) -> list:
    """The same kind of bracket, in memory (for the 16-bit response solve)."""
    scene = Scene(width, height, seed=seed)
    cam = camera()
    times = exposure_times(frames)
    dtype = np.uint8 if bits == 8 else np.uint16
    out = [np.empty((height, width, 3), dtype) for _ in times]
    for r0, r1 in scene.strips():
        log10 = scene.log10_strip(r0, r1)
        for j, t in enumerate(times):
            out[j][r0:r1] = expose_strip(log10, t, cam, bits, np.random.default_rng([seed, j, r0]))
    return out


def ensure_set(work: str, mp: float, frames: int, seed: int = 1, start=None, name=None) -> dict:
    """Generated (or cached) bracket of ``mp`` megapixels; returns paths, times, size."""
    width, height = dims(mp)
    name = name or f"{width}x{height}x{frames}-s{seed}-v{GEN_VERSION}"
    folder = os.path.join(work, "inputs", name)
    marker = os.path.join(folder, "set.json")
    if os.path.isfile(marker):
        with open(marker) as f:
            info = json.load(f)
        if all(os.path.isfile(p) for p in info["paths"]):
            return info
    os.makedirs(folder, exist_ok=True)
    start = start or _dt.datetime(2024, 6, 1, 10, 0, 0)
    t0 = time.perf_counter()
    _log(f"generating {size_label(mp, frames)} ({width}x{height}) JPEG q{JPEG_QUALITY} in {folder}")
    paths = write_bracket_jpegs(folder, width, height, frames, seed, start)
    info = {"paths": paths, "times": exposure_times(frames), "width": width, "height": height,
            "frames": frames, "megapixels": width * height / 1e6,
            "bytes": sum(os.path.getsize(p) for p in paths), "generate_s": time.perf_counter() - t0}
    with open(marker, "w") as f:
        json.dump(info, f, indent=1)
    _log(f"  done in {info['generate_s']:.1f} s, {info['bytes'] / MB:.0f} MB of JPEG")
    return info


def run_worker(kind: str, spec: dict, logdir: str, tag: str, timeout: float = 7200) -> dict:
    """Run an in-process measurement in its own Python process; returns its JSON."""
    res = run_measured([sys.executable, SCRIPT, "--worker", kind, json.dumps(spec)], logdir, tag, timeout)
    if res.get("rc") != 0:
        return {"error": res.get("error", "failed"), "stderr_tail": res.get("stderr", "")[-2000:]}
    out = json.loads(res["stdout"].strip().splitlines()[-1])
    out["worker_rss_mb"] = res["rss_mb"]
    if "background_cpu" in res:
        out["background_cpu"] = res["background_cpu"]
        BACKGROUND.append(res["background_cpu"])
    return out


# --------------------------------------------------------------------------------------
# Workers (each runs in its own process)
# --------------------------------------------------------------------------------------


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


OPENCV_SCRIPT = r"""
import json, sys, time
t0 = time.perf_counter()
import cv2
import numpy as np
t1 = time.perf_counter()
out, times, paths = sys.argv[1], np.asarray(json.loads(sys.argv[2]), np.float32), sys.argv[3:]
imgs = [cv2.imread(p, cv2.IMREAD_COLOR) for p in paths]
if any(i is None for i in imgs):
    sys.exit("cv2.imread failed")
t2 = time.perf_counter()
resp = cv2.createCalibrateDebevec().process(imgs, times)
t3 = time.perf_counter()
hdr = cv2.createMergeDebevec().process(imgs, times, resp)
t4 = time.perf_counter()
if not cv2.imwrite(out, hdr):
    sys.exit("cv2.imwrite failed")
t5 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "imread_s": t2 - t1, "calibrate_s": t3 - t2, "merge_s": t4 - t3,
                  "imwrite_s": t5 - t4, "threads": cv2.getNumThreads(), "version": cv2.__version__}))
"""


# --------------------------------------------------------------------------------------
# Orchestration
# --------------------------------------------------------------------------------------


#: The hdrcl merge runs per size: output type, response given (True) or calibrated.
MERGE_VARIANTS = {
    "merge_exr_response": (".exr", True),
    "merge_exr_calibrate": (".exr", False),
    "merge_hdr_response": (".hdr", True),
    "merge_hdr_calibrate": (".hdr", False),
}

#: Background CPU fraction of every measured run (see run_measured).
BACKGROUND: list = []


def _summ(runs: list) -> dict:
    """Best time, all times, max peak RSS over repeated runs of one command."""
    ok = [r for r in runs if r.get("rc") == 0]
    if not ok:
        return {"error": runs[-1].get("error", "failed") if runs else "not run", "cmd": runs[-1].get("cmd") if runs else ""}
    best = min(ok, key=lambda r: r["wall_s"])
    BACKGROUND.extend(r["background_cpu"] for r in ok if "background_cpu" in r)
    return {"best_s": best["wall_s"], "all_s": [round(r["wall_s"], 3) for r in ok],
            "cpu_all_s": [round(r["user_s"] + r["sys_s"], 3) for r in ok],
            "rss_mb": max(r["rss_mb"] for r in ok), "cmd": ok[0]["cmd"],
            "background_cpu_best_run": best.get("background_cpu"),
            **({"error": f"{len(runs) - len(ok)} of {len(runs)} runs failed"} if len(ok) < len(runs) else {})}


def bench_size(work: str, mp: float, frames: int, repeat: int, opencv: str, solve16: bool, logdir: str) -> dict:
    label = size_label(mp, frames)
    info = ensure_set(work, mp, frames)
    paths, times = info["paths"], info["times"]
    tmp = os.path.join(work, "out")
    os.makedirs(tmp, exist_ok=True)
    tag = f"{info['width']}x{info['height']}x{frames}"
    r = {"label": label, "width": info["width"], "height": info["height"], "frames": frames,
         "megapixels": info["megapixels"], "jpeg_mb": info["bytes"] / MB, "times": times, "repeat": repeat}

    _log(f"{label}: decode / solve / kernel / encode (in-process)")
    r["inproc"] = run_worker("inproc", {"paths": paths, "times": times, "repeat": repeat, "tmpdir": tmp,
                                        "solve16": solve16, "seed": 1}, logdir, f"{tag}-inproc")
    ip = r["inproc"]
    if "error" in ip:
        _log(f"  in-process measurements failed: {ip['error']}")
    else:
        _log(f"  decode {ip['decode_serial_s']:.2f} s serial, {ip['decode_parallel_s']:.2f} s parallel; "
             f"encode EXR {ip['encode_exr_s']:.2f} s; solve {ip['solve_8bit_s']:.3f} s; "
             + (f"kernel {ip['kernel_s']:.3f} s = {ip['kernel_gbps']:.2f} GB/s" if "kernel_s" in ip
                else f"kernel: {ip.get('kernel_error')}"))

    resp_path = os.path.join(tmp, f"{tag}-response.json")
    cal = run_measured(hdrcl_cmd("calibrate", *paths, "-o", resp_path), logdir, f"{tag}-calibrate")
    r["hdrcl_calibrate"] = _summ([cal])
    _log(f"  hdrcl calibrate: {cal.get('wall_s', float('nan')):.2f} s, {cal.get('rss_mb', float('nan')):.0f} MB"
         + (f" ({cal['error']})" if cal.get("error") else ""))

    variants = MERGE_VARIANTS
    runs = {k: [] for k in variants}
    for rep in range(repeat):  # round robin: drift affects every variant alike
        for k, (ext, given) in variants.items():
            if given and cal.get("rc") != 0:
                continue
            outp = os.path.join(tmp, f"{tag}-{k}{ext}")
            args = ["merge", *paths, "-o", outp] + (["--response", resp_path] if given else [])
            if ext == ".exr":
                # Like for like with the encode-only baseline (half, zip). With the default
                # --dtype auto this synthetic set (1/4096..1 s, clipped areas) would be
                # written as float: its possible range exceeds half floats.
                args += ["--dtype", "half"]
            res = run_measured(hdrcl_cmd(*args), logdir, f"{tag}-{k}-{rep}")
            runs[k].append(res)
            _log(f"  hdrcl {k} #{rep + 1}: " + (f"{res['wall_s']:.2f} s, {res['rss_mb']:.0f} MB"
                                               if res.get("rc") == 0 else res.get("error", "failed")))
            if os.path.exists(outp):
                os.remove(outp)
    for k in variants:
        r[k] = _summ(runs[k]) if runs[k] else {"error": "not run (calibrate failed)"}

    if opencv:
        cv_rep = 1 if mp >= 50 else repeat  # as many as hdrcl's: medians of >= 3 are quoted
        cvruns = []
        for rep in range(cv_rep):
            outp = os.path.join(tmp, f"{tag}-opencv.hdr")
            res = run_measured([sys.executable, "-c", OPENCV_SCRIPT, outp, json.dumps(times), *paths],
                               logdir, f"{tag}-opencv-{rep}")
            if res.get("rc") == 0:
                res["phases"] = json.loads(res["stdout"].strip().splitlines()[-1])
            cvruns.append(res)
            _log(f"  OpenCV #{rep + 1}: " + (f"{res['wall_s']:.2f} s, {res['rss_mb']:.0f} MB"
                                            if res.get("rc") == 0 else res.get("error", "failed")))
            if os.path.exists(outp):
                os.remove(outp)
        r["opencv"] = _summ(cvruns)
        ok = [c for c in cvruns if c.get("rc") == 0]
        if ok:
            r["opencv"]["phases"] = min(ok, key=lambda c: c["wall_s"])["phases"]
    else:
        r["opencv"] = {"error": "not measured (OpenCV not installed or --skip-opencv)"}

    # Ratios of this size.
    rat = {}
    m_hdr, m_exr = r["merge_hdr_calibrate"], r["merge_exr_response"]
    if "best_s" in r["opencv"] and "best_s" in m_hdr:
        rat["vs_opencv"] = r["opencv"]["best_s"] / m_hdr["best_s"]
    if len(r["opencv"].get("all_s", [])) >= 2 and len(m_hdr.get("all_s", [])) >= 2:
        # medians beside the best runs: on a shared machine the best run may be a lucky one
        rat["vs_opencv_median"] = statistics.median(r["opencv"]["all_s"]) / statistics.median(m_hdr["all_s"])
        # and of CPU seconds (user + system), which other processes on the cores move far less
        rat["vs_opencv_cpu"] = statistics.median(r["opencv"]["cpu_all_s"]) / statistics.median(m_hdr["cpu_all_s"])
    if "best_s" in r["opencv"] and "best_s" in r["merge_hdr_response"]:
        rat["vs_opencv_response_given"] = r["opencv"]["best_s"] / r["merge_hdr_response"]["best_s"]
    if "decode_parallel_s" in ip:
        de = ip["decode_parallel_s"] + ip["encode_exr_s"]
        rat["decode_encode_s"] = de
        rat["decode_serial_encode_s"] = ip["decode_serial_s"] + ip["encode_exr_s"]
        if "best_s" in m_exr:
            rat["vs_decode_encode"] = m_exr["best_s"] / de
        if "best_s" in r["merge_exr_calibrate"]:
            rat["vs_decode_encode_calibrating"] = r["merge_exr_calibrate"]["best_s"] / de
    rss = [r[k]["rss_mb"] for k in variants if "rss_mb" in r[k]]
    if rss:
        rat["merge_rss_max_mb"] = max(rss)
    r["ratios"] = rat
    return r


def bench_second_process(work: str, repeat: int, logdir: str) -> dict:
    info = ensure_set(work, 1.0, 3, seed=3)
    tmp = os.path.join(work, "out")
    os.makedirs(tmp, exist_ok=True)
    outp = os.path.join(tmp, "small.exr")
    resp = os.path.join(tmp, "small-response.json")
    out = {"set": f"{info['width']}x{info['height']} x 3 JPEG"}
    first = run_measured(hdrcl_cmd("merge", *info["paths"], "-o", outp, "--save-response", resp), logdir, "small-first")
    out["first_s"] = first.get("wall_s")
    if first.get("rc") != 0:
        out["error"] = first.get("error")
        return out
    for k, extra in (("calibrating", []), ("response_given", ["--response", resp])):
        runs = [run_measured(hdrcl_cmd("merge", *info["paths"], "-o", outp, *extra), logdir, f"small-{k}-{i}")
                for i in range(max(3, repeat))]
        out[k] = _summ(runs)
        if "best_s" in out[k]:
            out[k]["median_s"] = statistics.median(out[k]["all_s"])
    py = run_measured([sys.executable, "-c", "pass"], logdir, "python-startup")
    imp = run_measured([sys.executable, "-c", "import hdrcl"], logdir, "import-hdrcl")
    out["python_startup_s"] = py.get("wall_s")
    out["import_hdrcl_s"] = imp.get("wall_s")
    _log(f"second process: first {out['first_s']:.2f} s, then "
         + ", ".join(f"{k} {out[k].get('best_s', float('nan')):.2f} s" for k in ("calibrating", "response_given")))
    return out


def _help_option(text: str, *names):
    for n in names:
        if re.search(rf"(^|[\s,]){re.escape(n)}([\s,=]|$)", text, re.M):
            return n
    return None


OPENCV_BATCH_SCRIPT = r"""
import json, sys, time
import cv2
import numpy as np
sets = json.loads(sys.argv[1])
outdir = sys.argv[2]
for k, (paths, times) in enumerate(sets):
    imgs = [cv2.imread(p, cv2.IMREAD_COLOR) for p in paths]
    if any(i is None for i in imgs):
        sys.exit("cv2.imread failed")
    t = np.asarray(times, np.float32)
    resp = cv2.createCalibrateDebevec().process(imgs, t)
    hdr = cv2.createMergeDebevec().process(imgs, t, resp)
    if not cv2.imwrite(f"{outdir}/set{k}.hdr", hdr):
        sys.exit("cv2.imwrite failed")
"""


def bench_batch(work: str, logdir: str, repeat: int, opencv: str, sets: int = 8, mp: float = 6.0,
                frames: int = 3) -> dict:
    """``hdrcl batch`` over a folder of ``sets`` bracket sets, in megapixels merged per
    second, against one process looping OpenCV's calibrate + merge over the same sets."""
    probe = run_measured(hdrcl_cmd("batch", "--help"), logdir, "batch-help", timeout=120)
    if probe.get("rc") != 0:
        return {"available": False, "note": "batch: not available (" + probe.get("error", "?") + ")"}
    help_text = probe["stdout"]
    outopt = _help_option(help_text, "--out-dir", "--output-dir", "--outdir", "--output", "-o")
    force = _help_option(help_text, "--force")
    folder = os.path.join(work, "inputs", f"batch-{sets}x{mp:g}MPx{frames}-v{GEN_VERSION}")
    os.makedirs(folder, exist_ok=True)
    start = _dt.datetime(2024, 6, 2, 9, 0, 0)
    width, height = dims(mp)
    groups = []
    for k in range(sets):  # each set 10 minutes after the previous one: scan sees 8 sets
        sub = os.path.join(folder, f"set{k}")
        marker = os.path.join(sub, "done")
        if not os.path.isfile(marker):
            os.makedirs(sub, exist_ok=True)
            p = write_bracket_jpegs(sub, width, height, frames, seed=100 + k,
                                    start=start + _dt.timedelta(minutes=10 * k), prefix=f"s{k}_")
            # Flat folder: batch / scan group by EXIF, not by sub-folder.
            for q in p:
                os.replace(q, os.path.join(folder, os.path.basename(q)))
            open(marker, "w").close()
        groups.append(sorted(os.path.join(folder, f) for f in os.listdir(folder) if f.startswith(f"s{k}_")))
    megapixels = sets * width * height / 1e6  # radiance megapixels each tool writes
    out = {"available": True, "sets": sets, "set": f"{size_label(mp, frames)} JPEG", "folder": folder,
           "megapixels": megapixels}
    runs = {"hdrcl": [], "opencv": []}
    summary = None
    times = exposure_times(frames)
    for i in range(max(1, repeat)):  # alternately: drift hits both alike
        outdir = os.path.join(work, "out", "batch")
        shutil.rmtree(outdir, ignore_errors=True)
        os.makedirs(outdir)
        cmd = ["batch", folder] + ([outopt, outdir] if outopt else []) + ([force] if force else [])
        res = run_measured(hdrcl_cmd(*cmd), logdir, f"batch-hdrcl-{i}", cwd=None if outopt else outdir)
        runs["hdrcl"].append(res)
        try:  # hdrcl batch's own account of the sets it found and merged
            with open(os.path.join(outdir, "report.json")) as f:
                summary = json.load(f).get("summary")
        except (OSError, ValueError, AttributeError):
            pass
        _log(f"batch hdrcl #{i + 1}: " + (f"{res['wall_s']:.2f} s = {megapixels / res['wall_s']:.1f} MP/s, peak RSS "
                                         f"{res['rss_mb']:.0f} MB, report {summary}" if res.get("rc") == 0
                                         else res.get("error", "failed")))
        shutil.rmtree(outdir, ignore_errors=True)
        if opencv:
            os.makedirs(outdir)
            res = run_measured([sys.executable, "-c", OPENCV_BATCH_SCRIPT,
                                json.dumps([(g, times) for g in groups]), outdir], logdir, f"batch-opencv-{i}")
            runs["opencv"].append(res)
            _log(f"batch OpenCV loop #{i + 1}: " + (f"{res['wall_s']:.2f} s = {megapixels / res['wall_s']:.1f} MP/s"
                                                   if res.get("rc") == 0 else res.get("error", "failed")))
            shutil.rmtree(outdir, ignore_errors=True)
    out["hdrcl"] = _summ(runs["hdrcl"])
    if summary is not None:
        out["hdrcl"]["summary"] = summary
    out["opencv"] = _summ(runs["opencv"]) if runs["opencv"] else {"error": "not measured (OpenCV not installed)"}
    for k in ("hdrcl", "opencv"):
        if "best_s" in out[k]:
            out[k]["mp_per_s"] = megapixels / out[k]["best_s"]
            out[k]["mp_per_s_median"] = megapixels / statistics.median(out[k]["all_s"])
    if "mp_per_s" in out["hdrcl"] and "mp_per_s" in out["opencv"]:
        out["vs_opencv"] = out["hdrcl"]["mp_per_s"] / out["opencv"]["mp_per_s"]
    return out


# --------------------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------------------

def verdict(value, key: str) -> dict:
    """Whether ``value`` meets target ``key``; when missed, by how much.

    ``shortfall``: for a lower bound, the fraction of the target reached (0.4 = 40 %);
    for an upper bound, how far above the limit (0.2 = 20 % over).
    """
    target, kind = TARGETS[key]
    if value is None or kind == "info":
        return {"target": target, "kind": kind, "value": value, "met": None}
    met = value >= target if kind == "min" else value <= target
    v = {"target": target, "kind": kind, "value": value, "met": bool(met)}
    if not met:
        v["reached_fraction" if kind == "min" else "over_fraction"] = (
            value / target if kind == "min" else value / target - 1)
    return v


def _status(v: dict) -> str:
    if v["met"]:
        return "ok"
    if v["kind"] == "min":
        return f"MISSED: reaches {100 * v['reached_fraction']:.0f} % of the target (needs {1 / max(v['reached_fraction'], 1e-9):.1f}x)"
    return f"MISSED by {100 * v['over_fraction']:.0f} % (over the limit)"


def _fmt(x, unit="", nd=2):
    if x is None:
        return "-"
    return f"{x:.{nd}f}{unit}"


def evaluate(res: dict) -> list:
    """Rows (figure, value text, target text, status, key, verdict) of every target."""
    rows = []
    sizes = res["sizes"]
    first, last = sizes[0], sizes[-1]
    copy = res.get("copy", {})
    ref = copy.get("reference_gbps")

    def add(name, key, value, vtext, ttext, note=None, bg=()):
        v = verdict(value, key)
        bg = [b for b in bg if b is not None]
        if value is None:
            vtext = "-"
        if note:
            v["note"] = note
        if v["kind"] == "info" and value is not None:
            status = "(no target in the issue: for comparison)"
        elif v["met"] is None:
            status = note if note and note.startswith(("not measured", "batch:")) else \
                "not measured" + (f" ({note})" if note else "")
        else:
            status = _status(v)
            if bg:
                v["background_cpu"] = max(bg)
                if max(bg) > 0.10:
                    status += f"  * ({100 * max(bg):.0f} % background CPU)"
        rows.append((name, vtext, ttext, status, key, v))
        v["figure"] = name

    for s in sizes:
        ip = s["inproc"]
        val = ip.get("kernel_gbps") / ref if ref and ip.get("kernel_gbps") else None
        add(f"fusion kernel / copy bandwidth, {s['label']}", "kernel_vs_copy", val,
            f"{_fmt(100 * val if val else None, ' %', 0)} ({_fmt(ip.get('kernel_gbps'), ' GB/s')} vs "
            f"{_fmt(ref, ' GB/s')})", ">= 25 %",
            None if val else ip.get("kernel_error", "no kernel or copy figure"),
            bg=[ip.get("kernel_background"), copy.get(copy.get("reference", "").replace("_gbps", "_background"))])
    v = first["ratios"].get("vs_opencv")
    add(f"hdrcl merge (calibrating, .hdr) vs OpenCV, {first['label']}", "vs_opencv", v,
        f"{_fmt(v, 'x', 1)} faster ({_fmt(first['merge_hdr_calibrate'].get('best_s'), ' s')} vs "
        f"{_fmt(first['opencv'].get('best_s'), ' s')})", ">= 5x",
        None if v else first["opencv"].get("error", "failed"),
        bg=[first["merge_hdr_calibrate"].get("background_cpu_best_run"), first["opencv"].get("background_cpu_best_run")])
    v = first["ratios"].get("vs_decode_encode")
    add(f"hdrcl merge (response given, .exr) / (decode + encode), {first['label']}", "vs_decode_encode", v,
        f"{_fmt(v, 'x')} ({_fmt(first['merge_exr_response'].get('best_s'), ' s')} vs "
        f"{_fmt(first['ratios'].get('decode_encode_s'), ' s')})", "<= 1.3x",
        None if v else first["merge_exr_response"].get("error", "failed"),
        bg=[first["merge_exr_response"].get("background_cpu_best_run"), first["inproc"].get("decode_parallel_background"),
            first["inproc"].get("encode_exr_background")])
    cal = [first[k]["rss_mb"] for k in ("merge_exr_calibrate", "merge_hdr_calibrate") if "rss_mb" in first.get(k, {})]
    v = max(cal) if cal else None
    add(f"peak RSS of a calibrating hdrcl merge, {first['label']} (.exr and .hdr)", "rss_calibrating_mb", v,
        f"{_fmt(v, ' MB', 0)}", "<= 500 MB")
    v = last["ratios"].get("merge_rss_max_mb")
    add(f"peak RSS of hdrcl merge, {last['label']} (max over the 4 variants)", "rss_largest_mb", v,
        f"{_fmt(v, ' MB', 0)}", "<= 700 MB")
    if len(sizes) > 1:
        # Like with like: each merge variant at the last size against itself at the
        # first; the target holds for the variant that grows most.
        growth = {}
        for k in MERGE_VARIANTS:
            a, b = first.get(k, {}).get("rss_mb"), last.get(k, {}).get("rss_mb")
            if a and b:
                growth[k] = (b / a - 1, a, b)
        k = max(growth, key=lambda k: growth[k][0]) if growth else None
        v, a, b = growth[k] if k else (None, None, None)
        add(f"peak RSS growth {first['label']} -> {last['label']} (variant growing most)", "rss_growth", v,
            f"{_fmt(100 * v if v is not None else None, ' %', 0)} ({k}: {_fmt(a, ' MB', 0)} -> {_fmt(b, ' MB', 0)})",
            "< 15 %")
    bt = res.get("batch", {})
    v = bt.get("vs_opencv")
    hb, ob = bt.get("hdrcl", {}), bt.get("opencv", {})
    add(f"hdrcl batch vs a loop of OpenCV merges, {bt.get('sets', 8)} sets of {bt.get('set', '?')} (MP/s)",
        "batch_vs_opencv", v,
        f"{_fmt(v, 'x', 1)}" + (f" ({_fmt(hb.get('mp_per_s'), ' MP/s', 1)} vs {_fmt(ob.get('mp_per_s'), ' MP/s', 1)})"
                               if v else ""), "-",
        None if v else (bt.get("note") or ob.get("error") or hb.get("error") or "failed"),
        bg=[hb.get("background_cpu_best_run"), ob.get("background_cpu_best_run")])
    ip = first["inproc"]
    v = ip.get("solve_8bit_s")
    add(f"response solve, 8-bit RGB ({first['label']}, {ip.get('solve_8bit_samples', '?')} samples)",
        "solve_8bit_s", v, _fmt(v, " s", 3), "<= 0.3 s", bg=[ip.get("solve_8bit_background")])
    v = ip.get("solve_16bit_s")
    add(f"response solve, 16-bit RGB ({ip.get('solve_16bit_size', first['label'])}, "
        f"{ip.get('solve_16bit_samples', '?')} samples)", "solve_16bit_s", v, _fmt(v, " s", 3), "<= 2 s",
        bg=[ip.get("solve_16bit_background")])
    sp = res.get("second_process", {})
    v = sp.get("calibrating", {}).get("best_s")
    add(f"second hdrcl merge process, {sp.get('set', 'small set')} (calibrating)", "second_process_s", v,
        _fmt(v, " s"), "<= 1.5 s", None if v else sp.get("error", "failed"),
        bg=[sp.get("calibrating", {}).get("background_cpu_best_run")])
    return rows


def print_report(res: dict, rows: list) -> None:
    m = res["machine"]
    p = print
    p("")
    p("hdrcl benchmark")
    p(f"  machine: {m.get('cpu')}, {m.get('cpu_count')} cores, {m.get('memory_gb')} GB; "
      f"OpenCL: {m.get('opencl_device')}")
    p(f"  OpenCL driver that ran: {res.get('copy', {}).get('opencl_driver', 'unknown')}")
    p(f"  hdrcl {m.get('hdrcl_git', '')}, Python {m.get('python')}, NumPy {m.get('numpy')}, "
      f"OIIO {m.get('openimageio')}, OpenCV {res.get('opencv_version') or 'not installed'}")
    cp = res.get("copy", {})
    if cp:
        p(f"  copy bandwidth ({cp.get('buffer_mib')} MiB, read+write): NumPy 1 thread "
          f"{_fmt(cp.get('numpy_1thread_gbps'), ' GB/s')}, 2 threads {_fmt(cp.get('numpy_2threads_gbps'), ' GB/s')}, "
          f"OpenCL buffer copy {_fmt(cp.get('opencl_gbps'), ' GB/s')}; reference = {cp.get('reference')}")
    for s in res["sizes"]:
        ip, rat = s["inproc"], s["ratios"]
        p("")
        p(f"{s['label']}  ({s['width']}x{s['height']}, JPEG q{JPEG_QUALITY}, {s['jpeg_mb']:.0f} MB; best of "
          f"{s['repeat']})")
        if "error" in ip:
            p(f"  in-process measurements failed: {ip['error']}")
        else:
            p(f"  decode-only (OIIO)       serial {_fmt(ip['decode_serial_s'], ' s')}, "
              f"{ip['decode_threads']} threads {_fmt(ip['decode_parallel_s'], ' s')}")
            p(f"  encode-only (EXR half zip) {_fmt(ip['encode_exr_s'], ' s')}"
              f"   decode(threads)+encode {_fmt(rat.get('decode_encode_s'), ' s')}")
            if "kernel_s" in ip:
                p(f"  fusion kernel alone      {_fmt(ip['kernel_s'], ' s', 3)} = {_fmt(ip['kernel_gbps'], ' GB/s')} "
                  f"({ip['kernel_bytes'] / MB:.0f} MB moved, {ip['kernel_backend']}, profiling events)")
                if "kernel_host_s" in ip:
                    p(f"  fusion, host path        {_fmt(ip['kernel_host_s'], ' s', 3)} = "
                      f"{_fmt(ip['kernel_host_gbps'], ' GB/s')} (strips copied in and out, counts, fix-up)")
            else:
                p(f"  fusion kernel alone      failed: {ip.get('kernel_error')}")
            p(f"  response solve 8-bit     {_fmt(ip['solve_8bit_s'], ' s', 3)}")
        p(f"  {'hdrcl command':34s} {'time':>8s} {'peak RSS':>10s}")
        for k, name in (("hdrcl_calibrate", "calibrate"), ("merge_exr_response", "merge -> .exr, --response"),
                        ("merge_exr_calibrate", "merge -> .exr, calibrating"),
                        ("merge_hdr_response", "merge -> .hdr, --response"),
                        ("merge_hdr_calibrate", "merge -> .hdr, calibrating"), ("opencv", "OpenCV -> .hdr")):
            e = s.get(k, {})
            if "best_s" in e:
                med = statistics.median(e["all_s"]) if e.get("all_s") else e["best_s"]
                p(f"  {name:34s} {e['best_s']:7.2f}s {e['rss_mb']:7.0f} MB   (median {med:.2f} s of {len(e.get('all_s', [1]))})")
            else:
                p(f"  {name:34s} {e.get('error', '-')}")
        ph = s.get("opencv", {}).get("phases")
        if ph:
            p(f"    OpenCV phases: import {ph['import_s']:.2f}, imread {ph['imread_s']:.2f}, calibrate "
              f"{ph['calibrate_s']:.2f}, merge {ph['merge_s']:.2f}, imwrite {ph['imwrite_s']:.2f} s "
              f"({ph['threads']} threads)")
        p(f"  ratios: vs OpenCV {_fmt(rat.get('vs_opencv'), 'x', 1)} (calibrating, best runs; medians "
          f"{_fmt(rat.get('vs_opencv_median'), 'x', 2)}, CPU-seconds {_fmt(rat.get('vs_opencv_cpu'), 'x', 2)}; "
          f"{_fmt(rat.get('vs_opencv_response_given'), 'x', 1)} with response given), "
          f"vs decode+encode {_fmt(rat.get('vs_decode_encode'), 'x')} (response given; "
          f"{_fmt(rat.get('vs_decode_encode_calibrating'), 'x')} calibrating)")
    sp = res.get("second_process", {})
    if sp:
        p("")
        p(f"second process ({sp.get('set')}): first run {_fmt(sp.get('first_s'), ' s')}; then calibrating "
          f"{_fmt(sp.get('calibrating', {}).get('best_s'), ' s')}, response given "
          f"{_fmt(sp.get('response_given', {}).get('best_s'), ' s')} (python startup "
          f"{_fmt(sp.get('python_startup_s'), ' s')}, import hdrcl {_fmt(sp.get('import_hdrcl_s'), ' s')})")
    bt = res.get("batch", {})
    if bt and not bt.get("available"):
        p(bt.get("note", "batch: not available"))
    elif bt:
        p("")
        p(f"batch ({bt['sets']} sets of {bt['set']}, {bt['megapixels']:.0f} MP of radiance):")
        for k, name in (("hdrcl", "hdrcl batch (EXR + preview)"), ("opencv", "OpenCV loop (.hdr)")):
            e = bt.get(k, {})
            if "best_s" in e:
                p(f"  {name:30s} best {e['best_s']:.2f} s = {e['mp_per_s']:.1f} MP/s, median "
                  f"{statistics.median(e['all_s']):.2f} s = {e['mp_per_s_median']:.1f} MP/s, peak RSS {e['rss_mb']:.0f} MB")
            else:
                p(f"  {name:30s} {e.get('error', '-')}")
    bg = res.get("background_cpu", {})
    if bg.get("runs"):
        p("")
        p(f"background load: other processes used {100 * bg['mean']:.0f} % of the CPU on average during the "
          f"measured runs (max {100 * bg['max']:.0f} %; {bg['runs_over_10pct']} of {bg['runs']} runs above 10 %)"
          + ("  <- figures may be pessimistic; rerun on an idle machine" if bg["max"] > 0.10 else ""))
    p("")
    p("targets" + ("  (--quick sizes: NOT the issue's 24 MP x 7 / 100 MP x 5)" if res.get("quick") else ""))
    w1 = max(len(r[0]) for r in rows)
    w2 = max(len(r[1]) for r in rows)
    for name, vtext, ttext, status, _k, _v in rows:
        p(f"  {name:{w1}s}  {vtext:{w2}s}  target {ttext:10s} {status}")
    if any("  * (" in r[3] for r in rows):
        p("  * other processes used more than 10 % of the CPU during the best run behind this figure")
    p("")
    p(f"JSON: {res['json']}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default=None,
                    help="megapixels x frames, comma-separated [default: 24x7,100x5; --quick: 2x5,4x5]")
    ap.add_argument("--quick", action="store_true", help="small sizes and fewer repeats (a minute or two)")
    ap.add_argument("--work", default=None,
                    help="folder for generated inputs (cached between runs) and outputs "
                         "[default: $TMPDIR/hdrcl-bench]")
    ap.add_argument("--json", default=None, help="where to write the results [default: WORK/bench-results.json]")
    ap.add_argument("--skip-opencv", action="store_true", help="do not run the OpenCV comparison")
    ap.add_argument("--skip-batch", action="store_true", help="do not run the hdrcl batch throughput check")
    ap.add_argument("--repeat", type=int, default=None,
                    help="runs per figure, best kept [default: 3 below 50 MP, 2 from 50 MP; --quick: 2]")
    ap.add_argument("--copy-mib", type=int, default=512, help="buffer size of the copy-bandwidth test (>= 256)")
    ap.add_argument("--wait-idle", type=float, default=0.0, metavar="SECONDS",
                    help="before each measured run, wait up to this long for other processes to use "
                         "< 15 %% of the CPU (shared machines) [default: 0, do not wait]")
    ap.add_argument("--shoot", action="store_true",
                    help="run the shoot benchmark (scripts/shoot_bench.py: batch throughput on whole shoots) "
                         "instead; the other options go to it (see shoot_bench.py --help)")
    ap.add_argument("--worker", nargs=2, help=argparse.SUPPRESS)
    args = sys.argv[1:] if argv is None else [str(x) for x in argv]
    if "--shoot" in args:  # its own process; both scripts build on benchlib, neither imports the other
        return subprocess.call([sys.executable, os.path.join(os.path.dirname(SCRIPT), "shoot_bench.py"),
                                *[x for x in args if x != "--shoot"]])
    a = ap.parse_args(argv)
    ensure_importable()

    if a.worker:
        kind, spec = a.worker
        fn = {"inproc": worker_inproc, "copy": worker_copy}[kind]
        print(json.dumps(fn(json.loads(spec))))
        return 0

    WAIT_IDLE["max_s"] = max(0.0, a.wait_idle)
    sizes = parse_sizes(a.sizes or ("2x5,4x5" if a.quick else "24x7,100x5"))
    work = os.path.abspath(a.work or os.path.join(os.environ.get("TMPDIR", "/tmp"), "hdrcl-bench"))
    os.makedirs(work, exist_ok=True)
    logdir = os.path.join(work, "logs")
    json_path = os.path.abspath(a.json or os.path.join(work, "bench-results.json"))
    t_start = time.perf_counter()
    res = {"command": " ".join([os.path.basename(sys.executable), *sys.argv]) if argv is None else str(argv),
           "started": _dt.datetime.now().isoformat(timespec="seconds"), "quick": a.quick, "work": work,
           "json": json_path, "sizes": []}

    _log(f"work folder {work}")
    res["machine"] = machine_facts(logdir)
    _log(f"machine: {res['machine'].get('cpu')}, {res['machine'].get('cpu_count')} cores; "
         f"OpenCL {res['machine'].get('opencl_device')}")
    res["opencv_version"] = "" if a.skip_opencv else have_opencv()
    if not a.skip_opencv and not res["opencv_version"]:
        _log("OpenCV not installed (pip install opencv-python-headless): comparison skipped")

    _log("copy bandwidth")
    res["copy"] = run_worker("copy", {"mib": max(256, a.copy_mib), "reps": 5}, logdir, "copy")
    for i, (mp, frames) in enumerate(sizes):
        repeat = a.repeat or (2 if a.quick else (3 if mp < 50 else 2))
        res["sizes"].append(bench_size(work, mp, frames, repeat, res["opencv_version"], solve16=(i == 0),
                                       logdir=logdir))
    res["second_process"] = bench_second_process(work, a.repeat or 3, logdir)
    res["batch"] = {"available": False, "note": "batch: skipped (--skip-batch)"} if a.skip_batch else \
        bench_batch(work, logdir, 1 if a.quick else min(3, a.repeat or 3), res["opencv_version"])
    if not res["batch"].get("available"):
        _log(res["batch"]["note"])
    rows = evaluate(res)
    res["targets"] = [dict(r[5], id=r[4]) for r in rows]
    res["background_cpu"] = {"mean": statistics.mean(BACKGROUND) if BACKGROUND else None,
                             "max": max(BACKGROUND) if BACKGROUND else None,
                             "runs": len(BACKGROUND),
                             "runs_over_10pct": sum(1 for b in BACKGROUND if b > 0.10),
                             "waited_for_idle_s": WAIT_IDLE["waited_s"]}
    res["ratios"] = {s["label"]: s["ratios"] for s in res["sizes"]}
    for s in res["sizes"]:
        if s["inproc"].get("kernel_gbps") and res["copy"].get("reference_gbps"):
            res["ratios"][s["label"]]["kernel_vs_copy"] = s["inproc"]["kernel_gbps"] / res["copy"]["reference_gbps"]
    res["elapsed_s"] = time.perf_counter() - t_start
    os.makedirs(os.path.dirname(json_path), exist_ok=True)
    with open(json_path, "w") as f:
        json.dump(res, f, indent=1, default=float)
    print_report(res, rows)
    _log(f"finished in {res['elapsed_s'] / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
