"""Camera RAW files (CR2, CR3, NEF, ARW, DNG...) as linear 16-bit RGB, through rawpy.

RAW input is the optional extra ``raw`` (``pip install 'hdrcl[raw]'``); rawpy (LibRaw) is
imported inside the functions that need it, and a missing rawpy raises
:class:`~hdrcl.errors.InputError` saying how to install it.

Decoding
    LibRaw demosaics (AHD), applies a white balance, converts to linear sRGB primaries and
    writes 16-bit samples with a unit gamma and no automatic brightening, so a sample is
    proportional to the light that reached the sensor: the response is known
    (:func:`linear_response`) and calibration is skipped. The scaling maps the raw white
    level of the least-amplified channel to 65535. ``adjust_maximum_thr`` is set to 0:
    LibRaw's default (0.75) lowers the white level to the brightest sample of the frame when
    that sample is above 75 % of it, which rescales a frame without clipped areas and breaks
    the proportionality between the frames of a bracket.

White balance
    By default the camera's as-shot multipliers. A camera on auto white balance may change
    them from frame to frame, which would give the channels of one bracket different
    scales; pass the first frame's :attr:`RawFrame.white_balance` to the others (that is
    what a bracket reader should do).

Saturation
    A clipped raw sample does not always reach 65535 in the output: the colour matrix mixes
    it with unclipped channels and demosaicing spreads it into neighbours. So clipping is
    detected in the raw mosaic itself, where the raw white level (the file's per-channel
    levels where it has them, or the level where the frame's samples pile up just under it)
    is known, widened by :data:`SATURATION_DILATE` pixels, and
    :func:`clip_to_saturation` sets every channel of those pixels to 65535, the one code
    that hdrcl's weightings give zero weight. Fusion then treats them as clipped, exactly
    like a blown-out pixel in a JPEG.

Exposure metadata
    rawpy exposes only shutter time, aperture, ISO, focal length and a whole-second capture
    time (``RawPy.other``), and not the camera's make and model. The TIFF/EXIF header that
    most RAW formats carry (CR2, NEF, ARW, DNG, PEF, SRW, ORF, RW2; CR3's ``CMT1``/``CMT2``
    boxes; RAF's embedded JPEG) is read directly (:mod:`hdrcl.io.rawheader`) for exact rational exposure times,
    sub-second capture times, make, model, serial number, exposure bias and mode, which
    bracket grouping uses. Where neither gives an exposure time,
    ``FrameInfo.exposure_time`` is None and the times must come from ``--times`` or
    ``--times-file``.

Limits
    Old Fujifilm SuperCCD files (sensor rotated by 45 degrees) decode to a size the header
    does not predict; :func:`read_raw` reports the decoded size. Frames of one bracket
    shot at different ISO settings may have different white levels, and so a different
    scale, on cameras whose white level depends on ISO.
"""
from __future__ import annotations

import datetime as _dt
import logging
import os
from typing import NamedTuple, Optional, Sequence, Union

import numpy as np

from hdrcl.errors import InputError, check_readable
from hdrcl.io.exif import capture_time, snap_reciprocal
from hdrcl.io.metadata import FrameInfo
from hdrcl.io.rawheader import header_fields

logger = logging.getLogger(__name__)

__all__ = [
    "RAW_EXTENSIONS",
    "RawFrame",
    "is_raw",
    "rawpy_available",
    "read_raw_info",
    "read_raw",
    "camera_white_balance",
    "clip_to_saturation",
]

RAW_EXTENSIONS = (".cr2", ".cr3", ".nef", ".arw", ".dng", ".raf", ".rw2", ".orf", ".pef", ".srw")

#: Raw samples at or above ``black + SATURATION_MARGIN * (white - black)`` count as clipped.
#: White levels in LibRaw's camera tables (and in some files) sit slightly above where the
#: sensor really clips; a bracket loses nothing by discarding the top 2 %, since the next
#: shorter frame measures those pixels.
SATURATION_MARGIN = 0.98
#: Pixels within this distance of a clipped raw sample are treated as clipped too: AHD
#: demosaicing reads a neighbourhood of up to 5 x 5 samples.
SATURATION_DILATE = 2
#: Output code of a clipped value (LibRaw clips every channel at 65535).
TOP_CODE = 65535

_INSTALL_HINT = "RAW files need the optional extra: pip install 'hdrcl[raw]'"


class RawFrame(NamedTuple):
    """One decoded RAW file.

    Attributes
    ----------
    pixels : numpy.ndarray
        ``(H, W, 3)`` uint16 linear RGB (linear sRGB primaries), upright (the camera's
        orientation applied). With ``read_raw(clip=True)`` clipped pixels are already 65535.
    saturation : int
        Lowest output code that may hold a clipped value in every channel: LibRaw scales
        the raw white level of the least-amplified channel to 65535 and clips there, so
        this is 65535; clipping that the colour matrix or demosaicing moved below it is in
        ``saturated``.
    info : FrameInfo
        Header fields, with the decoded size.
    saturated : numpy.ndarray
        ``(H, W)`` bool, True where a raw sample within :data:`SATURATION_DILATE` pixels was
        clipped.
    white_balance : list of float
        The four channel multipliers used; pass them to the other frames of a bracket.
    """

    pixels: np.ndarray
    saturation: int
    info: FrameInfo
    saturated: np.ndarray
    white_balance: list


def is_raw(path) -> bool:
    """True when ``path`` has a camera RAW extension (:data:`RAW_EXTENSIONS`, any case)."""
    return os.path.splitext(os.fspath(path))[1].lower() in RAW_EXTENSIONS


def rawpy_available() -> bool:
    """True when rawpy can be imported (the ``raw`` extra is installed)."""
    try:
        import rawpy  # noqa: F401
    except ImportError:
        return False
    return True


def _rawpy(path: str):
    try:
        import rawpy  # lazy: an optional extra, and LibRaw is a large library
    except ImportError:
        raise InputError(f"{path}: {_INSTALL_HINT}") from None
    return rawpy


_check_file = check_readable


def _libraw_message(exc: BaseException) -> str:
    text = " ".join(str(exc).split()).rstrip(".")
    return text or type(exc).__name__


def _open(name: str):
    """Open ``name`` with rawpy (header parsed, raw data not yet unpacked)."""
    rawpy = _rawpy(name)
    _check_file(name)
    try:
        return rawpy.imread(name)
    except rawpy.LibRawFileUnsupportedError:
        raise InputError(f"{name}: not a RAW file LibRaw can read (unsupported or unknown format)") from None
    except (rawpy.LibRawError, OSError) as exc:
        raise InputError(f"{name}: cannot read RAW file ({_libraw_message(exc)})") from None


def _flip_shape(h: int, w: int, flip: int):
    return (w, h) if flip & 4 else (h, w)


def _output_size(sizes):
    """Size LibRaw's processed image will have, from the header (no decoding)."""
    h, w = int(sizes.height), int(sizes.width)
    aspect = float(sizes.pixel_aspect or 1.0)
    # LibRaw stretch(): non-square pixels are resampled to square ones.
    if aspect < 1.0 - 1e-6:
        h = int(h / aspect + 0.5)
    elif aspect > 1.0 + 1e-6:
        w = int(w * aspect + 0.5)
    return _flip_shape(h, w, int(sizes.flip))


def _apply_flip(a: np.ndarray, flip: int) -> np.ndarray:
    """Orient ``a`` (sensor orientation, (H, W[, C])) as LibRaw does for ``sizes.flip``:
    bit 0 mirrors left-right, bit 1 top-bottom, then bit 2 transposes."""
    if flip & 1:
        a = a[:, ::-1]
    if flip & 2:
        a = a[::-1]
    if flip & 4:
        a = a.swapaxes(0, 1)
    return np.ascontiguousarray(a)


def _positive(v) -> Optional[float]:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if np.isfinite(f) and f > 0 else None


def _capture_time(exif: dict) -> Optional[_dt.datetime]:
    """The header's DateTimeOriginal, else its DateTime: a RAW file is always a camera's."""
    original = exif.get("datetime_original")
    return capture_time(original if isinstance(original, str) else None,
                        exif.get("subsec_original") if original else None,
                        exif.get("datetime") if isinstance(exif.get("datetime"), str) else None, True)


def _frame_info(name: str, raw, exif: dict, height: int, width: int, nchannels: int) -> FrameInfo:
    t = _positive(exif.get("exposure_time"))
    fnumber = _positive(exif.get("fnumber"))
    iso = _positive(exif.get("iso"))
    focal = _positive(exif.get("focal_length"))
    when = _capture_time(exif)
    lens = exif.get("lens")
    if t is None or fnumber is None or iso is None or when is None:
        # rawpy's fields (LibRaw also reads maker notes) need the raw data unpacked, so
        # they are only asked for when the header left something out.
        try:
            other = raw.other
            t = t or (snap_reciprocal(other.shutter_speed) if _positive(other.shutter_speed) else None)
            fnumber = fnumber or _positive(other.aperture)
            iso = iso or _positive(other.iso_speed)
            focal = focal or _positive(other.focal_length)
            if when is None and other.timestamp.year > 1970:
                when = other.timestamp  # whole seconds, local time
            lens = lens or (raw.lens.model or None)
        except Exception as exc:  # rawpy raises LibRaw errors of many kinds here
            logger.debug("%s: rawpy exposure fields unavailable (%s)", name, exc)
    bias = exif.get("exposure_bias")
    mode = exif.get("exposure_mode")
    return FrameInfo(
        path=name,
        width=int(width),
        height=int(height),
        nchannels=int(nchannels),
        channel_names=("R", "G", "B") if nchannels == 3 else ("Y",),
        bits=16,
        exposure_time=t,
        fnumber=fnumber,
        iso=iso,
        exposure_bias=float(bias) if isinstance(bias, (int, float)) else None,
        exposure_mode=int(mode) if isinstance(mode, int) else None,
        capture_time=when,
        make=exif.get("make") if isinstance(exif.get("make"), str) else None,
        model=exif.get("model") if isinstance(exif.get("model"), str) else None,
        serial=str(exif["serial"]) if exif.get("serial") is not None else None,
        lens=lens if isinstance(lens, str) else None,
        focal_length=focal,
        extra={"raw": True, "raw:flip": int(raw.sizes.flip)},
    )


def read_raw_info(path) -> FrameInfo:
    """Read a RAW file's header: processed size, 3 channels, 16 bits, exposure fields.

    The size is that of :func:`read_raw`'s output (orientation and non-square pixels
    applied); no pixels are demosaiced. Exposure fields come from the file's EXIF header,
    else from rawpy (which needs the raw data unpacked, a fraction of a second); an
    exposure time found in neither is None, and ``--times`` or ``--times-file`` must
    give it.

    Raises
    ------
    InputError
        rawpy is not installed, or the file is missing or not a RAW file LibRaw reads.
    """
    name = os.fspath(path)
    with _open(name) as raw:
        try:
            h, w = _output_size(raw.sizes)
            nch = 1 if raw.num_colors == 1 else 3
        except Exception as exc:  # LibRaw errors of any kind
            raise InputError(f"{name}: cannot read RAW file ({_libraw_message(exc)})") from None
        return _frame_info(name, raw, header_fields(name), h, w, nch)


def _raw_clipped(raw) -> Optional[np.ndarray]:
    """Clipped samples of the visible raw mosaic (sensor orientation), or None when the
    file has no single-plane mosaic (Foveon, sRAW, linear DNG)."""
    import rawpy

    if raw.raw_type != rawpy.RawType.Flat:
        return None
    try:
        colors = raw.raw_colors_visible
    except (NotImplementedError, RuntimeError):  # exotic layouts (Leaf Catchlight...)
        return None
    data = raw.raw_image_visible
    black = np.asarray(raw.black_level_per_channel, np.float64)
    white = np.full(4, float(raw.white_level))
    per_channel = getattr(raw, "camera_white_level_per_channel", None)  # absent in old rawpy
    if per_channel is not None:
        lin = np.asarray(per_channel, np.float64)
        plausible = (lin > black + 0.5 * (white - black)) & (lin < white)
        white = np.where(plausible, lin, white)
    thr = black + SATURATION_MARGIN * (white - black)
    for c in np.unique(colors):
        vals = data[colors == c]
        top = int(vals.max())
        # Samples piled up at one value high in the range mark where this sensor really
        # clips, even below the nominal white level.
        if top >= black[c] + 0.5 * (white[c] - black[c]) and top < thr[c]:
            if np.count_nonzero(vals == top) >= max(16, 1e-4 * vals.size):
                thr[c] = top
    return data >= thr[colors]


def _multipliers(raw, white_balance) -> list:
    """The four multipliers LibRaw will use for ``white_balance``."""
    if white_balance == "camera":
        wb = [float(v) for v in raw.camera_whitebalance]
        if any(wb[:3]):
            return wb
        # No as-shot values: LibRaw falls back to daylight.
    elif not isinstance(white_balance, str):
        return [float(v) for v in white_balance]
    return [float(v) for v in raw.daylight_whitebalance]


def camera_white_balance(path) -> list:
    """A RAW file's as-shot white balance multipliers ``(R, G, B, G2)`` (daylight when
    the file has none), without demosaicing.

    Read the first frame's with this and pass them as ``read_raw(white_balance=...)`` to
    every frame of a bracket, so that a camera on auto white balance does not give the
    frames' channels different scales.
    """
    name = os.fspath(path)
    with _open(name) as raw:
        try:
            return _multipliers(raw, "camera")
        except Exception as exc:  # LibRaw errors of any kind
            raise InputError(f"{name}: cannot read RAW file ({_libraw_message(exc)})") from None


def _postprocess_args(rawpy, white_balance) -> dict:
    args = dict(gamma=(1, 1), no_auto_bright=True, output_bps=16, adjust_maximum_thr=0.0,
                output_color=rawpy.ColorSpace.sRGB, highlight_mode=rawpy.HighlightMode.Clip)
    if isinstance(white_balance, str):
        if white_balance == "camera":
            args["use_camera_wb"] = True
        elif white_balance != "daylight":
            raise ValueError(f"white_balance must be 'camera', 'daylight' or 4 multipliers, not {white_balance!r}")
    else:
        wb = [float(v) for v in white_balance]
        if len(wb) != 4 or not all(np.isfinite(wb)) or min(wb[:3]) <= 0:
            raise ValueError(f"white_balance multipliers must be 4 numbers (R, G, B, G2), not {white_balance!r}")
        args["user_wb"] = wb
    return args


def read_raw(path, *, white_balance: Union[str, Sequence[float]] = "camera", clip: bool = True) -> RawFrame:
    """Decode a RAW file into linear 16-bit RGB.

    Parameters
    ----------
    path : str or os.PathLike
    white_balance : "camera", "daylight" or sequence of 4 float
        The as-shot multipliers, LibRaw's daylight multipliers for the camera, or
        explicit ``(R, G, B, G2)`` multipliers (give all frames of a bracket the first
        frame's :attr:`RawFrame.white_balance`).
    clip : bool
        Apply :func:`clip_to_saturation` (clipped pixels become 65535 in every channel).

    Returns
    -------
    RawFrame
        ``(pixels, saturation, info, saturated, white_balance)``.

    Raises
    ------
    InputError
        rawpy is not installed, or the file is missing, not a RAW file LibRaw reads, or
        corrupt.
    """
    name = os.fspath(path)
    rawpy = _rawpy(name)
    args = _postprocess_args(rawpy, white_balance)
    with _open(name) as raw:
        try:
            flip = int(raw.sizes.flip)
            clipped = _raw_clipped(raw)
            wb = _multipliers(raw, white_balance)
            pixels = raw.postprocess(**args)
            info = _frame_info(name, raw, header_fields(name), pixels.shape[0], pixels.shape[1],
                               1 if pixels.shape[2] == 1 else 3)
        except InputError:
            raise
        except Exception as exc:  # LibRaw errors of any kind: truncated, corrupt
            raise InputError(f"{name}: cannot decode RAW data ({_libraw_message(exc)})") from None
    if pixels.dtype != np.uint16 or pixels.ndim != 3:
        raise InputError(f"{name}: LibRaw returned {pixels.dtype} {pixels.shape}, expected 16-bit (H, W, C)")
    if pixels.shape[2] not in (1, 3):
        pixels = np.ascontiguousarray(pixels[:, :, :3])
        info.nchannels, info.channel_names = 3, ("R", "G", "B")
    saturated = _saturated_pixels(clipped, pixels, flip)
    info.extra["raw:white_balance"] = wb
    if clip:
        pixels = clip_to_saturation(pixels, TOP_CODE, saturated)
    return RawFrame(pixels=pixels, saturation=TOP_CODE, info=info, saturated=saturated, white_balance=wb)


def _saturated_pixels(clipped: Optional[np.ndarray], pixels: np.ndarray, flip: int) -> np.ndarray:
    """Output-space (H, W) mask of pixels touched by a clipped raw sample."""
    h, w = pixels.shape[:2]
    if clipped is None:
        # No mosaic to look at: all that is known is LibRaw's clip at the top code.
        return np.any(pixels >= TOP_CODE, axis=2)
    from scipy import ndimage

    # A square maximum filter runs as two 1-D passes: cheap even at 50 megapixels.
    mask = ndimage.maximum_filter(clipped.view(np.uint8), size=2 * SATURATION_DILATE + 1,
                                  mode="nearest").view(bool)
    sh, sw = _flip_shape(h, w, flip)
    if mask.shape != (sh, sw):
        # Non-square pixels (stretched) or a rotated Fuji sensor: nearest-neighbour map.
        ys = np.minimum((np.arange(sh) * mask.shape[0]) // sh, mask.shape[0] - 1)
        xs = np.minimum((np.arange(sw) * mask.shape[1]) // sw, mask.shape[1] - 1)
        mask = mask[ys[:, None], xs[None, :]]
    return _apply_flip(mask, flip)


def clip_to_saturation(pixels: np.ndarray, saturation: int = TOP_CODE,
                       saturated: Optional[np.ndarray] = None) -> np.ndarray:
    """Mark clipped samples with the top code 65535, which hdrcl's weightings ignore.

    Parameters
    ----------
    pixels : numpy.ndarray
        ``(H, W, C)`` uint16.
    saturation : int
        Samples at or above this code are clipped (set to 65535).
    saturated : numpy.ndarray, optional
        ``(H, W)`` bool: every channel of these pixels is set to 65535 (a clipped raw
        channel corrupts all output channels through the colour matrix).

    Returns
    -------
    numpy.ndarray
        A new uint16 array.
    """
    out = np.array(pixels, dtype=np.uint16, copy=True)
    if out.ndim != 3:
        raise ValueError(f"pixels must be (H, W, C), got shape {out.shape}")
    out[out >= int(saturation)] = TOP_CODE
    if saturated is not None:
        if saturated.shape != out.shape[:2]:
            raise ValueError(f"saturated mask {saturated.shape} does not match pixels {out.shape[:2]}")
        out[saturated] = TOP_CODE
    return out


