#!/usr/bin/env python3
"""The luminance chain against Radiance itself (issue 28's acceptance check).

Generates a fisheye bracket and its hdrgen ``camera.rsp`` (``scripts/luminance_bench.py``),
writes the lab's own calibration files (HDRICalibrationTool's ``vignetting_f5d6``-form
file, the identity ``NDfilter_no_transform.cal``, ``CF_f5d6.cal`` = 1.18: their real text),
then:

* **hdrcl**: the docs' one command (``hdrcl merge ... --lens-circle --resize 1000
  --fisheye-projection equisolid-to-equidistant --vignetting --nd-filter
  --calibration-factor --view``), and ``hdrcl glare`` on its map;
* **Radiance** on hdrcl's plain ``--absolute`` merge, as the lab's pipeline runs it:
  ``pcompos`` (crop), ``pfilt -1`` (resize), ``pcomb -f fisheye_corr.cal``, ``pcomb -f``
  with each of the three files, ``getinfo -a VIEW=``, then ``evalglare -V`` and
  ``evalglare``.

It prints the vertical illuminance of both (and hdrcl's own figure against evalglare on
hdrcl's map), the 50 x 50-block luminance ratio (median, 5th and 95th percentile), Radiance's
reading of hdrcl's ``--absolute`` .hdr against hdrcl's cd/m^2, and DGP/UGR of ``hdrcl
glare`` against ``evalglare`` on the same file. Needs pyradiance (Radiance's programs).

    python scripts/radiance_check.py --mp 2
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))
sys.path.insert(0, HERE)

LAB_VIG = ("sq(x)=x*x;\nr=sqrt(sq(x-500)+sq(y-500))/500;\n"
           "sf=(1/(((-0.528613562104476)*(r^4))+((0.000000000000000052147170934049)*(r^3))+((0.1755458928191)*(r^2))"
           "+((0.000000000000000007599040843632)*r)+1));\nro=sf*ri(1);\ngo=sf*gi(1);\nbo=sf*bi(1);\n")
LAB_ND = "ro=ri(1);\ngo=gi(1);\nbo=bi(1);\n"
LAB_CF = "ro=ri(1)*1.18;\ngo=gi(1)*1.18;\nbo=bi(1)*1.18;\n"
FISHEYE_CORR = ("xc : xres/2;\nyc : yres/2;\nsq(x) : x*x;\nmap_inverse = -1;\n"
                "inp_r = sqrt(sq((x-xc)/xres) + sq((y-yc)/yres));\nmapped_r = rad(inp_r);\n"
                "rmult = if(map_inverse, inp_r/(mapped_r+1e-7), mapped_r/(inp_r+1e-7));\n"
                "xoff = (x-xc)*(1-rmult);\nyoff = (y-yc)*(1-rmult);\n"
                "ro = if(.5-inp_r, ri(1,xoff,yoff), 0);\ngo = if(.5-inp_r, gi(1,xoff,yoff), 0);\n"
                "bo = if(.5-inp_r, bi(1,xoff,yoff), 0);\nmapsolid(r) : 2/PI*asin(sqrt(2)*r);\nrad(r) = mapsolid(r);\n")
VIEW = "-vta -vh 180 -vv 180"


def run(cmd, **kw):
    return subprocess.run(cmd, check=True, capture_output=True, **kw).stdout


def pipe(cmd, data):
    return subprocess.run(cmd, input=data, check=True, capture_output=True).stdout


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mp", type=float, default=2.0)
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--work", default=None)
    ap.add_argument("--scenes", action="store_true",
                    help="also hdrcl glare against evalglare on the glare test scenes (tests/test_glare.py)")
    args = ap.parse_args(argv)
    import pyradiance

    rb = os.path.join(os.path.dirname(pyradiance.__file__), "bin")
    from luminance_bench import srgb_g, write_set

    from hdrcl.core.luminance.glare import glare_of_file, read_luminance_map
    from hdrcl.core.response import Response

    d = args.work or tempfile.mkdtemp(prefix="hdrcl-radcheck-")
    os.makedirs(d, exist_ok=True)
    paths, (cx, cy, dia) = write_set(d, args.mp, args.frames)
    rsp = os.path.join(d, "camera.rsp")
    Response(bits=8, g=np.stack([srgb_g()] * 3), knots=np.arange(256.0)).save(rsp)
    files = {}
    for name, text in (("vignetting_f5d6.cal", LAB_VIG), ("NDfilter_no_transform.cal", LAB_ND),
                       ("CF_f5d6.cal", LAB_CF), ("fisheye_corr.cal", FISHEYE_CORR)):
        files[name] = os.path.join(d, name)
        with open(files[name], "w") as f:
            f.write(text)
    circle = f"{cx:g},{cy:g},{dia:g}"
    chain = os.path.join(d, "chain.hdr")
    run(["hdrcl", "merge", *paths, "--response", rsp, "-o", chain, "--lens-circle", circle, "--resize", "1000",
         "--fisheye-projection", "equisolid-to-equidistant", "--vignetting", files["vignetting_f5d6.cal"],
         "--nd-filter", files["NDfilter_no_transform.cal"], "--calibration-factor", files["CF_f5d6.cal"],
         "--view", VIEW])
    plain = os.path.join(d, "plain.hdr")
    run(["hdrcl", "merge", *paths, "--response", rsp, "--absolute", "-o", plain])
    plain_exr = os.path.join(d, "plain.exr")
    run(["hdrcl", "merge", *paths, "--response", rsp, "--absolute", "--dtype", "float", "-o", plain_exr])

    # Radiance's chain on hdrcl's plain merge
    h = int(run([os.path.join(rb, "getinfo"), "-d", plain]).split()[-3])
    left, top, side = int(round(cx - dia / 2)), int(round(cy - dia / 2)), int(round(dia))
    data = run([os.path.join(rb, "pcompos"), "-x", str(side), "-y", str(side), plain, str(-left),
                str(-(h - top - side))])
    data = pipe([os.path.join(rb, "pfilt"), "-1", "-x", "1000", "-y", "1000"], data)
    for name in ("fisheye_corr.cal", "vignetting_f5d6.cal", "NDfilter_no_transform.cal", "CF_f5d6.cal"):
        data = pipe([os.path.join(rb, "pcomb"), "-h", "-f", files[name], "-"], data)
    data = pipe([os.path.join(rb, "getinfo"), "-a", f"VIEW= {VIEW}"], b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + data
                if not data.startswith(b"#?") else data)
    rad = os.path.join(d, "radiance.hdr")
    with open(rad, "wb") as f:
        f.write(data)

    def evalglare(*args):  # evalglare exits 1 after -V even when it worked: read its output
        return subprocess.run([os.path.join(rb, "evalglare"), *args], capture_output=True).stdout

    def ev(path):
        return float(evalglare("-V", path).split()[-1])

    head = open(chain, "rb").read(1 << 16).split(b"\n\n")[0].decode()
    ours = float(next(x for x in head.split("\n") if x.startswith("VERTICAL_ILLUMINANCE=")).split("=")[1])
    ev_rad, ev_chain = ev(rad), ev(chain)
    print(f"vertical illuminance: hdrcl {ours:.1f} lx; evalglare -V on hdrcl's map {ev_chain:.1f} lx "
          f"({ours / ev_chain - 1:+.3%}); Radiance's chain {ev_rad:.1f} lx ({ours / ev_rad - 1:+.3%})")
    a, _ = read_luminance_map(chain)
    b, _ = read_luminance_map(rad)
    blocks = lambda m: m.reshape(20, 50, 20, 50).mean(axis=(1, 3))
    ba, bb = blocks(a), blocks(b)
    ok = (ba > 0) & (bb > 0) & (blocks((a > 0).astype(float)) == 1) & (blocks((b > 0).astype(float)) == 1)
    r = ba[ok] / bb[ok]
    print(f"50x50 blocks inside the circle ({int(ok.sum())}): hdrcl / Radiance median {np.median(r):.4f}, "
          f"p5 {np.percentile(r, 5):.4f}, p95 {np.percentile(r, 95):.4f}")
    lum = np.frombuffer(run([os.path.join(rb, "pvalue"), "-h", "-H", "-df", "-b", plain]), np.float32) * 179.0
    ref, _ = read_luminance_map(plain_exr)
    pos = ref.ravel() > 0
    q = lum[pos] / ref.ravel()[pos]
    print(f"Radiance (pvalue) reads hdrcl's --absolute .hdr at {np.median(q):.4f} of hdrcl's cd/m2 "
          f"(p1 {np.percentile(q, 1):.4f}, p99 {np.percentile(q, 99):.4f})")
    g = glare_of_file(chain)
    line = next(x for x in evalglare("-d", chain).decode().splitlines()
                if x.startswith("dgp,av_lum"))
    names, values = line.split(": ")
    e = dict(zip(names.split(","), map(float, values.split())))
    print(f"hdrcl glare vs evalglare on hdrcl's map: DGP {g.dgp:.4f} / {e['dgp']:.4f}, UGR {g.ugr:.2f} / "
          f"{e['ugr']:.2f}, DGI {g.dgi:.2f} / {e['dgi']:.2f}, sources {len(g.sources)}")
    if args.scenes:
        scenes(rb, d)
    print(f"(files in {d})")
    return 0


def scenes(rb: str, folder: str) -> None:
    """hdrcl glare against evalglare -d on the scenes of tests/test_glare.py."""
    sys.path.insert(0, os.path.join(HERE, "..", "tests"))
    from pathlib import Path

    from test_glare import SCENES, _evalglare, _scene, _write

    from hdrcl.core.luminance.glare import glare_of_file

    print(f"{'scene':38s} {'Ev hdrcl/evalglare':>22s} {'DGP':>18s} {'UGR':>18s} {'DGI':>18s}")
    for name in sorted(SCENES):
        p = Path(folder) / f"scene{len(name)}.hdr"
        _write(Path(rb), p, _scene(300, seed=len(name), **SCENES[name]))
        w, r = _evalglare(Path(rb), p), glare_of_file(p)
        print(f"{name:38s} {r.vertical_illuminance:10.2f}/{w['E_v']:10.2f} {r.dgp:8.5f}/{w['dgp']:8.5f} "
              f"{r.ugr:8.3f}/{w['ugr']:8.3f} {r.dgi:8.3f}/{w['dgi']:8.3f}")


if __name__ == "__main__":
    sys.exit(main())
