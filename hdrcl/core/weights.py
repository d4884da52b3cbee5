"""Weighting functions w(z) over the integer code values of a photograph.

Both functions are zero at the lowest and highest code (clipped values carry no
measurement) and peak in the middle of the range, as the paper asks. Values are
normalised to a peak of 1; the scale cancels in both the response solve and fusion.
"""
from __future__ import annotations

import numpy as np

from hdrcl.errors import UsageError

WEIGHTS = ("hat", "gaussian")
#: The default weighting, chosen by measurement: on the paper's Memorial set the
#: leave-one-out error (``scripts/memorial_loo.py``, median over the 14 interior frames,
#: 8-bit levels) is 4.32 with gaussian and 4.97 with the paper's hat (OpenCV: 5.4). Hat
#: stays available as ``--weight hat``.
DEFAULT_WEIGHT = "gaussian"

#: 8-bit code at and above which a sample is clipped: it proves only that the scene is at
#: least that bright, so fusion takes no evidence from it nor from any longer exposure of
#: the same pixel-channel (:func:`hdrcl.core.reference.fuse`). JPEG cameras put the
#: highlights of a clipped area anywhere in 250..255 (ringing, per-channel processing),
#: so 255 alone is not enough. The noise floor mirrors it (8-bit: codes 0..5).
CLIP_HIGH_8BIT = 250


def weight_values(z, levels: int, kind: str = "hat") -> np.ndarray:
    """Weight of code value(s) ``z`` for an image with ``levels`` code values.

    Parameters
    ----------
    z : array_like
        Code values, possibly fractional, in ``[0, levels - 1]``.
    levels : int
        Number of code values (256 for 8-bit, 65536 for 16-bit).
    kind : {"hat", "gaussian"}
        ``hat`` is the paper's triangle ``w(z) = z - Zmin`` below ``Zmid`` and
        ``Zmax - z`` above, divided by ``Zmid``. ``gaussian`` is
        ``(exp(-4 x^2) - exp(-4)) / (1 - exp(-4))`` with ``x = (z - Zmid) / Zmid``: smooth
        near the middle, still exactly zero at both ends.

    Returns
    -------
    numpy.ndarray
        float64 weights in ``[0, 1]``.
    """
    z = np.asarray(z, dtype=np.float64)
    zmax = float(levels - 1)
    zmid = zmax / 2.0
    if kind == "hat":
        w = np.where(z <= zmid, z, zmax - z) / zmid
    elif kind == "gaussian":
        x = (z - zmid) / zmid
        e4 = np.exp(-4.0)
        w = (np.exp(-4.0 * x * x) - e4) / (1.0 - e4)
    else:
        raise UsageError(f"unknown weighting '{kind}': choose one of {', '.join(WEIGHTS)}")
    return np.clip(w, 0.0, None)


def weight_table(levels: int, kind: str = "hat") -> np.ndarray:
    """Weights of every code value ``0 .. levels-1`` (float64, length ``levels``)."""
    return weight_values(np.arange(levels), levels, kind)


def clip_levels(levels: int) -> tuple:
    """``(low, high)`` codes for images with ``levels`` code values: a sample at or below
    ``low`` is at the noise floor, at or above ``high`` clipped (:data:`CLIP_HIGH_8BIT`
    scaled to the depth, the floor its mirror): 8-bit ``(5, 250)``, 16-bit
    ``(1285, 64250)``. Codes strictly between them are evidence in fusion."""
    high = int(round(CLIP_HIGH_8BIT * (levels - 1) / 255.0))
    return levels - 1 - high, high


def evidence_weights(levels: int, weights: np.ndarray) -> np.ndarray:
    """``weights`` with the codes outside ``clip_levels(levels)`` set to 0: the weights
    fusion gives each code (float64, length ``levels``)."""
    low, high = clip_levels(levels)
    w = np.array(weights, np.float64)
    w[: low + 1] = 0.0
    w[high:] = 0.0
    return w
