#!/usr/bin/env python3
"""The picture of docs/deliver.md: one real set's deliverables side by side, left to right
the Ultra HDR JPEG's SDR base, its gain map (per channel, as stored) and the exposure
fusion of the frames, each as the files hold them.

    python scripts/deliver_pictures.py                      # Memorial, into docs/deliver-memorial.jpg
    python scripts/deliver_pictures.py --data ../shared/data --out /tmp/x.jpg
"""
from __future__ import annotations

import argparse
import glob
import os
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=os.path.normpath(os.path.join(HERE, "..", "..", "shared", "data")))
    ap.add_argument("--out", default=os.path.join(HERE, "..", "docs", "deliver-memorial.jpg"))
    args = ap.parse_args(argv)
    sys.path.insert(0, os.path.dirname(HERE))
    import hdrcl
    from hdrcl.core.mertens import exposure_fusion, read_frames, to_codes
    from hdrcl.core.options import DeliverOptions
    from hdrcl.io.ldr import write_ldr
    from hdrcl.report.deliver import Rendering

    m = os.path.join(args.data, "memorial")
    paths = sorted(glob.glob(os.path.join(m, "memorial*.png")))
    if not paths:
        print(f"deliver_pictures: no Memorial frames in {m}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        res = hdrcl.merge_files(paths, os.path.join(tmp, "m.exr"), times_file=os.path.join(m, "image_list.txt"),
                                ignore_color=(0, 0, 255), keep_radiance=True)
        r = Rendering(res.radiance, DeliverOptions(("uhdr",), 3.0))
        base = r.base()
        gains, _meta = r.gain_map()
    frames, valid = read_frames(paths, (0, 0, 255))
    fused = to_codes(exposure_fusion(frames, valid), 8)
    gap = np.full((base.shape[0], 8, 3), 255, np.uint8)
    strip = np.concatenate([base, gap, gains, gap, fused], axis=1)
    step = 2  # half size: the page shows three pictures in a row
    write_ldr(os.path.abspath(args.out), np.ascontiguousarray(strip[::step, ::step]))
    print(f"wrote {os.path.abspath(args.out)}: SDR base | gain map | exposure fusion, {strip.shape[1] // step}x"
          f"{strip.shape[0] // step}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
