"""Exposure fusion (Mertens et al. 2007): kernels/mertens.cl against its float64 twin,
bands against the whole image, both against OpenCV's MergeMertens, and ``hdrcl fuse``.

The OpenCV comparisons skip where ``cv2`` does not import (the ``bench`` and ``dev``
extras install it), unless ``HDRCL_REQUIRE_OPENCV`` is set: then that is a failure.
"""
import os

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli.group import main
from hdrcl.core import mertens as M
from hdrcl.core import mertens_bands as B
from hdrcl.core import synthetic as s
from hdrcl.errors import UsageError


def _bracket(h, w, n=3, channels=3, bits=8, seed=2):
    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8), bits=bits)
    rad = s.radiance_field(h, w, decades=4.5, channels=channels, seed=1)
    times = s.stops(n, 2.0, centre=1.0 / float(np.median(rad)))
    return s.bracket(rad, times, cam, noise=0.5, seed=seed)


@pytest.fixture(scope="module")
def cv2():
    try:
        import cv2
    except ImportError:
        if os.environ.get("HDRCL_REQUIRE_OPENCV", "") not in ("", "0"):
            pytest.fail("HDRCL_REQUIRE_OPENCV is set but cv2 does not import (pip install opencv-python-headless)")
        pytest.skip("OpenCV (cv2) not installed: pip install opencv-python-headless")
    return cv2


@pytest.fixture(scope="module")
def proc(cl_device):
    from hdrcl.cl.backend import get_processor

    return get_processor("mertens")


@pytest.mark.parametrize("channels,bits", [(3, 8), (1, 8), (3, 16)])
def test_kernel_equals_twin_on_odd_sizes(proc, channels, bits):
    frames = _bracket(31, 47, 4, channels, bits)
    rng = np.random.default_rng(5)
    valid = [rng.random((31, 47)) > 0.2 for _ in frames]
    fw = M.FusionWeights(1.0, 1.0, 1.0)
    top = M.max_level(31, 47)
    twin = M.NumpyFusion()
    for v in (None, valid):
        got, want = proc.blend(frames, v, fw, top), twin.blend(frames, v, fw, top)
        assert got.shape == (31, 47, channels) and got.dtype == np.float32
        np.testing.assert_allclose(got, want, atol=3e-5, rtol=0)
    gi, gv = proc.tops(frames, None, fw, 2)
    ti, tv = twin.tops(frames, None, fw, 2)
    for a, b in zip(gi + gv, ti + tv):
        assert a.shape == b.shape
        np.testing.assert_allclose(a, b, atol=1e-6, rtol=0)


def test_twin_pyramids_are_opencvs(cv2):
    rng = np.random.default_rng(3)
    for shape in ((31, 47, 3), (16, 24), (2, 3, 3), (1, 2)):
        a = rng.random(shape).astype(np.float32)
        np.testing.assert_allclose(M.pyr_down(a.astype(np.float64)), cv2.pyrDown(a), atol=2e-7)
        h, w = 2 * shape[0] - 1, 2 * shape[1]
        np.testing.assert_allclose(M.pyr_up(a.astype(np.float64), h, w), cv2.pyrUp(a, dstsize=(w, h)), atol=2e-7)
    assert [M.max_level(h, w) for h, w in ((31, 47), (64, 64), (1024, 2000), (1023, 2000))] == [4, 6, 10, 9]


@pytest.mark.parametrize("exponents", [(1.0, 1.0, 1.0), (1.0, 1.0, 0.0)])
def test_fusion_is_opencvs_merge_mertens(cl_device, cv2, exponents):
    frames = _bracket(120, 160, 5)
    want = cv2.createMergeMertens(*exponents).process([f.copy() for f in frames])  # RGB in: its RGB2GRAY is ours
    got = M.exposure_fusion(frames, contrast=exponents[0], saturation=exponents[1], exposedness=exponents[2])
    assert np.abs(got - want).max() * 255 < 0.1  # code levels


def test_bands_are_the_whole_image(cl_device):
    """Bands with their halo give the whole image's result (not an approximation), on
    both backends, with masks, for a height that is no multiple of the band."""
    frames = _bracket(301, 97, 3)
    rng = np.random.default_rng(7)
    valid = [rng.random((301, 97)) > 0.1 for _ in frames]
    for backend in (None, M.NumpyFusion()):
        src = B.ArraySource(frames, valid)
        be = backend or M.backend()
        whole = np.concatenate([r for _, _, r in B.fuse_bands(src, M.FusionWeights(), be)])
        assert B.plan_bands(src, 48)[1:] == (48, 4 * 16)
        parts = list(B.fuse_bands(src, M.FusionWeights(), be, band_rows=48))
        assert [p[0] for p in parts] == list(range(0, 301, 48))
        banded = np.concatenate([r for _, _, r in parts])
        np.testing.assert_allclose(banded, whole, atol=2e-6, rtol=0)


def test_row_source_streams_frames(cl_device):
    """A RowSource (frames made band by band) fuses as the same frames held in memory."""
    frames = _bracket(400, 70, 3)
    calls = []

    def read(k, a, b):
        calls.append((k, a, b))
        return frames[k][a:b]

    src = B.RowSource(400, 70, 3, 3, np.uint8, read)
    got = np.concatenate([r for _, _, r in B.fuse_bands(src, M.FusionWeights(), M.backend(), band_rows=32)])
    np.testing.assert_allclose(got, M.exposure_fusion(frames), atol=2e-6, rtol=0)
    assert max(b - a for _, a, b in calls) == 32 + 2 * 64  # a band and its halo, never the frame


def test_exposure_fusion_refuses_bad_input():
    f = np.zeros((8, 8, 3), np.uint8)
    with pytest.raises(UsageError, match="at least 2 frames"):
        M.exposure_fusion([f])
    with pytest.raises(UsageError, match="frame 1: size 9x8"):
        M.exposure_fusion([f, np.zeros((8, 9, 3), np.uint8)])
    with pytest.raises(UsageError, match="--contrast"):
        M.exposure_fusion([f, f], contrast=-1)
    with pytest.raises(UsageError, match="NaN"):
        M.exposure_fusion([f.astype(np.float32), np.full((8, 8, 3), np.nan, np.float32)])


def test_flat_frames_are_their_mean():
    """No contrast anywhere: every weight is OpenCV's 1e-12, so the result is the mean."""
    out = M.exposure_fusion([np.full((9, 13, 3), 50, np.uint8), np.full((9, 13, 3), 200, np.uint8)])
    np.testing.assert_allclose(out, 125 / 255.0, atol=1e-6)
    assert np.isfinite(out).all()


def test_cli_fuse_writes_the_fusion(tmp_path, write_frames, cl_device):
    frames = _bracket(41, 57, 3)
    paths = write_frames(tmp_path / "in", frames)
    out = tmp_path / "fused.png"
    r = CliRunner().invoke(main, ["fuse", *paths, "-o", str(out), "--exposedness", "0.5"])
    assert r.exit_code == 0, r.output
    assert "3 frames fused, 57x41, 8-bit" in r.output
    from hdrcl.io.frames import read_image

    got = read_image(out).pixels
    want = M.to_codes(M.exposure_fusion(frames, exposedness=0.5))
    assert got.shape == (41, 57, 3) and got.dtype == np.uint8
    assert np.abs(got.astype(int) - want).max() <= 1
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".")]  # no temporary left


def test_cli_fuse_errors_are_one_line(tmp_path, write_frames):
    paths = write_frames(tmp_path / "in", _bracket(20, 30, 2))
    r = CliRunner().invoke(main, ["fuse", paths[0], "-o", str(tmp_path / "o.jpg")])
    assert r.exit_code == 2 and "at least 2 frames" in r.output
    r = CliRunner().invoke(main, ["fuse", *paths, "-o", str(tmp_path / "o.jpg"), "--contrast", "-1"])
    assert r.exit_code == 2 and "--contrast" in r.output
    r = CliRunner().invoke(main, ["fuse", *paths, "-o", str(tmp_path / "o.exr")])
    assert r.exit_code == 2 and "o.exr" in r.output
    r = CliRunner().invoke(main, ["fuse", *paths, str(tmp_path / "missing.png"), "-o", str(tmp_path / "o.jpg")])
    assert r.exit_code == 3 and "missing.png" in r.output
    assert not (tmp_path / "o.jpg").exists()


def test_large_images_go_in_bands_by_themselves(cl_device, monkeypatch):
    """Over WHOLE_BYTES the fusion plans bands of BAND_BYTES (halo included) by itself,
    and gives the whole image's result."""
    frames = _bracket(160, 90, 3)
    whole = M.exposure_fusion(frames)
    src = B.ArraySource(frames)
    monkeypatch.setattr(B, "WHOLE_BYTES", B.working_bytes(100, 90, 3, 1, 3))
    monkeypatch.setattr(B, "BAND_BYTES", B.working_bytes(2 * 64 + 40, 90, 3, 1, 3))
    assert B.plan_bands(src) == (4, 32, 64)
    # 24 MP x 7 frames held in memory are fused whole (1.8 GB), 100 MP x 5 made by bands in bands
    assert B.working_bytes(4000, 6000, 3, 1, 7) <= 2_000_000_000
    made = B.RowSource(8160, 12240, 3, 5, np.uint8, None)
    monkeypatch.undo()
    assert B.plan_bands(made) == (4, 176, 64)
    np.testing.assert_allclose(M.exposure_fusion(frames), whole, atol=2e-6, rtol=0)


def test_cli_fuse_aligns_shifted_frames(tmp_path, cl_device):
    """--align registers hand-held frames (shifted views of one textured scene) before the
    fusion and crops to the common area: the result then matches the fusion of the
    frames cut out in register, far better than the fusion without --align does."""
    from test_align import textured_radiance  # texture at several scales: something to align on

    from hdrcl.io.frames import read_image
    from hdrcl.io.ldr import write_ldr

    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
    big = textured_radiance(300, 400, seed=21)
    times = s.stops(3, 1.5, centre=1.0 / float(np.median(big)))
    shifts = [(7, -12), (0, 0), (-9, 10)]  # the middle exposure is the reference
    paths, still = [], []
    for k, ((dy, dx), t) in enumerate(zip(shifts, times)):
        view = big[60 + dy:240 + dy, 60 + dx:340 + dx]
        frame = s.bracket(view, [t], cam, noise=0.5, seed=k)[0]
        paths.append(str(tmp_path / f"h{k}.png"))
        write_ldr(paths[-1], frame)
        still.append(s.bracket(big[60:240, 60:340], [t], cam, noise=0.5, seed=k)[0])
    out, plain = tmp_path / "aligned.png", tmp_path / "plain.png"
    r = CliRunner().invoke(main, ["fuse", *paths, "-o", str(out), "--align", "--align-model", "shift"])
    assert r.exit_code == 0, r.output
    assert CliRunner().invoke(main, ["fuse", *paths, "-o", str(plain)]).exit_code == 0
    got, unaligned = read_image(out).pixels, read_image(plain).pixels
    assert got.shape[0] <= 180 - 16 and got.shape[1] <= 280 - 22  # cropped to what every frame sees
    want = M.to_codes(M.exposure_fusion(still)).astype(int)

    def best(img):  # mean code difference from the in-register fusion at the best offset, inside a margin
        hh, ww = got.shape[0] - 32, got.shape[1] - 32
        inner = img[16:16 + hh, 16:16 + ww].astype(int)
        return min(np.abs(inner - want[y:y + hh, x:x + ww]).mean()
                   for y in range(0, want.shape[0] - hh + 1) for x in range(0, want.shape[1] - ww + 1))

    err_aligned, err_plain = best(got), best(unaligned[:got.shape[0], :got.shape[1]])
    assert err_aligned < 2 and err_aligned < err_plain / 3, (err_aligned, err_plain)


def test_deliver_fusion_in_merge_and_batch(tmp_path, write_frames, cl_device):
    """Issue 35: exposure fusion delivered by merge and by batch (`--deliver fusion`) beside
    the radiance map, the frames' fusion as `hdrcl fuse` makes it (JPEG rounding apart),
    counted in report.json, and made again from the frames when missing on a rerun."""
    import json

    from hdrcl.io.frames import read_image

    frames = _bracket(41, 57, 3)
    paths = write_frames(tmp_path / "in", frames)
    times = "1/60,1/15,1/4"
    want = M.to_codes(M.exposure_fusion(frames)).astype(int)
    r = CliRunner().invoke(main, ["merge", *paths, "--times", times, "-o", str(tmp_path / "m.exr"),
                                  "--deliver", "fusion"])
    assert r.exit_code == 0, r.output
    got = read_image(tmp_path / "m.fusion.jpg").pixels.astype(int)
    assert got.shape == want.shape and np.median(np.abs(got - want)) <= 2
    (tmp_path / "in" / "times.txt").write_text("".join(f"{os.path.basename(p)} {t}\n"
                                                       for p, t in zip(paths, times.split(","))))
    out = tmp_path / "out"
    for rerun in (False, True):
        r = CliRunner().invoke(main, ["batch", str(tmp_path / "in"), "-o", str(out), "--deliver", "fusion"])
        assert r.exit_code == 0, r.output
        rep = json.loads((out / "report.json").read_text())
        (s,) = rep["sets"]
        (d,) = s["deliverables"]
        assert d["kind"] == "fusion" and rep["summary"]["deliverables"] == {"fusion": 1}
        got = read_image(d["path"]).pixels.astype(int)
        assert np.median(np.abs(got - want)) <= 2
        if not rerun:
            os.remove(d["path"])
    assert any("fusion missing: made from the frames" in w for w in s["warnings"])


def test_quality_report_links_the_deliverables(tmp_path, write_frames, cl_device):
    """Issue 35: the quality report shows the deliverables (linked from the set's card)."""
    import json

    paths = write_frames(tmp_path / "in", _bracket(41, 57, 3))
    (tmp_path / "in" / "times.txt").write_text("".join(f"{os.path.basename(p)} {t}\n"
                                                       for p, t in zip(paths, ("1/60", "1/15", "1/4"))))
    out, rep_dir = tmp_path / "out", tmp_path / "out" / "quality"
    r = CliRunner().invoke(main, ["batch", str(tmp_path / "in"), "-o", str(out), "--deliver", "fusion",
                                  "--report", str(rep_dir)])
    assert r.exit_code == 0, r.output
    (card,) = [json.loads(p.read_text()) for p in rep_dir.glob("*.json")]
    (d,) = card["deliverables"]
    assert d["kind"] == "fusion" and (rep_dir / d["file"]).resolve() == (out / "f0.fusion.jpg").resolve()
    html = (rep_dir / "index.html").read_text()
    assert 'data-kind="fusion"' in html and "f0.fusion.jpg" in html
