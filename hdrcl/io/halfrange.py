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
