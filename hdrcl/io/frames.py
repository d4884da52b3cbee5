"""Reading bracketed photographs with OpenImageIO.

Only this package's modules, such as this one and :mod:`hdrcl.io.writers` import OpenImageIO, and both import it inside
functions so that ``import hdrcl`` stays cheap.

Every problem a user can cause (missing file, unreadable or truncated data, unsupported
pixel format, frames of different sizes) raises :class:`hdrcl.errors.InputError` with a
one-line message that starts with the file's name.

Notes on OpenImageIO behaviour relied on here (checked against OIIO 3.2):

* A truncated JPEG decodes "successfully" (the missing rows are grey) and only
  ``ImageInput.has_error`` reports "Premature end of JPEG file"; a truncated PNG returns
  ``None``. Both are caught by checking the input's error state after every read.
* PNG/TIFF readers premultiply colour by alpha unless the ``oiio:UnassociatedAlpha``
  configuration hint is set, which would change the measured pixel values; it is set.
* EXIF fields appear as ``ExposureTime``, ``FNumber``, ``Exif:PhotographicSensitivity``
  (older files or writers: ``Exif:ISOSpeedRatings``), ``Exif:DateTimeOriginal``,
  ``Exif:SubsecTimeOriginal`` (lower-case "sec"), ``Make``, ``Model``... EXIF rationals come
  back as float32, so ``1/30`` reads as 0.0333333; :func:`_clean_time` snaps such values
  back to ``1/n``.
"""
from __future__ import annotations

import concurrent.futures
import contextlib
import datetime as _dt
import logging
import os
import re
import sys
import tempfile
import threading
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from hdrcl.errors import InputError, check_readable
from hdrcl.io.exif import capture_time, orientation_value, snap_reciprocal
from hdrcl.io.metadata import FrameInfo
from hdrcl.io.raw import is_raw

logger = logging.getLogger(__name__)


@dataclass
class Image:
    """One decoded photograph.

    Attributes
    ----------
    pixels : numpy.ndarray
        ``(H, W, C)`` ``uint8`` or ``uint16`` colour samples exactly as stored, C = 1 (grey)
        or 3 (RGB). Alpha is not included.
    valid : numpy.ndarray or None
        ``(H, W)`` bool, False where the file's alpha is 0 (no measurement there);
        ``None`` when the file has no alpha channel.
    info : FrameInfo
        The header fields (size, bit depth, EXIF exposure data).
    """

    pixels: np.ndarray
    valid: Optional[np.ndarray]
    info: FrameInfo


def _oiio():
    import OpenImageIO as oiio  # lazy: keeps ``import hdrcl`` free of the OIIO load

    return oiio


def _name(path) -> str:
    return os.fspath(path)


def _clean_error(text: str, path: str) -> str:
    """First meaningful line of an OIIO error, without the quoted file name it repeats
    (removed first: a file name may hold a line break)."""
    text = text or ""
    base = os.path.basename(path)
    for p in (path, base):
        text = text.replace(f' ("{p}")', "").replace(f'"{p}"', "")
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    if not lines:
        return ""
    return " ".join(lines[0].split()).rstrip(".")


_FORMAT_NAMES = {"openexr": "EXR", "jpeg": "JPEG", "png": "PNG", "tiff": "TIFF", "hdr": "HDR"}


_TRUNCATED = re.compile(r"premature end|end of file|truncat|short read|unexpected end|eof",
                        re.IGNORECASE)


#: Lines C decoders print on the process's stderr; hdrcl reports the problem itself.
_DECODER_NOISE = re.compile(r"^(libpng (error|warning)|libtiff|TIFFRead|TIFFFetch|Corrupt JPEG data|"
                            r"Premature end of JPEG|Invalid SOS|Warning: unknown JFIF)", re.IGNORECASE)
_capture_lock = threading.Lock()
_capture = {"depth": 0, "saved": -1, "file": None}


@contextlib.contextmanager
def decoder_stderr():
    """Hold back what C decoders write on file descriptor 2 while pixels are decoded.

    libpng prints ``libpng error: ...`` itself before OpenImageIO reports the same
    problem, which hdrcl then turns into its own one-line message; that stray line
    would break the one-line contract. While any decode runs, fd 2 goes to a temporary
    file; afterwards decoder lines are logged at debug level and anything else (another
    thread's output) is written back to stderr. Nested and concurrent uses share one
    redirection.
    """
    with _capture_lock:
        if _capture["depth"] == 0:
            _redirect_stderr()
        _capture["depth"] += 1
    try:
        yield
    finally:
        with _capture_lock:
            _capture["depth"] -= 1
            if _capture["depth"] == 0 and _capture["file"] is not None:
                _release_stderr()


def _redirect_stderr() -> None:
    try:
        sys.stderr.flush()
    except (AttributeError, ValueError, OSError):
        pass
    try:
        tmp = tempfile.TemporaryFile()
    except OSError:
        return
    try:
        saved = os.dup(2)
    except OSError:  # no fd 2 at all: nothing to hold back
        tmp.close()
        return
    os.dup2(tmp.fileno(), 2)
    _capture.update(saved=saved, file=tmp)


def _release_stderr() -> None:
    tmp, saved = _capture["file"], _capture["saved"]
    _capture.update(saved=-1, file=None)
    try:
        sys.stderr.flush()
    except (AttributeError, ValueError, OSError):
        pass
    os.dup2(saved, 2)
    os.close(saved)
    try:
        tmp.seek(0)
        text = tmp.read().decode("utf-8", "replace")
    finally:
        tmp.close()
    keep = []
    for line in text.splitlines():
        if _DECODER_NOISE.match(line.strip()):
            logger.debug("decoder said: %s", line.strip())
        else:
            keep.append(line)
    if keep:
        os.write(2, ("\n".join(keep) + "\n").encode("utf-8", "replace"))


def _config():
    """Configuration hints used for every input: keep alpha unassociated (raw values)."""
    oiio = _oiio()
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    # PFM stores rows bottom to top; OIIO 3.2 flips only when this hint is present.
    config.attribute("pnm:pfmflip", 1)
    return config


def open_input(path):
    """Open ``path`` for reading, raising InputError naming it when it cannot be opened.

    Returns the open ``ImageInput``; the caller closes it.
    """
    oiio = _oiio()
    name = _name(path)
    check_readable(name)
    with decoder_stderr():
        inp = oiio.ImageInput.open(name, _config())
    if inp is None:
        detail = _clean_error(oiio.geterror(), name)
        raise InputError(f"{name}: cannot read image ({detail or 'unknown format'})")
    oiio.geterror()  # drop any stale global message so later checks see only this file's
    return inp


def _read_error(inp, path: str) -> Optional[str]:
    """Message for a failed or partial read, or None when the read was clean."""
    oiio = _oiio()
    text = inp.geterror() if inp.has_error else ""
    glob = oiio.geterror()
    text = text or glob
    if not text:
        return None
    detail = _clean_error(text, path)
    fmt = _FORMAT_NAMES.get(inp.format_name(), (inp.format_name() or "image").upper())
    kind = "truncated" if _TRUNCATED.search(text) else "corrupt"
    return f"{path}: {kind} {fmt} data ({detail})"


def _attr(spec, *names):
    for n in names:
        v = spec.getattribute(n)
        if v is not None:
            return v
    return None


def _as_float(v) -> Optional[float]:
    if v is None:
        return None
    if isinstance(v, (tuple, list)):
        if not v:
            return None
        v = v[0]
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if np.isfinite(f) else None


def _as_str(v) -> Optional[str]:
    if v is None:
        return None
    s = str(v).strip().strip("\x00").strip()
    return s or None


def _capture_time(spec) -> Optional[_dt.datetime]:
    """EXIF's DateTimeOriginal; the file's DateTime only where a camera wrote the file
    (:func:`hdrcl.io.exif.capture_time`)."""
    camera = bool(_as_str(spec.getattribute("Make")) or _as_str(spec.getattribute("Model")))
    return capture_time(_as_str(spec.getattribute("Exif:DateTimeOriginal")),
                        _as_str(_attr(spec, "Exif:SubsecTimeOriginal", "Exif:SubsecTime")),
                        _as_str(spec.getattribute("DateTime")), camera)


def _info_from_spec(spec, path: str) -> FrameInfo:
    oiio = _oiio()
    fmt = spec.format
    if fmt.basetype == oiio.UINT8:
        bits = 8
    elif fmt.basetype == oiio.UINT16:
        bits = 16
    else:
        raise InputError(
            f"{path}: unsupported pixel format {fmt}; "
            "hdrcl merges 8- or 16-bit integer photographs"
        )
    t = _as_float(_attr(spec, "ExposureTime", "Exif:ExposureTime"))
    if t is not None and t > 0:
        t = snap_reciprocal(t)
    mode = _as_float(spec.getattribute("Exif:ExposureMode"))
    extra = {}
    for key in ("Orientation", "oiio:BitsPerSample", "Exif:ExposureProgram",
                "Exif:WhiteBalance", "oiio:ColorSpace", "Copyright", "Artist"):
        v = spec.getattribute(key)
        if v is not None:
            extra[key] = v
    return FrameInfo(
        path=path,
        width=int(spec.width),
        height=int(spec.height),
        nchannels=int(spec.nchannels),
        channel_names=tuple(spec.channelnames),
        bits=bits,
        exposure_time=t,
        fnumber=_as_float(_attr(spec, "FNumber", "Exif:FNumber")),
        iso=_as_float(_attr(spec, "Exif:PhotographicSensitivity", "Exif:ISOSpeedRatings")),
        exposure_bias=_as_float(spec.getattribute("Exif:ExposureBiasValue")),
        exposure_mode=None if mode is None else int(mode),
        capture_time=_capture_time(spec),
        make=_as_str(spec.getattribute("Make")),
        model=_as_str(spec.getattribute("Model")),
        serial=_as_str(_attr(spec, "Exif:BodySerialNumber", "Exif:SerialNumber")),
        lens=_as_str(_attr(spec, "Exif:LensModel", "Exif:LensSpecification")),
        focal_length=_as_float(spec.getattribute("Exif:FocalLength")),
        orientation=orientation_value(spec.getattribute("Orientation")),
        extra=extra,
    )


def read_info(path) -> FrameInfo:
    """Read one photograph's header: size, channels, bit depth and EXIF exposure data.

    No pixels are decoded, so this is cheap enough to run over a whole folder when
    grouping bracket sets.

    Parameters
    ----------
    path : str or os.PathLike
        Image file in any format OpenImageIO reads (JPEG, PNG, TIFF...).

    Returns
    -------
    FrameInfo

    Raises
    ------
    InputError
        The file is missing or unreadable, or its samples are not 8- or 16-bit integers.
    """
    name = _name(path)
    if is_raw(name):
        from hdrcl.io.raw import read_raw_info

        return read_raw_info(name)
    inp = open_input(name)
    try:
        return _info_from_spec(inp.spec(), name)
    finally:
        inp.close()


def _channel_layout(spec, path: str):
    """Indices of the colour channels and of the alpha channel (or None)."""
    n = spec.nchannels
    if n in (1, 3):
        return list(range(n)), None
    if n in (2, 4):
        alpha = spec.alpha_channel
        if alpha < 0:
            names = [c.upper() for c in spec.channelnames]
            alpha = names.index("A") if "A" in names else n - 1
        return [c for c in range(n) if c != alpha], alpha
    raise InputError(
        f"{path}: unsupported channel count {n} ({','.join(spec.channelnames)}); "
        "hdrcl reads grey, grey+alpha, RGB or RGBA images"
    )


def read_image(path) -> Image:
    """Decode one photograph in its native 8- or 16-bit integer format.

    Parameters
    ----------
    path : str or os.PathLike
        Image file (grey, grey+alpha, RGB or RGBA).

    Returns
    -------
    Image
        Colour samples as stored (alpha not premultiplied) and a validity mask from alpha.

    Raises
    ------
    InputError
        Missing, unreadable, truncated or corrupt file, a float or 32-bit format, or an
        unsupported channel count. The message starts with the file name.
    """
    name = _name(path)
    if is_raw(name):
        from hdrcl.io.raw import read_raw, read_raw_info

        check_pixel_limit(read_raw_info(name))
        f = read_raw(name)
        return Image(pixels=f.pixels, valid=None, info=f.info)
    inp = open_input(name)
    try:
        spec = inp.spec()
        info = _info_from_spec(spec, name)
        check_pixel_limit(info)
        colour, alpha = _channel_layout(spec, name)
        fmt = "uint8" if info.bits == 8 else "uint16"
        with decoder_stderr():
            data = inp.read_image(0, 0, 0, spec.nchannels, fmt)
        problem = _read_error(inp, name)
        if problem is None and data is None:
            problem = f"{name}: cannot decode pixel data"
        if problem is not None:
            raise InputError(problem)
    finally:
        inp.close()
    data = np.asarray(data)
    if data.ndim == 2:
        data = data[:, :, None]
    expected = (info.height, info.width, spec.nchannels)
    if data.shape != expected:
        raise InputError(f"{name}: decoded {data.shape} samples, header says {expected}")
    valid = None if alpha is None else data[:, :, alpha] != 0
    if alpha is None:
        pixels = np.ascontiguousarray(data)
    else:
        pixels = np.ascontiguousarray(data[:, :, colour])
    return Image(pixels=pixels, valid=valid, info=info)


def read_images(paths: Sequence) -> list:
    """Decode a bracket set in parallel and check the frames are compatible.

    Parameters
    ----------
    paths : sequence of str or os.PathLike
        The frames, in the order the caller wants them back.

    Returns
    -------
    list of Image
        In the order of ``paths``.

    Raises
    ------
    InputError
        Any frame cannot be read (the first failing one in ``paths`` order is reported),
        or the frames differ in size, colour channel count or bit depth (the first
        frame that differs from ``paths[0]`` is named).
    """
    paths = [_name(p) for p in paths]
    if not paths:
        return []
    workers = max(1, min(len(paths), os.cpu_count() or 1))
    # OIIO decoders release the GIL, so threads decode frames concurrently.
    with concurrent.futures.ThreadPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(read_image, p) for p in paths]
        images = []
        for fut in futures:
            images.append(fut.result())  # raises the first failure in input order
    first = images[0]
    h, w, c = first.pixels.shape
    for img in images[1:]:
        ih, iw, ic = img.pixels.shape
        if (ih, iw) != (h, w):
            raise InputError(
                f"{img.info.path}: size {iw}x{ih} differs from {first.info.path} ({w}x{h})"
            )
        if ic != c:
            raise InputError(
                f"{img.info.path}: {ic} colour channel(s) but {first.info.path} has {c}"
            )
        if img.info.bits != first.info.bits:
            raise InputError(
                f"{img.info.path}: {img.info.bits}-bit samples but "
                f"{first.info.path} has {first.info.bits}-bit"
            )
    return images


#: Default of :func:`max_pixels`: one gigapixel per frame.
DEFAULT_MAX_PIXELS = 1_000_000_000


def max_pixels() -> int:
    """Pixels one frame may have (``HDRCL_MAX_PIXELS``, or ``hdrcl --max-pixels``;
    default one gigapixel). Checked from the header, before anything is decoded, so a
    small file that inflates to an enormous image is refused at once."""
    from hdrcl.env import number

    return number("HDRCL_MAX_PIXELS")


def check_pixel_limit(info: FrameInfo) -> None:
    """Raise InputError (naming the file) when a frame has more pixels than :func:`max_pixels`."""
    limit = max_pixels()
    n = int(info.width) * int(info.height)
    if n > limit:
        raise InputError(f"{info.path}: {info.width}x{info.height} is {n / 1e6:.0f} megapixels, over the limit "
                         f"of {limit / 1e6:g} megapixels per frame (raise it with --max-pixels or HDRCL_MAX_PIXELS)")


def check_compatible(infos: Sequence[FrameInfo]) -> None:
    """Raise InputError naming the first frame whose size, channels or depth differ."""
    if not infos:
        return
    first = infos[0]
    nc = len(_channel_layout_counts(first))
    for info in infos[1:]:
        if (info.width, info.height) != (first.width, first.height):
            raise InputError(
                f"{info.path}: size {info.width}x{info.height} differs from {first.path} "
                f"({first.width}x{first.height})"
            )
        ic = len(_channel_layout_counts(info))
        if ic != nc:
            raise InputError(f"{info.path}: {ic} colour channel(s) but {first.path} has {nc}")
        if info.bits != first.bits:
            raise InputError(
                f"{info.path}: {info.bits}-bit samples but {first.path} has {first.bits}-bit"
            )


def check_orientation(infos: Sequence[FrameInfo]) -> Optional[str]:
    """Warn when the frames' EXIF Orientation tags differ (some rotated by a tool, some
    only tagged), naming two of them; the warning is also returned. The pixels are used
    as stored. (A merge says this as a finding instead, :mod:`hdrcl.core.orientation`,
    and writes the set's orientation into its output.)"""
    tags = [orientation_value(getattr(info, "orientation", 1)) for info in infos]
    odd = next((k for k, t in enumerate(tags) if t != tags[0]), None)
    if odd is None:
        return None
    msg = (f"{infos[odd].path}: EXIF Orientation {tags[odd]}, but {infos[0].path} has {tags[0]}; "
           "the frames are used as stored (rotate the files alike if their pixels do not line up)")
    logger.warning("%s", msg)
    return msg


def _channel_layout_counts(info: FrameInfo):
    """Colour channel indices from a FrameInfo (alpha dropped)."""
    n = info.nchannels
    return list(range(n)) if n in (1, 3) else list(range(n - 1))
