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
) -> Response:
    """Recover the camera response from a bracket set.

    ``fit_exposures`` (``auto``, ``on``, ``off``): verify each frame's relative exposure
    against the pixels (:func:`hdrcl.core.exposure_fit.verify_exposures`) and report every
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

    Returns
    -------
    Response
        One curve per channel; ``save()`` writes it as JSON for ``--response``.

    Examples
    --------
    >>> resp = hdrcl.calibrate(paths, times_file="image_list.txt", ignore_color=(0, 0, 255))
    >>> resp.save("memorial.json")
    """
    if isinstance(images, Bracket):
        br = images
    elif len(images) and not any(isinstance(im, np.ndarray) for im in images):
        # Files: only the sampling grid is kept, so memory does not grow with the image.
        paths, infos, rel = _open_files(images, times, times_file)
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
        br = load_bracket(images, times, times_file=times_file, ignore_color=ignore_color)
    from hdrcl.core.exposure_fit import verify_exposures

    names = br.paths or [f"image {k}" for k in range(len(br.frames))]
    used, fit = verify_exposures(br.frames, br.times, names, mode=fit_exposures, valid=br.valid_all,
                                 samples=samples, seed=seed, tolerance=exposure_tolerance, decimate=not br.grid,
                                 warn=warn)
    fitted = None if fit is None else fit.fitted
    resp = recover_response(br.frames, used, valid=br.valid_all, samples=samples,
                            smoothness=smoothness, weight=weight, seed=seed, decimate=not br.grid, warn=warn)
    resp.camera = br.camera
    resp.exposures = [
        {"file": os.path.basename(n), "nominal": float(t), "fitted": None if fitted is None else float(f),
         "used": float(u)}
        for n, t, f, u in zip(names, br.times, fitted if fitted is not None else br.times, used)]
    from hdrcl.core.exposure_known import untrusted_metadata

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
