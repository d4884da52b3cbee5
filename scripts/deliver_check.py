#!/usr/bin/env python3
"""Usage: python scripts/deliver_check.py STEM  (STEM.exr merged with --deliver uhdr,avif,jxl, default
headroom and PQ 10-bit). Decode each deliverable of a radiance map with the codec library; median |stops| vs the map
in reference-white units (pixels inside the headroom), and the clip outside it."""
import sys, numpy as np, imagecodecs as ic
from hdrcl.io.radiance import read_radiance
from hdrcl.io.hdrdisplay import pq_decode
from hdrcl.core.options import DeliverOptions
from hdrcl.report.deliver import Rendering
stem = sys.argv[1]
rad = np.asarray(read_radiance(stem + ".exr")[0], np.float32)
r = Rendering(rad, DeliverOptions("uhdr"))
ref = r.hdr(0, r.h, headroom=99.0)
top = 8.0
inside = (ref.max(axis=2) < top * 0.97) & (ref.min(axis=2) > 0.01)
outside = ref.min(axis=2) > top * 1.1
st = lambda a, b: np.abs(np.log2(np.maximum(a, 1e-9) / np.maximum(b, 1e-9)))
got = {"uhdr": ic.ultrahdr_decode(open(stem + ".uhdr.jpg", "rb").read()).astype(np.float64)[..., :3],
       "avif": pq_decode(ic.avif_decode(open(stem + ".avif", "rb").read()) / 1023.0) / 203.0,
       "jxl": pq_decode(ic.jpegxl_decode(open(stem + ".jxl", "rb").read()) / 65535.0) / 203.0}
sdr = ic.ultrahdr_decode(open(stem + ".uhdr.jpg", "rb").read(), dtype=np.uint8)[..., :3].astype(int)
print(f"{r.w}x{r.h}: {inside.mean()*100:.1f} % of pixels inside the 3-stop headroom, {outside.mean()*100:.2f} % above")
for k, g in got.items():
    print(f"  {k}: median {np.median(st(g, ref)[inside]):.4f} stops inside, p95 {np.percentile(st(g, ref)[inside], 95):.4f};"
          f" outside: median {np.median(st(g, np.full_like(g, top))[outside]) if outside.any() else float('nan'):.4f} stops from 2^3")
print(f"  uhdr SDR vs our base: median {np.median(np.abs(sdr - r.base())):.1f} codes, p99 {np.percentile(np.abs(sdr - r.base()), 99):.1f}")
