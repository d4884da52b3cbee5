#!/usr/bin/env python3
"""hdrcl start-up benchmark: a small set merged end to end, beside the import floors.

Issue 26 item 6 asks for a 640x426 x 3 set in at most 0.25 s end to end (``hdrcl merge
FRAMES -o x.exr``, a fresh process as a user runs it). This script runs that command
``--runs`` times and prints the median wall time and the median CPU time (user + system
of the child: on a shared machine the CPU time is the steadier figure), and beside it
the floors that no merge can go under, each a fresh process timed the same way:

* ``python -c pass`` (the interpreter);
* ``python -c "import numpy"``;
* ``python -c "import numpy, OpenImageIO"`` (what reading and writing the files needs);
* ``python -c "import hdrcl.cli"`` (the command line before a command loads);
* the same decode and EXR write in plain OpenImageIO/NumPy (``--io-floor``): read the
  frames, write a half PIZ EXR of their mean, nothing else.

``--imports`` adds the modules that took longest to import in one merge (``python -X
importtime``), and ``--profile`` a cProfile of one merge (top functions by cumulative
time). The machine's /proc/loadavg is printed before and after: figures taken under load
are not quiet-machine figures.

    python scripts/startup_bench.py                     # 7 runs of the frobisher_001 set
    python scripts/startup_bench.py --runs 15 --imports
    python scripts/startup_bench.py --frames 'a/*.jpg' --target 0.25
"""
from __future__ import annotations

import argparse
import glob
import os
import statistics
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))

if HERE not in sys.path:
    sys.path.insert(0, HERE)
import benchlib  # noqa: E402  (scripts/benchlib.py: loadavg, timed_child)
DEFAULT_FRAMES = os.path.join(HERE, "..", "..", "shared", "data", "frobisher_001", "*.jpg")

IO_FLOOR = """
import sys
import numpy as np
import OpenImageIO as oiio
frames = [oiio.ImageBuf(p).get_pixels(oiio.FLOAT) for p in sys.argv[2:]]
img = np.mean(frames, axis=0)
spec = oiio.ImageSpec(img.shape[1], img.shape[0], img.shape[2], oiio.HALF)
spec.attribute("compression", "piz")
out = oiio.ImageOutput.create(sys.argv[1])
out.open(sys.argv[1], spec)
out.write_image(img)
out.close()
"""


def child_env(args):
    """The children's environment: bytecode cached outside the tree unless ``--as-is``."""
    env = dict(os.environ)
    if not args.as_is:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env["PYTHONPYCACHEPREFIX"] = args.pyc_dir
    return env



def import_times(cmd, env):
    """``[(self_us, cumulative_us, depth, module)]`` of every import in one run of ``cmd``
    (``python -X importtime``), in the order Python reports them."""
    r = subprocess.run([sys.executable, "-X", "importtime"] + cmd[1:], capture_output=True, text=True, env=env)
    rows = []
    for line in r.stderr.splitlines():
        if not line.startswith("import time:") or "|" not in line:
            continue
        parts = line.split("|")
        try:
            own, cum = int(parts[0].split(":")[1]), int(parts[1])
        except (ValueError, IndexError):
            continue
        name = parts[2].rstrip()
        depth = (len(name) - len(name.lstrip())) // 2
        rows.append((own, cum, depth, name.strip()))
    return rows


def import_top(cmd, env, n=12):
    """The ``n`` top-level modules with the largest cumulative import time in ``cmd``."""
    rows = [(cum, name) for _, cum, depth, name in import_times(cmd, env) if depth <= 1]
    rows.sort(reverse=True)
    return rows[:n]


def import_packages(cmd, env, n=12):
    """Import time by top-level package (sum of the modules' own times), largest first:
    what the start-up spends per library (numpy, OpenImageIO, hdrcl, click, ...)."""
    by = {}
    for own, _, _, name in import_times(cmd, env):
        by[name.split(".")[0]] = by.get(name.split(".")[0], 0) + own
    return sorted(((us, pkg) for pkg, us in by.items()), reverse=True)[:n]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", default=DEFAULT_FRAMES, help="glob of the set's frames (default frobisher_001)")
    ap.add_argument("--runs", type=int, default=7, help="runs of each command (medians are printed)")
    ap.add_argument("--target", type=float, default=0.25, help="end-to-end target, seconds")
    ap.add_argument("--imports", action="store_true", help="print the slowest imports of one merge")
    ap.add_argument("--profile", action="store_true", help="print a cProfile of one merge")
    ap.add_argument("--no-floors", action="store_true", help="time the merge only")
    ap.add_argument("--as-is", action="store_true",
                    help="keep PYTHONDONTWRITEBYTECODE / PYTHONPYCACHEPREFIX as the environment has them")
    ap.add_argument("--pyc-dir", default=os.path.join(tempfile.gettempdir(), "hdrcl-startup-pyc"),
                    help="bytecode cache of the children (PYTHONPYCACHEPREFIX)")
    args = ap.parse_args(argv)
    env = child_env(args)
    frames = sorted(glob.glob(args.frames))
    if len(frames) < 2:
        raise SystemExit(f"{args.frames}: fewer than two frames")
    py = sys.executable
    with tempfile.TemporaryDirectory(prefix="hdrcl-startup-") as tmp:
        out = os.path.join(tmp, "x.exr")
        merge = [py, "-m", "hdrcl", "merge", *frames, "-o", out]
        cases = [("hdrcl merge (end to end)", merge)]
        if not args.no_floors:
            cases += [
                ("python -c pass", [py, "-c", "pass"]),
                ("import numpy", [py, "-c", "import numpy"]),
                ("import numpy, OpenImageIO", [py, "-c", "import numpy, OpenImageIO"]),
                ("import hdrcl.cli", [py, "-c", "import hdrcl.cli"]),
                ("I/O floor (decode + EXR write)", [py, "-c", IO_FLOOR, os.path.join(tmp, "floor.exr"), *frames]),
            ]
        print(f"set: {len(frames)} frames, {frames[0]} ...; {args.runs} runs each; "
              f"bytecode {'as the environment has it' if args.as_is else 'cached in ' + args.pyc_dir}; "
              f"loadavg {benchlib.loadavg()}")
        for _, cmd in cases:  # warm the page cache, the bytecode and the OpenCL program caches
            benchlib.timed_child(cmd, env)
        stats = {name: [] for name, _ in cases}
        last = None
        for _ in range(args.runs):  # rounds alternate the commands: drift hits all alike
            for name, cmd in cases:
                wall, cpu, r = benchlib.timed_child(cmd, env)
                stats[name].append((wall, cpu))
                if cmd is merge:
                    last = r
        print(f"{'command':34s} {'wall med':>9s} {'wall min':>9s} {'CPU med':>9s}")
        for name, _ in cases:
            walls = [w for w, _ in stats[name]]
            cpus = [c for _, c in stats[name]]
            print(f"{name:34s} {statistics.median(walls):9.3f} {min(walls):9.3f} {statistics.median(cpus):9.3f}")
        med = statistics.median(w for w, _ in stats[cases[0][0]])
        print(f"end to end: median {med:.3f} s wall against the target {args.target:.2f} s "
              f"({'met' if med <= args.target else 'not met'}); loadavg {benchlib.loadavg()}")
        if last is not None and last.stdout.strip():
            print("merge said:", last.stdout.strip().splitlines()[0])
        if args.imports:
            print("slowest imports of one merge (cumulative ms, python -X importtime):")
            for cum, name in import_top(merge, env):
                print(f"  {cum / 1000:8.1f}  {name}")
            print("import time by package (ms, sum of the modules' own times, one run):")
            for us, pkg in import_packages(merge, env):
                print(f"  {us / 1000:8.1f}  {pkg}")
        if args.profile:
            r = subprocess.run([py, "-m", "cProfile", "-s", "cumtime", "-m", "hdrcl", "merge", *frames, "-o", out],
                               capture_output=True, text=True, env=env)
            print("\n".join(r.stdout.splitlines()[:60]))


if __name__ == "__main__":
    main()
