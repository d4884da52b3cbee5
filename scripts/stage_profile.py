#!/usr/bin/env python3
"""What sets a batch's time: ``hdrcl batch`` run in this process, every thread sampled.

Runs ``hdrcl batch SHOOT -r -o OUT [ARGS]`` in-process (the CLI's own entry, so the
figures are those of the command) while a sampler thread, every ``--interval`` ms, reads
each thread's Python stack (``sys._current_frames``) and its CPU clock (Linux per-thread
clocks: exact to the nanosecond, native threads included, i.e. OpenImageIO's and the
OpenCL runtime's workers). Each interval's wall and CPU are charged to the phase the
thread was in:

* a **context**, the batch step on the stack: scan, plan, responses (the pooled
  calibration), set read (hash, up-to-date check, headers; the read-ahead thread), decode
  ahead, set merge, report.json, CLI (the command outside ``run_batch``); a thread whose
  stack names none (a writer, the OpenCL warm-up) is in the main thread's context;
* a **stage**, the innermost step: open, decode, sample, solve, trust verdict, measure,
  agreement, fuse, encode, write, preview, hash, quality, headers.

Threads without a Python stack (native workers) are charged to the phase the main thread
was in at that moment ("native during"). It prints per phase: main-thread wall and CPU,
the other Python threads' CPU, native CPU during, and the total; then CPU per thread; then
the main thread's top waits (where it sat with its CPU idle: the innermost frame and the
hdrcl line that called it; time it was ready to run but the cores were busy, from
/proc schedstat, is counted apart); then the totals against ``getrusage``. ``--cprofile N`` adds
cProfile's top N functions of the main thread (it slows the run: the phase figures are
then for comparison only).

    python scripts/stage_profile.py SHOOT                     # one run, defaults
    python scripts/stage_profile.py SHOOT --report            # batch options after the shoot
    python scripts/stage_profile.py SHOOT --json prof.json --interval 2 --keep /tmp/out

The sampler costs a few percent of one core (printed); phases shorter than a few
intervals are estimates. Other processes on the machine do not change the CPU figures,
only the wall ones (the load average is printed before and after).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import sys
import tempfile
import threading
import time
from collections import defaultdict

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)

import benchlib  # noqa: E402  (scripts/benchlib.py: the checkout on the path, loadavg)

# (path suffix, function names or None for any, label): the innermost match on the stack
# names a thread's context and its stage. Paths are matched with "/" separators.
CONTEXTS = (
    ("hdrcl/shoot/batch/run.py", {"_manifest"}, "scan"),
    ("hdrcl/shoot/scan.py", {"scan_directory"}, "scan"),
    ("hdrcl/shoot/batch/run.py", {"_plan"}, "plan"),
    ("hdrcl/shoot/batch/pooling.py", {"_prepare_responses"}, "responses"),
    ("hdrcl/shoot/batch/run.py", {"read"}, "set read"),
    ("hdrcl/shoot/batch/setrun.py", {"_read_stage"}, "set read"),
    ("hdrcl/io/ahead.py", {"decode_ahead"}, "decode ahead"),
    ("hdrcl/shoot/batch/setrun.py", {"_merge_stage", "_merge_begin", "_commit_set", "process_set"}, "set merge"),
    ("hdrcl/shoot/batch/run.py", {"_write_report"}, "report.json"),
    ("hdrcl/shoot/batch/run.py", {"run_batch"}, "batch (other)"),
)
#: Contexts nest (a scan inside the batch, a decode ahead inside a set's read): the
#: innermost match names the context; a thread whose stack matches none (a writer or
#: warm-up thread) takes the main thread's context of the moment.
STAGES = (
    ("hdrcl/shoot/batch/pooling.py", {"set_verdict", "trust_findings", "_restore_trust"}, "trust verdict"),
    ("hdrcl/shoot/batch/state.py", {"_file_digest", "set_digest", "response_digest", "_json_digest"}, "hash"),
    ("hdrcl/shoot/batch/state.py", {"_up_to_date"}, "up-to-date check"),
    ("hdrcl/io/reader.py", None, "decode"),
    ("hdrcl/io/frames.py", None, "decode"),
    ("hdrcl/io/framecache.py", None, "decode"),
    ("hdrcl/io/ahead.py", None, "decode"),
    ("hdrcl/io/raw.py", None, "decode"),
    ("hdrcl/io/rawheader.py", None, "headers"),
    ("hdrcl/io/metadata.py", None, "headers"),
    ("hdrcl/io/exif.py", None, "headers"),
    ("hdrcl/io/probe.py", None, "headers"),
    ("hdrcl/core/solve.py", None, "solve"),
    ("hdrcl/core/agreement.py", None, "agreement"),
    ("hdrcl/core/exposure/", None, "measure"),
    ("hdrcl/core/scale.py", None, "measure"),
    ("hdrcl/core/sampling.py", None, "sample"),
    ("hdrcl/cl/fusion.py", None, "fuse"),
    ("hdrcl/core/pipeline.py", {"_fuse"}, "fuse"),
    ("hdrcl/core/reference.py", None, "fuse"),
    ("hdrcl/core/pipeline.py", {"_write"}, "encode"),
    ("hdrcl/core/encode.py", None, "encode"),
    ("hdrcl/io/writers.py", None, "encode"),
    ("hdrcl/io/encoders.py", None, "encode"),
    ("hdrcl/io/halfrange.py", None, "encode"),
    ("hdrcl/io/atomic.py", None, "write"),
    ("hdrcl/report/tonemap.py", None, ""),  # "": the caller decides (a preview's or the report's tone map)
    ("hdrcl/report/preview.py", None, "preview"),
    ("hdrcl/shoot/batch/setrun.py", {"_rebuild_preview"}, "preview"),
    ("hdrcl/io/ldr.py", None, "preview"),
    ("hdrcl/shoot/batch/setquality.py", None, "quality"),
    ("hdrcl/report/", None, "quality"),
    ("hdrcl/core/engine.py", {"open", "_warm_up", "warm"}, "open"),
    ("hdrcl/core/engine.py", {"load"}, "decode"),
    ("hdrcl/core/engine.py", {"sample"}, "sample"),
    ("hdrcl/core/bracket.py", {"_grid_bracket"}, "sample"),
    ("hdrcl/core/engine.py", {"respond"}, "solve"),
    ("hdrcl/core/engine.py", {"measure", "scale"}, "measure"),
    ("hdrcl/core/engine.py", {"fuse"}, "fuse (host)"),
    ("hdrcl/core/engine.py", {"commit"}, "write"),
    ("hdrcl/cl/", None, "OpenCL (other)"),
)
STAGE_ORDER = ("import", "scan", "headers", "hash", "up-to-date check", "open", "decode", "sample", "solve",
               "trust verdict", "measure", "agreement", "fuse", "fuse (host)", "OpenCL (other)", "encode", "write", "preview",
               "quality", "other")
CONTEXT_ORDER = ("CLI", "scan", "plan", "responses", "set read", "decode ahead", "set merge", "report.json",
                 "batch (other)", "idle")


def _match(rules, fn: str, name: str):
    fn = fn.replace(os.sep, "/")
    for suffix, names, label in rules:
        if (suffix in fn) and (names is None or name in names):
            return label
    return None


def classify(frame) -> tuple:
    """(context, stage, innermost hdrcl function) of a thread's stack."""
    stack = []
    while frame is not None:
        stack.append((frame.f_code.co_filename, frame.f_code.co_name, frame.f_lineno))
        frame = frame.f_back
    stage = inner = None
    for fn, name, line in stack:  # innermost first
        if inner is None and "/hdrcl/" in fn.replace(os.sep, "/"):
            inner = f"{name} ({os.path.basename(fn)}:{line})"
        if stage is None:
            stage = _match(STAGES, fn, name) or None
    if any(fn.startswith("<frozen importlib") for fn, _, _ in stack):
        stage = "import"  # a module loaded on first use, wherever that is
    context = None
    for fn, name, _ in stack:
        context = _match(CONTEXTS, fn, name)
        if context:
            break
    return context, stage or "other", inner


def wait_site(frame) -> str:
    """Where a thread waits: its innermost frame and the innermost hdrcl frame above it."""
    inner = f"{frame.f_code.co_name} ({os.path.basename(frame.f_code.co_filename)}:{frame.f_lineno})"
    f = frame
    while f is not None and "/hdrcl/" not in f.f_code.co_filename.replace(os.sep, "/"):
        f = f.f_back
    if f is None or f is frame:
        return inner
    return f"{inner} <- {f.f_code.co_name} ({os.path.basename(f.f_code.co_filename)}:{f.f_lineno})"


def thread_cpu(tid: int) -> float:
    """CPU seconds of thread ``tid`` of this process (Linux: its per-thread CPU clock)."""
    return time.clock_gettime(((~tid) << 3) | 6)


def run_delay(tid: int) -> float:
    """Seconds thread ``tid`` has waited on a run queue (ready, but the cores busy), from
    /proc schedstat; 0.0 where the kernel does not keep it."""
    try:
        with open(f"/proc/self/task/{tid}/schedstat") as f:
            return int(f.read().split()[1]) / 1e9
    except (OSError, ValueError, IndexError):
        return 0.0


def _comm(tid: int) -> str:
    try:
        with open(f"/proc/self/task/{tid}/comm") as f:
            return f.read().strip()
    except OSError:
        return "?"


class Sampler(threading.Thread):
    """Charges every thread's wall and CPU, interval by interval, to its phase."""

    def __init__(self, interval: float):
        super().__init__(name="stage-profile-sampler", daemon=True)
        self.interval = interval
        self.stop = threading.Event()
        self.main_id = threading.main_thread().ident
        self.main_tid = threading.main_thread().native_id
        self.phase = defaultdict(lambda: {"main_wall": 0.0, "main_cpu": 0.0, "py_cpu": 0.0, "native_cpu": 0.0})
        self.threads = defaultdict(lambda: {"cpu": 0.0, "python": False})
        self.waits = defaultdict(float)
        self.unclassified = defaultdict(float)
        self.last = {}
        self.delay = None
        self.main_delay = 0.0
        self.samples = 0
        self.own_cpu = 0.0

    def run(self):
        me = threading.get_native_id()
        t_prev = time.perf_counter()
        self._tick(t_prev, me, first=True)
        while not self.stop.wait(self.interval):
            now = time.perf_counter()
            self._tick(now, me, dt=now - t_prev)
            t_prev = now
        now = time.perf_counter()
        self._tick(now, me, dt=now - t_prev)
        self.own_cpu = thread_cpu(me)

    def _tick(self, now: float, me: int, dt: float = 0.0, first: bool = False):
        frames = sys._current_frames()
        py = {t.native_id: t for t in threading.enumerate() if t.native_id is not None}
        try:
            tids = [int(x) for x in os.listdir("/proc/self/task")]
        except OSError:
            return
        cpu = {}
        for tid in tids:
            if tid == me:
                continue
            try:
                cpu[tid] = thread_cpu(tid)
            except OSError:  # the thread ended meanwhile
                continue
        deltas = {tid: c - self.last.get(tid, c if first else 0.0) for tid, c in cpu.items()}
        delay = run_delay(self.main_tid)
        queued = 0.0 if self.delay is None else max(0.0, delay - self.delay)
        self.delay = delay
        # a thread born during the interval: all of its CPU so far belongs to it
        self.last.update(cpu)
        if first:
            return
        self.samples += 1
        main_frame = frames.get(self.main_id)
        main_phase = classify(main_frame)[:2] if main_frame is not None else (None, "other")
        # the main thread outside run_batch: the CLI (imports, options, printing)
        main_phase = (main_phase[0] or "CLI", main_phase[1])
        for tid, d in deltas.items():
            t = py.get(tid)
            if t is not None and t.ident in frames:
                ctx, stage, inner = classify(frames[t.ident])
                ctx = ctx or main_phase[0]
                name = t.name
                self.threads[name]["python"] = True
                if tid == self.main_tid:
                    ph = self.phase[(ctx, stage)]
                    ph["main_wall"] += dt
                    ph["main_cpu"] += d
                    if stage == "other" and inner:
                        self.unclassified[inner] += dt
                    self.main_delay += queued
                    blocked = dt - d - queued  # neither running nor ready: waiting on something
                    if blocked > 0.5 * dt:
                        self.waits[(ctx, wait_site(frames[t.ident]))] += blocked
                else:
                    self.phase[(ctx, stage)]["py_cpu"] += d
            else:
                name = "native: " + _comm(tid)
                self.phase[main_phase]["native_cpu"] += d
            self.threads[name]["cpu"] += d


def _order(key):
    ctx, stage = key
    ci = CONTEXT_ORDER.index(ctx) if ctx in CONTEXT_ORDER else len(CONTEXT_ORDER)
    si = STAGE_ORDER.index(stage) if stage in STAGE_ORDER else len(STAGE_ORDER)
    return ci, si, stage


def profile_batch(shoot: str, out: str, extra: list, interval: float, cprofile: int = 0) -> dict:
    """One in-process ``hdrcl batch SHOOT -r -o OUT EXTRA``; the figures as a dict."""
    t0 = time.perf_counter()
    from hdrcl.cli import main as cli_main  # the CLI's imports: not part of the batch's figure

    import_s = time.perf_counter() - t0
    args = ["batch", shoot, "-r", "-o", out, *extra]
    sampler = Sampler(interval)
    prof = None
    if cprofile:
        import cProfile

        prof = cProfile.Profile()
    r0, w0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    sampler.start()
    code = 0
    try:
        if prof is not None:
            prof.enable()
        cli_main(args, prog_name="hdrcl", standalone_mode=False)
    except SystemExit as exc:
        code = exc.code or 0
    finally:
        if prof is not None:
            prof.disable()
        sampler.stop.set()
        sampler.join()
    wall = time.perf_counter() - w0
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    res = {"cmd": "hdrcl " + " ".join(args), "exit": code, "import_cli_s": import_s, "wall_s": wall,
           "cpu_s": (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime), "samples": sampler.samples,
           "interval_ms": interval * 1000, "sampler_cpu_s": sampler.own_cpu,
           "main_run_queue_s": sampler.main_delay,
           "phases": [dict(context=c, stage=s, **v) for (c, s), v in sorted(sampler.phase.items(),
                                                                              key=lambda kv: _order(kv[0]))],
           "threads": {k: v for k, v in sorted(sampler.threads.items(), key=lambda kv: -kv[1]["cpu"])},
           "waits": [{"context": c, "site": s, "seconds": v} for (c, s), v in
                     sorted(sampler.waits.items(), key=lambda kv: -kv[1])],
           "unclassified": dict(sorted(sampler.unclassified.items(), key=lambda kv: -kv[1])[:10])}
    rep = os.path.join(out, "report.json")
    if os.path.isfile(rep):
        with open(rep) as f:
            r = json.load(f)
        res["summary"] = r.get("summary")
        sums = defaultdict(float)
        for s in r.get("sets", []):
            for k, v in (s.get("seconds") or {}).items():
                if isinstance(v, (int, float)):
                    sums[k] += v
        res["report_seconds"] = dict(sums)
    if prof is not None:
        import io
        import pstats

        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats("cumulative").print_stats(cprofile)
        res["cprofile"] = buf.getvalue()
    return res


def print_profile(res: dict, top: int = 12) -> None:
    p = print
    p(f"{res['cmd']}  (exit {res['exit']}; {res.get('summary')})")
    p(f"  wall {res['wall_s']:.2f} s, process CPU {res['cpu_s']:.2f} s (getrusage, sampler included); "
      f"CLI imports before it {res['import_cli_s']:.2f} s; {res['samples']} samples every "
      f"{res['interval_ms']:g} ms, sampler CPU {res['sampler_cpu_s']:.2f} s")
    p("")
    p(f"  {'context':14s} {'stage':17s} {'main wall':>9s} {'main CPU':>9s} {'py threads':>10s} "
      f"{'native':>8s} {'CPU total':>9s}")
    tot = defaultdict(float)
    for ph in res["phases"]:
        cpu = ph["main_cpu"] + ph["py_cpu"] + ph["native_cpu"]
        if ph["main_wall"] < 0.005 and cpu < 0.005:
            continue
        p(f"  {ph['context']:14s} {ph['stage']:17s} {ph['main_wall']:9.2f} {ph['main_cpu']:9.2f} "
          f"{ph['py_cpu']:10.2f} {ph['native_cpu']:8.2f} {cpu:9.2f}")
        for k in ("main_wall", "main_cpu", "py_cpu", "native_cpu"):
            tot[k] += ph[k]
    p(f"  {'all':14s} {'':17s} {tot['main_wall']:9.2f} {tot['main_cpu']:9.2f} {tot['py_cpu']:10.2f} "
      f"{tot['native_cpu']:8.2f} {tot['main_cpu'] + tot['py_cpu'] + tot['native_cpu']:9.2f}")
    p("  (main wall/CPU: the main thread in that phase; py threads: other Python threads' CPU in that phase by")
    p("   their own stacks; native: threads without a Python stack, charged to the main thread's phase then)")
    by_ctx = defaultdict(lambda: [0.0, 0.0])
    for ph in res["phases"]:
        by_ctx[ph["context"]][0] += ph["main_wall"]
        by_ctx[ph["context"]][1] += ph["main_cpu"] + ph["py_cpu"] + ph["native_cpu"]
    p("")
    p("  per context (wall on the main thread, CPU of all threads): " + "; ".join(
        f"{c} {w:.2f} s / {c_:.2f} CPU-s" for c, (w, c_) in sorted(by_ctx.items(), key=lambda kv: _order((kv[0], "")))
        if w >= 0.005 or c_ >= 0.005))
    p("")
    p("  CPU per thread (s): " + "; ".join(f"{k} {v['cpu']:.2f}" for k, v in list(res["threads"].items())[:top]
                                         if v["cpu"] >= 0.005))
    p("")
    p(f"  main thread's top waits (neither running nor ready to run, "
      f"{sum(w['seconds'] for w in res['waits']):.2f} s in all; besides, ready but the cores busy: "
      f"{res['main_run_queue_s']:.2f} s):")
    for w in res["waits"][:top]:
        p(f"    {w['seconds']:7.2f} s  [{w['context']}] {w['site']}")
    if res.get("unclassified"):
        p("  main thread in hdrcl code no stage rule names (innermost hdrcl function, wall s): " + "; ".join(
            f"{k} {v:.2f}" for k, v in list(res["unclassified"].items())[:6]))
    if res.get("report_seconds"):
        p("  report.json seconds summed over sets: " + ", ".join(
            f"{k} {v:.2f}" for k, v in res["report_seconds"].items()))
    if res.get("cprofile"):
        p("")
        p(res["cprofile"])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 epilog="Arguments after SHOOT that this script does not know go to hdrcl batch.")
    ap.add_argument("shoot", help="folder of photographs (scanned recursively, as hdrcl batch -r)")
    ap.add_argument("--interval", type=float, default=5.0, help="sampling interval in ms [default: 5]")
    ap.add_argument("--keep", default=None, help="output folder to keep [default: a temporary one, removed]")
    ap.add_argument("--json", default=None, help="also write the figures to this file")
    ap.add_argument("--cprofile", type=int, default=0, metavar="N", help="add cProfile's top N functions")
    ap.add_argument("--top", type=int, default=12, help="rows of the thread and wait lists [default: 12]")
    a, extra = ap.parse_known_args(argv)
    benchlib.ensure_importable()
    if a.interval <= 0:
        raise SystemExit("--interval must be > 0")
    if not os.path.isdir(a.shoot):
        raise SystemExit(f"{a.shoot}: not a folder")
    out = a.keep or tempfile.mkdtemp(prefix="stage-profile-")
    if a.keep:
        shutil.rmtree(out, ignore_errors=True)
    load0 = benchlib.loadavg()
    try:
        res = profile_batch(os.path.abspath(a.shoot), out, extra, a.interval / 1000, a.cprofile)
    finally:
        if not a.keep:
            shutil.rmtree(out, ignore_errors=True)
    res["loadavg"] = [load0, benchlib.loadavg()]
    print(f"load average before / after: {load0} / {res['loadavg'][1]}  ({os.cpu_count()} cores)")
    print_profile(res, a.top)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(res, f, indent=1)
    return 0 if res["exit"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
