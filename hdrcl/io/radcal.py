"""Readers of the three Radiance ``.cal`` files of a luminance-map chain (Pierson et al.
2019; radiantlab's HDRICalibrationTool), and of the same values given inline.

The files are read in Radiance's ``.cal`` language as ``pcomb -f`` reads it
(:mod:`hdrcl.io.calexpr`: definitions, functions such as the lab's ``sq(x)=x*x;``,
nested comments, ``xres/2``, any parenthesising) and must define ``ro``, ``go``, ``bo``
as a factor times their own channel (``ro = f(x, y) * ri(1)``), checked by evaluating
the file:

* **vignetting**: the factor depends on the pixel position (``x``, ``y`` as pcomb:
  column and row of the cropped, resized map, ``y = 0`` the bottom row); the factor map
  is the file evaluated on the map (:meth:`Vignetting.factors`). The centre and radius
  constants the file compares ``x``, ``y`` with (``x-500``, ``/500``) are compared with
  the map's: a file made for another size is warned about.
* **neutral density**: one factor per channel (``ro=KR*ri(1); go=KG*gi(1); bo=KB*bi(1);``,
  identity ``ro=ri(1); ...`` too).
* **calibration factor**: the same factor for the three channels.

A file outside the language, or whose outputs are not such factors, is refused with one
line naming the file (and for the language the line and token), exit code 3.

Inline values (the command-line options accept either a file or numbers):

* ``--vignetting A1,...,A8``: the coefficients of ``r^1 .. r^8`` in that order
  (ascending powers, fewer allowed), constant 1, centre and radius those of the
  output picture (``N/2``).
* ``--nd-filter KR,KG,KB`` (or one K for all three).
* ``--calibration-factor K``.

:func:`check_factor_range` range-checks the factors against what the output format can
hold (luminances of :data:`SCENE_RANGE` times the factors must stay normal numbers).
"""
from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass
from typing import Dict, Optional, Tuple

import numpy as np

from hdrcl.errors import InputError, UsageError
from hdrcl.io import calexpr

logger = logging.getLogger(__name__)

__all__ = ["Vignetting", "RadialProjection", "read_projection", "read_vignetting", "read_nd_filter", "read_calibration_factor",
           "vignetting_option", "nd_filter_option", "calibration_factor_option", "check_factor_range",
           "calibration_factor_text", "write_calibration_factor",
           "SCENE_RANGE", "geometry_constants"]

MAX_POWER = 8
#: Luminances (cd/m^2) a calibrated map must be able to hold: starlit ground to above the sun's disc.
SCENE_RANGE = (1e-6, 1e10)
#: Smallest normal and largest finite value per output extension (RGBE: its exponent byte;
#: half EXR is checked by the writer, which falls back to float for a luminance map).
FORMAT_RANGE = {".hdr": (2.0 ** -126, 1.7e38), ".pic": (2.0 ** -126, 1.7e38), ".rgbe": (2.0 ** -126, 1.7e38)}
FLOAT32_RANGE = (float(np.finfo(np.float32).tiny), float(np.finfo(np.float32).max))
_OUT = (("ro", "ri"), ("go", "gi"), ("bo", "bi"))
_PROBE = (2.0, 3.0, 5.0)


@dataclass(frozen=True)
class Vignetting:
    """A vignetting correction: inline ``sf = 1 / (a0 + a1 r + ... + a8 r^8)``,
    ``r = |(x, y) - (xc, yc)| / radius`` (``coefficients``), or a ``.cal`` file
    (``program``, with the geometry constants it was found to use, None where it has none).

    ``xc``, ``yc``, ``radius`` None for inline values: the output picture's centre and half width."""

    coefficients: Optional[Tuple[float, ...]]  # a0, a1, ..., a8; None for a file
    xc: Optional[float] = None
    yc: Optional[float] = None
    radius: Optional[float] = None
    source: str = "inline"
    program: Optional[calexpr.CalProgram] = None

    def factors(self, n: int) -> np.ndarray:
        """``(N, N, 3)`` multipliers of the file on an ``N x N`` map (float64; non-finite
        values are left for the caller to judge)."""
        return _factor_map(self.program, self.source, n, n, "vignetting")

    def check_geometry(self, n: int) -> Optional[str]:
        """A warning when the file's centre/radius constants are not the ``N x N`` map's."""
        if self.program is None:
            return None
        half, tol = n / 2.0, max(1.0, 0.01 * n)
        wrong = [(k, v) for k, v in (("centre x", self.xc), ("centre y", self.yc), ("radius", self.radius))
                 if v is not None and abs(v - half) > tol]
        if not wrong:
            return None
        made = 2 * (self.radius if self.radius is not None else (self.xc if self.xc is not None else self.yc))
        return (f"{self.source}: its {', '.join(f'{k} {v:g}' for k, v in wrong)} fit a {made:g}-pixel map, "
                f"not this {n}x{n} one (centre and radius {half:g}): the correction is applied as the file says")


def _factor_map(prog, path: str, xres: int, yres: int, what: str, full: bool = True) -> np.ndarray:
    """The per-channel factors ``ro/ri`` .. of a program on an ``xres x yres`` picture
    (``full``: every pixel; else a 17 x 17 grid across it), checked to be factors: on the
    grid, the outputs for inputs ``(1, 1, 1)`` and :data:`_PROBE` must scale with their
    own channel."""
    for out, _ in _OUT:
        if not (prog.defines(out) or prog.defines("lo")):
            raise InputError(f"{path}: a {what} .cal file must define {out} (as '{out}=K*{out[0]}i(1);')")
    names = [o for o, _ in _OUT]
    gx = np.unique(np.round(np.linspace(0, xres - 1, 17)))[None, :]
    gy = np.unique(np.round(np.linspace(0, yres - 1, 17)))[:, None]
    one = prog.evaluate(names, xres=xres, yres=yres, inputs=(1.0, 1.0, 1.0), x=gx, y=gy)
    probe = prog.evaluate(names, xres=xres, yres=yres, inputs=_PROBE, x=gx, y=gy)
    with np.errstate(all="ignore"):
        for (out, inp), p in zip(_OUT, _PROBE):
            a, b = one[out], probe[out]
            ok = np.isfinite(a) & np.isfinite(b)
            if not np.allclose(b[ok], p * a[ok], rtol=1e-9, atol=0.0):
                raise InputError(f"{path}: not a {what} factor file: {out} must be a factor times {inp}(1) "
                                 f"(as '{out}=K*{inp}(1);'), with no other channel or offset")
    if full:
        one = prog.evaluate(names, xres=xres, yres=yres, inputs=(1.0, 1.0, 1.0))
    return np.stack([one[o] for o, _ in _OUT], axis=-1)


def _not_finite(prog, path: str, what: str, n: int) -> InputError:
    """The error for factors that are not finite numbers, naming the operation that made
    them so (``(-8)^(1/3)`` is NaN in Radiance too: rcalc prints nan), not the position."""
    cause = prog.why_not_finite([o for o, _ in _OUT], xres=n, yres=n, inputs=(1.0, 1.0, 1.0))
    why = f", line {cause.split('line ', 1)[1]}" if cause else ": its factors are not finite numbers"
    noun = what if what.endswith("factor") else f"{what} factor"
    return InputError(f"{path}{why} (Radiance computes the same: rcalc prints nan or inf); the {noun} "
                      f"must be a finite positive number")


def _constant_factors(path: str, what: str) -> Tuple[float, float, float]:
    prog = calexpr.parse_file(path)
    f = _factor_map(prog, path, 8, 8, what, full=False)
    if not np.all(np.isfinite(f)):
        raise _not_finite(prog, path, what, 8)
    if not np.all(f == f[:1, :1]):
        raise InputError(f"{path}: a {what} .cal file is one factor per channel; this one depends on "
                         f"the pixel position (x, y)")
    return tuple(float(v) for v in f[0, 0])


def read_nd_filter(path) -> Tuple[float, float, float]:
    """``(KR, KG, KB)`` of a neutral density .cal file (:class:`InputError` otherwise)."""
    path = os.fspath(path)
    return _positive(_constant_factors(path, "neutral density"), path, "neutral density")


def read_calibration_factor(path) -> float:
    """``K`` of a calibration factor .cal file (the same factor for R, G and B)."""
    path = os.fspath(path)
    k = _positive(_constant_factors(path, "calibration factor"), path, "calibration factor")
    if len(set(k)) != 1:
        raise InputError(f"{path}: a calibration factor .cal file has one K for all channels, not "
                         f"{', '.join(f'{v:g}' for v in k)}")
    return k[0]


def _positive(values, path: str, what: str):
    if not all(0 < v < float("inf") for v in values):
        raise InputError(f"{path}: the {what} factors must be positive, not {', '.join(f'{v:g}' for v in values)}")
    return tuple(values)


def read_vignetting(path) -> Vignetting:
    """The vignetting correction of a .cal file (factors that depend on ``x``, ``y``)."""
    path = os.fspath(path)
    prog = calexpr.parse_file(path)
    geo = geometry_constants(prog)
    probe = int(round(2 * geo["radius"])) if geo.get("radius") and 2 <= 2 * geo["radius"] <= 4096 else 64
    if geo.get("radius") is not None and not geo["radius"] > 0:
        raise InputError(f"{path}: the vignetting radius must be positive, not {geo['radius']:g}")
    f = _factor_map(prog, path, probe, probe, "vignetting", full=False)
    if not np.any(np.isfinite(f)):
        raise _not_finite(prog, path, "vignetting", probe)
    if np.all(f == f[:1, :1]):
        raise InputError(f"{path}: not a vignetting .cal file: its factors do not depend on the pixel "
                         f"position (x, y) (a neutral density or calibration factor file?)")
    return Vignetting(None, geo.get("xc"), geo.get("yc"), geo.get("radius"), source=path, program=prog)


@dataclass(frozen=True)
class RadialProjection:
    """A user projection: Radiance's ``fisheye_corr.cal`` convention, ``rad(r)`` the
    corrected (output, equidistant) radius of a pixel at radius ``r`` of the input, radii
    in units of the picture's width (the view's edge at 0.5); ``map_inverse > 0`` says the
    file's ``rad`` is the inverse (output radius -> input radius)."""

    source: str
    program: calexpr.CalProgram
    inverse: bool

    def source_radius(self, rd: np.ndarray) -> np.ndarray:
        """The input radius an output pixel at radius ``rd`` takes: ``rad(rd)`` for an
        inverse file; else the exact inverse of ``rad`` where it rises over 0..0.5
        (a table of 4097 radii, linear between them), otherwise Radiance's own
        approximation ``2 rd - rad(rd)`` (fisheye_corr.cal's ``x + (x - xc)(1 - rmult)``)."""
        rd = np.asarray(rd, np.float64)
        if self.inverse:
            return calexpr.call_function(self.program, "rad", rd)
        r = np.linspace(0.0, 0.5, 4097)
        f = calexpr.call_function(self.program, "rad", r)
        if np.all(np.isfinite(f)) and np.all(np.diff(f) > 0):
            return np.interp(rd, f, r, right=np.nan)
        return 2.0 * rd - calexpr.call_function(self.program, "rad", rd)

    def describe(self) -> dict:
        return {"source": self.source, "program": self.program.canonical(), "inverse": self.inverse}


def read_projection(path) -> RadialProjection:
    """A ``--fisheye-projection FILE.cal``: Radiance's ``fisheye_corr.cal`` itself (its
    ``rad(r)``, default ``mapsolid``), or a file that defines ``rad(r)`` (and optionally
    ``map_inverse``). The radii the map needs (0..0.5) must map to finite radii."""
    path = os.fspath(path)
    prog = calexpr.parse_file(path)
    d = prog.definitions.get("rad")
    if d is None or not d.is_function or len(d.params) != 1:
        raise InputError(f"{path}: a projection .cal file defines rad(r) (Radiance's fisheye_corr.cal: the "
                         f"corrected radius of radius r, 0..0.5 of the picture's width)")
    inverse = False
    if prog.defines("map_inverse"):
        inverse = bool(prog.evaluate(["map_inverse"], xres=1, yres=1)["map_inverse"].ravel()[0] > 0)
    proj = RadialProjection(path, prog, inverse)
    rs = proj.source_radius(np.linspace(0.0, 0.5, 257))
    if not np.all(np.isfinite(rs[:-1])) or np.any(rs[:-1] < 0):
        raise InputError(f"{path}: rad(r) does not give a finite, non-negative radius for every r in 0..0.5")
    return proj


def geometry_constants(prog: calexpr.CalProgram) -> Dict[str, float]:
    """The constants a file compares pixel positions with: ``xc`` of ``x - C``, ``yc`` of
    ``y - C`` and ``radius`` of ``... / R`` over an expression of ``x`` and ``y``
    (None where the file has none or writes them with ``xres``/``yres``)."""
    found: Dict[str, Optional[float]] = {}

    def constant(node) -> Optional[float]:
        """The value of a subexpression of numbers and + - * / alone, else None."""
        if node.kind == "num":
            return float(node.value)
        if node.kind == "neg":
            v = constant(node.kids[0])
            return None if v is None else -v
        if node.kind in ("+", "-", "*", "/"):
            a, b = constant(node.kids[0]), constant(node.kids[1])
            if a is None or b is None or (node.kind == "/" and b == 0):
                return None if node.kind != "/" or a is None or b is None else 0.0
            return {"+": a + b, "-": a - b, "*": a * b, "/": a / b if b else 0.0}[node.kind]
        return None

    def uses_xy(node, seen) -> bool:
        if node.kind == "var":
            if node.value in ("x", "y"):
                return True
            d = prog.definitions.get(node.value)
            if d is not None and node.value not in seen:
                return uses_xy(d.body, seen | {node.value})
        return any(uses_xy(k, seen) for k in node.kids)

    def walk(node) -> None:
        if node.kind == "-" and node.kids[0].kind == "var" and constant(node.kids[1]) is not None:
            name = {"x": "xc", "y": "yc"}.get(node.kids[0].value)
            if name:
                found.setdefault(name, constant(node.kids[1]))
        if node.kind == "/" and constant(node.kids[1]) is not None and uses_xy(node.kids[0], frozenset()):
            found.setdefault("radius", constant(node.kids[1]))
        for k in node.kids:
            walk(k)

    try:
        for d in prog.definitions.values():
            walk(d.body)
    except RecursionError:  # definitions chained thousands deep: no geometry to compare
        return {}
    return found


def calibration_factor_text(k: float, comment: str = "") -> str:
    """A calibration factor ``.cal`` in the lab's own form (HDRICalibrationTool's
    ``CF_*.cal``: ``ro=ri(1)*K; go=gi(1)*K; bo=bi(1)*K;`` one per line), which ``pcomb -f``
    and :func:`read_calibration_factor` read; ``comment`` goes first as ``{ ... }``."""
    k = float(k)
    if not (k > 0 and math.isfinite(k)):
        raise UsageError(f"calibration factor: expected a positive finite factor, not {k:g}")
    clean = " ".join(str(comment).replace("{", "(").replace("}", ")").split())
    head = f"{{ {clean} }}\n" if clean else ""
    return head + "".join(f"{o}={i}(1)*{k:.6g};\n" for o, i in _OUT)


def write_calibration_factor(path, k: float, comment: str = "") -> None:
    """Write :func:`calibration_factor_text` to ``path``, atomically."""
    from hdrcl.io.atomic import write_text

    write_text(os.fspath(path), calibration_factor_text(k, comment))


def check_factor_range(factor: float, flag: str = "--calibration-factor", output=None) -> float:
    """``factor`` (the calibration factor, or its product with the ND factors) refused
    with :class:`UsageError` naming ``flag`` when luminances of :data:`SCENE_RANGE` times
    it are not normal finite numbers of the output's format (``output``: a path or an
    extension; None: float32, what every format hdrcl writes a luminance map in holds at
    most). Checked before anything is decoded."""
    ext = os.path.splitext(os.fspath(output))[1].lower() if output is not None and \
        os.path.splitext(os.fspath(output))[1] else (str(output).lower() if output else "")
    lo, hi = FORMAT_RANGE.get(ext, FLOAT32_RANGE)
    scale = 1.0 / 179.0 if ext in FORMAT_RANGE else 1.0  # .hdr stores cd/m^2 / 179
    f = float(factor)
    if not (math.isfinite(f) and f > 0 and SCENE_RANGE[0] * f * scale >= lo and SCENE_RANGE[1] * f * scale <= hi):
        where = f"a {ext} file" if ext else "a float32 map"
        raise UsageError(f"{flag}: a factor of {f:g} puts luminances of {SCENE_RANGE[0]:g}..{SCENE_RANGE[1]:g} "
                         f"cd/m2 outside what {where} holds ({lo:.3g}..{hi:.3g})")
    return f


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
        return check_factor_range(read_calibration_factor(_check_file(os.fspath(value), flag)), flag)
    k = _numbers(value, flag, (1,), "K") if isinstance(value, str) else (float(value),)
    if not 0 < k[0] < float("inf"):
        raise UsageError(f"{flag}: expected a positive factor K, not '{value}'")
    return check_factor_range(k[0], flag)
