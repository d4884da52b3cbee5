"""Time hdrcl's tone mapping on a synthetic radiance map: the OpenCL kernel against its
float64 NumPy twin for the global operators, and the CPU-only local operator.

    python scripts/tonemap_bench.py [--size 6000x4000] [--operators reinhard,drago,filmic,reinhard-local]
"""
import argparse
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="6000x4000", help="WxH of the radiance map [6000x4000, 24 MP]")
    ap.add_argument("--operators", default="reinhard,drago,filmic,reinhard-local")
    ap.add_argument("--device", default=None)
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.lower().split("x"))
    from hdrcl.cl.backend import get_processor
    from hdrcl.report import tonemap as tm

    rng = np.random.default_rng(0)
    rad = np.exp(rng.normal(0.0, 2.0, (h, w, 3))).astype(np.float32)
    proc = get_processor("tonemap", args.device)
    print(f"{w}x{h} ({w * h / 1e6:.1f} MP), device: {proc.ctx.name if proc else 'none (NumPy only)'}")
    for op in args.operators.split(","):
        t0 = time.perf_counter()
        p = tm.statistics(rad, op)
        t1 = time.perf_counter()
        if op == "reinhard-local":
            tm.tone_map_array(rad, op)
            t2 = time.perf_counter()
            print(f"{op:15s} statistics {t1 - t0:6.2f} s   NumPy/SciPy (float32 blurs) {t2 - t1:6.2f} s")
            continue
        tm.apply_global(rad, p, 8)
        t2 = time.perf_counter()
        line = f"{op:15s} statistics {t1 - t0:6.2f} s   NumPy float64 twin {t2 - t1:6.2f} s"
        if proc is not None:
            proc.apply(rad[:64], tm.OP_CODES[op], p.scale, p.white, 8)  # build the kernel first
            t3 = time.perf_counter()
            proc.apply(rad, tm.OP_CODES[op], p.scale, p.white, 8)
            line += f"   OpenCL {time.perf_counter() - t3:6.2f} s (with transfers)"
        print(line)


if __name__ == "__main__":
    main()
