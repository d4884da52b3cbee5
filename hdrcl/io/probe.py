"""Cheap looks at image files: a reduced-resolution version of a photograph (for
comparing scenes), and whether every pixel of a file can be read (for trusting an
output a rerun would skip).
"""
from __future__ import annotations

import logging
import os
from typing import Optional, Tuple

import numpy as np

from hdrcl.errors import InputError

logger = logging.getLogger(__name__)

__all__ = ["reduced_pixels", "pixels_readable", "Damaged"]


class Damaged(InputError):
    """A file whose header reads but whose pixels do not decode (truncated or corrupt
    data); the message is one line naming the file and the decoder's cause."""


def reduced_pixels(path, min_size: Tuple[int, int] = (24, 32)) -> Optional[np.ndarray]:
    """A small version of the photograph at ``path`` (at least ``min_size`` = (rows,
    columns) where the image is that large), decoded as cheaply as possible, or None.

    In order: the embedded EXIF thumbnail (cameras write 160x120); a JPEG decoded at
    1/2, 1/4 or 1/8 scale by libjpeg's DCT scaling, in grey (OpenCV or Pillow, when one
    is installed); the smallest MIP level of a tiled file that is large enough; a full
    decode in the file's own sample type (a 4 MP JPEG: 0.05 s as uint8, 0.38 s as
    float). Camera RAW files give None (their previews are not read here). The values
    are the file's own (uint8, uint16 or float); the caller reduces them further.

    Raises
    ------
    Damaged
        The pixels decoded in full do not decode cleanly (a truncated JPEG, whose
        missing rows the decoder fills with grey, or a corrupt PNG); the decoder's own
        lines are held back from stderr.
    """
    import OpenImageIO as oiio

    from hdrcl.io.frames import _read_error as read_error, decoder_stderr
    from hdrcl.io.raw import is_raw

    path = os.fspath(path)
    if is_raw(path):
        return None
    rows, cols = min_size
    if not _regular(path):
        return None
    inp = oiio.ImageInput.open(path)
    if inp is None:
        oiio.geterror()
        return None
    try:
        try:
            th = inp.get_thumbnail(0)
        except Exception:  # an OpenImageIO without thumbnails
            th = None
        if th is not None and th.spec().width >= cols and th.spec().height >= rows:
            return np.asarray(th.get_pixels(oiio.FLOAT))
        full = inp.spec()
        if os.path.splitext(path)[1].lower() in (".jpg", ".jpeg") and full.width >= 4 * cols \
                and full.height >= 4 * rows:
            a = _jpeg_reduced(path, full.width, cols)
            if a is not None:
                return a
        level, n, spec = 0, 0, full
        while inp.seek_subimage(0, n + 1):  # MIP levels: the smallest one still large enough
            s = inp.spec()
            if s.width < cols or s.height < rows:
                break
            n += 1
            level, spec = n, s
        inp.geterror()  # the failed seek past the last level
        own = {oiio.UINT8: oiio.UINT8, oiio.UINT16: oiio.UINT16}.get(spec.format.basetype, oiio.FLOAT)
        with decoder_stderr():
            try:
                a = inp.read_image(0, level, 0, min(spec.nchannels, 3), own)
            except Exception as exc:  # noqa: BLE001 - some OIIO readers raise on damage
                raise Damaged(f"{path}: corrupt data ({' '.join(str(exc).split())})") from None
            why = read_error(inp, path) if (a is None or inp.has_error) else None
        if why is not None or a is None:
            raise Damaged(why or f"{path}: corrupt data (no pixels decoded)")
        return np.asarray(a)
    finally:
        inp.close()


def _jpeg_reduced(path: str, width: int, cols: int) -> Optional[np.ndarray]:
    """A grey JPEG decoded at 1/8, 1/4 or 1/2 scale (at least ``2 cols`` wide), or None."""
    scale = 8 if width >= 16 * cols else 4 if width >= 8 * cols else 2
    try:
        import cv2
    except ImportError:
        return _pillow_reduced(path, scale)
    flag = {8: cv2.IMREAD_REDUCED_GRAYSCALE_8, 4: cv2.IMREAD_REDUCED_GRAYSCALE_4,
            2: cv2.IMREAD_REDUCED_GRAYSCALE_2}[scale]
    return cv2.imread(path, flag | cv2.IMREAD_IGNORE_ORIENTATION)


def _pillow_reduced(path: str, scale: int) -> Optional[np.ndarray]:
    """The same through Pillow's ``draft`` (libjpeg's DCT scaling, grey), or None."""
    try:
        from PIL import Image
    except ImportError:
        return None
    try:
        with Image.open(path) as im:
            if im.format != "JPEG":
                return None
            w, h = im.size
            im.draft("L", (-(-w // scale), -(-h // scale)))
            return np.asarray(im.convert("L"))
    except Exception as exc:  # damaged: the caller's full decode says what it can
        logger.debug("%s: no reduced decode: %s", path, exc)
        return None


def pixels_readable(path, rows: int = 256) -> bool:
    """Whether every pixel of ``path`` decodes (strip by strip, bounded memory) and is
    finite. A truncated or damaged file whose header is intact fails here."""
    import OpenImageIO as oiio

    if not _regular(path):
        return False
    inp = oiio.ImageInput.open(os.fspath(path))
    if inp is None:
        oiio.geterror()
        return False
    try:
        spec = inp.spec()
        for y in range(spec.y, spec.y + spec.height, rows):
            y1 = min(y + rows, spec.y + spec.height)
            a = inp.read_scanlines(0, 0, y, y1, 0, 0, spec.nchannels, oiio.FLOAT)
            if a is None or inp.has_error:
                inp.geterror()
                return False
            if not np.all(np.isfinite(a)):
                return False
        return True
    except Exception as exc:  # OpenImageIO raises on some damage
        logger.debug("%s: unreadable pixels: %s", path, exc)
        return False
    finally:
        inp.close()


def _regular(path) -> bool:
    """Whether ``path`` is a regular file (a FIFO or a device would block the decoder)."""
    from hdrcl.errors import HdrclError, check_regular

    try:
        check_regular(path)
    except HdrclError:
        return False
    return True
