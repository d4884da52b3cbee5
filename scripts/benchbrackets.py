#!/usr/bin/env python3
"""The generated inputs of ``scripts/bench.py``: textured HDR scenes photographed through
an S-shaped camera, JPEG q92 with EXIF exposure data (also used by ``fusion_bench.py`` and
``encode_bench.py``).

:class:`Scene` evaluates a scene strip by strip, so 100 MP frames never exist whole in
memory; :func:`ensure_set` writes a bracket once into ``WORK/inputs`` and reuses it;
:func:`bracket_arrays` makes the same kind of bracket in memory. Imports no other script
but ``benchlib``.
"""
from __future__ import annotations

import concurrent.futures
import datetime as _dt
import json
import math
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)

from benchlib import MB  # noqa: E402

#: Bump when the generated scenes change, so cached inputs are regenerated.
GEN_VERSION = 1
JPEG_QUALITY = 92


def _log(msg: str) -> None:
    print(f"[bench {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def dims(mp: float):
    """Width and height (3:2, multiples of 16) of an ``mp`` megapixel frame."""
    w = int(round(math.sqrt(mp * 1e6 * 1.5) / 16.0)) * 16
    h = int(round(mp * 1e6 / w / 16.0)) * 16
    return max(w, 16), max(h, 16)


def size_label(mp: float, frames: int) -> str:
    return f"{mp:g} MP x {frames}"



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
