"""Encode time and file size of a radiance map in each EXR compression, and as Radiance RGBE.

    python scripts/compression_bench.py [--input MAP.exr] [--size 6000x4000] [--repeat 3]
        [--compressions none,zip,zips,piz,pxr24,dwaa] [--dtypes half,float] [--threads 0,1]
        [--rows N] [--no-hdr]

The map is written the way ``hdrcl merge`` writes it: strip by strip (``--rows``, default
about 256K pixels a strip) through :class:`hdrcl.io.writers.RadianceWriter`, into a
temporary folder, and read back to check it. Without ``--input`` it is a synthetic scene
(a window-lit room: smooth light over five decades, textures, 1 % sensor noise); an
input map is tiled (flipped and rescaled tiles, see :func:`load`) or cut to ``--size``.
``--threads`` lists OpenImageIO ``exr_threads`` settings to time (0: every core hdrcl
may use; 1: one thread, the strips handed over as they come, as before batching).

Columns: seconds (median of ``--repeat`` runs; wall clock and process CPU time, all
threads), ``thr``: threads running or waiting for a CPU, on average (sampled from
``/proc``: how much parallel work the encoder offers, which a busy machine does not
hide), size in MB and as a share of the uncompressed samples (half: 2 bytes, float: 4),
throughput of radiance in MP/s (wall), and the largest error read back relative to the
value written (0: lossless; half's own rounding is not counted). RGBE rows compare
hdrcl's NumPy encoder (run-length coded and flat) with OpenImageIO's followed by the
header copy hdrcl needed with it; their error is relative to each pixel's largest
channel (RGBE keeps about 1 %). On a busy machine the wall clock is noisy: compare rows
of one run, and ``thr``.
"""
import argparse
import os
import shutil
import statistics
import tempfile
import threading
import time

import numpy as np


def synthetic(w, h, seed=0):
    """A window-lit room: a bright window, a sunlit patch, walls falling off over five
    decades, textured surfaces and multiplicative sensor noise."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    y /= h
    x /= w
    light = 0.05 + 2.0 * np.exp(-((x - 0.7) ** 2 + (y - 0.4) ** 2) / 0.08)
    window = ((x > 0.55) & (x < 0.85) & (y > 0.15) & (y < 0.6)).astype(np.float32)
    patch = ((x > 0.2) & (x < 0.45) & (y > 0.7) & (y < 0.95)).astype(np.float32)
    texture = 1.0 + 0.3 * np.sin(x * 300.0) * np.sin(y * 170.0)
    lum = light * texture + 400.0 * window + 20.0 * patch
    lum *= np.exp(-3.0 * x * (1.0 - window))  # deep shadow to the left
    tint = np.stack([np.full_like(x, 1.0), 0.9 + 0.05 * y, 0.75 + 0.2 * window], axis=2)
    img = lum[..., None] * tint
    img *= 1.0 + 0.01 * rng.standard_normal(img.shape, dtype=np.float32)
    return np.ascontiguousarray(np.maximum(img, 1e-4).astype(np.float32))


def load(path, w, h):
    """A radiance map from ``path``, tiled or cut to ``w`` x ``h``, 3 channels.

    Tiles are flipped four ways and scaled by distinct powers 2^(k/7), so no row repeats
    an earlier stretch: ZIP's deflate would find plain or mirrored copies within its
    32 KB window and report a ratio the real image does not have.
    """
    from hdrcl.io.radiance import read_radiance

    img, _ = read_radiance(path)
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    th, tw = img.shape[:2]
    out = np.empty((h, w, 3), np.float32)
    for i, y in enumerate(range(0, h, th)):
        for j, x in enumerate(range(0, w, tw)):
            k = i * ((w + tw - 1) // tw) + j
            tile = img[::-1] if k % 2 else img
            tile = tile[:, ::-1] if (k // 2) % 2 else tile
            out[y:y + th, x:x + tw] = (tile * np.float32(2.0 ** (k / 7.0)))[:h - y, :w - x]
    return out
def encode_streamed(path, img, rows, **kw):
    """Write ``img`` through RadianceWriter in strips; (wall s, CPU s)."""
    from hdrcl.io.writers import RadianceWriter

    h, w, c = img.shape
    t, p = time.perf_counter(), time.process_time()
    with RadianceWriter(path, w, h, c, **kw) as wr:
        for y in range(0, h, rows):
            wr.write_rows(y, min(h, y + rows), img[y:y + rows])
    return time.perf_counter() - t, time.process_time() - p


def encode_oiio_hdr(path, img, rows):
    """OpenImageIO's own RGBE writer, strip by strip, and hdrcl's header lines inserted
    afterwards by copying the file: how hdrcl wrote ``.hdr`` before its own encoder."""
    import OpenImageIO as oiio

    from hdrcl.io.outmeta import hdr_header_lines, patch_hdr_header

    h, w, _ = img.shape
    t, p = time.perf_counter(), time.process_time()
    out = oiio.ImageOutput.create(path)
    out.open(path, oiio.ImageSpec(w, h, 3, "float"))
    for y in range(0, h, rows):
        out.write_scanlines(y, min(h, y + rows), 0, img[y:y + rows])
    out.close()
    patch_hdr_header(path, hdr_header_lines(None, "rec709", None))
    return time.perf_counter() - t, time.process_time() - p


def encode_flat_hdr(path, img, rows):
    """hdrcl's NumPy RGBE encoder without run-length coding."""
    from hdrcl.io.encoders import RGBEFile

    h, w, _ = img.shape
    t, p = time.perf_counter(), time.process_time()
    out = RGBEFile(path, w, h, rle=False)
    for y in range(0, h, rows):
        out.write(img[y:y + rows])
    out.close()
    return time.perf_counter() - t, time.process_time() - p


def readback_error(path, img, dtype, rgbe):
    """Largest error of the file's values relative to what was written."""
    from hdrcl.io.radiance import read_radiance

    back, _ = read_radiance(path)
    ref = img.astype(np.float16).astype(np.float32) if dtype == "half" else img
    if rgbe:
        return float((np.abs(back - img) / img.max(axis=2, keepdims=True)).max())
    return float((np.abs(back - ref) / np.maximum(np.abs(ref), 1e-30)).max())


class Runnable:
    """Samples, every 2 ms, how many of this process's threads are running or waiting for
    a CPU (Linux ``/proc``): the parallelism the encoder offers, which a busy machine
    does not hide the way it hides a speed-up in wall time. NaN where ``/proc`` is missing."""

    def __init__(self):
        self.samples = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        me = str(threading.get_native_id())
        while not self._stop.is_set():
            n = 0
            for tid in os.listdir("/proc/self/task"):
                if tid == me:
                    continue
                try:
                    with open(f"/proc/self/task/{tid}/stat") as f:
                        n += f.read().rsplit(")", 1)[1].split()[0] == "R"
                except OSError:
                    continue
            self.samples.append(n)
            time.sleep(0.002)

    def __enter__(self):
        if os.path.isdir("/proc/self/task"):
            self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()

    @property
    def mean(self):
        return statistics.mean(self.samples) if self.samples else float("nan")


def timed(fn, repeat):
    """Median wall and CPU seconds of ``repeat`` runs, and the mean runnable threads."""
    runs, par = [], []
    for _ in range(repeat):
        with Runnable() as r:
            runs.append(fn())
        par.append(r.mean)
    return statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs), statistics.median(par)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--input", help="a radiance map (EXR, HDR, ...) instead of the synthetic scene")
    ap.add_argument("--size", default="6000x4000", help="WxH [6000x4000, 24 MP]")
    ap.add_argument("--repeat", type=int, default=3, help="runs per row; the median is shown [3]")
    ap.add_argument("--compressions", default="none,zip,zips,piz,pxr24,dwaa")
    ap.add_argument("--dtypes", default="half,float")
    ap.add_argument("--threads", default="0", help="OpenImageIO exr_threads settings to time [0: all cores]")
    ap.add_argument("--rows", type=int, default=0, help="rows per strip [about 256K pixels]")
    ap.add_argument("--no-hdr", action="store_true", help="leave out the Radiance RGBE rows")
    ap.add_argument("--tmp", default=None, help="folder for the files [a temporary one]")
    args = ap.parse_args(argv)

    import OpenImageIO as oiio

    from hdrcl.io.encoders import exr_threads

    w, h = (int(v) for v in args.size.lower().split("x"))
    img = load(args.input, w, h) if args.input else synthetic(w, h)
    rows = args.rows or max(1, (1 << 18) // w)
    folder = tempfile.mkdtemp(prefix="hdrcl-compression-", dir=args.tmp)
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"{args.input or 'synthetic scene'}: {w}x{h} ({w * h / 1e6:.1f} MP), strips of {rows} rows, "
          f"median of {args.repeat}; {cpus} CPUs, OpenImageIO {oiio.__version__}, "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"{'format':28s} {'wall s':>7s} {'cpu s':>7s} {'thr':>5s} {'MB':>8s} {'share':>6s} {'MP/s':>6s} "
          f"{'max err':>9s}")
    raw = {"half": 2, "float": 4}
    try:
        for setting in (int(t) for t in args.threads.split(",")):
            oiio.attribute("exr_threads", setting)
            n = exr_threads(oiio)
            for dtype in args.dtypes.split(","):
                for comp in args.compressions.split(","):
                    path = os.path.join(folder, f"{comp}-{dtype}.exr")
                    wall, cpu, par = timed(lambda: encode_streamed(path, img, rows, dtype=dtype, compression=comp,
                                                                   timestamp=""), args.repeat)
                    size = os.path.getsize(path)
                    err = readback_error(path, img, dtype, False)
                    print(f"{f'exr {dtype} {comp} ({n} thr)':28s} {wall:7.2f} {cpu:7.2f} {par:5.2f} {size / 1e6:8.1f} "
                          f"{size / (img.size * raw[dtype]):6.3f} {w * h / 1e6 / wall:6.1f} {err:9.2e}", flush=True)
        if not args.no_hdr:
            for name, fn in (("hdr rle (hdrcl NumPy)", lambda p: encode_streamed(p, img, rows)),
                             ("hdr flat (hdrcl NumPy)", lambda p: encode_flat_hdr(p, img, rows)),
                             ("hdr rle (OpenImageIO+patch)", lambda p: encode_oiio_hdr(p, img, rows))):
                path = os.path.join(folder, name.split()[1] + name.split()[2][1:6] + ".hdr")
                wall, cpu, par = timed(lambda: fn(path), args.repeat)
                size = os.path.getsize(path)
                err = readback_error(path, img, "float", True)
                print(f"{name:28s} {wall:7.2f} {cpu:7.2f} {par:5.2f} {size / 1e6:8.1f} {size / (img.size * 4):6.3f} "
                      f"{w * h / 1e6 / wall:6.1f} {err:9.2e}", flush=True)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
