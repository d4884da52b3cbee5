"""The equations of a fisheye luminance map, in NumPy float64: the twins of
``kernels/fisheye.cl`` and the streaming crop-and-resize of :mod:`hdrcl.core.luminance.fisheye`.

Geometry. Pictures are ``N x N``, rows top to bottom. A pixel ``(row i, column j)`` has
its centre at ``u = (j + 1/2) / N - 1/2``, ``v = (i + 1/2) / N - 1/2`` in units of the
picture's width (0 at the centre, the view's edge at radius 1/2).

* **Projection** equisolid-angle to equidistant (Radiance's ``fisheye_corr.cal``:
  ``rad(r) = 2/PI*asin(sqrt(2)*r)`` maps an equisolid radius to the equidistant one). An
  output pixel at equidistant radius ``rd <= 1/2`` takes the source at the equisolid
  radius ``rs = sin(PI rd / 2) / sqrt(2)`` along the same direction, by bilinear
  interpolation (edge pixels repeated); outside the view it is 0. Values are radiance
  (per solid angle), so a reprojection keeps them as they are: no Jacobian.
  "Inside the view" is decided exactly in integers: ``(2j+1-N)^2 + (2i+1-N)^2 <= N^2``.
* **Vignetting** (Radiance's pcomb coordinates: ``x = j``, ``y = N - 1 - i``, from the
  bottom) ``r = |(x, y) - (XC, YC)| / RADIUS``, value / ``(a0 + a1 r + ... + a8 r^8)``.
* **Vertical illuminance** of an equidistant (``-vta``) picture of view angle ``vh``:
  ``theta = rho * dtheta`` with ``rho`` the pixel centre's distance from the centre in
  pixels and ``dtheta = vh / N``; ``Ev = sum L cos(theta) dOmega`` over the pixels with
  ``rho <= N/2`` and ``theta < PI/2`` (the front hemisphere), ``dOmega = sin(theta) /
  theta * dtheta^2``. ``L`` is Radiance's luminance ``0.265 R + 0.670 G + 0.065 B`` of the
  channels in cd/m^2.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

#: Radiance's luminance weights of R, G, B (``179 * (...)`` of stored values is cd/m^2).
RADIANCE_LUMA = np.array([0.265, 0.670, 0.065])
#: Radiance's luminous efficacy of its white (lm/W).
WHITE_EFFICACY = 179.0


def radiance_luminance(rgb: np.ndarray) -> np.ndarray:
    """``0.265 R + 0.670 G + 0.065 B`` (the channel itself for grey), float64."""
    rgb = np.asarray(rgb, np.float64)
    return rgb[..., 0] if rgb.shape[-1] == 1 else rgb @ RADIANCE_LUMA


def _centres(n: int):
    c = (np.arange(n, dtype=np.float64) + 0.5) / n - 0.5
    return c[None, :], c[:, None]  # u (columns), v (rows)


def inside_view(n: int) -> np.ndarray:
    """``(N, N)`` bool: pixel centres within the view's circle (exact, in integers)."""
    k = 2 * np.arange(n, dtype=np.int64) + 1 - n
    return k[None, :] ** 2 + k[:, None] ** 2 <= n * n


def bilinear(img: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """``img`` ``(H, W, C)`` at pixel-index coordinates ``(xs, ys)`` (centres at integers),
    bilinear, edges repeated."""
    h, w = img.shape[:2]
    xs = np.clip(xs, 0.0, w - 1.0)
    ys = np.clip(ys, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(xs).astype(np.int64), w - 2) if w > 1 else np.zeros(xs.shape, np.int64)
    y0 = np.minimum(np.floor(ys).astype(np.int64), h - 2) if h > 1 else np.zeros(ys.shape, np.int64)
    fx = (xs - x0)[..., None]
    fy = (ys - y0)[..., None]
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    src = np.asarray(img, np.float64)
    top = src[y0, x0] * (1 - fx) + src[y0, x1] * fx
    bottom = src[y1, x0] * (1 - fx) + src[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def equisolid_to_equidistant(img: np.ndarray) -> np.ndarray:
    """The equidistant picture of an equisolid ``(N, N, C)`` one (float64)."""
    n = img.shape[0]
    u, v = _centres(n)
    rd = np.hypot(u, v)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(rd > 0, np.sin(math.pi * rd / 2.0) / (math.sqrt(2.0) * rd),
                         math.pi / (2.0 * math.sqrt(2.0)))
    xs = (0.5 + u * scale) * n - 0.5
    ys = (0.5 + v * scale) * n - 0.5
    out = bilinear(img, xs, ys)
    out[~inside_view(n)] = 0.0
    return out


def project_radial(img: np.ndarray, source_radius) -> np.ndarray:
    """A user projection (``--fisheye-projection FILE.cal``): the output pixel at radius
    ``rd`` (units of the width, the view's edge at 1/2) takes the input at radius
    ``source_radius(rd)`` along the same direction, bilinear; 0 outside the view and where
    the radius is not finite (float64). :func:`equisolid_to_equidistant` with
    ``source_radius = sin(PI rd / 2) / sqrt(2)``."""
    n = img.shape[0]
    u, v = _centres(n)
    rd = np.hypot(u, v)
    rs = np.asarray(source_radius(rd), np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(rd > 0, rs / np.where(rd > 0, rd, 1.0), 0.0)
    good = np.isfinite(scale)
    scale = np.where(good, scale, 0.0)
    out = bilinear(img, (0.5 + u * scale) * n - 0.5, (0.5 + v * scale) * n - 0.5)
    out[~inside_view(n) | ~good] = 0.0
    return out


def vignetting_factors(n: int, coefficients: Sequence[float], xc: float, yc: float, radius: float) -> np.ndarray:
    """``(N, N)`` multipliers ``1 / (a0 + a1 r + ... + a8 r^8)`` (float64)."""
    x = np.arange(n, dtype=np.float64)[None, :]
    y = (n - 1 - np.arange(n, dtype=np.float64))[:, None]
    r = np.hypot(x - xc, y - yc) / radius
    den = np.zeros_like(r)
    for a in reversed(list(coefficients)):
        den = den * r + a
    with np.errstate(divide="ignore"):
        return 1.0 / den


def apply_vignetting(img: np.ndarray, coefficients, xc, yc, radius) -> np.ndarray:
    return np.asarray(img, np.float64) * vignetting_factors(img.shape[0], coefficients, xc, yc, radius)[..., None]


def vertical_illuminance(img_cd: np.ndarray, view_angle_deg: float) -> float:
    """``Ev`` (lux) of an equidistant ``(N, N, C)`` picture in cd/m^2 of ``view_angle_deg``."""
    n = img_cd.shape[0]
    dtheta = math.radians(view_angle_deg) / n
    k = np.arange(n, dtype=np.float64) + 0.5 - n / 2.0
    rho = np.hypot(k[None, :], k[:, None])
    theta = rho * dtheta
    use = (rho <= n / 2.0) & (theta < math.pi / 2.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        domega = np.where(theta > 0, np.sin(theta) / theta, 1.0) * dtheta * dtheta
    lum = radiance_luminance(img_cd)
    return float(np.sum(np.where(use, lum * np.cos(theta) * domega, 0.0)))


def area_weights(size: int, n: int, lo: int, hi: int) -> tuple:
    """Weights of source rows ``lo .. hi`` (of ``size``) in the output rows ``k0 .. k1`` of
    an ``n``-row area average: ``(k0, W)`` with ``W`` ``(k1 - k0, hi - lo)``."""
    step = size / n
    k0 = (lo * n) // size
    k1 = min(n, -(-hi * n // size) + 1)
    k = np.arange(k0, k1, dtype=np.float64)[:, None]
    y = np.arange(lo, hi, dtype=np.float64)[None, :]
    overlap = np.minimum(y + 1, (k + 1) * step) - np.maximum(y, k * step)
    return k0, np.clip(overlap, 0.0, None) / step


def row_average(rows: np.ndarray, size: int, n: int, lo: int) -> tuple:
    """Rows ``lo .. lo + r`` (of ``size``) area-weighted into the output rows they touch:
    ``(k0, part)``, ``part`` ``(k, ...)`` to be added to output rows ``k0 ..``.

    Shrinking (``size >= n``) a source row lies in output row ``ka = y n // size`` and at
    most one boundary cuts it, giving the fraction past it to ``ka + 1``: two scaled
    copies summed by group (no matrix product: BLAS threads cost more than they save
    on these shapes). Enlarging uses the overlap matrix (:func:`area_weights`).
    """
    r = rows.shape[0]
    if size < n:
        k0, w = area_weights(size, n, lo, lo + r)
        return k0, np.einsum("kr,r...->k...", w.astype(rows.dtype), rows)
    y = np.arange(lo, lo + r, dtype=np.int64)
    ka = (y * n) // size
    cut = (ka + 1) * size  # the next boundary times n
    wb = np.clip((y + 1) * n - cut, 0, None) / size  # fraction past it, times n / size
    wa = n / size - wb
    k0 = int(ka[0])
    part = np.zeros((int(ka[-1]) + 2 - k0,) + rows.shape[1:], rows.dtype)
    wa, wb = wa.astype(rows.dtype), wb.astype(rows.dtype)
    for j in range(r):  # a few rows per output row: plain slices beat reduceat along axis 0
        part[ka[j] - k0] += rows[j] * wa[j]
        if wb[j] > 0:
            part[ka[j] + 1 - k0] += rows[j] * wb[j]
    k1 = min(n, k0 + part.shape[0])
    return k0, part[:k1 - k0]


def column_average(rows: np.ndarray, n: int) -> np.ndarray:
    """Area average of ``(r, S, C)`` rows into ``(r, n, C)`` columns (float64), exact for
    pixels that are constant over their area. Output column ``k`` covers source columns
    ``[k S / n, (k + 1) S / n)``: the whole pixels inside (summed in the rows' type: a
    float32 sum of S / n terms errs by about S / n float32 steps), plus the fractions of
    the pixels cut at its ends."""
    r, size, c = rows.shape
    k = np.arange(n + 1, dtype=np.int64)
    i, f = (k * size) // n, ((k * size) % n) / n  # boundary k S / n = i + f, exactly
    if size < n:  # enlarging: prefix sums at the fractional boundaries
        prefix = np.zeros((r, size + 1, c), np.float64)
        np.cumsum(rows, axis=1, dtype=np.float64, out=prefix[:, 1:])
        j = np.minimum(i, size - 1)
        g = (i - j + f)[None, :, None]
        at = prefix[:, j] + g * (prefix[:, j + 1] - prefix[:, j])
        return np.diff(at, axis=1) * (n / size)
    # pixels i_k .. i_(k+1) - 1: sums of about S / n terms, in the rows' own type
    total = np.add.reduceat(rows, i[:-1], axis=1).astype(np.float64)
    total -= f[:-1, None] * rows[:, i[:-1]]  # the part of pixel i_k before the boundary
    inner = i[1:-1]  # pixel i_(k+1) contributes its fraction f_(k+1) (none past the last)
    total[:, :-1] += f[1:-1, None] * rows[:, inner]
    total *= n / size
    return total
