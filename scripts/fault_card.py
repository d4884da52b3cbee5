#!/usr/bin/env python3
"""Break copies of real camera sets the way cards break, batch each, and say whether the
batch's own result (exit code, summary, ``report.json``) names what went wrong.

Issue 32: an unattended batch must be right or say why. Each case copies the real sets of
``../shared/data`` (the Nikon E995 window ladder, 12 JPEGs, and the Canon 5D Mark II
frobisher bracket, 3 JPEGs) into a card, injects one fault into the window ladder, runs
``hdrcl batch CARD -o OUT`` (with the case's options) in a child process and reads the
result. A case is

``flagged``  when the exit code is not 0, or a set of the ladder failed or is "check", or
             the fault's file (or cause) is named in the summary or in the warnings or
             findings of the ladder's sets (a frame merely set aside as a "single frame"
             is not named); "(ladder cut in N)" is added where the ladder came out as
             several sets, and a note where the untouched frobisher set is not "done";
``silent``   when the batch says "done" and names nothing (the worst outcome we have).

The clean card must come out ``clean``: every set done, no finding (false alarms are
counted too). Prints one line per case and a total; ``--json`` writes the details.

    python scripts/fault_card.py                       # every case
    python scripts/fault_card.py --cases truncated-50,mirrored --keep /tmp/cards
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from typing import Callable, Dict, List, Optional

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.normpath(os.path.join(HERE, "..", "..", "shared", "data"))
WINDOW = "window_e995"
VICTIM = "HDRI_Sample_Scene_Window_-_06.jpg"  # a middle frame of the ladder (1/15 s)


def _read(path):
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise SystemExit(f"{path}: {oiio.geterror()}")
    spec = inp.spec()
    pixels = inp.read_image(0, 0, 0, spec.nchannels, "uint8")
    inp.close()
    return pixels, spec


def _write(path, pixels, spec, **attrs):
    """A JPEG with ``spec``'s metadata (EXIF kept), ``attrs`` changed, quality 95."""
    import OpenImageIO as oiio

    out_spec = oiio.ImageSpec(spec)
    out_spec.width, out_spec.height = pixels.shape[1], pixels.shape[0]
    out_spec.full_width, out_spec.full_height = out_spec.width, out_spec.height
    out_spec.attribute("Compression", "jpeg:95")
    for key, value in attrs.items():
        out_spec.attribute(key, value)
    out = oiio.ImageOutput.create(path)
    if out is None or not out.open(path, out_spec) or not out.write_image(np.ascontiguousarray(pixels)):
        raise SystemExit(f"{path}: cannot write: {oiio.geterror()}")
    out.close()


def _truncate(fraction: float) -> Callable[[str], List[str]]:
    def fault(card: str) -> List[str]:
        p = os.path.join(card, VICTIM)
        data = open(p, "rb").read()
        open(p, "wb").write(data[: int(len(data) * fraction)])
        return [VICTIM]
    return fault


def _zero_bytes(card: str) -> List[str]:
    open(os.path.join(card, VICTIM), "wb").close()
    return [VICTIM]


def _foreign(card: str) -> List[str]:
    """The frame replaced by one of another view (the frobisher scene resized), its EXIF kept."""
    p = os.path.join(card, VICTIM)
    pix, spec = _read(p)
    other, _ = _read(os.path.join(DATA, "frobisher_001", "IMG_2601.jpg"))
    ys = (np.arange(spec.height) * other.shape[0] // spec.height)
    xs = (np.arange(spec.width) * other.shape[1] // spec.width)
    _write(p, other[ys][:, xs], spec)
    return [VICTIM]


def _wrong_exif(card: str) -> List[str]:
    p = os.path.join(card, VICTIM)
    pix, spec = _read(p)
    _write(p, pix, spec, ExposureTime=float(spec.getattribute("ExposureTime")) * 4.0)
    return [VICTIM]


def _mirrored(card: str) -> List[str]:
    p = os.path.join(card, VICTIM)
    pix, spec = _read(p)
    _write(p, pix[:, ::-1], spec)
    return [VICTIM]


def _duplicated(card: str) -> List[str]:
    name = VICTIM.replace(".jpg", "_copy.jpg")
    shutil.copy2(os.path.join(card, VICTIM), os.path.join(card, name))
    return [name]


def _rotated_tag(card: str) -> List[str]:
    """Every frame of the ladder tagged EXIF orientation 6 (a camera held upright)."""
    names = sorted(f for f in os.listdir(card) if f.startswith("HDRI"))
    for f in names:
        p = os.path.join(card, f)
        pix, spec = _read(p)
        _write(p, pix, spec, Orientation=6)
    return ["orientation"]


def _other_camera(card: str) -> List[str]:
    p = os.path.join(card, VICTIM)
    pix, spec = _read(p)
    _write(p, pix, spec, Make="Canon", Model="Canon EOS 5D Mark II")
    return [VICTIM]


def _moved(card: str) -> List[str]:
    """Hand-held: every frame shifted a few pixels against the next (crop windows)."""
    names = sorted(f for f in os.listdir(card) if f.startswith("HDRI"))
    rng = np.random.default_rng(3)
    for f in names:
        p = os.path.join(card, f)
        pix, spec = _read(p)
        dy, dx = rng.integers(0, 12, 2)
        _write(p, pix[dy:dy + spec.height - 12, dx:dx + spec.width - 12], spec)
    return ["--align"]


def _moving_object(card: str) -> List[str]:
    """A bright object covering 5 % of the frame in one middle frame only."""
    p = os.path.join(card, VICTIM)
    pix, spec = _read(p)
    h, w = pix.shape[:2]
    s = int((0.05 * h * w) ** 0.5)
    pix = pix.copy()
    pix[h // 3:h // 3 + s, w // 3:w // 3 + s] = 250
    _write(p, pix, spec)
    return ["--deghost"]


CASES: Dict[str, tuple] = {
    "clean": (None, []),
    "truncated-10": (_truncate(0.10), []),
    "truncated-50": (_truncate(0.50), []),
    "truncated-90": (_truncate(0.90), []),
    "zero-byte": (_zero_bytes, []),
    "foreign-scene": (_foreign, []),
    "wrong-exif": (_wrong_exif, []),
    "mirrored": (_mirrored, []),
    "mirrored-align": (_mirrored, ["--align"]),
    "duplicated": (_duplicated, []),
    "rotated": (_rotated_tag, []),
    "other-camera": (_other_camera, []),
    "hand-held-no-align": (_moved, []),
    "tripod-align": (None, ["--align"]),
    "moving-object": (_moving_object, []),
}


def run_case(name: str, work: str) -> dict:
    fault, options = CASES[name]
    card, out = os.path.join(work, name, "card"), os.path.join(work, name, "out")
    shutil.rmtree(os.path.join(work, name), ignore_errors=True)
    os.makedirs(card)
    for folder in (WINDOW, "frobisher_001"):
        for f in sorted(os.listdir(os.path.join(DATA, folder))):
            if f.lower().endswith(".jpg"):
                shutil.copy2(os.path.join(DATA, folder, f), os.path.join(card, f))
    names = fault(card) if fault else []
    proc = subprocess.run([sys.executable, "-m", "hdrcl", "batch", card, "-o", out, *options],
                          capture_output=True, text=True)
    try:
        report = json.load(open(os.path.join(out, "report.json")))
    except (OSError, ValueError):
        report = {"sets": [], "unmerged": []}
    sets = report.get("sets", [])
    ladder = [x for x in sets if any(os.path.basename(f).startswith("HDRI") for f in x["files"])]
    said = proc.stdout  # the summary, and what the ladder's sets say of themselves
    for x in ladder:
        said += " ".join(x.get("warnings") or []) + json.dumps(x.get("findings") or []) + (x.get("error") or "")
    statuses = {os.path.basename(x["files"][0]): x["status"] for x in sets}
    frob_ok = statuses.get("IMG_2600.jpg") == "done"
    bad = [x["status"] for x in ladder if x["status"] in ("failed", "check")]
    named = [n for n in names if n in said]
    findings = sum(len(x.get("findings") or []) for x in sets)
    if fault is None:
        verdict = "clean" if proc.returncode == 0 and not bad and not findings and len(ladder) == 1 else "false alarm"
    else:
        verdict = "flagged" if (proc.returncode != 0 or bad or named) else "silent"
        if len(ladder) > 1:
            verdict += f" (ladder cut in {len(ladder)})"
        if not frob_ok:
            verdict += " (the untouched set did not come out done)"
    return {"case": name, "verdict": verdict, "exit": proc.returncode, "statuses": statuses, "named": named,
            "findings": findings, "summary": proc.stdout.strip().splitlines()[:6],
            "stderr": proc.stderr.strip().splitlines()[-8:]}


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", help="comma-separated case names (default: all): " + ", ".join(CASES))
    ap.add_argument("--keep", help="work folder to keep (default: a temporary one, removed)")
    ap.add_argument("--json", help="write the details here")
    args = ap.parse_args(argv)
    if not os.path.isdir(os.path.join(DATA, WINDOW)):
        print(f"fault_card: {DATA} holds no {WINDOW}: the real sets are needed", file=sys.stderr)
        return 2
    names = args.cases.split(",") if args.cases else list(CASES)
    work = args.keep or tempfile.mkdtemp(prefix="hdrcl-faults-")
    results = []
    try:
        for n in names:
            r = run_case(n, work)
            results.append(r)
            print(f"{n:20s} {r['verdict']:12s} exit {r['exit']}  sets {r['statuses']}  named {r['named']}",
                  flush=True)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    silent = [r["case"] for r in results if r["verdict"].startswith("silent")]
    alarms = [r["case"] for r in results if r["verdict"] == "false alarm"]
    print(f"{len(results)} case(s): {len(silent)} silent {silent}, {len(alarms)} false alarm(s) {alarms}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
