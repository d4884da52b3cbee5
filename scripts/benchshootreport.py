#!/usr/bin/env python3
"""The printed report of ``scripts/shoot_bench.py``: per shape, megapixels per second of
``hdrcl batch``, the floors and OpenCV, the ratios beside their targets, the seconds per
stage from ``report.json``, the CPU-seconds against the floors' and start-up costs.
Imports no other script.
"""
from __future__ import annotations

#: The floors measured, each in its own process (``floors.py``).
FLOOR_KINDS = ("decode", "encode", "fusion")

#: Targets: hdrcl batch (defaults) at least 5x the OpenCV loop and at most 1.6x the I/O
#: floor (issue 26), at least 35 % of the decode floor's MP/s (issue 16).
TARGETS = {"vs_opencv": 5.0, "vs_decode": 0.35, "io_floor": 1.6, "cpu_floor": 1.3}

#: Stage keys of report.json's per-set ``seconds``, printed in this order; keys not listed
#: here follow in the order they are first met.
STAGE_ORDER = ("startup", "decode", "sample", "solve", "fuse", "encode", "write", "report",
               "hash", "open", "merge", "preview", "quality")


def _mmm(st: dict, fmt: str = "{:.2f}") -> str:
    if not st:
        return "-"
    if st["n"] == 1:
        return fmt.format(st["median"])
    return f"{fmt.format(st['median'])} [{fmt.format(st['min'])} - {fmt.format(st['max'])}]"


def _verdict(value, target) -> str:
    if value is None:
        return "not measured"
    if value >= target:
        return "ok"
    return f"MISSED: reaches {100 * value / target:.0f} % of the target (needs {target / value:.2f}x)"


def print_report(res: dict) -> None:
    p = print
    m = res["machine"]
    p("")
    p("hdrcl shoot benchmark (scripts/shoot_bench.py)")
    p(f"  processor: {m.get('lscpu') or m.get('cpu')} (lscpu), {m.get('cpu_count')} cores, {m.get('memory_gb')} GB")
    p(f"  OpenCL: {m.get('opencl_device')}")
    p(f"  hdrcl {m.get('hdrcl')} {m.get('hdrcl_git', '')}, Python {m.get('python')}, NumPy {m.get('numpy')}, "
      f"OpenImageIO {m.get('openimageio')}, OpenCV {res.get('opencv_version') or 'not measured'}")
    p(f"  {res['runs']} run(s) per figure, in rounds; figures are median [min - max]; "
      f"MP = input megapixels (frames x pixels, summed over the shoot)")
    p("  CPU s: user + system time of the process tree (median); other CPU: the largest share of the machine "
      "other processes used during a run")
    for s in res["shapes"]:
        info, r = s["info"], s["result"]
        sizes = sorted({f"{x['width']}x{x['height']}" for x in info["sets"]})
        cams = sorted({x["camera"] for x in info["sets"]})
        p("")
        p(f"shape {info['shape']}: {len(info['sets'])} sets x "
          f"{'/'.join(str(len(x['files'])) for x in info['sets'])} frames, "
          f"{len(cams)} camera{'s' if len(cams) > 1 else ''}"
          + (f" ({cams[0]})" if len(cams) == 1 else "")
          + f", {', '.join(sizes)} ({info['mp']:g} MP), {info['frames']} frames = {info['megapixels']:.0f} MP input, "
          f"JPEG q{'/'.join(sorted({str(x['quality']) for x in info['sets']}))}, {info['bytes'] / 1e6:.0f} MB "
          f"({info['bytes_per_pixel']:.2f} B/px)")
        sc = info.get("scan", {})
        p(f"  hdrcl scan reads it back: " + (f"{sc.get('sets_found')} sets, EXIF as written" if sc.get("ok")
                                            else f"PROBLEM: {sc.get('problem') or '; '.join(sc.get('problems', []))}"))
        p(f"  {'figure':48s} {'seconds':>23s} {'MP/s':>22s} {'CPU s':>7s} {'peak RSS':>9s} {'other CPU':>9s}")
        names = {"hdrcl": "hdrcl batch SHOOT -r -o OUT (defaults)",
                 "hdrcl_jobs2": "hdrcl batch SHOOT -r -o OUT --jobs 2",
                 "decode": "decode floor (OIIO, {t} threads, decode only)",
                 "encode": "encode floor (OIIO, {t} threads, the outputs)",
                 "io_floor": "I/O floor (decode + encode floor)",
                 "fusion": "fusion floor (OpenCL, decoded frames)",
                 "opencv": "OpenCV loop ({t} threads: imread, Debevec, .hdr)"}
        for k in ("hdrcl", "hdrcl_jobs2", "decode", "encode", "io_floor", "fusion", "opencv"):
            f = r["figures"].get(k)
            if f is None:
                if k == "opencv":
                    p(f"  {'OpenCV loop':48s} not measured ({res.get('opencv_note')})")
                continue
            name = names[k].format(t=f.get("threads", "?"))
            if "seconds" in f and k == "io_floor":
                p(f"  {name:48s} {_mmm(f['seconds']):>23s} {_mmm(f['mp_per_s'], '{:.1f}'):>22s}")
            elif "seconds" in f:
                rss = f"{f['rss_mb']:.0f} MB"
                bg = f"{100 * f['background_cpu']['max']:.0f} %"
                p(f"  {name:48s} {_mmm(f['seconds']):>23s} {_mmm(f['mp_per_s'], '{:.1f}'):>22s} "
                  f"{f['cpu_s']['median']:7.1f} {rss:>9s} {bg:>9s}"
                  + (f"  ({f['failed']} failed)" if f.get("failed") else ""))
            else:
                p(f"  {name:48s} FAILED: {f.get('error')}")
        dec = r["figures"].get("decode", {})
        if "process_seconds" in dec:
            p(f"    (decode floor as a whole process, interpreter and imports included: "
              f"{_mmm(dec['process_seconds'])} s)")
        enc = r["figures"].get("encode", {})
        if "outputs" in enc:
            p(f"    (encode floor: {enc['outputs']} outputs, {enc['output_mp']:.1f} MP, "
              f"{', '.join(enc['formats'])}, as the batch wrote them)")
        _print_cpu_floor(r)
        v = r["ratios"].get("io_floor")
        v2 = r["ratios"].get("io_floor_jobs2")
        if v:
            verdict = "ok" if v["median"] <= TARGETS["io_floor"] else \
                f"MISSED: needs {v['median'] / TARGETS['io_floor']:.2f}x less time"
            jobs2 = f"{v2['median']:.2f}x" if v2 else "-"
            p(f"  {'batch wall / I/O floor':22s} {v['median']:.2f}x [" + ", ".join(f"{x:.2f}x" for x in v["rounds"])
              + f"]; --jobs 2: {jobs2}   target <= {TARGETS['io_floor']:g}x: {verdict}")
        else:
            p(f"  {'batch wall / I/O floor':22s} not measured (a batch, decode or encode run failed)")
        p("  ratios of MP/s, hdrcl defaults: the median of each round's own ratio [every round]; --jobs 2 beside")
        for key, label, target, pct in (("vs_opencv", "hdrcl / OpenCV", TARGETS["vs_opencv"], False),
                                        ("vs_decode", "hdrcl / decode floor", TARGETS["vs_decode"], True)):
            v, v2 = r["ratios"].get(key), r["ratios"].get(key + "_jobs2")

            def fmt(x):
                return "-" if x is None else (f"{100 * x:.0f} %" if pct else f"{x:.2f}x")

            def rounds(x):
                return "" if not x or not x["rounds"] else " [" + ", ".join(fmt(y) for y in x["rounds"]) + "]"

            med = v["median"] if v else None
            tt = f">= {100 * target:.0f} %" if pct else f">= {target:g}x"
            p(f"  {label:22s} {fmt(med)}{rounds(v)}; --jobs 2: {fmt(v2['median'] if v2 else None)}"
              f"   target {tt}: {_verdict(med, target)}")
        ph = r["figures"].get("opencv", {}).get("phases")
        if ph:
            p(f"  OpenCV phases (s, summed over sets, median): import {ph['import_s']:.2f}, imread "
              f"{ph['imread_s']:.2f}, calibrate {ph['calibrate_s']:.2f}, merge {ph['merge_s']:.2f}, "
              f"imwrite {ph['imwrite_s']:.2f}")
        st = r.get("stages", {})
        if st:
            keys = [k for k in STAGE_ORDER if any(k in st[h] for h in st)]
            keys += [k for h in st for k in st[h] if k not in keys and k not in STAGE_ORDER]
            keys = list(dict.fromkeys(keys))
            cols = [h for h in ("hdrcl", "hdrcl_jobs2") if h in st]
            p("  hdrcl stage seconds from OUT/report.json, summed over sets (median of runs):")
            p("    " + f"{'stage':12s}" + "".join(f"{('defaults' if h == 'hdrcl' else '--jobs 2'):>11s}" for h in cols))
            for k in keys:
                p("    " + f"{k:12s}" + "".join(f"{st[h][k]:11.2f}" if k in st[h] else f"{'-':>11s}" for h in cols))
            p("    " + f"{'batch wall':12s}" + "".join(
                f"{r['figures'][h]['seconds']['median']:11.2f}" if "seconds" in r["figures"][h] else f"{'-':>11s}"
                for h in cols) + "  (stages overlap; work outside the sets, e.g. the scan and a pooled"
                                 " calibration, shows only in the wall time)")
    su = res.get("startup", {})
    if su.get("runs"):
        p("")
        p(f"start-up (whole processes, {su['runs']} runs, median [min - max]):")
        for k, label in (("version", "hdrcl --version"), ("tiny_merge", "hdrcl merge frobisher_001/*.jpg -o X.exr")):
            e = su.get(k, {})
            p(f"  {label:48s} " + (f"{_mmm(e['seconds'])} s, CPU {e['cpu_s']['median']:.2f} s" if "seconds" in e
                                   else f"FAILED: {e.get('error')}"))
    bg = res.get("background", {})
    if bg.get("runs"):
        p("")
        p(f"other processes used {100 * bg['mean']:.0f} % of the CPU on average during the measured runs "
          f"(max {100 * bg['max']:.0f} %, {bg['over_10pct']} of {bg['runs']} runs above 10 %)"
          + ("  <- figures may be pessimistic; rerun on an idle machine" if bg["max"] > 0.10 else ""))
    p(f"elapsed {res['elapsed_s'] / 60:.1f} min; JSON: {res['json']}; logs: {res['logs']}")


def _print_cpu_floor(r: dict) -> None:
    """Batch CPU-seconds beside decode + encode + fusion CPU-seconds, and their ratio."""
    v, v2 = r["ratios"].get("cpu_floor"), r["ratios"].get("cpu_floor_jobs2")
    fl = {k: r["figures"].get(k, {}).get("timed_cpu_s") for k in FLOOR_KINDS}
    if fl["decode"] and fl["encode"] and fl["fusion"]:
        print(f"    (floors' own CPU-seconds, median: decode {fl['decode']['median']:.2f}, encode "
              f"{fl['encode']['median']:.2f}, fusion {fl['fusion']['median']:.2f}; CPU s above: whole processes)")
    if not v:
        print(f"  {'batch CPU-s / floors':22s} not measured (a batch or floor run failed)")
        return
    floors = v["decode_cpu_s"] + v["encode_cpu_s"] + v["fusion_cpu_s"]
    print(f"  batch CPU-seconds {v['batch_cpu_s']:.2f} (user + system of the batch process); decode + encode + "
          f"fusion CPU-seconds {v['decode_cpu_s']:.2f} + {v['encode_cpu_s']:.2f} + {v['fusion_cpu_s']:.2f} = "
          f"{floors:.2f}")
    verdict = "ok" if v["median"] <= TARGETS["cpu_floor"] else \
        f"MISSED: needs {v['median'] / TARGETS['cpu_floor']:.2f}x less CPU"
    jobs2 = f"{v2['median']:.2f}x" if v2 else "-"
    print(f"  {'batch CPU-s / floors':22s} {v['median']:.2f}x [" + ", ".join(f"{x:.2f}x" for x in v["rounds"])
          + f"]; --jobs 2: {jobs2}   target <= {TARGETS['cpu_floor']:g}x: {verdict}")
