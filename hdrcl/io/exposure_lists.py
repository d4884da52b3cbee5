"""Exposures as people give them: one frame's settings (:class:`Exposure`), exposure
times on the command line or from Python (``"1/30,0.5,2"``, numbers, strings), and
exposure lists beside the frames (``image_list.txt`` in HDRShop's columns, ``times.txt``).

This module does not import OpenImageIO.
"""
from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass
from typing import Mapping, Optional

from hdrcl.errors import InputError, UsageError, check_regular

logger = logging.getLogger("hdrcl.io.metadata")

__all__ = ["Exposure", "EXPOSURE_LISTS", "MAX_GAIN_DB", "MAX_ND", "coerce_times", "list_in", "parse_seconds",
           "parse_times", "read_times_file"]

#: Exposure lists looked for beside frames that carry no EXIF exposure time, in this
#: order of preference (``merge``, ``calibrate``, ``scan`` and ``batch`` alike).
EXPOSURE_LISTS = ("image_list.txt", "times.txt")


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


def parse_seconds(text: str) -> Optional[float]:
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
        value = parse_seconds(item)
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
            value = parse_seconds(t)
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


def read_times_file(path, frames=None) -> dict:
    """Read a list of exposures, one file per line.

    Three layouts are recognised:

    * ``file seconds`` where seconds may be a fraction (``IMG_1.JPG 1/30``);
    * HDRShop image lists, ``file exposure 1/shutter_speed f/stop gain(db) ND_filters``
      (trailing columns may be left out). The ``exposure`` column is the shutter time in
      seconds (the Memorial Church list runs from 32 down to 1/1024 with ``1/shutter``
      its reciprocal); it is used as the time, the f-stop, gain and ND as given;
    * a bare list of times, one a line and nothing else on any line (the Memorial
      download's ``shutter_times.txt``): the times of ``frames`` in name order, when the
      list holds exactly one time per frame.

    ``#`` starts a comment; blank lines are skipped.

    Parameters
    ----------
    path : str or os.PathLike
    frames : sequence of str, optional
        The files a bare list applies to (sorted by base name); without them, or when
        their number differs from the list's, a bare list is refused naming both counts.

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
    bare = _bare_times(name, lines, frames)
    if bare is not None:
        return bare
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
        seconds = parse_seconds(fields[1])
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


def _bare_times(name: str, lines, frames) -> Optional[dict]:
    """A list of times alone (one a line, no file names) as ``{frame: Exposure}`` for
    ``frames`` in name order; None when the list names files."""
    rows = [(k, f[0]) for k, raw in enumerate(lines, 1) if (f := raw.split("#", 1)[0].split())]
    if not rows or any(len(raw.split("#", 1)[0].split()) != 1 for raw in lines if raw.split("#", 1)[0].split()):
        return None
    times = []
    for lineno, text in rows:
        seconds = parse_seconds(text)
        if seconds is None:
            if _float_field(text) is not None:
                raise InputError(f"{name} line {lineno}: exposure time {text} s is not a positive time")
            return None  # a lone word: a file name without its time, refused as such below
        times.append(seconds)
    names = sorted({os.path.basename(os.fspath(f)) for f in (frames or [])})
    if len(names) != len(times):
        frames_text = f"{len(names)} frame(s) to apply it to" if frames else "no frames named to apply it to"
        raise InputError(f"{name}: a bare list of {len(times)} time(s) (no file names) and {frames_text}; "
                         "give one time per frame, or 'file seconds' lines")
    logger.warning("%s: a bare list of %d times, taken for the frames in name order (%s .. %s)",
                name, len(times), names[0], names[-1])
    return {n: Exposure(time=t) for n, t in zip(names, times)}


def list_in(folder: str) -> Optional[str]:
    for name in EXPOSURE_LISTS:
        candidate = os.path.join(folder, name)
        if os.path.isfile(candidate):
            return candidate
    return None


