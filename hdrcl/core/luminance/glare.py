"""Glare metrics of a calibrated fisheye luminance map, by evalglare's method.

Method (Wienold and Christoffersen 2006, *Evaluation methods and development of a new
glare prediction model for daylight environments with the use of CCD cameras*, Energy and
Buildings 38(7); evalglare 2.x/3.x as Radiance ships it, ``src/util/evalglare.c`` and
``pictool.c``), on the picture as Radiance reads it:

* **Geometry.** Every pixel's direction is Radiance's ``viewray`` of its centre for the
  map's ``VIEW=`` (``-vta`` equidistant or ``-vth`` hemispherical fisheye; ``-vd``/``-vu``
  honoured) and its solid angle the spherical quadrilateral of its four corner rays
  (``pict_get_sangle``). Pixels behind the view direction (``-vta``) do not count.
* **Luminance** ``L = 179 (0.265074 R + 0.670115 G + 0.064811 B)`` of the values Radiance
  reads (hdrcl: the map in cd/m^2 with those weights).
* **Vertical illuminance** ``Ev = sum L cos(theta) omega``; the average luminance
  ``sum L omega / sum omega``.
* **Glare sources.** Pixels brighter than the threshold: evalglare's default, 2000 cd/m^2
  (``-b 2000``; since evalglare 2.05, after Pierson's study), or a factor (<= 100) times the
  average luminance (``-b 5``, the older default, 5x). Pixels closer than 0.1 rad to each
  other belong to one source (evalglare's search radius ``-r 0.2``, used as twice the
  angle); then evalglare's peak extraction: the pixels of a source at or above 50,000
  cd/m^2 become sources of their own (grouped the same way). A source's luminance is the
  solid-angle weighted mean, its solid angle the sum, its position the mean pixel
  weighted by luminance times solid angle (evalglare 3; truncated to a pixel, as
  evalglare does) and the position index
  Guth's (IES handbook form) above the line of sight; below it the CIE 2010 form of
  evalglare 3.02+ (Guth's with tau = 90 degrees, :data:`BELOW_SIGHT_STRETCH`), at most 16.
* **Background luminance** (CIE): ``Lb = (Ev - Edir) / PI``, ``Edir`` the sources'
  ``sum L cos(theta) omega``.
* **Metrics.** ``DGP = 5.87e-5 Ev + 0.092 log10(1 + sum Ls^2 ws / (Ev^1.87 P^2)) + 0.159``
  (at most 1; evalglare 3 applies no low-light correction by default, 2.x multiplied by
  ``exp(0.024 Ev - 4) / (1 + exp(0.024 Ev - 4))`` below 1000 lx); ``DGI = 10 log10 sum 0.478 Ls^1.6 (ws/P^2)^0.8 /
  (Lb + 0.07 ws^0.5 Ls)`` (Hopkinson, Chauvel et al. 1982); ``UGR = 8 log10(0.25 / Lb
  sum Ls^2 ws / P^2)`` (CIE 117-1995). With no source, DGI and UGR are 0 as evalglare
  prints them.

Checked against evalglare on the same files in ``tests/test_glare.py``.
"""
from __future__ import annotations

import logging
import math
import os
from dataclasses import asdict, dataclass, field
from typing import List, Optional, Tuple

import numpy as np

from hdrcl.errors import InputError, UsageError

logger = logging.getLogger(__name__)

__all__ = ["GlareSource", "GlareResult", "glare_metrics", "glare_of_file", "ViewSpec", "parse_glare_view",
           "check_luminance",
           "calibration_from_measurement", "calibrate_luminance_file",
           "DEFAULT_THRESHOLD", "PEAK_LIMIT", "SEARCH_ANGLE"]

#: Radiance's ``bright()`` weights of its standard primaries (``CIE_rf``, ``CIE_gf``, ``CIE_bf``).
RADIANCE_CIE = np.array([0.265074126, 0.670114631, 0.064811243])
DEFAULT_THRESHOLD = 2000.0
PEAK_LIMIT = 50000.0
SEARCH_ANGLE = 0.1  # radians: evalglare's -r 0.2 compared with twice the angle


@dataclass(frozen=True)
class ViewSpec:
    """A Radiance view: type, direction, up, horizontal and vertical size (degrees)."""

    vtype: str
    vdir: Tuple[float, float, float] = (0.0, 1.0, 0.0)
    vup: Tuple[float, float, float] = (0.0, 0.0, 1.0)
    vh: float = 180.0
    vv: float = 180.0


@dataclass
class GlareSource:
    luminance: float  # cd/m^2, solid-angle weighted mean
    solid_angle: float  # sr
    position_index: float
    pixels: int
    column: float  # weighted mean pixel position, from the left
    row: float  # from the top
    direction: Tuple[float, float, float]
    max_luminance: float
    illuminance: float  # its part of Ev, lux


@dataclass
class GlareResult:
    vertical_illuminance: float
    dgp: float
    dgi: float
    ugr: float
    background_luminance: float
    average_luminance: float
    direct_illuminance: float
    threshold: float
    view: str
    sources: List[GlareSource] = field(default_factory=list)

    def as_dict(self) -> dict:
        return asdict(self)


def parse_glare_view(text: str, where: str = "VIEW") -> ViewSpec:
    """A ``VIEW=`` text, checked as Radiance's view parser does (the view types glare
    metrics are computed for: ``-vta`` and ``-vth``); errors start with ``where``."""
    from hdrcl.core.luminance.fisheye import parse_view

    try:
        _, vtype, vh, vv = parse_view(text)
    except UsageError as exc:
        raise UsageError(f"{where}: {str(exc).split(': ', 1)[-1]}") from None
    words = str(text).split()
    vecs = {"-vd": (0.0, 1.0, 0.0), "-vu": (0.0, 0.0, 1.0)}
    for i, w in enumerate(words):
        if w in vecs:
            vecs[w] = tuple(float(v) for v in words[i + 1:i + 4])
    if vtype not in ("a", "h"):
        raise UsageError(f"{where}: glare metrics need a fisheye view (-vta or -vth), not -vt{vtype} ('{text}')")
    for name, v in vecs.items():
        if not math.hypot(*v) > 0:
            raise UsageError(f"{where}: {name} must not be 0 0 0 ('{text}')")
    return ViewSpec(vtype, vecs["-vd"], vecs["-vu"], vh, vv)


def _frame(view: ViewSpec):
    vdir = np.asarray(view.vdir, np.float64) / np.linalg.norm(view.vdir)
    hvec = np.cross(vdir, np.asarray(view.vup, np.float64))
    if not np.linalg.norm(hvec) > 0:
        raise UsageError("VIEW: the up vector (-vu) is parallel to the view direction (-vd)")
    hvec /= np.linalg.norm(hvec)
    vvec = np.cross(hvec, vdir)
    return vdir, hvec, vvec


def view_rays(view: ViewSpec, lx: np.ndarray, ly: np.ndarray):
    """Radiance's ``viewray`` at image locations ``lx``, ``ly`` (0..1, ``ly`` from the
    bottom): unit directions ``(..., 3)`` and a mask of the locations inside the view."""
    vdir, hvec, vvec = _frame(view)
    x, y = lx - 0.5, ly - 0.5
    if view.vtype == "a":
        x = x * math.radians(view.vh)
        y = y * math.radians(view.vv)
        d2 = x * x + y * y
        ok = d2 <= math.pi * math.pi
        d = np.sqrt(d2)
        z = np.cos(d)
        with np.errstate(invalid="ignore", divide="ignore"):
            s = np.where(d > 0, np.sin(d) / np.where(d > 0, d, 1.0), 1.0)
        dirs = z[..., None] * vdir + (x * s)[..., None] * hvec + (y * s)[..., None] * vvec
    else:  # hemispherical: the sine of the half angles scales the picture plane
        x = x * 2.0 * math.sin(math.radians(view.vh) / 2.0)
        y = y * 2.0 * math.sin(math.radians(view.vv) / 2.0)
        d2 = x * x + y * y
        ok = d2 <= 1.0
        z = np.sqrt(np.maximum(1.0 - d2, 0.0))
        dirs = z[..., None] * vdir + x[..., None] * hvec + y[..., None] * vvec
    norm = np.linalg.norm(dirs, axis=-1, keepdims=True)
    return dirs / np.where(norm > 0, norm, 1.0), ok


def pixel_geometry(height: int, width: int, view: ViewSpec):
    """``(dirs (H, W, 3), omega (H, W))`` of the pixels, rows from the top; ``omega`` is 0
    where a corner lies outside the view (evalglare then skips the pixel)."""
    cx = (np.arange(width, dtype=np.float64) + 0.5) / width
    cy = 1.0 - (np.arange(height, dtype=np.float64) + 0.5) / height  # from the bottom
    dirs, _ = view_rays(view, cx[None, :], cy[:, None])
    kx = np.arange(width + 1, dtype=np.float64) / width
    ky = 1.0 - np.arange(height + 1, dtype=np.float64) / height
    corners, ok = view_rays(view, kx[None, :], ky[:, None])
    c = [corners[:-1, :-1], corners[:-1, 1:], corners[1:, 1:], corners[1:, :-1]]  # a loop around the pixel
    normals = []
    for i in range(4):
        n = np.cross(c[i], c[(i + 1) % 4])
        normals.append(n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300))
    ang = np.zeros((height, width))
    for i in range(4):
        dot = np.clip(np.sum(normals[i] * normals[(i + 1) % 4], axis=-1), -1.0, 1.0)
        ang += math.pi - np.arccos(dot)
    omega = np.abs(ang - 2.0 * math.pi)
    good = ok[:-1, :-1] & ok[:-1, 1:] & ok[1:, 1:] & ok[1:, :-1]
    return dirs, np.where(good & (omega < 2 * math.pi), omega, 0.0)


#: Below the line of sight evalglare 3 (since 3.02, after Iwata and Osterhaus, CIE 2010) uses
#: Guth's formula with tau = 90 degrees at an angle whose vertical tangent is stretched by
#: this factor: ``sigma' = atan(hypot(tan_h, K tan_v))``. Fitted to evalglare 3.06's printed
#: position indices of one-pixel sources below the sightline (straight down 14..77 degrees,
#: off axis 30..80 degrees): within 8e-4 relative (tests/test_glare.py).
BELOW_SIGHT_STRETCH = 1.149


def _guth(sigma_deg: np.ndarray, tau_deg) -> np.ndarray:
    tau = tau_deg
    return np.exp((35.2 - 0.31889 * tau - 1.22 * np.exp(-2.0 * tau / 9.0)) / 1000.0 * sigma_deg
                  + (21.0 + 0.26667 * tau - 0.002963 * tau * tau) / 1e5 * sigma_deg * sigma_deg)


def position_index(dirs: np.ndarray, view: ViewSpec) -> np.ndarray:
    """Guth's position index (IES) above the line of sight; below it the CIE 2010 form
    evalglare 3.02+ uses (Guth's with tau = 90 degrees, :data:`BELOW_SIGHT_STRETCH`; the
    older Iwata form ``1 + 0.8 r`` / ``1 + 1.2 r`` of evalglare 2.x is gone); at most 16
    (evalglare's ``get_posindex``, default model)."""
    vdir, hvec, vvec = _frame(view)
    up = np.asarray(view.vup, np.float64) / np.linalg.norm(view.vup)
    d = np.asarray(dirs, np.float64)
    cos_s = np.clip(d @ vdir, -1.0, 1.0)
    sigma = np.abs(np.degrees(np.arccos(cos_s)))
    with np.errstate(invalid="ignore", divide="ignore"):
        hv = d / cos_s[..., None] - vdir
        hv /= np.linalg.norm(hv, axis=-1, keepdims=True)
        tau = np.degrees(np.arccos(np.clip(hv @ up, -1.0, 1.0)))
    tau = np.where(np.isfinite(tau), tau, 0.0)
    below = (d @ vvec) < 0  # below the line of sight
    guth = _guth(sigma, tau)
    sigma_below = np.degrees(np.arctan2(np.hypot(d @ hvec, BELOW_SIGHT_STRETCH * (d @ vvec)), cos_s))
    return np.minimum(np.where(below, _guth(sigma_below, 90.0), guth), 16.0)


#: Source edge pixels compared pairwise at most (:func:`_clusters`); real maps have a few
#: thousand (a 1000 px sky with its sun and 2,000 glints: 2 s in all).
MAX_EDGE_PIXELS = 40_000


def _clusters(mask: np.ndarray, dirs: np.ndarray, angle: float) -> np.ndarray:
    """Labels (0: none, 1..) of ``mask``'s pixels joined when closer than ``angle``
    (radians, between pixel-centre directions): single linkage, as evalglare's merging
    of sources within its search radius ends up."""
    from scipy import ndimage, sparse
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    labels, n = ndimage.label(mask, structure=np.ones((3, 3), bool))
    if n <= 1:
        return labels
    edge = mask & ~ndimage.binary_erosion(mask, structure=np.ones((3, 3), bool), border_value=0)
    ii, jj = np.nonzero(edge)
    if ii.size > MAX_EDGE_PIXELS:
        # A map of noise-like sources (every other pixel over the threshold) would give
        # billions of pairs: the edges are taken on a coarser grid (a component with no
        # pixel on it stays a source of its own), and the caller is told.
        step = int(math.ceil(math.sqrt(ii.size / MAX_EDGE_PIXELS)))
        keep = (ii % step == 0) & (jj % step == 0)
        logger.warning("glare: %d source edge pixels; sources within %.3g rad are joined on every %d-th "
                       "row and column only", ii.size, angle, step)
        ii, jj = ii[keep], jj[keep]
    tree = cKDTree(dirs[ii, jj])
    pairs = tree.query_pairs(2.0 * math.sin(angle / 2.0), output_type="ndarray")
    a, b = labels[ii[pairs[:, 0]], jj[pairs[:, 0]]], labels[ii[pairs[:, 1]], jj[pairs[:, 1]]]
    keep = a != b
    graph = sparse.coo_matrix((np.ones(int(keep.sum())), (a[keep] - 1, b[keep] - 1)), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    out = np.zeros_like(labels)
    out[labels > 0] = comp[labels[labels > 0] - 1] + 1
    return out


def _sources(lum, omega, dirs, labels, view) -> List[GlareSource]:
    vdir = _frame(view)[0]
    h, w = lum.shape
    rows, cols = np.nonzero(labels)
    lab = labels[rows, cols]
    om = omega[rows, cols]
    lw = lum[rows, cols] * om
    cosw = np.clip(dirs[rows, cols] @ vdir, 0.0, None) * lw
    n = int(labels.max())
    osum = np.bincount(lab, om, n + 1)[1:]
    lsum = np.bincount(lab, lw, n + 1)[1:]
    # position: luminance x solid angle weighted (evalglare 3; 2.x weighted by solid angle only)
    xsum = np.bincount(lab, cols * lw, n + 1)[1:]
    ysum = np.bincount(lab, (h - 1 - rows) * lw, n + 1)[1:]  # evalglare's y counts from the bottom
    esum = np.bincount(lab, cosw, n + 1)[1:]
    count = np.bincount(lab, None, n + 1)[1:]
    lmax = np.zeros(n + 1)
    np.maximum.at(lmax, lab, lum[rows, cols])
    out = []
    for k in np.flatnonzero(count > 0):
        px, py = xsum[k] / lsum[k], ysum[k] / lsum[k]
        col, row_b = int(px), int(py)  # evalglare's pict_get_dir takes whole pixels
        d = dirs[h - 1 - min(row_b, h - 1), min(col, w - 1)]
        p = float(position_index(d[None, :], view)[0])
        out.append(GlareSource(float(lsum[k] / osum[k]), float(osum[k]), p, int(count[k]), float(px),
                               float(h - py), tuple(float(v) for v in d), float(lmax[k + 1]), float(esum[k])))
    return out


def glare_metrics(lum: np.ndarray, view: ViewSpec, *, threshold: float = DEFAULT_THRESHOLD,
                  peak_extraction: bool = True, view_text: str = "") -> GlareResult:
    """The metrics of a luminance picture ``lum`` ``(H, W)`` in cd/m^2 (Radiance's weights)."""
    if not (threshold > 0 and math.isfinite(threshold)):
        raise UsageError(f"--threshold: expected a positive factor (<= 100) or luminance (> 100), not {threshold:g}")
    lum = np.asarray(lum, np.float64)
    check_luminance(lum)
    h, w = lum.shape
    dirs, omega = pixel_geometry(h, w, view)
    vdir = _frame(view)[0]
    cos_t = dirs @ vdir
    valid = omega > 0
    if view.vtype == "a":
        valid &= cos_t >= 0.0
    lum = np.where(valid, lum, 0.0)
    om = np.where(valid, omega, 0.0)
    ev = float(np.sum(cos_t * om * lum))
    avlum = float(np.sum(om * lum) / np.sum(om)) if np.sum(om) > 0 else 0.0
    limit = threshold if threshold > 100 else threshold * avlum
    labels = _clusters(valid & (lum > limit), dirs, SEARCH_ANGLE)
    if peak_extraction and labels.any() and float(lum[labels > 0].max()) > PEAK_LIMIT:
        from scipy import ndimage

        high = (labels > 0) & (lum >= PEAK_LIMIT)
        nxt = int(labels.max())
        boxes = ndimage.find_objects(labels)  # each source's bounding box: the work stays in it
        for k in np.unique(labels[high]):
            box = boxes[k - 1]
            region = labels[box]  # a view: the new labels land in ``labels``
            sub = _clusters(high[box] & (region == k), dirs[box], SEARCH_ANGLE)
            region[sub > 0] = sub[sub > 0] + nxt
            nxt += int(sub.max())
    sources = _sources(lum, om, dirs, labels, view)
    edir = float(sum(s.illuminance for s in sources))
    lb = (ev - edir) / math.pi
    return GlareResult(ev, _dgp(ev, sources), *_dgi_ugr(lb, sources), lb, avlum, edir, float(limit), view_text,
                       sources)


def _dgp(ev: float, sources) -> float:
    if ev <= 0:
        return 0.0
    s = sum(x.luminance ** 2 * x.solid_angle / x.position_index ** 2 for x in sources)
    dgp = 5.87e-5 * ev + 0.159 + (0.092 * math.log10(1.0 + s / ev ** 1.87) if sources else 0.0)
    return min(dgp, 1.0)


def _dgi_ugr(lb: float, sources) -> Tuple[float, float]:
    if not sources:
        return 0.0, 0.0
    dgi_sum = sum(0.478 * s.luminance ** 1.6 * (s.solid_angle / s.position_index ** 2) ** 0.8 /
                  (lb + 0.07 * s.solid_angle ** 0.5 * s.luminance) for s in sources)
    ugr_sum = sum((s.luminance / s.position_index) ** 2 * s.solid_angle for s in sources)
    dgi = 10.0 * math.log10(dgi_sum) if dgi_sum > 0 else 0.0
    ugr = 8.0 * math.log10(0.25 / lb * ugr_sum) if lb > 0 and ugr_sum > 0 else (-99.0 if lb <= 0 else 0.0)
    return dgi, ugr


def read_luminance_map(path) -> Tuple[np.ndarray, Optional[str]]:
    """``(L (H, W) cd/m^2 with Radiance's weights, VIEW text or None)`` of a map: an
    hdrcl map in cd/m^2 (``.hdr`` or EXR) or a foreign Radiance picture (179 lm/W)."""
    from hdrcl.io.outmeta import hdr_header
    from hdrcl.io.radiance import read_radiance, white_luminance

    name = os.fspath(path)
    pixels, meta = read_radiance(name, require_float=True)
    rgb = np.asarray(pixels, np.float64)
    units = str(meta.get("units", ""))
    is_hdr = name.lower().endswith((".hdr", ".pic", ".rgbe"))
    view = hdr_header(name)["view"] if is_hdr else None
    view = view or meta.get("view")
    if is_hdr and not units:
        rgb = rgb * 179.0  # Radiance's convention
    elif not units.startswith("cd/m2"):
        white = white_luminance(name)
        if white is None:
            raise InputError(f"{name}: not a luminance map (relative units); merge with --absolute, "
                             "--reference-patch or the luminance options (--lens-circle ...)")
        rgb = rgb * white
    lum = rgb[..., 0] if rgb.shape[2] == 1 else rgb @ RADIANCE_CIE
    check_luminance(lum, name)
    return lum, view


def check_luminance(lum: np.ndarray, where: str = "luminance map") -> None:
    """Refuse (:class:`InputError`, exit 3) a map with negative or non-finite luminance:
    no light is negative, and every figure here (Ev, the average, DGP) sums it; a map
    whose luminances are all negative gave Ev -30.7 lx and an average of -16.7 cd/m2."""
    lum = np.asarray(lum)
    bad = ~np.isfinite(lum)
    if bad.any():
        raise InputError(f"{where}: not a usable luminance map ({int(bad.sum())} NaN or infinite luminance(s))")
    neg = lum < 0
    if neg.any():
        raise InputError(f"{where}: not a usable luminance map ({int(neg.sum())} of {lum.size} pixel(s) have negative "
                         f"luminance, down to {float(lum.min()):.4g} cd/m2); light is not negative: check how it "
                         "was made (a calibration, a subtraction)")


def glare_of_file(path, *, view: Optional[str] = None, threshold: float = DEFAULT_THRESHOLD) -> GlareResult:
    """:func:`glare_metrics` of a map file; ``view`` overrides its ``VIEW=``."""
    lum, file_view = read_luminance_map(path)
    text = view or file_view
    if not text:
        raise UsageError(f"{os.fspath(path)}: the map has no VIEW= (give --view, e.g. '-vta -vh 180 -vv 180')")
    where = "--view" if view else f"{os.fspath(path)}: VIEW="
    return glare_metrics(lum, parse_glare_view(text, where), threshold=threshold, view_text=text)


def _parse_patch(text) -> Tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in str(text).split(","))
    except ValueError:
        vals = ()
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals) or not vals[2] > 0:
        raise UsageError(f"--patch: expected COLUMN,ROW,RADIUS in pixels of the map (radius > 0), not '{text}'")
    return vals


def calibration_from_measurement(path, *, illuminance: Optional[float] = None, luminance: Optional[float] = None,
                                 patch=None, view: Optional[str] = None) -> dict:
    """The calibration factor that makes a map agree with a measurement: a vertical
    illuminance at the lens (``illuminance``, lux; the map's ``Ev`` computed as evalglare
    does) or a patch's luminance (``luminance`` cd/m^2 in the disc ``patch`` =
    ``column,row,radius``, pixel centres from the top left). A map made with a
    calibration factor ``K0`` (its ``luminanceChain``) gives ``K = K0 x measured /
    map``, the factor to use in its place."""
    import json

    if (illuminance is None) == (luminance is None):
        raise UsageError("calibrate-luminance: give one of --illuminance LUX or --luminance CD with --patch")
    measured = float(illuminance if illuminance is not None else luminance)
    flag = "--illuminance" if illuminance is not None else "--luminance"
    if not (measured > 0 and math.isfinite(measured)):
        raise UsageError(f"{flag}: expected a positive measurement, not {measured:g}")
    lum, file_view = read_luminance_map(path)
    if illuminance is not None:
        text = view or file_view
        if not text:
            raise UsageError(f"{os.fspath(path)}: the map has no VIEW= (give --view, e.g. '-vta -vh 180 -vv 180')")
        where = "--view" if view else f"{os.fspath(path)}: VIEW="
        value = glare_metrics(lum, parse_glare_view(text, where), view_text=text).vertical_illuminance
        what = "vertical illuminance (lx)"
    else:
        if patch is None:
            raise UsageError("--luminance: needs --patch COLUMN,ROW,RADIUS (the measured spot on the map)")
        cx, cy, r = _parse_patch(patch)
        rows, cols = np.mgrid[0:lum.shape[0], 0:lum.shape[1]]
        disc = np.hypot(cols + 0.5 - cx, rows + 0.5 - cy) <= r  # no squares: 1e200 would overflow to inf
        if not disc.any():
            raise UsageError(f"--patch: {patch} holds no pixel centre of the {lum.shape[1]}x{lum.shape[0]} map")
        value = float(np.mean(lum[disc]))
        what = f"mean luminance (cd/m2) of {int(disc.sum())} pixel(s)"
    if not (value > 0 and math.isfinite(value)):
        raise InputError(f"{os.fspath(path)}: the map's {what} is {value:g}; nothing to calibrate against")
    from hdrcl.io.radiance import read_metadata

    previous = 1.0
    chain = read_metadata(os.fspath(path)).get("luminanceChain")
    if chain:
        try:
            previous = float(json.loads(chain).get("calibrationFactor", 1.0))
        except (ValueError, TypeError, AttributeError):
            previous = 1.0
    k = previous * measured / value
    from hdrcl.io.radcal import check_factor_range

    # refused where it is made: merge --calibration-factor would refuse it (a K of 3.62e298
    # from --illuminance 1e300)
    check_factor_range(k, f"{flag} {measured:g} (calibration factor {previous:g} x measured / map {value:.6g})")
    return {"calibration_factor": k, "measured": measured, "map_value": value, "quantity": what,
            "previous_factor": previous}


def calibrate_luminance_file(path, output, *, illuminance: Optional[float] = None, luminance: Optional[float] = None,
                             patch=None, view: Optional[str] = None) -> dict:
    """:func:`calibration_from_measurement`, written to ``output`` as the lab's
    calibration factor ``.cal`` (:func:`hdrcl.io.radcal.write_calibration_factor`)."""
    from hdrcl.io.radcal import write_calibration_factor

    r = calibration_from_measurement(path, illuminance=illuminance, luminance=luminance, patch=patch, view=view)
    note = (f"hdrcl calibrate-luminance: measured {r['measured']:g}, map {r['map_value']:.6g} "
            f"({r['quantity']}), map made with K={r['previous_factor']:g}")
    write_calibration_factor(output, r["calibration_factor"], note)
    return r
