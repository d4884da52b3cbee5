"""Messages that say what is so (issue 29): notes name the capture's own settings, and no
warning nests one conclusion inside another."""
import logging

import numpy as np
import pytest

from hdrcl.core import synthetic as s
from hdrcl.core.exposure.fit import verify_exposures
from hdrcl.core.exposure.known import estimate_exposures
from hdrcl.core.response import Response, knot_positions

CAM = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))


def _true_response(cam=CAM):
    knots = knot_positions(cam.bits)
    z = np.clip(knots, 0.5, cam.levels - 1.5)
    mid = np.argmin(np.abs(knots - cam.levels / 2))
    g = np.stack([cam.g(z, c) for c in range(3)])
    return Response(bits=cam.bits, g=g - g[:, mid:mid + 1], knots=knots, channels=("R", "G", "B"))


def test_known_curve_notes_quote_the_recorded_settings_not_equivalents():
    """A batch measures a frame on the shoot's reference f-number and ISO: its times are
    equivalents (1/826.5 s for a frame shot at 1/4000 s f/1.4 ISO 1600). The notes must
    quote what the camera recorded."""
    rad = s.radiance_field(60, 80, decades=4.0, seed=5)
    labelled = s.stops(5, 1.0, centre=1.0 / float(np.median(rad)))
    truth = labelled.copy()
    truth[3] *= 2.0
    frames = s.bracket(rad, truth, CAM, noise=0.5, seed=6)
    labels = [f"1/{4000 >> k} s f/1.4 ISO 1600" for k in range(5)]
    fit = estimate_exposures(frames, labelled, _true_response(), labels=labels)
    assert list(np.flatnonzero(fit.flagged)) == [3]
    assert fit.notes[0].startswith("image 3: metadata says 1/500 s f/1.4 ISO 1600 but the pixels say (+1.0")
    # without labels the nominal times are quoted, as before
    plain = estimate_exposures(frames, labelled, _true_response())
    assert "metadata says" in plain.notes[0] and "f/1.4" not in plain.notes[0]


def test_no_consensus_warning_is_not_nested(caplog):
    """'metadata kept (no three frames agree ...; the metadata is kept (give --response ...))'
    said the same thing twice, one inside the other."""
    rad = s.radiance_field(60, 80, decades=3.0, seed=4)
    c = 1.0 / float(np.median(rad))
    truth = c * np.array([0.5, 1.0, 2.0, 4.0])
    frames = s.bracket(rad, truth, CAM, noise=0.5, seed=5)
    labelled = truth * np.array([1.0, 2.0, 1.0, 0.5])
    with caplog.at_level(logging.DEBUG):
        verify_exposures(frames, labelled, [f"f{k}.png" for k in range(4)], warn=True)
    text = [r.getMessage() for r in caplog.records]
    kept = [t for t in text if "metadata kept" in t]
    assert kept, text
    for t in text:
        assert t.count("metadata is kept") + t.count("metadata kept") <= 1, t
        assert "((" not in t and not ("(" in t and t.count("(") > t.count(")")), t


def test_standard_attributes_describe_the_capture_not_the_shoot_reference():
    """Issue 29: a Sony set shot at f/1.4 ISO 1600 in a batch whose shoot reference is
    f/8 ISO 100 was written with FNumber 8, isoSpeed 100, ExposureTime 8. The standard
    attributes describe the capture; the reference goes to hdrcl's own attributes."""
    from types import SimpleNamespace

    from hdrcl.io.outmeta import camera_from_infos, hdr_header_lines, standard_attributes

    infos = [SimpleNamespace(fnumber=1.4, iso=1600.0, make="Sony", model="ILCE-7M3", lens=None,
                             focal_length=None, extra={}) for _ in range(3)]
    cam = camera_from_infos(infos, reference=(8.0, 100.0), exposure_time=8.0)
    attrs = dict(standard_attributes(".exr", cam))
    assert attrs["FNumber"] == 1.4 and attrs["isoSpeed"] == 1600.0
    # the same white point at the capture's settings: 8 s at f/8 ISO 100 = 1/65.3 s at f/1.4 ISO 1600
    assert attrs["ExposureTime"] == pytest.approx(8.0 * (1.4 / 8.0) ** 2 * (100.0 / 1600.0))
    assert attrs["hdrcl:referenceFNumber"] == 8.0 and attrs["hdrcl:referenceISO"] == 100.0
    # Radiance's EXPOSURE= stays the reference exposure the stored values were scaled by
    assert "EXPOSURE=8.000000e+00" in hdr_header_lines(cam, "rec709", None)
    # an ISO ladder has no one ISO: no isoSpeed, and no ExposureTime that would need one
    infos[1].iso = 3200.0
    attrs = dict(standard_attributes(".exr", camera_from_infos(infos, exposure_time=0.5)))
    assert "isoSpeed" not in attrs and "ExposureTime" not in attrs and attrs["FNumber"] == 1.4
    assert attrs["hdrcl:referenceISO"] == 1600.0


def test_merge_summary_quotes_the_recorded_shutter_times(tmp_path, cl_device):
    """Issue 29: merge printed '(1/60 s .. 0.9097 s)' for frames shot 1/60 .. 1/4 s: the
    merge's own exposures are equivalents at the first frame's ISO (and refined); the
    summary quotes what the camera recorded."""
    from click.testing import CliRunner

    from hdrcl.cli import main
    from hdrcl.io.ldr import write_photo

    rad = s.radiance_field(48, 64, decades=2.5, seed=3)
    c = 1.0 / float(np.median(rad))
    shots = [(1 / 60, 100), (1 / 15, 100), (1 / 4, 400)]  # the last at ISO 400: 1 s at ISO 100
    frames = s.bracket(rad, [c * t * iso / 100 for t, iso in shots], CAM, noise=0.3, seed=4)
    paths = []
    for k, (f, (t, iso)) in enumerate(zip(frames, shots)):
        paths.append(str(tmp_path / f"f{k}.png"))
        write_photo(paths[-1], f, {"ExposureTime": t, "FNumber": 8.0, "Exif:PhotographicSensitivity": iso})
    res = CliRunner().invoke(main, ["merge", *paths, "-o", str(tmp_path / "o.exr")])
    assert res.exit_code == 0, res.output
    assert "3 frames (1/60 s .. 1/4 s)" in res.output, res.output
    from hdrcl.io.radiance import read_metadata

    assert read_metadata(str(tmp_path / "o.exr"))["exposureText"] == "1/60 s, 1/15 s, 1/4 s"
