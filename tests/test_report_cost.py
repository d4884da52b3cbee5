"""The quality report at the price of a preview (issue 26 item 4): measured on the report's
grid, the same figures by the fast paths as by the plain ones, the grid and its precision
stated, and the batch's kept frames no bigger than that grid."""
import numpy as np
import pytest

import hdrcl.report.leaveoneout as leaveoneout
import hdrcl.report.quality as quality
from hdrcl.core.bracket import Bracket, load_bracket
from hdrcl.core.merge import merge_bracket
from hdrcl.report.leaveoneout import leave_one_out_all
from hdrcl.report.quality import QualityFigures, measure, report_stride


@pytest.fixture(scope="module")
def merged(scene):
    br = load_bracket(scene["frames"], scene["times"])
    return br, merge_bracket(br)


def test_report_stride():
    assert report_stride(512, 768) == 1  # memorial: every pixel
    assert report_stride(2000, 3000) == 4  # 6 MP: 375 000 pixels measured
    assert report_stride(4000, 6000) == 7
    for h, w in [(2000, 3000), (3456, 5184), (1001, 1999)]:
        k = report_stride(h, w)
        assert len(range(0, h, k)) * len(range(0, w, k)) <= quality.LOO_MAX_PIXELS
        assert k == 1 or len(range(0, h, k - 1)) * len(range(0, w, k - 1)) > quality.LOO_MAX_PIXELS / 1.01


@pytest.mark.parametrize("bits", [8, 16])
def test_rmse_levels_is_the_plain_formula(bits):
    rng = np.random.default_rng(bits)
    top = 255 if bits == 8 else 65535
    dt = np.uint8 if bits == 8 else np.uint16
    real = rng.integers(0, top + 1, (40, 50, 3)).astype(dt)
    rendered = np.clip(real.astype(np.int64) + rng.integers(-9 * (top // 255), 9 * (top // 255) + 1, real.shape),
                       0, top).astype(dt)
    valid = rng.random((40, 50)) > 0.2
    scale = 1.0 if bits == 8 else 257.0
    r, v = real / scale, rendered / scale
    mask = (r >= 10) & (r <= 245) & valid[..., None]
    d = (v - r)[mask]
    want = float(np.sqrt(np.mean(d * d)))
    got, n = leaveoneout._rmse_levels(real, rendered, valid, 10, 245)
    assert n == d.size and got == pytest.approx(want, rel=1e-12)
    assert leaveoneout._rmse_levels(np.zeros_like(real), rendered, None, 10, 245) == (pytest.approx(float("nan"),
                                                                                               nan_ok=True), 0)


def test_leave_one_out_same_on_threads(merged, monkeypatch):
    """The curves solved on several threads give the figures of one thread."""
    br, res = merged
    sub = Bracket(frames=[f[::2, ::2] for f in br.frames], times=res.times, valid=[None] * len(br.frames))
    kw = dict(weight=res.response.weight, smoothness=res.response.smoothness, fit_exposures="off")
    monkeypatch.setattr(leaveoneout, "LOO_THREADS", 1)
    one = leave_one_out_all(sub, **kw)
    monkeypatch.setattr(leaveoneout, "LOO_THREADS", 3)
    many = leave_one_out_all(sub, **kw)
    assert [(r.index, r.rmse, r.pixels) for r in one] == [(r.index, r.rmse, r.pixels) for r in many]
    assert len(one) == len(br.frames) - 2


def test_evidence_by_comparison_equals_the_gather(merged, monkeypatch):
    """Counting evidence by a run of codes gives the figures of the table lookup."""
    br, res = merged
    fast = measure(br, res.response, res.radiance, loo=False)
    from hdrcl.report import clipping

    monkeypatch.setattr(clipping, "_code_interval", lambda table: None)
    slow = measure(br, res.response, res.radiance, loo=False)
    assert np.array_equal(fast.coverage, slow.coverage)
    assert fast.to_dict() == slow.to_dict()


def test_measured_on_a_grid_says_so(merged):
    """A bracket that is every 3rd row and column: the strides are recorded in the frames
    merged, and the sheet states the grid and the precision of the fractions."""
    from hdrcl.report.sheet import format_figures, fraction_precision

    br, res = merged
    grid = Bracket(frames=[f[::3, ::3] for f in br.frames], times=br.times, valid=[None] * len(br.frames),
                   grid=True)
    fig = measure(grid, res.response, res.radiance, stride=3, loo_max_pixels=10 ** 6)
    assert fig.grid_stride == 3 and fig.loo_stride == 3
    back = QualityFigures.from_dict(fig.to_dict())
    assert back.grid_stride == 3 and back.loo_stride == 3
    rows = dict(format_figures(fig))
    assert "every 3rd row and column" in rows["Leave-one-out RMSE"]
    assert "±" in rows["Clipped high"] and "every 3rd row and column" in rows["Clipped high"]
    whole = dict(format_figures(measure(br, res.response, res.radiance, loo=False)))
    assert "±" not in whole["Clipped high"]
    # 95 % binomial half-width; a fraction of 0 reads as below about 2 / n.
    assert fraction_precision(0.25, 10_000) == pytest.approx(2 * np.sqrt(0.25 * 0.75 / 10_000))
    assert fraction_precision(0.0, 10_000) == pytest.approx(2 * np.sqrt(1e-4 * (1 - 1e-4) / 10_000))


def test_grid_figures_close_to_whole_frames(merged):
    """The grid's figures estimate the whole frames' (the scene is smooth, so closely)."""
    br, res = merged
    whole = measure(br, res.response, res.radiance, loo_max_pixels=10 ** 7)
    k = 2
    grid = Bracket(frames=[f[::k, ::k] for f in br.frames], times=br.times, valid=[None] * len(br.frames),
                   grid=True)
    part = measure(grid, res.response, res.radiance, stride=k, loo_max_pixels=10 ** 7)
    assert part.loo_rmse == pytest.approx(whole.loo_rmse, abs=0.05)
    for key in ("clipped_high_fraction", "clipped_low_fraction"):
        assert abs(getattr(part, key) - getattr(whole, key)) <= 2 * max(
            1.0 / part.valid_pixels, np.sqrt(getattr(whole, key) / part.valid_pixels))


def test_batch_keeps_only_the_report_grid():
    """The batch's tap keeps every k-th row and column (k = report_stride), never whole
    frames, and the stride is found again from the kept grid."""
    from hdrcl.shoot.batch.setquality import _KeptFrames, _quality_stride, _stride_of

    h, w = 1100, 1700  # 1.87 MP -> every 2nd row and column
    k = _quality_stride(5, h, w, 3, np.uint8)
    assert k == report_stride(h, w) == 2

    class Reader:
        height, width, nch, dtype = h, w, 3, np.dtype(np.uint8)
        paths = ["a", "b"]

        def strips(self, rows):
            rng = np.random.default_rng(0)
            self.full = [rng.integers(0, 256, (h, w, 3)).astype(np.uint8) for _ in self.paths]
            for y0 in range(0, h, rows):
                y1 = min(h, y0 + rows)
                yield y0, y1, [f[y0:y1] for f in self.full], [None, None]

    class Info:
        height, width = h, w

    reader = Reader()
    kept = _KeptFrames(reader, k)
    for _ in kept.strips(37):  # strips that do not start on the grid
        pass
    for got, full in zip(kept.kept, reader.full):
        assert np.array_equal(got, full[::k, ::k])
    br = kept.bracket(["a", "b"], [Info(), Info()], [1.0, 4.0], None)
    assert br.grid and _stride_of(br) == k


def test_grid_figures_keep_the_frames_shape(merged):
    """Measured on a grid, the figures still name the frames merged (not the grid), and a
    grid with every pixel valid shows no 'no data' in the legend."""
    from hdrcl.report.pages import ReportEntry
    from hdrcl.report.sheet import format_figures

    br, res = merged
    h, w, c = br.frames[0].shape
    grid = Bracket(frames=[f[::3, ::3] for f in br.frames], times=br.times, valid=[None] * len(br.frames),
                   grid=True)
    fig = measure(grid, res.response, res.radiance, stride=3, shape=(h, w, c), loo=False)
    assert fig.shape == (h, w, c)
    assert f"× {w}×{h}," in dict(format_figures(fig))["Frames"]
    assert fig.valid_pixels == len(range(0, h, 3)) * len(range(0, w, 3))
    entry = ReportEntry("s", "done", figures=fig, files={"coverage": "s-coverage.png"})
    from hdrcl.report.sheet import _card

    assert "no data" not in _card(entry, 0)


def test_leave_one_out_curves_from_the_shared_grid(scene):
    """The curves solved from one contiguous sampling grid shared by every leave-out give
    the figures of each solve decimating the frames itself (frames big enough for a grid)."""
    br = load_bracket(scene["frames"], scene["times"])
    big = Bracket(frames=[np.ascontiguousarray(np.tile(f, (4, 6, 1))) for f in br.frames], times=br.times,
                  valid=[None] * len(br.frames))  # 480 x 960: sampling grid stride 2
    from hdrcl.core.sampling import grid_stride

    assert grid_stride(*big.frames[0].shape[:2]) == 2
    kw = dict(weight="gaussian", fit_exposures="off")
    shared = leave_one_out_all(big, **kw)
    own = leave_one_out_all(big, grid=None, **kw)
    assert [(r.index, r.rmse, r.pixels) for r in shared] == [(r.index, r.rmse, r.pixels) for r in own]
