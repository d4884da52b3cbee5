"""Exposure verification and refinement (issue 5): wrong metadata is named and fixed;
right metadata (the Memorial set) is left alone."""
import logging

import numpy as np
import pytest

import hdrcl
from hdrcl.core import synthetic as s
from hdrcl.core.bracket import Bracket
from hdrcl.core.calibrate import exposures_used
from hdrcl.core.exposure.fit import fit_exposures
from hdrcl.report.leaveoneout import leave_one_out_all


@pytest.fixture(scope="module")
def bracket():
    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
    rad = s.radiance_field(90, 120, decades=4.0, seed=11)
    times = s.stops(7, 1.0, centre=1.0 / float(np.median(rad)))
    return s.bracket(rad, times, cam, noise=0.5, seed=12), times


def test_fit_finds_exact_deviations(bracket):
    frames, times = bracket
    wrong = times.copy()
    wrong[2] *= 2.0  # labelled a stop brighter than it is
    wrong[5] /= 2.0
    fit = fit_exposures(frames, wrong)
    assert list(np.flatnonzero(fit.flagged)) == [2, 5]
    np.testing.assert_allclose(fit.stops[[2, 5]], [-1.0, 1.0], atol=0.05)
    np.testing.assert_allclose(fit.fitted, times, rtol=0.03)
    good = fit_exposures(frames, times)
    assert not good.flagged.any() and np.abs(good.stops).max() < 0.05


def test_wrong_frames_named_and_loo_recovers(bracket, caplog, cl_device):
    frames, times = bracket
    wrong = times.copy()
    wrong[2] *= 1.7  # 0.77 stops off
    wrong[4] = wrong[3] * 1.05  # mistyped: nearly the neighbour's time
    caplog.set_level(logging.WARNING, logger="hdrcl")
    resp = hdrcl.calibrate(frames, wrong)
    named = [r.getMessage() for r in caplog.records if "pixels say" in r.getMessage()]
    assert any(m.startswith("image 2:") for m in named) and any(m.startswith("image 4:") for m in named)
    assert len(named) == 2
    used = exposures_used(resp, wrong)
    valid = [None] * len(frames)

    def loo(t):
        rows = leave_one_out_all(Bracket(frames=frames, times=np.asarray(t), valid=valid), fit_exposures="off")
        return float(np.median([r.rmse for r in rows]))

    truth, refined, raw = loo(times), loo(used), loo(wrong)
    assert raw > truth + 3  # the wrong metadata really hurts
    assert refined <= truth + 1.0


def test_off_and_on_modes(bracket):
    frames, times = bracket
    wrong = times.copy()
    wrong[1] *= 1.5
    off = hdrcl.calibrate(frames, wrong, fit_exposures="off")
    assert [e["used"] for e in off.exposures] == list(wrong) and off.exposures[0]["fitted"] is None
    on = hdrcl.calibrate(frames, wrong, fit_exposures="on")
    np.testing.assert_allclose([e["used"] for e in on.exposures], times, rtol=0.05)


@pytest.mark.slow
def test_memorial_times_stay_untouched(memorial_bracket, cl_device):
    br = memorial_bracket
    resp = hdrcl.calibrate(br)
    used = np.array([e["used"] for e in resp.exposures])
    np.testing.assert_array_equal(used, br.times)  # the memorial metadata is right
    fitted = np.array([e["fitted"] for e in resp.exposures])
    assert np.all(np.abs(np.log2(fitted / br.times)) < 0.5)


def test_file_merge_records_nominal_and_used_times(bracket, tmp_path, cl_device):
    from hdrcl.io.radiance import read_metadata
    from hdrcl.io.ldr import write_ldr

    frames, times = bracket
    paths = []
    for k, f in enumerate(frames):
        paths.append(str(tmp_path / f"e{k}.png"))
        write_ldr(paths[-1], f)
    wrong = [float(t) for t in times]
    wrong[2] *= 1.7
    res = hdrcl.merge_files(paths, tmp_path / "m.exr", times=wrong)
    np.testing.assert_allclose(res.nominal, wrong)
    assert abs(np.log2(res.times[2] / times[2])) < 0.1  # refined back to the truth
    meta = read_metadata(str(tmp_path / "m.exr"))
    got = meta["exposuresNominal"]
    got = __import__("json").loads(got) if isinstance(got, str) else got
    np.testing.assert_allclose(got, wrong, rtol=1e-6)
