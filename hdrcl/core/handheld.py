"""Hand-held brackets: each frame registered to the middle exposure by a translation,
a similarity or a homography, then warped onto it (``merge --align``).

Stages, per frame:

1. **Whole-pixel shift** by median threshold bitmaps (:mod:`hdrcl.core.align`, Ward
   2003): the start, reaching 63 pixels or more.
2. **Sub-pixel fit** of the model(s) (:mod:`hdrcl.core.register`) on the frames' rank
   images, coarse to fine on a pyramid of at most a few megapixels. Each frame is
   registered to its neighbour in exposure on the way to the reference (they share the
   most well-exposed pixels), already registered, and the matrices are composed.
3. **Model choice** (``auto``): the translation, unless the similarity lowers the
   residual misalignment by more than :data:`CLEAR_GAIN_PX` and :data:`CLEAR_GAIN_FRAC`
   of it; then the homography, only when it also lands the frame's tiles, block-matched
   independently of the fit (:mod:`hdrcl.core.register_check`), clearly closer than the
   similarity (:data:`HOMOGRAPHY_GAIN_PX`). A result within :data:`SNAP_PX` of a
   whole-pixel shift at every corner is taken as that shift (an exact copy, no
   resampling). A bracket in which no frame moved :data:`STATIC_PX` or more
   (:func:`motion_px`: the median over the frame) is left as it is (model ``none``: a
   tripod).
4. **Trust** (:func:`_register`). A fit over fewer than :data:`FEW_SAMPLES` samples (a
   dark frame: its pedestal is left out, :func:`hdrcl.core.register.usable_range`), or
   one whose residual cannot be measured (NaN: no textured tile), is accepted only when
   a second, independent estimate, block matching of tiles on the two frames' shared
   bright structure, agrees with it within :data:`AGREE_PX` where the frame has content
   (the fit is retried from that estimate first); else the frame takes its neighbour's
   motion (model ``inherited``, with a warning naming it), and the next frames chain to
   the last frame measured. A frame with plenty of samples that cannot be aligned (no
   convergence, a degenerate transform, rank images that do not correlate, a residual
   above :data:`MAX_RESIDUAL_PX`, or an unmeasurable residual no second estimate
   confirms) is refused: :class:`hdrcl.errors.InputError` naming the frame. Frames under
   :data:`MIN_SIDE` pixels on a side are merged as they are, with a warning.
5. **Warp** (:mod:`hdrcl.core.warp`; on the device :class:`hdrcl.cl.warp.WarpProcessor`,
   each frame as soon as its matrix is final, on a worker thread while the host
   estimates the next), masks warped with the frames; ``crop`` keeps the largest
   axis-aligned box every frame covers.
"""
from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence

import numpy as np

from hdrcl.core import register as R
from hdrcl.core import warp as W
from hdrcl.core.handheld_warp import _warper, _Warps, apply_alignment, warp_one  # noqa: F401 (the API here)
from hdrcl.errors import InputError, UsageError

logger = logging.getLogger(__name__)

MODELS = ("auto", "shift", "similarity", "homography")
#: A richer model must lower the residual by this much (full-size pixels) ...
CLEAR_GAIN_PX = 0.1
#: ... and by this fraction of it.
CLEAR_GAIN_FRAC = 0.2
#: A fit within this (pixels, at every corner) of a whole-pixel shift is that shift.
SNAP_PX = 0.15
#: A frame sharing fewer usable samples than this with its neighbour cannot be
#: measured: it takes the neighbour's motion (model ``inherited``), with a warning.
MIN_MEASURABLE = 200
#: A fit over fewer samples than this (of :data:`hdrcl.core.register.MAX_SAMPLES`) is
#: accepted only when a second, independent estimate agrees with it within
#: :data:`AGREE_PX` (full-size pixels; :func:`_register`).
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
#: ``auto``: a bracket whose every frame moved less than this (pixels, median over the
#: frame: :func:`motion_px`) is static (a tripod): no frame is resampled. Registration
#: between frames several stops apart is biased by up to about half a pixel on real
#: tripod JPEGs (window_e995: 0.46-0.55 px across its 12 frames, along the 4:2:2
#: chroma's subsampled axis), the Memorial film frames differ by up to 0.77 px (0067 ->
#: 0068, a fit to non-rigid scan differences), and a resampling blurs more than a
#: sub-pixel misregistration costs the fusion.
STATIC_PX = 1.0
#: Frames with a side under this many pixels are not aligned (merged as they are).
MIN_SIDE = 16
#: Refusal: residual misalignment above this (full-size pixels) ...
MAX_RESIDUAL_PX = 2.0
#: ... rank images correlating less than this ...
MIN_ZNCC = 0.3
#: ... scale outside this range, rotation beyond this (degrees).
SCALE_RANGE = (0.8, 1.25)
MAX_ROTATION = 20.0


def check_model(model) -> str:
    """``model`` lower-cased if it is one of :data:`MODELS`, else :class:`UsageError`."""
    m = str(model).strip().lower() if model is not None else "auto"
    if m not in MODELS:
        raise UsageError(f"align model '{model}' is not one of {', '.join(MODELS)}")
    return m


@dataclass
class Aligned:
    """What :func:`align_bracket` made: frames and masks as merged, the whole-pixel
    shifts (``(dy, dx)`` of each frame's centre), the crop box (or None) and one
    :func:`describe` dict per frame."""

    frames: List[np.ndarray]
    valid: List[Optional[np.ndarray]]
    shifts: List[tuple]
    crop: Optional[tuple]
    alignment: List[dict]


def describe(name: str, model: str, m: np.ndarray, residual: float, h: int, w: int, anchor: str) -> dict:
    """The per-frame record: file, model, matrix (reference -> frame pixel coordinates),
    rotation (degrees), scale, ``shift_px`` ``[dy, dx]`` of the frame centre,
    ``residual_px`` and the frame it was registered against."""
    a = m[:2, :2]
    c = np.array([[(w - 1) / 2.0, (h - 1) / 2.0]])
    d = W.apply(m, c)[0] - c[0]
    return {"file": name, "model": model, "matrix": [[float(v) for v in row] for row in m],  # full precision: re-warps
            "rotation_deg": round(math.degrees(math.atan2(a[1, 0] - a[0, 1], a[0, 0] + a[1, 1])), 5),
            "scale": round(math.sqrt(abs(float(np.linalg.det(a)))), 7),
            "shift_px": [round(float(d[1]), 4), round(float(d[0]), 4)],
            "residual_px": None if residual is None or not np.isfinite(residual) else round(float(residual), 4),
            "against": anchor}


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


class _Registrar:
    """Grey pyramids (levels ``est`` .. coarsest), usable ranges and rank pyramids of
    the bracket's frames, the last built on first use."""

    def __init__(self, pyramids, valid, est: int, start: int, lo: int, hi: int, tol: int, shape):
        self.pyr, self.est, self.start, self.tol = pyramids, est, start, tol
        self.shape = shape
        self.valid = [_usable_pyramid(v, p, est) for v, p in zip(valid, pyramids)]
        self.range = [R.usable_range(p[0], lo, hi, None if v is None else v[0], margin=lo)
                      for p, v in zip(pyramids, self.valid)]
        self._levels: Dict[int, list] = {}

    def levels(self, j: int):
        if j not in self._levels:
            k = self.start - self.est + 1
            vp = self.valid[j][:k] if self.valid[j] is not None else None
            self._levels[j] = R.levels_of(self.pyr[j][:k], self.est, *self.range[j], vp)
        return self._levels[j]

    def shift(self, a: int, b: int) -> np.ndarray:
        """Whole-pixel shift of ``b`` against ``a`` by median threshold bitmaps on the
        kept levels (each frame's usable range in place of the fixed one), full size."""
        from hdrcl.core import align as A
        from hdrcl.cl.pyramid import GreyPyramid

        pa, pb = self.pyr[a], self.pyr[b]
        shapes = [g.shape for g in pa]
        q = A.shared_percentile(A.usable_interval(pa[0], *self.range[a]), A.usable_interval(pb[0], *self.range[b]))
        twin = A.NumpyAligner()
        bm = [twin.bitmaps(GreyPyramid("x", shapes, p), [A.level_threshold(g, q) for g in p], self.tol)
              for p in (pa, pb)]
        (dy, dx), _ = A.search_shift(twin, bm[0], bm[1], len(pa), A.coarse_radius(len(pa)))
        return W.translation(dy * (1 << self.est), dx * (1 << self.est))


def _usable_pyramid(valid, pyr, est: int):
    """Per kept level: valid (the frame's mask brought to the level) and not fill
    (:func:`hdrcl.core.register.fill_mask` of the estimation level); None when all is."""
    v = None if valid is None else R.valid_pyramid(valid, len(pyr) + est)[est]
    fill = R.fill_mask(pyr[0])
    if fill.any():
        v = ~fill if v is None else v & ~fill
    return None if v is None else R.valid_pyramid(v, len(pyr))


def _richer(r_old: float, r_new: float) -> bool:
    """True when ``r_new`` is clearly lower than ``r_old`` (NaN never is)."""
    if not np.isfinite(r_new):
        return False
    if not np.isfinite(r_old):
        return True
    return r_old - r_new > max(CLEAR_GAIN_PX, CLEAR_GAIN_FRAC * r_old)


def _fit_models(reg: _Registrar, anchor: int, j: int, m0: np.ndarray, model: str, richest: str = "homography"):
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


def _held_out_wins(reg: _Registrar, anchor: int, j: int, fs, fh) -> bool:
    """True when the homography ``fh`` lands the frame's tiles clearly closer than the
    similarity ``fs`` (:func:`_richer`, and by :data:`HOMOGRAPHY_GAIN_PX` at least) to
    where block matching finds them
    (:func:`hdrcl.core.register_check.tile_matches`: tiles and a criterion the fits did
    not use). A homography fitted to the rank images' samples can bend the corners by
    pixels for a residual a tenth of a pixel lower (film grain, blooming that grows with
    the exposure): its own residual, even on held-out samples, cannot tell."""
    from hdrcl.core import register_check as RC

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


def _snap(m: np.ndarray, h: int, w: int) -> Optional[np.ndarray]:
    """The whole-pixel shift within :data:`SNAP_PX` of ``m`` at every corner, or None."""
    c = np.array([[(w - 1) / 2.0, (h - 1) / 2.0]])
    d = W.apply(m, c)[0] - c[0]
    t = W.translation(round(float(d[1])), round(float(d[0])))
    return t if W.corner_distance(m, t, h, w) <= SNAP_PX else None


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


def estimate(frames: Sequence[np.ndarray], ref: int, model: str, device=None, names=None, valid=None,
             on_final=None):
    """Matrices (reference -> frame), chosen models, residuals and anchors per frame
    (``frames`` ordered by exposure). Raises InputError for a frame that cannot be aligned.

    ``on_final(j, matrix)``, when given, is called for each frame (but the reference) as
    soon as its matrix is final: once the bracket is known not to be static (a frame
    moved more than :data:`STATIC_PX`, or ``model`` is not ``auto``), so that its warp
    can start while the next frames are estimated."""
    from hdrcl.core import align as A

    n = len(frames)
    names = names or [f"frame {j}" for j in range(n)]
    h, w = frames[0].shape[:2]
    levels = A.default_levels(h, w)
    est, start = R.estimation_level(h, w, levels), R.start_level(h, w, levels)
    start = max(start, est)
    tol = A._tolerance(4, frames[0].dtype)
    top = np.iinfo(frames[0].dtype).max
    lo, hi = 2 * tol + 1, top - 2 * tol - 1
    aligner = A.get_aligner(device)
    pyr = []
    for f in frames:  # grey pyramids on the device; the levels used are kept on the host
        pyr.append(list(aligner.grey_pyramid(f, levels, slot="frame", host_from=est).host[est:]))
    vmask = valid or [None] * n
    reg = _Registrar(pyr, vmask, est, start, lo, hi, tol, (h, w))
    mats: List[np.ndarray] = [np.eye(3)] * n
    out = [("reference", np.eye(3), 0.0, ref)] * n
    pending: List[int] = []
    moving = [model != "auto"]  # _static leaves the fits as they are

    def final(j: int) -> None:
        if on_final is None:
            return
        pending.append(j)
        if not moving[0] and motion_px(out[j][1], h, w, vmask[j]) > STATIC_PX:
            moving[0] = True
        while moving[0] and pending:
            k = pending.pop(0)
            on_final(k, out[k][1])

    for j in sorted(range(n), key=lambda k: (abs(k - ref), k)):
        if j == ref:
            continue
        anchor = j + (1 if j < ref else -1)  # the neighbour in exposure: most pixels shared ...
        while out[anchor][0] == "inherited":  # ... that was measured
            anchor += 1 if j < ref else -1
        kind, f, r, why = _register(reg, anchor, j, model, names)
        if why is not None:
            logger.warning("%s: %s; it takes the motion of %s", names[j], why, names[anchor])
            mats[j] = mats[anchor]
            out[j] = ("inherited", mats[anchor], float("nan"), anchor)
            final(j)
            continue
        m = f.matrix @ mats[anchor]
        if model in ("auto", "shift"):
            snapped = _snap(m, h, w)
            if snapped is not None:
                kind, m = "shift", snapped
        mats[j] = m
        out[j] = (kind, m, r, anchor)
        logger.info("align: %s: %s against %s, residual %.3f px", names[j], kind, names[anchor], r)
        final(j)
    return _static(out, h, w, vmask) if model == "auto" else out, aligner


def _register(reg: _Registrar, anchor: int, j: int, model: str, names):
    """``(model, fit, residual, why)`` of frame ``j`` against ``anchor``. ``why`` (not
    None) says why a frame with few usable pixels cannot be measured (it then takes the
    anchor's motion); a frame that has plenty and still cannot be aligned is refused
    (InputError naming it).

    A fit over few samples (under :data:`FEW_SAMPLES`), or one whose residual cannot be
    measured (no textured tile: NaN), is accepted only when the block-matching estimate
    of :mod:`hdrcl.core.register_check` agrees with it within :data:`AGREE_PX` where the
    frame has content; the fit is retried from that estimate once. Its residual is then
    the larger of the tiles' and the two estimates' distance: never NaN."""
    from hdrcl.core import register_check as RC

    h, w = reg.shape
    m0 = reg.shift(anchor, j)
    kind, f, r = _fit_models(reg, anchor, j, m0, model)
    if f.samples >= FEW_SAMPLES and np.isfinite(r):
        why = _refusal(f, r, f.matrix, h, w)
        if why:
            raise InputError(f"{names[j]}: cannot be aligned to {names[anchor]}: {why}")
        return kind, f, r, None
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
        return kind, f, max(gap, r) if np.isfinite(r) else gap, None
    if f.samples >= FEW_SAMPLES:  # plenty to go on, and yet no estimate to confirm it
        why = _refusal(f, r, f.matrix, h, w) or (
            "its residual cannot be measured (no textured tile) and no second estimate confirms the fit"
            if est is None else f"a second estimate (block matching) puts it {gap:.1f} px away")
        raise InputError(f"{names[j]}: cannot be aligned to {names[anchor]}: {why}")
    if est is None:
        return kind, f, r, (f"too few well-exposed pixels shared with {names[anchor]} ({f.samples} samples) "
                            "to align it, and no second estimate to confirm a fit")
    return kind, f, r, (f"too few well-exposed pixels shared with {names[anchor]} ({f.samples} samples) to "
                        f"trust a fit: a second estimate (block matching) puts it {gap:.1f} px away")


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


def _static(fits, h: int, w: int, valid=None):
    """``fits`` as they are, or, when no frame moved more than :data:`STATIC_PX`
    (:func:`motion_px`: a tripod), every frame left as it is: model ``none``, identity,
    and as residual the motion measured and not undone."""
    valid = valid or [None] * len(fits)
    motion = [motion_px(m, h, w, v) for (_, m, _, _), v in zip(fits, valid)]
    if max(motion) > STATIC_PX:
        return fits
    logger.info("align: no frame moved more than %.2f px: the frames are merged as they are", STATIC_PX)
    return [(k if k == "reference" else "none", np.eye(3), r if k == "reference" else max(r, d), a)
            for (k, _, r, a), d in zip(fits, motion)]


def align_bracket(frames, valid, times, device=None, crop: bool = False, model: str = "auto",
                  names: Optional[Sequence[str]] = None, inplace: bool = False) -> Aligned:
    """Register every frame to the middle exposure and warp it there (module docstring).

    ``frames``/``valid`` are in any order; ``times`` orders them. ``names`` (file paths)
    name a frame that cannot be aligned. The lists given are not modified, unless
    ``inplace``: then each frame and mask is replaced in them by its warped version as
    soon as it is made (the original can be freed: one frame's memory, not a bracket's),
    and a replaced frame's memory is reused for the next frame's warp (no fresh pages to
    fault in: measured 0.35-0.9 s less for 6 frames of 24 MP), so the caller must hold
    no other reference to the frames it passes.
    """
    model = check_model(model)
    n = len(frames)
    names = [os.path.basename(os.fspath(p)) for p in names] if names is not None else [f"frame {j}" for j in range(n)]
    order = [int(i) for i in np.argsort(np.asarray(times, np.float64), kind="stable")]
    h, w = frames[0].shape[:2]
    ref = n // 2
    from hdrcl.core.align import get_aligner

    out_f, out_v = (frames, valid) if inplace else (list(frames), list(valid))
    if min(h, w) < MIN_SIDE:  # nothing to register on: merged as they are, said once
        logger.warning("%s: frames of %dx%d pixels are too small to align (under %d on a side); they are "
                       "merged as they are", names[order[0]], w, h, MIN_SIDE)
        ref_i = order[ref]
        records = [describe(names[i], "reference" if i == ref_i else "none", np.eye(3), 0.0, h, w, names[ref_i])
                   for i in range(n)]
        return Aligned(out_f, out_v, [(0, 0)] * n, (0, h, 0, w) if crop else None, records)
    warps = _Warps(out_f, out_v, order, _warper(get_aligner(device)), inplace)
    try:
        fits, _ = estimate([frames[i] for i in order], ref, model, device, [names[i] for i in order],
                           [valid[i] for i in order], on_final=warps.submit)
    except BaseException:
        # The warps already started end before the error is raised; theirs (a device
        # fault on the worker) is logged, not raised over it: the refusal naming the frame
        # is the message.
        try:
            warps.finish()
        except Exception as exc:  # noqa: BLE001
            logger.debug("align: a warp failed while alignment stopped: %s", exc)
        raise
    warps.finish()
    shifts: List[tuple] = [(0, 0)] * n
    records: List[dict] = [{}] * n
    for pos, i in enumerate(order):
        kind, m, r, anchor = fits[pos]
        warps.submit(pos, m)  # those not warped yet (the reference, a static bracket): here
        rec = describe(names[i], kind, m, r, h, w, names[order[anchor]])
        records[i] = rec
        shifts[i] = (int(round(rec["shift_px"][0])), int(round(rec["shift_px"][1])))
    box = W.crop_box((h, w), [f[1] for f in fits]) if crop else None
    if box is not None:
        if box[1] <= box[0] or box[3] <= box[2]:
            raise InputError(f"{names[order[0]]}: the aligned frames share no common area to crop to")
        out_f, out_v = W.crop_frames(out_f, out_v, box)
    return Aligned(out_f, out_v, shifts, box, records)


def alignment_meta(shifts, alignment) -> dict:
    """Output-file metadata of an alignment: ``alignShifts`` (whole-pixel ``[dy, dx]``
    per frame), ``alignModel`` (per frame) and ``alignTransforms`` (per frame: the
    3x3 matrix, reference -> frame pixel coordinates, row-major, 9 numbers)."""
    meta = {"alignShifts": [list(map(int, sh)) for sh in shifts]}
    if alignment:
        meta["alignModel"] = [a["model"] for a in alignment]
        meta["alignTransforms"] = [[v for row in a["matrix"] for v in row] for a in alignment]
        meta["alignResidualPx"] = [a["residual_px"] for a in alignment]
    return meta
