"""The encode stage: what 1.0 means in a radiance file, how its values are stored, and
fusing a bracket into it.

**Scale.** hdrcl computes radiance relative to a 1 s exposure (the paper's ``E``). A
file holds ``E x t_ref`` instead, where ``t_ref`` is the *reference exposure*: a value
of 1.0 is what a frame of ``t_ref`` seconds, at the reference f-number and ISO, records
as full white (linearised). By default ``t_ref`` is the power of two nearest the
bracket's middle exposure (geometric), so ordinary scenes sit in the middle of the half
float range and other tools show the image as bright as its middle frame; being a
power of two, the scaling is exact in binary floating point. ``hdrcl batch`` gives every
set of one camera the same ``t_ref`` (one radiometric scale across a shoot), and
``reference_exposure`` / ``--reference-exposure`` set it explicitly. The reference is
recorded in standard metadata: OpenEXR's ``expTime`` (with ``aperture`` and
``isoSpeed``) and ``hdrcl:referenceExposure``, Radiance's ``EXPOSURE=`` line (stored =
original x EXPOSURE, Radiance's own convention), and the TIFF's hdrcl JSON. PFM files
have no metadata and hold ``E`` as is; so do maps in absolute units (cd/m^2), except a
``.hdr``, which holds them in Radiance's units (cd/m^2 / 179, :func:`hdr_factor`,
``whiteEfficacy`` on its ``HDRCL=`` line, no ``EXPOSURE=`` line). A
calibrated fisheye luminance map (``chain=``, :mod:`hdrcl.core.luminance.fisheye`) is absolute
too: written once its ``N x N`` result is known (:func:`fuse_through_chain`), with no
reference exposure and no ``EXPOSURE=`` line.

**Storage.** An EXR is half float whenever the values fit (``--dtype auto``, the
default, and ``--dtype half``). The range is measured on the merged data as it streams
(:class:`RangeMeter`), not predicted from the curve's ends: the fusion writes half
optimistically and, only when a strip holds a value half cannot (beyond 65504, or a
positive value below 2^-16), it measures the rest and fuses again into float (``auto``,
and always for absolute units) or into half rescaled by a recorded power of two
(``--dtype half``: ``hdrcl:halfScale``). A calibrating merge reads the second pass from
its decoded-frame cache, so nothing is decoded twice.

**One pass.** Each strip is scaled by the reference exposure, measured and converted to
the file's type in one walk over cache-sized blocks, straight into the EXR encoder's
batch (:meth:`hdrcl.io.writers.RadianceWriter.write_scaled`,
:class:`hdrcl.io.halfrange.OnePass`): the strip the fusion hands over is read once and
never copied or changed; the file is the one ``strip * scale`` would give, bit for bit.
"""
from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from hdrcl.io import halfrange

logger = logging.getLogger(__name__)

#: Output types whose metadata can say what 1.0 means (they hold ``E x t_ref``).
SCALED_EXTENSIONS = (".exr", ".hdr", ".tif", ".tiff")
#: Radiance's luminous efficacy of its white (lm/W): a ``.hdr`` in Radiance's units holds
#: cd/m^2 / 179 (``179 (0.265 R + 0.670 G + 0.065 B)`` is the luminance).
RADIANCE_WHITE_EFFICACY = 179.0


def hdr_factor(output: str, units: str) -> float:
    """What a map's values are multiplied by in the file: ``1/179`` for a ``.hdr`` in
    absolute units (``units`` cd/m2: Radiance reads it as radiance in its 179 lm/W
    convention), 1 otherwise."""
    ext = os.path.splitext(os.fspath(output))[1].lower()
    return 1.0 / RADIANCE_WHITE_EFFICACY if ext == ".hdr" and units.startswith("cd/m2") else 1.0


def default_reference(times: Sequence[float]) -> float:
    """The power of two nearest the geometric middle of ``times`` (seconds).

    The middle is the median of the log exposures, so one odd frame does not move it.
    """
    t = np.asarray([v for v in np.asarray(times, np.float64).ravel() if v > 0 and math.isfinite(v)])
    if not t.size:
        return 1.0
    return float(2.0 ** round(float(np.median(np.log2(t)))))


def reference_for(output: str, times: Sequence[float], given: Optional[float], units: str) -> float:
    """The reference exposure a file of ``output``'s type gets: 1.0 for PFM and for
    absolute units, else ``given`` or :func:`default_reference`."""
    ext = os.path.splitext(os.fspath(output))[1].lower()
    if units != "relative" or ext not in SCALED_EXTENSIONS:
        return 1.0
    return float(given) if given is not None else default_reference(times)


class RangeMeter:
    """A sink that scales strips to the file's values, measures their positive range
    and hands them to ``sink`` while they fit half floats (``check``).

    Once a strip does not fit, nothing more is forwarded (the file will be written
    again) but the measuring goes on, so that the second pass knows the whole range.
    """

    def __init__(self, sink, scale: float, check: bool):
        self.sink, self.scale, self.check = sink, np.float32(scale), check
        self.lo, self.hi = math.inf, 0.0
        self.overflow = False
        self._one = halfrange.OnePass()

    def write_rows(self, y0: int, y1: int, data: np.ndarray) -> None:
        """Measure ``data x scale`` (pixels without data are 0 and are not counted; NaN
        or Inf make ``hi`` infinite: half cannot hold them, float keeps what there is)
        and, until a strip does not fit, write it: in one pass with the writer's
        ``write_scaled`` (:class:`hdrcl.io.halfrange.OnePass`), which returns the range.
        A strip that does not fit may already be in the writer; the writer is dropped."""
        if self.overflow:
            self._take(self._one.measure(data, float(self.scale)))
        elif hasattr(self.sink, "write_scaled"):
            self._take(self.sink.write_scaled(y0, y1, data, float(self.scale)))
        else:
            values = data * self.scale if self.scale != 1 else data
            if not self._take(self._one.measure(values, 1.0)):
                self.sink.write_rows(y0, y1, values)

    def _take(self, found: halfrange.StripRange) -> bool:
        """Count a strip's range in; whether the file must be written again."""
        self.lo, self.hi = min(self.lo, found.lo), max(self.hi, found.hi)
        if self.check and not self.overflow and (self.hi > halfrange.HALF_MAX or self.lo < halfrange.HALF_FLOOR):
            self.overflow = True
        return self.overflow


@dataclass
class Stored:
    """How a radiance file was written."""

    dtype: str  # "half" or "float" (EXR); the writer's own type elsewhere
    reference: float  # t_ref: file value = E (1 s) x reference x half_scale
    half_scale: float = 1.0
    lo: float = math.nan  # measured positive range of the file's values
    hi: float = math.nan
    note: Optional[str] = None  # the storage decision, when it was not plain half
    passes: int = 1


def radiance_opener(output: str, width: int, height: int, nch: int, metadata: dict, camera: dict, *,
                    compression: str, timestamp, colorspace: str) -> Callable:
    """The ``open_writer(dtype, half_scale, chain=None)`` of :func:`fuse_to_file` for a
    merge writing ``output``: a :class:`hdrcl.io.writers.RadianceWriter` of the merged
    size, or of a luminance chain's ``N x N`` map with its metadata
    (``chain.writer_args``); ``hdrcl:halfScale`` when a half is rescaled. ``metadata``
    is read when the writer opens (later additions count)."""
    from hdrcl.io.writers import RadianceWriter

    def open_writer(dtype, half_scale, chain=None):
        m, cam, w, h = dict(metadata), camera, width, height
        if chain is not None:  # the chain's N x N map: its units, VIEW=, vertical illuminance
            m, cam, w, h = chain.writer_args(m, cam)
        if half_scale != 1.0:
            m["halfScale"] = half_scale
        return RadianceWriter(output, w, h, nch, dtype=dtype, compression=compression, metadata=m,
                              timestamp=timestamp, colorspace=colorspace, camera=cam)

    return open_writer


def fuse_to_file(open_writer: Callable, run: Callable, *, output: str, dtype: str, reference: float,
                 keep_units: bool, chain=None):
    """Fuse into a radiance file, half whenever the data fit.

    Parameters
    ----------
    open_writer : callable
        ``open_writer(dtype, half_scale)`` -> an open :class:`hdrcl.io.writers.RadianceWriter`
        (with ``hdrcl:halfScale`` in its metadata when ``half_scale != 1``).
    run : callable
        ``run(file_sink, first)`` streams the fusion into ``file_sink`` (strips of
        radiance relative to 1 s) and returns the counts; ``first`` is False for the
        second pass, which must not feed the caller's other sinks again.
    dtype : {"auto", "half", "float"}
    reference : float
        Multiplier from 1 s radiance to the file's values (:func:`reference_for`).
    keep_units : bool
        Absolute units: never rescale; float when half cannot hold them.
    chain : hdrcl.core.luminance.fisheye.LuminanceChain, optional
        A calibrated fisheye luminance map (:func:`fuse_through_chain`): the strips go
        into the chain, whose ``N x N`` result is written once the fusion ends, with
        ``open_writer(dtype, 1.0, chain)`` (the callback adapts its metadata, camera and
        size with ``chain.writer_args(metadata, camera)``). One pass, never a second.

    Returns
    -------
    writer, counts, Stored
        The writer is still open: the caller commits it with ``close()`` (or ``abort()``).
    """
    if chain is not None:
        return fuse_through_chain(open_writer, run, chain, output=output, dtype=dtype)
    ext = os.path.splitext(os.fspath(output))[1].lower()
    optimistic = ext == ".exr" and dtype in ("auto", "half")
    first = "half" if optimistic or dtype == "auto" else dtype
    writer = open_writer(first, 1.0)
    # a .hdr in cd/m^2 holds Radiance's radiance (cd/m^2 / 179)
    file_scale = hdr_factor(output, "cd/m2" if keep_units else "relative")
    meter = RangeMeter(writer, reference * file_scale, check=optimistic)
    try:
        counts = run(meter, True)
    except BaseException:
        writer.abort()
        raise
    stored = Stored(dtype=first, reference=reference, lo=meter.lo, hi=meter.hi)
    if not meter.overflow:
        return writer, counts, stored
    writer.abort()
    hp = halfrange.plan(meter.lo, meter.hi, dtype, keep_units=keep_units)
    stored = Stored(dtype=hp.dtype, reference=reference, half_scale=hp.scale, lo=meter.lo, hi=meter.hi,
                    note=hp.message.replace("may reach", "reaches") if hp.message else None, passes=2)
    logger.info("%s: %s", output, stored.note)
    writer = open_writer(hp.dtype, hp.scale)
    again = RangeMeter(writer, reference * hp.scale * file_scale, check=False)
    try:
        counts = run(again, False)
    except BaseException:
        writer.abort()
        raise
    return writer, counts, stored


def fuse_through_chain(open_writer: Callable, run: Callable, chain, *, output: str, dtype: str):
    """Fuse into ``chain`` (strips in cd/m^2), then write its calibrated map.

    The map is in the writer's memory whole (``N x N``), so its range is known before
    the file is opened: half when it fits (``auto``, ``half``), float otherwise (the
    units are kept: never rescaled). Returns ``writer, counts, Stored`` as
    :func:`fuse_to_file` does; ``Stored.reference`` is 1 (absolute units).
    """
    counts = run(chain, True)
    values = chain.file_values(output, chain.finish())
    pos = values[values > 0]
    lo = float(pos.min()) if pos.size else math.inf
    hi = float(values.max()) if values.size else 0.0
    ext = os.path.splitext(os.fspath(output))[1].lower()
    if pos.size:
        hp = halfrange.plan(lo, hi, dtype if ext == ".exr" else "float", keep_units=True)
    else:  # all black: any type holds it
        hp = halfrange.HalfPlan("float" if dtype == "float" else "half")
    stored = Stored(dtype=hp.dtype, reference=1.0, lo=lo, hi=hi, note=hp.message)
    writer = open_writer(hp.dtype, 1.0, chain)
    try:
        writer.write_rows(0, values.shape[0], values)
    except BaseException:
        writer.abort()
        raise
    return writer, counts, stored
