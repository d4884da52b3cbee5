"""Issue 32 item 1: a damaged frame is damaged wherever it is met. A truncated or
undecodable frame stays with its set (placed by its EXIF) and fails it naming the file;
a header-less one is unmerged "corrupt"; never a "single frame" cutting its set, never
dropped while the rest merges "done"; nothing raw from the decoders on stderr."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading

import pytest

try:
    import cardgen
except ImportError:  # tests/ made a package
    from tests import cardgen

from hdrcl.shoot.scan import format_table, scan_directory

LADDER = [1 / 500, 1 / 125, 1 / 30, 1 / 8, 1 / 2]


def _card(folder, n=5, fmt="jpg"):
    shots = [cardgen.Shot(cardgen._ladder(LADDER[:n], gaps=[2.0] * (n - 1)), label="a"),
             cardgen.Shot(cardgen._ladder([1 / 1000, 1 / 250, 1 / 60], gaps=[2.0, 2.0], first_gap=100.0), label="b")]
    truth = cardgen.write_shots(folder, shots)
    if fmt != "jpg":  # the same frames as PNG, EXIF kept
        import OpenImageIO as oiio

        for names in truth["sets"]:
            for k, name in enumerate(names):
                src = os.path.join(folder, name)
                buf = oiio.ImageBuf(src)
                dst = os.path.splitext(src)[0] + "." + fmt
                assert buf.write(dst), buf.geterror()
                os.remove(src)
                names[k] = os.path.basename(dst)
    return truth


def _damage(path, how):
    data = open(path, "rb").read()
    if how == "zero":
        data = b""
    elif how == "garbage":
        data = bytes((i * 7919 + 13) % 256 for i in range(len(data)))
    else:
        data = data[:int(len(data) * how)]
    with open(path, "wb") as fh:
        fh.write(data)


def _names(files):
    return [os.path.basename(f) for f in files]


@pytest.mark.parametrize("fmt", ["jpg", "png"])
@pytest.mark.parametrize("how", [0.05, 0.1, 0.3, 0.5, 0.9, "zero", "garbage"])
@pytest.mark.parametrize("n", [3, 5])
def test_damaged_frame_never_cuts_its_set(tmp_path, fmt, how, n):
    truth = _card(tmp_path, n, fmt)
    victim = truth["sets"][0][1]
    _damage(tmp_path / victim, how)
    m = scan_directory(tmp_path)
    got = [_names(s.files) for s in m.sets]
    unmerged = {tuple(_names(u.files)): u.reason for u in m.unmerged}
    assert got[-1] == truth["sets"][1], got  # the other set untouched
    if got[0] == truth["sets"][0]:  # placed in its set: the set names it as damaged
        assert list(m.sets[0].extra["damaged"]) == [victim]
        assert unmerged == {}
        assert f"{victim}: " in format_table(m) and "set 0 fails" in format_table(m)
    else:  # nothing to place it by: unreadable, counted, and the set without it
        assert unmerged == {(victim,): unmerged.get((victim,), "")} and unmerged[(victim,)].startswith("corrupt")
        assert got[0] == [f for f in truth["sets"][0] if f != victim]
        assert how in (0.05, "zero", "garbage") or fmt == "png", (how, unmerged)
    assert not any(r == "single frame" for r in unmerged.values())


def test_cut_exif_still_places_the_frame(tmp_path):
    """10 % of a JPEG: OpenImageIO cannot open it, its EXIF still places it."""
    truth = _card(tmp_path, 5)
    victim = truth["sets"][0][2]
    _damage(tmp_path / victim, 0.1)
    m = scan_directory(tmp_path)
    assert _names(m.sets[0].files) == truth["sets"][0]
    assert "Premature end of JPEG file" in m.sets[0].extra["damaged"][victim]
    assert m.unmerged == []


def test_batch_fails_the_set_naming_the_file(tmp_path):
    truth = _card(tmp_path / "in", 5)
    victim = truth["sets"][0][2]
    _damage(tmp_path / "in" / victim, 0.5)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    r = subprocess.run([sys.executable, "-m", "hdrcl", "batch", str(tmp_path / "in"), "-o", str(tmp_path / "out")],
                       capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 1, r.stderr
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    statuses = [s["status"] for s in rep["sets"]]
    assert statuses == ["failed", "done"], rep["sets"]
    assert victim in rep["sets"][0]["error"] and "truncated JPEG data" in rep["sets"][0]["error"]
    assert rep["summary"]["unreadable_files"] == 1
    raw = [ln for ln in r.stderr.splitlines() if not ln.startswith("hdrcl:")]
    assert raw == [], r.stderr  # no libjpeg line, no driver crash banner at exit


def test_warm_up_is_waited_for_at_exit():
    """A set that fails before its fusion leaves the OpenCL build running; a daemon
    thread there crashed the Intel runtime at exit (rc 134/139)."""
    from hdrcl.core import stages

    started = []
    real = threading.Thread.start

    def spy(self):
        started.append(self)
        return real(self)

    threading.Thread.start = spy
    try:
        stages.warm_up("numpy").join()
    finally:
        threading.Thread.start = real
    assert [t.daemon for t in started if t.name == "hdrcl-warm-up"] == [False]


def test_every_damaged_set_of_a_camera_names_its_file(tmp_path, cl_device):
    """Both sets of one camera hold a frame cut short (so the camera has no set to pool): each
    set fails naming its own file, not with the camera's "no response" (review)."""
    from click.testing import CliRunner

    from hdrcl.cli import main

    truth = _card(tmp_path / "in", 5)
    victims = [truth["sets"][0][2], truth["sets"][1][1]]
    _damage(tmp_path / "in" / victims[0], 0.5)
    _damage(tmp_path / "in" / victims[1], 0.3)
    r = CliRunner().invoke(main, ["batch", str(tmp_path / "in"), "-o", str(tmp_path / "out")])
    assert r.exit_code == 1, r.output
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    assert [s["status"] for s in rep["sets"]] == ["failed", "failed"]
    for s, victim in zip(rep["sets"], victims):
        assert victim in s["error"], s["error"]
