#!/usr/bin/env python3
"""hdrcl shoot benchmark: batch throughput on whole shoots of camera-sized JPEGs.

The project's reproducible record of batch throughput (issue 16). For each shoot shape
it generates (once; cached) a folder of 12-24 MP JPEGs with camera EXIF, then measures,
in rounds that alternate the tools so drift hits all alike:

* ``hdrcl batch SHOOT -r -o OUT`` with its defaults (a separate process, as a user runs
  it), and the same with ``--jobs 2``;
* the **decode floor**: every frame decoded once with OpenImageIO and nothing else, on
  ``os.cpu_count()`` threads in one process;
* the **encode floor**: every output of that round's ``hdrcl batch`` (defaults) encoded
  once more in its own format (the EXR's pixel type and compression: half, PIZ by
  default; or .hdr) with OpenImageIO on all cores, one output after another, the encodes
  timed only (as ``../shared/tools/io_floor.py`` does); decode + encode floor = the
  **I/O floor**, what a batch cannot beat on the CPU;
* a loop of **OpenCV**'s Debevec pipeline in one process (``cv2.imread`` per frame,
  ``createCalibrateDebevec().process``, ``createMergeDebevec().process``,
  ``cv2.imwrite(.hdr)`` per set), when ``opencv-python-headless`` is installed;

and prints input megapixels per second (frames x pixels, summed over the shoot) for each,
the ratios batch wall / I/O floor, hdrcl / OpenCV and hdrcl / decode floor beside their
targets (each round's own ratio, median of the rounds), the seconds per
stage that ``hdrcl batch`` records in ``OUT/report.json`` (summed over sets), and
start-up costs (``hdrcl --version`` and a tiny merge).

Shapes: ``one-camera`` (several sets from one camera: one pooled response) and
``per-camera`` (one set per camera, 5-13 frames: one calibration per set).

    python scripts/shoot_bench.py                         # both shapes, 5 sets of 12 MP frames, 3 runs
    python scripts/shoot_bench.py --shape one-camera --mp 24 --sets 6 --runs 5 --workdir /tmp/sb
    python scripts/bench.py --shoot [options]             # the same, from the main benchmark

Frames are made from the real scenes in ``../shared/data`` (memorial, window_e995,
frobisher_001) by ``scripts/benchshoots.py``; ``scripts/benchshootreport.py`` prints the
figures. docs/bench.md describes them.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

SCRIPT = os.path.abspath(__file__)
HERE = os.path.dirname(SCRIPT)
ROOT = os.path.dirname(HERE)
if HERE not in sys.path:
    sys.path.insert(0, HERE)

import benchlib  # noqa: E402  (scripts/benchlib.py: process launcher, machine facts, checkout on the path)
from benchshoots import generate_shoot  # noqa: E402  (scripts/benchshoots.py: the generated shoots)
from benchshootreport import FLOOR_KINDS, TARGETS, print_report  # noqa: E402  (scripts/benchshootreport.py)

FLOORS = os.path.join(HERE, "floors.py")  # the decode, encode and fusion floors, each in its own process

SHAPES = ("one-camera", "per-camera")
DEFAULT_FRAMES = {"one-camera": "7", "per-camera": "5,7,9,13,7,5"}


def _log(msg: str) -> None:
    print(f"[shoot-bench {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def parse_frames(text: str) -> list:
    try:
        vals = [int(v) for v in str(text).split(",") if v.strip()]
    except ValueError:
        raise SystemExit(f"--frames: expected a number or a comma list, got {text!r}") from None
    if not vals or min(vals) < 2 or max(vals) > 15:
        raise SystemExit(f"--frames: each set needs 2 to 15 frames, got {text!r}")
    return vals


# --------------------------------------------------------------------------------------
# Measurements
# --------------------------------------------------------------------------------------

OPENCV_LOOP = r"""
import json, sys, time
t0 = time.perf_counter()
import cv2
import numpy as np
spec = json.load(open(sys.argv[1]))
ph = {"import_s": time.perf_counter() - t0, "imread_s": 0.0, "calibrate_s": 0.0, "merge_s": 0.0, "imwrite_s": 0.0}
for k, s in enumerate(spec["sets"]):
    t1 = time.perf_counter()
    imgs = [cv2.imread(p, cv2.IMREAD_COLOR) for p in s["files"]]
    if any(i is None for i in imgs):
        sys.exit("cv2.imread failed")
    t = np.asarray(s["times"], np.float32)
    t2 = time.perf_counter()
    resp = cv2.createCalibrateDebevec().process(imgs, t)
    t3 = time.perf_counter()
    hdr = cv2.createMergeDebevec().process(imgs, t, resp)
    t4 = time.perf_counter()
    if not cv2.imwrite(f"{spec['out']}/set{k:03d}.hdr", hdr):
        sys.exit("cv2.imwrite failed")
    del imgs, hdr
    t5 = time.perf_counter()
    for key, a, b in (("imread_s", t1, t2), ("calibrate_s", t2, t3), ("merge_s", t3, t4), ("imwrite_s", t4, t5)):
        ph[key] += b - a
ph["threads"] = cv2.getNumThreads()
ph["version"] = cv2.__version__
print(json.dumps(ph))
"""


def _run(cmd, logdir, tag, timeout=3600, cwd=None) -> dict:
    return benchlib.run_measured(cmd, logdir, tag, timeout=timeout, cwd=cwd)


def _stage_sums(report_path: str) -> dict:
    """Seconds per stage key summed over the sets of a batch report, and set counts."""
    with open(report_path) as f:
        rep = json.load(f)
    sums = {}
    for s in rep.get("sets", []):
        for k, v in (s.get("seconds") or {}).items():
            if isinstance(v, (int, float)):
                sums[k] = sums.get(k, 0.0) + float(v)
    return {"stages": sums, "summary": rep.get("summary")}


def run_batch(info: dict, work: str, logdir: str, tag: str, jobs=None, keep=None) -> dict:
    """``hdrcl batch`` on the shoot; its outputs are moved to ``keep`` (for the encode
    floor) when given, else removed."""
    out = os.path.join(work, "out", f"batch-{tag}")
    shutil.rmtree(out, ignore_errors=True)
    extra = ["--jobs", str(jobs)] if jobs else []
    res = _run(benchlib.hdrcl_cmd("batch", info["photos"], "-r", "-o", out, *extra), logdir, tag)
    rep = os.path.join(out, "report.json")
    if os.path.isfile(rep):
        try:
            res.update(_stage_sums(rep))
            shutil.copy(rep, os.path.join(logdir, f"{tag}-report.json"))
        except (OSError, ValueError) as exc:
            res["report_error"] = str(exc)
    summ = res.get("summary") or {}
    if res.get("rc") == 0 and summ.get("done") != len(info["sets"]):
        res["error"] = f"report.json: {summ} (expected {len(info['sets'])} sets done)"
        res["rc"] = -1
    if keep and res.get("rc") == 0:
        shutil.rmtree(keep, ignore_errors=True)
        os.replace(out, keep)
    shutil.rmtree(out, ignore_errors=True)
    return res


def run_encode(info: dict, work: str, logdir: str, tag: str, outputs: str) -> dict:
    """The encode floor of one batch's outputs (``outputs``: the folder run_batch kept)."""
    if not os.path.isdir(outputs):
        return {"rc": -1, "error": "the batch before it failed: no outputs to encode"}
    spec = os.path.join(work, "out", f"{info['key']}-encode.json")
    with open(spec, "w") as f:
        json.dump({"dir": outputs, "tmp": os.path.join(work, "out")}, f)
    res = _floor("encode", spec, logdir, tag)
    if res.get("rc") == 0:
        if not res["outputs"]:
            res.update(rc=-1, error=f"{outputs}: no .exr or .hdr outputs")
    shutil.rmtree(outputs, ignore_errors=True)
    return res


def run_decode(info: dict, work: str, logdir: str, tag: str) -> dict:
    spec = os.path.join(work, "out", f"{info['key']}-decode.json")
    with open(spec, "w") as f:
        json.dump({"files": [p for s in info["sets"] for p in s["files"]]}, f)
    return _floor("decode", spec, logdir, tag)


def run_fusion(info: dict, work: str, logdir: str, tag: str) -> dict:
    """The fusion floor: each set's frames fused once on the OpenCL device (decode not timed)."""
    spec = os.path.join(work, "out", f"{info['key']}-fusion.json")
    with open(spec, "w") as f:
        json.dump({"sets": [{"files": s["files"], "times": s["times"]} for s in info["sets"]]}, f)
    return _floor("fusion", spec, logdir, tag)


def _floor(kind: str, spec: str, logdir: str, tag: str) -> dict:
    """One floor (scripts/floors.py) in its own process: its wall and CPU seconds are those
    of the timed part only (not the interpreter start, the imports or untimed set-up)."""
    res = _run([sys.executable, FLOORS, kind, spec], logdir, tag)
    if res.get("rc") == 0:
        res.update(json.loads(res["stdout"].strip().splitlines()[-1]))
        res["process_wall_s"] = res["wall_s"]
        res["wall_s"] = res[f"{kind}_s"]
        res["timed_cpu_s"] = res.pop("cpu_s")
    return res


def run_opencv(info: dict, work: str, logdir: str, tag: str) -> dict:
    out = os.path.join(work, "out", f"opencv-{tag}")
    shutil.rmtree(out, ignore_errors=True)
    os.makedirs(out)
    spec = os.path.join(work, "out", f"{info['key']}-opencv.json")
    with open(spec, "w") as f:
        json.dump({"out": out, "sets": [{"files": s["files"], "times": s["times"]} for s in info["sets"]]}, f)
    res = _run([sys.executable, "-c", OPENCV_LOOP, spec], logdir, tag)
    if res.get("rc") == 0:
        res["phases"] = json.loads(res["stdout"].strip().splitlines()[-1])
    shutil.rmtree(out, ignore_errors=True)
    return res


def _warm_page_cache(info: dict) -> None:
    for s in info["sets"]:
        for p in s["files"]:
            with open(p, "rb") as f:
                while f.read(1 << 24):
                    pass


def _stats(values: list) -> dict:
    return {"median": statistics.median(values), "min": min(values), "max": max(values), "n": len(values)} \
        if values else {}


def bench_shape(info: dict, work: str, logdir: str, runs: int, opencv: str) -> dict:
    mp = info["megapixels"]
    kinds = ["hdrcl", "encode", "hdrcl_jobs2", "decode", "fusion"] + (["opencv"] if opencv else [])
    kept = os.path.join(work, "out", f"{info['key']}-outputs")
    raw = {k: [] for k in kinds}
    _warm_page_cache(info)
    for i in range(runs):  # rounds: every tool once per round, so drift hits all alike
        for k in kinds:
            tag = f"{info['shape']}-{k}-{i}"
            if k == "hdrcl":
                r = run_batch(info, work, logdir, tag, keep=kept)
            elif k == "encode":
                r = run_encode(info, work, logdir, tag, kept)
            elif k == "hdrcl_jobs2":
                r = run_batch(info, work, logdir, tag, jobs=2)
            elif k == "decode":
                r = run_decode(info, work, logdir, tag)
            elif k == "fusion":
                r = run_fusion(info, work, logdir, tag)
            else:
                r = run_opencv(info, work, logdir, tag)
            raw[k].append(r)
            _log(f"{info['shape']} round {i + 1}/{runs} {k}: " + (
                f"{r['wall_s']:.2f} s = {mp / r['wall_s']:.1f} MP/s, peak RSS {r['rss_mb']:.0f} MB, other "
                f"processes {100 * r.get('background_cpu', 0):.0f} % CPU" if r.get("rc") == 0
                else f"FAILED: {r.get('error', '?')}"))
    res = {"shape": info["shape"], "runs": runs, "figures": {}, "ratios": {}, "stages": {}}
    for k in kinds:
        ok = [r for r in raw[k] if r.get("rc") == 0]
        fig = {"failed": len(raw[k]) - len(ok), "cmd": raw[k][0].get("cmd") if raw[k] else None}
        if not ok:
            fig["error"] = raw[k][-1].get("error", "failed") if raw[k] else "not run"
        else:
            fig["seconds"] = _stats([r["wall_s"] for r in ok])
            fig["mp_per_s"] = _stats([mp / r["wall_s"] for r in ok])
            fig["rss_mb"] = max(r["rss_mb"] for r in ok)
            fig["cpu_s"] = _stats([r["user_s"] + r["sys_s"] for r in ok])  # the process tree's CPU time
            fig["background_cpu"] = _stats([r.get("background_cpu", 0.0) for r in ok])
            fig["background_all"] = [r.get("background_cpu", 0.0) for r in ok]
            if k in FLOOR_KINDS:
                fig["threads"] = ok[0].get("threads")
                fig["process_seconds"] = _stats([r["process_wall_s"] for r in ok])
                fig["timed_cpu_s"] = _stats([r["timed_cpu_s"] for r in ok])  # the floor's own CPU seconds
            if k == "fusion":
                fig["device"] = ok[0].get("device")
            if k == "encode":
                fig["outputs"], fig["output_mp"] = ok[0]["outputs"], ok[0]["output_mp"]
                fig["formats"] = ok[0]["formats"]
            if k == "opencv":
                fig["phases"] = {p: statistics.median(r["phases"][p] for r in ok)
                                 for p in ("import_s", "imread_s", "calibrate_s", "merge_s", "imwrite_s")}
                fig["threads"] = ok[0]["phases"].get("threads")
            if k.startswith("hdrcl"):
                keys = []
                for r in ok:
                    for s in r.get("stages", {}):
                        if s not in keys:
                            keys.append(s)
                res["stages"][k] = {s: statistics.median(r.get("stages", {}).get(s, 0.0) for r in ok) for s in keys}
        if fig.get("error") or fig["failed"]:
            fig.setdefault("error", f"{fig['failed']} of {len(raw[k])} runs failed: "
                                    f"{next(r.get('error') for r in raw[k] if r.get('rc') != 0)}")
        res["figures"][k] = fig

    def ratio(a, b, invert=False):
        fa, fb = res["figures"].get(a, {}), res["figures"].get(b, {})
        if "mp_per_s" not in fa or "mp_per_s" not in fb:
            return None
        of_medians = fa["mp_per_s"]["median"] / fb["mp_per_s"]["median"]
        # Each round's own ratio (its two runs are a few minutes apart at most, so a
        # neighbour's load or the machine's drift hits both alike); the median of those.
        rounds = [rb["wall_s"] / ra["wall_s"] for ra, rb in zip(raw[a], raw[b])
                  if ra.get("rc") == 0 and rb.get("rc") == 0]
        return {"median": statistics.median(rounds) if rounds else of_medians, "rounds": rounds,
                "of_medians": of_medians}

    # The I/O floor: each round's decode floor plus its encode floor.
    floors = [rd["wall_s"] + re_["wall_s"] for rd, re_ in zip(raw["decode"], raw["encode"])
              if rd.get("rc") == 0 and re_.get("rc") == 0]
    if floors:
        res["figures"]["io_floor"] = {"seconds": _stats(floors), "mp_per_s": _stats([mp / f for f in floors]),
                                      "failed": len(raw["decode"]) - len(floors)}
    for h in ("hdrcl", "hdrcl_jobs2"):
        suffix = "" if h == "hdrcl" else "_jobs2"
        res["ratios"]["vs_opencv" + suffix] = ratio(h, "opencv")
        res["ratios"]["vs_decode" + suffix] = ratio(h, "decode")
        # batch wall / I/O floor, round by round (lower is better; 1 = the floor)
        rounds = [rh["wall_s"] / (rd["wall_s"] + re_["wall_s"]) for rh, rd, re_ in
                  zip(raw[h], raw["decode"], raw["encode"]) if rh.get("rc") == 0 and rd.get("rc") == 0
                  and re_.get("rc") == 0]
        res["ratios"]["io_floor" + suffix] = {"median": statistics.median(rounds), "rounds": rounds} \
            if rounds else None
        res["ratios"]["cpu_floor" + suffix] = cpu_floor_ratio(raw[h], raw["decode"], raw["encode"], raw["fusion"])
    return res


def cpu_floor_ratio(batch: list, decode: list, encode: list, fusion: list):
    """Batch CPU-seconds (user + system of the batch process) over the CPU-seconds of the
    decode, encode and fusion floors, round by round (issue 33: <= 1.3x); None where a
    round failed throughout."""
    rounds, parts = [], []
    for rb, rd, re_, rf in zip(batch, decode, encode, fusion):
        if all(r.get("rc") == 0 for r in (rb, rd, re_, rf)):
            floor = rd["timed_cpu_s"] + re_["timed_cpu_s"] + rf["timed_cpu_s"]
            rounds.append((rb["user_s"] + rb["sys_s"]) / floor)
            parts.append((rb["user_s"] + rb["sys_s"], rd["timed_cpu_s"], re_["timed_cpu_s"], rf["timed_cpu_s"]))
    if not rounds:
        return None
    med = [statistics.median(p[i] for p in parts) for i in range(4)]
    return {"median": statistics.median(rounds), "rounds": rounds, "batch_cpu_s": med[0], "decode_cpu_s": med[1],
            "encode_cpu_s": med[2], "fusion_cpu_s": med[3]}


def bench_startup(work: str, logdir: str, data: str, runs: int) -> dict:
    """``hdrcl --version`` and a tiny merge (frobisher, 3 x 0.27 MP), whole processes."""
    out = {"runs": runs}
    if runs <= 0:
        return out
    v = [_run(benchlib.hdrcl_cmd("--version"), logdir, f"startup-version-{i}", timeout=300) for i in range(runs)]
    ok = [r["wall_s"] for r in v if r.get("rc") == 0]
    out["version"] = {"seconds": _stats(ok), "cmd": v[0].get("cmd"),
                      "cpu_s": _stats([r["user_s"] + r["sys_s"] for r in v if r.get("rc") == 0])} \
        if ok else {"error": v[-1].get("error")}
    fro = os.path.join(data, "frobisher_001")
    frames = sorted(os.path.join(fro, f) for f in os.listdir(fro) if f.lower().endswith(".jpg")) \
        if os.path.isdir(fro) else []
    if len(frames) < 2:
        out["tiny_merge"] = {"error": f"{fro}: no frames"}
        return out
    dst = os.path.join(work, "out", "tiny.exr")
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    # No warm-up run: the batch runs before this one have built (and cached) the kernels.
    m = [_run(benchlib.hdrcl_cmd("merge", *frames, "-o", dst), logdir, f"startup-merge-{i}", timeout=300)
         for i in range(runs)]
    ok = [r["wall_s"] for r in m if r.get("rc") == 0]
    out["tiny_merge"] = {"seconds": _stats(ok), "cmd": m[0].get("cmd"), "frames": len(frames),
                         "cpu_s": _stats([r["user_s"] + r["sys_s"] for r in m if r.get("rc") == 0]),
                         "rss_mb": max(r["rss_mb"] for r in m if r.get("rc") == 0)} if ok \
        else {"error": m[-1].get("error")}
    return out


def _lscpu_model() -> str:
    """``lscpu``'s model name, family and model, and hypervisor (e.g. "AMD EPYC, family 25 model 1, KVM")."""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return ""
    f = {k.strip(): v.strip() for k, _, v in (line.partition(":") for line in out.splitlines())}
    parts = [f.get("Model name", "")]
    if f.get("CPU family") and f.get("Model"):
        parts.append(f"family {f['CPU family']} model {f['Model']}")
    if f.get("Hypervisor vendor"):
        parts.append(f"{f['Hypervisor vendor']} guest")
    return ", ".join(p for p in parts if p)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shape", choices=SHAPES + ("both",), default="both",
                    help="one-camera: several sets from one camera (pooled response); per-camera: one set per "
                         "camera [default: both]")
    ap.add_argument("--mp", type=float, default=12.0, help="frame size in megapixels [default: 12]")
    ap.add_argument("--sets", type=int, default=5, help="sets per shoot [default: 5]")
    ap.add_argument("--frames", default=None,
                    help="frames per set, a number or a comma list cycled over the sets [default: one-camera "
                         f"{DEFAULT_FRAMES['one-camera']}, per-camera {DEFAULT_FRAMES['per-camera']}]")
    ap.add_argument("--runs", type=int, default=3, help="runs of each figure, median/min/max reported [default: 3]")
    ap.add_argument("--startup-runs", type=int, default=5,
                    help="runs of each start-up figure; 0 leaves them out [default: 5]")
    ap.add_argument("--skip-opencv", action="store_true", help="leave the OpenCV loop out")
    ap.add_argument("--workdir", "--work", default=os.path.join(tempfile.gettempdir(), "hdrcl-shoot-bench"),
                    help="generated shoots (cached, keyed by their parameters), outputs and logs "
                         "[default: $TMPDIR/hdrcl-shoot-bench]")
    ap.add_argument("--data", default=os.path.join(os.path.dirname(ROOT), "shared", "data"),
                    help="folder of the real scenes (memorial, window_e995, frobisher_001) "
                         "[default: ../shared/data beside the checkout]")
    ap.add_argument("--json", default=None, help="results file [default: WORKDIR/shoot-bench-results.json]")
    ap.add_argument("--wait-idle", type=float, default=0.0, metavar="SECONDS",
                    help="before each measured run, wait up to this long for other processes to use < 15 %% "
                         "of the CPU (shared machines, as in bench.py) [default: 0, do not wait]")
    ap.add_argument("--generate-only", action="store_true", help="generate (or check) the shoots and stop")
    a = ap.parse_args(argv)
    benchlib.ensure_importable()
    if a.mp <= 0 or a.sets < 1 or a.runs < 1:
        raise SystemExit("--mp must be > 0, --sets and --runs >= 1")

    t_start = time.perf_counter()
    benchlib.WAIT_IDLE["max_s"] = max(0.0, a.wait_idle)
    work = os.path.abspath(a.workdir)
    logdir = os.path.join(work, "logs")
    os.makedirs(os.path.join(work, "out"), exist_ok=True)
    shapes = SHAPES if a.shape == "both" else (a.shape,)
    data = os.path.abspath(a.data)
    infos = []
    for shape in shapes:
        frames = parse_frames(a.frames or DEFAULT_FRAMES[shape])
        info = generate_shoot(work, data, shape, a.mp, a.sets, frames)
        if info.get("cached"):
            _log(f"{shape} shoot: cached in {info['folder']}")
        if not info.get("scan", {}).get("ok"):
            _log(f"WARNING: hdrcl scan does not read the {shape} shoot back as written: {info.get('scan')}")
        infos.append(info)
    if a.generate_only:
        for info in infos:
            print(f"{info['shape']}: {info['photos']} ({info['frames']} frames, {info['megapixels']:.0f} MP, "
                  f"scan {'ok' if info['scan'].get('ok') else info['scan']})")
        return 0

    json_path = os.path.abspath(a.json or os.path.join(work, "shoot-bench-results.json"))
    res = {"command": " ".join(sys.argv) if argv is None else "shoot_bench " + " ".join(map(str, argv)),
           "started": _dt.datetime.now().isoformat(timespec="seconds"), "runs": a.runs, "json": json_path,
           "logs": logdir, "targets": TARGETS, "shapes": []}
    res["machine"] = benchlib.machine_facts(logdir)
    res["machine"]["lscpu"] = _lscpu_model()
    _log(f"machine: {res['machine'].get('cpu')}, {res['machine'].get('cpu_count')} cores; "
         f"OpenCL {res['machine'].get('opencl_device')}")
    res["opencv_version"] = "" if a.skip_opencv else benchlib.have_opencv()
    res["opencv_note"] = "--skip-opencv" if a.skip_opencv else (
        "" if res["opencv_version"] else "OpenCV not installed: pip install '.[bench]'")
    if res["opencv_note"] and not a.skip_opencv:
        _log(res["opencv_note"])
    for info in infos:
        _log(f"measuring the {info['shape']} shoot: {info['frames']} frames, {info['megapixels']:.0f} MP")
        res["shapes"].append({"info": info, "result": bench_shape(info, work, logdir, a.runs, res["opencv_version"])})
    if a.startup_runs > 0:
        _log("start-up: hdrcl --version and a tiny merge")
    res["startup"] = bench_startup(work, logdir, data, a.startup_runs)
    bgs = [b for s in res["shapes"] for f in s["result"]["figures"].values() for b in f.get("background_all", [])]
    if bgs:
        res["background"] = {"mean": statistics.mean(bgs), "max": max(bgs), "runs": len(bgs),
                             "over_10pct": sum(1 for b in bgs if b > 0.10)}
    res["elapsed_s"] = time.perf_counter() - t_start
    os.makedirs(os.path.dirname(json_path), exist_ok=True)
    with open(json_path, "w") as f:
        json.dump(res, f, indent=1, default=float)
    print_report(res)
    failed = [f"{s['info']['shape']} {k}" for s in res["shapes"] for k, f in s["result"]["figures"].items()
              if f.get("failed") or "seconds" not in f]
    if failed:
        _log(f"runs failed ({', '.join(failed)}): see {logdir}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
