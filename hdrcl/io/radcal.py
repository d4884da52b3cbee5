"""Readers of the three Radiance ``.cal`` files of a luminance-map chain (Pierson et al.
2019; radiantlab's HDRICalibrationTool), and of the same values given inline.

Exactly three forms are understood; anything else is refused with one line naming the
file and what was expected (there is no general ``calc`` language here):

* **vignetting** ``r = sqrt(sq(x-XC)+sq(y-YC))/RADIUS; sf = 1/(a8*r^8 + ... + a1*r + 1);
  ro = sf*ri(1); go = sf*gi(1); bo = sf*bi(1);``. Terms of the polynomial may come in
  any order, any subset of powers 1..8 may be present, the constant must be there.
  ``x``, ``y`` are pixel positions in the cropped, resized picture (Radiance: ``y`` counts
  from the bottom row).
* **neutral density** ``ro=KR*ri(1); go=KG*gi(1); bo=KB*bi(1);`` (or ``ri(1)*KR``).
* **calibration factor** ``ro=ri(1)*K; go=gi(1)*K; bo=bi(1)*K;`` (the same K thrice).

Numbers may be written as Radiance does (``1.2e-3``, ``.5``, a leading sign), spaces and
line breaks are free, Radiance comments ``{...}`` are ignored.

Inline values (the command-line options accept either a file or numbers):

* ``--vignetting A1,...,A8``: the coefficients of ``r^1 .. r^8`` in that order
  (ascending powers, fewer allowed), constant 1, centre and radius those of the
  output picture (``N/2``).
* ``--nd-filter KR,KG,KB`` (or one K for all three).
* ``--calibration-factor K``.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass
from typing import Optional, Tuple

from hdrcl.errors import InputError, UsageError

__all__ = ["Vignetting", "read_vignetting", "read_nd_filter", "read_calibration_factor",
           "vignetting_option", "nd_filter_option", "calibration_factor_option"]

NUM = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_N = f"({NUM})"
MAX_POWER = 8


@dataclass(frozen=True)
class Vignetting:
    """``sf = 1 / (a0 + a1 r + ... + a8 r^8)``, ``r = |(x, y) - (xc, yc)| / radius``.

    ``xc``, ``yc``, ``radius`` None: the output picture's centre and half width."""

    coefficients: Tuple[float, ...]  # a0, a1, ..., a8
    xc: Optional[float] = None
    yc: Optional[float] = None
    radius: Optional[float] = None
    source: str = "inline"


def _text(path: str, what: str) -> str:
    try:
        with open(path, "r", encoding="utf-8-sig") as f:
            text = f.read(1 << 16)
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text {what} .cal file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    text = re.sub(r"\{[^{}]*\}", " ", text)  # Radiance comments (not nested)
    if "{" in text or "}" in text:
        raise InputError(f"{path}: unbalanced comment braces in the {what} .cal file")
    return "".join(text.split())


def _statements(text: str) -> list:
    return [s for s in text.split(";") if s]


def _refuse(path: str, what: str, expected: str):
    raise InputError(f"{path}: not a {what} .cal file of the form '{expected}'")


def _channel(stmt: str, out: str, inp: str) -> Optional[float]:
    """The factor K of ``out=K*inp(1)`` or ``out=inp(1)*K``, else None."""
    m = re.fullmatch(rf"{out}=(?:{_N}\*{inp}\(1\)|{inp}\(1\)\*{_N})", stmt)
    if not m:
        return None
    return float(m.group(1) if m.group(1) is not None else m.group(2))


def _factors(path: str, what: str, expected: str) -> Tuple[float, float, float]:
    stmts = _statements(_text(path, what))
    if len(stmts) != 3:
        _refuse(path, what, expected)
    got = [_channel(s, o, i) for s, (o, i) in zip(stmts, (("ro", "ri"), ("go", "gi"), ("bo", "bi")))]
    if any(v is None for v in got):
        _refuse(path, what, expected)
    return tuple(got)


ND_FORM = "ro=KR*ri(1); go=KG*gi(1); bo=KB*bi(1);"
K_FORM = "ro=ri(1)*K; go=gi(1)*K; bo=bi(1)*K;"
VIG_FORM = ("r = sqrt(sq(x-XC)+sq(y-YC))/RADIUS; sf = 1/(a8*r^8 + ... + a1*r + 1); "
            "ro = sf*ri(1); go = sf*gi(1); bo = sf*bi(1);")


def read_nd_filter(path) -> Tuple[float, float, float]:
    """``(KR, KG, KB)`` of a neutral density .cal file (:class:`InputError` otherwise)."""
    path = os.fspath(path)
    return _positive(_factors(path, "neutral density", ND_FORM), path, "neutral density")


def read_calibration_factor(path) -> float:
    """``K`` of a calibration factor .cal file (the same factor for R, G and B)."""
    path = os.fspath(path)
    k = _positive(_factors(path, "calibration factor", K_FORM), path, "calibration factor")
    if len(set(k)) != 1:
        raise InputError(f"{path}: a calibration factor .cal file has one K for all channels, not {k}")
    return k[0]


def _positive(values, path: str, what: str):
    if not all(0 < v < float("inf") for v in values):
        raise InputError(f"{path}: the {what} factors must be positive, not {', '.join(f'{v:g}' for v in values)}")
    return tuple(values)


_U = r"(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"  # an unsigned number
_TERM = re.compile(rf"([+-]{{0,2}})(?:(?:({_U})\*)?r(?:\^(\d+))?|({_U}))")  # "+ -0.1*r^2" too


def _poly(expr: str, path: str) -> Tuple[float, ...]:
    """Coefficients a0..a8 of a sum of terms ``c*r^k``, ``c*r``, ``r^k``, ``r`` and ``c``."""
    coeffs = [0.0] * (MAX_POWER + 1)
    seen, pos = set(), 0
    while pos < len(expr):
        m = _TERM.match(expr, pos)
        if not m or m.end() == pos or (pos > 0 and not m.group(1)):
            _refuse(path, "vignetting", VIG_FORM)
        sign, factor, power, constant = m.groups()
        if constant is not None:
            k, value = 0, float(constant)
        else:
            k, value = (int(power) if power else 1), (float(factor) if factor else 1.0)
        if k > MAX_POWER or k in seen:
            _refuse(path, "vignetting", VIG_FORM)
        seen.add(k)
        coeffs[k] = -value if sign.count("-") % 2 else value
        pos = m.end()
    if 0 not in seen:
        _refuse(path, "vignetting", VIG_FORM)
    return tuple(coeffs)


def read_vignetting(path) -> Vignetting:
    """The vignetting correction of a .cal file of the form :data:`VIG_FORM`."""
    path = os.fspath(path)
    stmts = _statements(_text(path, "vignetting"))
    if len(stmts) != 5:
        _refuse(path, "vignetting", VIG_FORM)
    m = re.fullmatch(rf"r=sqrt\(sq\(x-{_N}\)\+sq\(y-{_N}\)\)/{_N}", stmts[0])
    s = re.fullmatch(r"sf=1/\((.+)\)", stmts[1])
    tail = [re.fullmatch(rf"{o}=(?:sf\*{i}\(1\)|{i}\(1\)\*sf)", t)
            for t, (o, i) in zip(stmts[2:], (("ro", "ri"), ("go", "gi"), ("bo", "bi")))]
    if not m or not s or not all(tail):
        _refuse(path, "vignetting", VIG_FORM)
    xc, yc, radius = (float(v) for v in m.groups())
    if not radius > 0:
        raise InputError(f"{path}: the vignetting RADIUS must be positive, not {radius:g}")
    return Vignetting(_poly(s.group(1), path), xc, yc, radius, source=path)


def _numbers(text: str, flag: str, counts, what: str) -> Tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) not in counts or not all(abs(v) < float("inf") for v in values):
        raise UsageError(f"{flag}: expected a .cal file or {what}, not '{text}'")
    return values


def _is_file_arg(value) -> bool:
    return isinstance(value, os.PathLike) or (isinstance(value, str) and value.strip().lower().endswith(".cal"))


def _check_file(path: str, flag: str) -> str:
    if not os.path.isfile(path):
        raise InputError(f"{path}: no such file ({flag})")
    return path


def vignetting_option(value, flag: str = "--vignetting") -> Vignetting:
    """``--vignetting FILE.cal|A1,...,A8`` (or a :class:`Vignetting`, or a sequence)."""
    if isinstance(value, Vignetting):
        return value
    if _is_file_arg(value):
        return read_vignetting(_check_file(os.fspath(value), flag))
    if isinstance(value, str):
        a = _numbers(value, flag, range(1, MAX_POWER + 1), "A1,...,A8 (coefficients of r^1..r^8)")
    else:
        a = tuple(float(v) for v in value)
        if not 1 <= len(a) <= MAX_POWER:
            raise UsageError(f"{flag}: expected 1 to {MAX_POWER} coefficients (r^1..r^8), not {len(a)}")
    return Vignetting((1.0,) + a + (0.0,) * (MAX_POWER - len(a)))


def nd_filter_option(value, flag: str = "--nd-filter") -> Tuple[float, float, float]:
    """``--nd-filter FILE.cal|KR,KG,KB|K`` -> per-channel factors (positive)."""
    if _is_file_arg(value):
        return read_nd_filter(_check_file(os.fspath(value), flag))
    k = _numbers(value, flag, (1, 3), "KR,KG,KB") if isinstance(value, str) else tuple(
        float(v) for v in (value if hasattr(value, "__len__") else [value]))
    if len(k) == 1:
        k = k * 3
    if len(k) != 3 or not all(0 < v < float("inf") for v in k):
        raise UsageError(f"{flag}: expected three positive factors KR,KG,KB, not '{value}'")
    return k


def calibration_factor_option(value, flag: str = "--calibration-factor") -> float:
    """``--calibration-factor FILE.cal|K`` -> K (positive)."""
    if _is_file_arg(value):
        return read_calibration_factor(_check_file(os.fspath(value), flag))
    k = _numbers(value, flag, (1,), "K") if isinstance(value, str) else (float(value),)
    if not 0 < k[0] < float("inf"):
        raise UsageError(f"{flag}: expected a positive factor K, not '{value}'")
    return k[0]
