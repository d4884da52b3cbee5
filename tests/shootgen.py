"""Generate a small bracketed "shoot" of JPEGs with real EXIF, and its true grouping.

Test helper shared by the grouping and batch tests; it imports OpenImageIO and NumPy
only (no hdrcl), so any test can use it.

The shoot (camera A unless noted; times are capture starts, gaps end-to-start)::

    IMG_0001-0003  hand bracket, manual, 3 frames 1/250 .. 1/15, gaps ~3 s
                   40 s
    IMG_0004-0008  auto bracket, EV 0,-1,+1,-2,+2 (1/125 base), burst 0.15 s
                   55 s
    IMG_0009-0015  hand bracket, 7 frames 1/1000 .. 1/15, gaps 1.5-4 s
    DSC_0001-0003  camera B (.JPG), auto bracket EV 0,-1,+1, shot in the middle of
                   IMG_0009-0015 by a second photographer
    IMG_0016       corrupt file (garbage bytes)
                   30 s
    IMG_0017       stray single frame, auto exposure
                   45 s
    IMG_0018-0020  auto bracket EV -2,0,+2 (1/4, 1, 4 s)
                   0.5 s  (shorter than the 4 s exposure before it)
    IMG_0021-0023  auto bracket EV -2,0,+2 metered again (1/2, 2, 8 s)
                   60 s
    IMG_0024-0026  hand bracket 2 s, 1/2, 1/8
                   1 s    (shorter than the 2 s exposure it repeats)
    IMG_0027-0029  hand bracket 2 s, 1/2, 1/8 again
    notes.txt      not an image

Pixel values follow the exposure: a seeded textured radiance field times
``t * ISO/100 * (8/N)^2`` through a gamma 2.2 curve, so the frames look like a real bracket.
"""
from __future__ import annotations

import datetime as _dt
import os

import numpy as np

__all__ = ["make_shoot", "EXIF_ATTRIBUTES", "write_frame"]

WIDTH, HEIGHT = 48, 32

#: OIIO attribute names that survive a JPEG write + read with OpenImageIO 3.2.
EXIF_ATTRIBUTES = (
    "ExposureTime", "FNumber", "Exif:PhotographicSensitivity", "Exif:ExposureBiasValue",
    "Exif:ExposureMode", "Exif:DateTimeOriginal", "Exif:SubsecTimeOriginal", "Make",
    "Model", "Exif:BodySerialNumber", "Exif:LensModel", "Exif:FocalLength",
)

CAMERA_A = {"make": "Canon", "model": "Canon EOS R6", "serial": "012345678901",
            "lens": "RF24-105mm F4 L IS USM", "focal_length": 24.0}
CAMERA_B = {"make": "NIKON CORPORATION", "model": "NIKON Z 6", "serial": "6001234",
            "lens": "NIKKOR Z 24-70mm f/4 S", "focal_length": 35.0}

MANUAL, AUTO, AUTO_BRACKET = 1, 0, 2  # EXIF ExposureMode


def _scene(rng) -> np.ndarray:
    """Radiance field spanning about three decades, with texture."""
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    base = np.exp(np.log(1000.0) * (x / (WIDTH - 1)))  # left-right ramp, 3 decades
    blobs = np.zeros_like(base)
    for _ in range(6):
        cx, cy = rng.uniform(0, WIDTH), rng.uniform(0, HEIGHT)
        r = rng.uniform(3, 9)
        blobs += rng.uniform(-0.6, 0.6) * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * r * r))
    texture = 1.0 + 0.15 * np.sin(x * 1.3 + y * 0.7) * np.cos(y * 1.1)
    rad = base * np.exp(blobs) * texture * 0.05
    return np.repeat(rad[:, :, None], 3, axis=2) * np.array([1.0, 0.9, 0.75])


def write_frame(path, radiance, *, time, fnumber, iso, bias, mode, when, camera, rng):
    """Write one JPEG whose pixels and EXIF agree with the given exposure settings."""
    import OpenImageIO as oiio

    exposure = time * (iso / 100.0) * (8.0 / fnumber) ** 2
    lin = np.clip(radiance * exposure * 4.0, 0.0, 1.0)
    pixels = 255.0 * lin ** (1 / 2.2) + rng.normal(0.0, 0.8, radiance.shape)
    data = np.clip(np.round(pixels), 0, 255).astype(np.uint8)

    spec = oiio.ImageSpec(WIDTH, HEIGHT, 3, oiio.UINT8)
    spec.attribute("ExposureTime", oiio.TypeFloat, float(time))
    spec.attribute("FNumber", oiio.TypeFloat, float(fnumber))
    spec.attribute("Exif:PhotographicSensitivity", oiio.TypeInt, int(iso))
    spec.attribute("Exif:ExposureBiasValue", oiio.TypeFloat, float(bias))
    spec.attribute("Exif:ExposureMode", oiio.TypeInt, int(mode))
    spec.attribute("Exif:DateTimeOriginal", when.strftime("%Y:%m:%d %H:%M:%S"))
    spec.attribute("Exif:SubsecTimeOriginal", f"{when.microsecond // 1000:03d}")
    spec.attribute("DateTime", when.strftime("%Y:%m:%d %H:%M:%S"))
    spec.attribute("Make", camera["make"])
    spec.attribute("Model", camera["model"])
    spec.attribute("Exif:BodySerialNumber", camera["serial"])
    spec.attribute("Exif:LensModel", camera["lens"])
    spec.attribute("Exif:FocalLength", oiio.TypeFloat, float(camera["focal_length"]))
    out = oiio.ImageOutput.create(os.fspath(path))
    if out is None:
        raise RuntimeError(f"cannot create {path}: {oiio.geterror()}")
    try:
        if not out.open(os.fspath(path), spec):
            raise RuntimeError(f"cannot open {path}: {out.geterror()}")
        if not out.write_image(data):
            raise RuntimeError(f"cannot write {path}: {out.geterror()}")
    finally:
        out.close()


# Shutter speeds as cameras write them (third stops below one second).
_NOMINAL = [1 / d for d in (8000, 6400, 5000, 4000, 3200, 2500, 2000, 1600, 1250, 1000,
                            800, 640, 500, 400, 320, 250, 200, 160, 125, 100, 80, 60, 50,
                            40, 30, 25, 20, 15, 13, 10, 8, 6, 5, 4, 3, 2.5, 2, 1.6, 1.3)]


def _ev_times(base, evs):
    """Auto-bracket times around ``base``, snapped to the nominal values under 1 s."""
    out = []
    for ev in evs:
        t = base * 2.0 ** ev
        if t < 1:
            t = min(_NOMINAL, key=lambda v: abs(np.log2(v / t)))
        out.append(t)
    return out


def make_shoot(folder, seed: int = 0) -> dict:
    """Write the shoot described in the module docstring into ``folder``.

    Parameters
    ----------
    folder : str or os.PathLike
        Existing folder; files are written directly into it.
    seed : int
        Seeds the scenes, noise and hand-bracketing gaps (file names and the grouping do
        not depend on it).

    Returns
    -------
    dict
        ``"sets"``: list of file-name lists (base names, capture order) that form the
        bracket sets, in order of their first frame's capture time;
        ``"exposures"``: the exposure times (s) of each set;
        ``"unmerged"``: list of ``{"files": [...], "kind": "single frame" | "corrupt"}``;
        ``"frames"``: base name -> settings written (``time``, ``fnumber``, ``iso``,
        ``bias``, ``mode``, ``when`` (datetime), ``make``, ``model``, ``serial``,
        ``lens``, ``focal_length``); ``"corrupt"``: base names of unreadable files;
        ``"ignored"``: files that are not images.
    """
    folder = os.fspath(folder)
    rng = np.random.default_rng(seed)
    t0 = _dt.datetime(2024, 6, 1, 10, 0, 0)

    # Each shot: (name, time, fnumber, iso, bias, mode, camera, start). Built as a
    # timeline: next start = previous start + its exposure + gap.
    shots = []
    sets, unmerged = [], []

    def run(names, times, *, gaps, fnumber=8.0, iso=100, biases=None, mode=MANUAL,
            camera=CAMERA_A, start):
        biases = biases or [0.0] * len(times)
        when = start
        for i, (name, t, b) in enumerate(zip(names, times, biases)):
            shots.append(dict(name=name, time=t, fnumber=fnumber, iso=iso, bias=b,
                              mode=mode, camera=camera, when=when))
            if i < len(names) - 1:
                when = when + _dt.timedelta(seconds=t + gaps[i])
        return when + _dt.timedelta(seconds=times[-1])  # end of the last exposure

    def names(a, b, prefix="IMG_", ext=".jpg"):
        return [f"{prefix}{i:04d}{ext}" for i in range(a, b + 1)]

    def after(end, gap):
        return end + _dt.timedelta(seconds=gap)

    # Hand bracketing, 3 frames.
    n = names(1, 3)
    end = run(n, [1 / 250, 1 / 60, 1 / 15], gaps=rng.uniform(2.0, 3.5, 2), start=t0)
    sets.append(n)
    # Auto bracketing, 5 frames, camera order 0,-1,+1,-2,+2.
    n = names(4, 8)
    evs = [0, -1, 1, -2, 2]
    end = run(n, _ev_times(1 / 125, evs), gaps=[0.15] * 4, biases=evs, mode=AUTO_BRACKET,
              start=after(end, 40.0))
    sets.append(n)
    # Hand bracketing, 7 frames in one-stop steps.
    n = names(9, 15)
    s2_start = after(end, 55.0)
    s2_times = [1 / 1000, 1 / 500, 1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15]
    end = run(n, s2_times, gaps=[1.5, 2.5, 4.0, 3.0, 2.0, 1.5], start=s2_start)
    sets.append(n)
    # Camera B fires an auto bracket in the middle of the 7-frame hand bracket.
    nb = names(1, 3, prefix="DSC_", ext=".JPG")
    evs = [0, -1, 1]
    run(nb, _ev_times(1 / 200, evs), gaps=[0.2, 0.2], fnumber=5.6, iso=200, biases=evs,
        mode=AUTO_BRACKET, camera=CAMERA_B, start=s2_start + _dt.timedelta(seconds=5.3))
    sets.append(nb)
    # The corrupt file: garbage bytes with a .jpg name.
    corrupt = "IMG_0016.jpg"
    # A stray single frame, auto exposure.
    n = names(17, 17)
    end = run(n, [1 / 100], gaps=[], fnumber=5.6, mode=AUTO, start=after(end, 30.0))
    unmerged.append({"files": n, "kind": "single frame"})
    # Two auto brackets back to back: the gap (0.5 s) is shorter than the longest
    # exposure (4 s), and the second one is metered differently (no time repeats; the
    # EV ladder -2,0,+2 restarts).
    n = names(18, 20)
    evs = [-2, 0, 2]
    end = run(n, _ev_times(1.0, evs), gaps=[0.3, 0.3], fnumber=11.0, biases=evs,
              mode=AUTO_BRACKET, start=after(end, 45.0))
    sets.append(n)
    n = names(21, 23)
    end = run(n, _ev_times(2.0, evs), gaps=[0.3, 0.3], fnumber=11.0, biases=evs,
              mode=AUTO_BRACKET, start=after(end, 0.5))
    sets.append(n)
    # Two hand brackets back to back: the second repeats the first's settings 1 s
    # after the first ends (shorter than its 2 s exposure).
    n = names(24, 26)
    end = run(n, [2.0, 0.5, 0.125], gaps=[1.0, 1.0], fnumber=11.0, start=after(end, 60.0))
    sets.append(n)
    n = names(27, 29)
    end = run(n, [2.0, 0.5, 0.125], gaps=[1.0, 1.0], fnumber=11.0, start=after(end, 1.0))
    sets.append(n)

    scenes = {}
    frames = {}
    for shot in shots:
        key = _set_of(shot["name"], sets)
        if key not in scenes:
            scenes[key] = _scene(np.random.default_rng([seed, len(scenes)]))
        write_frame(os.path.join(folder, shot["name"]), scenes[key], time=shot["time"],
                    fnumber=shot["fnumber"], iso=shot["iso"], bias=shot["bias"],
                    mode=shot["mode"], when=shot["when"], camera=shot["camera"], rng=rng)
        frames[shot["name"]] = dict(
            time=shot["time"], fnumber=shot["fnumber"], iso=shot["iso"], bias=shot["bias"],
            mode=shot["mode"], when=shot["when"], width=WIDTH, height=HEIGHT,
            **shot["camera"])

    garbage = np.random.default_rng([seed, 99]).integers(0, 256, 3000, dtype=np.uint8)
    with open(os.path.join(folder, corrupt), "wb") as fh:
        fh.write(b"this is not a JPEG\n" + garbage.tobytes())
    unmerged.append({"files": [corrupt], "kind": "corrupt"})
    with open(os.path.join(folder, "notes.txt"), "w") as fh:
        fh.write("shoot notes: not an image\n")

    sets.sort(key=lambda s: (frames[s[0]]["when"], s[0]))
    return {
        "sets": sets,
        "exposures": [[frames[f]["time"] for f in s] for s in sets],
        "unmerged": unmerged,
        "frames": frames,
        "corrupt": [corrupt],
        "ignored": ["notes.txt"],
    }


def _set_of(name, sets):
    for i, s in enumerate(sets):
        if name in s:
            return i
    return name
