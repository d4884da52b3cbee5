"""Response recovery: the solve, its oracle (dense least squares), truth, persistence."""
import json

import numpy as np
import pytest

from hdrcl.core import synthetic as s
from hdrcl.core.response import BINS_16BIT, Response, knot_positions
from hdrcl.core.solve import recover_response, recover_response_pooled, solve_curve
from hdrcl.core.weights import weight_values
from hdrcl.errors import InputError, UsageError


def _dense_paper_solve(z, log_t, lam, levels=256):
    """The paper's gsolve, written out densely (the oracle for the sparse solve)."""
    n, p = z.shape
    a = np.zeros((n * p + levels - 1, levels + n))
    b = np.zeros(a.shape[0])
    w = weight_values(np.arange(levels), levels, "hat")
    k = 0
    for i in range(n):
        for j in range(p):
            wij = w[z[i, j]]
            a[k, z[i, j]] = wij
            a[k, levels + i] = -wij
            b[k] = wij * log_t[j]
            k += 1
    a[k, levels // 2] = 1
    k += 1
    for zz in range(1, levels - 1):
        a[k, zz - 1:zz + 2] = lam * w[zz] * np.array([1, -2, 1])
        k += 1
    x = np.linalg.lstsq(a, b, rcond=None)[0]
    return x[:levels] - x[levels // 2]


def test_sparse_solve_equals_dense_least_squares():
    rng = np.random.default_rng(0)
    cam = s.Camera()
    lnE = rng.uniform(-3, 3, 60)
    log_t = np.log(s.stops(6, 1.5))
    x = np.exp(lnE[:, None] + log_t[None, :])
    z = np.clip(np.round(cam.forward(x) * 255 + rng.normal(0, 1, x.shape)), 0, 255).astype(int)
    g_sparse = solve_curve(z, log_t, 8, smoothness=30.0)
    g_dense = _dense_paper_solve(z, log_t, 30.0)
    np.testing.assert_allclose(g_sparse, g_dense, atol=1e-7)


@pytest.mark.parametrize("weight", ["hat", "gaussian"])
def test_recovers_known_s_curve_8bit(scene, weight):
    resp = recover_response(scene["frames"], scene["times"], weight=weight)
    z = np.arange(10, 246)
    for c in range(3):
        d = resp.tables()[c, z] - scene["camera"].g(z, c)
        assert np.max(np.abs(d - d.mean())) < 0.02, f"channel {c}"
    assert resp.warnings == []


def test_recovers_known_curve_16bit_on_binned_levels():
    cam = s.Camera(a=1.0, x0=(1.0,), bits=16)
    rad = s.radiance_field(90, 110, decades=4.0, channels=1, seed=3)
    times = s.stops(5, 2.0, centre=1.0 / float(np.median(rad)))
    frames = s.bracket(rad, times, cam, noise=0.5, seed=4)
    assert frames[0].dtype == np.uint16
    resp = recover_response(frames, times)
    assert resp.knots.size == BINS_16BIT  # never a 65536-column system
    t = resp.tables()
    assert t.shape == (1, 65536)
    z = np.arange(10 * 257, 245 * 257, 97)
    d = t[0, z] - cam.g(z, 0)
    assert np.max(np.abs(d - d.mean())) < 0.02


def test_g_mid_is_zero_and_knots():
    assert knot_positions(8).size == 256
    k16 = knot_positions(16)
    assert k16[0] == pytest.approx(31.5) and k16[-1] == pytest.approx(65503.5)


def test_curve_offset_fixed_at_zmid(scene):
    resp = recover_response(scene["frames"], scene["times"])
    assert np.allclose(resp.tables()[:, 128], 0.0, atol=1e-12)


def test_deterministic_for_a_seed(scene):
    a = recover_response(scene["frames"], scene["times"], seed=5)
    b = recover_response(scene["frames"], scene["times"], seed=5)
    np.testing.assert_array_equal(a.g, b.g)


def test_json_round_trip(tmp_path, scene):
    resp = recover_response(scene["frames"], scene["times"], samples=400, smoothness=25)
    resp.camera = {"make": "Kodak", "model": "DCS460"}
    p = tmp_path / "r.json"
    resp.save(p)
    back = Response.load(p)
    np.testing.assert_allclose(back.g, resp.g, atol=1e-8)
    assert back.smoothness == 25 and back.samples == resp.samples and back.camera["make"] == "Kodak"
    d = json.loads(p.read_text())
    assert d["format"] == "hdrcl-response" and d["version"] == 1 and d["levels"] == 256
    assert not list(tmp_path.glob(".*tmp"))


def test_bad_response_files(tmp_path):
    p = tmp_path / "x.json"
    p.write_text("{not json")
    with pytest.raises(InputError, match="x.json"):
        Response.load(p)
    p.write_text(json.dumps({"format": "other"}))
    with pytest.raises(InputError, match="not an hdrcl response"):
        Response.load(p)
    p.write_text(json.dumps({"format": "hdrcl-response", "version": 99}))
    with pytest.raises(InputError, match="newer"):
        Response.load(p)
    with pytest.raises(InputError, match="no such response file"):
        Response.load(tmp_path / "missing.json")


def test_non_monotonic_curve_is_reported():
    g = np.linspace(-3, 3, 256)[None, :].copy()
    g[0, 100:110] = g[0, 100:110][::-1]
    r = Response(bits=8, g=g, knots=knot_positions(8), channels=("Y",))
    probs = r.monotonic_problems()
    assert len(probs) == 1 and "not monotonic" in probs[0] and "channel Y" in probs[0]


def test_bad_parameters(scene):
    with pytest.raises(UsageError):
        recover_response(scene["frames"][:1], scene["times"][:1])
    with pytest.raises(UsageError):
        recover_response(scene["frames"], scene["times"], smoothness=-1)


def test_pooled_calibration_across_sets(scene):
    cam = scene["camera"]
    sets = []
    for k in range(3):
        rad = s.radiance_field(60, 80, decades=4.0, seed=10 + k)
        times = s.stops(3 + 2 * k, 2.0, centre=1.0 / float(np.median(rad)))
        sets.append((s.bracket(rad, times, cam, noise=0.5, seed=20 + k), times, None))
    resp = recover_response_pooled(sets)
    z = np.arange(10, 246)
    for c in range(3):
        d = resp.tables()[c, z] - cam.g(z, c)
        assert np.max(np.abs(d - d.mean())) < 0.03
