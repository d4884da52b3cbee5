#!/usr/bin/env python3
"""hdrcl shoot benchmark: batch throughput on whole shoots of camera-sized JPEGs.

The project's reproducible record of batch throughput (issue 16). For each shoot shape
it generates (once; cached) a folder of 12-24 MP JPEGs with camera EXIF, then measures,
in rounds that alternate the tools so drift hits all alike:

* ``hdrcl batch SHOOT -r -o OUT`` with its defaults (a separate process, as a user runs
  it), and the same with ``--jobs 2``;
* the **decode floor**: every frame decoded once with OpenImageIO and nothing else, on
  ``os.cpu_count()`` threads in one process;
* the **encode floor**: every output of that round's ``hdrcl batch`` (defaults) encoded
  once more in its own format (the EXR's pixel type and compression: half, PIZ by
  default; or .hdr) with OpenImageIO on all cores, one output after another, the encodes
  timed only (as ``../shared/tools/io_floor.py`` does); decode + encode floor = the
  **I/O floor**, what a batch cannot beat on the CPU;
* a loop of **OpenCV**'s Debevec pipeline in one process (``cv2.imread`` per frame,
  ``createCalibrateDebevec().process``, ``createMergeDebevec().process``,
  ``cv2.imwrite(.hdr)`` per set), when ``opencv-python-headless`` is installed;

and prints input megapixels per second (frames x pixels, summed over the shoot) for each,
the ratios batch wall / I/O floor, hdrcl / OpenCV and hdrcl / decode floor beside their
targets (each round's own ratio, median of the rounds), the seconds per
stage that ``hdrcl batch`` records in ``OUT/report.json`` (summed over sets), and
start-up costs (``hdrcl --version`` and a tiny merge).

Shapes: ``one-camera`` (several sets from one camera: one pooled response) and
``per-camera`` (one set per camera, 5-13 frames: one calibration per set).

    python scripts/shoot_bench.py                         # both shapes, 5 sets of 12 MP frames, 3 runs
    python scripts/shoot_bench.py --shape one-camera --mp 24 --sets 6 --runs 5 --workdir /tmp/sb
    python scripts/bench.py --shoot [options]             # the same, from the main benchmark

Frames are made from the real scenes in ``../shared/data`` (memorial, window_e995,
frobisher_001): a radiance map estimated from each bracket, cropped to the camera's
aspect ratio, upscaled (separable cubic) with a little fine texture, photographed
through a known S-shaped response per camera, plus read noise, JPEG quality 92-95.
Without that folder, a synthetic scene (``hdrcl.core.synthetic.radiance_field``) is
used. docs/bench.md describes the figures.
"""
from __future__ import annotations

import argparse
import concurrent.futures
import datetime as _dt
import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

SCRIPT = os.path.abspath(__file__)
HERE = os.path.dirname(SCRIPT)
ROOT = os.path.dirname(HERE)
if HERE not in sys.path:
    sys.path.insert(0, HERE)

import benchlib  # noqa: E402  (scripts/benchlib.py: process launcher, machine facts, checkout on the path)

FLOORS = os.path.join(HERE, "floors.py")  # the decode, encode and fusion floors, each in its own process

#: Bump when generated shoots change, so cached ones are regenerated.
GEN_VERSION = 1
SHAPES = ("one-camera", "per-camera")
FLOOR_KINDS = ("decode", "encode", "fusion")
DEFAULT_FRAMES = {"one-camera": "7", "per-camera": "5,7,9,13,7,5"}

#: Targets: hdrcl batch (defaults) at least 5x the OpenCV loop and at most 1.6x the I/O
#: floor (issue 26), at least 35 % of the decode floor's MP/s (issue 16).
TARGETS = {"vs_opencv": 5.0, "vs_decode": 0.35, "io_floor": 1.6, "cpu_floor": 1.3}

#: Stage keys of report.json's per-set ``seconds``, printed in this order; keys not listed
#: here follow in the order they are first met.
STAGE_ORDER = ("startup", "decode", "sample", "solve", "fuse", "encode", "write", "report",
               "hash", "open", "merge", "preview", "quality")

#: Cameras of the per-camera shape (the one-camera shape uses the first). ``a``/``x0``:
#: the known S-shaped response (hdrcl.core.synthetic.Camera: a logistic in log
#: exposure); ``aspect`` 3:2 or 4:3; JPEG quality and chroma subsampling as such cameras
#: write them; ``folder``/``prefix``: the card layout.
CAMERAS = (
    dict(make="Canon", model="Canon EOS R6", a=1.10, x0=(1.00, 0.95, 1.08), aspect=1.5, quality=95,
         subsampling="4:2:2", fnumber=8.0, iso=100, lens="RF24-105mm F4 L IS USM", focal=24.0,
         folder="DCIM/100CANON", prefix="IMG_", ext=".JPG"),
    dict(make="NIKON CORPORATION", model="NIKON Z 6", a=0.95, x0=(1.05, 1.00, 0.92), aspect=1.5, quality=94,
         subsampling="4:2:2", fnumber=11.0, iso=100, lens="NIKKOR Z 24-70mm f/4 S", focal=35.0,
         folder="DCIM/100NCZ_6", prefix="DSC_", ext=".JPG"),
    dict(make="Apple", model="iPhone 15 Pro", a=1.35, x0=(1.00, 0.97, 1.03), aspect=4 / 3, quality=92,
         subsampling="4:2:0", fnumber=1.78, iso=80, lens="iPhone 15 Pro back camera 6.765mm f/1.78", focal=6.765,
         folder="DCIM/100APPLE", prefix="IMG_", ext=".JPG"),
    dict(make="SONY", model="ILCE-7M3", a=1.25, x0=(0.97, 1.00, 1.05), aspect=1.5, quality=93,
         subsampling="4:2:2", fnumber=8.0, iso=100, lens="FE 24-105mm F4 G OSS", focal=28.0,
         folder="DCIM/100MSDCF", prefix="DSC0", ext=".JPG"),
    dict(make="Panasonic", model="DC-G9", a=1.15, x0=(1.02, 0.98, 1.00), aspect=4 / 3, quality=92,
         subsampling="4:2:0", fnumber=8.0, iso=200, lens="LUMIX G VARIO 12-60/F3.5-5.6", focal=12.0,
         folder="DCIM/100_PANA", prefix="P10", ext=".JPG"),
    dict(make="FUJIFILM", model="X-T4", a=1.05, x0=(1.00, 1.04, 0.96), aspect=1.5, quality=93,
         subsampling="4:2:2", fnumber=5.6, iso=160, lens="XF16-55mmF2.8 R LM WR", focal=16.0,
         folder="DCIM/100_FUJI", prefix="DSCF", ext=".JPG"),
)

#: Shutter speeds as cameras write them (third stops).
NOMINAL_TIMES = sorted([1 / d for d in (8000, 6400, 5000, 4000, 3200, 2500, 2000, 1600, 1250, 1000, 800, 640,
                                        500, 400, 320, 250, 200, 160, 125, 100, 80, 60, 50, 40, 30, 25, 20, 15,
                                        13, 10, 8, 6, 5, 4, 3, 2.5, 2, 1.6, 1.3)]
                       + [1.0, 1.3, 1.6, 2.0, 2.5, 3.2, 4.0, 5.0, 6.0, 8.0, 10.0, 13.0, 15.0, 20.0, 25.0, 30.0])
#: Middle shutter speed of each set, cycled (the scene's median lands mid-curve there).
MID_TIMES = (1 / 60, 1 / 125, 1 / 30, 1 / 250, 1 / 15, 1 / 100)

#: Generated frames: read noise (8-bit codes, Gaussian) and fine scene texture (ln units).
READ_NOISE = 2.0
TEXTURE = 0.22
SET_SPACING_S = 300  # seconds between the starts of two sets (hdrcl splits at 8 s gaps)


def _log(msg: str) -> None:
    print(f"[shoot-bench {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# --------------------------------------------------------------------------------------
# Scenes: radiance maps estimated from the real brackets in ../shared/data
# --------------------------------------------------------------------------------------

def _read_u8(path: str):
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise RuntimeError(f"{path}: {oiio.geterror()}")
    try:
        spec = inp.spec()
        px = np.asarray(inp.read_image(0, 0, 0, 3, "uint8"))
        t = spec.getattribute("ExposureTime")
    finally:
        inp.close()
    return px, t


def _scene_sources(data: str) -> list:
    """(name, paths, exposure times or None for EXIF, ignore-blue, margin) of each real scene found."""
    out = []
    win = os.path.join(data, "window_e995")
    if os.path.isdir(win):
        out.append(("window_e995", sorted(os.path.join(win, f) for f in os.listdir(win) if f.lower().endswith(".jpg")),
                    None, False, 0))
    mem = os.path.join(data, "memorial")
    lst = os.path.join(mem, "image_list.txt")
    if os.path.isfile(lst):
        names, times = [], []
        with open(lst) as f:
            for line in f:
                parts = line.split()
                if parts and not parts[0].startswith("#"):
                    names.append(os.path.join(mem, parts[0]))
                    times.append(float(parts[1]))  # HDRShop "exposure" column: seconds (1/1024 .. 32)
        # Unregistered borders painted pure blue (up to ~30 px): excluded, and cropped.
        out.append(("memorial", names, times, True, 32))
    fro = os.path.join(data, "frobisher_001")
    if os.path.isdir(fro):
        out.append(("frobisher_001", sorted(os.path.join(fro, f) for f in os.listdir(fro)
                                            if f.lower().endswith(".jpg")), None, False, 0))
    return [s for s in out if len(s[1]) >= 2 and all(os.path.isfile(p) for p in s[1])]


def _estimate_radiance(paths, times, ignore_blue: bool, margin: int) -> np.ndarray:
    """ln radiance (float32, H x W x 3) of a bracket: a hat-weighted average of
    ``2.2 ln(z/255) - ln t`` (a gamma-2.2 guess at the camera; only the scene's look
    matters here), the shortest frame where no frame is well exposed."""
    num = den = None
    frames = []
    for k, p in enumerate(paths):
        z8, t_exif = _read_u8(p)
        if z8.shape[0] * z8.shape[1] > 1_000_000:  # half resolution is plenty (and 4x faster)
            z8 = np.ascontiguousarray(z8[::2, ::2])
        t = times[k] if times else t_exif
        if not t:
            raise RuntimeError(f"{p}: no exposure time")
        z = z8.astype(np.float32)
        w = np.maximum(np.minimum(z, 255.0 - z) - 2.0, 0.0)
        if ignore_blue:
            w[(z8[..., 0] == 0) & (z8[..., 1] == 0) & (z8[..., 2] == 255)] = 0.0
        ln_e = 2.2 * np.log(np.maximum(z, 0.5) / 255.0) - math.log(t)
        num = w * ln_e if num is None else num + w * ln_e
        den = w if den is None else den + w
        frames.append((t, z))
    t_min, z_min = min(frames, key=lambda f: f[0])
    fallback = 2.2 * np.log(np.maximum(z_min, 0.5) / 255.0) - math.log(t_min)
    lnr = np.where(den > 0, num / np.maximum(den, 1e-6), fallback)
    if margin:
        lnr = lnr[margin:-margin, margin:-margin]
    return np.ascontiguousarray(lnr, dtype=np.float32)


class Scenes:
    """The scenes, loaded when first used: ``scenes[k]`` is ``(name, ln radiance at source
    resolution, median 0)`` of scene ``k % len(scenes)``; cached in WORKDIR/scenes."""

    def __init__(self, workdir: str, data: str):
        self.folder = os.path.join(workdir, "scenes")
        self.sources = _scene_sources(data)
        self.data = data
        self.loaded = {}

    def __len__(self):
        return max(1, len(self.sources))

    def __getitem__(self, k: int):
        k %= len(self)
        if k not in self.loaded:
            self.loaded[k] = self._load(k)
        return self.loaded[k]

    def _load(self, k: int):
        if not self.sources:  # no ../shared/data: a synthetic scene
            from hdrcl.core.synthetic import radiance_field

            _log(f"no real scenes under {self.data}: using hdrcl.core.synthetic.radiance_field")
            lnr = np.log(radiance_field(400, 600, decades=4.0, channels=3, seed=7)).astype(np.float32)
            return "synthetic", lnr - np.float32(np.median(lnr.mean(axis=2)))
        name, paths, times, blue, margin = self.sources[k]
        cache = os.path.join(self.folder, f"{name}-v{GEN_VERSION}.npy")
        if os.path.isfile(cache):
            return name, np.load(cache)
        if len(paths) > 8:  # every other frame is plenty for the scene's look
            paths, times = paths[::2], (times[::2] if times else None)
        _log(f"estimating the radiance of {name} ({len(paths)} frames)")
        lnr = _estimate_radiance(paths, times, blue, margin)
        lnr -= np.float32(np.median(lnr.mean(axis=2)))
        os.makedirs(self.folder, exist_ok=True)
        np.save(cache + ".tmp.npy", lnr)
        os.replace(cache + ".tmp.npy", cache)
        return name, lnr


def _cubic_taps(n_out: int, n_in: int):
    """Source indices (n_out x 4) and weights of a Keys cubic (Catmull-Rom) resampling."""
    s = (np.arange(n_out) + 0.5) * n_in / n_out - 0.5
    i0 = np.floor(s).astype(np.int64)
    f = (s - i0)[:, None] + np.array([1.0, 0.0, -1.0, -2.0])  # distances to the 4 taps
    x = np.abs(f)
    w = np.where(x < 1, 1.5 * x ** 3 - 2.5 * x ** 2 + 1, np.where(x < 2, -0.5 * x ** 3 + 2.5 * x ** 2 - 4 * x + 2, 0))
    idx = np.clip(i0[:, None] + np.arange(-1, 3)[None, :], 0, n_in - 1)
    return idx, w.astype(np.float32)


def upscale(lnr: np.ndarray, height: int, width: int) -> np.ndarray:
    """Separable cubic resampling of ``lnr`` (h x w x 3) to height x width (float32)."""
    iy, wy = _cubic_taps(height, lnr.shape[0])
    tmp = lnr[iy[:, 0]] * wy[:, 0, None, None]
    for j in range(1, 4):
        tmp += lnr[iy[:, j]] * wy[:, j, None, None]
    ix, wx = _cubic_taps(width, lnr.shape[1])
    out = tmp[:, ix[:, 0]] * wx[None, :, 0, None]
    for j in range(1, 4):
        out += tmp[:, ix[:, j]] * wx[None, :, j, None]
    return out


def crop_to_aspect(lnr: np.ndarray, aspect: float) -> np.ndarray:
    """Centre crop to width/height = ``aspect``."""
    h, w = lnr.shape[:2]
    if w / h > aspect:
        cw = max(2, int(round(h * aspect)))
        x0 = (w - cw) // 2
        return lnr[:, x0:x0 + cw]
    ch = max(2, int(round(w / aspect)))
    y0 = (h - ch) // 2
    return lnr[y0:y0 + ch]


def frame_dims(mp: float, aspect: float, portrait: bool):
    """Width and height (multiples of 8) of an ``mp`` megapixel frame of ``aspect`` >= 1."""
    w = max(8, int(round(math.sqrt(mp * 1e6 * aspect) / 8.0)) * 8)
    h = max(8, int(round(mp * 1e6 / w / 8.0)) * 8)
    return (h, w) if portrait else (w, h)


def ladder(frames: int, t_mid: float):
    """Exposure times of a bracket of ``frames`` around ``t_mid``, snapped to the nominal
    third-stop values cameras write (wide brackets step less: 2 EV for <= 5 frames, 5/3
    for <= 7, 4/3 for <= 9, else 1 EV). The snapped values are the true exposures.
    Returns the times and the middle (moved so that the whole ladder fits 1/8000..30 s)."""
    step = 2.0 if frames <= 5 else (5 / 3 if frames <= 7 else (4 / 3 if frames <= 9 else 1.0))
    half = step * (frames - 1) / 2  # stops from the middle to either end: keep both in range
    t_mid = min(max(t_mid, NOMINAL_TIMES[0] * 2.0 ** half), NOMINAL_TIMES[-1] / 2.0 ** half)
    out = []
    for i in range(frames):
        t = t_mid * 2.0 ** (step * (i - (frames - 1) / 2))
        out.append(min(NOMINAL_TIMES, key=lambda v: abs(math.log2(v / t))))
    if len(set(out)) < len(out):
        raise ValueError(f"{frames} frames do not fit the shutter range around {t_mid}")
    return out, t_mid


def parse_frames(text: str) -> list:
    try:
        vals = [int(v) for v in str(text).split(",") if v.strip()]
    except ValueError:
        raise SystemExit(f"--frames: expected a number or a comma list, got {text!r}") from None
    if not vals or min(vals) < 2 or max(vals) > 15:
        raise SystemExit(f"--frames: each set needs 2 to 15 frames, got {text!r}")
    return vals


# --------------------------------------------------------------------------------------
# Shoot generation
# --------------------------------------------------------------------------------------

class _NoiseBank:
    """Read noise for every frame of one size: one buffer of standard normals, a random
    window of it per frame (generating fresh normals costs more than the JPEG encode)."""

    def __init__(self, n: int, seed: int):
        self.n = n
        self.extra = 1 << 16
        self.buf = np.random.default_rng(seed).standard_normal(n + self.extra, dtype=np.float32)
        self.buf *= np.float32(READ_NOISE)

    def window(self, rng) -> np.ndarray:
        o = int(rng.integers(0, self.extra))
        return self.buf[o:o + self.n]


def _texture_tile(seed: int) -> np.ndarray:
    """A tileable band-limited texture (ln units), fine and medium grain."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    t = gaussian_filter(rng.standard_normal((509, 521)), 0.8, mode="wrap")
    t = t / t.std() + 0.7 * gaussian_filter(rng.standard_normal((509, 521)), 3.0, mode="wrap") * 3.0
    return (TEXTURE * t / t.std()).astype(np.float32)


def _add_tiled(img: np.ndarray, tile: np.ndarray, dy: int, dx: int) -> None:
    th, tw = tile.shape
    tile = np.roll(tile, (dy % th, dx % tw), axis=(0, 1))
    for y in range(0, img.shape[0], th):
        for x in range(0, img.shape[1], tw):
            blk = img[y:y + th, x:x + tw]
            blk += tile[:blk.shape[0], :blk.shape[1], None]


def _write_jpeg(path: str, codes: np.ndarray, cam: dict, t: float, when: _dt.datetime) -> None:
    import OpenImageIO as oiio

    h, w = codes.shape[:2]
    spec = oiio.ImageSpec(w, h, 3, oiio.UINT8)
    spec.attribute("Compression", f"jpeg:{cam['quality']}")
    spec.attribute("jpeg:subsampling", cam["subsampling"])
    spec.attribute("Make", cam["make"])
    spec.attribute("Model", cam["model"])
    spec.attribute("Software", "hdrcl shoot_bench (synthetic frame)")
    spec.attribute("ExposureTime", oiio.TypeFloat, float(t))
    spec.attribute("FNumber", oiio.TypeFloat, float(cam["fnumber"]))
    spec.attribute("Exif:PhotographicSensitivity", oiio.TypeInt, int(cam["iso"]))
    spec.attribute("Exif:ExposureMode", oiio.TypeInt, 1)  # manual: a hand bracket
    spec.attribute("Exif:DateTimeOriginal", when.strftime("%Y:%m:%d %H:%M:%S"))
    spec.attribute("Exif:SubsecTimeOriginal", f"{when.microsecond // 10000:02d}")
    spec.attribute("DateTime", when.strftime("%Y:%m:%d %H:%M:%S"))
    spec.attribute("Exif:LensModel", cam["lens"])
    spec.attribute("Exif:FocalLength", oiio.TypeFloat, float(cam["focal"]))
    tmp = os.path.join(os.path.dirname(path), "." + os.path.basename(path) + ".tmp.jpg")
    out = oiio.ImageOutput.create(tmp)
    if out is None or not out.open(tmp, spec):
        raise RuntimeError(f"{tmp}: cannot write JPEG ({oiio.geterror()})")
    try:
        if not out.write_image(codes):
            raise RuntimeError(f"{tmp}: write failed ({out.geterror()})")
    finally:
        out.close()
    os.replace(tmp, path)


def _expose(radiance: np.ndarray, t_rel: float, cam: dict, noise: np.ndarray) -> np.ndarray:
    """8-bit codes: ``255 / (1 + (x0 / X)^a)`` with ``X = exp(ln radiance) * t_rel``, plus noise."""
    k = (np.float32(math.log(t_rel)) - np.log(np.asarray(cam["x0"], np.float32))) * np.float32(-cam["a"])
    y = radiance * np.float32(-cam["a"])
    y += k
    with np.errstate(over="ignore"):
        np.exp(y, out=y)
    y += np.float32(1.0)
    np.reciprocal(y, out=y)
    y *= np.float32(255.0)
    y += noise.reshape(y.shape)
    np.rint(y, out=y)
    np.clip(y, 0, 255, out=y)
    return y.astype(np.uint8)


def shoot_plan(shape: str, sets: int, frames: list) -> list:
    """Per set: camera (dict), number of frames, middle shutter speed, scene index."""
    plan = []
    for k in range(sets):
        if shape == "one-camera":
            cam = dict(CAMERAS[0])
        else:
            cam = dict(CAMERAS[k % len(CAMERAS)])
            if k >= len(CAMERAS):  # more sets than cameras: another body of each model
                cam["model"] = f"{cam['model']} #{k // len(CAMERAS) + 1}"
                cam["folder"] = f"{cam['folder']}_{k // len(CAMERAS) + 1}"
        plan.append(dict(camera=cam, frames=frames[k % len(frames)], t_mid=MID_TIMES[k % len(MID_TIMES)], scene=k))
    return plan


def generate_shoot(workdir: str, data: str, shape: str, mp: float, sets: int, frames: list) -> dict:
    """Generate (or reuse) one shoot; returns its description (``shoot.json``)."""
    key = f"{shape}-{mp:g}mp-{sets}sets-f{'_'.join(map(str, frames))}-v{GEN_VERSION}"
    folder = os.path.join(workdir, "shoots", key)
    marker = os.path.join(folder, "shoot.json")
    if os.path.isfile(marker):
        with open(marker) as f:
            info = json.load(f)
        if all(os.path.isfile(p) for s in info["sets"] for p in s["files"]):
            if not info.get("scan", {}).get("ok"):  # hdrcl may have been fixed since: ask again
                info["scan"] = check_with_scan(info)
                with open(marker + ".tmp", "w") as f:
                    json.dump(info, f, indent=1)
                os.replace(marker + ".tmp", marker)
            info["cached"] = True
            return info
    shutil.rmtree(folder, ignore_errors=True)
    photos = os.path.join(folder, "card")
    os.makedirs(photos)
    t0 = time.perf_counter()
    scenes = Scenes(workdir, data)
    plan = shoot_plan(shape, sets, frames)
    _log(f"generating the {shape} shoot ({sets} sets, {mp:g} MP frames) in {folder}")
    tile = _texture_tile(GEN_VERSION)
    banks = {}
    counters = {}
    start = _dt.datetime(2024, 9, 14, 9, 0, 0)
    info = {"shape": shape, "key": key, "folder": folder, "photos": photos, "mp": mp, "sets": [],
            "generator": f"shoot_bench v{GEN_VERSION}", "read_noise": READ_NOISE, "texture": TEXTURE}
    threads = max(1, os.cpu_count() or 1)
    with concurrent.futures.ThreadPoolExecutor(max_workers=threads) as pool:
        for k, p in enumerate(plan):
            cam = p["camera"]
            name, lnr = scenes[p["scene"]]
            cycle = p["scene"] // len(scenes)
            if cycle % 2:
                lnr = lnr[:, ::-1]  # a mirrored view on the second pass over the scenes
            portrait = lnr.shape[0] > lnr.shape[1]
            w, h = frame_dims(mp, cam["aspect"], portrait)
            src = crop_to_aspect(lnr, w / h)
            radiance = upscale(src, h, w)
            rng = np.random.default_rng([GEN_VERSION, k])
            _add_tiled(radiance, tile, int(rng.integers(0, 1 << 20)), int(rng.integers(0, 1 << 20)))
            if w * h not in banks:  # portrait and landscape frames share one
                banks[w * h] = _NoiseBank(w * h * 3, seed=w * h)
            bank = banks[w * h]
            times, t_mid = ladder(p["frames"], p["t_mid"])
            when = start + _dt.timedelta(seconds=SET_SPACING_S * k)
            files, jobs = [], []
            out_dir = os.path.join(photos, cam["folder"])
            os.makedirs(out_dir, exist_ok=True)
            for j, t in enumerate(times):
                n = counters.get(cam["folder"], 0) + 1
                counters[cam["folder"]] = n
                path = os.path.join(out_dir, f"{cam['prefix']}{1000 + n:04d}{cam['ext']}")
                files.append(path)
                jobs.append((path, t, when, bank.window(rng)))
                when += _dt.timedelta(seconds=t + 0.9 + 0.4 * float(rng.uniform()))  # hand bracket: ~1 s gaps

            def one(job, radiance=radiance, cam=cam, t_mid=t_mid):
                path, t, when, noise = job
                _write_jpeg(path, _expose(radiance, t / t_mid, cam, noise), cam, t, when)

            list(pool.map(one, jobs))
            del radiance
            label = cam["model"] if cam["model"].startswith(cam["make"]) else f"{cam['make']} {cam['model']}"
            info["sets"].append({"files": files, "times": times, "camera": label,
                                 "make": cam["make"], "model": cam["model"], "fnumber": cam["fnumber"],
                                 "iso": cam["iso"], "quality": cam["quality"], "scene": name,
                                 "width": w, "height": h})
            _log(f"  set {k}: {cam['model']}, {name}, {len(times)} frames {w}x{h}, "
                 f"{bench_time(times[0])} .. {bench_time(times[-1])}")
    _finish_info(info)
    info["generate_s"] = round(time.perf_counter() - t0, 1)
    info["scan"] = check_with_scan(info)
    with open(marker + ".tmp", "w") as f:
        json.dump(info, f, indent=1)
    os.replace(marker + ".tmp", marker)
    _log(f"  done in {info['generate_s']:.0f} s: {info['frames']} frames, {info['megapixels']:.0f} MP, "
         f"{info['bytes'] / 1e6:.0f} MB of JPEG ({info['bytes_per_pixel']:.2f} bytes/pixel)")
    info["cached"] = False
    return info


def _finish_info(info: dict) -> None:
    files = [p for s in info["sets"] for p in s["files"]]
    pixels = sum(s["width"] * s["height"] * len(s["files"]) for s in info["sets"])
    info["frames"] = len(files)
    info["megapixels"] = pixels / 1e6
    info["bytes"] = sum(os.path.getsize(p) for p in files)
    info["bytes_per_pixel"] = info["bytes"] / pixels


def bench_time(t: float) -> str:
    return f"1/{1 / t:.0f} s" if t < 0.35 else f"{t:g} s"


def check_with_scan(info: dict) -> dict:
    """``hdrcl scan`` reads the shoot back: the sets as generated, with their EXIF."""
    r = subprocess.run(benchlib.hdrcl_cmd("scan", info["photos"], "--recursive", "--json"),
                       capture_output=True, text=True, timeout=600)
    if r.returncode != 0:
        return {"ok": False, "problem": f"hdrcl scan failed (exit {r.returncode}): "
                                        f"{(r.stderr.strip().splitlines() or ['?'])[-1]}"}
    try:
        found = json.loads(r.stdout)["sets"]
    except (ValueError, KeyError):
        return {"ok": False, "problem": "hdrcl scan printed no JSON"}
    problems = []
    by_first = {os.path.realpath(s["files"][0]): s for s in found}
    for k, s in enumerate(info["sets"]):
        got = by_first.get(os.path.realpath(s["files"][0]))
        if got is None or [os.path.realpath(p) for p in got["files"]] != [os.path.realpath(p) for p in s["files"]]:
            problems.append(f"set {k}: grouped differently")
            continue
        if any(abs(a / b - 1) > 0.01 for a, b in zip(got.get("exposures") or [], s["times"])) \
                or len(got.get("exposures") or []) != len(s["times"]):
            problems.append(f"set {k}: exposures {got.get('exposures')} != {s['times']}")
        if s["model"] not in str(got.get("camera")):
            problems.append(f"set {k}: camera {got.get('camera')!r}, wrote {s['make']} / {s['model']}")
        if got.get("fnumber") is None or abs(got["fnumber"] - s["fnumber"]) > 0.01:
            problems.append(f"set {k}: f-number {got.get('fnumber')} != {s['fnumber']}")
        if any(i is None or abs(i - s["iso"]) > 0.5 for i in got.get("iso") or [None]):
            problems.append(f"set {k}: ISO {got.get('iso')} != {s['iso']}")
        if not got.get("start"):
            problems.append(f"set {k}: no capture time (DateTimeOriginal)")
    if len(found) != len(info["sets"]):
        problems.append(f"{len(found)} sets found, {len(info['sets'])} written")
    return {"ok": not problems, "sets_found": len(found), "problems": problems[:10]}


# --------------------------------------------------------------------------------------
# Measurements
# --------------------------------------------------------------------------------------

OPENCV_LOOP = r"""
import json, sys, time
t0 = time.perf_counter()
import cv2
import numpy as np
spec = json.load(open(sys.argv[1]))
ph = {"import_s": time.perf_counter() - t0, "imread_s": 0.0, "calibrate_s": 0.0, "merge_s": 0.0, "imwrite_s": 0.0}
for k, s in enumerate(spec["sets"]):
    t1 = time.perf_counter()
    imgs = [cv2.imread(p, cv2.IMREAD_COLOR) for p in s["files"]]
    if any(i is None for i in imgs):
        sys.exit("cv2.imread failed")
    t = np.asarray(s["times"], np.float32)
    t2 = time.perf_counter()
    resp = cv2.createCalibrateDebevec().process(imgs, t)
    t3 = time.perf_counter()
    hdr = cv2.createMergeDebevec().process(imgs, t, resp)
    t4 = time.perf_counter()
    if not cv2.imwrite(f"{spec['out']}/set{k:03d}.hdr", hdr):
        sys.exit("cv2.imwrite failed")
    del imgs, hdr
    t5 = time.perf_counter()
    for key, a, b in (("imread_s", t1, t2), ("calibrate_s", t2, t3), ("merge_s", t3, t4), ("imwrite_s", t4, t5)):
        ph[key] += b - a
ph["threads"] = cv2.getNumThreads()
ph["version"] = cv2.__version__
print(json.dumps(ph))
"""


def _run(cmd, logdir, tag, timeout=3600, cwd=None) -> dict:
    return benchlib.run_measured(cmd, logdir, tag, timeout=timeout, cwd=cwd)


def _stage_sums(report_path: str) -> dict:
    """Seconds per stage key summed over the sets of a batch report, and set counts."""
    with open(report_path) as f:
        rep = json.load(f)
    sums = {}
    for s in rep.get("sets", []):
        for k, v in (s.get("seconds") or {}).items():
            if isinstance(v, (int, float)):
                sums[k] = sums.get(k, 0.0) + float(v)
    return {"stages": sums, "summary": rep.get("summary")}


def run_batch(info: dict, work: str, logdir: str, tag: str, jobs=None, keep=None) -> dict:
    """``hdrcl batch`` on the shoot; its outputs are moved to ``keep`` (for the encode
    floor) when given, else removed."""
    out = os.path.join(work, "out", f"batch-{tag}")
    shutil.rmtree(out, ignore_errors=True)
    extra = ["--jobs", str(jobs)] if jobs else []
    res = _run(benchlib.hdrcl_cmd("batch", info["photos"], "-r", "-o", out, *extra), logdir, tag)
    rep = os.path.join(out, "report.json")
    if os.path.isfile(rep):
        try:
            res.update(_stage_sums(rep))
            shutil.copy(rep, os.path.join(logdir, f"{tag}-report.json"))
        except (OSError, ValueError) as exc:
            res["report_error"] = str(exc)
    summ = res.get("summary") or {}
    if res.get("rc") == 0 and summ.get("done") != len(info["sets"]):
        res["error"] = f"report.json: {summ} (expected {len(info['sets'])} sets done)"
        res["rc"] = -1
    if keep and res.get("rc") == 0:
        shutil.rmtree(keep, ignore_errors=True)
        os.replace(out, keep)
    shutil.rmtree(out, ignore_errors=True)
    return res


def run_encode(info: dict, work: str, logdir: str, tag: str, outputs: str) -> dict:
    """The encode floor of one batch's outputs (``outputs``: the folder run_batch kept)."""
    if not os.path.isdir(outputs):
        return {"rc": -1, "error": "the batch before it failed: no outputs to encode"}
    spec = os.path.join(work, "out", f"{info['key']}-encode.json")
    with open(spec, "w") as f:
        json.dump({"dir": outputs, "tmp": os.path.join(work, "out")}, f)
    res = _floor("encode", spec, logdir, tag)
    if res.get("rc") == 0:
        if not res["outputs"]:
            res.update(rc=-1, error=f"{outputs}: no .exr or .hdr outputs")
    shutil.rmtree(outputs, ignore_errors=True)
    return res


def run_decode(info: dict, work: str, logdir: str, tag: str) -> dict:
    spec = os.path.join(work, "out", f"{info['key']}-decode.json")
    with open(spec, "w") as f:
        json.dump({"files": [p for s in info["sets"] for p in s["files"]]}, f)
    return _floor("decode", spec, logdir, tag)


def run_fusion(info: dict, work: str, logdir: str, tag: str) -> dict:
    """The fusion floor: each set's frames fused once on the OpenCL device (decode not timed)."""
    spec = os.path.join(work, "out", f"{info['key']}-fusion.json")
    with open(spec, "w") as f:
        json.dump({"sets": [{"files": s["files"], "times": s["times"]} for s in info["sets"]]}, f)
    return _floor("fusion", spec, logdir, tag)


def _floor(kind: str, spec: str, logdir: str, tag: str) -> dict:
    """One floor (scripts/floors.py) in its own process: its wall and CPU seconds are those
    of the timed part only (not the interpreter start, the imports or untimed set-up)."""
    res = _run([sys.executable, FLOORS, kind, spec], logdir, tag)
    if res.get("rc") == 0:
        res.update(json.loads(res["stdout"].strip().splitlines()[-1]))
        res["process_wall_s"] = res["wall_s"]
        res["wall_s"] = res[f"{kind}_s"]
        res["timed_cpu_s"] = res.pop("cpu_s")
    return res


def run_opencv(info: dict, work: str, logdir: str, tag: str) -> dict:
    out = os.path.join(work, "out", f"opencv-{tag}")
    shutil.rmtree(out, ignore_errors=True)
    os.makedirs(out)
    spec = os.path.join(work, "out", f"{info['key']}-opencv.json")
    with open(spec, "w") as f:
        json.dump({"out": out, "sets": [{"files": s["files"], "times": s["times"]} for s in info["sets"]]}, f)
    res = _run([sys.executable, "-c", OPENCV_LOOP, spec], logdir, tag)
    if res.get("rc") == 0:
        res["phases"] = json.loads(res["stdout"].strip().splitlines()[-1])
    shutil.rmtree(out, ignore_errors=True)
    return res


def _warm_page_cache(info: dict) -> None:
    for s in info["sets"]:
        for p in s["files"]:
            with open(p, "rb") as f:
                while f.read(1 << 24):
                    pass


def _stats(values: list) -> dict:
    return {"median": statistics.median(values), "min": min(values), "max": max(values), "n": len(values)} \
        if values else {}


def bench_shape(info: dict, work: str, logdir: str, runs: int, opencv: str) -> dict:
    mp = info["megapixels"]
    kinds = ["hdrcl", "encode", "hdrcl_jobs2", "decode", "fusion"] + (["opencv"] if opencv else [])
    kept = os.path.join(work, "out", f"{info['key']}-outputs")
    raw = {k: [] for k in kinds}
    _warm_page_cache(info)
    for i in range(runs):  # rounds: every tool once per round, so drift hits all alike
        for k in kinds:
            tag = f"{info['shape']}-{k}-{i}"
            if k == "hdrcl":
                r = run_batch(info, work, logdir, tag, keep=kept)
            elif k == "encode":
                r = run_encode(info, work, logdir, tag, kept)
            elif k == "hdrcl_jobs2":
                r = run_batch(info, work, logdir, tag, jobs=2)
            elif k == "decode":
                r = run_decode(info, work, logdir, tag)
            elif k == "fusion":
                r = run_fusion(info, work, logdir, tag)
            else:
                r = run_opencv(info, work, logdir, tag)
            raw[k].append(r)
            _log(f"{info['shape']} round {i + 1}/{runs} {k}: " + (
                f"{r['wall_s']:.2f} s = {mp / r['wall_s']:.1f} MP/s, peak RSS {r['rss_mb']:.0f} MB, other "
                f"processes {100 * r.get('background_cpu', 0):.0f} % CPU" if r.get("rc") == 0
                else f"FAILED: {r.get('error', '?')}"))
    res = {"shape": info["shape"], "runs": runs, "figures": {}, "ratios": {}, "stages": {}}
    for k in kinds:
        ok = [r for r in raw[k] if r.get("rc") == 0]
        fig = {"failed": len(raw[k]) - len(ok), "cmd": raw[k][0].get("cmd") if raw[k] else None}
        if not ok:
            fig["error"] = raw[k][-1].get("error", "failed") if raw[k] else "not run"
        else:
            fig["seconds"] = _stats([r["wall_s"] for r in ok])
            fig["mp_per_s"] = _stats([mp / r["wall_s"] for r in ok])
            fig["rss_mb"] = max(r["rss_mb"] for r in ok)
            fig["cpu_s"] = _stats([r["user_s"] + r["sys_s"] for r in ok])  # the process tree's CPU time
            fig["background_cpu"] = _stats([r.get("background_cpu", 0.0) for r in ok])
            fig["background_all"] = [r.get("background_cpu", 0.0) for r in ok]
            if k in FLOOR_KINDS:
                fig["threads"] = ok[0].get("threads")
                fig["process_seconds"] = _stats([r["process_wall_s"] for r in ok])
                fig["timed_cpu_s"] = _stats([r["timed_cpu_s"] for r in ok])  # the floor's own CPU seconds
            if k == "fusion":
                fig["device"] = ok[0].get("device")
            if k == "encode":
                fig["outputs"], fig["output_mp"] = ok[0]["outputs"], ok[0]["output_mp"]
                fig["formats"] = ok[0]["formats"]
            if k == "opencv":
                fig["phases"] = {p: statistics.median(r["phases"][p] for r in ok)
                                 for p in ("import_s", "imread_s", "calibrate_s", "merge_s", "imwrite_s")}
                fig["threads"] = ok[0]["phases"].get("threads")
            if k.startswith("hdrcl"):
                keys = []
                for r in ok:
                    for s in r.get("stages", {}):
                        if s not in keys:
                            keys.append(s)
                res["stages"][k] = {s: statistics.median(r.get("stages", {}).get(s, 0.0) for r in ok) for s in keys}
        if fig.get("error") or fig["failed"]:
            fig.setdefault("error", f"{fig['failed']} of {len(raw[k])} runs failed: "
                                    f"{next(r.get('error') for r in raw[k] if r.get('rc') != 0)}")
        res["figures"][k] = fig

    def ratio(a, b, invert=False):
        fa, fb = res["figures"].get(a, {}), res["figures"].get(b, {})
        if "mp_per_s" not in fa or "mp_per_s" not in fb:
            return None
        of_medians = fa["mp_per_s"]["median"] / fb["mp_per_s"]["median"]
        # Each round's own ratio (its two runs are a few minutes apart at most, so a
        # neighbour's load or the machine's drift hits both alike); the median of those.
        rounds = [rb["wall_s"] / ra["wall_s"] for ra, rb in zip(raw[a], raw[b])
                  if ra.get("rc") == 0 and rb.get("rc") == 0]
        return {"median": statistics.median(rounds) if rounds else of_medians, "rounds": rounds,
                "of_medians": of_medians}

    # The I/O floor: each round's decode floor plus its encode floor.
    floors = [rd["wall_s"] + re_["wall_s"] for rd, re_ in zip(raw["decode"], raw["encode"])
              if rd.get("rc") == 0 and re_.get("rc") == 0]
    if floors:
        res["figures"]["io_floor"] = {"seconds": _stats(floors), "mp_per_s": _stats([mp / f for f in floors]),
                                      "failed": len(raw["decode"]) - len(floors)}
    for h in ("hdrcl", "hdrcl_jobs2"):
        suffix = "" if h == "hdrcl" else "_jobs2"
        res["ratios"]["vs_opencv" + suffix] = ratio(h, "opencv")
        res["ratios"]["vs_decode" + suffix] = ratio(h, "decode")
        # batch wall / I/O floor, round by round (lower is better; 1 = the floor)
        rounds = [rh["wall_s"] / (rd["wall_s"] + re_["wall_s"]) for rh, rd, re_ in
                  zip(raw[h], raw["decode"], raw["encode"]) if rh.get("rc") == 0 and rd.get("rc") == 0
                  and re_.get("rc") == 0]
        res["ratios"]["io_floor" + suffix] = {"median": statistics.median(rounds), "rounds": rounds} \
            if rounds else None
        res["ratios"]["cpu_floor" + suffix] = cpu_floor_ratio(raw[h], raw["decode"], raw["encode"], raw["fusion"])
    return res


def cpu_floor_ratio(batch: list, decode: list, encode: list, fusion: list):
    """Batch CPU-seconds (user + system of the batch process) over the CPU-seconds of the
    decode, encode and fusion floors, round by round (issue 33: <= 1.3x); None where a
    round failed throughout."""
    rounds, parts = [], []
    for rb, rd, re_, rf in zip(batch, decode, encode, fusion):
        if all(r.get("rc") == 0 for r in (rb, rd, re_, rf)):
            floor = rd["timed_cpu_s"] + re_["timed_cpu_s"] + rf["timed_cpu_s"]
            rounds.append((rb["user_s"] + rb["sys_s"]) / floor)
            parts.append((rb["user_s"] + rb["sys_s"], rd["timed_cpu_s"], re_["timed_cpu_s"], rf["timed_cpu_s"]))
    if not rounds:
        return None
    med = [statistics.median(p[i] for p in parts) for i in range(4)]
    return {"median": statistics.median(rounds), "rounds": rounds, "batch_cpu_s": med[0], "decode_cpu_s": med[1],
            "encode_cpu_s": med[2], "fusion_cpu_s": med[3]}


def bench_startup(work: str, logdir: str, data: str, runs: int) -> dict:
    """``hdrcl --version`` and a tiny merge (frobisher, 3 x 0.27 MP), whole processes."""
    out = {"runs": runs}
    if runs <= 0:
        return out
    v = [_run(benchlib.hdrcl_cmd("--version"), logdir, f"startup-version-{i}", timeout=300) for i in range(runs)]
    ok = [r["wall_s"] for r in v if r.get("rc") == 0]
    out["version"] = {"seconds": _stats(ok), "cmd": v[0].get("cmd"),
                      "cpu_s": _stats([r["user_s"] + r["sys_s"] for r in v if r.get("rc") == 0])} \
        if ok else {"error": v[-1].get("error")}
    fro = os.path.join(data, "frobisher_001")
    frames = sorted(os.path.join(fro, f) for f in os.listdir(fro) if f.lower().endswith(".jpg")) \
        if os.path.isdir(fro) else []
    if len(frames) < 2:
        out["tiny_merge"] = {"error": f"{fro}: no frames"}
        return out
    dst = os.path.join(work, "out", "tiny.exr")
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    # No warm-up run: the batch runs before this one have built (and cached) the kernels.
    m = [_run(benchlib.hdrcl_cmd("merge", *frames, "-o", dst), logdir, f"startup-merge-{i}", timeout=300)
         for i in range(runs)]
    ok = [r["wall_s"] for r in m if r.get("rc") == 0]
    out["tiny_merge"] = {"seconds": _stats(ok), "cmd": m[0].get("cmd"), "frames": len(frames),
                         "cpu_s": _stats([r["user_s"] + r["sys_s"] for r in m if r.get("rc") == 0]),
                         "rss_mb": max(r["rss_mb"] for r in m if r.get("rc") == 0)} if ok \
        else {"error": m[-1].get("error")}
    return out


# --------------------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------------------

def _mmm(st: dict, fmt: str = "{:.2f}") -> str:
    if not st:
        return "-"
    if st["n"] == 1:
        return fmt.format(st["median"])
    return f"{fmt.format(st['median'])} [{fmt.format(st['min'])} - {fmt.format(st['max'])}]"


def _verdict(value, target) -> str:
    if value is None:
        return "not measured"
    if value >= target:
        return "ok"
    return f"MISSED: reaches {100 * value / target:.0f} % of the target (needs {target / value:.2f}x)"


def print_report(res: dict) -> None:
    p = print
    m = res["machine"]
    p("")
    p("hdrcl shoot benchmark (scripts/shoot_bench.py)")
    p(f"  processor: {m.get('lscpu') or m.get('cpu')} (lscpu), {m.get('cpu_count')} cores, {m.get('memory_gb')} GB")
    p(f"  OpenCL: {m.get('opencl_device')}")
    p(f"  hdrcl {m.get('hdrcl')} {m.get('hdrcl_git', '')}, Python {m.get('python')}, NumPy {m.get('numpy')}, "
      f"OpenImageIO {m.get('openimageio')}, OpenCV {res.get('opencv_version') or 'not measured'}")
    p(f"  {res['runs']} run(s) per figure, in rounds; figures are median [min - max]; "
      f"MP = input megapixels (frames x pixels, summed over the shoot)")
    p("  CPU s: user + system time of the process tree (median); other CPU: the largest share of the machine "
      "other processes used during a run")
    for s in res["shapes"]:
        info, r = s["info"], s["result"]
        sizes = sorted({f"{x['width']}x{x['height']}" for x in info["sets"]})
        cams = sorted({x["camera"] for x in info["sets"]})
        p("")
        p(f"shape {info['shape']}: {len(info['sets'])} sets x "
          f"{'/'.join(str(len(x['files'])) for x in info['sets'])} frames, "
          f"{len(cams)} camera{'s' if len(cams) > 1 else ''}"
          + (f" ({cams[0]})" if len(cams) == 1 else "")
          + f", {', '.join(sizes)} ({info['mp']:g} MP), {info['frames']} frames = {info['megapixels']:.0f} MP input, "
          f"JPEG q{'/'.join(sorted({str(x['quality']) for x in info['sets']}))}, {info['bytes'] / 1e6:.0f} MB "
          f"({info['bytes_per_pixel']:.2f} B/px)")
        sc = info.get("scan", {})
        p(f"  hdrcl scan reads it back: " + (f"{sc.get('sets_found')} sets, EXIF as written" if sc.get("ok")
                                            else f"PROBLEM: {sc.get('problem') or '; '.join(sc.get('problems', []))}"))
        p(f"  {'figure':48s} {'seconds':>23s} {'MP/s':>22s} {'CPU s':>7s} {'peak RSS':>9s} {'other CPU':>9s}")
        names = {"hdrcl": "hdrcl batch SHOOT -r -o OUT (defaults)",
                 "hdrcl_jobs2": "hdrcl batch SHOOT -r -o OUT --jobs 2",
                 "decode": "decode floor (OIIO, {t} threads, decode only)",
                 "encode": "encode floor (OIIO, {t} threads, the outputs)",
                 "io_floor": "I/O floor (decode + encode floor)",
                 "fusion": "fusion floor (OpenCL, decoded frames)",
                 "opencv": "OpenCV loop ({t} threads: imread, Debevec, .hdr)"}
        for k in ("hdrcl", "hdrcl_jobs2", "decode", "encode", "io_floor", "fusion", "opencv"):
            f = r["figures"].get(k)
            if f is None:
                if k == "opencv":
                    p(f"  {'OpenCV loop':48s} not measured ({res.get('opencv_note')})")
                continue
            name = names[k].format(t=f.get("threads", "?"))
            if "seconds" in f and k == "io_floor":
                p(f"  {name:48s} {_mmm(f['seconds']):>23s} {_mmm(f['mp_per_s'], '{:.1f}'):>22s}")
            elif "seconds" in f:
                rss = f"{f['rss_mb']:.0f} MB"
                bg = f"{100 * f['background_cpu']['max']:.0f} %"
                p(f"  {name:48s} {_mmm(f['seconds']):>23s} {_mmm(f['mp_per_s'], '{:.1f}'):>22s} "
                  f"{f['cpu_s']['median']:7.1f} {rss:>9s} {bg:>9s}"
                  + (f"  ({f['failed']} failed)" if f.get("failed") else ""))
            else:
                p(f"  {name:48s} FAILED: {f.get('error')}")
        dec = r["figures"].get("decode", {})
        if "process_seconds" in dec:
            p(f"    (decode floor as a whole process, interpreter and imports included: "
              f"{_mmm(dec['process_seconds'])} s)")
        enc = r["figures"].get("encode", {})
        if "outputs" in enc:
            p(f"    (encode floor: {enc['outputs']} outputs, {enc['output_mp']:.1f} MP, "
              f"{', '.join(enc['formats'])}, as the batch wrote them)")
        _print_cpu_floor(r)
        v = r["ratios"].get("io_floor")
        v2 = r["ratios"].get("io_floor_jobs2")
        if v:
            verdict = "ok" if v["median"] <= TARGETS["io_floor"] else \
                f"MISSED: needs {v['median'] / TARGETS['io_floor']:.2f}x less time"
            jobs2 = f"{v2['median']:.2f}x" if v2 else "-"
            p(f"  {'batch wall / I/O floor':22s} {v['median']:.2f}x [" + ", ".join(f"{x:.2f}x" for x in v["rounds"])
              + f"]; --jobs 2: {jobs2}   target <= {TARGETS['io_floor']:g}x: {verdict}")
        else:
            p(f"  {'batch wall / I/O floor':22s} not measured (a batch, decode or encode run failed)")
        p("  ratios of MP/s, hdrcl defaults: the median of each round's own ratio [every round]; --jobs 2 beside")
        for key, label, target, pct in (("vs_opencv", "hdrcl / OpenCV", TARGETS["vs_opencv"], False),
                                        ("vs_decode", "hdrcl / decode floor", TARGETS["vs_decode"], True)):
            v, v2 = r["ratios"].get(key), r["ratios"].get(key + "_jobs2")

            def fmt(x):
                return "-" if x is None else (f"{100 * x:.0f} %" if pct else f"{x:.2f}x")

            def rounds(x):
                return "" if not x or not x["rounds"] else " [" + ", ".join(fmt(y) for y in x["rounds"]) + "]"

            med = v["median"] if v else None
            tt = f">= {100 * target:.0f} %" if pct else f">= {target:g}x"
            p(f"  {label:22s} {fmt(med)}{rounds(v)}; --jobs 2: {fmt(v2['median'] if v2 else None)}"
              f"   target {tt}: {_verdict(med, target)}")
        ph = r["figures"].get("opencv", {}).get("phases")
        if ph:
            p(f"  OpenCV phases (s, summed over sets, median): import {ph['import_s']:.2f}, imread "
              f"{ph['imread_s']:.2f}, calibrate {ph['calibrate_s']:.2f}, merge {ph['merge_s']:.2f}, "
              f"imwrite {ph['imwrite_s']:.2f}")
        st = r.get("stages", {})
        if st:
            keys = [k for k in STAGE_ORDER if any(k in st[h] for h in st)]
            keys += [k for h in st for k in st[h] if k not in keys and k not in STAGE_ORDER]
            keys = list(dict.fromkeys(keys))
            cols = [h for h in ("hdrcl", "hdrcl_jobs2") if h in st]
            p("  hdrcl stage seconds from OUT/report.json, summed over sets (median of runs):")
            p("    " + f"{'stage':12s}" + "".join(f"{('defaults' if h == 'hdrcl' else '--jobs 2'):>11s}" for h in cols))
            for k in keys:
                p("    " + f"{k:12s}" + "".join(f"{st[h][k]:11.2f}" if k in st[h] else f"{'-':>11s}" for h in cols))
            p("    " + f"{'batch wall':12s}" + "".join(
                f"{r['figures'][h]['seconds']['median']:11.2f}" if "seconds" in r["figures"][h] else f"{'-':>11s}"
                for h in cols) + "  (stages overlap; work outside the sets, e.g. the scan and a pooled"
                                 " calibration, shows only in the wall time)")
    su = res.get("startup", {})
    if su.get("runs"):
        p("")
        p(f"start-up (whole processes, {su['runs']} runs, median [min - max]):")
        for k, label in (("version", "hdrcl --version"), ("tiny_merge", "hdrcl merge frobisher_001/*.jpg -o X.exr")):
            e = su.get(k, {})
            p(f"  {label:48s} " + (f"{_mmm(e['seconds'])} s, CPU {e['cpu_s']['median']:.2f} s" if "seconds" in e
                                   else f"FAILED: {e.get('error')}"))
    bg = res.get("background", {})
    if bg.get("runs"):
        p("")
        p(f"other processes used {100 * bg['mean']:.0f} % of the CPU on average during the measured runs "
          f"(max {100 * bg['max']:.0f} %, {bg['over_10pct']} of {bg['runs']} runs above 10 %)"
          + ("  <- figures may be pessimistic; rerun on an idle machine" if bg["max"] > 0.10 else ""))
    p(f"elapsed {res['elapsed_s'] / 60:.1f} min; JSON: {res['json']}; logs: {res['logs']}")


def _print_cpu_floor(r: dict) -> None:
    """Batch CPU-seconds beside decode + encode + fusion CPU-seconds, and their ratio."""
    v, v2 = r["ratios"].get("cpu_floor"), r["ratios"].get("cpu_floor_jobs2")
    fl = {k: r["figures"].get(k, {}).get("timed_cpu_s") for k in FLOOR_KINDS}
    if fl["decode"] and fl["encode"] and fl["fusion"]:
        print(f"    (floors' own CPU-seconds, median: decode {fl['decode']['median']:.2f}, encode "
              f"{fl['encode']['median']:.2f}, fusion {fl['fusion']['median']:.2f}; CPU s above: whole processes)")
    if not v:
        print(f"  {'batch CPU-s / floors':22s} not measured (a batch or floor run failed)")
        return
    floors = v["decode_cpu_s"] + v["encode_cpu_s"] + v["fusion_cpu_s"]
    print(f"  batch CPU-seconds {v['batch_cpu_s']:.2f} (user + system of the batch process); decode + encode + "
          f"fusion CPU-seconds {v['decode_cpu_s']:.2f} + {v['encode_cpu_s']:.2f} + {v['fusion_cpu_s']:.2f} = "
          f"{floors:.2f}")
    verdict = "ok" if v["median"] <= TARGETS["cpu_floor"] else \
        f"MISSED: needs {v['median'] / TARGETS['cpu_floor']:.2f}x less CPU"
    jobs2 = f"{v2['median']:.2f}x" if v2 else "-"
    print(f"  {'batch CPU-s / floors':22s} {v['median']:.2f}x [" + ", ".join(f"{x:.2f}x" for x in v["rounds"])
          + f"]; --jobs 2: {jobs2}   target <= {TARGETS['cpu_floor']:g}x: {verdict}")


def _lscpu_model() -> str:
    """``lscpu``'s model name, family and model, and hypervisor (e.g. "AMD EPYC, family 25 model 1, KVM")."""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return ""
    f = {k.strip(): v.strip() for k, _, v in (line.partition(":") for line in out.splitlines())}
    parts = [f.get("Model name", "")]
    if f.get("CPU family") and f.get("Model"):
        parts.append(f"family {f['CPU family']} model {f['Model']}")
    if f.get("Hypervisor vendor"):
        parts.append(f"{f['Hypervisor vendor']} guest")
    return ", ".join(p for p in parts if p)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shape", choices=SHAPES + ("both",), default="both",
                    help="one-camera: several sets from one camera (pooled response); per-camera: one set per "
                         "camera [default: both]")
    ap.add_argument("--mp", type=float, default=12.0, help="frame size in megapixels [default: 12]")
    ap.add_argument("--sets", type=int, default=5, help="sets per shoot [default: 5]")
    ap.add_argument("--frames", default=None,
                    help="frames per set, a number or a comma list cycled over the sets [default: one-camera "
                         f"{DEFAULT_FRAMES['one-camera']}, per-camera {DEFAULT_FRAMES['per-camera']}]")
    ap.add_argument("--runs", type=int, default=3, help="runs of each figure, median/min/max reported [default: 3]")
    ap.add_argument("--startup-runs", type=int, default=5,
                    help="runs of each start-up figure; 0 leaves them out [default: 5]")
    ap.add_argument("--skip-opencv", action="store_true", help="leave the OpenCV loop out")
    ap.add_argument("--workdir", "--work", default=os.path.join(tempfile.gettempdir(), "hdrcl-shoot-bench"),
                    help="generated shoots (cached, keyed by their parameters), outputs and logs "
                         "[default: $TMPDIR/hdrcl-shoot-bench]")
    ap.add_argument("--data", default=os.path.join(os.path.dirname(ROOT), "shared", "data"),
                    help="folder of the real scenes (memorial, window_e995, frobisher_001) "
                         "[default: ../shared/data beside the checkout]")
    ap.add_argument("--json", default=None, help="results file [default: WORKDIR/shoot-bench-results.json]")
    ap.add_argument("--wait-idle", type=float, default=0.0, metavar="SECONDS",
                    help="before each measured run, wait up to this long for other processes to use < 15 %% "
                         "of the CPU (shared machines, as in bench.py) [default: 0, do not wait]")
    ap.add_argument("--generate-only", action="store_true", help="generate (or check) the shoots and stop")
    a = ap.parse_args(argv)
    benchlib.ensure_importable()
    if a.mp <= 0 or a.sets < 1 or a.runs < 1:
        raise SystemExit("--mp must be > 0, --sets and --runs >= 1")

    t_start = time.perf_counter()
    benchlib.WAIT_IDLE["max_s"] = max(0.0, a.wait_idle)
    work = os.path.abspath(a.workdir)
    logdir = os.path.join(work, "logs")
    os.makedirs(os.path.join(work, "out"), exist_ok=True)
    shapes = SHAPES if a.shape == "both" else (a.shape,)
    data = os.path.abspath(a.data)
    infos = []
    for shape in shapes:
        frames = parse_frames(a.frames or DEFAULT_FRAMES[shape])
        info = generate_shoot(work, data, shape, a.mp, a.sets, frames)
        if info.get("cached"):
            _log(f"{shape} shoot: cached in {info['folder']}")
        if not info.get("scan", {}).get("ok"):
            _log(f"WARNING: hdrcl scan does not read the {shape} shoot back as written: {info.get('scan')}")
        infos.append(info)
    if a.generate_only:
        for info in infos:
            print(f"{info['shape']}: {info['photos']} ({info['frames']} frames, {info['megapixels']:.0f} MP, "
                  f"scan {'ok' if info['scan'].get('ok') else info['scan']})")
        return 0

    json_path = os.path.abspath(a.json or os.path.join(work, "shoot-bench-results.json"))
    res = {"command": " ".join(sys.argv) if argv is None else "shoot_bench " + " ".join(map(str, argv)),
           "started": _dt.datetime.now().isoformat(timespec="seconds"), "runs": a.runs, "json": json_path,
           "logs": logdir, "targets": TARGETS, "shapes": []}
    res["machine"] = benchlib.machine_facts(logdir)
    res["machine"]["lscpu"] = _lscpu_model()
    _log(f"machine: {res['machine'].get('cpu')}, {res['machine'].get('cpu_count')} cores; "
         f"OpenCL {res['machine'].get('opencl_device')}")
    res["opencv_version"] = "" if a.skip_opencv else benchlib.have_opencv()
    res["opencv_note"] = "--skip-opencv" if a.skip_opencv else (
        "" if res["opencv_version"] else "OpenCV not installed: pip install '.[bench]'")
    if res["opencv_note"] and not a.skip_opencv:
        _log(res["opencv_note"])
    for info in infos:
        _log(f"measuring the {info['shape']} shoot: {info['frames']} frames, {info['megapixels']:.0f} MP")
        res["shapes"].append({"info": info, "result": bench_shape(info, work, logdir, a.runs, res["opencv_version"])})
    if a.startup_runs > 0:
        _log("start-up: hdrcl --version and a tiny merge")
    res["startup"] = bench_startup(work, logdir, data, a.startup_runs)
    bgs = [b for s in res["shapes"] for f in s["result"]["figures"].values() for b in f.get("background_all", [])]
    if bgs:
        res["background"] = {"mean": statistics.mean(bgs), "max": max(bgs), "runs": len(bgs),
                             "over_10pct": sum(1 for b in bgs if b > 0.10)}
    res["elapsed_s"] = time.perf_counter() - t_start
    os.makedirs(os.path.dirname(json_path), exist_ok=True)
    with open(json_path, "w") as f:
        json.dump(res, f, indent=1, default=float)
    print_report(res)
    failed = [f"{s['info']['shape']} {k}" for s in res["shapes"] for k, f in s["result"]["figures"].items()
              if f.get("failed") or "seconds" not in f]
    if failed:
        _log(f"runs failed ({', '.join(failed)}): see {logdir}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
