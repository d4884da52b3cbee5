"""The fits of :mod:`hdrcl.core.align.handheld` and which of them are trusted: the model
choice (:func:`_fit_models`; ``auto``'s homography judged on block-matched tiles,
:func:`_held_out_wins`), the refusals (:func:`_refusal`), a frame registered along the
chain of exposure neighbours (:func:`register_chained`), and a fit over few samples
accepted only when a second, independent estimate agrees (:func:`register`)."""
from __future__ import annotations

import numpy as np

import logging
import math
from typing import Optional

from hdrcl.core.align import register as R
from hdrcl.core.align import warp as W
from hdrcl.errors import InputError

logger = logging.getLogger("hdrcl.core.align.handheld")

#: A richer model must lower the residual by this much (full-size pixels) ...
CLEAR_GAIN_PX = 0.1
#: ... and by this fraction of it.
CLEAR_GAIN_FRAC = 0.2
#: A fit within this (pixels, at every corner) of a whole-pixel shift is that shift.
SNAP_PX = 0.15
#: A frame sharing fewer usable samples than this with its neighbour cannot be
#: measured: it takes the neighbour's motion (model ``inherited``), with a warning.
MIN_MEASURABLE = 200
#: A fit over fewer samples than this (of :data:`hdrcl.core.align.register.MAX_SAMPLES`) is
#: accepted only when a second, independent estimate agrees with it within
#: :data:`AGREE_PX` (full-size pixels; :func:`hdrcl.core.align.trust.register`).
FEW_SAMPLES = 20_000
AGREE_PX = 1.0
#: ``auto``'s homography is judged on tiles block-matched this far (estimation-level
#: pixels) around where the similarity puts them.
HELD_OUT_RADIUS = 8
#: ... and wins only when it brings them this much closer (full-size pixels, median):
#: real tripod film frames differ by up to a pixel in ways a homography fits better over
#: the textured part (0.15 against 0.49 px, Memorial 0067 -> 0068) while bending the
#: untextured corners by 6 px; a merge is not helped by either.
HOMOGRAPHY_GAIN_PX = 0.5
#: A frame registered against its neighbour and against the neighbour's own anchor
#: that lands this far apart (pixels, median over the frame) takes the shorter chain
#: (:func:`hdrcl.core.align.trust.register_chained`).
SKIP_PX = 0.25
#: Refusal: residual misalignment above this (full-size pixels) ...
MAX_RESIDUAL_PX = 2.0
#: ... rank images correlating less than this ...
MIN_ZNCC = 0.3
#: ... scale outside this range, rotation beyond this (degrees).
SCALE_RANGE = (0.8, 1.25)
MAX_ROTATION = 20.0
#: The fitted models (what ``auto`` chooses among).
MODEL_KINDS = ("shift", "similarity", "homography")
#: Frames the chain of registrations passes over: not measured (:data:`INHERITED`) or
#: not merged (:data:`LEFT_OUT`, :mod:`hdrcl.core.align.unaligned`).
INHERITED, LEFT_OUT = "inherited", "left out"
SKIPPED = (INHERITED, LEFT_OUT)
#: A frame sharing at least this share of the estimation level's pixels (well exposed in
#: both, at the whole-pixel start) with its neighbour has plenty to be measured by: a fit
#: that ends with few samples lost its way (a mirror image, another scene, a frame beyond
#: the start's reach), the frame is not dark. (Memorial's dark frames on their pedestal
#: share 7 %; a count such as :data:`FEW_SAMPLES` would call them plenty.)
PLENTY_FRAC = 0.25
#: ... and a fit that keeps fewer than this share of them lost its way; one that keeps
#: more is only short of samples (a small image: 1826 of 2059 on a 96x64 tripod frame).
LOST_FRAC = 0.5


class Unaligned(InputError):
    """A frame that has plenty to be registered on and yet cannot be aligned to
    ``anchor`` (its index in exposure order): ``cause`` says why. The message is the
    one-line refusal naming the frame."""

    def __init__(self, frame: str, anchor_name: str, anchor: int, cause: str):
        super().__init__(f"{frame}: cannot be aligned to {anchor_name}: {cause}")
        self.frame, self.anchor_name, self.anchor, self.cause = frame, anchor_name, anchor, cause


def _degenerate(m: np.ndarray, h: int, w: int) -> Optional[str]:
    a = m[:2, :2]
    scale = math.sqrt(abs(float(np.linalg.det(a))))
    rot = math.degrees(math.atan2(a[1, 0] - a[0, 1], a[0, 0] + a[1, 1]))
    if not np.all(np.isfinite(m)) or not SCALE_RANGE[0] <= scale <= SCALE_RANGE[1]:
        return f"degenerate transform (scale {scale:.3g})"
    if float(np.linalg.det(a)) <= 0:
        return "degenerate transform (a mirror image)"
    if abs(rot) > MAX_ROTATION:
        return f"degenerate transform (rotation {rot:.1f} degrees)"
    cs = W.corners(h, w)
    p = np.c_[cs, np.ones(4)] @ m.T
    if np.any(p[:, 2] <= 0):
        return "degenerate transform (the frame folds over the horizon)"
    q = p[:, :2] / p[:, 2:]
    e = np.roll(q, -1, axis=0) - q  # edges
    cross = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
    if not (all(c > 0 for c in cross) or all(c < 0 for c in cross)):
        return "degenerate transform (the frame's corners cross)"
    return None


def _richer(r_old: float, r_new: float) -> bool:
    """True when ``r_new`` is clearly lower than ``r_old`` (NaN never is)."""
    if not np.isfinite(r_new):
        return False
    if not np.isfinite(r_old):
        return True
    return r_old - r_new > max(CLEAR_GAIN_PX, CLEAR_GAIN_FRAC * r_old)


def _fit_models(reg, anchor: int, j: int, m0: np.ndarray, model: str, richest: str = "homography"):
    """``(model, fit, residual)`` for frame ``j`` against ``anchor`` under ``model``.

    ``auto``: the translation; the similarity when it lowers the translation's residual
    clearly (:func:`_richer`) and moves some corner more than :data:`SNAP_PX` away from
    a translation; the homography (unless ``richest`` is ``similarity``) when it lowers
    the similarity's residual clearly on tiles the fits did not use
    (:func:`_held_out_wins`).
    """
    img = reg.levels(j)
    tpl = [R.Template(lt, R.joint_ok(li, m0, lt.scale)) for lt, li in zip(reg.levels(anchor), img)]
    h, w = reg.shape

    def run(kind, init, max_iter=R.MAX_ITER):
        f = R.fit(tpl, img, init, kind, max_iter)
        return f, R.tile_residual(tpl[0], img[0], f.matrix)

    if model in ("similarity", "homography"):
        fs, rs = run("similarity", m0)
        if model == "similarity":
            return model, fs, rs
        f, r = run("homography", fs.matrix)
        return model, f, r
    ft, rt = run("shift", m0, R.MAX_ITER if model == "shift" else R.PROBE_ITER)
    if model == "shift" or (ft.converged and rt <= CLEAR_GAIN_PX):
        return "shift", ft, rt
    fs, rs = run("similarity", ft.matrix if ft.converged else m0)
    best = ("shift", ft, rt)
    bent = W.corner_distance(fs.matrix, _centre_shift(fs.matrix, h, w), h, w) > SNAP_PX
    if fs.converged and (not ft.converged or (bent and _richer(rt, rs))):
        best = ("similarity", fs, rs)
        if rs > CLEAR_GAIN_PX and richest == "homography":
            fh, rh = run("homography", fs.matrix)
            if fh.converged and _richer(rs, rh) and _held_out_wins(reg, anchor, j, fs, fh):
                best = ("homography", fh, rh)
    return best


def _held_out_wins(reg, anchor: int, j: int, fs, fh) -> bool:
    """True when the homography ``fh`` lands the frame's tiles clearly closer than the
    similarity ``fs`` (:func:`_richer`, and by :data:`HOMOGRAPHY_GAIN_PX` at least) to
    where block matching finds them
    (:func:`hdrcl.core.align.check.tile_matches`: tiles and a criterion the fits did
    not use). A homography fitted to the rank images' samples can bend the corners by
    pixels for a residual a tenth of a pixel lower (film grain, blooming that grows with
    the exposure): its own residual, even on held-out samples, cannot tell."""
    from hdrcl.core.align import check as RC

    va, vb = (reg.valid[k][0] if reg.valid[k] is not None else None for k in (anchor, j))
    p, q = RC.tile_matches(reg.levels(anchor)[0], va, reg.levels(j)[0], vb, fs.matrix, radius=HELD_OUT_RADIUS)
    es, eh = RC.model_errors([fs.matrix, fh.matrix], p, q)
    logger.debug("align: held-out tiles: similarity %.3f px, homography %.3f px", es, eh)
    return bool(np.isfinite(es) and _richer(es, eh) and es - eh >= HOMOGRAPHY_GAIN_PX)


def _centre_shift(m: np.ndarray, h: int, w: int) -> np.ndarray:
    """The translation that moves the frame centre as ``m`` does."""
    c = np.array([[(w - 1) / 2.0, (h - 1) / 2.0]])
    d = W.apply(m, c)[0] - c[0]
    return W.translation(float(d[1]), float(d[0]))


def _refusal(f, r: float, m: np.ndarray, h: int, w: int) -> Optional[str]:
    why = _degenerate(m, h, w)
    if why:
        return why
    if not f.converged:
        return "the registration did not converge"
    if f.zncc < MIN_ZNCC:
        return f"it does not match (correlation {f.zncc:.2f} of the exposure-normalised images, under {MIN_ZNCC})"
    if np.isfinite(r) and r > MAX_RESIDUAL_PX:
        return f"residual misalignment {r:.2f} px after the fit (over {MAX_RESIDUAL_PX} px)"
    return None


def motion_px(m: np.ndarray, h: int, w: int, valid: Optional[np.ndarray] = None) -> float:
    """How far ``m`` moves the frame: the median distance over a 17 x 17 grid of its
    pixels (those valid in ``valid``, when given and any are), full-size pixels. Not
    the corners: a fit extrapolates there, and a rotation of a tenth of a degree that
    moves the picture half a pixel moves an empty corner of a 24 MP frame by five."""
    ys, xs = np.meshgrid(np.linspace(0, h - 1, 17), np.linspace(0, w - 1, 17), indexing="ij")
    if valid is not None:
        keep = np.asarray(valid)[np.round(ys).astype(int), np.round(xs).astype(int)]
        if keep.any():
            ys, xs = ys[keep], xs[keep]
    p = np.c_[xs.ravel(), ys.ravel()]
    return float(np.median(np.hypot(*(W.apply(m, p) - p).T)))




def register_chained(reg, out, links, mats, j: int, ref: int, model: str, names):
    """``(anchor, model, fit, residual, why)`` of frame ``j`` (:func:`register`) against
    its nearest measured neighbour toward the reference; and (with the model that fit
    chose) against that neighbour's own nearest measured neighbour when that one is
    fewer fits from the reference. When the two agree within :data:`AGREE_PX` (median
    over the frame), the frame takes the mean of the two (:func:`_both`); when they put
    the frame further apart and the shorter chain's fit has the lower residual, the
    neighbour is the odd one and the shorter chain is taken, so that one frame's own
    misregistration does not carry into every frame beyond it (Memorial's tripod 0067
    sits 0.77 px off 0068 and 0.51 px off 0066, while 0066 sits 0.15 px off 0068)."""
    step = 1 if j < ref else -1

    def measured(k):
        while out[k][0] in SKIPPED:
            k += step
        return k

    near = measured(j + step)
    got = (near,) + register(reg, near, j, model, names)
    if near == ref or got[4] is not None:
        return got
    far = measured(near + step)
    if links[far] >= links[near]:
        return got
    try:
        alt = (far,) + register(reg, far, j, got[1] if model == "auto" and got[1] in MODEL_KINDS else model, names)
    except InputError:
        return got
    if alt[4] is not None:
        return got
    h, w = reg.shape
    apart = motion_px(np.linalg.inv(got[2].matrix @ mats[near]) @ (alt[2].matrix @ mats[far]), h, w)
    def res(x):
        return x[3] if np.isfinite(x[3]) else np.inf

    both = _both(got, alt, mats, near, far, apart)
    if both is not None:
        return both
    return alt if apart > SKIP_PX and res(alt) < res(got) else got


def _both(got, alt, mats, near: int, far: int, apart: float):
    """``got`` (against ``near``) with its matrix made the mean of the two chains'
    (through ``near`` and through ``far``) when both are affine and land within
    :data:`AGREE_PX` of each other (``apart``), else None: two trusted measurements of
    one motion whose errors are largely their own (each link's matching noise, a
    neighbour's own non-rigid difference), so their mean is closer than either
    (Memorial moved, seed 3, 1.5 degrees: 0.20 -> 0.17 stops RMS from the tripod merge;
    taking the shorter chain alone when they were over :data:`SKIP_PX` apart chained
    1.0-1.4 px of error into its five darkest frames). The mean of two affine matrices
    is affine, of two similarities a similarity."""
    from dataclasses import replace

    a, b = got[2].matrix @ mats[near], alt[2].matrix @ mats[far]
    if apart > AGREE_PX or np.any(a[2, :2]) or np.any(b[2, :2]):
        return None
    mean = 0.5 * (a + b)
    return got[:2] + (replace(got[2], matrix=mean @ np.linalg.inv(mats[near])),) + got[3:]


def shared_at_start(reg, anchor: int, j: int, m0: np.ndarray) -> int:
    """Pixels of the estimation level well exposed in ``anchor`` and, brought there by
    the whole-pixel start ``m0``, in frame ``j``: what a fit could use."""
    la, lj = reg.levels(anchor)[0], reg.levels(j)[0]
    return int(np.count_nonzero(la.ok & R.joint_ok(lj, m0, la.scale)))


def _as_whole(reg, anchor: int, j: int, kind: str, f):
    """``f`` refitted to the frame's tiles, each once, where held-out tiles confirm it
    (:func:`hdrcl.core.align.tilefit.refine`), else ``f``."""
    from dataclasses import replace

    from hdrcl.core.align import tilefit

    m = tilefit.refine(reg, anchor, j, kind, f.matrix)
    return f if m is None else replace(f, matrix=m)


def register(reg, anchor: int, j: int, model: str, names):
    """``(model, fit, residual, why)`` of frame ``j`` against ``anchor``. ``why`` (not
    None) says why a frame with few usable pixels cannot be measured (it then takes the
    anchor's motion); a frame that has plenty and still cannot be aligned is refused
    (InputError naming it).

    A fit over few samples (under :data:`FEW_SAMPLES`), or one whose residual cannot be
    measured (no textured tile: NaN), is accepted only when the block-matching estimate
    of :mod:`hdrcl.core.align.check` agrees with it within :data:`AGREE_PX` where the
    frame has content; the fit is retried from that estimate once. Its residual is then
    the larger of the tiles' and the two estimates' distance: never NaN."""
    from hdrcl.core.align import check as RC

    h, w = reg.shape
    m0 = reg.shift(anchor, j)
    kind, f, r = _fit_models(reg, anchor, j, m0, model)
    if f.samples >= FEW_SAMPLES and np.isfinite(r):
        why = _refusal(f, r, f.matrix, h, w)
        if why:
            raise Unaligned(names[j], names[anchor], anchor, why)
        return kind, _as_whole(reg, anchor, j, kind, f), r, None
    va, vb = (reg.valid[k][0] if reg.valid[k] is not None else None for k in (anchor, j))
    est = RC.tile_estimate(reg.levels(anchor)[0], va, reg.levels(j)[0], vb, m0)
    tried = []
    if est is not None:
        # The fit as made, again from the second estimate, and (auto) a similarity from
        # either start and a translation from the second estimate (a few samples cannot
        # tell one from the other): the one closest to the second estimate, if it agrees
        # (the first that agrees chains up to 1.4 px of error over seven dark frames).
        start = est.full()[0]
        retries = [lambda: _fit_models(reg, anchor, j, start, model, richest="similarity")]
        if model == "auto":
            retries = [lambda: _fit_models(reg, anchor, j, m0, "similarity")] + retries + [
                lambda: _fit_models(reg, anchor, j, start, "similarity"),
                lambda: _fit_models(reg, anchor, j, start, "shift")]
        best = (kind, f, r)
        for retry in [None] + retries:
            kind_c, f_c, r_c = (kind, f, r) if retry is None else retry()
            if _degenerate(f_c.matrix, h, w) is not None:
                continue
            d = RC.disagreement(f_c.matrix, est)
            tried.append(d)
            if d == min(tried):
                best = (kind_c, f_c, r_c)
        kind, f, r = best
    gap = min(tried, default=float("inf"))
    if gap <= AGREE_PX:  # two estimates agree: converged or not
        return kind, _as_whole(reg, anchor, j, kind, f), max(gap, r) if np.isfinite(r) else gap, None
    if f.samples >= FEW_SAMPLES:  # plenty to go on, and yet no estimate to confirm it
        why = _refusal(f, r, f.matrix, h, w) or (
            "its residual cannot be measured (no textured tile) and no second estimate confirms the fit"
            if est is None else f"a second estimate (block matching) puts it {gap:.1f} px away")
        raise Unaligned(names[j], names[anchor], anchor, why)
    shared = shared_at_start(reg, anchor, j, m0)
    if shared >= PLENTY_FRAC * reg.levels(anchor)[0].ok.size and f.samples < LOST_FRAC * shared:
        # Not a dark frame: it shares plenty where it started, and the fit lost it. (A fit
        # that kept them is only short of samples on a small image: a still tripod frame.)
        why = _refusal(f, r, f.matrix, h, w) or (
            f"the fit keeps {f.samples} of the {shared} well-exposed pixels it shares with it at the start, and "
            + ("no second estimate confirms it" if est is None else
               f"a second estimate (block matching) puts it {gap:.1f} px away"))
        raise Unaligned(names[j], names[anchor], anchor, why)
    if est is None:
        return kind, f, r, (f"too few well-exposed pixels shared with {names[anchor]} ({f.samples} samples) "
                            "to align it, and no second estimate to confirm a fit")
    return kind, f, r, (f"too few well-exposed pixels shared with {names[anchor]} ({f.samples} samples) to "
                        f"trust a fit: a second estimate (block matching) puts it {gap:.1f} px away")
