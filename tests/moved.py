"""Hand-held brackets made from real frames moved by known transforms (test helper).

Each frame is resampled at high quality (cubic spline on approximately linear values,
``(z / zmax) ** 2.2``) and re-quantised; pixels whose source falls outside the frame
or touches a masked pixel are painted with the ignore colour, so a merge masks them.
"""
import math

import numpy as np
from scipy import ndimage

IGNORE = (0, 0, 255)


def similarity(rot_deg, scale, dy, dx, h, w):
    """Matrix (reference -> frame pixel coordinates) rotating by ``rot_deg`` and scaling
    about the frame centre, then shifting the centre by ``(dy, dx)``."""
    c, s = math.cos(math.radians(rot_deg)) * scale, math.sin(math.radians(rot_deg)) * scale
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    a = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    t0 = np.array([[1.0, 0.0, -cx], [0.0, 1.0, -cy], [0.0, 0.0, 1.0]])
    t1 = np.array([[1.0, 0.0, cx + dx], [0.0, 1.0, cy + dy], [0.0, 0.0, 1.0]])
    return t1 @ a @ t0


def move(frame, matrix, ignore=IGNORE):
    """``out(p) = frame(M^-1 p)``: the frame the camera would have recorded had it moved
    so that ``out(M q) ~ frame(q)``."""
    h, w, c = frame.shape
    zmax = float(np.iinfo(frame.dtype).max)
    inv = np.linalg.inv(matrix)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    u = inv[0, 0] * xs + inv[0, 1] * ys + inv[0, 2]
    v = inv[1, 0] * xs + inv[1, 1] * ys + inv[1, 2]
    s = inv[2, 0] * xs + inv[2, 1] * ys + inv[2, 2]
    sx, sy = u / s, v / s
    bad = np.all(frame == np.asarray(ignore, frame.dtype), axis=2)
    bad = ndimage.binary_dilation(bad, np.ones((5, 5), bool))
    lost = ndimage.map_coordinates(bad.astype(np.float32), [sy, sx], order=1, mode="constant", cval=1.0) > 0
    lost |= (sx < 1) | (sx > w - 2) | (sy < 1) | (sy > h - 2)
    lin = (frame.astype(np.float64) / zmax) ** 2.2
    out = np.empty_like(frame)
    for k in range(c):
        res = ndimage.map_coordinates(lin[..., k], [sy, sx], order=3, mode="nearest")
        out[..., k] = np.round(np.clip(res, 0.0, 1.0) ** (1 / 2.2) * zmax).astype(frame.dtype)
    out[lost] = np.asarray(ignore, frame.dtype)
    return out


def exposures(frame, stops, seed=0, noise=0.002, ignore=IGNORE):
    """Frames of one real frame's scene at ``2**stop`` times its exposure: linearised
    (``(z / zmax) ** 2.2``), scaled, given fresh noise, clipped and re-quantised; masked
    pixels keep the ignore colour. The scene is the same in every frame: any motion
    given them later is the only misregistration."""
    rng = np.random.default_rng(seed)
    zmax = float(np.iinfo(frame.dtype).max)
    lin = (frame.astype(np.float64) / zmax) ** 2.2
    masked = np.all(frame == np.asarray(ignore, frame.dtype), axis=2)
    out = []
    for st in stops:
        e = np.clip(lin * 2.0 ** st + rng.normal(0.0, noise, lin.shape), 0.0, 1.0)
        f = np.round(e ** (1 / 2.2) * zmax).astype(frame.dtype)
        f[masked] = np.asarray(ignore, frame.dtype)
        out.append(f)
    return out


def handheld_set(frame, stops, seed=0, max_rot=2.0, max_shift=40.0, max_scale=0.02):
    """``(tripod, moved, matrices)``: :func:`exposures` of ``frame``, the same frames
    moved by random similarities (the middle one, the reference, not moved) and the
    matrices (reference -> frame pixel coordinates). The first and last frames get the
    largest rotation, shift and scale asked for."""
    tripod = exposures(frame, stops, seed)
    h, w = frame.shape[:2]
    rng = np.random.default_rng(seed + 1)
    ref = len(stops) // 2
    mats, moved = [], []
    for j, f in enumerate(tripod):
        if j == ref:
            mats.append(np.eye(3))
            moved.append(f)
            continue
        if j in (0, len(stops) - 1):
            sign = 1.0 if j == 0 else -1.0
            m = similarity(sign * max_rot, 1.0 + sign * max_scale, sign * max_shift, -sign * max_shift, h, w)
        else:
            m = similarity(rng.uniform(-max_rot, max_rot), 1.0 + rng.uniform(-max_scale, max_scale),
                           rng.uniform(-max_shift, max_shift), rng.uniform(-max_shift, max_shift), h, w)
        mats.append(m)
        moved.append(move(f, m))
    return tripod, moved, mats
