"""The quality report of one file merge (``hdrcl merge --report DIR``): the frames are
read again, measured against the merge and written as a set report and contact sheet.
"""
from __future__ import annotations

import os
from dataclasses import replace
from typing import Optional, Union

import numpy as np

from hdrcl.core.bracket import (
    Bracket,
    parse_ignore_color,
    read_infos,
    with_ignore,
)
from hdrcl.core.merge import MergeResult
from hdrcl.core.weights import DEFAULT_WEIGHT


def write_quality_report(result: MergeResult, folder: Union[str, os.PathLike], *, ignore_color=None,
                         weight: str = DEFAULT_WEIGHT, device: Optional[str] = None, name: Optional[str] = None,
                         loo: bool = True):
    """Quality figures of a file merge and their report in ``folder``.

    Writes the set's preview, frame thumbnails, plots and JSON, and an ``index.html``
    contact sheet over every set in ``folder`` (earlier runs' too;
    :mod:`hdrcl.report.pages`). The frames come from ``result.kept`` when the merge kept
    them (``keep_frames``), else they are read again: whole when they fit
    :func:`memory_budget`, else as the sampling grid (the clipping and coverage figures
    are then on that grid).

    Returns
    -------
    (QualityFigures, ReportEntry)
    """
    from hdrcl.core.sampling import grid_stride
    from hdrcl.io.reader import BracketReader
    from hdrcl.report.inputs import shot_settings
    from hdrcl.report.pages import load_report_folder, write_contact_sheet, write_set_report
    from hdrcl.report.quality import measure, report_stride

    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    paths = result.paths
    infos = read_infos(paths)
    rgb = parse_ignore_color(ignore_color)
    h, w, c = result.shape
    k = report_stride(h, w)  # the grid every figure but the dynamic range is measured on
    stride = 1  # of the frames in hand
    kept = getattr(result, "kept", None)
    if kept is not None:  # the merge's own decode (merge_files(keep_frames=True)): none again
        frames, valid, is_grid = kept
        frames, valid = list(frames), list(valid)
        stride = grid_stride(h, w) if is_grid else 1
    else:
        with BracketReader(paths, infos) as reader:
            if result.shifts is not None or k == 1:  # aligned: warped below, whole
                frames, valid = reader.read_all()
            else:  # at most half a megapixel a frame: no memory budget to mind
                stride = k
                frames, valid = reader.read_grid(stride)
    valid = with_ignore(frames, valid, rgb)
    if getattr(result, "alignment", None) and kept is None:  # what was merged: the warped (and cropped) frames
        from hdrcl.core.align.handheld import apply_alignment

        frames, valid = apply_alignment(frames, valid, result.alignment, result.crop)
    if stride == 1 and k > 1:  # whole frames in hand: measured on the report's grid all the same
        frames = [np.ascontiguousarray(f[::k, ::k]) for f in frames]
        valid = [None if v is None else np.ascontiguousarray(v[::k, ::k]) for v in valid]
        stride = k
    nominal = result.nominal if result.nominal is not None else result.times
    if shot_settings(infos, nominal) is None:  # --times or a times file overrode EXIF: label what was given
        infos = [replace(i, exposure_time=None) for i in infos]
    br = Bracket(frames=frames, times=np.asarray(nominal), valid=valid, paths=paths, infos=infos, grid=stride > 1)
    preview = result.thumbnail if result.thumbnail is not None else result.radiance
    fig = measure(br, result.response, preview, weight=weight, times=result.times, device=device, loo=loo,
                  stride=stride, shape=(h, w, c))
    stem = name or os.path.splitext(os.path.basename(result.output or paths[0]))[0]
    entry = write_set_report(folder, stem, fig, result.response, preview, fig.coverage, warnings=result.warnings,
                             bracket=br, alignment=getattr(result, "alignment", None))
    # The folder accumulates: every set reported into it before (any run) is on the page.
    entries = [e for e in load_report_folder(folder) if e.name != entry.name] + [entry]
    write_contact_sheet(folder, sorted(entries, key=lambda e: e.name))
    return fig, entry
