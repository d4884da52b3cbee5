"""Issue 34: ``--lens-circle`` in the lab's form (the square's lower-left corner, y from
the bottom) converts as docs/luminance.md says, and a circle that does not fit the image's
dark border is said (a ``check`` finding in merge and batch), never for a correct one."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.core.luminance.border import BorderMeter, lens_circle_finding
from hdrcl.core.luminance.fisheye import LuminanceChain

from test_fisheye import _equisolid_sky
from test_luminance_batch import CX, CY, D, H, W, _fisheye_set, _srgb_g


def _lab_to_circle(xleft, ydown, d, height):
    """docs/luminance.md, 'The lens circle': CX = xleft + D/2, CY = H - ydown - D/2."""
    return xleft + d / 2.0, height - ydown - d / 2.0, d


@pytest.mark.parametrize("xleft, ydown, d", [(33, 5, 136), (0, 0, 150), (20, 14, 100), (980 // 20, 10 // 2, 95)])
def test_the_lab_form_converts_to_the_square_pcompos_cuts(xleft, ydown, d):
    img = np.arange(H * W, dtype=np.float64).reshape(H, W)
    # pcompos -x D -y D in.hdr -xleft -ydown: the square whose lower-left corner is (xleft, ydown), y up
    up = img[::-1]
    lab = up[ydown:ydown + d, xleft:xleft + d][::-1]
    left, top, side = LuminanceChain.from_options(lens_circle=_lab_to_circle(xleft, ydown, d, H)).crop_box()
    np.testing.assert_array_equal(img[top:top + side, left:left + side], lab)


def _meter(image, circle):
    h, w, _ = image.shape
    meter = BorderMeter(*circle, h, w)
    for y in range(0, h, 37):  # in strips, as the fusion hands them
        meter.add(y, image[y:y + 37])
    return meter


def test_border_meter_on_a_known_sky():
    cx, cy, d = 161.0, 117.0, 210.0
    sky = _equisolid_sky(lambda t: 1000.0 * (0.3 + np.cos(t)), cx, cy, d, (240, 330))
    assert _meter(sky, (cx, cy, d)).fits() is True
    assert lens_circle_finding(_meter(sky, (cx, cy, d)), (cx, cy, d), "a.jpg") is None
    for wrong in ((cx, cy, d * 0.94), (cx, cy, d * 1.06), (cx + 8, cy, d), (cx, cy - 8, d)):
        f = lens_circle_finding(_meter(sky, wrong), wrong, "/x/a.jpg")
        assert f is not None and f.severity == "check" and f.check == "lens-circle", wrong
        assert f.message.startswith(f"--lens-circle {wrong[0]:g},{wrong[1]:g},{wrong[2]:g} does not fit the dark "
                                    "border of a.jpg (mean outside the circle"), f.message
        assert "check the circle for this camera" in f.message and "\n" not in f.message
    # a circle larger than the frame: the outer ring barely in the image, not judged
    assert _meter(sky, (cx, cy, 700.0)).fits() is None


@pytest.fixture(scope="module")
def domes(tmp_path_factory):
    from hdrcl.io.rsp import write_rsp

    d = tmp_path_factory.mktemp("domes")
    _fisheye_set(d / "shoot" / "dome1", 1)
    g = _srgb_g()
    write_rsp(np.stack([g, g, g]), 256, str(d / "cam.rsp"))
    return d


def _merge(d, circle, out):
    frames = sorted(str(p) for p in (d / "shoot" / "dome1").glob("*.jpg"))
    return CliRunner().invoke(main, ["merge", *frames, "--response", str(d / "cam.rsp"), "--lens-circle",
                                     ",".join(f"{v:g}" for v in circle), "--resize", "48", "-o", str(out)])


def test_merge_says_a_circle_that_does_not_fit_and_not_a_correct_one(domes, tmp_path):
    ok = _merge(domes, (CX, CY, D), tmp_path / "ok.hdr")
    assert ok.exit_code == 0, ok.output
    assert "lens-circle" not in ok.output, ok.output
    for wrong in ((CX, CY, D * 0.94), (CX, CY, D * 1.06), (CX + 5, CY, D)):
        r = _merge(domes, wrong, tmp_path / "w.hdr")
        assert r.exit_code == 0, r.output
        lines = [ln for ln in r.output.splitlines() if "does not fit the dark border" in ln]
        assert len(lines) == 1 and lines[0].startswith("hdrcl: warning: --lens-circle ") and "F1_0.jpg" in lines[0], \
            r.output


def test_batch_marks_the_set_check_with_the_finding(domes, tmp_path):
    args = ["--response", str(domes / "cam.rsp"), "--resize", "48", "--format", "hdr", "--no-preview"]
    good = CliRunner().invoke(main, ["batch", str(domes / "shoot"), "-o", str(tmp_path / "good"), "--lens-circle",
                                     f"{CX:g},{CY:g},{D:g}", *args])
    assert good.exit_code == 0, good.output
    (entry,) = json.loads((tmp_path / "good" / "report.json").read_text())["sets"]
    assert entry["status"] == "done" and not [f for f in entry["findings"] if f["check"] == "lens-circle"], entry
    bad = CliRunner().invoke(main, ["batch", str(domes / "shoot"), "-o", str(tmp_path / "bad"), "--lens-circle",
                                    f"{CX + 5:g},{CY:g},{D:g}", *args])
    assert bad.exit_code == 0, bad.output
    (entry,) = json.loads((tmp_path / "bad" / "report.json").read_text())["sets"]
    assert entry["status"] == "check", entry
    (f,) = [f for f in entry["findings"] if f["check"] == "lens-circle"]
    assert f["severity"] == "check" and f["file"] == "F1_0.jpg" and f["figure"] > 20, f
