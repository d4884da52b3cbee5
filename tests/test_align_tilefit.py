"""Issue 32, alignment: the frame as a whole (:mod:`hdrcl.core.align.tilefit`).

Generated pairs with known truth: a frame whose small, high-contrast part moved 1.5 px
more than the rest (as film frames scanned one by one differ: Memorial 0067 against
0068 on a tripod, -1.1 to +1.2 px across the frame) is registered where the frame as a
whole sits, not where its strongest edges do.
"""
import numpy as np
import pytest
from scipy import ndimage

from hdrcl.core.align import tilefit as T
from hdrcl.core.align.warp import apply


def _pair(h=240, w=320, seed=3, d=(3.4, -2.3), bump=1.5):
    """``(frames, truth, box)``: a smooth low-contrast texture with a high-contrast
    checkerboard in one corner (``box``, 18 % of the frame), and the same scene
    shifted by ``d`` with the checkerboard ``bump`` px further in x; frames in
    exposure order (the moved one first), truth the shift (reference -> frame)."""
    rng = np.random.default_rng(seed)
    s = 0.35 + 3.0 * ndimage.gaussian_filter(rng.normal(size=(h, w)), 3)
    yy, xx = np.mgrid[0:h, 0:w]
    box = (yy > h * 0.55) & (xx > w * 0.6)
    s = np.where(box, 0.1 + 0.8 * ((yy // 6 + xx // 6) % 2), s)
    s = np.clip(ndimage.gaussian_filter(s, 1.0), 0.02, 0.98)
    inbox = ndimage.gaussian_filter(box.astype(float), 4)
    b = ndimage.map_coordinates(s, [yy - d[1], xx - d[0] - bump * inbox], order=3, mode="nearest")

    def q(a):
        return np.repeat((np.clip(a, 0, 1) * 255).round().astype(np.uint8)[..., None], 3, axis=2)

    return [q(b), q(s)], np.array([[1, 0, d[0]], [0, 1, d[1]], [0, 0, 1.0]]), box


def _median_error(m, truth, h, w):
    ys, xs = np.mgrid[0:h:8, 0:w:8]
    p = np.c_[xs.ravel(), ys.ravel()].astype(float)
    return float(np.median(np.hypot(*(apply(m, p) - apply(truth, p)).T)))


def test_a_part_that_moved_more_does_not_decide_the_motion(cl_device):
    """The strongest edges (the checkerboard) moved 1.5 px more than the frame: the
    Gauss-Newton fit alone lands 0.71 px (median over the frame) from the rest; refitted
    to the tiles, each once, within 0.45 (the checkerboard's own tiles pull it 0.27)."""
    from hdrcl.core.align.handheld import estimate

    frames, truth, box = _pair()
    out, _ = estimate(frames, 1, "auto")
    assert _median_error(out[0][1], truth, *box.shape) < 0.45


def test_held_out_tiles_refuse_a_refit_to_noise():
    """A few tiles matched with 0.5 px of noise around a right fit: the refit follows
    the noise and the held-out halves say so; tiles that all sit 0.6 px off the fit
    take the refit."""
    rng = np.random.default_rng(1)
    ys, xs = np.mgrid[0:4, 0:4]
    p = np.c_[xs.ravel(), ys.ravel()].astype(float) * 48 + 24
    right = np.eye(3)
    noisy = p + rng.normal(0, 0.5, p.shape)
    assert not T.held_out("similarity", right, p, noisy, 48.0)[0]
    assert T.held_out("similarity", right, p, p + [0.6, 0.0], 48.0)[0]
    m = T.fit_model("similarity", p, p + [0.6, 0.0])
    assert np.allclose(m, [[1, 0, 0.6], [0, 1, 0], [0, 0, 1]], atol=1e-9)


def test_too_few_tiles_keep_the_fit():
    """Fewer than :data:`hdrcl.core.align.tilefit.MIN_TILES` in a half: no refit."""
    p = np.array([[24.0, 24.0], [72.0, 24.0], [24.0, 72.0]])
    assert not T.held_out("shift", np.eye(3), p, p + 0.5, 48.0)[0]


# ------------------------------------------------- two chains: their mean


def _chain(monkeypatch, near_err, far_err, res=(0.2, 0.2)):
    """Frame 0 of three (reference 2, frame 1 already at its true motion) registered
    through frame 1 and directly, each fit off by its own ``(dx, dy)``; the absolute
    matrix register_chained gives it."""
    from types import SimpleNamespace

    from hdrcl.core.align import register as R
    from hdrcl.core.align import trust

    truth = np.array([[1.0, 0.0, 5.0], [0.0, 1.0, -3.0], [0.0, 0.0, 1.0]])
    mats = [np.eye(3), np.array([[1.0, 0.0, 2.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]]), np.eye(3)]

    def off(e):
        return np.array([[1.0, 0.0, e[0]], [0.0, 1.0, e[1]], [0.0, 0.0, 1.0]])

    def fake(reg, anchor, j, model, names):
        e, r = (near_err, res[0]) if anchor == 1 else (far_err, res[1])
        link = off(e) @ truth @ np.linalg.inv(mats[anchor])
        return "shift", R.Fit(link, True, 0.9, 30_000), r, None

    monkeypatch.setattr(trust, "register", fake)
    out = [("shift", np.eye(3), 0.0, 1), ("shift", mats[1], 0.1, 2), ("reference", np.eye(3), 0.0, 2)]
    anchor, kind, f, r, why = trust.register_chained(SimpleNamespace(shape=(100, 150)), out, [0, 1, 0], mats, 0, 2,
                                                     "auto", ["a", "b", "c"])
    return f.matrix @ mats[anchor], truth


def test_two_chains_that_agree_give_their_mean(monkeypatch):
    """Through the neighbour 0.4 px off, directly 0.2 px off the other way (each its own
    error): the frame takes the mean, 0.1 px off; before, the neighbour's 0.4."""
    m, truth = _chain(monkeypatch, (0.4, 0.0), (-0.2, 0.0))
    assert np.allclose(m, np.array([[1, 0, 0.1], [0, 1, 0], [0, 0, 1]]) @ truth, atol=1e-9)
    # the shorter chain's lower residual does not make it the whole answer (it was)
    m, truth = _chain(monkeypatch, (0.4, 0.0), (-0.2, 0.0), res=(0.2, 0.1))
    assert np.allclose(m, np.array([[1, 0, 0.1], [0, 1, 0], [0, 0, 1]]) @ truth, atol=1e-9)


def test_two_chains_that_disagree_keep_the_rules(monkeypatch):
    """1.5 px apart (over :data:`hdrcl.core.align.trust.AGREE_PX`): no mean; the
    shorter chain with the lower residual is taken, else the neighbour's."""
    m, truth = _chain(monkeypatch, (1.5, 0.0), (0.0, 0.0), res=(0.2, 0.1))
    assert np.allclose(m, truth, atol=1e-9)
    m, truth = _chain(monkeypatch, (1.5, 0.0), (0.0, 0.0), res=(0.1, 0.2))
    assert np.allclose(m, np.array([[1, 0, 1.5], [0, 1, 0], [0, 0, 1]]) @ truth, atol=1e-9)
