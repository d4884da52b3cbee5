"""hdrgen's camera response files (``.rsp``), read and written.

**Format.** One line per channel (R, G, B): ``N cN ... c1 c0``, a polynomial of order
``N`` giving the relative linear exposure ``p(x)`` of the pixel value scaled to
``x = z / (levels - 1)`` in 0..1, normalised so that ``p(1) = 1``.

**Reading.** hdrcl's response is ``g(z) = ln f^-1(z)`` per code level with
``g(Zmid) = 0`` (``Zmid = levels / 2``), so ``g(z) = ln p(z / (levels - 1)) - ln p(Zmid /
(levels - 1))``. A fitted polynomial often reaches 0 or goes negative near code 0 (hdrgen
fits the usable codes only): from the lowest code ``z1`` above which ``p`` is positive and
increasing, lower codes get ``p(z) = p(z1) (z + 1/2) / (z1 + 1/2)``, the straight line to 0
that a linear sensor would give. Those codes have (almost) no weight in a merge. 8-bit
is assumed (hdrgen's inputs are 8-bit JPEG or TIFF).

**Writing.** ``exp(g)`` rescaled to ``p(1) = 1`` is fitted by least squares in relative
error (weights ``1 / p``) over codes :data:`FIT_LOW` .. top, with ``p(1) = 1`` exact.
The order is the lowest of 3 .. :data:`MAX_ORDER` whose largest error over codes
10 .. 245 is below :data:`FIT_TOLERANCE` (in ``ln`` exposure, i.e. about 1 %); when none
is, the order with the smallest error. :func:`write_rsp` returns the order and the
error, and the response loses its provenance (JSON keeps it).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import List

import numpy as np

from hdrcl.errors import InputError

__all__ = ["RspFit", "read_rsp", "write_rsp", "rsp_text", "fit_polynomial", "g_from_polynomial"]

MAX_ORDER = 10
FIT_TOLERANCE = 0.01
FIT_LOW = 10  # 8-bit codes; scaled for 16-bit responses
CHECK = (10, 245)


@dataclass
class RspFit:
    """What writing a ``.rsp`` did: per-channel order and largest ``ln`` error (codes 10..245)."""

    orders: List[int]
    max_error: List[float]


def g_from_polynomial(coeffs, levels: int = 256) -> np.ndarray:
    """``g`` at every code from a polynomial ``c0 .. cN`` (ascending), ``g(levels/2) = 0``."""
    x = np.arange(levels, dtype=np.float64) / (levels - 1)
    with np.errstate(all="ignore"):  # huge coefficients: one error below, no NumPy warnings
        p = np.polynomial.polynomial.polyval(x, np.asarray(coeffs, np.float64))
        finite = bool(np.all(np.isfinite(p))) and bool(np.all(np.isfinite(np.diff(p))))
    if not finite:
        raise ValueError("the polynomial overflows between codes 0 and the top (coefficients too large)")
    good = (p > 0) & np.concatenate(([True], np.diff(p) > 0))
    # z1: the lowest code from which p is positive and increasing all the way up
    bad = np.flatnonzero(~good)
    z1 = int(bad[-1]) + 1 if bad.size else 0
    if z1 >= levels // 2:
        raise ValueError("the polynomial is not positive and increasing above mid-grey")
    z = np.arange(levels, dtype=np.float64)
    p = np.where(z < z1, p[z1] * (z + 0.5) / (z1 + 0.5), p)
    return np.log(p) - math.log(p[levels // 2])


def read_rsp(path):
    """``(g, channels)`` of an hdrgen ``.rsp`` file: ``g`` ``(C, 256)`` at every 8-bit code
    (:func:`g_from_polynomial`); :class:`hdrcl.core.response.Response` wraps it."""
    path = os.fspath(path)
    try:
        with open(path, "r", encoding="utf-8-sig") as f:
            lines = [ln.split() for ln in f.read(1 << 16).splitlines() if ln.strip()]
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the response ({getattr(exc, 'strerror', None) or exc})") from None
    expected = "one line 'N cN ... c1 c0' per channel R, G, B"
    if len(lines) not in (1, 3):
        raise InputError(f"{path}: not an hdrgen response: {len(lines)} lines, expected {expected}")
    g = []
    for i, fields in enumerate(lines):
        try:
            order = int(fields[0])
            coeffs = [float(v) for v in fields[1:]][::-1]  # c0 .. cN
        except ValueError:
            raise InputError(f"{path}: line {i + 1}: not numbers; expected {expected}") from None
        if not 1 <= order <= 20 or len(coeffs) != order + 1 or not all(math.isfinite(c) for c in coeffs):
            raise InputError(f"{path}: line {i + 1}: expected the order N then N+1 coefficients")
        try:
            g.append(g_from_polynomial(coeffs))
        except ValueError as exc:
            raise InputError(f"{path}: line {i + 1}: {exc}") from None
    return np.asarray(g), (("R", "G", "B") if len(g) == 3 else ("Y",))


def fit_polynomial(g_codes: np.ndarray, levels: int, order: int):
    """Least-squares polynomial (ascending coefficients) of order ``order`` through
    ``p = exp(g)`` rescaled to ``p(1) = 1``, with ``p(1) = 1`` exact; returns
    ``(coeffs, max ln error over codes 10..245)``."""
    z = np.arange(levels, dtype=np.float64)
    x = z / (levels - 1)
    p = np.exp(np.asarray(g_codes, np.float64) - float(g_codes[-1]))
    scale = (levels - 1) / 255.0
    use = z >= FIT_LOW * scale
    k = np.arange(1, order + 1)
    basis = x[use, None] ** k - 1.0  # p(x) = 1 + sum c_k (x^k - 1): p(1) = 1 for any c
    w = 1.0 / p[use]
    c, *_ = np.linalg.lstsq(basis * w[:, None], (p[use] - 1.0) * w, rcond=None)
    coeffs = np.concatenate(([1.0 - c.sum()], c))
    return coeffs, _error(coeffs, g_codes, levels)


def _error(coeffs, g_codes: np.ndarray, levels: int) -> float:
    """Largest ``|ln p_fit - (g - g(top))|`` over codes 10..245 (inf where ``p_fit <= 0``)."""
    scale = (levels - 1) / 255.0
    z = np.arange(int(round(CHECK[0] * scale)), int(round(CHECK[1] * scale)) + 1, dtype=np.float64)
    fit = np.polynomial.polynomial.polyval(z / (levels - 1), np.asarray(coeffs, np.float64))
    if not np.all(fit > 0):
        return math.inf
    g = np.asarray(g_codes, np.float64)
    return float(np.max(np.abs(np.log(fit) - (g[z.astype(np.int64)] - g[-1]))))


def rsp_text(tables: np.ndarray, levels: int):
    """The ``.rsp`` text of a response's ``g`` tables ``(C, levels)`` and the :class:`RspFit`."""
    tables = np.asarray(tables, np.float64)
    lines, fit = [], RspFit([], [])
    for c in range(tables.shape[0]):
        best = None
        for order in range(3, MAX_ORDER + 1):
            coeffs, err = fit_polynomial(tables[c], levels, order)
            if best is None or err < best[1] - 1e-12:
                best = (order, err, coeffs)
            if err <= FIT_TOLERANCE:
                best = (order, err, coeffs)
                break
        order, err, coeffs = best
        words = [f"{v:.12g}" for v in coeffs[::-1]]
        fit.orders.append(order)
        fit.max_error.append(_error([float(v) for v in words[::-1]], tables[c], levels))
        lines.append(" ".join([str(order)] + words))
    return "\n".join(lines) + "\n", fit


def write_rsp(tables: np.ndarray, levels: int, path) -> RspFit:
    """Write ``g`` tables as an hdrgen ``.rsp`` file, atomically; returns the fit."""
    from hdrcl.io.atomic import write_text

    text, fit = rsp_text(tables, levels)
    write_text(path, text)
    return fit
