"""Whether a radiance map fits OpenEXR half floats, and how to make it fit.

Half floats hold values up to 65504 with 11 significant bits down to 2^-14 (6.1e-5);
below that they are subnormal, with a fixed step of 2^-24, and below 2^-25 they are 0.
Values are accepted down to :data:`HALF_FLOOR` = 2^-16 (step 0.4 % of the value, finer
than RGBE's 1 %): about 9.6 decades in all. A radiance map that reaches beyond either end
would be written as ``inf`` or as an underflowed (or coarsely rounded) value.
:func:`plan` decides, from bounds on the values that can occur, whether to write half as
is or float (``--dtype auto``, the default: every tool reads the values as they are), or,
with ``--dtype half``, half rescaled by a power of two (the multiplier is recorded in the
file's metadata as ``hdrcl:halfScale``: stored value = radiance x halfScale).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

HALF_MAX = 65504.0
HALF_MIN_NORMAL = 2.0 ** -14
#: Smallest value written as half without rescaling (subnormal, relative step <= 0.4 %).
HALF_FLOOR = 2.0 ** -16


@dataclass
class HalfPlan:
    """How to store a radiance map.

    Attributes
    ----------
    dtype : str
        ``"half"`` or ``"float"``.
    scale : float
        Power of two the radiance is multiplied by before writing (1.0: unchanged).
    message : str or None
        What was decided and why, for the user; None when nothing had to change.
    """

    dtype: str
    scale: float = 1.0
    message: Optional[str] = None


def plan(lo: float, hi: float, dtype: str = "auto", *, keep_units: bool = False) -> HalfPlan:
    """Choose the storage of values in ``[lo, hi]`` (smallest positive, largest).

    Parameters
    ----------
    lo, hi : float
        Bounds on the positive values the map can hold.
    dtype : {"auto", "half", "float"}
        What was asked for. ``auto`` (the default): half when ``[lo, hi]`` fits, else
        float, so that every tool reads the radiance as it is. ``half``: half always,
        rescaled by a power of two when needed (the multiplier is recorded as
        ``hdrcl:halfScale``; hdrcl's reader undoes it, other tools see scaled values).
    keep_units : bool
        The values are in physical units (``--absolute``, ``--reference-patch``): never
        rescale them; write float when half cannot hold them.

    Returns
    -------
    HalfPlan
    """
    if dtype not in ("half", "auto"):
        return HalfPlan(dtype)
    if not (lo > 0 and math.isfinite(lo) and math.isfinite(hi) and hi >= lo):
        return HalfPlan("float", 1.0, f"radiance bounds {lo:g}..{hi:g} are not usable with half floats; "
                                      "written as float")
    if lo >= HALF_FLOOR and hi <= HALF_MAX:
        return HalfPlan("half")
    span = f"{lo:.3g}..{hi:.3g}"
    if keep_units:
        return HalfPlan("float", 1.0, f"radiance may reach {span}, beyond half floats "
                                      f"({HALF_FLOOR:.3g}..{HALF_MAX:g}); written as float to keep its units")
    if dtype == "auto":
        return HalfPlan("float", 1.0, f"radiance may reach {span}, beyond half floats "
                                      f"({HALF_FLOOR:.3g}..{HALF_MAX:g}); written as float "
                                      "(--dtype half stores it rescaled instead)")
    k_min = math.ceil(math.log2(HALF_FLOOR / lo))  # smallest exponent that lifts lo
    k_max = math.floor(math.log2(HALF_MAX / hi))  # largest that keeps hi finite
    if k_min > k_max:
        return HalfPlan("float", 1.0, f"radiance may reach {span}, more than half floats hold "
                                      f"({HALF_FLOOR:.3g}..{HALF_MAX:g}); written as float")
    # Centre the values in the half range (in log2) within the feasible exponents.
    mid = (math.log2(HALF_MIN_NORMAL) + math.log2(HALF_MAX) - math.log2(lo) - math.log2(hi)) / 2.0
    k = int(min(max(round(mid), k_min), k_max))
    scale = 2.0 ** k
    return HalfPlan("half", scale, f"radiance may reach {span}, beyond half floats; stored x 2^{k} "
                                   f"(hdrcl:halfScale = {scale:g}; divide by it for radiance)")


#: Smallest positive half (subnormal); anything smaller becomes 0.
HALF_MIN = 2.0 ** -24


def clamp(data: np.ndarray):
    """Last-resort guard for a strip about to be written as half: finite values beyond
    +-65504 become +-65504 and non-zero values smaller than :data:`HALF_MIN` become
    +-HALF_MIN, so nothing finite turns into inf or 0.

    Returns ``(data, count)``: a corrected copy (or ``data`` itself) and how many values
    were changed.
    """
    a = np.abs(data)
    bad = np.isfinite(a) & ((a > HALF_MAX) | ((a > 0) & (a < HALF_MIN)))
    n = int(np.count_nonzero(bad))
    if not n:
        return data, 0
    out = np.array(data, copy=True)
    out[bad] = np.sign(out[bad]) * np.where(a[bad] > HALF_MAX, HALF_MAX, HALF_MIN)
    return out, n


def fits(data: np.ndarray) -> bool:
    """Whether every finite non-zero value of ``data`` is within ``HALF_FLOOR..HALF_MAX``."""
    a = np.abs(data[np.isfinite(data)])
    a = a[a > 0]
    return not a.size or (a.min() >= HALF_FLOOR and a.max() <= HALF_MAX)


# --------------------------------------------------------------------------------------
# Scaling, measuring and converting a strip in one pass
# --------------------------------------------------------------------------------------
#
# A merge hands every strip of float32 radiance to the file writer, which multiplies it by
# the file's scale (the reference exposure), measures its positive range (does it fit
# half?) and converts it to half. Done as whole-array NumPy operations these are five or
# six passes over memory, and NumPy's float32 -> float16 cast is scalar code (about 2.5 ns
# a value here): together as much CPU as the fusion of seven frames. Here the strip is
# walked in blocks of :data:`BLOCK` values that stay in the L2 cache; a block whose values
# are positive, finite and within the normal half range (almost all of them) is measured
# with one ``minimum.reduce`` and one ``maximum.reduce`` and converted with integer
# operations on its bits, in which a power-of-two scale is one added constant:
#
#     half bits = (b + 0xfff + ((b >> 13) & 1) + ((k - 112) << 23)) >> 13
#
# for the float32 bits ``b`` of ``x``, scale ``2^k``: round to nearest, ties to even, as
# NumPy and OpenEXR round, bit for bit, wherever ``x 2^k`` is a normal half
# (2^-14 .. 65504). Any other block (zeros, negatives, NaN or Inf, values beyond
# 65504 or below 2^-14) takes NumPy's own path, which also clamps what half cannot hold
# (:func:`clamp`). The range of a block is measured on the unscaled values: rounding
# ``x s`` to float32 is monotonic for ``s > 0``, so ``min(x s) = min(x) s``.

#: Values per block of the one-pass loops: a block and its work array stay in L2.
BLOCK = 1 << 15
_F32_NORMAL_HALF = np.float32(HALF_MIN_NORMAL)
_F32_HALF_MAX = np.float32(HALF_MAX)
_F32_TINY = np.finfo(np.float32).tiny  # the smallest normal float32


@dataclass
class StripRange:
    """What one pass over scaled values found.

    Attributes
    ----------
    lo : float
        Smallest positive finite value (``inf`` when there is none).
    hi : float
        Largest value; ``inf`` when any value is NaN or infinite.
    nonfinite : int
        NaN and infinite values.
    clamped : int
        Values changed by :func:`clamp` (half only).
    negative : int
        Values below 0.
    """

    lo: float = math.inf
    hi: float = 0.0
    nonfinite: int = 0
    clamped: int = 0
    negative: int = 0

    def add(self, other: "StripRange") -> None:
        """Take ``other`` (a later block or strip) into account."""
        self.lo, self.hi = min(self.lo, other.lo), max(self.hi, other.hi)
        self.nonfinite += other.nonfinite
        self.clamped += other.clamped
        self.negative += other.negative


def pow2_exponent(scale: float) -> Optional[int]:
    """``k`` when ``scale`` is exactly ``2^k`` (a normal float32), else None."""
    m, e = math.frexp(float(scale))
    return e - 1 if m == 0.5 and -126 <= e - 1 <= 127 else None


class OnePass:
    """Scales, measures and converts float32 strips block by block (see above).

    One object per writer: it keeps its work arrays (fresh memory for every strip would
    cost page faults). Not for use from two threads at once.
    """

    def __init__(self, block: int = BLOCK):
        self.block = int(block)
        self._u32 = np.empty(self.block, np.uint32)
        self._f32 = np.empty(self.block, np.float32)

    @staticmethod
    def _flat(a: np.ndarray, dtype) -> np.ndarray:
        if a.dtype != dtype or not a.flags.c_contiguous:
            raise ValueError(f"expected a C-contiguous {np.dtype(dtype)} array, got {a.dtype}")
        return a.reshape(-1)

    def to_half(self, src: np.ndarray, scale: float, out: np.ndarray) -> StripRange:
        """``out[...] = clamp(src * scale)`` as float16, and the range of ``src * scale``.

        ``src``: float32, C-contiguous; ``out``: float16 of the same size, C-contiguous.
        Bit-identical to ``clamp(src * np.float32(scale)).astype(np.float16)``.
        """
        x, o = self._flat(src, np.float32), self._flat(out, np.float16)
        if x.size != o.size:
            raise ValueError(f"{x.size} values into {o.size}")
        s = np.float32(scale)
        k = pow2_exponent(scale)
        total = StripRange()
        with np.errstate(over="ignore", under="ignore", invalid="ignore"):  # as the data give them
            for i in range(0, x.size, self.block):
                j = min(x.size, i + self.block)
                total.add(self._half_block(x[i:j], s, k, o[i:j]))
        return total

    def _half_block(self, x: np.ndarray, s, k: Optional[int], o: np.ndarray) -> StripRange:
        n = x.size
        if k is None:  # scale first: the bits of x s are converted as they are
            x = np.multiply(x, s, out=self._f32[:n])
            s, k = np.float32(1), 0
        mn, mx = np.minimum.reduce(x), np.maximum.reduce(x)
        lo, hi = mn * s, mx * s
        if mn == 0 and mx * s <= _F32_HALF_MAX:  # pixels without data: 0, the rest may be plain
            pos = np.minimum.reduce(x, where=x > 0, initial=np.inf)
            # the bit trick needs normal float32 inputs: a subnormal's exponent field is 0
            if pos * s >= _F32_NORMAL_HALF and pos >= _F32_TINY:
                self._bits_to_half(x, k, o)
                zero = x == 0
                np.copyto(o, x, where=zero, casting="unsafe")  # 0 and -0 as they are
                return StripRange(float(pos * s), float(hi))
        elif lo >= _F32_NORMAL_HALF and hi <= _F32_HALF_MAX and mn >= _F32_TINY:  # NaN fails them all
            self._bits_to_half(x, k, o)
            return StripRange(float(lo), float(hi))
        v = np.multiply(x, s, out=self._f32[:n]) if s != 1 else x
        r = _slow_range(v)
        v, r.clamped = clamp(v)
        np.copyto(o, v, casting="unsafe")
        return r

    def _bits_to_half(self, x: np.ndarray, k: int, o: np.ndarray) -> None:
        b = x.view(np.uint32)
        u = self._u32[:x.size]
        np.right_shift(b, 13, out=u)
        np.bitwise_and(u, 1, out=u)
        np.add(u, b, out=u)
        np.add(u, np.uint32((0xFFF + ((k - 112) << 23)) & 0xFFFFFFFF), out=u)
        np.right_shift(u, 13, out=u)
        np.copyto(o.view(np.uint16), u, casting="unsafe")

    def to_float(self, src: np.ndarray, scale: float, out: np.ndarray) -> StripRange:
        """``out[...] = src * scale`` (float32, C-contiguous, same size; may be ``src``)
        and its range."""
        x, o = self._flat(src, np.float32), self._flat(out, np.float32)
        if x.size != o.size:
            raise ValueError(f"{x.size} values into {o.size}")
        s = np.float32(scale)
        same = o.ctypes.data == x.ctypes.data
        if not same and np.may_share_memory(o, x):
            raise ValueError("out overlaps src without being it")
        total = StripRange()
        with np.errstate(over="ignore", under="ignore", invalid="ignore"):
            for i in range(0, x.size, self.block):
                j = min(x.size, i + self.block)
                ob = o[i:j]
                if s != 1:
                    np.multiply(x[i:j], s, out=ob)
                elif not same:
                    np.copyto(ob, x[i:j])
                total.add(self._range_of(ob))
        return total

    def measure(self, src: np.ndarray, scale: float) -> StripRange:
        """The range of ``src * scale`` (float32 ``src``), nothing written."""
        x = np.ascontiguousarray(src, np.float32).reshape(-1)
        s = np.float32(scale)
        total = StripRange()
        with np.errstate(over="ignore", under="ignore", invalid="ignore"):
            for i in range(0, x.size, self.block):
                j = min(x.size, i + self.block)
                xb = x[i:j]
                mn, mx = np.minimum.reduce(xb), np.maximum.reduce(xb)
                if mn > 0 and np.isfinite(mx * s) and mn * s > 0:
                    total.add(StripRange(float(mn * s), float(mx * s)))
                else:
                    total.add(_slow_range(np.multiply(xb, s, out=self._f32[:j - i])))
        return total

    @staticmethod
    def _range_of(v: np.ndarray) -> StripRange:
        mn, mx = np.minimum.reduce(v), np.maximum.reduce(v)
        if mn > 0 and np.isfinite(mx):
            return StripRange(float(mn), float(mx))
        return _slow_range(v)


def _slow_range(v: np.ndarray) -> StripRange:
    """The range of a block holding zeros, negatives, NaN or Inf (any float32 array)."""
    if not v.size:
        return StripRange()
    mn, mx = np.minimum.reduce(v, axis=None), np.maximum.reduce(v, axis=None)
    r = StripRange(hi=float(mx))
    if not (np.isfinite(mn) and np.isfinite(mx)):
        fin = np.isfinite(v)
        r.nonfinite = int(v.size - np.count_nonzero(fin))
        r.hi = math.inf
        good = (v > 0) & fin
        mn = np.minimum.reduce(v, where=fin, initial=np.inf, axis=None)
    else:
        good = v > 0
    if mn > 0:
        r.lo = float(mn)
    else:
        r.lo = float(np.minimum.reduce(v, where=good, initial=np.inf, axis=None))
        r.negative = int(np.count_nonzero(v < 0))
    if r.hi < 0:
        r.hi = 0.0
    return r
