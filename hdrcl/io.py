"""Reading bracketed photographs with OpenImageIO.

Only this module and :mod:`hdrcl.writers` import OpenImageIO, and both import it inside
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
import datetime as _dt
import logging
import os
import re
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from .errors import InputError, check_readable
from .raw import is_raw
from .metadata import FrameInfo

logger = logging.getLogger(__name__)

__all__ = ["Image", "read_info", "read_image", "read_images", "ignore_color_mask", "BracketReader"]


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
    """First meaningful line of an OIIO error, without the quoted file name it repeats."""
    lines = [ln.strip() for ln in (text or "").splitlines() if ln.strip()]
    if not lines:
        return ""
    msg = lines[0]
    base = os.path.basename(path)
    for p in (path, base):
        msg = msg.replace(f' ("{p}")', "").replace(f'"{p}"', "")
    return " ".join(msg.split()).rstrip(".")


_FORMAT_NAMES = {"openexr": "EXR", "jpeg": "JPEG", "png": "PNG", "tiff": "TIFF", "hdr": "HDR"}
_TRUNCATED = re.compile(r"premature end|end of file|truncat|short read|unexpected end|eof",
                        re.IGNORECASE)


def _config():
    """Configuration hints used for every input: keep alpha unassociated (raw values)."""
    oiio = _oiio()
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    # PFM stores rows bottom to top; OIIO 3.2 flips only when this hint is present.
    config.attribute("pnm:pfmflip", 1)
    return config


def _open_input(path):
    """Open ``path`` for reading, raising InputError naming it when it cannot be opened.

    Returns the open ``ImageInput``; the caller closes it.
    """
    oiio = _oiio()
    name = _name(path)
    check_readable(name)
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


def _snap_reciprocal(t: float) -> float:
    """EXIF rationals arrive as float32: turn 0.0333333 back into exactly 1/30."""
    t = float(str(np.float32(t)))  # shortest decimal that round-trips the float32
    if 0.0 < t < 1.0:
        n = round(1.0 / t)
        if n >= 1 and abs(1.0 / t - n) <= 1e-4 * n:
            return 1.0 / n
    return t


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
    text = _as_str(_attr(spec, "Exif:DateTimeOriginal", "DateTime"))
    if not text:
        return None
    try:
        when = _dt.datetime.strptime(text[:19], "%Y:%m:%d %H:%M:%S")
    except ValueError:
        try:
            when = _dt.datetime.fromisoformat(text)
        except ValueError:
            logger.debug("unparsable capture time %r", text)
            return None
    sub = _as_str(_attr(spec, "Exif:SubsecTimeOriginal", "Exif:SubsecTime"))
    if sub:
        digits = "".join(ch for ch in sub if ch.isdigit())
        if digits:
            # SubsecTime is the decimal fraction's digits: "25" means 0.25 s.
            when = when.replace(microsecond=int(round(float("0." + digits) * 1e6)) % 1000000)
    return when


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
        t = _snap_reciprocal(t)
    mode = _as_float(spec.getattribute("Exif:ExposureMode"))
    extra = {}
    for key in ("Orientation", "oiio:BitsPerSample", "Exif:ExposureProgram",
                "Exif:WhiteBalance", "oiio:ColorSpace"):
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
        from .raw import read_raw_info

        return read_raw_info(name)
    inp = _open_input(name)
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
        from .raw import read_raw

        f = read_raw(name)
        return Image(pixels=f.pixels, valid=None, info=f.info)
    inp = _open_input(name)
    try:
        spec = inp.spec()
        info = _info_from_spec(spec, name)
        colour, alpha = _channel_layout(spec, name)
        fmt = "uint8" if info.bits == 8 else "uint16"
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


def _channel_layout_counts(info: FrameInfo):
    """Colour channel indices from a FrameInfo (alpha dropped)."""
    n = info.nchannels
    return list(range(n)) if n in (1, 3) else list(range(n - 1))


class BracketReader:
    """Decodes the frames of a bracket set strip by strip, all frames in parallel.

    Memory stays bounded by the strip height whatever the image size: each frame's
    file is opened once and read top to bottom with ``read_scanlines``, one thread per
    frame (OpenImageIO releases the GIL while decoding), and :meth:`strips` decodes the
    next strip while the caller works on the current one.

    Parameters
    ----------
    paths : sequence of path
    infos : sequence of FrameInfo, optional
        Headers already read (skips a second header read).

    Raises
    ------
    InputError
        A file cannot be opened, or the frames are incompatible.
    """

    def __init__(self, paths: Sequence, infos: Optional[Sequence[FrameInfo]] = None):
        self.paths = [_name(p) for p in paths]
        raws = [is_raw(p) for p in self.paths]
        if any(raws) and not all(raws):
            odd = self.paths[raws.index(False) if raws[0] else raws.index(True)]
            raise InputError(f"{odd}: a bracket set mixes RAW and non-RAW files")
        self.infos = list(infos) if infos is not None else [read_info(p) for p in self.paths]
        check_compatible(self.infos)
        first = self.infos[0]
        self.width, self.height = first.width, first.height
        self.dtype = np.dtype(np.uint8 if first.bits == 8 else np.uint16)
        self._inputs: list = [None] * len(self.paths)
        self._layout: list = [None] * len(self.paths)
        self._raw_wb = None
        if any(raws):
            from .raw import camera_white_balance

            # one white balance for every frame: auto WB must not rescale channels per frame
            self._raw_wb = camera_white_balance(self.paths[0])
        self._pool = concurrent.futures.ThreadPoolExecutor(
            max_workers=max(1, min(len(self.paths), (os.cpu_count() or 1) + 1)),
            thread_name_prefix="hdrcl-decode")

    @property
    def nch(self) -> int:
        return len(_channel_layout_counts(self.infos[0]))

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        self._pool.shutdown(wait=True)
        for k, inp in enumerate(self._inputs):
            if inp is not None and hasattr(inp, "close"):
                inp.close()
            self._inputs[k] = None

    def _read(self, k: int, y0: int, y1: int):
        name = self.paths[k]
        if self._raw_wb is not None:
            # LibRaw decodes whole frames: keep the frame while its strips are served
            px = self._inputs[k]
            if px is None:
                from .raw import read_raw

                px = self._inputs[k] = read_raw(name, white_balance=self._raw_wb).pixels
                if px.shape[:2] != (self.height, self.width):
                    raise InputError(f"{name}: decoded {px.shape[1]}x{px.shape[0]}, header says "
                                     f"{self.width}x{self.height}")
            out = np.ascontiguousarray(px[y0:y1])
            if y1 >= self.height:
                self._inputs[k] = None
            return out, None
        inp = self._inputs[k]
        if inp is None:
            inp = self._inputs[k] = _open_input(name)
            self._layout[k] = _channel_layout(inp.spec(), name)
        colour, alpha = self._layout[k]
        spec = inp.spec()
        fmt = "uint8" if self.dtype == np.uint8 else "uint16"
        data = inp.read_scanlines(0, 0, y0, y1, 0, 0, spec.nchannels, fmt)
        problem = _read_error(inp, name)
        if problem is None and data is None:
            problem = f"{name}: cannot decode pixel data"
        if problem is not None:
            raise InputError(problem)
        data = np.asarray(data)
        if data.ndim == 2:
            data = data[:, :, None]
        if data.shape != (y1 - y0, self.width, spec.nchannels):
            raise InputError(f"{name}: decoded {data.shape} samples for rows {y0}-{y1}")
        if alpha is None:
            return np.ascontiguousarray(data), None
        return np.ascontiguousarray(data[:, :, colour]), data[:, :, alpha] != 0

    def read_rows(self, y0: int, y1: int):
        """Rows ``y0..y1`` of every frame: ``(frames, valid)`` lists in path order."""
        futs = [self._pool.submit(self._read, k, y0, y1) for k in range(len(self.paths))]
        got = [f.result() for f in futs]  # first failure in path order is raised
        return [g[0] for g in got], [g[1] for g in got]

    def strips(self, rows: int):
        """Yield ``(y0, y1, frames, valid)`` top to bottom, decoding one strip ahead."""
        rows = max(1, int(rows))
        starts = list(range(0, self.height, rows))
        ahead = None
        try:
            for n, y0 in enumerate(starts):
                y1 = min(self.height, y0 + rows)
                current = ahead.result() if ahead is not None else self.read_rows(y0, y1)
                ahead = None
                if n + 1 < len(starts):
                    ny0 = starts[n + 1]
                    ahead = _Prefetch(self, ny0, min(self.height, ny0 + rows))
                yield (y0, y1) + tuple(current)
        finally:
            if ahead is not None:  # never close the files under a running decode
                ahead.wait()

    def read_all(self):
        """Every frame whole: ``(frames, valid)``; memory grows with the image.

        Each frame is decoded in one call on its own thread, straight into the array
        returned (no strip copies).
        """
        futs = [self._pool.submit(self._read, k, 0, self.height) for k in range(len(self.paths))]
        got = [f.result() for f in futs]
        return [g[0] for g in got], [g[1] for g in got]

    def read_grid(self, stride: int):
        """Every ``stride``-th row and column of every frame, read in one pass."""
        stride = max(1, int(stride))
        hh = len(range(0, self.height, stride))
        ww = len(range(0, self.width, stride))
        frames = [np.empty((hh, ww, self.nch), self.dtype) for _ in self.paths]
        valid = [None] * len(self.paths)
        rows = stride * max(1, (1 << 22) // max(self.width * stride, 1))
        for y0, y1, fs, vs in self.strips(rows):
            g0 = y0 // stride
            g1 = g0 + len(range(y0, y1, stride))
            for k, (f, v) in enumerate(zip(fs, vs)):
                frames[k][g0:g1] = f[::stride, ::stride]
                if v is not None:
                    if valid[k] is None:
                        valid[k] = np.ones((hh, ww), bool)
                    valid[k][g0:g1] = v[::stride, ::stride]
        return frames, valid


class _Prefetch:
    """A strip being decoded on a helper thread while the caller uses the previous one."""

    def __init__(self, reader: "BracketReader", y0: int, y1: int):
        import threading

        self._result = None
        self._error = None
        self._thread = threading.Thread(target=self._run, args=(reader, y0, y1), daemon=True,
                                        name="hdrcl-prefetch")
        self._thread.start()

    def _run(self, reader, y0, y1):
        try:
            self._result = reader.read_rows(y0, y1)
        except BaseException as exc:  # handed to the consumer
            self._error = exc

    def wait(self):
        self._thread.join()

    def result(self):
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._result


def ignore_color_mask(pixels: np.ndarray, rgb) -> np.ndarray:
    """Mark pixels that equal a colour exactly (for example the blue fill of Memorial).

    Parameters
    ----------
    pixels : numpy.ndarray
        ``(H, W, C)`` ``uint8`` or ``uint16`` samples, C = 1 or 3 (or ``(H, W)`` grey).
    rgb : sequence of int
        The colour in 8-bit units, e.g. ``(0, 0, 255)``; multiplied by 257 for 16-bit
        pixels so that 255 maps to 65535. Grey images compare with ``rgb[0]``.

    Returns
    -------
    numpy.ndarray
        ``(H, W)`` bool, True where the pixel equals the colour.
    """
    px = np.asarray(pixels)
    if px.ndim == 2:
        px = px[:, :, None]
    if px.ndim != 3 or px.shape[2] not in (1, 3):
        raise ValueError(f"pixels must be (H, W, 1) or (H, W, 3), got shape {px.shape}")
    values = [int(v) for v in (rgb if np.ndim(rgb) else (rgb,))]
    if any(v < 0 or v > 255 for v in values):
        raise ValueError(f"colour {tuple(values)} is not in 8-bit units 0..255")
    scale = 257 if px.dtype == np.uint16 else 1
    if px.shape[2] == 1:
        target = np.array([values[0] * scale])
    else:
        if len(values) != 3:
            raise ValueError(f"colour {tuple(values)} needs three values for RGB pixels")
        target = np.array(values) * scale
    return np.all(px == target.astype(px.dtype), axis=2)
