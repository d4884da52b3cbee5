"""Hand-held brackets: each frame registered to the middle exposure by a translation,
a similarity or a homography, then warped onto it (``merge --align``).

Stages, per frame:

1. **Whole-pixel shift** by median threshold bitmaps (:mod:`hdrcl.core.align.mtb`, Ward
   2003): the start, reaching 63 pixels or more.
2. **Sub-pixel fit** of the model(s) (:mod:`hdrcl.core.align.register`) on the frames' rank
   images, coarse to fine on a pyramid of at most a few megapixels. Each frame is
   registered to its neighbour in exposure on the way to the reference (they share the
   most well-exposed pixels), already registered, and the matrices are composed.
   The fit is then refitted to the frame's tiles, each tile once, where held-out tiles
   confirm it (:mod:`hdrcl.core.align.tilefit`: the frame as a whole, not its strongest
   edges).
3. **Model choice** (``auto``): the translation, unless the similarity lowers the
   residual misalignment by more than :data:`CLEAR_GAIN_PX` and :data:`CLEAR_GAIN_FRAC`
   of it; then the homography, only when it also lands the frame's tiles, block-matched
   independently of the fit (:mod:`hdrcl.core.align.check`), clearly closer than the
   similarity (:data:`HOMOGRAPHY_GAIN_PX`). A result within :data:`SNAP_PX` of a
   whole-pixel shift at every corner is taken as that shift (an exact copy, no
   resampling). A bracket in which no frame moved :data:`STATIC_PX` or more
   (:func:`motion_px`: the median over the frame) is left as it is (model ``none``: a
   tripod).
4. **Trust** (:mod:`hdrcl.core.align.trust`). A fit over fewer than :data:`FEW_SAMPLES` samples (a
   dark frame: its pedestal is left out, :func:`hdrcl.core.align.register.usable_range`), or
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
5. **Warp** (:mod:`hdrcl.core.align.warp`; on the device :class:`hdrcl.cl.warp.WarpProcessor`,
   each frame as soon as its matrix is final, on a worker thread while the host
   estimates the next), masks warped with the frames; ``crop`` keeps the largest
   axis-aligned box every frame covers.
"""
from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence

import numpy as np

from hdrcl.core.align import register as R
from hdrcl.core.align import unaligned as U
from hdrcl.core.align import warp as W
from hdrcl.core.align.trust import (  # noqa: F401 (the rules, here as before)
    AGREE_PX, CLEAR_GAIN_FRAC, CLEAR_GAIN_PX, FEW_SAMPLES, HELD_OUT_RADIUS, HOMOGRAPHY_GAIN_PX, MAX_RESIDUAL_PX,
    INHERITED, LEFT_OUT, MAX_ROTATION, MIN_MEASURABLE, MIN_ZNCC, SCALE_RANGE, SKIP_PX, SNAP_PX, Unaligned,
    motion_px, register_chained)
from hdrcl.core.align.unaligned import without  # noqa: F401 (the API here)
from hdrcl.core.align.warping import _warper, _Warps, apply_alignment, warp_one  # noqa: F401 (the API here)
from hdrcl.errors import InputError, UsageError

logger = logging.getLogger(__name__)

MODELS = ("auto", "shift", "similarity", "homography")
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
    :func:`describe` dict per frame merged; the frames left out (indices as given:
    :func:`hdrcl.core.align.unaligned.without` drops them from a merge's inputs)."""

    frames: List[np.ndarray]
    valid: List[Optional[np.ndarray]]
    shifts: List[tuple]
    crop: Optional[tuple]
    alignment: List[dict]
    left_out: List[int] = field(default_factory=list)  # indices (as given) of the frames not merged


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

    def forget(self, keep) -> None:
        """Drop the rank pyramids of the frames not in ``keep`` (made again, the same, if
        asked for): the estimate's memory is a few frames' levels, not the bracket's."""
        for k in [k for k in self._levels if k not in keep]:
            del self._levels[k]

    def shift(self, a: int, b: int) -> np.ndarray:
        """Whole-pixel shift of ``b`` against ``a`` by median threshold bitmaps on the
        kept levels (each frame's usable range in place of the fixed one), full size."""
        from hdrcl.core.align import mtb as A
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
    (:func:`hdrcl.core.align.register.fill_mask` of the estimation level); None when all is."""
    v = None if valid is None else R.valid_pyramid(valid, len(pyr) + est)[est]
    fill = R.fill_mask(pyr[0])
    if fill.any():
        v = ~fill if v is None else v & ~fill
    return None if v is None else R.valid_pyramid(v, len(pyr))


def _snap(m: np.ndarray, h: int, w: int) -> Optional[np.ndarray]:
    """The whole-pixel shift within :data:`SNAP_PX` of ``m`` at every corner, or None."""
    c = np.array([[(w - 1) / 2.0, (h - 1) / 2.0]])
    d = W.apply(m, c)[0] - c[0]
    t = W.translation(round(float(d[1])), round(float(d[0])))
    return t if W.corner_distance(m, t, h, w) <= SNAP_PX else None


def estimate(frames: Sequence[np.ndarray], ref: int, model: str, device=None, names=None, valid=None,
             on_final=None, events: Optional[list] = None, leave_out: bool = False):
    """Matrices (reference -> frame), chosen models, residuals and anchors per frame
    (``frames`` ordered by exposure). Raises InputError for a frame that cannot be aligned
    and does not stand still (:mod:`hdrcl.core.align.unaligned`), unless ``leave_out``:
    then such a frame is left out (model ``left out``) while at least two frames remain.
    ``events`` (a list) receives what did not align as fitted
    (:class:`hdrcl.core.align.unaligned.Event`).

    ``on_final(j, matrix)``, when given, is called for each frame (but the reference) as
    soon as its matrix is final: once the bracket is known not to be static (a frame
    moved more than :data:`STATIC_PX`, or ``model`` is not ``auto``), so that its warp
    can start while the next frames are estimated."""
    from hdrcl.core.align import mtb as A

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
    links = [0] * n  # fits composed between each frame and the reference
    out = [("reference", np.eye(3), 0.0, ref)] * n
    pending: List[int] = []
    moving = [model != "auto"]  # _static leaves the fits as they are
    events = [] if events is None else events

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
        # A frame registers against its two nearer neighbours toward the reference
        # (register_chained): the frames nearer still are done with.
        reg.forget({k for k in range(n) if abs(k - ref) >= abs(j - ref) - 2})
        try:
            anchor, kind, f, r, why = register_chained(reg, out, links, mats, j, ref, model, names)
        except Unaligned as exc:  # unmoved, or left out (hdrcl.core.align.unaligned)
            ev = U.settle(reg, exc, j, STATIC_PX)
            if ev.kind == LEFT_OUT and not leave_out:
                raise
            events.append(ev)
            a = ev.anchor
            if ev.kind == LEFT_OUT:
                out[j] = (LEFT_OUT, mats[a], float("nan"), a)
                continue
            mats[j], out[j], links[j] = mats[a], ("none", mats[a], ev.figure, a), links[a] + 1
            final(j)
            continue
        if why is not None:
            events.append(U.Event(j, anchor, INHERITED, why))
            mats[j] = mats[anchor]
            out[j] = (INHERITED, mats[anchor], float("nan"), anchor)
            final(j)
            continue
        m = f.matrix @ mats[anchor]
        if model in ("auto", "shift"):
            snapped = _snap(m, h, w)
            if snapped is not None:
                kind, m = "shift", snapped
        mats[j] = m
        out[j] = (kind, m, r, anchor)
        links[j] = links[anchor] + 1
        logger.info("align: %s: %s against %s, residual %.3f px", names[j], kind, names[anchor], r)
        final(j)
    U.check_kept(events, n)
    return _static(out, h, w, vmask) if model == "auto" else out, aligner


def _static(fits, h: int, w: int, valid=None):
    """``fits`` as they are, or, when no frame moved more than :data:`STATIC_PX`
    (:func:`motion_px`: a tripod), every frame left as it is: model ``none``, identity,
    and as residual the motion measured and not undone (frames left out stay out)."""
    valid = valid or [None] * len(fits)
    motion = [0.0 if k == LEFT_OUT else motion_px(m, h, w, v) for (k, m, _, _), v in zip(fits, valid)]
    if max(motion) > STATIC_PX:
        return fits
    logger.info("align: no frame moved more than %.2f px: the frames are merged as they are", STATIC_PX)
    return [(k if k in ("reference", LEFT_OUT) else "none", np.eye(3),
             r if k in ("reference", LEFT_OUT) else max(r, d), a) for (k, _, r, a), d in zip(fits, motion)]


def align_bracket(frames, valid, times, device=None, crop: bool = False, model: str = "auto",
                  names: Optional[Sequence[str]] = None, inplace: bool = False, find=None) -> Aligned:
    """Register every frame to the middle exposure and warp it there (module docstring).

    ``frames``/``valid`` are in any order; ``times`` orders them. ``names`` (file paths)
    name a frame that cannot be aligned. The lists given are not modified, unless
    ``inplace``: then each frame and mask is replaced in them by its warped version as
    soon as it is made (the original can be freed: one frame's memory, not a bracket's),
    and a replaced frame's memory is reused for the next frame's warp (no fresh pages to
    fault in: measured 0.35-0.9 s less for 6 frames of 24 MP), so the caller must hold
    no other reference to the frames it passes.

    ``find``: a callable taking each :class:`hdrcl.core.findings.Finding` of the
    alignment (a frame left out, unmoved or inherited: :mod:`hdrcl.core.align.unaligned`).
    Only with it is a frame that cannot be aligned left out (``Aligned.left_out``, its
    frame, mask and record dropped from the result) rather than refused; without it the
    findings are logged as warnings.
    """
    model = check_model(model)
    n = len(frames)
    names = [os.path.basename(os.fspath(p)) for p in names] if names is not None else [f"frame {j}" for j in range(n)]
    order = [int(i) for i in np.argsort(np.asarray(times, np.float64), kind="stable")]
    h, w = frames[0].shape[:2]
    ref = n // 2
    from hdrcl.core.align.mtb import get_aligner

    out_f, out_v = (frames, valid) if inplace else (list(frames), list(valid))
    if min(h, w) < MIN_SIDE:  # nothing to register on: merged as they are, said once
        logger.warning("%s: frames of %dx%d pixels are too small to align (under %d on a side); they are "
                       "merged as they are", names[order[0]], w, h, MIN_SIDE)
        ref_i = order[ref]
        records = [describe(names[i], "reference" if i == ref_i else "none", np.eye(3), 0.0, h, w, names[ref_i])
                   for i in range(n)]
        return Aligned(out_f, out_v, [(0, 0)] * n, (0, h, 0, w) if crop else None, records)
    warps = _Warps(out_f, out_v, order, _warper(get_aligner(device)), inplace)
    events: list = []
    ordered = [names[i] for i in order]
    try:
        fits, _ = estimate([frames[i] for i in order], ref, model, device, ordered,
                           [valid[i] for i in order], on_final=warps.submit, events=events,
                           leave_out=find is not None)
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
    st = settle(fits, order, names, events, find, h, w, crop)
    for pos, i in enumerate(order):
        if fits[pos][0] != LEFT_OUT:
            warps.submit(pos, fits[pos][1])  # those not warped yet (the reference, a static bracket): here
    if st.left:  # merged without them: every per-frame list in step
        out_f, out_v = [out_f[i] for i in st.keep], [out_v[i] for i in st.keep]
    if st.crop is not None:
        out_f, out_v = W.crop_frames(out_f, out_v, st.crop)
    return Aligned(out_f, out_v, st.shifts, st.crop, st.alignment, st.left)


@dataclass
class Settled:
    """What the fits of a bracket come to (:func:`settle`), per frame merged (input order,
    those left out dropped): the matrices, whole-pixel shifts and records; the indices
    kept and left out (as given), and the crop box (or None)."""

    matrices: List[np.ndarray]
    shifts: List[tuple]
    alignment: List[dict]
    keep: List[int]
    left: List[int]
    crop: Optional[tuple]


def settle(fits, order, names, events, find, h: int, w: int, crop: bool) -> Settled:
    """The findings of the alignment handed to ``find`` (logged without it), the frames
    left out, each frame's record and shift, and the crop box (InputError when the
    frames share no area): :func:`estimate`'s ``fits`` (exposure order) in input order."""
    ordered = [names[i] for i in order]
    static = all(f[0] in ("reference", "none", LEFT_OUT) for f in fits)
    for fd in U.findings(events, ordered, static):
        if find is None:
            logger.warning("%s", fd.message)
        else:
            find(fd)
    n = len(order)
    left = sorted(order[pos] for pos, f in enumerate(fits) if f[0] == LEFT_OUT)
    shifts: List[tuple] = [(0, 0)] * n
    records: List[dict] = [{}] * n
    mats: List[np.ndarray] = [np.eye(3)] * n
    for pos, i in enumerate(order):
        kind, m, r, anchor = fits[pos]
        rec = describe(names[i], kind, m, r, h, w, names[order[anchor]])
        records[i], mats[i] = rec, m
        shifts[i] = (int(round(rec["shift_px"][0])), int(round(rec["shift_px"][1])))
    keep = [i for i in range(n) if i not in left]
    box = W.crop_box((h, w), [mats[i] for i in keep]) if crop else None
    if box is not None and (box[1] <= box[0] or box[3] <= box[2]):
        raise InputError(f"{names[order[0]]}: the aligned frames share no common area to crop to")
    return Settled([mats[i] for i in keep], [shifts[i] for i in keep], [records[i] for i in keep], keep, left,
                   box)


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
