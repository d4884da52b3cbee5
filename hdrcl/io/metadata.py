"""Exposure information of photographs: header fields and relative exposure.

:class:`FrameInfo` is what :func:`hdrcl.io.frames.read_info` reads from a file's header.
:class:`hdrcl.io.exposure_lists.Exposure` is one frame's exposure settings, from
``--times``, a times file (:mod:`hdrcl.io.exposure_lists`) or EXIF;
:func:`resolve_exposures` chooses among those sources and
:func:`relative_exposures` turns the settings into the effective exposure times
``Δt_j`` that the Debevec-Malik model uses.

This module does not import OpenImageIO.
"""
from __future__ import annotations

import datetime as _dt
import logging
import math
import os
from dataclasses import dataclass, field
from typing import List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from hdrcl.errors import InputError, UsageError
from hdrcl.io.exposure_lists import Exposure, coerce_times, list_in, read_times_file

logger = logging.getLogger(__name__)

__all__ = [
    "FrameInfo",
    "relative_exposures",
    "resolve_exposures",
    "format_time",
    "check_exposures",
    "header_exposures",
]


# Two exposures whose effective times differ by less than this fraction (0.0014 stops)
# are the same exposure: they add no range, but they are fused (less noise).
SAME_EXPOSURE_RTOL = 1e-3


@dataclass
class FrameInfo:
    """What one photograph's header says, read without decoding its pixels.

    Attributes are ``None`` where the file does not carry the field.
    ``capture_time`` joins DateTimeOriginal and SubSecTimeOriginal (naive local time).
    ``orientation`` is EXIF Orientation 1..8 (:data:`hdrcl.io.exif.ORIENTATIONS`); 1 for a
    file without it and for camera RAW, which LibRaw turns upright as it decodes.
    """

    path: str
    width: int
    height: int
    nchannels: int
    channel_names: tuple = ()
    bits: int = 8  # 8 or 16: bits per sample of the stored integer data
    exposure_time: Optional[float] = None  # seconds
    fnumber: Optional[float] = None
    iso: Optional[float] = None
    exposure_bias: Optional[float] = None  # EV
    exposure_mode: Optional[int] = None  # EXIF ExposureMode: 0 auto, 1 manual, 2 auto bracket
    capture_time: Optional[_dt.datetime] = None
    make: Optional[str] = None
    model: Optional[str] = None
    serial: Optional[str] = None
    lens: Optional[str] = None
    focal_length: Optional[float] = None  # mm
    orientation: int = 1  # EXIF Orientation: how the stored pixels are to be shown
    extra: dict = field(default_factory=dict)


def _has_time(info) -> bool:
    t = info.exposure_time
    return t is not None and math.isfinite(t) and t > 0


def header_exposures(paths, infos) -> Tuple[list, List[str]]:
    """Each frame's exposure from its header, or from the exposure list beside it.

    A frame with an EXIF exposure time keeps it (with its f-number and ISO); one
    without takes its entry in the first of :data:`hdrcl.io.exposure_lists.EXPOSURE_LISTS` in its own folder
    (time, f-number, gain and ND as listed). The one rule of ``merge``, ``calibrate``,
    ``scan`` and ``batch``.

    Returns
    -------
    (list, list of str)
        One :class:`Exposure` per frame (None for a frame neither source times), and
        the lists that were used.

    Raises
    ------
    InputError
        A list beside the frames cannot be read (the message names it).
    """
    tables: dict = {}
    used: List[str] = []
    out = []
    for n, info in zip(paths, infos):
        if _has_time(info):
            out.append(Exposure(time=float(info.exposure_time), fnumber=info.fnumber, iso=info.iso))
            continue
        folder = os.path.dirname(os.path.abspath(os.fspath(n)))
        if folder not in tables:
            found = list_in(folder)
            tables[folder] = (found, read_times_file(found, _frames_in(folder, paths)) if found else {})
        found, table = tables[folder]
        e = table.get(os.path.basename(os.fspath(n)))
        if e is not None and found not in used:
            used.append(found)
        out.append(None if e is None else Exposure(e.time, info.fnumber or e.fnumber, info.iso, e.gain_db, e.nd))
    return out, used


def _frames_in(folder: str, paths) -> list:
    """The frames of ``paths`` in ``folder`` (what a bare list beside them applies to)."""
    return [p for p in paths if os.path.dirname(os.path.abspath(os.fspath(p))) == folder]


def _shared_or_none(values, label):
    """The reference value for a factor, or None when it must be ignored."""
    if any(v is None or v <= 0 for v in values):
        known = {v for v in values if v is not None and v > 0}
        if len(known) > 1:
            logger.warning(
                "some frames have no %s while the others differ (%s); ignoring %s",
                label, ", ".join(f"{v:g}" for v in sorted(known)), label,
            )
        return None
    return values[0]


def relative_exposures(exposures: Sequence[Exposure]) -> np.ndarray:
    """Effective exposure time of each frame, in seconds at the first frame's settings.

    ``t * (N0 / N)**2 * (ISO / ISO0) * 10**(gain_db / 20) * 10**(-nd)``, i.e. what
    each frame's shutter time would have been at frame 0's f-number and ISO, 0 dB gain and
    no ND filter. When any frame lacks its f-number (or ISO), that factor is left out
    for all frames.

    Parameters
    ----------
    exposures : sequence of Exposure

    Returns
    -------
    numpy.ndarray
        float64, one value per frame.
    """
    exposures = list(exposures)
    if not exposures:
        return np.zeros(0, dtype=np.float64)
    use_n = _shared_or_none([e.fnumber for e in exposures], "f-number") is not None
    use_iso = _shared_or_none([e.iso for e in exposures], "ISO") is not None
    ref = exposures[0]
    out = np.empty(len(exposures), dtype=np.float64)
    for i, e in enumerate(exposures):
        f = e.factor
        if use_n:
            f *= (ref.fnumber / e.fnumber) ** 2
        if use_iso:
            f *= e.iso / ref.iso
        out[i] = f
    return out


#: Shorter times are written as fractions (``1/250 s``), longer ones as decimals, as
#: cameras show them.
FRACTION_BELOW = 0.3


def format_time(seconds: float) -> str:
    """Exposure time, one format everywhere: ``"1/30 s"``, ``"1/122.5 s"``, ``"0.4 s"``, ``"2 s"``.

    Below :data:`FRACTION_BELOW` seconds a fraction ``1/N`` with N to four significant
    digits (whole from 1000 on), a nominal 1/30 s and a fitted 1/122.5 s alike;
    otherwise seconds to four significant digits.
    """
    s = float(seconds)
    if not math.isfinite(s) or s <= 0:
        return f"{s:g} s"
    if s < FRACTION_BELOW:
        n = 1.0 / s
        return f"1/{n:.0f} s" if n >= 1000 else f"1/{float(f'{n:.4g}'):g} s"
    if abs(s - round(s)) <= 1e-6 * s:
        return f"{round(s)} s"
    return f"{s:.4g} s"


def resolve_exposures(
    paths: Sequence,
    infos: Optional[Sequence[FrameInfo]] = None,
    times: Optional[Sequence[float]] = None,
    times_file: Union[str, os.PathLike, Mapping[str, Exposure], None] = None,
) -> list:
    """Choose each frame's exposure from the given sources and check the set is usable.

    Precedence: ``times`` (the whole exposure: EXIF aperture and ISO are not used), then
    ``times_file``, then each frame's EXIF (ExposureTime, FNumber, ISO), or for a frame
    without EXIF exposure time its entry in an ``image_list.txt`` or ``times.txt``
    beside it (:func:`header_exposures`; one info line per list).

    Parameters
    ----------
    paths : sequence of str or os.PathLike
        The frames of one bracket set.
    infos : sequence of FrameInfo, optional
        Headers of ``paths`` in the same order; needed only for the EXIF source.
    times : sequence of float, optional
        Exposure times in seconds, one per file (from ``--times``).
    times_file : path or mapping, optional
        A times file (see :func:`read_times_file`) or its parsed mapping.

    Returns
    -------
    list of Exposure

    Raises
    ------
    InputError
        Fewer than two frames; a frame missing from the times file or without EXIF
        exposure time; fewer than two distinct effective exposures, an absurd one, or
        one file given twice with different exposures (:func:`check_exposures`).
    UsageError
        ``times`` does not have one entry per file.
    """
    names = [os.fspath(p) for p in paths]
    if len(names) < 2:
        first = names[0] if names else "no input files"
        raise InputError(f"{first}: a bracket set needs at least two exposures")
    if times is not None:
        times = coerce_times(times)
        if len(times) != len(names):
            raise UsageError(
                f"--times: {len(times)} exposure time(s) given for {len(names)} files"
            )
        exposures = []
        for t in times:
            t = float(t)
            if not math.isfinite(t) or t <= 0:
                raise UsageError(f"--times: '{t:g}' is not a positive exposure time")
            exposures.append(Exposure(time=t))
    elif times_file is not None:
        if isinstance(times_file, Mapping):
            table, source = times_file, "the times file"
        else:
            table, source = read_times_file(times_file, names), os.fspath(times_file)
        exposures = []
        for n in names:
            key = os.path.basename(n)
            if key not in table:
                raise InputError(f"{n}: not listed in {source}")
            e = table[key]
            exposures.append(Exposure(e.time, e.fnumber, e.iso, e.gain_db, e.nd))
    else:
        if infos is None or len(infos) != len(names):
            raise ValueError("resolve_exposures needs one FrameInfo per path for EXIF")
        exposures, used = header_exposures(names, infos)
        for u in used:
            logger.info("%s: exposures of the frames it lists (they carry no EXIF exposure time)", u)
        for n, e in zip(names, exposures):
            if e is None:
                beside = list_in(os.path.dirname(os.path.abspath(n)))
                raise InputError(f"{n}: no exposure time in EXIF; give --times or --times-file"
                                 + (f" (not listed in {beside})" if beside else ""))
    rel = relative_exposures(exposures)
    for n, r in zip(names, rel):
        if not (math.isfinite(r) and r > 0):
            raise InputError(f"{n}: its exposure ({exposures[names.index(n)].time:g} s with the "
                             "aperture, ISO, gain and ND given) is out of range")
    check_exposures(names, rel)
    return exposures


#: Relative exposures outside this range (seconds) are taken for a typing or metadata
#: error: radiance computed from them leaves the float range (an all-zero map).
TIME_RANGE = (1e-9, 1e7)


def check_exposures(names: Sequence[str], rel: Sequence[float]) -> list:
    """Check a set's effective exposures; return the groups of frames that share one.

    Frames with the same effective exposure (an auto-ISO ladder: 4 s at ISO 2500 and
    2 s at ISO 5000; a phone repeating an exposure) are merged like any other: they add
    no range but average noise down. The set is refused only when fewer than two
    distinct exposures remain, or an exposure is absurd.

    Parameters
    ----------
    names : sequence of str
        The frames, for messages.
    rel : sequence of float
        Effective exposure of each frame (seconds).

    Returns
    -------
    list of list of int
        Groups (two or more frames) at the same exposure, in frame order.

    Raises
    ------
    InputError
        Fewer than two distinct exposures; an exposure outside :data:`TIME_RANGE`.
    """
    rel = np.asarray(rel, np.float64)
    for n, r in zip(names, rel):
        if not (TIME_RANGE[0] <= r <= TIME_RANGE[1]):
            raise InputError(
                f"{n}: effective exposure {r:g} s is outside {TIME_RANGE[0]:g}..{TIME_RANGE[1]:g} s; "
                "check the times, ND and gain values"
            )
    seen = {}
    for i, n in enumerate(names):
        key = os.path.realpath(n) if os.path.exists(n) else None
        if key is not None:
            seen.setdefault(key, []).append(i)
    for idx in seen.values():
        if len(idx) > 1:
            if np.ptp(rel[idx]) > SAME_EXPOSURE_RTOL * rel[idx].max():
                raise InputError(
                    f"{names[idx[0]]}: the same file is given {len(idx)} times with different exposures "
                    f"({', '.join(format_time(rel[j]) for j in idx)})"
                )
            logger.warning("%s: the same file is given %d times; the copies add no information",
                           names[idx[0]], len(idx))
    groups = []
    assigned = [False] * len(rel)
    for i in range(len(rel)):
        if assigned[i]:
            continue
        group = [j for j in range(i, len(rel)) if not assigned[j]
                 and abs(rel[j] - rel[i]) <= SAME_EXPOSURE_RTOL * max(rel[i], rel[j])]
        for j in group:
            assigned[j] = True
        if len(group) > 1:
            groups.append(group)
    distinct = len(rel) - sum(len(g) - 1 for g in groups)
    if distinct < 2:
        raise InputError(
            f"{names[0]}: all {len(rel)} frames have the same exposure ({format_time(rel[0])}); "
            "a bracket needs at least two different exposures"
        )
    for g in groups:
        logger.info("%s share one exposure (%s); they are fused together",
                    ", ".join(os.path.basename(names[j]) for j in g), format_time(rel[g[0]]))
    return groups
