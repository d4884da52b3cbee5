"""hdrcl merge --align: hand-held brackets end to end through the CLI."""
import os

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.core import synthetic as s

SHIFTS = [(7, -12), (-25, 31), (0, 0), (40, -40)]  # the middle exposure (index 2) is the reference


@pytest.fixture()
def handheld(tmp_path):
    from test_align import (
        textured_radiance,  # texture at several scales: something to align on
    )

    from hdrcl.io.ldr import write_ldr

    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
    big = textured_radiance(300, 400, seed=21)
    times = s.stops(4, 1.5, centre=1.0 / float(np.median(big)))
    paths = []
    for k, ((dy, dx), t) in enumerate(zip(SHIFTS, times)):
        view = big[60 + dy:240 + dy, 60 + dx:340 + dx]  # the camera moved: frame(y+dy, x+dx) = ref(y, x)
        p = tmp_path / f"h{k}.png"
        write_ldr(str(p), s.bracket(view, [t], cam, noise=0.5, seed=k)[0])
        paths.append(str(p))
    return paths, times, tmp_path


def test_merge_align_recovers_shifts_and_crops(handheld, cl_device):
    paths, times, d = handheld
    tt = ",".join(repr(float(t)) for t in times)
    r = CliRunner().invoke(main, ["merge", *paths, "--times", tt, "-o", str(d / "a.exr"), "--align", "--crop"])
    assert r.exit_code == 0, r.output
    line = [ln for ln in r.output.splitlines() if ln.strip().startswith("aligned")][0]  # "aligned:" or "aligned (to ...):"
    from hdrcl.io.radiance import read_radiance

    rad, meta = read_radiance(str(d / "a.exr"))
    got = [tuple(v) for v in __import__("json").loads(meta["alignShifts"])] if isinstance(meta["alignShifts"], str) \
        else [tuple(v) for v in meta["alignShifts"]]
    ref = SHIFTS[2]  # the middle exposure (index 2 of 4, by time order) is the reference
    want = [(ref[0] - dy, ref[1] - dx) for dy, dx in SHIFTS]  # frame(y+dy, x+dx) = reference(y, x)
    for g, w in zip(got, want):
        assert abs(g[0] - w[0]) <= 1 and abs(g[1] - w[1]) <= 1, (got, want, line)
    assert rad.shape[0] < 180 and rad.shape[1] < 280  # cropped to the common area
    assert np.all(np.isfinite(rad)) and rad.min() > 0


def test_crop_needs_align(handheld):
    paths, times, d = handheld
    r = CliRunner().invoke(main, ["merge", *paths, "--times", "1,2,4,8", "-o", str(d / "b.exr"), "--crop"])
    assert r.exit_code == 2 and "--align" in r.output


def test_align_masks_reach_the_kernel(handheld, monkeypatch, cl_device):
    """Pixels an aligned frame no longer covers are masked on the OpenCL path too:
    the OpenCL and NumPy merges agree."""
    import hdrcl

    paths, times, d = handheld
    a = hdrcl.merge_files(paths, d / "cl.exr", times=list(times), align=True, dtype="float", keep_radiance=True,
                          fit_exposures="off")
    monkeypatch.setenv("HDRCL_OPENCL", "0")
    monkeypatch.delenv("HDRCL_REQUIRE_OPENCL", raising=False)
    b = hdrcl.merge_files(paths, d / "np.exr", times=list(times), align=True, dtype="float", keep_radiance=True,
                          fit_exposures="off", response=a.response)
    np.testing.assert_allclose(a.radiance, b.radiance, rtol=2e-5)


def test_align_masks_decide_the_clipping_rule(tmp_path, monkeypatch, cl_device):
    """A border an aligned frame lost, where every other frame is clipped: with its mask
    honoured the pixel is 'clipped high'; read as a real black sample it would turn
    'clipped low'. OpenCL and NumPy must agree."""
    from test_align import textured_radiance

    import hdrcl
    from hdrcl.io.ldr import write_ldr

    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
    big = textured_radiance(200, 260, seed=4)
    big[:, :40] *= 1e4  # a window blown out in every exposure
    times = s.stops(3, 2.0, centre=1.0 / float(np.median(big)))
    shifts = [(0, 6), (0, 0), (0, 0)]  # the shortest frame moved: its left edge is lost
    paths = []
    for k, ((dy, dx), t) in enumerate(zip(shifts, times)):
        view = big[30 + dy:170 + dy, 30 + dx:230 + dx]
        p = tmp_path / f"c{k}.png"
        write_ldr(str(p), s.bracket(view, [t], cam, noise=0.5, seed=k)[0])
        paths.append(str(p))
    a = hdrcl.merge_files(paths, tmp_path / "cl.exr", times=list(times), align=True, dtype="float",
                          keep_radiance=True, fit_exposures="off")
    assert a.shifts[0] == (0, -6)
    monkeypatch.setenv("HDRCL_OPENCL", "0")
    monkeypatch.delenv("HDRCL_REQUIRE_OPENCL", raising=False)
    b = hdrcl.merge_files(paths, tmp_path / "np.exr", times=list(times), align=True, dtype="float",
                          keep_radiance=True, fit_exposures="off", response=a.response)
    np.testing.assert_allclose(a.radiance, b.radiance, rtol=2e-5)
    assert a.radiance[:, :6].min() > np.median(a.radiance)  # the lost border stays bright


def test_report_measures_the_aligned_cropped_frames(handheld, tmp_path, cl_device):
    import hdrcl
    from hdrcl.report.merge_report import write_quality_report

    paths, times, d = handheld
    res = hdrcl.merge_files(paths, d / "r.exr", times=list(times), align=True, crop=True, thumbnail=64)
    fig, entry = write_quality_report(res, tmp_path / "rep", loo=False)
    assert fig.coverage.shape == res.shape[:2]
    assert (tmp_path / "rep" / "index.html").is_file()


# --------------------------------------------- hand-held: rotation, scale, refusal


@pytest.fixture(scope="module")
def memorial_handheld_files(memorial, tmp_path_factory):
    """Tripod and hand-held (moved by known similarities) brackets of a real Memorial
    frame's scene, as PNG files (see test_align.memorial_handheld)."""
    import imageio.v3 as iio

    from moved import handheld_set

    from hdrcl.io.ldr import write_ldr

    d = tmp_path_factory.mktemp("handheld")
    base = iio.imread(memorial / "memorial0066.png")[..., :3]
    stops = [-2, -1, 0, 1, 2]
    tripod, moved, mats = handheld_set(base, stops, seed=5)
    out = {}
    for kind, frames in (("tripod", tripod), ("moved", moved)):
        paths = []
        for k, f in enumerate(frames):
            p = d / f"{kind}{k}.png"
            write_ldr(str(p), f)
            paths.append(str(p))
        out[kind] = paths
    return out, [float(t) for t in np.exp2(stops)], mats, d


def _stops_rms(a, b):
    """RMS difference in stops of the luminance over the central 80 %."""
    h, w = a.shape[:2]
    y0, y1, x0, x1 = h // 10, h - h // 10, w // 10, w - w // 10
    la = a[y0:y1, x0:x1] @ np.array([0.2126, 0.7152, 0.0722])
    lb = b[y0:y1, x0:x1] @ np.array([0.2126, 0.7152, 0.0722])
    ok = (la > 0) & (lb > 0)
    return float(np.sqrt(np.mean(np.log2(la[ok] / lb[ok]) ** 2)))


def test_handheld_merge_matches_the_tripod_merge(memorial_handheld_files, cl_device):
    import json

    import hdrcl
    from hdrcl.io.radiance import read_radiance

    files, times, mats, d = memorial_handheld_files
    common = dict(times=times, ignore_color=(0, 0, 255), dtype="float", keep_radiance=True, fit_exposures="off")
    tri = hdrcl.merge_files(files["tripod"], d / "tripod.exr", **common)
    common["response"] = tri.response
    plain = hdrcl.merge_files(files["moved"], d / "plain.exr", **common)
    al = hdrcl.merge_files(files["moved"], d / "aligned.exr", align=True, **common)
    err_plain, err_al = _stops_rms(plain.radiance, tri.radiance), _stops_rms(al.radiance, tri.radiance)
    assert err_plain > 0.3  # the motion matters ...
    assert err_al < 0.1, (err_al, err_plain)  # ... and alignment undoes it
    assert len(al.alignment) == 5 and al.alignment[2]["model"] == "reference"
    assert al.shifts[0] == tuple(int(round(v)) for v in al.alignment[0]["shift_px"])
    _, meta = read_radiance(str(d / "aligned.exr"))

    def field(k):
        v = meta[k]
        return json.loads(v) if isinstance(v, str) else v

    assert field("alignModel")[2] == "reference"
    m0 = np.asarray(field("alignTransforms")[0], np.float64).reshape(3, 3)
    np.testing.assert_allclose(m0, al.alignment[0]["matrix"], atol=1e-6)


def test_handheld_merge_with_deghost_and_crop(memorial_handheld_files, cl_device):
    import hdrcl

    files, times, mats, d = memorial_handheld_files
    res = hdrcl.merge_files(files["moved"], d / "dg.exr", times=times, ignore_color=(0, 0, 255), align=True,
                            crop=True, deghost=True, align_model="similarity", keep_radiance=True)
    y0, y1, x0, x1 = res.crop
    assert res.radiance.shape[:2] == (y1 - y0, x1 - x0) and 0.6 < (y1 - y0) / 768 < 1 and 0.6 < (x1 - x0) / 512 < 1
    assert np.all(np.isfinite(res.radiance)) and res.radiance.max() > 0
    assert all(a["model"] in ("similarity", "reference") for a in res.alignment)
    assert res.counts["ghost"] < 0.05 * res.radiance.shape[0] * res.radiance.shape[1]  # aligned: few ghosts


@pytest.mark.parametrize("culprit", ["noise", "other scene"])
def test_unalignable_frame_is_left_out_by_name(memorial_handheld_files, memorial, culprit, cl_device):
    """A frame that cannot be aligned is left out, named by a finding that needs a check
    (the rest still make a bracket); alone with the reference it is refused by name
    (``tests/test_align_unaligned.py``)."""
    import imageio.v3 as iio

    import hdrcl
    from hdrcl.io.ldr import write_ldr

    files, times, mats, d = memorial_handheld_files
    paths = list(files["moved"])
    bad = d / f"bad-{culprit.replace(' ', '-')}.png"
    if culprit == "noise":
        img = np.random.default_rng(0).integers(0, 256, (768, 512, 3)).astype(np.uint8)
    else:  # a frame of a different scene: frobisher's, cut to size
        other = iio.imread(memorial.parent / "frobisher_001" / "IMG_2601.jpg")[..., :3]  # 426 x 640
        img = np.concatenate([other[:, :512]] * 2, axis=0)[:768]
    write_ldr(str(bad), img)
    paths[1] = str(bad)
    out = d / f"left-out-{culprit.replace(' ', '-')}.exr"
    res = hdrcl.merge_files(paths, out, times=times, ignore_color=(0, 0, 255), align=True)
    assert out.exists()
    (f,) = [f for f in res.findings if f.check == "alignment" and f.severity == "check"]
    assert f.file == bad.name and "left out" in f.message
    assert bad.name not in [a["file"] for a in res.alignment] and len(res.alignment) == len(paths) - 1


def test_align_model_is_checked(memorial_handheld_files):
    import hdrcl
    from hdrcl.errors import UsageError

    files, times, _, d = memorial_handheld_files
    with pytest.raises(UsageError, match="affine"):
        hdrcl.merge_files(files["moved"], d / "u.exr", times=times, align=True, align_model="affine")


def test_batch_aligns_before_it_calibrates_as_merge_does(memorial_handheld_files, tmp_path, cl_device):
    """A hand-held set in a batch is warped first, and its response and exposures are
    measured on the warped frames, as ``merge --align`` does: the same map comes out."""
    import shutil

    from click.testing import CliRunner

    from hdrcl.cli import main
    from hdrcl.io.radiance import read_radiance

    files, times, _mats, _d = memorial_handheld_files
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    for p, t in zip(files["moved"], times):
        shutil.copy(p, shoot)
    (shoot / "times.txt").write_text("".join(f"{os.path.basename(p)} {t}\n" for p, t in zip(files["moved"], times)))
    frames = sorted(str(p) for p in shoot.glob("*.png"))
    res = CliRunner().invoke(main, ["merge", *frames, "--align", "-o", str(tmp_path / "m.exr")])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(main, ["batch", str(shoot), "--align", "-o", str(tmp_path / "out"), "--no-preview",
                                    "--frames-per-set", str(len(frames))])
    assert res.exit_code == 0, res.output
    a, _ = read_radiance(str(tmp_path / "m.exr"))
    (b_path,) = (tmp_path / "out").glob("*.exr")
    b, _ = read_radiance(str(b_path))
    assert a.shape == b.shape
    assert _stops_rms(a, b) < 0.01
