"""Calibration of a bracket set: exposure verification, then the response solve."""
from __future__ import annotations

import logging
import os
from typing import Optional, Sequence, Union

import numpy as np

from hdrcl.core.bracket import (
    Bracket,
    PathOrArray,
    _all_raw,
    _grid_bracket,
    _open_files,
    _parse_ignore_color,
    load_bracket,
)
from hdrcl.core.response import SPAN_BODY, Response
from hdrcl.core.solve import recover_response
from hdrcl.core.weights import DEFAULT_WEIGHT
from hdrcl.errors import InputError

logger = logging.getLogger(__name__)


def calibrate(
    images: Union[Sequence[PathOrArray], Bracket],
    times: Optional[Sequence[float]] = None,
    *,
    times_file=None,
    samples: Optional[int] = None,
    smoothness: Optional[float] = None,
    weight: str = DEFAULT_WEIGHT,
    ignore_color=None,
    seed: int = 0,
    fit_exposures: str = "auto",
    exposure_tolerance: Optional[float] = None,
    warn: bool = True,
    channel_order: str = "rgb",
) -> Response:
    """Recover the camera response from a bracket set.

    ``fit_exposures`` (``auto``, ``on``, ``off``): verify each frame's relative exposure
    against the pixels (:func:`hdrcl.core.exposure.fit.verify_exposures`) and report every
    frame whose metadata disagrees by more than ``exposure_tolerance`` stops (default
    0.5), and frames that are in truth at the same exposure. The scale of the exposure
    axis comes from the frames whose metadata agree, never from a free fit. ``auto``
    changes a frame only when the pixels contradict it decisively and the change lowers
    the fit error; ``on`` uses the pixel estimate for every frame; ``off`` never fits.
    The curve's span in decades (codes 10..245) is logged, and an 8-bit curve spanning
    more than 4 decades is warned about (``Response.warnings``). The times used are
    recorded per frame in ``Response.exposures``
    (``nominal``, ``fitted``, ``used``) and a merge of the same set uses them.
    ``warn=False`` keeps the curve's problems out of the log (they stay in
    ``Response.warnings``): for re-solves the user did not ask for.
    ``channel_order="bgr"`` reads arrays in OpenCV's channel order (the default, and
    files, are RGB). Every option is checked (:mod:`hdrcl.core.params`) before any
    file is decoded; frames with nothing to measure (black, white or transparent
    everywhere) raise InputError before the exposure check warns about them.

    Returns
    -------
    Response
        One curve per channel; ``save()`` writes it as JSON for ``--response``.

    Examples
    --------
    >>> resp = hdrcl.calibrate(paths, times_file="image_list.txt", ignore_color=(0, 0, 255))
    >>> resp.save("memorial.json")
    """
    from hdrcl.core.params import check_images, check_options

    opts = check_options(samples=samples, smoothness=smoothness, weight=weight, seed=seed,
                         fit_exposures=fit_exposures, exposure_tolerance=exposure_tolerance,
                         ignore_color=ignore_color, channel_order=channel_order)
    samples, smoothness, seed, exposure_tolerance = (opts[k] for k in ("samples", "smoothness", "seed",
                                                                       "exposure_tolerance"))
    if not isinstance(images, Bracket):
        images = check_images(images)
    if isinstance(images, Bracket):
        br = images
    elif len(images) and not any(isinstance(im, np.ndarray) for im in images):
        # Files: only the sampling grid is kept, so memory does not grow with the image.
        paths, infos, rel = _open_files(images, times, times_file)
        from hdrcl.io.frames import check_orientation

        check_orientation(infos)
        if _all_raw(paths):
            from hdrcl.core.response import linear_response

            logger.info("RAW input is linear; no calibration needed")
            resp = linear_response(3 if infos[0].nchannels >= 3 else 1)
            resp.camera = Bracket(frames=[], times=rel, valid=[], infos=infos).camera
            resp.exposures = [{"file": os.path.basename(p), "nominal": float(t), "fitted": None, "used": float(t)}
                              for p, t in zip(paths, rel)]
            return resp
        br = _grid_bracket(paths, infos, rel, _parse_ignore_color(ignore_color))
    else:
        br = load_bracket(images, times, times_file=times_file, ignore_color=ignore_color,
                          channel_order=channel_order)
    from hdrcl.core.exposure.fit import verify_exposures
    from hdrcl.core.sampling import sample_candidates

    names = br.paths or [f"image {k}" for k in range(len(br.frames))]
    check_measurable(br.frames, br.valid_all, names, decimate=not br.grid)
    # The exposure check and the curve draw their samples from the same candidates.
    pool = sample_candidates(br.frames, br.valid_all, decimate=not br.grid)
    used, fit = verify_exposures(br.frames, br.times, names, mode=fit_exposures, valid=br.valid_all,
                                 samples=samples, seed=seed, tolerance=exposure_tolerance, decimate=not br.grid,
                                 warn=warn, candidates=pool)
    fitted = None if fit is None else fit.fitted
    resp = recover_response(br.frames, used, valid=br.valid_all, samples=samples, smoothness=smoothness,
                            weight=weight, seed=seed, decimate=not br.grid, warn=warn, candidates=pool)
    resp.camera = br.camera
    resp.exposures = [
        {"file": os.path.basename(n), "nominal": float(t), "fitted": None if fitted is None else float(f),
         "used": float(u)}
        for n, t, f, u in zip(names, br.times, fitted if fitted is not None else br.times, used)]
    from hdrcl.core.exposure.verdict import untrusted_metadata

    doubt = untrusted_metadata(resp, fit, names)
    report_span(resp, warn=warn and doubt is None)
    if doubt is not None:
        # One warning, naming the frames, says it all (it includes a stretched curve).
        problem = resp.span_problem()
        if problem in resp.warnings:
            resp.warnings.remove(problem)
        if warn:
            logger.warning("%s", doubt)
        resp.warnings.append(doubt)
    return resp


def check_measurable(frames, valid, names, decimate: bool = True) -> None:
    """InputError, one line naming the frames, when too few pixels measure anything for
    a solve: every frame black, white (clipped) or transparent everywhere. Checked before
    the exposure check, whose warnings (identical frames, exposures the pixels
    contradict) would only describe the same failure."""
    from hdrcl.core.response import knot_positions
    from hdrcl.core.sampling import grid_stride

    h, w = frames[0].shape[:2]
    k = grid_stride(h, w) if decimate else 1
    subs = [f[::k, ::k] for f in frames]
    subs = [s.reshape(s.shape[0], s.shape[1], -1) for s in subs]
    top = int(np.iinfo(frames[0].dtype).max)
    ok = np.ones(subs[0].shape[:2], bool) if valid is None else np.asarray(valid)[::k, ::k].copy()
    lo = np.zeros(ok.shape, bool)
    hi = np.zeros(ok.shape, bool)
    for s in subs:
        for c in range(s.shape[2]):  # channel by channel: NumPy's any() over a last axis of 3 is slow
            lo |= s[:, :, c] > 0
            hi |= s[:, :, c] < top
    usable = ok & lo & hi
    need = knot_positions(8 * frames[0].dtype.itemsize).size // 4
    if int(usable.sum()) * (len(frames) - 1) > need:
        return
    what = (f"{os.path.basename(names[0])} .. {os.path.basename(names[-1])} ({len(names)} frames)"
            if len(names) > 3 else ", ".join(os.path.basename(n) for n in names))
    if not ok.any():
        why = "no pixel is valid in every frame (transparent, or the --ignore-color, everywhere)"
    elif not (ok & lo).any():
        why = "every frame is black (code 0) wherever it is valid"
    elif not (ok & hi).any():
        why = f"every frame is white (clipped at {top}) wherever it is valid"
    else:
        why = "almost every pixel is black, clipped or masked in every frame"
    raise InputError(f"{what}: {why}; nothing to calibrate from (give frames with detail, or --response)")


def report_span(resp: Response, warn: bool = True) -> float:
    """Log the curve's span in decades (codes 10..245) and warn (``warn``), into
    ``resp.warnings`` too, when an 8-bit curve is stretched (:meth:`Response.span_problem`)."""
    span = resp.span_decades()
    logger.log(logging.INFO if warn else logging.DEBUG,
               "response spans %.2f decades between codes 10 and 245 (%.2f between %d and %d)",
               span, resp.span_decades(*SPAN_BODY), *SPAN_BODY)
    problem = resp.span_problem()
    if problem and problem not in resp.warnings:
        if warn:
            logger.warning("%s", problem)
        resp.warnings.append(problem)
    return span


def exposures_used(response: Response, bracket_times) -> np.ndarray:
    """The times a merge should use: those its response refined, when it was
    calibrated from this very set (same count and nominal values), else the nominal."""
    ex = response.exposures or []
    nominal = np.asarray(bracket_times, np.float64)
    if len(ex) == nominal.size and all("used" in e for e in ex) and np.allclose(
            [e["nominal"] for e in ex], nominal, rtol=1e-9):
        return np.asarray([e["used"] for e in ex], np.float64)
    return nominal


#: The verdict is a statistic over the whole picture: it is asked on at most this many
#: pixels a frame (a batch asks it of every set, so it must stay cheap: 0.5 s -> 0.15 s a
#: 12 MP set's grid), and a doubt found there is confirmed on the whole grid.
VERDICT_PIXELS = 65_536


def _thinned(bracket: Bracket, max_pixels: int) -> Bracket:
    """``bracket`` on every k-th row and column, k the smallest that leaves at most
    ``max_pixels`` pixels a frame."""
    import dataclasses
    import math

    h, w = bracket.frames[0].shape[:2]
    k = max(1, math.ceil(math.sqrt(h * w / max_pixels)))
    if k == 1:
        return bracket
    return dataclasses.replace(bracket, frames=[f[::k, ::k] for f in bracket.frames],
                               valid=[None if v is None else v[::k, ::k] for v in bracket.valid])


def metadata_verdict(bracket: Bracket, *, samples: Optional[int] = None, smoothness: Optional[float] = None,
                     weight: str = DEFAULT_WEIGHT, seed: int = 0, fit_exposures: str = "auto",
                     exposure_tolerance: Optional[float] = None):
    """What :func:`calibrate` would say of a set's exposure metadata, said by nobody:
    ``(verdict, span)``, the verdict of
    :func:`hdrcl.core.exposure.verdict.untrusted_metadata` (None when nothing says the
    metadata is wrong) and the span in decades (codes 10..245) of the set's own curve.

    A batch asks it of every set it pools (:mod:`hdrcl.shoot.batch.pooling`), so that a
    set whose times cannot be trusted never shapes its camera's pooled curve, and of every
    other set it merges with a pooled curve, so that it says so as ``calibrate`` would.
    """
    from hdrcl.core.exposure.fit import UNTRUSTED

    if bracket.paths and _all_raw(bracket.paths):  # linear: no curve, no verdict
        return None, 0.0
    def ask(br):
        resp = calibrate(br, samples=samples, smoothness=smoothness, weight=weight, seed=seed,
                         fit_exposures=fit_exposures, exposure_tolerance=exposure_tolerance, warn=False)
        return next((w for w in resp.warnings if w.startswith(UNTRUSTED)), None), float(resp.span_decades())

    thin = _thinned(bracket, VERDICT_PIXELS)
    verdict, span = ask(thin)
    if verdict is not None and thin is not bracket:
        # Near its limits the verdict can turn on which pixels are sampled (Memorial with its
        # blue borders unmasked): a doubt found on the thinned grid is confirmed on the whole.
        verdict, span = ask(bracket)
    return verdict, span
