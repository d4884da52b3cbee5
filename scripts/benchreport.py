#!/usr/bin/env python3
"""The figures of ``scripts/bench.py`` against the targets of issues 4 and 11: each
verdict (ok / MISSED by how much, :func:`evaluate`) and the printed report
(:func:`print_report`). Imports no other script but ``benchlib`` and ``benchbrackets``.
"""
from __future__ import annotations

import os
import statistics
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)

from benchlib import MB  # noqa: E402
from benchbrackets import JPEG_QUALITY  # noqa: E402

# Targets of issues 4 and 11 (value, direction): "min" means the figure must be >= value.
TARGETS = {
    "kernel_vs_copy": (0.25, "min"),
    "vs_opencv": (5.0, "min"),
    "vs_decode_encode": (1.3, "max"),
    "rss_calibrating_mb": (500.0, "max"),
    "rss_largest_mb": (700.0, "max"),
    "rss_growth": (0.15, "max"),
    "batch_vs_opencv": (None, "info"),
    "solve_8bit_s": (0.3, "max"),
    "solve_16bit_s": (2.0, "max"),
    "second_process_s": (1.5, "max"),
}

#: The hdrcl merge runs per size: output type, response given (True) or calibrated.
MERGE_VARIANTS = {
    "merge_exr_response": (".exr", True),
    "merge_exr_calibrate": (".exr", False),
    "merge_hdr_response": (".hdr", True),
    "merge_hdr_calibrate": (".hdr", False),
}


def verdict(value, key: str) -> dict:
    """Whether ``value`` meets target ``key``; when missed, by how much.

    ``shortfall``: for a lower bound, the fraction of the target reached (0.4 = 40 %);
    for an upper bound, how far above the limit (0.2 = 20 % over).
    """
    target, kind = TARGETS[key]
    if value is None or kind == "info":
        return {"target": target, "kind": kind, "value": value, "met": None}
    met = value >= target if kind == "min" else value <= target
    v = {"target": target, "kind": kind, "value": value, "met": bool(met)}
    if not met:
        v["reached_fraction" if kind == "min" else "over_fraction"] = (
            value / target if kind == "min" else value / target - 1)
    return v


def _status(v: dict) -> str:
    if v["met"]:
        return "ok"
    if v["kind"] == "min":
        return f"MISSED: reaches {100 * v['reached_fraction']:.0f} % of the target (needs {1 / max(v['reached_fraction'], 1e-9):.1f}x)"
    return f"MISSED by {100 * v['over_fraction']:.0f} % (over the limit)"


def _fmt(x, unit="", nd=2):
    if x is None:
        return "-"
    return f"{x:.{nd}f}{unit}"


def evaluate(res: dict) -> list:
    """Rows (figure, value text, target text, status, key, verdict) of every target."""
    rows = []
    sizes = res["sizes"]
    first, last = sizes[0], sizes[-1]
    copy = res.get("copy", {})
    ref = copy.get("reference_gbps")

    def add(name, key, value, vtext, ttext, note=None, bg=()):
        v = verdict(value, key)
        bg = [b for b in bg if b is not None]
        if value is None:
            vtext = "-"
        if note:
            v["note"] = note
        if v["kind"] == "info" and value is not None:
            status = "(no target in the issue: for comparison)"
        elif v["met"] is None:
            status = note if note and note.startswith(("not measured", "batch:")) else \
                "not measured" + (f" ({note})" if note else "")
        else:
            status = _status(v)
            if bg:
                v["background_cpu"] = max(bg)
                if max(bg) > 0.10:
                    status += f"  * ({100 * max(bg):.0f} % background CPU)"
        rows.append((name, vtext, ttext, status, key, v))
        v["figure"] = name

    for s in sizes:
        ip = s["inproc"]
        val = ip.get("kernel_gbps") / ref if ref and ip.get("kernel_gbps") else None
        add(f"fusion kernel / copy bandwidth, {s['label']}", "kernel_vs_copy", val,
            f"{_fmt(100 * val if val else None, ' %', 0)} ({_fmt(ip.get('kernel_gbps'), ' GB/s')} vs "
            f"{_fmt(ref, ' GB/s')})", ">= 25 %",
            None if val else ip.get("kernel_error", "no kernel or copy figure"),
            bg=[ip.get("kernel_background"), copy.get(copy.get("reference", "").replace("_gbps", "_background"))])
    v = first["ratios"].get("vs_opencv")
    add(f"hdrcl merge (calibrating, .hdr) vs OpenCV, {first['label']}", "vs_opencv", v,
        f"{_fmt(v, 'x', 1)} faster ({_fmt(first['merge_hdr_calibrate'].get('best_s'), ' s')} vs "
        f"{_fmt(first['opencv'].get('best_s'), ' s')})", ">= 5x",
        None if v else first["opencv"].get("error", "failed"),
        bg=[first["merge_hdr_calibrate"].get("background_cpu_best_run"), first["opencv"].get("background_cpu_best_run")])
    v = first["ratios"].get("vs_decode_encode")
    add(f"hdrcl merge (response given, .exr) / (decode + encode), {first['label']}", "vs_decode_encode", v,
        f"{_fmt(v, 'x')} ({_fmt(first['merge_exr_response'].get('best_s'), ' s')} vs "
        f"{_fmt(first['ratios'].get('decode_encode_s'), ' s')})", "<= 1.3x",
        None if v else first["merge_exr_response"].get("error", "failed"),
        bg=[first["merge_exr_response"].get("background_cpu_best_run"), first["inproc"].get("decode_parallel_background"),
            first["inproc"].get("encode_exr_background")])
    cal = [first[k]["rss_mb"] for k in ("merge_exr_calibrate", "merge_hdr_calibrate") if "rss_mb" in first.get(k, {})]
    v = max(cal) if cal else None
    add(f"peak RSS of a calibrating hdrcl merge, {first['label']} (.exr and .hdr)", "rss_calibrating_mb", v,
        f"{_fmt(v, ' MB', 0)}", "<= 500 MB")
    v = last["ratios"].get("merge_rss_max_mb")
    add(f"peak RSS of hdrcl merge, {last['label']} (max over the 4 variants)", "rss_largest_mb", v,
        f"{_fmt(v, ' MB', 0)}", "<= 700 MB")
    if len(sizes) > 1:
        # Like with like: each merge variant at the last size against itself at the
        # first; the target holds for the variant that grows most.
        growth = {}
        for k in MERGE_VARIANTS:
            a, b = first.get(k, {}).get("rss_mb"), last.get(k, {}).get("rss_mb")
            if a and b:
                growth[k] = (b / a - 1, a, b)
        k = max(growth, key=lambda k: growth[k][0]) if growth else None
        v, a, b = growth[k] if k else (None, None, None)
        add(f"peak RSS growth {first['label']} -> {last['label']} (variant growing most)", "rss_growth", v,
            f"{_fmt(100 * v if v is not None else None, ' %', 0)} ({k}: {_fmt(a, ' MB', 0)} -> {_fmt(b, ' MB', 0)})",
            "< 15 %")
    bt = res.get("batch", {})
    v = bt.get("vs_opencv")
    hb, ob = bt.get("hdrcl", {}), bt.get("opencv", {})
    add(f"hdrcl batch vs a loop of OpenCV merges, {bt.get('sets', 8)} sets of {bt.get('set', '?')} (MP/s)",
        "batch_vs_opencv", v,
        f"{_fmt(v, 'x', 1)}" + (f" ({_fmt(hb.get('mp_per_s'), ' MP/s', 1)} vs {_fmt(ob.get('mp_per_s'), ' MP/s', 1)})"
                               if v else ""), "-",
        None if v else (bt.get("note") or ob.get("error") or hb.get("error") or "failed"),
        bg=[hb.get("background_cpu_best_run"), ob.get("background_cpu_best_run")])
    ip = first["inproc"]
    v = ip.get("solve_8bit_s")
    add(f"response solve, 8-bit RGB ({first['label']}, {ip.get('solve_8bit_samples', '?')} samples)",
        "solve_8bit_s", v, _fmt(v, " s", 3), "<= 0.3 s", bg=[ip.get("solve_8bit_background")])
    v = ip.get("solve_16bit_s")
    add(f"response solve, 16-bit RGB ({ip.get('solve_16bit_size', first['label'])}, "
        f"{ip.get('solve_16bit_samples', '?')} samples)", "solve_16bit_s", v, _fmt(v, " s", 3), "<= 2 s",
        bg=[ip.get("solve_16bit_background")])
    sp = res.get("second_process", {})
    v = sp.get("calibrating", {}).get("best_s")
    add(f"second hdrcl merge process, {sp.get('set', 'small set')} (calibrating)", "second_process_s", v,
        _fmt(v, " s"), "<= 1.5 s", None if v else sp.get("error", "failed"),
        bg=[sp.get("calibrating", {}).get("background_cpu_best_run")])
    return rows


def print_report(res: dict, rows: list) -> None:
    m = res["machine"]
    p = print
    p("")
    p("hdrcl benchmark")
    p(f"  machine: {m.get('cpu')}, {m.get('cpu_count')} cores, {m.get('memory_gb')} GB; "
      f"OpenCL: {m.get('opencl_device')}")
    p(f"  OpenCL driver that ran: {res.get('copy', {}).get('opencl_driver', 'unknown')}")
    p(f"  hdrcl {m.get('hdrcl_git', '')}, Python {m.get('python')}, NumPy {m.get('numpy')}, "
      f"OIIO {m.get('openimageio')}, OpenCV {res.get('opencv_version') or 'not installed'}")
    cp = res.get("copy", {})
    if cp:
        p(f"  copy bandwidth ({cp.get('buffer_mib')} MiB, read+write): NumPy 1 thread "
          f"{_fmt(cp.get('numpy_1thread_gbps'), ' GB/s')}, 2 threads {_fmt(cp.get('numpy_2threads_gbps'), ' GB/s')}, "
          f"OpenCL buffer copy {_fmt(cp.get('opencl_gbps'), ' GB/s')}; reference = {cp.get('reference')}")
    for s in res["sizes"]:
        ip, rat = s["inproc"], s["ratios"]
        p("")
        p(f"{s['label']}  ({s['width']}x{s['height']}, JPEG q{JPEG_QUALITY}, {s['jpeg_mb']:.0f} MB; best of "
          f"{s['repeat']})")
        if "error" in ip:
            p(f"  in-process measurements failed: {ip['error']}")
        else:
            p(f"  decode-only (OIIO)       serial {_fmt(ip['decode_serial_s'], ' s')}, "
              f"{ip['decode_threads']} threads {_fmt(ip['decode_parallel_s'], ' s')}")
            p(f"  encode-only (EXR half zip) {_fmt(ip['encode_exr_s'], ' s')}"
              f"   decode(threads)+encode {_fmt(rat.get('decode_encode_s'), ' s')}")
            if "kernel_s" in ip:
                p(f"  fusion kernel alone      {_fmt(ip['kernel_s'], ' s', 3)} = {_fmt(ip['kernel_gbps'], ' GB/s')} "
                  f"({ip['kernel_bytes'] / MB:.0f} MB moved, {ip['kernel_backend']}, profiling events)")
                if "kernel_host_s" in ip:
                    p(f"  fusion, host path        {_fmt(ip['kernel_host_s'], ' s', 3)} = "
                      f"{_fmt(ip['kernel_host_gbps'], ' GB/s')} (strips copied in and out, counts, fix-up)")
            else:
                p(f"  fusion kernel alone      failed: {ip.get('kernel_error')}")
            p(f"  response solve 8-bit     {_fmt(ip['solve_8bit_s'], ' s', 3)}")
        p(f"  {'hdrcl command':34s} {'time':>8s} {'peak RSS':>10s}")
        for k, name in (("hdrcl_calibrate", "calibrate"), ("merge_exr_response", "merge -> .exr, --response"),
                        ("merge_exr_calibrate", "merge -> .exr, calibrating"),
                        ("merge_hdr_response", "merge -> .hdr, --response"),
                        ("merge_hdr_calibrate", "merge -> .hdr, calibrating"), ("opencv", "OpenCV -> .hdr")):
            e = s.get(k, {})
            if "best_s" in e:
                med = statistics.median(e["all_s"]) if e.get("all_s") else e["best_s"]
                p(f"  {name:34s} {e['best_s']:7.2f}s {e['rss_mb']:7.0f} MB   (median {med:.2f} s of {len(e.get('all_s', [1]))})")
            else:
                p(f"  {name:34s} {e.get('error', '-')}")
        ph = s.get("opencv", {}).get("phases")
        if ph:
            p(f"    OpenCV phases: import {ph['import_s']:.2f}, imread {ph['imread_s']:.2f}, calibrate "
              f"{ph['calibrate_s']:.2f}, merge {ph['merge_s']:.2f}, imwrite {ph['imwrite_s']:.2f} s "
              f"({ph['threads']} threads)")
        p(f"  ratios: vs OpenCV {_fmt(rat.get('vs_opencv'), 'x', 1)} (calibrating, best runs; medians "
          f"{_fmt(rat.get('vs_opencv_median'), 'x', 2)}, CPU-seconds {_fmt(rat.get('vs_opencv_cpu'), 'x', 2)}; "
          f"{_fmt(rat.get('vs_opencv_response_given'), 'x', 1)} with response given), "
          f"vs decode+encode {_fmt(rat.get('vs_decode_encode'), 'x')} (response given; "
          f"{_fmt(rat.get('vs_decode_encode_calibrating'), 'x')} calibrating)")
    sp = res.get("second_process", {})
    if sp:
        p("")
        p(f"second process ({sp.get('set')}): first run {_fmt(sp.get('first_s'), ' s')}; then calibrating "
          f"{_fmt(sp.get('calibrating', {}).get('best_s'), ' s')}, response given "
          f"{_fmt(sp.get('response_given', {}).get('best_s'), ' s')} (python startup "
          f"{_fmt(sp.get('python_startup_s'), ' s')}, import hdrcl {_fmt(sp.get('import_hdrcl_s'), ' s')})")
    bt = res.get("batch", {})
    if bt and not bt.get("available"):
        p(bt.get("note", "batch: not available"))
    elif bt:
        p("")
        p(f"batch ({bt['sets']} sets of {bt['set']}, {bt['megapixels']:.0f} MP of radiance):")
        for k, name in (("hdrcl", "hdrcl batch (EXR + preview)"), ("opencv", "OpenCV loop (.hdr)")):
            e = bt.get(k, {})
            if "best_s" in e:
                p(f"  {name:30s} best {e['best_s']:.2f} s = {e['mp_per_s']:.1f} MP/s, median "
                  f"{statistics.median(e['all_s']):.2f} s = {e['mp_per_s_median']:.1f} MP/s, peak RSS {e['rss_mb']:.0f} MB")
            else:
                p(f"  {name:30s} {e.get('error', '-')}")
    bg = res.get("background_cpu", {})
    if bg.get("runs"):
        p("")
        p(f"background load: other processes used {100 * bg['mean']:.0f} % of the CPU on average during the "
          f"measured runs (max {100 * bg['max']:.0f} %; {bg['runs_over_10pct']} of {bg['runs']} runs above 10 %)"
          + ("  <- figures may be pessimistic; rerun on an idle machine" if bg["max"] > 0.10 else ""))
    p("")
    p("targets" + ("  (--quick sizes: NOT the issue's 24 MP x 7 / 100 MP x 5)" if res.get("quick") else ""))
    w1 = max(len(r[0]) for r in rows)
    w2 = max(len(r[1]) for r in rows)
    for name, vtext, ttext, status, _k, _v in rows:
        p(f"  {name:{w1}s}  {vtext:{w2}s}  target {ttext:10s} {status}")
    if any("  * (" in r[3] for r in rows):
        p("  * other processes used more than 10 % of the CPU during the best run behind this figure")
    p("")
    p(f"JSON: {res['json']}")
