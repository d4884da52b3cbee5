#!/usr/bin/env python3
"""The generated shoots of ``scripts/shoot_bench.py`` (also used by ``report_bench.py``):
folders of camera-sized JPEGs with camera EXIF, in a card's layout.

Frames are made from the real scenes in ``../shared/data`` (memorial, window_e995,
frobisher_001): a radiance map estimated from each bracket, cropped to the camera's
aspect ratio, upscaled (separable cubic) with a little fine texture, photographed
through a known S-shaped response per camera (:data:`CAMERAS`), plus read noise, JPEG
quality 92-95. Without that folder, a synthetic scene
(``hdrcl.core.synthetic.radiance_field``) is used. :func:`generate_shoot` writes a shoot
once (cached under ``WORKDIR/shoots``) and checks that ``hdrcl scan`` reads it back as
written. Imports no other script but ``benchlib``.
"""
from __future__ import annotations

import concurrent.futures
import datetime as _dt
import json
import math
import os
import shutil
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)

import benchlib  # noqa: E402  (scripts/benchlib.py: the hdrcl command line)

#: Bump when generated shoots change, so cached ones are regenerated.
GEN_VERSION = 1

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
