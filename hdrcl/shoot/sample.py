"""A small sample shoot to try ``hdrcl scan`` and ``hdrcl batch`` on (``hdrcl sample-shoot``).

JPEGs with real EXIF, as a camera writes them, of a synthetic scene with a known
camera curve (:mod:`hdrcl.core.synthetic`): three overlapping views of one wide scene, as
for a panorama, bracketed three ways, and one stray frame::

    PANO_0001-0003  view 1, hand bracket 1/400, 1/100, 1/25 s at f/8, ISO 100
                    30 s
    PANO_0004-0006  view 2, auto bracket EV 0, -2, +2 (1/100 s base), burst
                    40 s
    PANO_0007-0011  view 3, hand bracket 1/1000 .. 1/60 s at f/5.6, ISO 200
                    60 s
    PANO_0012       a stray single frame (auto exposure)

The third view is shot at another aperture and ISO: merged by ``hdrcl batch`` its
radiance still matches the other two (one exposure scale per shoot), and its EXR
records the difference as ``hdrcl:evOffset`` (about +2 EV).
"""
from __future__ import annotations

import datetime as _dt
import os
from typing import List

import numpy as np

from hdrcl.core import synthetic
from hdrcl.errors import UsageError

__all__ = ["write_sample_shoot"]

CAMERA = {"Make": "hdrcl", "Model": "Synthetic Camera", "Exif:BodySerialNumber": "0001",
          "Exif:LensModel": "Synthetic 24mm", "Exif:FocalLength": 24.0}
# EXIF ExposureMode values.
_AUTO, _MANUAL, _AUTO_BRACKET = 0, 1, 2


def write_sample_shoot(folder, *, width: int = 192, height: int = 128, seed: int = 0) -> List[str]:
    """Write the sample shoot into ``folder`` (created if needed).

    Parameters
    ----------
    folder : str or os.PathLike
    width, height : int
        Size of each photograph (at least 32 x 32).
    seed : int
        Seeds the scene and the noise.

    Returns
    -------
    list of str
        The paths written, in capture order.
    """
    from hdrcl.io.ldr import write_photo

    if width < 32 or height < 32:
        raise UsageError("sample shoot: frames must be at least 32x32")
    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    cam = synthetic.Camera(a=1.1, x0=(1.0, 1.15, 0.85))
    # A wide scene; each view is a window of it, overlapping its neighbours by half.
    scene = synthetic.radiance_field(height, 2 * width, decades=3.5, seed=seed) * 100.0
    step = width // 2
    views = [scene[:, k * step:k * step + width] for k in range(3)]
    rng = np.random.default_rng([seed, 1])

    shots = []  # (view, time, fnumber, iso, bias, mode, gap_before)
    for t in (1 / 400, 1 / 100, 1 / 25):
        shots.append((0, t, 8.0, 100, 0.0, _MANUAL, 2.0))
    for t, ev in ((1 / 100, 0.0), (1 / 400, -2.0), (1 / 25, 2.0)):
        shots.append((1, t, 8.0, 100, ev, _AUTO_BRACKET, 0.2))
    for t in (1 / 1000, 1 / 500, 1 / 250, 1 / 125, 1 / 60):
        shots.append((2, t, 5.6, 200, 0.0, _MANUAL, 2.5))
    shots.append((1, 1 / 160, 8.0, 100, 0.0, _AUTO, 0.0))
    breaks = {3: 30.0, 6: 40.0, 11: 60.0}  # gaps before the first frame of each group

    paths = []
    when = _dt.datetime(2024, 6, 1, 10, 0, 0)
    prev_t = 0.0
    for n, (view, t, fnum, iso, ev, mode, gap) in enumerate(shots):
        if n:
            when += _dt.timedelta(seconds=prev_t + breaks.get(n, gap))
        exposure = t * (iso / 100.0) * (8.0 / fnum) ** 2
        frame = synthetic.bracket(views[view], [exposure], cam, noise=0.5, seed=int(rng.integers(1 << 30)))[0]
        path = os.path.join(folder, f"PANO_{n + 1:04d}.jpg")
        exif = dict(CAMERA)
        exif.update({
            "ExposureTime": float(t), "FNumber": float(fnum), "Exif:PhotographicSensitivity": int(iso),
            "Exif:ExposureBiasValue": float(ev), "Exif:ExposureMode": int(mode),
            "Exif:DateTimeOriginal": when.strftime("%Y:%m:%d %H:%M:%S"),
            "Exif:SubsecTimeOriginal": f"{when.microsecond // 1000:03d}",
            "DateTime": when.strftime("%Y:%m:%d %H:%M:%S"),
        })
        write_photo(path, frame, exif)
        paths.append(path)
        prev_t = t
    return paths
