"""Exposure information of photographs: EXIF fields, exposure lists, relative exposure.

:class:`FrameInfo` is what :func:`hdrcl.io.frames.read_info` reads from a file's header.
:class:`Exposure` is one frame's exposure settings, from ``--times``, a times file or
EXIF; :func:`resolve_exposures` chooses among those sources and
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

from hdrcl.errors import InputError, UsageError, check_regular

logger = logging.getLogger(__name__)

__all__ = [
    "FrameInfo",
    "Exposure",
    "parse_times",
    "read_times_file",
    "relative_exposures",
    "resolve_exposures",
    "format_time",
    "check_exposures",
    "EXPOSURE_LISTS",
    "header_exposures",
]

#: Exposure lists looked for beside frames that carry no EXIF exposure time, in this
#: order of preference (``merge``, ``calibrate``, ``scan`` and ``batch`` alike).
EXPOSURE_LISTS = ("image_list.txt", "times.txt")

# Two exposures whose effective times differ by less than this fraction (0.0014 stops)
# are the same exposure: they add no range, but they are fused (less noise).
SAME_EXPOSURE_RTOL = 1e-3


@dataclass
class FrameInfo:
    """What one photograph's header says, read without decoding its pixels.

    Attributes are ``None`` where the file does not carry the field.
    ``capture_time`` joins DateTimeOriginal and SubSecTimeOriginal (naive local time).
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
    extra: dict = field(default_factory=dict)


@dataclass
class Exposure:
    """One frame's exposure settings.

    Attributes
    ----------
    time : float
        Shutter time in seconds (> 0).
    fnumber : float, optional
        Aperture f-number; ``None`` when unknown.
    iso : float, optional
        Sensitivity; ``None`` when unknown.
    gain_db : float
        Extra amplification in decibels (amplitude: ``10 ** (gain_db / 20)``), as in
        HDRShop image lists.
    nd : float
        Neutral-density filtering as optical density: the filter transmits
        ``10 ** -nd`` of the light (ND 0.3 is one stop). HDRShop's ``ND_filters`` column
        is read with this meaning.
    """

    time: float
    fnumber: Optional[float] = None
    iso: Optional[float] = None
    gain_db: float = 0.0
    nd: float = 0.0

    @property
    def factor(self) -> float:
        """Exposure relative to a 1 s frame with no gain and no filter, ignoring
        aperture and ISO: ``time * 10**(gain_db/20) * 10**(-nd)``."""
        return self.time * 10.0 ** (self.gain_db / 20.0) * 10.0 ** (-self.nd)

    def relative_to(self, reference: "Exposure") -> float:
        """Effective exposure time in seconds as if shot at ``reference``'s f-number
        and ISO with 0 dB gain and no ND filter.

        ``time * (N_ref / N)**2 * (ISO / ISO_ref) * 10**(gain_db/20) * 10**(-nd)``; the
        aperture (or ISO) term is left out when either frame lacks that value.
        """
        f = self.factor
        if self.fnumber and reference.fnumber:
            f *= (reference.fnumber / self.fnumber) ** 2
        if self.iso and reference.iso:
            f *= self.iso / reference.iso
        return f


#: Largest gain (dB) and neutral density a times file may give; beyond them the
#: exposure factor leaves the range of a float.
MAX_GAIN_DB = 200.0
MAX_ND = 30.0


def _parse_seconds(text: str) -> Optional[float]:
    """``"1/30"``, ``"0.5"`` or ``"2"`` as seconds; None when not a positive finite time."""
    text = text.strip()
    try:
        if "/" in text:
            num, den = text.split("/", 1)
            value = float(num) / float(den)
        else:
            value = float(text)
    except (ValueError, ZeroDivisionError):
        return None
    if not math.isfinite(value) or value <= 0:
        return None
    return value


def parse_times(text: str, name: str = "--times") -> list:
    """Parse a comma-separated list of exposure times in seconds.

    Parameters
    ----------
    text : str
        For example ``"1/30,0.5,2"``: fractions, decimals or integers; spaces allowed.
    name : str
        The option or parameter the text came from, for messages (``--time``, ``times``).

    Returns
    -------
    list of float

    Raises
    ------
    UsageError
        An entry is empty, not a number, zero, negative, infinite or NaN.
    """
    items = [t.strip() for t in str(text).split(",")]
    if not any(items):
        raise UsageError(f"{name}: no exposure times given")
    out = []
    for item in items:
        value = _parse_seconds(item)
        if value is None:
            raise UsageError(f"{name}: '{_clip(item)}' is not a positive exposure time")
        out.append(value)
    return out


def _clip(text: str, n: int = 40) -> str:
    text = "".join(ch if ch.isprintable() else "?" for ch in str(text))
    return text if len(text) <= n else text[: n - 3] + "..."


def coerce_times(times, name: str = "--times") -> list:
    """Exposure times as floats from what a caller may give: numbers, strings such as
    ``"1/30"`` (one per frame), or one comma-separated string ``"1/30,1/60"``.

    Raises
    ------
    UsageError
        An entry is not a positive, finite number of seconds (the message names ``name``).
    """
    if isinstance(times, (str, bytes)):
        return parse_times(times.decode() if isinstance(times, bytes) else times, name)
    if isinstance(times, (Mapping, set, frozenset)):  # keys, or no order: never one time per frame
        from hdrcl.errors import ParameterTypeError

        raise ParameterTypeError(f"{name}: expected a list of exposure times, one per image in their order, "
                                 f"not a {type(times).__name__}")
    try:
        items = list(times)
    except TypeError:
        raise UsageError(f"{name}: expected a list of exposure times, not {type(times).__name__}") from None
    out = []
    for t in items:
        if isinstance(t, str):
            value = _parse_seconds(t)
        elif isinstance(t, bool):
            value = None
        else:
            try:
                value = float(t)
            except (TypeError, ValueError):
                value = None
            if value is not None and (not math.isfinite(value) or value <= 0):
                value = None
        if value is None:
            raise UsageError(f"{name}: '{_clip(t)}' is not a positive exposure time")
        out.append(value)
    return out


def _float_field(text: str) -> Optional[float]:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def read_times_file(path) -> dict:
    """Read a list of exposures, one file per line.

    Two layouts are recognised line by line:

    * ``file seconds`` where seconds may be a fraction (``IMG_1.JPG 1/30``);
    * HDRShop image lists, ``file exposure 1/shutter_speed f/stop gain(db) ND_filters``
      (trailing columns may be left out). The ``exposure`` column is the shutter time in
      seconds (the Memorial Church list runs from 32 down to 1/1024 with ``1/shutter``
      its reciprocal); it is used as the time, the f-stop, gain and ND as given.

    ``#`` starts a comment; blank lines are skipped.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    dict of str to Exposure
        Keyed by the file's base name.

    Raises
    ------
    InputError
        The file cannot be read, a line is malformed (or its time not positive), or a file is listed twice.
    """
    name = os.fspath(path)
    check_regular(name, "times file")  # a FIFO or a device would block or never end
    try:
        with open(name, encoding="utf-8-sig") as fh:
            lines = fh.read().splitlines()
    except FileNotFoundError:
        raise InputError(f"{name}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{name}: cannot read times file ({exc})") from None
    result = {}
    where = {}
    inconsistent = []
    for lineno, raw in enumerate(lines, 1):
        fields = raw.split("#", 1)[0].split()
        if not fields:
            continue
        bad = InputError(f"{name} line {lineno}: expected 'file seconds' or HDRShop columns")
        if len(fields) < 2 or len(fields) > 6:
            raise bad
        seconds = _parse_seconds(fields[1])
        if seconds is None and _float_field(fields[1]) is not None:  # a number, but no exposure: -2, 0
            raise InputError(f"{name} line {lineno}: {fields[0]}: exposure time {fields[1]} s is not a positive time")
        if seconds is None:
            raise bad
        exposure = Exposure(time=seconds)
        if len(fields) >= 3:
            extra = [_float_field(f) for f in fields[2:]]
            if any(v is None for v in extra):
                raise bad
            inverse = extra[0]
            if inverse <= 0:
                raise bad
            if abs(seconds * inverse - 1.0) > 0.01:
                inconsistent.append(lineno)
            if len(extra) >= 2:
                if extra[1] <= 0:
                    raise bad
                exposure.fnumber = extra[1]
            if len(extra) >= 3:
                if abs(extra[2]) > MAX_GAIN_DB:
                    raise InputError(f"{name} line {lineno}: gain {extra[2]:g} dB is out of range "
                                     f"(at most {MAX_GAIN_DB:g} dB either way)")
                exposure.gain_db = extra[2]
            if len(extra) >= 4:
                if extra[3] < 0 or extra[3] > MAX_ND:
                    raise InputError(f"{name} line {lineno}: ND density {extra[3]:g} is out of range "
                                     f"(0 to {MAX_ND:g})")
                exposure.nd = extra[3]
        key = os.path.basename(fields[0])
        if key in result:
            raise InputError(
                f"{name} line {lineno}: {key} is already listed on line {where[key]}"
            )
        result[key] = exposure
        where[key] = lineno
    if inconsistent:
        # Some HDRShop lists carry relative exposures in column 2; column 2 still wins.
        logger.warning(
            "%s: the exposure and 1/shutter_speed columns disagree on line(s) %s; "
            "using the exposure column as seconds",
            name, ", ".join(map(str, inconsistent)),
        )
    if not result:
        raise InputError(f"{name}: no exposures listed")
    return result


def _has_time(info) -> bool:
    t = info.exposure_time
    return t is not None and math.isfinite(t) and t > 0


def _list_in(folder: str) -> Optional[str]:
    for name in EXPOSURE_LISTS:
        candidate = os.path.join(folder, name)
        if os.path.isfile(candidate):
            return candidate
    return None


def header_exposures(paths, infos) -> Tuple[list, List[str]]:
    """Each frame's exposure from its header, or from the exposure list beside it.

    A frame with an EXIF exposure time keeps it (with its f-number and ISO); one
    without takes its entry in the first of :data:`EXPOSURE_LISTS` in its own folder
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
            found = _list_in(folder)
            tables[folder] = (found, read_times_file(found) if found else {})
        found, table = tables[folder]
        e = table.get(os.path.basename(os.fspath(n)))
        if e is not None and found not in used:
            used.append(found)
        out.append(None if e is None else Exposure(e.time, info.fnumber or e.fnumber, info.iso, e.gain_db, e.nd))
    return out, used


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
            table, source = read_times_file(times_file), os.fspath(times_file)
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
                beside = _list_in(os.path.dirname(os.path.abspath(n)))
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
