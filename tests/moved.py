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


def move(frame, matrix, ignore=IGNORE, fill=None):
    """``out(p) = frame(M^-1 p)``: the frame the camera would have recorded had it moved
    so that ``out(M q) ~ frame(q)``. Pixels whose source falls outside the frame get
    ``fill`` (default: the ignore colour; ``(0, 0, 0)``: black corners, as a camera's
    own rotation or a converter fills them); those touching a masked pixel the ignore
    colour."""
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
    lost = ndimage.map_coordinates(bad.astype(np.float32), [sy, sx], order=1, mode="constant", cval=0.0) > 0
    outside = (sx < 1) | (sx > w - 2) | (sy < 1) | (sy > h - 2)
    lin = (frame.astype(np.float64) / zmax) ** 2.2
    out = np.empty_like(frame)
    for k in range(c):
        res = ndimage.map_coordinates(lin[..., k], [sy, sx], order=3, mode="nearest")
        out[..., k] = np.round(np.clip(res, 0.0, 1.0) ** (1 / 2.2) * zmax).astype(frame.dtype)
    out[lost] = np.asarray(ignore, frame.dtype)
    out[outside] = np.asarray(ignore if fill is None else fill, frame.dtype)
    return out


def exposures(frame, stops, seed=0, noise=0.002, ignore=IGNORE, pedestal=0):
    """Frames of one real frame's scene at ``2**stop`` times its exposure: linearised
    (``(z / zmax) ** 2.2``), scaled, given fresh noise, clipped and re-quantised; masked
    pixels keep the ignore colour. The scene is the same in every frame: any motion
    given them later is the only misregistration. ``pedestal`` > 0: codes sit on a
    sensor's black level of that many codes, with noise of a code (a dark frame's
    median is then the pedestal, as on the Memorial film's short exposures)."""
    rng = np.random.default_rng(seed)
    zmax = float(np.iinfo(frame.dtype).max)
    lin = (frame.astype(np.float64) / zmax) ** 2.2
    masked = np.all(frame == np.asarray(ignore, frame.dtype), axis=2)
    out = []
    for st in stops:
        e = np.clip(lin * 2.0 ** st + rng.normal(0.0, noise, lin.shape), 0.0, 1.0)
        if pedestal:
            z = pedestal + e ** (1 / 2.2) * (zmax - pedestal) + rng.normal(0.0, 1.0, lin.shape)
            f = np.round(np.clip(z, 0.0, zmax)).astype(frame.dtype)
        else:
            f = np.round(e ** (1 / 2.2) * zmax).astype(frame.dtype)
        f[masked] = np.asarray(ignore, frame.dtype)
        out.append(f)
    return out


def handheld_set(frame, stops, seed=0, max_rot=2.0, max_shift=40.0, max_scale=0.02, fill=None, pedestal=0):
    """``(tripod, moved, matrices)``: :func:`exposures` of ``frame``, the same frames
    moved by random similarities (the middle one, the reference, not moved) and the
    matrices (reference -> frame pixel coordinates). The first and last frames get the
    largest rotation, shift and scale asked for. ``fill``, ``pedestal``: as
    :func:`move` and :func:`exposures` take them."""
    tripod = exposures(frame, stops, seed, pedestal=pedestal)
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
        moved.append(move(f, m, fill=fill))
    return tripod, moved, mats


def random_motion(rng, h, w, max_rot=1.5, max_shift=20.0, max_scale=0.01):
    """A random similarity (reference -> frame) within the limits, uniform in each."""
    return similarity(rng.uniform(-max_rot, max_rot), 1.0 + rng.uniform(-max_scale, max_scale),
                      rng.uniform(-max_shift, max_shift), rng.uniform(-max_shift, max_shift), h, w)


def memorial_moved(folder, seed, max_rot=1.5, max_shift=20.0, max_scale=0.01, fill=(0, 0, 0), step=1):
    """The real Memorial bracket (``folder``: its 16 frames, by file name) moved as a
    hand-held camera moves: every frame but the middle exposure (the reference) moved
    by a random similarity within the limits, the uncovered corners in ``fill``.
    ``step`` > 1 keeps every ``step``-th frame (counted from the reference).
    Returns ``(names, tripod, moved, times, matrices)``, in file order."""
    import imageio.v3 as iio

    lines = [ln.split() for ln in open(f"{folder}/image_list.txt") if ln.strip() and not ln.startswith("#")]
    names = [ln[0] for ln in lines]
    times = [1.0 / float(ln[2]) for ln in lines]
    order = sorted(range(len(names)), key=lambda k: times[k])
    ref = order[len(order) // 2]
    keep = [k for k in range(len(names)) if abs(order.index(k) - order.index(ref)) % step == 0]
    names, times = [names[k] for k in keep], [times[k] for k in keep]
    ref = keep.index(ref)
    tripod = [iio.imread(f"{folder}/{n}")[..., :3] for n in names]
    h, w = tripod[0].shape[:2]
    rng = np.random.default_rng(seed)
    mats, moved = [], []
    for j, f in enumerate(tripod):
        m = np.eye(3) if j == ref else random_motion(rng, h, w, max_rot, max_shift, max_scale)
        mats.append(m)
        moved.append(f if j == ref else move(f, m, fill=fill))
    return names, tripod, moved, times, mats


def stops_rms(a, b):
    """RMS difference in stops of the luminance of two radiance maps over the central
    80 % (pixels positive in both)."""
    h, w = a.shape[:2]
    y0, y1, x0, x1 = h // 10, h - h // 10, w // 10, w - w // 10
    lum = np.array([0.2126, 0.7152, 0.0722])
    la, lb = a[y0:y1, x0:x1] @ lum, b[y0:y1, x0:x1] @ lum
    ok = (la > 0) & (lb > 0)
    return float(np.sqrt(np.mean(np.log2(la[ok] / lb[ok]) ** 2)))


def tripod_merge(folder, out_dir):
    """The plain merge of the real Memorial bracket (the truth a moved set's aligned
    merge is held to)."""
    import glob

    import hdrcl

    paths = sorted(glob.glob(f"{folder}/memorial*.png"))
    return hdrcl.merge_files(paths, f"{out_dir}/tripod.exr", times_file=f"{folder}/image_list.txt",
                             ignore_color=IGNORE, dtype="float", keep_radiance=True, fit_exposures="off")


def moved_merge(folder, out_dir, seed, max_rot, fill, tripod, **kw):
    """``(rms, result, truth, moved, names)``: Memorial moved (:func:`memorial_moved`,
    ``fill`` the corners' colour) merged with ``--align`` through the tripod merge's
    curve, and its RMS difference in stops from ``tripod`` (:func:`stops_rms`)."""
    import os

    import hdrcl
    from hdrcl.io.ldr import write_ldr

    names, _, moved, times, mats = memorial_moved(folder, seed, max_rot=max_rot, fill=fill)
    paths = []
    for n, f in zip(names, moved):
        p = os.path.join(out_dir, n)
        write_ldr(p, f)
        paths.append(p)
    res = hdrcl.merge_files(paths, os.path.join(out_dir, "aligned.exr"), times=times, ignore_color=IGNORE,
                            dtype="float", keep_radiance=True, fit_exposures="off", response=tripod.response,
                            align=True, **kw)
    return stops_rms(res.radiance, tripod.radiance), res, mats, moved, names


def content_error(m_est, m_true, frame, lo=24, hi=246, step=8):
    """``(p99, median)`` distance (pixels) between where ``m_est`` and the truth put the
    frame's well-exposed pixels (codes in ``(lo, hi)``, fill and ignore colour left out)."""
    from hdrcl.core.align.mtb import grey_image
    from hdrcl.core.align.warp import apply

    g = grey_image(frame)
    use = (g > lo) & (g < hi) & ~np.all(frame == np.asarray(IGNORE, frame.dtype), axis=2) & ~np.all(frame == 0, axis=2)
    ys, xs = np.nonzero(use[::step, ::step])
    pf = np.c_[xs * step, ys * step].astype(np.float64)
    if len(pf) == 0:
        return float("nan"), float("nan")
    d = np.hypot(*(apply(np.asarray(m_est, np.float64), apply(np.linalg.inv(m_true), pf)) - pf).T)
    return float(np.percentile(d, 99)), float(np.median(d))


def sweep(folder, seeds=(1, 2, 3, 4, 5), rots=(1.5, 0.5), fills=("black", "ignore")):
    """Every case of issue 27's hand-held Memorial check, printed: RMS stops from the
    tripod merge, and each frame's model and error where it has content."""
    import tempfile
    import time

    with tempfile.TemporaryDirectory() as d:
        tri = tripod_merge(folder, d)
        worst = 0.0
        for fill in fills:
            for rot in rots:
                for seed in seeds:
                    t = time.perf_counter()
                    try:
                        rms, res, mats, moved, names = moved_merge(
                            folder, d, seed, rot, (0, 0, 0) if fill == "black" else IGNORE, tri)
                    except Exception as exc:  # a refusal is a result here
                        print(f"fill={fill} rot={rot} seed={seed}: REFUSED {exc}")
                        worst = float("inf")
                        continue
                    errs = [content_error(a["matrix"], m, f)[0] for a, m, f in zip(res.alignment, mats, moved)
                            if a["model"] not in ("inherited", "reference")]
                    inh = [a["file"] for a in res.alignment if a["model"] == "inherited"]
                    worst = max(worst, rms)
                    print(f"fill={fill} rot={rot} seed={seed}: {rms:.3f} stops RMS; frame error p99 max "
                          f"{max(errs):.2f} px; inherited {inh}; {time.perf_counter() - t:.1f} s", flush=True)
        print(f"worst {worst:.3f} stops RMS")


if __name__ == "__main__":
    import sys

    sweep(sys.argv[1] if len(sys.argv) > 1 else "../shared/data/memorial")
