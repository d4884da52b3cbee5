"""Are this checkout's outputs the same as another's? Runs merge, batch, farm chunks and Dask on
real and generated sets, and prints one JSON object: for every file written, the digest of its
pixels and of its header (attributes that change from run to run left out: timings, dates,
the software version).

    python scripts/same_outputs.py WORK_DIR > a.json          # with one checkout on PYTHONPATH
    python scripts/same_outputs.py --compare a.json b.json    # what differs (exit 1 if anything)

The refactors of issue 33 hold the merge's outputs byte-identical; this is how that is shown.
"""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
#: The shared camera files: HDRCL_DATA, else ../shared/data beside the checkout, else /work/shared/data.
DATA = next((d for d in (os.environ.get("HDRCL_DATA"), os.path.join(HERE, "..", "..", "shared", "data"),
                         "/work/shared/data") if d and os.path.isdir(d)), os.path.join(HERE, "..", "..", "shared", "data"))
#: Header attributes that differ between two runs of the same merge.
VOLATILE = ("DateTime", "Software", "hdrcl:seconds", "hdrcl:version", "hdrcl:stages", "capDate",
            "hdrcl:created", "hdrcl:host", "hdrcl:command")


def _hdrcl(*args, cwd=None):
    cmd = [sys.executable, "-m", "hdrcl", "-q", *args]
    r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    return {"cmd": " ".join(args), "rc": r.returncode, "stderr": r.stderr.strip().splitlines()[-3:]}


def _digest(path):
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    if inp is None:
        with open(path, "rb") as f:
            return {"bytes": hashlib.sha256(f.read()).hexdigest()[:16]}
    spec = inp.spec()
    pix = inp.read_image(format=oiio.UNKNOWN)
    inp.close()
    attrs = {}
    for a in spec.extra_attribs:
        if any(a.name.startswith(v) or a.name == v for v in VOLATILE):
            continue
        attrs[a.name] = str(a.value)
    return {"pixels": hashlib.sha256(pix.tobytes()).hexdigest()[:16], "shape": list(pix.shape),
            "format": str(spec.format), "header": hashlib.sha256(json.dumps(attrs, sort_keys=True).encode()).hexdigest()[:16],
            "attrs": attrs}


def run(work):
    os.makedirs(work, exist_ok=True)
    runs = []
    mem = os.path.join(DATA, "memorial")
    memorial = sorted(os.path.join(mem, f) for f in os.listdir(mem) if f.endswith(".png"))
    fro = os.path.join(DATA, "frobisher_001")
    frob = sorted(os.path.join(fro, f) for f in os.listdir(fro) if f.lower().endswith(".jpg"))
    runs.append(_hdrcl("merge", *frob, "-o", f"{work}/frobisher.exr"))
    runs.append(_hdrcl("merge", *memorial, "-o", f"{work}/memorial.exr", "--ignore-color", "0,0,255"))
    runs.append(_hdrcl("merge", *memorial, "-o", f"{work}/memorial_align.exr", "--ignore-color", "0,0,255",
                       "--align"))
    runs.append(_hdrcl("merge", *frob, "-o", f"{work}/frobisher_deghost.hdr", "--deghost"))
    shoot = f"{work}/shoot"
    runs.append(_hdrcl("sample-shoot", shoot, "--size", "384x256"))
    runs.append(_hdrcl("batch", shoot, "-o", f"{work}/batch"))
    runs.append(_hdrcl("batch", shoot, "-o", f"{work}/chunks", "--sets", "0"))
    runs.append(_hdrcl("batch", shoot, "-o", f"{work}/chunks", "--sets", "1-9"))
    runs.append(_hdrcl("batch", shoot, "-o", f"{work}/jobs2", "-j", "2"))
    dask = subprocess.run([sys.executable, "-c", (
        "import sys\nfrom distributed import Client, LocalCluster\nfrom hdrcl.api.batch import run_batch\n"
        "if __name__ == '__main__':\n"
        " with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c, "
        "Client(c) as cl:\n"
        f"  r = run_batch({shoot!r}, {work + '/dask'!r}, scheduler=cl)\n  sys.exit(r.exit_code)\n")],
        capture_output=True, text=True)
    runs.append({"cmd": "dask", "rc": dask.returncode, "stderr": dask.stderr.strip().splitlines()[-3:]})
    files = {}
    for dp, _, fs in os.walk(work):
        if os.path.relpath(dp, work).startswith("shoot"):
            continue
        for f in sorted(fs):
            if f.endswith((".exr", ".hdr")):
                p = os.path.join(dp, f)
                files[os.path.relpath(p, work)] = _digest(p)
    return {"runs": runs, "files": files}


def compare(a, b):
    A, B = (json.load(open(p)) for p in (a, b))
    bad = 0
    for ra, rb in zip(A["runs"], B["runs"]):
        if ra["rc"] != rb["rc"]:
            print(f"exit code differs: {ra['cmd']}: {ra['rc']} vs {rb['rc']}"); bad += 1
    for name in sorted(set(A["files"]) | set(B["files"])):
        fa, fb = A["files"].get(name), B["files"].get(name)
        if fa is None or fb is None:
            print(f"{name}: only in {'b' if fa is None else 'a'}"); bad += 1
            continue
        for key in ("pixels", "shape", "format", "header"):
            if fa.get(key) != fb.get(key):
                bad += 1
                print(f"{name}: {key} differs")
                if key == "header":
                    for k in sorted(set(fa["attrs"]) | set(fb["attrs"])):
                        if fa["attrs"].get(k) != fb["attrs"].get(k):
                            print(f"   {k}: {fa['attrs'].get(k)!r:.80} vs {fb['attrs'].get(k)!r:.80}")
    print(f"{len(A['files'])} vs {len(B['files'])} files; {bad} difference(s)")
    return 1 if bad else 0


if __name__ == "__main__":
    if sys.argv[1] == "--compare":
        sys.exit(compare(sys.argv[2], sys.argv[3]))
    print(json.dumps(run(sys.argv[1]), indent=1))
