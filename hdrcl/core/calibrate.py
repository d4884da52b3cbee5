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
from hdrcl.core.response import Response
from hdrcl.core.solve import recover_response
from hdrcl.errors import UsageError

logger = logging.getLogger(__name__)


def calibrate(
    images: Union[Sequence[PathOrArray], Bracket],
    times: Optional[Sequence[float]] = None,
    *,
    times_file=None,
    samples: Optional[int] = None,
    smoothness: Optional[float] = None,
    weight: str = "hat",
    ignore_color=None,
    seed: int = 0,
    fit_exposures: str = "auto",
    exposure_tolerance: Optional[float] = None,
    warn: bool = True,
) -> Response:
    """Recover the camera response from a bracket set.

    ``fit_exposures`` (``auto``, ``on``, ``off``): estimate each frame's relative
    exposure from the pixels (:func:`hdrcl.core.exposure_fit.fit_exposures`) and report every
    frame whose metadata disagrees by more than ``exposure_tolerance`` stops (default
    0.5). ``auto`` uses the fitted value only for those frames, ``on`` for all, ``off``
    never fits. The times used are recorded per frame in ``Response.exposures``
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
    from hdrcl.core.exposure_fit import EXPOSURE_TOLERANCE_STOPS
    from hdrcl.core.exposure_fit import fit_exposures as _fit
    from hdrcl.io.metadata import format_time

    if fit_exposures not in ("auto", "on", "off"):
        raise UsageError(f"--fit-exposures: '{fit_exposures}' is not one of auto, on, off")
    tol = EXPOSURE_TOLERANCE_STOPS if exposure_tolerance is None else float(exposure_tolerance)
    names = br.paths or [f"image {k}" for k in range(len(br.frames))]
    used = np.asarray(br.times, np.float64)
    fitted = None
    if fit_exposures != "off" and len(br.frames) >= 3:
        # The fit always uses the paper's hat weights: their wide overlap between frames
        # conditions the exposure estimates better than a narrow weighting does (on the
        # Memorial set gaussian weights let the fit wander by up to 0.8 stops).
        fit = _fit(br.frames, br.times, valid=br.valid_all, samples=min(samples or 400, 400),
                   weight="hat", seed=seed, tolerance=tol, decimate=not br.grid)
        fitted = fit.fitted
        for k in np.flatnonzero(fit.flagged):
            logger.warning("%s: metadata says %s but the pixels say %s (%+.2f stops)%s", os.path.basename(names[k]),
                           format_time(fit.nominal[k]), format_time(fit.fitted[k]), fit.stops[k],
                           "" if fit_exposures != "auto" else "; using the fitted exposure")
        if fit_exposures == "on":
            used = fit.fitted.copy()
        elif fit.flagged.any():
            used = np.where(fit.flagged, fit.fitted, used)
    resp = recover_response(br.frames, used, valid=br.valid_all, samples=samples,
                            smoothness=smoothness, weight=weight, seed=seed, decimate=not br.grid, warn=warn)
    resp.camera = br.camera
    resp.exposures = [
        {"file": os.path.basename(n), "nominal": float(t), "fitted": None if fitted is None else float(f),
         "used": float(u)}
        for n, t, f, u in zip(names, br.times, fitted if fitted is not None else br.times, used)]
    return resp


def exposures_used(response: Response, bracket_times) -> np.ndarray:
    """The times a merge should use: those its response refined, when it was
    calibrated from this very set (same count and nominal values), else the nominal."""
    ex = response.exposures or []
    nominal = np.asarray(bracket_times, np.float64)
    if len(ex) == nominal.size and all("used" in e for e in ex) and np.allclose(
            [e["nominal"] for e in ex], nominal, rtol=1e-9):
        return np.asarray([e["used"] for e in ex], np.float64)
    return nominal
