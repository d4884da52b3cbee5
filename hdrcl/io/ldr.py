"""Writers of 8- and 16-bit images: virtual photographs, previews, thumbnails
(:func:`write_ldr`) and photographs with camera metadata for sample and test data
(:func:`write_photo`). Radiance maps are :mod:`hdrcl.io.writers`'."""
from __future__ import annotations

import os
from typing import Mapping, Optional

import numpy as np

from hdrcl.errors import UsageError
from hdrcl.io.attributes import description as _description, metadata_attributes as _metadata_attributes
from hdrcl.io.attributes import write_image

__all__ = ["LDR_EXTENSIONS", "JPEG_QUALITY", "write_ldr", "write_photo"]

LDR_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff")

JPEG_QUALITY = 95


def _ext(path: str) -> str:
    return os.path.splitext(path)[1].lower()


def _ldr_target(path, pixels, channels):
    """Checked target path, extension and ``(H, W, C)`` integer pixels of an LDR write."""
    target = os.fspath(path)
    ext = _ext(target)
    if ext not in LDR_EXTENSIONS:
        raise UsageError(
            f"{target}: unsupported image format '{ext or '(none)'}'; "
            f"use {', '.join(LDR_EXTENSIONS)}"
        )
    px = np.asarray(pixels)
    if px.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"pixels must be uint8 or uint16, got {px.dtype}")
    if px.ndim == 2:
        px = px[:, :, None]
    if px.ndim != 3 or px.shape[2] not in channels:
        raise ValueError(f"pixels must be (H, W, C) with C in {channels}, got {px.shape}")
    return target, ext, px


def write_ldr(path, pixels, *, metadata=None) -> None:
    """Write an 8- or 16-bit image (a virtual photograph, a preview) atomically.

    Parameters
    ----------
    path : str or os.PathLike
        ``.jpg``/``.jpeg`` (8-bit only, quality 95), ``.png`` or ``.tif``/``.tiff``.
    pixels : numpy.ndarray
        ``(H, W, C)`` or ``(H, W)`` ``uint8`` or ``uint16``; C = 1 or 3, or 2/4 with
        unassociated alpha last (PNG and TIFF only).
    metadata : mapping, optional
        As for :func:`write_radiance`: ``hdrcl:*`` attributes (kept by PNG) and JSON in
        ImageDescription (kept by JPEG and TIFF).

    Raises
    ------
    UsageError
        Unknown extension, 16-bit or alpha data for JPEG, missing output folder.
    ProcessingError
        OpenImageIO failed to write the file.
    ValueError
        Wrong dtype or shape (caller bugs).
    """
    target, ext, px = _ldr_target(path, pixels, (1, 2, 3, 4))
    px = np.ascontiguousarray(px)
    from hdrcl.io.outmeta import software

    attrs = _metadata_attributes(metadata) + [("Software", software())]
    if ext in (".jpg", ".jpeg"):
        if px.dtype != np.uint8:
            raise UsageError(f"{target}: JPEG holds 8-bit data only; write .png or .tif")
        if px.shape[2] not in (1, 3):
            raise UsageError(f"{target}: JPEG cannot hold alpha; write .png or .tif")
        attrs.append(("Compression", f"jpeg:{JPEG_QUALITY}"))
    if ext in (".tif", ".tiff"):
        attrs.append(("compression", "zip"))
        attrs.append(("tiff:write_exif", 0))
    if ext != ".png":
        desc = _description(metadata)
        if desc:
            attrs.append(("ImageDescription", desc))
    # Alpha as given: without this OIIO would divide colour by alpha when writing.
    attrs.append(("oiio:UnassociatedAlpha", 1))
    write_image(target, px, "uint8" if px.dtype == np.uint8 else "uint16", attrs)


def write_photo(path, pixels, exif: Optional[Mapping] = None) -> None:
    """Write an 8- or 16-bit photograph with camera metadata, atomically.

    For sample and test data (``hdrcl sample-shoot``): unlike :func:`write_ldr`, the
    attribute names are OpenImageIO's own, unprefixed, so EXIF fields written here are
    read back by :func:`hdrcl.io.frames.read_info` as a camera's would be.

    Parameters
    ----------
    path : str or os.PathLike
        ``.jpg``/``.jpeg`` (8-bit, quality 95), ``.png`` or ``.tif``/``.tiff``.
    pixels : numpy.ndarray
        ``(H, W, C)`` or ``(H, W)`` ``uint8`` or ``uint16``, C = 1 or 3.
    exif : mapping, optional
        OIIO attribute name to value, e.g. ``{"ExposureTime": 1/60, "FNumber": 8.0,
        "Exif:PhotographicSensitivity": 100, "Exif:DateTimeOriginal":
        "2024:06:01 10:00:00", "Make": "Canon"}``. Python floats are stored as
        float, ints as int, anything else as text.

    Raises
    ------
    UsageError
        Unknown extension or 16-bit data for JPEG; missing output folder.
    ProcessingError
        OpenImageIO failed to write the file.
    """
    target, ext, px = _ldr_target(path, pixels, (1, 3))
    if ext in (".jpg", ".jpeg") and px.dtype != np.uint8:
        raise UsageError(f"{target}: JPEG holds 8-bit data only; write .png or .tif")
    attrs = []
    for key, value in (exif or {}).items():
        if isinstance(value, np.generic):
            value = value.item()
        if isinstance(value, bool):
            value = int(value)
        if not isinstance(value, (int, float, str)):
            value = str(value)
        attrs.append((str(key), value))
    if ext in (".jpg", ".jpeg"):
        attrs.append(("Compression", f"jpeg:{JPEG_QUALITY}"))
    if ext in (".tif", ".tiff"):
        attrs.append(("compression", "zip"))
    write_image(target, np.ascontiguousarray(px), "uint8" if px.dtype == np.uint8 else "uint16", attrs)
