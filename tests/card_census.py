"""How many generated card patterns ``hdrcl scan`` groups exactly, over seeds.

    python tests/card_census.py [--seeds 0-9] [--group all|scenarios|missed|people] [-v]

Writes every pattern of :mod:`cardgen` (``SCENARIOS`` with ``mixed``, ``MISSED`` with
``mixed_missed``, ``PEOPLE`` with ``mixed_people``) for each seed into a temporary folder,
scans it and compares the sets and the unmerged frames with the truth. Prints one line
per pattern (exact / seeds) and the total; ``-v`` prints the grouping of each miss.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import cardgen  # noqa: E402

GROUPS = {
    "scenarios": list(cardgen.SCENARIOS) + ["mixed"],
    "missed": list(cardgen.MISSED) + ["mixed_missed"],
    "people": list(cardgen.PEOPLE) + ["mixed_people"],
}


def exact(folder, name, seed, verbose=False) -> bool:
    from hdrcl.shoot.scan import scan_directory

    truth = cardgen.write_card(folder, name, seed=seed)
    m = scan_directory(folder)
    got = [[os.path.basename(f) for f in s.files] for s in m.sets]
    stray = sorted(os.path.basename(f) for u in m.unmerged for f in u.files)
    ok = got == truth["sets"] and stray == sorted(truth["unmerged"])
    if not ok and verbose:
        print(f"  {name} seed {seed}: got {[len(g) for g in got]} want {[len(t) for t in truth['sets']]}")
        for s in m.sets:
            print(f"    set ended: {s.reason}")
        for u in m.unmerged:
            print(f"    unmerged {len(u.files)}: {u.reason}; ended: {u.ended}")
    return ok


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-9", help="first-last (inclusive)")
    ap.add_argument("--group", default="all", choices=["all"] + list(GROUPS))
    ap.add_argument("-v", action="store_true")
    a = ap.parse_args(argv)
    lo, hi = (int(x) for x in a.seeds.split("-"))
    seeds = range(lo, hi + 1)
    names = [n for g, ns in GROUPS.items() if a.group in ("all", g) for n in ns]
    total = good = 0
    for name in names:
        n_ok = 0
        for seed in seeds:
            with tempfile.TemporaryDirectory() as tmp:
                n_ok += exact(tmp, name, seed, a.v)
        print(f"{name:20s} {n_ok}/{len(seeds)}")
        total += len(seeds)
        good += n_ok
    print(f"patterns x seeds grouped exactly: {good}/{total} ({len(names)} patterns, seeds {lo}-{hi})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
