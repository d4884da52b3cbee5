"""Issue 33: the calibration's fixed costs cut without changing a sample, a curve or an
exposure. The oracles are the plain formulations the fast paths replace (a stable sort of
everything, ``np.quantile`` per stratum), on generated brackets."""
import numpy as np
import pytest

from hdrcl.core import sampling
from hdrcl.core import synthetic as s


def _brackets():
    """Generated brackets: odd sizes, 8 and 16 bits, grey and RGB, ties (posterised codes),
    masks, decimated or not."""
    rng = np.random.default_rng(5)
    out = []
    for t, (h, w) in enumerate(((31, 47), (120, 160), (257, 91), (64, 600))):
        cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8), bits=16 if t == 2 else 8)
        rad = s.radiance_field(h, w, decades=4.0, seed=t)
        times = s.stops(3 + t, 1.0, centre=1.0 / float(np.median(rad)))
        frames = s.bracket(rad, times, cam, noise=0.5, seed=10 + t)
        if t == 1:
            frames = [(f // 9 * 9).astype(f.dtype) for f in frames]  # many equal keys and variances
        if t == 3:
            frames = [f[:, :, :1] for f in frames]
        valid = rng.random((h, w)) > 0.1 if t % 2 else None
        out.append((frames, valid, t != 1))
    return out


def _old_quarter_quantiles(bins, values, nbins):
    return np.array([np.quantile(values[bins == b], 0.25) if (bins == b).any() else np.nan
                     for b in range(nbins)])


def test_quarter_quantiles_are_numpys():
    rng = np.random.default_rng(1)
    for n, nb in ((1, 1), (7, 3), (500, 64), (20_000, 64)):
        bins = rng.integers(0, nb, n)
        values = np.round(rng.random(n) * 5) / 5  # ties
        order = np.argsort(bins, kind="stable")
        starts = np.searchsorted(bins[order], np.arange(nb + 1))
        got = sampling._quarter_quantiles(order, values, starts)
        np.testing.assert_array_equal(got, _old_quarter_quantiles(bins, values, nb))


def test_smallest_first_is_a_stable_sorts_head():
    rng = np.random.default_rng(2)
    for _ in range(300):
        v = rng.integers(0, 6, int(rng.integers(1, 60))).astype(float)
        k = int(rng.integers(0, 70))
        want = np.sort(np.argsort(v, kind="stable")[:k])
        np.testing.assert_array_equal(sampling._smallest_first(v, k), want)


@pytest.mark.parametrize("case", range(4))
def test_candidates_draw_the_samples_select_samples_draws(case):
    frames, valid, decimate = _brackets()[case]
    pool = sampling.sample_candidates(frames, valid, decimate=decimate)
    for n in (1, 40, 64, 400, 1000, 10**6):
        for seed in (0, 7):
            plain = sampling.select_samples(frames, valid, n, seed=seed, decimate=decimate)
            shared = sampling.select_samples(frames, valid, n, seed=seed, decimate=decimate, candidates=pool)
            np.testing.assert_array_equal(shared, plain)
            assert plain.size == min(n, pool.cand.size) and np.all(np.diff(plain) > 0)
    # Candidates of other frames are not used by mistake.
    other = [f[:-1] for f in frames]
    np.testing.assert_array_equal(sampling.select_samples(other, None, 100, candidates=pool),
                                  sampling.select_samples(other, None, 100))


def test_a_calibration_makes_its_candidates_once(monkeypatch, scene):
    import hdrcl
    from hdrcl.core.bracket import Bracket

    made = []
    real = sampling.SampleCandidates.__init__

    def counting(self, *a, **k):
        made.append(1)
        real(self, *a, **k)

    br = Bracket(frames=list(scene["frames"]), times=np.asarray(scene["times"]),
                 valid=[None] * len(scene["frames"]))
    want = hdrcl.calibrate(br, warn=False)
    monkeypatch.setattr(sampling.SampleCandidates, "__init__", counting)
    got = hdrcl.calibrate(br, warn=False)
    assert len(made) == 1  # the exposure check's draw and the curve's share them
    np.testing.assert_array_equal(got.g, want.g)


def test_exposure_fit_does_not_depend_on_the_blas_pool(scene):
    """The fit's dense product runs on one BLAS thread: the same bits whatever the pool
    (before, OpenBLAS's pool of two split it differently from one thread)."""
    from threadpoolctl import threadpool_limits

    from hdrcl.core.exposure.fit import fit_exposures

    wrong = np.array(scene["times"], np.float64)
    wrong[3] *= 1.8
    fits = []
    for threads in (1, 2):
        with threadpool_limits(threads, user_api="blas"):
            fits.append(fit_exposures(scene["frames"], wrong))
    np.testing.assert_array_equal(fits[0].fitted, fits[1].fitted)
    assert fits[0].flagged[3]


def test_known_curve_measurement_is_the_plain_one(scene):
    """Exposures measured through a known curve: the shared pixel-channels taken once per
    pair and the draw of pixels made once per frame size give the plain computation's
    figures (medians of boolean-masked differences)."""
    from hdrcl.core.exposure import known
    from hdrcl.core.response import Response

    frames = list(scene["frames"])
    lt = np.log(np.asarray(scene["times"], np.float64))
    g = np.log(np.linspace(1e-3, 1.0, 256))
    resp = Response(bits=8, g=np.stack([g - g[128]] * 3), knots=np.arange(256.0), channels=("R", "G", "B"))
    xs, ws, oks, pixels = known._usable_samples(frames, resp, "gaussian", None)
    got = known._measure(xs, ws, oks, pixels, lt)
    plain = []
    for j in range(len(xs)):
        for k in range(j + 1, len(xs)):
            ok = oks[j] & oks[k]
            if int(ok.sum()) >= known.MIN_OVERLAP:
                d = xs[k][ok] - xs[j][ok]
                m = float(np.median(d))
                plain.append((j, k, m, max(1.4826 * float(np.median(np.abs(d - m))), known._SPREAD_FLOOR)))
    assert len(plain) >= len(xs) - 1
    measured = np.zeros(len(xs), bool)
    comps = known._components(len(xs), [(j, k) for j, k, _, _ in plain])
    main = max(comps, key=lambda c: (len(c), int(pixels[c].sum())))
    measured[main] = True
    np.testing.assert_array_equal(got[0], measured)
    # Every pair's location is the plain median, bit for bit.
    for j, k, m, s_ in plain:
        ok = oks[j] & oks[k]
        loc, _ = known._location(xs[k][ok] - xs[j][ok], ws[j][ok] * ws[k][ok])
        assert loc == m
    # A frame larger than the draw: the same draw every time, made once, not writeable.
    a, b = known._subsample(known.MAX_PIXELS + 12345), known._subsample(known.MAX_PIXELS + 12345)
    assert a is b and not a.flags.writeable and a.size == known.MAX_PIXELS
    np.testing.assert_array_equal(a, np.sort(np.random.default_rng(0).choice(known.MAX_PIXELS + 12345,
                                                                              known.MAX_PIXELS, replace=False)))
