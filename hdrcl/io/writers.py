"""Writing radiance maps (EXR, Radiance RGBE, float TIFF, PFM), whole or strip by strip,
atomically (8- and 16-bit images: :mod:`hdrcl.io.ldr`).

Every writer renders into a hidden temporary file beside the target and renames it onto
the target only when the whole file has been written, so an interrupted run never
leaves a half-written file under the real name and never destroys the previous one.

Formats, chosen by extension:

========  ==============================================================
``.exr``  OpenEXR, half (default) or float, any OpenEXR compression
          (:data:`DEFAULT_EXR_COMPRESSION`), on all the cores OpenImageIO's
          ``exr_threads`` allows (:class:`hdrcl.io.encoders.ExrBatch`);
          metadata as ``hdrcl:*`` header attributes plus the standard ones
          (``Software``, ``owner``, ``capDate``, camera, lens, reference
          exposure: :mod:`hdrcl.io.outmeta`), the colour space's
          ``chromaticities`` (Rec.709 or ACEScg AP1) and ``oiio:ColorSpace``
``.hdr``  Radiance RGBE (shared 8-bit exponent: about 1% precision;
          grey is written as RGB), run-length encoded by hdrcl's NumPy
          encoder (:mod:`hdrcl.io.encoders`), each strip in parts on up to
          four threads (the same bytes); header lines SOFTWARE, EXPOSURE,
          PRIMARIES, CAPDATE; no ``hdrcl:*`` metadata
``.tif``  32-bit float TIFF; metadata as JSON in ImageDescription
``.pfm``  Portable float map (1 or 3 channels); no metadata
========  ==============================================================

Only this module and :mod:`hdrcl.io.frames` import OpenImageIO, lazily.
"""
from __future__ import annotations

import logging
import os
from typing import Mapping, Optional

import numpy as np

from hdrcl.errors import ProcessingError, UsageError
from hdrcl.io import halfrange
from hdrcl.io.atomic import atomic_output
from hdrcl.io.attributes import METADATA_PREFIX
from hdrcl.io.attributes import description as _description, metadata_attributes as _metadata_attributes
from hdrcl.io.attributes import write_image
from hdrcl.io.frames import _clean_error
from hdrcl.io.encoders import RGBE_MAX, ExrBatch, RGBEFile, exr_batch_rows, exr_threads, write_rgbe

logger = logging.getLogger(__name__)


RADIANCE_EXTENSIONS = (".exr", ".hdr", ".tif", ".tiff", ".pfm")




# OIIO silently falls back to zip for names it does not know, so names are checked here.
EXR_COMPRESSIONS = ("none", "rle", "zips", "zip", "piz", "pxr24", "b44", "b44a", "dwaa", "dwab")


#: Lossless EXR compression for radiance maps: for half the fastest and smallest of zip,
#: zips, piz, pxr24; for float the smallest, slower than zip (scripts/compression_bench.py).
DEFAULT_EXR_COMPRESSION = "piz"


TIFF_COMPRESSIONS = ("none", "zip", "lzw")


HALF_MAX = 65504.0


# OIIO 3.x name (the colour-interop ID) for scene-linear Rec.709 / sRGB primaries.
LINEAR_COLORSPACE = "lin_rec709_scene"


# CIE xy of the red, green, blue primaries and the D65 white point (Rec.709 / sRGB).
REC709_CHROMATICITIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)




def _oiio():
    import OpenImageIO as oiio  # lazy: keeps ``import hdrcl`` free of the OIIO load

    return oiio


def _ext(path: str) -> str:
    return os.path.splitext(path)[1].lower()


def _hdr_lines(ext, camera, colorspace, timestamp, metadata=None):
    """Radiance header lines (SOFTWARE, EXPOSURE, PRIMARIES, CAPDATE) or None."""
    if ext != ".hdr":
        return None
    from hdrcl.io.outmeta import hdr_header_lines

    return hdr_header_lines(camera, colorspace, timestamp, metadata)


def _exr_compression(compression: str) -> str:
    text = str(compression).strip().lower()
    base, _, level = text.partition(":")
    if base not in EXR_COMPRESSIONS or (level and not level.replace(".", "", 1).isdigit()):
        raise UsageError(
            f"--compression: '{compression}' is not one of {', '.join(EXR_COMPRESSIONS)}"
        )
    return text


def _radiance_header(path, nch: int, dtype: str, compression: str, metadata, timestamp,
                     colorspace: str = "rec709", camera: Optional[Mapping] = None):
    """Checked target, extension, and the OIIO header of a radiance file.

    Returns ``(target, ext, fmt, attrs, channelnames, warnings)``; shared by
    :func:`write_radiance` and :class:`RadianceWriter`. The standard attributes
    (:func:`hdrcl.io.outmeta.standard_attributes`) are part of ``attrs``; a Radiance
    file's header lines are added after writing (:func:`_hdr_lines`).
    """
    target = os.fspath(path)
    ext = _ext(target)
    if ext not in RADIANCE_EXTENSIONS:
        raise UsageError(
            f"{target}: unsupported radiance format '{ext or '(none)'}'; "
            f"use {', '.join(RADIANCE_EXTENSIONS)}"
        )
    if dtype not in ("half", "float"):
        raise UsageError(f"--dtype: '{dtype}' is not one of half, float")
    warnings = []
    attrs = _metadata_attributes(metadata)  # validates keys for every format
    from hdrcl.io.colorspace import COLORSPACES, chromaticities
    from hdrcl.io.colorspace import check as check_space
    from hdrcl.io.outmeta import standard_attributes

    colorspace = check_space(colorspace)
    if colorspace != "rec709" and ext not in (".exr", ".hdr"):
        raise UsageError(f"{target}: --colorspace {colorspace} needs an .exr or .hdr output "
                         f"({ext} cannot say which primaries it holds)")
    attrs.append(("oiio:ColorSpace", LINEAR_COLORSPACE if colorspace == "rec709" else COLORSPACES[colorspace]))
    attrs.extend(standard_attributes(ext, camera))
    fmt = "float"
    channelnames = None
    if ext == ".exr":
        oiio = _oiio()
        fmt = dtype
        attrs.append(("compression", _exr_compression(compression)))
        attrs.append(("chromaticities", oiio.TypeDesc("float[8]"), chromaticities(colorspace)))
        if timestamp is not None:
            # OIIO stamps the time of writing unless DateTime is set ("" leaves it out);
            # it is the EXR's capDate.
            attrs.append(("DateTime", str(timestamp)))
        if nch == 1:
            channelnames = ("Y",)
    elif ext in (".tif", ".tiff"):
        comp = str(compression).strip().lower()
        if comp not in TIFF_COMPRESSIONS:
            if comp != DEFAULT_EXR_COMPRESSION:  # the EXR default was not asked of TIFF
                warnings.append(f"{target}: TIFF has no '{compression}' compression; used zip")
            comp = "zip"
        attrs = [a for a in attrs if not a[0].startswith(METADATA_PREFIX)]
        desc = _description(metadata)
        if desc:
            attrs.append(("ImageDescription", desc))
        attrs.append(("compression", comp))
        # OIIO 3.2 reports "failed TIFFWriteCustomDirectory() of the Exif data" on
        # every TIFF it writes unless the (here useless) EXIF directory is skipped.
        attrs.append(("tiff:write_exif", 0))
    else:
        if metadata:
            logger.debug("%s: %s cannot store metadata; %d entries not written",
                         target, ext, len(metadata))
        attrs = [a for a in attrs if not a[0].startswith(METADATA_PREFIX)]
    return target, ext, fmt, attrs, channelnames, warnings


def write_radiance(path, image, *, dtype="half", compression=DEFAULT_EXR_COMPRESSION, metadata=None,
                   timestamp=None, colorspace="rec709", camera=None) -> list:
    """Write a floating-point radiance map; the format follows the extension.

    Parameters
    ----------
    path : str or os.PathLike
        ``.exr``, ``.hdr``, ``.tif``/``.tiff`` or ``.pfm``.
    image : numpy.ndarray
        ``(H, W, C)`` (or ``(H, W)``) radiance, C = 1 or 3; converted to float32.
    dtype : {"half", "float"}
        Sample type of EXR files. The other formats have one encoding each (RGBE, 32-bit
        float) and ignore it.
    compression : str
        EXR: one of :data:`EXR_COMPRESSIONS`, optionally with a level (``"dwaa:45"``).
        TIFF: ``none``, ``zip`` or ``lzw`` (others fall back to zip, with a warning
        unless it is the EXR default).
        Ignored for HDR and PFM.
    metadata : mapping, optional
        Short keys (``hdrcl:`` + key at most 31 characters) to str, int or float values
        (anything else is stored as JSON text). EXR keeps them as ``hdrcl:*`` attributes
        (floats at float32 precision), TIFF as JSON in ImageDescription; HDR and PFM
        cannot store them.
    timestamp : str, optional
        EXR only: the ``DateTime`` attribute (``"YYYY:MM:DD HH:MM:SS"``) instead of the
        time of writing, which OpenImageIO records by default; ``""`` records none. Given,
        the same pixels and metadata always give the same bytes (``hdrcl batch`` uses
        the capture time of the first frame). Radiance files get it as ``CAPDATE=``.
    colorspace : {"rec709", "acescg"}
        Colour space of the file (EXR and HDR): ``image`` is linear Rec.709 and is
        converted to ACEScg (:mod:`hdrcl.io.colorspace`) when asked; the file is tagged
        with the space's ``oiio:ColorSpace`` and primaries (EXR ``chromaticities``,
        Radiance ``PRIMARIES``).
    camera : mapping, optional
        Standard metadata (:mod:`hdrcl.io.outmeta`): make, model, lens, focal length,
        owner and the reference exposure.

    Returns
    -------
    list of str
        Warnings for the user (also logged), such as values beyond the half range.

    Raises
    ------
    UsageError
        Unknown extension, dtype or compression; missing output folder.
    ProcessingError
        OpenImageIO (or, for ``.hdr``, the file system) failed to write the file.
    ValueError
        ``image`` has the wrong shape or a metadata key is too long (caller bugs).
    """
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3 or img.shape[2] not in (1, 3) or img.shape[0] < 1 or img.shape[1] < 1:
        raise ValueError(f"radiance image must be (H, W, 1) or (H, W, 3), got {img.shape}")
    target, ext, fmt, attrs, channelnames, warnings = _radiance_header(
        path, img.shape[2], dtype, compression, metadata, timestamp, colorspace, camera)
    from hdrcl.io.colorspace import convert

    img = np.ascontiguousarray(convert(img, "rec709", colorspace))
    finite = np.isfinite(img)
    if not finite.all():
        bad = img.size - int(np.count_nonzero(finite))
        warnings.append(f"{target}: {bad} value(s) are NaN or infinite")
    if ext == ".exr" and dtype == "half" and not halfrange.fits(img):
        # Half would turn values into inf or 0 (or lose them in subnormals): keep them.
        fmt = "float"
        warnings.append(f"{target}: values beyond the half-float range "
                        f"({halfrange.HALF_FLOOR:.2g}..{HALF_MAX:g}); written as float")
    if ext == ".hdr":
        if np.any(img[finite] < 0):
            warnings.append(f"{target}: negative values are written as 0 in RGBE")
        write_rgbe(target, img, _hdr_lines(ext, camera, colorspace, timestamp, metadata),
                   orientation=int((camera or {}).get("orientation") or 1))
    else:
        if ext == ".exr":
            exr_threads(_oiio())
        write_image(target, img, fmt, attrs, channelnames)
    for w in warnings:
        logger.warning("%s", w)
    return warnings


class RadianceWriter:
    """Writes a radiance map strip by strip (top to bottom), atomically.

    The file is written to a hidden temporary name beside ``path`` and renamed onto it
    by :meth:`close` only when every row has been written; :meth:`abort` (or leaving a
    ``with`` block by an exception) deletes it. Memory use is one strip, whatever the
    image size, with two exceptions: EXR strips are gathered into two batches of a few
    blocks per OpenEXR thread (at most 64 MB each, :class:`hdrcl.io.encoders.ExrBatch`)
    so that OpenEXR compresses on every thread, and PFM, whose rows are stored bottom to
    top, is collected whole before writing. Radiance ``.hdr`` strips are encoded as they
    come, each cut into parts of whole scanlines measured and encoded at once on the
    CPUs (:class:`hdrcl.io.encoders.RGBEFile`, :func:`hdrcl.io.encoders.rgbe_threads`).

    Parameters are those of :func:`write_radiance` plus the image size; ``write_rows``
    takes float32 ``(rows, width, nch)`` strips.
    """

    def __init__(self, path, width: int, height: int, nch: int, *, dtype: str = "half",
                 compression: str = DEFAULT_EXR_COMPRESSION, metadata=None, timestamp=None, colorspace="rec709",
                 camera=None):
        if nch not in (1, 3):
            raise ValueError(f"radiance must have 1 or 3 channels, not {nch}")
        target, ext, fmt, attrs, channelnames, warnings = _radiance_header(
            path, nch, dtype, compression, metadata, timestamp, colorspace, camera)
        self.colorspace = str(colorspace).strip().lower()
        self._hdr_lines = _hdr_lines(ext, camera, colorspace, timestamp, metadata)
        self.path, self.ext = target, ext
        self.width, self.height, self.nch = int(width), int(height), int(nch)
        self.dtype, self.warnings = dtype, list(warnings)
        self._nonfinite = self._over_half = self._negative = 0
        self._next_row = 0
        self._attrs, self._fmt, self._channelnames = attrs, fmt, channelnames
        self._whole = np.empty((height, width, nch), np.float32) if ext == ".pfm" else None
        self._rgbe = self._batch = None
        self._one = halfrange.OnePass()
        self._ctx = atomic_output(target)
        self._tmp = self._ctx.__enter__()
        self._out = None
        if ext == ".hdr":
            from hdrcl.io.encoders import rgbe_threads

            threads = rgbe_threads()
            self._ones = [self._one] + [halfrange.OnePass() for _ in range(threads - 1)]
            self._rgbe = self._guarded(lambda: RGBEFile(self._tmp, width, height, self._hdr_lines, name=target,
                                                        orientation=int((camera or {}).get("orientation") or 1),
                                                        threads=threads))
        elif self._whole is None:
            self._open()
            if ext == ".exr":
                threads = exr_threads(_oiio())
                rows = min(self.height, exr_batch_rows(compression, self.width, self.nch, threads))
                if threads > 1:
                    self._batch = ExrBatch(self._out, rows, self.width, self.nch, fmt == "half")

    def _open(self):
        oiio = _oiio()
        spec = oiio.ImageSpec(self.width, self.height, self.nch, self._fmt)
        if self._channelnames is not None:
            spec.channelnames = tuple(self._channelnames)
        for attr in self._attrs:
            spec.attribute(*attr)
        out = oiio.ImageOutput.create(self._tmp)
        if out is None or not out.open(self._tmp, spec):
            detail = _clean_error((out.geterror() if out is not None else "") or oiio.geterror(), self._tmp)
            self.abort()
            raise ProcessingError(f"{self.path}: cannot write ({detail or 'no writer for this format'})")
        self._out = out

    def _check(self, data: np.ndarray) -> np.ndarray:
        """Count problems; for half, clamp values it cannot hold (:func:`halfrange.clamp`).
        Min and max (NaN propagates through both) settle the usual strip in two passes."""
        lo, hi = data.min(), data.max()
        finite_all = bool(np.isfinite(lo) and np.isfinite(hi))
        if not finite_all:
            finite = np.isfinite(data)
            self._nonfinite += data.size - int(np.count_nonzero(finite))
        if self.ext == ".exr" and self.dtype == "half" and not (
                finite_all and lo >= halfrange.HALF_MIN and hi <= HALF_MAX):
            data, n = halfrange.clamp(data)
            self._over_half += n
        if self.ext == ".hdr" and not lo >= 0:
            self._negative += int(np.count_nonzero(data < 0 if finite_all else data[finite] < 0))
        return data

    def _guarded(self, call):
        """``call()``, dropping the temporary file first if it raises."""
        try:
            return call()
        except BaseException:
            self.abort()
            raise

    def _fail(self, y0: int, y1: int, error: str = "") -> ProcessingError:
        """Abort and describe OpenImageIO's failure to write rows ``y0 .. y1``."""
        detail = _clean_error(error or self._out.geterror() or _oiio().geterror(), self._tmp)
        self.abort()
        return ProcessingError(f"{self.path}: cannot write rows {y0}-{y1} ({detail or 'unknown error'})")

    def write_rows(self, y0: int, y1: int, data: np.ndarray) -> None:
        """Write rows ``y0 .. y1`` (in order) from a float32 ``(rows, W, C)`` array."""
        self.write_scaled(y0, y1, data, 1.0)

    def write_scaled(self, y0: int, y1: int, data: np.ndarray, scale: float) -> halfrange.StripRange:
        """Write rows ``y0 .. y1`` (in order) of ``data x scale`` (float32 ``(rows, W, C)``,
        left as it is; the file as from ``data * np.float32(scale)``) and return their
        range before any clamping. Batched EXR, PFM and ``.hdr`` in Rec.709 take one pass
        over the strip (:class:`hdrcl.io.halfrange.OnePass`)."""
        if y0 != self._next_row:
            raise ValueError(f"rows must be written in order: expected {self._next_row}, got {y0}")
        data, one = np.ascontiguousarray(data, dtype=np.float32), self._one
        plain = self.colorspace != "rec709" or (self._out is not None and self._batch is None)
        if plain:  # TIFF, EXR on one thread, other colour spaces
            data = data * np.float32(scale) if scale != 1 else data
            found = one.measure(data, 1.0)
            self._write_plain(y0, y1, data)
        elif self._rgbe is not None:
            found = self._write_rgbe(data, scale)
        elif self._whole is not None:
            found = one.to_float(data, scale, self._whole[y0:y1])
        else:
            found, convert = halfrange.StripRange(), one.to_half if self._fmt == "half" else one.to_float
            if not self._batch.add(data, lambda src, dst: found.add(convert(src, scale, dst))):
                raise self._fail(*self._batch.failed)
        if not plain:
            self._nonfinite += found.nonfinite
            self._over_half += found.clamped
            self._negative += found.negative if self.ext == ".hdr" else 0
        self._next_row = y1
        return found

    def _write_rgbe(self, data: np.ndarray, scale: float) -> halfrange.StripRange:
        """Measure and encode a strip, in parts on the encoder's threads (each part
        measured where it is encoded, by a :class:`hdrcl.io.halfrange.OnePass` of its
        own); the strip's range, as one pass over it would find it."""
        found = [None] * len(self._ones)

        def check(part, y0, y1):
            r = found[part] = self._ones[part].measure(data[y0:y1], scale)
            return not (r.nonfinite or r.negative) and r.hi <= RGBE_MAX

        self._guarded(lambda: self._rgbe.write(np.broadcast_to(data, data.shape[:2] + (3,)), scale, check=check))
        total = halfrange.StripRange()
        for r in found:
            if r is not None:
                total.add(r)
        return total

    def _write_plain(self, y0: int, y1: int, data: np.ndarray) -> None:
        if self.colorspace != "rec709":
            from hdrcl.io.colorspace import convert

            data = convert(data, "rec709", self.colorspace)
        data = self._check(np.ascontiguousarray(data, dtype=np.float32))
        if self._whole is not None:
            self._whole[y0:y1] = data
        elif self._rgbe is not None:  # grey is written as RGB: RGBE has no grey
            self._guarded(lambda: self._rgbe.write(np.broadcast_to(data, (y1 - y0, self.width, 3))))
        elif self._batch is not None:
            if not self._batch.add(data):
                raise self._fail(*self._batch.failed)
        elif not self._out.write_scanlines(y0, y1, 0, data):
            raise self._fail(y0, y1)

    def close(self) -> list:
        """Finish the file and move it into place; returns the warnings."""
        if self._next_row != self.height:
            self.abort()
            raise ValueError(f"{self.path}: only {self._next_row} of {self.height} rows were written")
        if self._whole is not None:
            write_image(self._tmp, self._whole, self._fmt, self._attrs, self._channelnames)
        elif self._rgbe is not None:
            self._guarded(self._rgbe.close)
            self._rgbe = None
        else:
            if self._batch is not None and not self._batch.flush():
                raise self._fail(*self._batch.failed)
            ok = self._out.close()
            if not ok:
                detail = _clean_error(self._out.geterror() or _oiio().geterror(), self._tmp)
                self.abort()
                raise ProcessingError(f"{self.path}: cannot write ({detail or 'unknown error'})")
            self._out = None
        total = self.width * self.height * self.nch
        if self._nonfinite:
            self.warnings.append(f"{self.path}: {self._nonfinite} value(s) are NaN or infinite")
        if self._over_half:
            self.warnings.append(
                f"{self.path}: {self._over_half} value(s) ({100.0 * self._over_half / total:.2g}%) were beyond "
                f"the half-float range and were clamped to it (+-{HALF_MAX:g}, {halfrange.HALF_MIN:.3g}); "
                "use --dtype float")
        if self._negative:
            self.warnings.append(f"{self.path}: negative values are written as 0 in RGBE")
        self._ctx.__exit__(None, None, None)  # rename onto the target
        self._ctx = None
        for w in self.warnings:
            logger.warning("%s", w)
        return self.warnings

    def abort(self) -> None:
        """Drop the temporary file; the target is left as it was."""
        if self._batch is not None:
            self._batch.cancel()  # before closing: a batch may be being written
            self._batch = None
        if self._out is not None:
            try:
                self._out.close()
            except Exception:  # the file is deleted anyway
                pass
            self._out = None
        if self._rgbe is not None:
            self._rgbe.abort()
            self._rgbe = None
        if self._ctx is not None:
            ctx, self._ctx = self._ctx, None
            try:
                ctx.__exit__(ProcessingError, ProcessingError("aborted"), None)
            except ProcessingError:
                pass

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self.abort()
