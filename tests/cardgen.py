"""Synthetic camera cards: bracket sets shot the way people shoot, with the true grouping.

Test helper (OpenImageIO and NumPy only, no hdrcl). Each scenario is a list of *sets*
(or stray frames) on one timeline; :func:`write_card` writes them as small JPEGs with
real EXIF (DateTimeOriginal, SubSecTimeOriginal, ExposureTime, FNumber, ISO,
ExposureBiasValue, ExposureMode, camera) and returns the true grouping.

Every set shows its own scene (a seeded radiance field; a tripod: the frames of one set
differ only by exposure and noise, hand held ones by a pixel of shake). Scenarios
(:data:`SCENARIOS`):

``manual_long_gaps``
    A phone in pro mode / a DSLR without AEB: the shutter changed by hand, 5-60 s
    between frames, a clean one-stop ladder; sets 3 minutes apart.
``back_to_back``
    Three sets with the *same* ladder on one tripod position after another, minutes
    apart, the frames 2-25 s apart.
``auto_iso``
    Auto ISO: both time and ISO change, ``t * ISO`` is the one-stop ladder.
``exposure_comp``
    Phone auto mode with exposure compensation: ExposureBiasValue steps -2..+2 (or
    0,-2,+2), time and ISO follow the metering (with its noise), 3-20 s apart.
``subsecond``
    Auto brackets of 3-5 frames fired in 0.1 s, several frames in one DateTimeOriginal
    second; only SubSecTimeOriginal orders them (file names are not in capture order).
``aeb_orders``
    Auto bracketing in the orders ``0,-,+``, ``0,-2,+2,-4,+4`` and ``-,0,+``, back to
    back (0.5-2 s apart).
``scene_only``
    Three hand ladders on three views, each continuing the ladder of the one before,
    5 s and 40 s apart: only the content tells the sets apart.
``mixed``
    All of the above on one card, one camera, in one timeline, with stray frames.
"""
from __future__ import annotations

import datetime as _dt
import os
from dataclasses import dataclass, field
from typing import Dict, List, Optional

import numpy as np

__all__ = ["SCENARIOS", "write_card", "write_shots", "scenario", "Shot", "Frame"]

WIDTH, HEIGHT = 96, 64
T0 = _dt.datetime(2025, 3, 14, 9, 0, 0)

PHONE = {"make": "Google", "model": "Pixel 8", "serial": None, "lens": None, "focal_length": 6.9}
DSLR = {"make": "NIKON CORPORATION", "model": "NIKON D750", "serial": "3051234",
        "lens": "24.0-70.0 mm f/2.8", "focal_length": 24.0}

# Nominal shutter speeds cameras write (1/3 stops).
_NOMINAL = [1 / d for d in (8000, 6400, 5000, 4000, 3200, 2500, 2000, 1600, 1250, 1000, 800, 640, 500, 400, 320,
                            250, 200, 160, 125, 100, 80, 60, 50, 40, 30, 25, 20, 15, 13, 10, 8, 6, 5, 4, 3, 2.5,
                            2, 1.6, 1.3)] + [1.0, 1.3, 1.6, 2.0, 2.5, 3.2, 4.0, 5.0, 6.0, 8.0, 10.0, 13.0, 15.0, 20.0,
                                             25.0, 30.0]


def nominal(t: float) -> float:
    """The shutter speed a camera would write for ``t`` seconds."""
    return min(_NOMINAL, key=lambda v: abs(np.log2(v / t)))


@dataclass
class Frame:
    time: float
    iso: float = 100.0
    fnumber: float = 8.0
    bias: Optional[float] = None
    mode: int = 1  # EXIF ExposureMode: 0 auto, 1 manual, 2 auto bracket
    gap: float = 1.0  # end-to-start seconds after the previous frame
    shake: int = 0


@dataclass
class Shot:
    """One set (``merge`` True) or stray frames, in capture order."""

    frames: List[Frame]
    merge: bool = True
    camera: dict = field(default_factory=lambda: dict(DSLR))
    label: str = ""


def _ladder(times, *, gaps, iso=100.0, mode=1, fnumber=8.0, first_gap=200.0, isos=None, biases=None):
    out = []
    for i, t in enumerate(times):
        out.append(Frame(time=t, iso=isos[i] if isos else iso, fnumber=fnumber, mode=mode,
                         bias=None if biases is None else biases[i], gap=first_gap if i == 0 else gaps[i - 1]))
    return out


def scenario(name: str, rng: np.random.Generator) -> List[Shot]:
    """The shots of scenario ``name`` (see the module docstring)."""
    if name == "manual_long_gaps":
        a = [nominal(1 / 1000 * 2 ** k) for k in range(9)]
        b = [nominal(1 / 15 / 2 ** k) for k in range(7)]  # descending
        c = [nominal(1 / 250 * 4 ** k) for k in range(4)]  # 2-stop steps
        return [Shot(_ladder(a, gaps=rng.uniform(5, 60, 8)), label="manual 9 frames, 5-60 s apart"),
                Shot(_ladder(b, gaps=rng.uniform(5, 60, 6), first_gap=180.0), label="manual descending"),
                Shot(_ladder(c, gaps=rng.uniform(20, 60, 3), first_gap=240.0), label="manual 2-stop steps")]
    if name == "back_to_back":
        lad = [1 / 500, 1 / 125, 1 / 30, 1 / 8]
        return [Shot(_ladder(lad, gaps=rng.uniform(2, 25, 3), first_gap=g), label="same ladder")
                for g in (10.0, 150.0, 240.0)]
    if name == "auto_iso":
        t1 = [1 / 60, 1 / 60, 1 / 30, 1 / 15, 1 / 15]
        i1 = [200, 400, 400, 400, 800]  # t*ISO: 1-stop steps
        t2 = [1 / 250, 1 / 125, 1 / 125, 1 / 60, 1 / 60]
        i2 = [100, 100, 200, 200, 400]
        return [Shot(_ladder(t1, isos=i1, gaps=rng.uniform(3, 15, 4), first_gap=30.0, mode=0), label="auto ISO up"),
                Shot(_ladder(t2, isos=i2, gaps=rng.uniform(3, 15, 4), first_gap=200.0, mode=0), label="auto ISO 2")]
    if name == "exposure_comp":
        shots = []
        for evs, base, first in (([-2, -1, 0, 1, 2], 1 / 120, 20.0), ([0, -2, 2], 1 / 400, 90.0),
                                 ([-2, -1, 0, 1, 2], 1 / 60, 150.0)):
            frames = []
            for i, ev in enumerate(evs):
                e = base * 2.0 ** ev * 2.0 ** rng.normal(0, 0.12)  # the metering drifts
                iso = float(np.clip(50 * 2 ** round(max(0.0, np.log2(e / (1 / 30)) + 0.5)), 50, 3200))
                t = e * 100.0 / iso
                frames.append(Frame(time=t, iso=iso, fnumber=1.7, bias=float(ev), mode=0,
                                    gap=first if i == 0 else rng.uniform(3, 20), shake=int(rng.integers(0, 2))))
            shots.append(Shot(frames, camera=dict(PHONE), label=f"exposure compensation {evs}"))
        return shots
    if name == "subsecond":
        shots = []
        for evs, base, first in (([0, -1, 1], 1 / 500, 30.0), ([0, -1, 1], 1 / 320, 0.3),
                                 ([0, -1, 1, -2, 2], 1 / 800, 0.25), ([-1, 0, 1], 1 / 200, 40.0)):
            frames = [Frame(time=nominal(base * 2.0 ** ev), bias=float(ev), mode=2, gap=first if i == 0 else 0.08)
                      for i, ev in enumerate(evs)]
            shots.append(Shot(frames, label=f"AEB burst {evs}"))
        return shots
    if name == "aeb_orders":
        shots = []
        for evs, base, first in (([0, -1, 1], 1 / 125, 60.0), ([0, -2, 2, -4, 4], 1 / 60, 1.5),
                                 ([-1, 0, 1], 1 / 30, 0.8), ([0, -2, 2], 1 / 30 * 1.26, 2.0)):
            frames = [Frame(time=nominal(base * 2.0 ** ev), bias=float(ev), mode=2, gap=first if i == 0 else 0.2)
                      for i, ev in enumerate(evs)]
            shots.append(Shot(frames, label=f"AEB {evs}"))
        return shots
    if name == "scene_only":
        # Each set's ladder continues the one before, on another view: only the scene
        # tells them apart (5 s after one set, and 40 s after the next).
        return [Shot(_ladder([1 / 1000, 1 / 500, 1 / 250], gaps=[3.0, 3.0], first_gap=60.0), label="view 1"),
                Shot(_ladder([1 / 125, 1 / 60, 1 / 30], gaps=[3.0, 3.0], first_gap=5.0), label="view 2"),
                Shot(_ladder([1 / 15, 1 / 8, 1 / 4], gaps=[20.0, 30.0], first_gap=40.0), label="view 3")]
    raise ValueError(name)


SCENARIOS = ("manual_long_gaps", "back_to_back", "auto_iso", "exposure_comp", "subsecond", "aeb_orders",
             "scene_only")


def _mixed(rng) -> List[Shot]:
    shots = []
    for k, name in enumerate(SCENARIOS):
        block = scenario(name, rng)
        block[0].frames[0].gap = 300.0  # a few minutes between scenarios
        shots.extend(block)
        if k % 2 == 1:  # a stray frame
            shots.append(Shot([Frame(time=1 / 100, mode=0, gap=120.0)], merge=False, label="stray frame"))
    return shots


def _scene(rng) -> np.ndarray:
    """A radiance field of its own: ramp in a random direction, blobs, texture."""
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    ang = rng.uniform(0, 2 * np.pi)
    u = (np.cos(ang) * (x - WIDTH / 2) + np.sin(ang) * (y - HEIGHT / 2)) / (WIDTH / 2)
    base = np.exp(np.log(300.0) * (u + 1) / 2)
    for _ in range(8):
        cx, cy, r = rng.uniform(0, WIDTH), rng.uniform(0, HEIGHT), rng.uniform(4, 14)
        base *= np.exp(rng.uniform(-1.5, 1.5) * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * r * r)))
    f1, f2 = rng.uniform(0.2, 0.9, 2)
    base *= 1.0 + 0.2 * np.sin(x * f1 + rng.uniform(0, 6)) * np.cos(y * f2)
    rad = base * 0.02
    tint = rng.uniform(0.7, 1.0, 3)
    return rad[:, :, None] * tint


def _write(path, radiance, fr: Frame, when: _dt.datetime, camera: dict, rng, subsec_digits: int = 3):
    import OpenImageIO as oiio

    exposure = fr.time * (fr.iso / 100.0) * (8.0 / fr.fnumber) ** 2
    rad = np.roll(radiance, fr.shake, axis=1) if fr.shake else radiance
    lin = np.clip(rad * exposure * 4.0, 0.0, 1.0)
    pixels = 255.0 * lin ** (1 / 2.2) + rng.normal(0.0, 1.0, rad.shape)
    data = np.clip(np.round(pixels), 0, 255).astype(np.uint8)
    spec = oiio.ImageSpec(WIDTH, HEIGHT, 3, oiio.UINT8)
    spec.attribute("ExposureTime", oiio.TypeFloat, float(fr.time))
    spec.attribute("FNumber", oiio.TypeFloat, float(fr.fnumber))
    spec.attribute("Exif:PhotographicSensitivity", oiio.TypeInt, int(round(fr.iso)))
    if fr.bias is not None:
        spec.attribute("Exif:ExposureBiasValue", oiio.TypeFloat, float(fr.bias))
    spec.attribute("Exif:ExposureMode", oiio.TypeInt, int(fr.mode))
    spec.attribute("Exif:DateTimeOriginal", when.strftime("%Y:%m:%d %H:%M:%S"))
    sub = f"{when.microsecond:06d}"[:subsec_digits]
    spec.attribute("Exif:SubsecTimeOriginal", sub)
    spec.attribute("DateTime", when.strftime("%Y:%m:%d %H:%M:%S"))
    spec.attribute("Make", camera["make"])
    spec.attribute("Model", camera["model"])
    if camera.get("serial"):
        spec.attribute("Exif:BodySerialNumber", camera["serial"])
    if camera.get("lens"):
        spec.attribute("Exif:LensModel", camera["lens"])
    spec.attribute("Exif:FocalLength", oiio.TypeFloat, float(camera["focal_length"]))
    out = oiio.ImageOutput.create(os.fspath(path))
    try:
        if not out.open(os.fspath(path), spec) or not out.write_image(data):
            raise RuntimeError(f"cannot write {path}: {out.geterror()}")
    finally:
        out.close()


def write_card(folder, name: str, seed: int = 0) -> Dict:
    """Write scenario ``name`` (or ``"mixed"``) into ``folder``.

    Returns
    -------
    dict
        ``"sets"``: list of base-name lists, each a true bracket set in capture order,
        ordered by capture time; ``"unmerged"``: base names of stray frames;
        ``"labels"``: one label per set.
    """
    rng = np.random.default_rng([seed, len(name)])
    shots = _mixed(rng) if name == "mixed" else scenario(name, rng)
    return write_shots(folder, shots, seed=seed, scrambled=name in ("subsecond", "mixed"), rng=rng)


def write_shots(folder, shots: List[Shot], seed: int = 0, scrambled: bool = False, rng=None) -> Dict:
    """Write ``shots`` (one scene per shot) into ``folder``; returns as :func:`write_card`.

    ``scrambled``: name the files so that their names do not follow capture order.
    """
    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    rng = rng if rng is not None else np.random.default_rng(seed)
    sets, labels, stray = [], [], []
    n = 0
    prev_end = None
    for k, shot in enumerate(shots):
        scene = _scene(np.random.default_rng([seed, 7, k]))
        names = []
        for fr in shot.frames:
            start = T0 if prev_end is None else prev_end + _dt.timedelta(seconds=fr.gap)
            n += 1
            # Names follow capture order, except in sub-second scenarios, where a
            # scrambled name makes SubSecTimeOriginal the only way to order frames.
            base = f"IMG_{n:04d}.jpg" if not scrambled else f"P{(n * 7919) % 10007:05d}.jpg"
            digits = 2 if n % 3 == 0 else 3
            _write(os.path.join(folder, base), scene, fr, start, shot.camera, rng, subsec_digits=digits)
            names.append(base)
            prev_end = start + _dt.timedelta(seconds=fr.time)
            # A camera rounds the sub-second field: keep the timeline on what it wrote.
            us = (start.microsecond // (10 ** (6 - digits))) * 10 ** (6 - digits)
            prev_end = start.replace(microsecond=us) + _dt.timedelta(seconds=fr.time)
        if shot.merge:
            sets.append(names)
            labels.append(shot.label)
        else:
            stray.extend(names)
    return {"sets": sets, "unmerged": stray, "labels": labels}
