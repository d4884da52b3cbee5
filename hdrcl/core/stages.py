"""Small stages of a merge that ``merge_files`` (:mod:`hdrcl.core.merge`) and the batch's
set runner share: the OpenCL warm-up, the exposure measurement through a known curve and
its warnings, the frames a quality report may reuse, and a sink that feeds several.
"""
from __future__ import annotations

import logging

logger = logging.getLogger("hdrcl.core.merge")


def _measured_exposures(frames, valid, times, resp, mode, weight, tolerance, paths):
    """:func:`hdrcl.core.exposure_known.exposures_for_merge` on a set's grid; its notes
    are logged as warnings (a corrected or doubtful exposure is worth a line)."""
    from hdrcl.core.exposure_known import exposures_for_merge

    used, notes = exposures_for_merge(frames, times, resp, mode=mode, valid=valid, weight=weight,
                                      tolerance_stops=tolerance, names=paths)
    for note in notes:
        logger.warning("%s", note)
    return used, notes


def _kept_frames(source, grid):
    """``(frames, valid, is_grid)`` the merge holds already: an aligned set's frames, the
    decoded-frame cache when it is in memory, else the sampling grid; None otherwise."""
    if hasattr(source, "frames"):  # aligned (and cropped): what was merged
        return list(source.frames), list(source.valid), False
    cache = getattr(source, "cache", None)
    if cache is not None and cache.complete and cache.in_memory:
        frames, valid = cache.rows(0, cache.height)
        return frames, valid, False
    if grid is not None:
        return list(grid.frames), list(grid.valid), True
    return None


def _report_exposure_check(check, result, tolerance):
    """Warn about exposures the pixels contradict; refuse a set whose exposures run in
    reverse order of its brightness (raised inside the writer: no output is left)."""
    from hdrcl.core.exposure_fit import EXPOSURE_TOLERANCE_STOPS
    from hdrcl.errors import InputError

    msgs, backwards = check.problems(EXPOSURE_TOLERANCE_STOPS if tolerance is None else float(tolerance))
    if backwards:
        raise InputError(f"{check.names[-1]}: the exposure times run in reverse order of the frames' "
                         "brightness with this response; check the times")
    for m in msgs:
        logger.warning("%s", m)
        result.warnings.append(m)


def _warm_up(device, calibrating: bool, work=None):
    """Open the OpenCL device (and import the solver) on a helper thread while the
    frames decode: both take a few tenths of a second that need not add up."""
    import threading

    def warm():
        try:
            if calibrating:
                import scipy.sparse  # noqa: F401
            from hdrcl.cl.backend import get_processor

            get_processor("fusion", device, work=work)
        except Exception:  # the main thread meets the same error and reports it
            pass

    t = threading.Thread(target=warm, name="hdrcl-warm-up", daemon=True)
    t.start()
    return t


class _Tee:
    def __init__(self, *sinks):
        self.sinks = sinks

    def write_rows(self, y0, y1, data):
        for s in self.sinks:
            s.write_rows(y0, y1, data)
