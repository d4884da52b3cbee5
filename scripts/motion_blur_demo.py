#!/usr/bin/env python3
"""The paper's virtual-photograph application: motion blur on radiance vs on 8 bits.

Synthesises a scene with small, very bright lights (far beyond one exposure's range),
photographs it through an S-shaped camera, merges the bracket with hdrcl, and writes
``motion-blur.jpg`` in the current folder: left, the middle photograph; centre, that
photograph blurred (8-bit, as an image editor would); right, the radiance map blurred by
the same vector and then exposed like the middle photograph (``hdrcl expose
--motion-blur``). The lights streak brightly only on the right: blurring clipped 8-bit
values loses their energy. ``--out docs/motion-blur.jpg`` regenerates the picture
shown in docs/tonemap.md (a tracked file: only on purpose).

    python scripts/motion_blur_demo.py [--out motion-blur.jpg] [--blur 40,0]
"""
import argparse
import sys

import numpy as np

import hdrcl
from hdrcl.core import synthetic as s
from hdrcl.core.radiometry import motion_blur
from hdrcl.io.ldr import write_ldr


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="motion-blur.jpg",
                    help="picture to write [motion-blur.jpg; docs/motion-blur.jpg is the one docs/tonemap.md shows]")
    ap.add_argument("--blur", default="40,0")
    a = ap.parse_args(argv)
    dx, dy = (float(v) for v in a.blur.split(","))
    h, w = 200, 300
    scene = s.radiance_field(h, w, decades=1.5, seed=7)
    rng = np.random.default_rng(3)
    for _ in range(12):  # street lights: 3x3 px, 300-3000 times the median
        y, x = rng.integers(20, h - 20), rng.integers(20, w - 60)
        scene[y:y + 3, x:x + 3] = np.median(scene) * rng.uniform(300, 3000)
    cam = s.Camera(a=1.0, x0=(1.0, 1.05, 0.95))
    times = s.stops(7, 2.0, centre=1.0 / float(np.median(scene)))
    frames = s.bracket(scene, times, cam, noise=0.5, seed=1)
    resp = hdrcl.calibrate(frames, times)
    rad = hdrcl.merge(frames, times, response=resp)
    mid = frames[3]
    blurred_8bit = np.clip(np.round(motion_blur(mid.astype(np.float32), dx, dy)), 0, 255).astype(np.uint8)
    blurred_rad = hdrcl.expose(motion_blur(rad, dx, dy), resp, float(times[3]))
    gap = np.full((h, 6, 3), 255, np.uint8)
    panel = np.concatenate([mid, gap, blurred_8bit, gap, blurred_rad], axis=1)
    write_ldr(a.out, panel)
    print(f"wrote {a.out}: photo | blurred 8-bit photo | blurred radiance, exposed ({panel.shape[1]}x{h})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
