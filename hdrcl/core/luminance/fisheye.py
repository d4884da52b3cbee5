"""Calibrated luminance maps from fisheye brackets, in the one pass of the fusion.

The lighting researchers' chain (Pierson et al. 2019; radiantlab's HDRICalibrationTool:
hdrgen, then per image pcompos, pfilt, pcomb with ``fisheye_corr.cal``, the vignetting,
neutral density and calibration ``.cal`` files, ``getinfo -a VIEW=``, evalglare's
vertical illuminance) as a sink of the fused radiance strips (:class:`LuminanceChain`):

1. ``--lens-circle CX,CY,DIAMETER`` (pixels of the merged image, origin top left, pixel
   edges at integers): the square ``round(CX - D/2), round(CY - D/2)``, side
   ``round(D)``, is kept and every pixel whose centre lies farther than ``D/2`` from
   ``(CX, CY)`` is set to 0. The square must lie inside the image.
2. ``--resize N`` (default 1000): the square is area-averaged into ``N x N`` as the strips
   come (memory: the ``N x N`` output in float64).
3. at the end, in this order: ``--fisheye-projection equisolid-to-equidistant``,
   ``--vignetting``, ``--nd-filter``, ``--calibration-factor``
   (:mod:`hdrcl.core.luminance.fisheye_math`, :mod:`hdrcl.io.radcal`).

The strips must be in cd/m^2 (the merge's absolute scale, ``--absolute`` or
``--reference-patch``; the chain multiplies by K). Files: ``.hdr`` holds the values
divided by 179 (Radiance's convention: ``179 (0.265 R + 0.670 G + 0.065 B)`` is cd/m^2),
with ``VIEW=`` and ``VERTICAL_ILLUMINANCE=`` lines and no ``EXPOSURE=``; EXR, TIFF and PFM
hold cd/m^2 (EXR: ``hdrcl:units = cd/m2`` and OpenEXR's ``whiteLuminance = 1``).
``--view`` (a Radiance view, e.g. ``"-vta -vh 186 -vv 186"``) defaults to
``-vta -vh 180 -vv 180`` when the projection is corrected (the formula's edge is 90
degrees off axis) and is left out otherwise. The vertical illuminance at the lens is
computed for ``-vta`` views (:func:`hdrcl.core.luminance.fisheye_math.vertical_illuminance`).
"""
from __future__ import annotations

import json
import logging
import math
import os
from typing import Optional, Tuple

import numpy as np

from hdrcl.core.luminance import fisheye_math as fm
from hdrcl.core.luminance.border import BorderMeter
from hdrcl.errors import InputError, ProcessingError, UsageError
from hdrcl.io.radcal import (RadialProjection, Vignetting, calibration_factor_option, check_factor_range,
                             nd_filter_option, read_projection, vignetting_option)

logger = logging.getLogger(__name__)

PROJECTIONS = ("equisolid-to-equidistant",)
DEFAULT_RESIZE = 1000
MAX_RESIZE = 16384
#: The largest lens circle (pixels): beyond any camera's sensor (a 400 MP frame is 24,500 wide).
MAX_DIAMETER = 100000
DEFAULT_VIEW = "-vta -vh 180 -vv 180"
_VIEW_TYPES = ("v", "l", "a", "h", "s", "c")
#: Radiance's view parser's limits (``setview``): (largest -vh, -vh may equal it,
#: largest -vv, -vv may equal it); 0 < angle always; None: no limit (-vtl, in world units).
_VIEW_LIMITS = {"v": (180.0, False, 180.0, False), "h": (180.0, True, 180.0, True),
                "a": (360.0, True, 360.0, True), "c": (360.0, True, 180.0, False),
                "s": (360.0, False, 360.0, False), "l": (None, True, None, True)}
_VIEW_ARGS = {"-vp": 3, "-vd": 3, "-vu": 3, "-vh": 1, "-vv": 1, "-vo": 1, "-va": 1, "-vs": 1, "-vl": 1}


def parse_lens_circle(value) -> Tuple[float, float, float]:
    """``CX,CY,DIAMETER`` in pixels (a string or a 3-sequence)."""
    try:
        vals = tuple(float(v) for v in (value.split(",") if isinstance(value, str) else value))
    except (TypeError, ValueError):
        vals = ()
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals) or not 2 <= vals[2] <= MAX_DIAMETER:
        raise UsageError(f"--lens-circle: expected CX,CY,DIAMETER in pixels (DIAMETER 2..{MAX_DIAMETER}), "
                         f"not '{value}'")
    return vals


def _check_view_vectors(vecs: dict, text) -> None:
    """Radiance's ``setview``: a view direction, and an up vector not parallel to it."""
    d, u = np.asarray(vecs["-vd"], np.float64), np.asarray(vecs["-vu"], np.float64)
    if not np.linalg.norm(d) > 0:
        raise UsageError(f"--view: -vd must not be 0 0 0 (Radiance's view parser: zero view direction): '{text}'")
    if not np.linalg.norm(np.cross(d, u)) > 1e-6 * np.linalg.norm(d) * max(np.linalg.norm(u), 1e-300):
        raise UsageError(f"--view: -vu is parallel to -vd (Radiance's view parser refuses it): '{text}'")


def parse_view(text) -> Tuple[str, str, float, float]:
    """A Radiance view (``-vta -vh 186 -vv 186``): ``(text, type, vh, vv)``."""
    words = str(text).split()
    vtype, vh, vv, i = "v", 45.0, 45.0, 0
    vecs = {"-vd": [0.0, 1.0, 0.0], "-vu": [0.0, 0.0, 1.0]}
    while i < len(words):
        w = words[i]
        if len(w) == 4 and w.startswith("-vt") and w[3] in _VIEW_TYPES:
            vtype, i = w[3], i + 1
            continue
        n = _VIEW_ARGS.get(w)
        try:
            args = [float(a) for a in words[i + 1:i + 1 + (n or 0)]]
        except ValueError:
            args = []
        if n is None or len(args) != n or not all(math.isfinite(a) for a in args):
            raise UsageError(f"--view: expected Radiance view options such as '-vta -vh 186 -vv 186', not '{text}'")
        if w == "-vh":
            vh = args[0]
        elif w == "-vv":
            vv = args[0]
        elif w in ("-vd", "-vu"):
            vecs[w] = args
        i += 1 + n
    _check_view_vectors(vecs, text)
    if not words:
        raise UsageError("--view: expected Radiance view options such as '-vta -vh 186 -vv 186', not ''")
    for name, angle, (limit, closed) in (("-vh", vh, _VIEW_LIMITS[vtype][:2]), ("-vv", vv, _VIEW_LIMITS[vtype][2:])):
        if not angle > 0 or (limit is not None and (angle > limit or (angle == limit and not closed))):
            bound = "" if limit is None else f" {'up to' if closed else 'below'} {limit:g} degrees"
            raise UsageError(f"--view: {name} {angle:g} is not a -vt{vtype} view's size (Radiance's view parser "
                             f"takes more than 0{bound}): '{text}'")
    return " ".join(words), vtype, vh, vv


def chain_or_none(*, lens_circle=None, resize=None, projection=None, vignetting=None, nd_filter=None,
                  calibration_factor=None, view=None, device=None, output=None) -> Optional["LuminanceChain"]:
    """The chain of the command-line options, or None when none is given; the other
    options without ``--lens-circle`` are a usage error naming them."""
    if lens_circle is None:
        given = [flag for flag, v in (("--resize", resize), ("--fisheye-projection", projection),
                                      ("--vignetting", vignetting), ("--nd-filter", nd_filter),
                                      ("--calibration-factor", calibration_factor), ("--view", view)) if v is not None]
        if given:
            raise UsageError(f"{given[0]}: needs --lens-circle (a fisheye luminance map)")
        return None
    return LuminanceChain.from_options(lens_circle=lens_circle, resize=DEFAULT_RESIZE if resize is None else resize,
                                       projection=projection, vignetting=vignetting, nd_filter=nd_filter,
                                       calibration_factor=calibration_factor, view=view, device=device, output=output)


class LuminanceChain:
    """The chain as a sink of fused strips; build it with :meth:`from_options`.

    ``write_rows(y0, y1, strip)`` takes rows of the merged image (cd/m^2), in order;
    :meth:`finish` returns the ``N x N`` map (cd/m^2, float32) and sets
    :attr:`vertical_illuminance` (lux, or None when the view is not ``-vta``).
    """

    def __init__(self, lens_circle, resize, projection, vignetting: Optional[Vignetting], nd_filter,
                 calibration_factor: float, view: Optional[str], device=None):
        self.lens_circle, self.size, self.projection = lens_circle, resize, projection
        self.vignetting, self.nd_filter, self.calibration_factor = vignetting, nd_filter, calibration_factor
        self.view = parse_view(view) if view is not None else None
        self.device = device
        self.vertical_illuminance: Optional[float] = None
        self._output = None  # the file to write, when from_options was told (factor ranges)
        self.backend = "numpy"
        self._acc = None
        self._box = None
        self.border = None  # a BorderMeter once bound
        self._rows_seen = 0

    @classmethod
    def from_options(cls, *, lens_circle, resize=DEFAULT_RESIZE, projection=None, vignetting=None, nd_filter=None,
                     calibration_factor=None, view=None, device=None, output=None) -> "LuminanceChain":
        """Every option checked (UsageError names the flag; a bad ``.cal`` file is an
        InputError naming it). ``lens_circle`` is required; the others may be None.
        ``output`` (the file to write, when known): the calibration and ND factors are
        checked against what its format holds (:func:`hdrcl.io.radcal.check_factor_range`),
        else against float32's range."""
        circle = parse_lens_circle(lens_circle)
        try:
            n = int(resize)
        except (TypeError, ValueError):
            n = 0
        if isinstance(resize, bool) or not (2 <= n <= MAX_RESIZE) or float(resize) != n:
            raise UsageError(f"--resize: expected a whole number of pixels in 2..{MAX_RESIZE}, not '{resize}'")
        if projection is not None and not isinstance(projection, RadialProjection) and projection not in PROJECTIONS:
            if not str(projection).lower().endswith(".cal"):
                raise UsageError(f"--fisheye-projection: '{projection}' is not one of {', '.join(PROJECTIONS)} "
                                 f"or a .cal file with rad(r) (Radiance's fisheye_corr.cal)")
            if not os.path.isfile(os.fspath(projection)):
                raise InputError(f"{projection}: no such file (--fisheye-projection)")
            projection = read_projection(projection)
        vig = vignetting_option(vignetting) if vignetting is not None else None
        nd = nd_filter_option(nd_filter) if nd_filter is not None else None
        k = calibration_factor_option(calibration_factor) if calibration_factor is not None else 1.0
        for f in {min(nd or (1.0,)), max(nd or (1.0,))}:
            check_factor_range(k * f, "--calibration-factor" if nd is None else "--nd-filter with --calibration-factor",
                               output=output)
        if view is None and projection is not None:
            view = DEFAULT_VIEW
        chain = cls(circle, n, projection, vig, nd, k, view, device)
        chain._output = output
        if vig is not None:
            chain._check_vignetting()
        return chain

    # -- geometry ------------------------------------------------------------------
    def _vig_geometry(self):
        """The file's centre and radius constants, or the map's ``N/2`` where it has none."""
        v, half = self.vignetting, self.size / 2.0
        return (v.xc if v.xc is not None else half, v.yc if v.yc is not None else half,
                v.radius if v.radius is not None else half)

    def _check_vignetting(self) -> None:
        """The correction must be finite and positive over the view (r in 0..1); a file
        made for another map size is warned about."""
        warning = self.vignetting.check_geometry(self.size)
        if warning:
            logger.warning("%s", warning)
        f = self._vignetting_factors()
        inside = fm.inside_view(self.size)
        if not np.all(np.isfinite(f[inside]) & (f[inside] > 0)):
            what = "the correction 1/(a0 + a1 r + ... + a8 r^8)" if self.vignetting.program is None else \
                "the correction ro/ri(1), go/gi(1), bo/bi(1)"
            raise UsageError(f"--vignetting: {what} of {self.vignetting.source} is not finite and positive "
                             f"over the lens circle")
        nd = np.asarray(self.nd_filter if self.nd_filter is not None else (1.0, 1.0, 1.0), np.float64)
        for value in (float(f[inside].min()) * self.calibration_factor * float(nd.min()),
                      float(f[inside].max()) * self.calibration_factor * float(nd.max())):
            check_factor_range(value, f"--vignetting ({self.vignetting.source}, with the ND and calibration factors)",
                               output=self._output)

    def _vignetting_factors(self) -> np.ndarray:
        """``(N, N, 3)`` factors of the vignetting step (float64); outside the view,
        where the map is black, a non-finite factor is 0."""
        v = self.vignetting
        if getattr(self, "_vig_factors", None) is not None:
            return self._vig_factors
        if v.program is not None:
            f = v.factors(self.size)
        else:
            xc, yc, radius = self._vig_geometry()
            f = np.repeat(fm.vignetting_factors(self.size, v.coefficients, xc, yc, radius)[..., None], 3, axis=2)
        outside = ~fm.inside_view(self.size)
        f[outside[..., None] & ~np.isfinite(f)] = 0.0
        self._vig_factors = f  # evaluated once: checked by from_options, applied by finish
        return f

    def crop_box(self) -> Tuple[int, int, int]:
        """``(left, top, side)`` of the square around the lens circle, in pixels."""
        cx, cy, d = self.lens_circle
        return int(round(cx - d / 2.0)), int(round(cy - d / 2.0)), int(round(d))

    def bind(self, height: int, width: int, nch: int) -> None:
        """Check the circle against the merged image's size; reset the accumulator.

        A circle cut by the image's edges (a circular fisheye on a smaller sensor) is
        padded with black, as ``pcompos`` does; its centre must lie inside the image."""
        left, top, side = self.crop_box()
        cx, cy, d = self.lens_circle
        if not (0 <= cx <= width and 0 <= cy <= height):
            raise UsageError(f"--lens-circle: the centre {cx:g},{cy:g} lies outside the {width}x{height} image")
        if d > 2.0 * math.hypot(width, height):
            raise UsageError(f"--lens-circle: the diameter {d:g} is more than twice the {width}x{height} image's "
                             f"diagonal (a lens circle lies mostly on the sensor)")
        if left < 0 or top < 0 or left + side > width or top + side > height:
            logger.info("--lens-circle: the circle %g,%g,%g runs outside the %dx%d image: padded with black",
                        cx, cy, d, width, height)
        self._box = (left, top, side)
        self._image = (height, width)
        self.border = BorderMeter(cx, cy, d, height, width)  # does the circle fit the dark border?
        self._acc = np.zeros((self.size, self.size, nch), np.float64)
        self._rows_seen = 0

    @property
    def output_size(self) -> Tuple[int, int]:
        return self.size, self.size

    # -- the sink ------------------------------------------------------------------
    def write_rows(self, y0: int, y1: int, data: np.ndarray) -> None:
        if self._acc is None:  # not bound by the caller: the height is checked at the end
            self.bind(max(y1, sum(self.crop_box()[1:])), data.shape[1], data.shape[2])
        left, top, side = self._box
        self.border.add(y0, data)
        a, b = max(y0, top), min(y1, top + side)
        self._rows_seen = y1
        if a >= b:
            return
        c0, c1 = max(left, 0), min(left + side, data.shape[1])
        if c0 == left and c1 == left + side:
            rows = np.array(data[a - y0:b - y0, left:left + side], np.float32)
        else:  # the square reaches past the image's sides: black there
            rows = np.zeros((b - a, side, data.shape[2]), np.float32)
            if c1 > c0:
                rows[:, c0 - left:c1 - left] = data[a - y0:b - y0, c0:c1]
        self._mask(rows, a)
        # rows first (float32 sums of about S/N + 1 terms), then the columns of the
        # fewer rows; the output accumulates in float64
        k0, merged = fm.row_average(rows, side, self.size, a - top)
        self._acc[k0:k0 + merged.shape[0]] += fm.column_average(merged, self.size)

    def _mask(self, rows: np.ndarray, y: int) -> None:
        """Zero the pixels of ``rows`` (image rows ``y ..``) whose centre lies outside the circle."""
        cx, cy, d = self.lens_circle
        left, _, side = self._box
        dy = np.arange(y, y + rows.shape[0], dtype=np.float64) + 0.5 - cy
        half = np.sqrt(np.maximum((d / 2.0) ** 2 - dy ** 2, 0.0)) * np.where(np.abs(dy) <= d / 2.0, 1, -1)
        # inside: |x + 0.5 - cx| <= half, i.e. column indices lo .. hi - 1 (of the crop)
        lo = np.clip(np.ceil(cx - half - 0.5) - left, 0, side).astype(np.int64)
        hi = np.clip(np.floor(cx + half - 0.5) + 1 - left, 0, side).astype(np.int64)
        for j in range(rows.shape[0]):
            if hi[j] <= lo[j]:
                rows[j] = 0.0
            else:
                rows[j, :lo[j]] = 0.0
                rows[j, hi[j]:] = 0.0

    def finish(self) -> np.ndarray:
        """The corrected ``N x N`` map in cd/m^2 (float32); computes the vertical illuminance."""
        if self._acc is None:
            raise ProcessingError("the luminance chain received no image")
        left, top, side = self._box
        if self._rows_seen < min(top + side, getattr(self, "_image", (top + side,))[0]):
            raise UsageError(f"--lens-circle: the square {left},{top} side {side} runs below the image "
                             f"({self._rows_seen} rows)")
        img = self._acc
        proc = self._processor()
        if isinstance(self.projection, RadialProjection):
            img = fm.project_radial(img, self.projection.source_radius)
        elif self.projection is not None:
            img = proc.project(img) if proc is not None else fm.equisolid_to_equidistant(img)
        if self.vignetting is not None and self.vignetting.program is not None:
            f = self._vignetting_factors()
            img = np.asarray(img, np.float64) * (f if img.shape[2] == 3 else (f @ fm.RADIANCE_LUMA)[..., None])
        elif self.vignetting is not None:
            xc, yc, radius = self._vig_geometry()
            coeffs = self.vignetting.coefficients
            img = proc.vignette(img, coeffs, xc, yc, radius) if proc is not None else \
                fm.apply_vignetting(img, coeffs, xc, yc, radius)
        img = np.asarray(img, np.float64) * self._factors(img.shape[2])
        if self.view is not None and self.view[1] == "a":
            self.vertical_illuminance = fm.vertical_illuminance(img, self.view[2])
        bad = ~np.isfinite(img)
        if bad.any():
            raise ProcessingError(f"the luminance chain produced {int(bad.sum())} non-finite value(s)")
        return img.astype(np.float32)

    def _factors(self, nch: int) -> np.ndarray:
        nd = np.asarray(self.nd_filter if self.nd_filter is not None else (1.0, 1.0, 1.0), np.float64)
        if nch == 1:
            nd = np.array([float(nd @ fm.RADIANCE_LUMA)])
        return nd * self.calibration_factor

    def _processor(self):
        """The OpenCL twin of the projection and vignetting steps, or None (NumPy)."""
        if self.projection is None and self.vignetting is None:
            return None
        from hdrcl.core.pipeline import fusion_processor

        fusion = fusion_processor(self.device, self.size * self.size)  # by size and device alone (issue 25)
        if fusion is None:
            return None
        from hdrcl.cl.fisheye import FisheyeProcessor

        self.backend = "opencl"
        return FisheyeProcessor(ctx=fusion.ctx)

    # -- the file ------------------------------------------------------------------
    def file_values(self, output: str, image: np.ndarray) -> np.ndarray:
        """What the file stores: cd/m^2, or for ``.hdr`` cd/m^2 / 179 (Radiance)."""
        from hdrcl.core.encode import hdr_factor

        factor = hdr_factor(output, "cd/m2")
        return image if factor == 1.0 else (image.astype(np.float64) * factor).astype(np.float32)

    def describe(self) -> dict:
        """The options, for metadata and reports."""
        proj = self.projection.describe() if isinstance(self.projection, RadialProjection) else self.projection
        d = {"lensCircle": list(self.lens_circle), "resize": self.size, "projection": proj,
             "vignetting": None if self.vignetting is None else self._describe_vignetting(),
             "ndFilter": None if self.nd_filter is None else list(self.nd_filter),
             "calibrationFactor": self.calibration_factor}
        return {k: v for k, v in d.items() if v is not None}

    def _describe_vignetting(self) -> dict:
        v = self.vignetting
        d = {"centre_radius": list(self._vig_geometry()), "source": v.source}
        if v.program is not None:
            d["program"] = v.program.canonical()
        else:
            d["coefficients"] = list(v.coefficients)
        return d

    def writer_args(self, metadata: dict, camera: dict):
        """``(metadata, camera, width, height)`` for the file's writer: the caller's
        metadata and standard camera mapping adapted to the calibrated map."""
        m = {k: v for k, v in (metadata or {}).items() if k not in ("referenceExposure", "halfScale")}
        m["units"] = "cd/m2"
        m["luminanceChain"] = json.dumps(self.describe(), sort_keys=True)
        cam = {k: v for k, v in (camera or {}).items() if k not in ("exposure_time", "fnumber", "iso")}
        cam["units"] = "cd/m2"
        if self.view is not None:
            m["view"] = self.view[0]
            cam["view"] = self.view[0]
        if self.vertical_illuminance is not None:
            m["verticalIlluminance"] = round(self.vertical_illuminance, 6)
            cam["vertical_illuminance"] = self.vertical_illuminance
        return m, cam, self.size, self.size
