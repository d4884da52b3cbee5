#!/usr/bin/env python3
"""hdrcl benchmark: speed, bandwidth and memory against the targets of issues 4 and 11.

One command generates its own inputs (textured JPEG brackets, quality 92, with EXIF
exposure data), then measures on the same files, in one run:

* decode-only (OpenImageIO, serial and in parallel threads) and encode-only (EXR, half,
  zip: hdrcl's default);
* ``hdrcl merge`` end to end (CLI processes; response given, and calibrating), with the
  peak resident memory of every ``hdrcl`` process;
* OpenCV's pipeline (imread, CalibrateDebevec, MergeDebevec, imwrite), both tools
  writing Radiance ``.hdr`` (OpenCV's PyPI wheel writes no EXR);
* the fusion kernel alone in bytes per second, beside memory-copy bandwidth (NumPy and
  OpenCL buffer copies) measured in the same run;
* the response solve (8- and 16-bit), a second small ``hdrcl merge`` process (warm
  caches), and ``hdrcl batch`` throughput (megapixels per second) against a loop of
  OpenCV merges over the same sets.

It prints every figure with its target (ok / MISSED by how much) and writes JSON.

    python scripts/bench.py                      # 24 MP x 7 and 100 MP x 5 (several minutes)
    python scripts/bench.py --quick              # 2 MP x 5 and 4 MP x 5 (a minute or two)
    python scripts/bench.py --sizes 24x7,100x5 --work /tmp/hdrcl-bench --json out.json

OpenCV is an optional benchmark dependency (``pip install opencv-python-headless``);
without it, or with ``--skip-opencv``, that comparison is reported as not measured.
docs/bench.md explains each figure and its caveats.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import time

import numpy as np

SCRIPT = os.path.abspath(__file__)
HERE = os.path.dirname(SCRIPT)
if HERE not in sys.path:
    sys.path.insert(0, HERE)

from benchlib import MB, WAIT_IDLE, ensure_importable, have_opencv, hdrcl_cmd, machine_facts, run_measured  # noqa: E402
from benchbrackets import GEN_VERSION, dims, ensure_set, exposure_times, size_label, write_bracket_jpegs  # noqa: E402
from benchreport import MERGE_VARIANTS, evaluate, print_report  # noqa: E402
from benchworkers import worker_copy, worker_inproc  # noqa: E402

def _log(msg: str) -> None:
    print(f"[bench {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)



# --------------------------------------------------------------------------------------
# Sizes
# --------------------------------------------------------------------------------------

def parse_sizes(text: str):
    """``"24x7,100x5"`` -> [(24.0, 7), (100.0, 5)]; a bare ``24`` means 7 frames below
    50 MP and 5 from 50 MP (the issue's two sets)."""
    out = []
    for part in text.split(","):
        part = part.strip().lower()
        if not part:
            continue
        mp, _, frames = part.partition("x")
        mp = float(mp)
        n = int(frames) if frames else (7 if mp < 50 else 5)
        if mp <= 0 or n < 2:
            raise SystemExit(f"--sizes: bad entry '{part}' (megapixels x frames, frames >= 2)")
        out.append((mp, n))
    if not out:
        raise SystemExit("--sizes: nothing to measure")
    return out


def run_worker(kind: str, spec: dict, logdir: str, tag: str, timeout: float = 7200) -> dict:
    """Run an in-process measurement in its own Python process; returns its JSON."""
    res = run_measured([sys.executable, SCRIPT, "--worker", kind, json.dumps(spec)], logdir, tag, timeout)
    if res.get("rc") != 0:
        return {"error": res.get("error", "failed"), "stderr_tail": res.get("stderr", "")[-2000:]}
    out = json.loads(res["stdout"].strip().splitlines()[-1])
    out["worker_rss_mb"] = res["rss_mb"]
    if "background_cpu" in res:
        out["background_cpu"] = res["background_cpu"]
        BACKGROUND.append(res["background_cpu"])
    return out


OPENCV_SCRIPT = r"""
import json, sys, time
t0 = time.perf_counter()
import cv2
import numpy as np
t1 = time.perf_counter()
out, times, paths = sys.argv[1], np.asarray(json.loads(sys.argv[2]), np.float32), sys.argv[3:]
imgs = [cv2.imread(p, cv2.IMREAD_COLOR) for p in paths]
if any(i is None for i in imgs):
    sys.exit("cv2.imread failed")
t2 = time.perf_counter()
resp = cv2.createCalibrateDebevec().process(imgs, times)
t3 = time.perf_counter()
hdr = cv2.createMergeDebevec().process(imgs, times, resp)
t4 = time.perf_counter()
if not cv2.imwrite(out, hdr):
    sys.exit("cv2.imwrite failed")
t5 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "imread_s": t2 - t1, "calibrate_s": t3 - t2, "merge_s": t4 - t3,
                  "imwrite_s": t5 - t4, "threads": cv2.getNumThreads(), "version": cv2.__version__}))
"""


# --------------------------------------------------------------------------------------
# Orchestration
# --------------------------------------------------------------------------------------


#: Background CPU fraction of every measured run (see run_measured).
BACKGROUND: list = []


def _summ(runs: list) -> dict:
    """Best time, all times, max peak RSS over repeated runs of one command."""
    ok = [r for r in runs if r.get("rc") == 0]
    if not ok:
        return {"error": runs[-1].get("error", "failed") if runs else "not run", "cmd": runs[-1].get("cmd") if runs else ""}
    best = min(ok, key=lambda r: r["wall_s"])
    BACKGROUND.extend(r["background_cpu"] for r in ok if "background_cpu" in r)
    return {"best_s": best["wall_s"], "all_s": [round(r["wall_s"], 3) for r in ok],
            "cpu_all_s": [round(r["user_s"] + r["sys_s"], 3) for r in ok],
            "rss_mb": max(r["rss_mb"] for r in ok), "cmd": ok[0]["cmd"],
            "background_cpu_best_run": best.get("background_cpu"),
            **({"error": f"{len(runs) - len(ok)} of {len(runs)} runs failed"} if len(ok) < len(runs) else {})}


def bench_size(work: str, mp: float, frames: int, repeat: int, opencv: str, solve16: bool, logdir: str) -> dict:
    label = size_label(mp, frames)
    info = ensure_set(work, mp, frames)
    paths, times = info["paths"], info["times"]
    tmp = os.path.join(work, "out")
    os.makedirs(tmp, exist_ok=True)
    tag = f"{info['width']}x{info['height']}x{frames}"
    r = {"label": label, "width": info["width"], "height": info["height"], "frames": frames,
         "megapixels": info["megapixels"], "jpeg_mb": info["bytes"] / MB, "times": times, "repeat": repeat}

    _log(f"{label}: decode / solve / kernel / encode (in-process)")
    r["inproc"] = run_worker("inproc", {"paths": paths, "times": times, "repeat": repeat, "tmpdir": tmp,
                                        "solve16": solve16, "seed": 1}, logdir, f"{tag}-inproc")
    ip = r["inproc"]
    if "error" in ip:
        _log(f"  in-process measurements failed: {ip['error']}")
    else:
        _log(f"  decode {ip['decode_serial_s']:.2f} s serial, {ip['decode_parallel_s']:.2f} s parallel; "
             f"encode EXR {ip['encode_exr_s']:.2f} s; solve {ip['solve_8bit_s']:.3f} s; "
             + (f"kernel {ip['kernel_s']:.3f} s = {ip['kernel_gbps']:.2f} GB/s" if "kernel_s" in ip
                else f"kernel: {ip.get('kernel_error')}"))

    resp_path = os.path.join(tmp, f"{tag}-response.json")
    cal = run_measured(hdrcl_cmd("calibrate", *paths, "-o", resp_path), logdir, f"{tag}-calibrate")
    r["hdrcl_calibrate"] = _summ([cal])
    _log(f"  hdrcl calibrate: {cal.get('wall_s', float('nan')):.2f} s, {cal.get('rss_mb', float('nan')):.0f} MB"
         + (f" ({cal['error']})" if cal.get("error") else ""))

    variants = MERGE_VARIANTS
    runs = {k: [] for k in variants}
    for rep in range(repeat):  # round robin: drift affects every variant alike
        for k, (ext, given) in variants.items():
            if given and cal.get("rc") != 0:
                continue
            outp = os.path.join(tmp, f"{tag}-{k}{ext}")
            args = ["merge", *paths, "-o", outp] + (["--response", resp_path] if given else [])
            if ext == ".exr":
                # Like for like with the encode-only baseline (half, zip). With the default
                # --dtype auto this synthetic set (1/4096..1 s, clipped areas) would be
                # written as float: its possible range exceeds half floats.
                args += ["--dtype", "half"]
            res = run_measured(hdrcl_cmd(*args), logdir, f"{tag}-{k}-{rep}")
            runs[k].append(res)
            _log(f"  hdrcl {k} #{rep + 1}: " + (f"{res['wall_s']:.2f} s, {res['rss_mb']:.0f} MB"
                                               if res.get("rc") == 0 else res.get("error", "failed")))
            if os.path.exists(outp):
                os.remove(outp)
    for k in variants:
        r[k] = _summ(runs[k]) if runs[k] else {"error": "not run (calibrate failed)"}

    if opencv:
        cv_rep = 1 if mp >= 50 else repeat  # as many as hdrcl's: medians of >= 3 are quoted
        cvruns = []
        for rep in range(cv_rep):
            outp = os.path.join(tmp, f"{tag}-opencv.hdr")
            res = run_measured([sys.executable, "-c", OPENCV_SCRIPT, outp, json.dumps(times), *paths],
                               logdir, f"{tag}-opencv-{rep}")
            if res.get("rc") == 0:
                res["phases"] = json.loads(res["stdout"].strip().splitlines()[-1])
            cvruns.append(res)
            _log(f"  OpenCV #{rep + 1}: " + (f"{res['wall_s']:.2f} s, {res['rss_mb']:.0f} MB"
                                            if res.get("rc") == 0 else res.get("error", "failed")))
            if os.path.exists(outp):
                os.remove(outp)
        r["opencv"] = _summ(cvruns)
        ok = [c for c in cvruns if c.get("rc") == 0]
        if ok:
            r["opencv"]["phases"] = min(ok, key=lambda c: c["wall_s"])["phases"]
    else:
        r["opencv"] = {"error": "not measured (OpenCV not installed or --skip-opencv)"}

    # Ratios of this size.
    rat = {}
    m_hdr, m_exr = r["merge_hdr_calibrate"], r["merge_exr_response"]
    if "best_s" in r["opencv"] and "best_s" in m_hdr:
        rat["vs_opencv"] = r["opencv"]["best_s"] / m_hdr["best_s"]
    if len(r["opencv"].get("all_s", [])) >= 2 and len(m_hdr.get("all_s", [])) >= 2:
        # medians beside the best runs: on a shared machine the best run may be a lucky one
        rat["vs_opencv_median"] = statistics.median(r["opencv"]["all_s"]) / statistics.median(m_hdr["all_s"])
        # and of CPU seconds (user + system), which other processes on the cores move far less
        rat["vs_opencv_cpu"] = statistics.median(r["opencv"]["cpu_all_s"]) / statistics.median(m_hdr["cpu_all_s"])
    if "best_s" in r["opencv"] and "best_s" in r["merge_hdr_response"]:
        rat["vs_opencv_response_given"] = r["opencv"]["best_s"] / r["merge_hdr_response"]["best_s"]
    if "decode_parallel_s" in ip:
        de = ip["decode_parallel_s"] + ip["encode_exr_s"]
        rat["decode_encode_s"] = de
        rat["decode_serial_encode_s"] = ip["decode_serial_s"] + ip["encode_exr_s"]
        if "best_s" in m_exr:
            rat["vs_decode_encode"] = m_exr["best_s"] / de
        if "best_s" in r["merge_exr_calibrate"]:
            rat["vs_decode_encode_calibrating"] = r["merge_exr_calibrate"]["best_s"] / de
    rss = [r[k]["rss_mb"] for k in variants if "rss_mb" in r[k]]
    if rss:
        rat["merge_rss_max_mb"] = max(rss)
    r["ratios"] = rat
    return r


def bench_second_process(work: str, repeat: int, logdir: str) -> dict:
    info = ensure_set(work, 1.0, 3, seed=3)
    tmp = os.path.join(work, "out")
    os.makedirs(tmp, exist_ok=True)
    outp = os.path.join(tmp, "small.exr")
    resp = os.path.join(tmp, "small-response.json")
    out = {"set": f"{info['width']}x{info['height']} x 3 JPEG"}
    first = run_measured(hdrcl_cmd("merge", *info["paths"], "-o", outp, "--save-response", resp), logdir, "small-first")
    out["first_s"] = first.get("wall_s")
    if first.get("rc") != 0:
        out["error"] = first.get("error")
        return out
    for k, extra in (("calibrating", []), ("response_given", ["--response", resp])):
        runs = [run_measured(hdrcl_cmd("merge", *info["paths"], "-o", outp, *extra), logdir, f"small-{k}-{i}")
                for i in range(max(3, repeat))]
        out[k] = _summ(runs)
        if "best_s" in out[k]:
            out[k]["median_s"] = statistics.median(out[k]["all_s"])
    py = run_measured([sys.executable, "-c", "pass"], logdir, "python-startup")
    imp = run_measured([sys.executable, "-c", "import hdrcl"], logdir, "import-hdrcl")
    out["python_startup_s"] = py.get("wall_s")
    out["import_hdrcl_s"] = imp.get("wall_s")
    _log(f"second process: first {out['first_s']:.2f} s, then "
         + ", ".join(f"{k} {out[k].get('best_s', float('nan')):.2f} s" for k in ("calibrating", "response_given")))
    return out


def _help_option(text: str, *names):
    for n in names:
        if re.search(rf"(^|[\s,]){re.escape(n)}([\s,=]|$)", text, re.M):
            return n
    return None


OPENCV_BATCH_SCRIPT = r"""
import json, sys, time
import cv2
import numpy as np
sets = json.loads(sys.argv[1])
outdir = sys.argv[2]
for k, (paths, times) in enumerate(sets):
    imgs = [cv2.imread(p, cv2.IMREAD_COLOR) for p in paths]
    if any(i is None for i in imgs):
        sys.exit("cv2.imread failed")
    t = np.asarray(times, np.float32)
    resp = cv2.createCalibrateDebevec().process(imgs, t)
    hdr = cv2.createMergeDebevec().process(imgs, t, resp)
    if not cv2.imwrite(f"{outdir}/set{k}.hdr", hdr):
        sys.exit("cv2.imwrite failed")
"""


def bench_batch(work: str, logdir: str, repeat: int, opencv: str, sets: int = 8, mp: float = 6.0,
                frames: int = 3) -> dict:
    """``hdrcl batch`` over a folder of ``sets`` bracket sets, in megapixels merged per
    second, against one process looping OpenCV's calibrate + merge over the same sets."""
    probe = run_measured(hdrcl_cmd("batch", "--help"), logdir, "batch-help", timeout=120)
    if probe.get("rc") != 0:
        return {"available": False, "note": "batch: not available (" + probe.get("error", "?") + ")"}
    help_text = probe["stdout"]
    outopt = _help_option(help_text, "--out-dir", "--output-dir", "--outdir", "--output", "-o")
    force = _help_option(help_text, "--force")
    folder = os.path.join(work, "inputs", f"batch-{sets}x{mp:g}MPx{frames}-v{GEN_VERSION}")
    os.makedirs(folder, exist_ok=True)
    start = _dt.datetime(2024, 6, 2, 9, 0, 0)
    width, height = dims(mp)
    groups = []
    for k in range(sets):  # each set 10 minutes after the previous one: scan sees 8 sets
        sub = os.path.join(folder, f"set{k}")
        marker = os.path.join(sub, "done")
        if not os.path.isfile(marker):
            os.makedirs(sub, exist_ok=True)
            p = write_bracket_jpegs(sub, width, height, frames, seed=100 + k,
                                    start=start + _dt.timedelta(minutes=10 * k), prefix=f"s{k}_")
            # Flat folder: batch / scan group by EXIF, not by sub-folder.
            for q in p:
                os.replace(q, os.path.join(folder, os.path.basename(q)))
            open(marker, "w").close()
        groups.append(sorted(os.path.join(folder, f) for f in os.listdir(folder) if f.startswith(f"s{k}_")))
    megapixels = sets * width * height / 1e6  # radiance megapixels each tool writes
    out = {"available": True, "sets": sets, "set": f"{size_label(mp, frames)} JPEG", "folder": folder,
           "megapixels": megapixels}
    runs = {"hdrcl": [], "opencv": []}
    summary = None
    times = exposure_times(frames)
    for i in range(max(1, repeat)):  # alternately: drift hits both alike
        outdir = os.path.join(work, "out", "batch")
        shutil.rmtree(outdir, ignore_errors=True)
        os.makedirs(outdir)
        cmd = ["batch", folder] + ([outopt, outdir] if outopt else []) + ([force] if force else [])
        res = run_measured(hdrcl_cmd(*cmd), logdir, f"batch-hdrcl-{i}", cwd=None if outopt else outdir)
        runs["hdrcl"].append(res)
        try:  # hdrcl batch's own account of the sets it found and merged
            with open(os.path.join(outdir, "report.json")) as f:
                summary = json.load(f).get("summary")
        except (OSError, ValueError, AttributeError):
            pass
        _log(f"batch hdrcl #{i + 1}: " + (f"{res['wall_s']:.2f} s = {megapixels / res['wall_s']:.1f} MP/s, peak RSS "
                                         f"{res['rss_mb']:.0f} MB, report {summary}" if res.get("rc") == 0
                                         else res.get("error", "failed")))
        shutil.rmtree(outdir, ignore_errors=True)
        if opencv:
            os.makedirs(outdir)
            res = run_measured([sys.executable, "-c", OPENCV_BATCH_SCRIPT,
                                json.dumps([(g, times) for g in groups]), outdir], logdir, f"batch-opencv-{i}")
            runs["opencv"].append(res)
            _log(f"batch OpenCV loop #{i + 1}: " + (f"{res['wall_s']:.2f} s = {megapixels / res['wall_s']:.1f} MP/s"
                                                   if res.get("rc") == 0 else res.get("error", "failed")))
            shutil.rmtree(outdir, ignore_errors=True)
    out["hdrcl"] = _summ(runs["hdrcl"])
    if summary is not None:
        out["hdrcl"]["summary"] = summary
    out["opencv"] = _summ(runs["opencv"]) if runs["opencv"] else {"error": "not measured (OpenCV not installed)"}
    for k in ("hdrcl", "opencv"):
        if "best_s" in out[k]:
            out[k]["mp_per_s"] = megapixels / out[k]["best_s"]
            out[k]["mp_per_s_median"] = megapixels / statistics.median(out[k]["all_s"])
    if "mp_per_s" in out["hdrcl"] and "mp_per_s" in out["opencv"]:
        out["vs_opencv"] = out["hdrcl"]["mp_per_s"] / out["opencv"]["mp_per_s"]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default=None,
                    help="megapixels x frames, comma-separated [default: 24x7,100x5; --quick: 2x5,4x5]")
    ap.add_argument("--quick", action="store_true", help="small sizes and fewer repeats (a minute or two)")
    ap.add_argument("--work", default=None,
                    help="folder for generated inputs (cached between runs) and outputs "
                         "[default: $TMPDIR/hdrcl-bench]")
    ap.add_argument("--json", default=None, help="where to write the results [default: WORK/bench-results.json]")
    ap.add_argument("--skip-opencv", action="store_true", help="do not run the OpenCV comparison")
    ap.add_argument("--skip-batch", action="store_true", help="do not run the hdrcl batch throughput check")
    ap.add_argument("--repeat", type=int, default=None,
                    help="runs per figure, best kept [default: 3 below 50 MP, 2 from 50 MP; --quick: 2]")
    ap.add_argument("--copy-mib", type=int, default=512, help="buffer size of the copy-bandwidth test (>= 256)")
    ap.add_argument("--wait-idle", type=float, default=0.0, metavar="SECONDS",
                    help="before each measured run, wait up to this long for other processes to use "
                         "< 15 %% of the CPU (shared machines) [default: 0, do not wait]")
    ap.add_argument("--shoot", action="store_true",
                    help="run the shoot benchmark (scripts/shoot_bench.py: batch throughput on whole shoots) "
                         "instead; the other options go to it (see shoot_bench.py --help)")
    ap.add_argument("--worker", nargs=2, help=argparse.SUPPRESS)
    args = sys.argv[1:] if argv is None else [str(x) for x in argv]
    if "--shoot" in args:  # its own process; both scripts build on benchlib, neither imports the other
        return subprocess.call([sys.executable, os.path.join(os.path.dirname(SCRIPT), "shoot_bench.py"),
                                *[x for x in args if x != "--shoot"]])
    a = ap.parse_args(argv)
    ensure_importable()

    if a.worker:
        kind, spec = a.worker
        fn = {"inproc": worker_inproc, "copy": worker_copy}[kind]
        print(json.dumps(fn(json.loads(spec))))
        return 0

    WAIT_IDLE["max_s"] = max(0.0, a.wait_idle)
    sizes = parse_sizes(a.sizes or ("2x5,4x5" if a.quick else "24x7,100x5"))
    work = os.path.abspath(a.work or os.path.join(os.environ.get("TMPDIR", "/tmp"), "hdrcl-bench"))
    os.makedirs(work, exist_ok=True)
    logdir = os.path.join(work, "logs")
    json_path = os.path.abspath(a.json or os.path.join(work, "bench-results.json"))
    t_start = time.perf_counter()
    res = {"command": " ".join([os.path.basename(sys.executable), *sys.argv]) if argv is None else str(argv),
           "started": _dt.datetime.now().isoformat(timespec="seconds"), "quick": a.quick, "work": work,
           "json": json_path, "sizes": []}

    _log(f"work folder {work}")
    res["machine"] = machine_facts(logdir)
    _log(f"machine: {res['machine'].get('cpu')}, {res['machine'].get('cpu_count')} cores; "
         f"OpenCL {res['machine'].get('opencl_device')}")
    res["opencv_version"] = "" if a.skip_opencv else have_opencv()
    if not a.skip_opencv and not res["opencv_version"]:
        _log("OpenCV not installed (pip install opencv-python-headless): comparison skipped")

    _log("copy bandwidth")
    res["copy"] = run_worker("copy", {"mib": max(256, a.copy_mib), "reps": 5}, logdir, "copy")
    for i, (mp, frames) in enumerate(sizes):
        repeat = a.repeat or (2 if a.quick else (3 if mp < 50 else 2))
        res["sizes"].append(bench_size(work, mp, frames, repeat, res["opencv_version"], solve16=(i == 0),
                                       logdir=logdir))
    res["second_process"] = bench_second_process(work, a.repeat or 3, logdir)
    res["batch"] = {"available": False, "note": "batch: skipped (--skip-batch)"} if a.skip_batch else \
        bench_batch(work, logdir, 1 if a.quick else min(3, a.repeat or 3), res["opencv_version"])
    if not res["batch"].get("available"):
        _log(res["batch"]["note"])
    rows = evaluate(res)
    res["targets"] = [dict(r[5], id=r[4]) for r in rows]
    res["background_cpu"] = {"mean": statistics.mean(BACKGROUND) if BACKGROUND else None,
                             "max": max(BACKGROUND) if BACKGROUND else None,
                             "runs": len(BACKGROUND),
                             "runs_over_10pct": sum(1 for b in BACKGROUND if b > 0.10),
                             "waited_for_idle_s": WAIT_IDLE["waited_s"]}
    res["ratios"] = {s["label"]: s["ratios"] for s in res["sizes"]}
    for s in res["sizes"]:
        if s["inproc"].get("kernel_gbps") and res["copy"].get("reference_gbps"):
            res["ratios"][s["label"]]["kernel_vs_copy"] = s["inproc"]["kernel_gbps"] / res["copy"]["reference_gbps"]
    res["elapsed_s"] = time.perf_counter() - t_start
    os.makedirs(os.path.dirname(json_path), exist_ok=True)
    with open(json_path, "w") as f:
        json.dump(res, f, indent=1, default=float)
    print_report(res, rows)
    _log(f"finished in {res['elapsed_s'] / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
