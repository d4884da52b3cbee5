"""Alignment never lies and never loses a set (issue 32 item 3).

Generated hand-held brackets (textured radiance through a known camera, each frame a
window of a larger canvas cut at a known offset) with one bad frame: mirrored, noise,
another part of the scene beyond the start's reach. Such a frame is left out with a
``check`` finding naming it, or refused when too few frames would remain; a set on a
tripod whose registration fails (half the frame moving: leaves, water) is merged
unaligned with a ``note``, never refused.
"""
import json
import os

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.core import synthetic as s

H, W, M = 240, 320, 150
CAM = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
SHIFTS = [(5, -7), (-9, 4), (0, 0), (3, 11), (-6, 9)]  # the middle exposure is the reference


def _canvas(seed=21):
    from test_align import textured_radiance

    big = textured_radiance(H + 2 * M, W + 2 * M, seed=seed)
    return big, s.stops(len(SHIFTS), 1.5, centre=1.0 / float(np.median(big)))


def _frame(big, t, dy, dx, k, noise=0.5):
    return s.bracket(big[M + dy:M + dy + H, M + dx:M + dx + W], [t], CAM, noise=noise, seed=k)[0]


def _write(d, frames, times):
    from hdrcl.io.ldr import write_ldr

    os.makedirs(d, exist_ok=True)
    paths = []
    for k, f in enumerate(frames):
        paths.append(os.path.join(str(d), f"f{k}.png"))
        write_ldr(paths[-1], f)
    return paths, ",".join(repr(float(t)) for t in times)


def handheld_with(bad, d):
    """The hand-held bracket with frame 1 replaced by ``bad`` (mirrored, noise, far);
    ``(paths, times text)``."""
    big, times = _canvas()
    frames = [_frame(big, t, dy, dx, k) for k, ((dy, dx), t) in enumerate(zip(SHIFTS, times))]
    if bad == "mirrored":
        frames[1] = frames[1][:, ::-1].copy()
    elif bad == "noise":
        frames[1] = np.random.default_rng(0).integers(0, 256, frames[1].shape).astype(np.uint8)
    elif bad == "far":  # 120 px away: beyond the whole-pixel search's reach
        frames[1] = _frame(big, times[1], 100, -120, 1)
    return _write(d, frames, times)


def static_windy(d, n=5, seed=3):
    """A tripod set in which the left half moves between frames (leaves, water): the
    registration of some frames does not converge, the frames do not move."""
    from test_align import textured_radiance

    rad = textured_radiance(H, W, seed=seed)
    times = s.stops(n, 1.5, centre=1.0 / float(np.median(rad)))
    frames = s.bracket(rad, times, CAM, noise=8.0, seed=1)
    for k in range(n):
        other = textured_radiance(H, W, seed=10 + k)
        frames[k][:, : W // 2] = s.bracket(other, [times[k]], CAM, noise=8.0, seed=1)[0][:, : W // 2]
    return _write(d, frames, times)


def _merge(paths, tt, out, *opts):
    return CliRunner().invoke(main, ["merge", *paths, "--times", tt, "-o", str(out), "--align", *opts])


@pytest.mark.parametrize("bad, opts", [("mirrored", ()), ("noise", ("--align-model", "homography", "--crop")),
                                       ("far", ("--crop",))])
def test_a_frame_that_cannot_be_aligned_is_left_out_and_named(cl_device, tmp_path, bad, opts):
    import hdrcl

    paths, tt = handheld_with(bad, tmp_path / "in")
    r = _merge(paths, tt, tmp_path / "a.exr", *opts)
    assert r.exit_code == 0, r.output
    said = [ln for ln in r.output.splitlines() if "f1.png" in ln and "left out" in ln]
    assert len(said) == 1 and "cannot be aligned to" in said[0], r.output
    assert "4 frames" in r.output
    model = opts[1] if opts and opts[0] == "--align-model" else "auto"
    res = hdrcl.merge_files(paths, tmp_path / "b.exr", times=[float(t) for t in tt.split(",")], align=True,
                            align_model=model, crop="--crop" in opts, keep_radiance=True)
    (f,) = [f for f in res.findings if f.check == "alignment"]
    assert f.severity == "check" and f.file == "f1.png"
    assert [os.path.basename(p) for p in res.paths] == ["f0.png", "f2.png", "f3.png", "f4.png"]
    assert len(res.times) == len(res.alignment) == len(res.shifts) == 4
    assert [a["file"] for a in res.alignment] == ["f0.png", "f2.png", "f3.png", "f4.png"]
    assert np.all(np.isfinite(res.radiance))


def test_a_set_left_with_one_frame_is_refused_naming_the_frame(cl_device, tmp_path):
    paths, tt = handheld_with("noise", tmp_path / "in")
    keep = [1, 2]  # the noise frame and the reference: nothing to merge without it
    r = _merge([paths[k] for k in keep], ",".join(tt.split(",")[k] for k in keep), tmp_path / "a.exr")
    assert r.exit_code == 3, r.output
    assert "f1.png" in r.output and "cannot be aligned" in r.output
    assert len([ln for ln in r.output.splitlines() if ln.strip()]) == 1
    assert not (tmp_path / "a.exr").exists()


@pytest.mark.parametrize("model", ["auto", "shift"])
def test_a_static_set_whose_registration_fails_is_merged_unaligned(cl_device, tmp_path, model):
    import hdrcl

    paths, tt = static_windy(tmp_path / "in")
    r = _merge(paths, tt, tmp_path / "a.exr", "--align-model", model)
    assert r.exit_code == 0, r.output
    assert "5 frames" in r.output
    res = hdrcl.merge_files(paths, tmp_path / "b.exr", times=[float(t) for t in tt.split(",")], align=True,
                            align_model=model)
    notes = [f for f in res.findings if f.check == "alignment" and "do not move" in f.message]
    assert notes and all(f.severity == "note" for f in res.findings if f.check == "alignment")
    if model == "auto":
        assert any("merged unaligned" in f.message for f in notes)
        assert all(a["model"] in ("none", "reference") for a in res.alignment)
    assert all(np.allclose(a["matrix"], np.eye(3), atol=0.5) for a in res.alignment)


def test_batch_keeps_a_set_with_a_bad_frame_flagged_and_a_static_set_done(cl_device, tmp_path):
    """In a batch with --align: the set with a noise frame is merged without it, status
    ``check`` naming it; the tripod set whose registration fails is merged whole, with no
    alignment finding."""
    shoot = tmp_path / "shoot"
    lines = []
    for name, (paths, tt) in (("a", handheld_with("noise", tmp_path / "a")), ("b", static_windy(tmp_path / "b"))):
        for p, t in zip(paths, tt.split(",")):
            os.makedirs(shoot, exist_ok=True)
            dst = shoot / f"{name}{os.path.basename(p)}"
            os.replace(p, dst)
            lines.append(f"{dst.name} {t}\n")
    (shoot / "times.txt").write_text("".join(lines))
    r = CliRunner().invoke(main, ["batch", str(shoot), "--align", "-o", str(tmp_path / "out"), "--no-preview",
                                  "--frames-per-set", "5"])
    assert r.exit_code == 0, r.output
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    by = {os.path.basename(st["files"][0])[0]: st for st in rep["sets"]}
    assert by["a"]["status"] == "check", by["a"]
    assert [f["file"] for f in by["a"]["findings"] if f["severity"] == "check"] == ["af1.png"]
    assert len(by["a"]["alignment"]) == 4
    # the tripod set is merged whole and its alignment flags nothing; its moving half is the
    # agreement check's business (frames disagree there: "try --deghost")
    assert not [f for f in by["b"]["findings"] if f["check"] == "alignment" and f["severity"] == "check"], by["b"]
    assert {f["check"] for f in by["b"]["findings"] if f["severity"] == "check"} <= {"agreement"}
    assert len(by["b"]["alignment"]) == 5


def _moved_case(d, fill):
    """Frames moved by known similarities (corners uncovered by the motion in ``fill``)
    and the true bracket (the reference window, every frame)."""
    from moved import IGNORE, move, similarity

    big, times = _canvas(seed=5)
    truth = [_frame(big, t, 0, 0, k) for k, t in enumerate(times)]
    rng = np.random.default_rng(2)
    frames = []
    for k, f in enumerate(truth):
        if k == len(truth) // 2:
            frames.append(f)
            continue
        m = similarity(rng.uniform(-1.5, 1.5), 1.0 + rng.uniform(-0.01, 0.01), rng.uniform(-12, 12),
                       rng.uniform(-12, 12), H, W)
        frames.append(move(f, m, ignore=IGNORE, fill=fill))
    return _write(d, frames, times), _write(os.path.join(str(d), "truth"), truth, times)


def test_black_corners_cost_no_more_than_ignore_colour_ones(cl_device, tmp_path):
    """Corners a rotation uncovered, painted black (a camera's or converter's fill) or
    in the ignore colour: the aligned merges are as close to the unmoved bracket's."""
    import hdrcl
    from moved import IGNORE, stops_rms

    rms = {}
    for fill in ("black", "ignore"):
        (paths, tt), (tpaths, _) = _moved_case(tmp_path / fill, (0, 0, 0) if fill == "black" else IGNORE)
        times = [float(t) for t in tt.split(",")]
        tri = hdrcl.merge_files(tpaths, tmp_path / f"t-{fill}.exr", times=times, keep_radiance=True,
                                ignore_color=IGNORE, fit_exposures="off")
        res = hdrcl.merge_files(paths, tmp_path / f"m-{fill}.exr", times=times, keep_radiance=True, align=True,
                                ignore_color=IGNORE, response=tri.response, fit_exposures="off")
        assert not res.findings, [f.message for f in res.findings]
        rms[fill] = stops_rms(res.radiance, tri.radiance)
    assert rms["black"] <= rms["ignore"] + 0.01, rms
    assert rms["black"] < 0.1, rms


def test_a_small_still_set_is_merged_whole(cl_device, tmp_path):
    """A 96x64 tripod set with --align: the fits are short of samples only because the
    image is small (they keep most of what the frames share), never "cannot be aligned"
    (review: the whole set was refused, or lost a frame)."""
    from test_align import textured_radiance

    rad = textured_radiance(64, 96, seed=4)
    times = s.stops(3, 2.0, centre=1.0 / float(np.median(rad)))
    paths, tt = _write(tmp_path / "in", s.bracket(rad, times, CAM, noise=1.0, seed=2), times)
    r = _merge(paths, tt, tmp_path / "a.exr")
    assert r.exit_code == 0, r.output
    assert "3 frames" in r.output and "left out" not in r.output and "cannot be aligned" not in r.output
