"""Reading radiance maps and their hdrcl metadata back (EXR, HDR, float TIFF, PFM)."""
from __future__ import annotations

import json
import os
from typing import Optional

import numpy as np

from hdrcl.errors import InputError
from hdrcl.io.frames import open_input, _read_error
from hdrcl.io.outmeta import hdr_header
from hdrcl.io.writers import METADATA_PREFIX


def _pick_channels(spec, path: str) -> list:
    names = [str(n) for n in spec.channelnames]
    upper = [n.split(".")[-1].upper() for n in names]
    if all(c in upper for c in ("R", "G", "B")):
        return [upper.index(c) for c in ("R", "G", "B")]
    if "Y" in upper:
        return [upper.index("Y")]
    n = spec.nchannels
    if n in (1, 3):
        return list(range(n))
    if n in (2, 4) and spec.alpha_channel == n - 1:
        return list(range(n - 1))
    raise InputError(
        f"{path}: cannot find grey or RGB channels among {', '.join(names) or n}"
    )


def pick_channels(spec, path: str) -> list:
    """Indices of the grey or R, G, B channels of an OpenImageIO header (alpha and other
    channels left out); :class:`InputError` naming ``path`` when there are none."""
    return _pick_channels(spec, path)


def radiance_header(path) -> tuple:
    """``(width, height, channels)`` of a radiance map from its header alone (channels:
    1 or 3, as :func:`read_radiance` returns them)."""
    name = os.fspath(path)
    inp = open_input(name)
    try:
        spec = inp.spec()
        width, height = int(spec.width), int(spec.height)
        if _is_rgbe(name) and rgbe_orientation(name)[1] == "X":  # columns as scanlines
            width, height = height, width
        return width, height, len(_pick_channels(spec, name))
    finally:
        inp.close()


def read_radiance_colorspace(path, *, require_float: bool = False) -> tuple:
    """:func:`read_radiance`'s pixels and the file's colour space, ``rec709`` or ``acescg``.

    From ``oiio:ColorSpace`` (EXR), or a Radiance file's ``PRIMARIES=`` line (which
    OpenImageIO does not read); ``rec709`` when the file says nothing else.
    """
    from hdrcl.io.colorspace import from_file_tag

    name = os.fspath(path)
    pixels, _meta = read_radiance(name, require_float=require_float)
    if os.path.splitext(name)[1].lower() == ".hdr":
        from hdrcl.io.outmeta import hdr_colorspace

        return pixels, hdr_colorspace(name) or "rec709"
    inp = open_input(name)
    try:
        tag = inp.spec().getattribute("oiio:ColorSpace")
    finally:
        inp.close()
    return pixels, from_file_tag(tag)


def read_radiance(path, *, require_float: bool = False) -> tuple:
    """Read a radiance map written by :func:`write_radiance` (or any float image).

    Parameters
    ----------
    path : str or os.PathLike
        EXR, HDR, TIFF, PFM or another format OpenImageIO reads.
    require_float : bool
        Refuse files stored as integers (an ordinary 8- or 16-bit photograph is not a
        radiance map) and files holding NaN or infinite values.

    Returns
    -------
    pixels : numpy.ndarray
        ``(H, W, C)`` float32, C = 1 or 3 (alpha and other channels dropped); radiance
        relative to a 1 s exposure, i.e. the stored values divided by
        :func:`stored_scale` (the reference exposure and any ``hdrcl:halfScale``), or
        cd/m^2 for a map in absolute units. A Radiance file is decoded as Radiance does
        (:func:`rgbe_centre`), divided by the product of its ``EXPOSURE=`` lines, and a
        map in cd/m^2 multiplied by :func:`hdr_luminance_factor`.
    metadata : dict
        The ``hdrcl:*`` attributes without the prefix (or the JSON kept in a TIFF's
        ImageDescription); empty when there are none.

    Raises
    ------
    InputError
        Missing, unreadable, truncated or corrupt file, or no grey/RGB channels.
    """
    name = os.fspath(path)
    inp = open_input(name)
    try:
        spec = inp.spec()
        channels = _pick_channels(spec, name)
        if require_float:
            _check_float_format(spec, name)
        from hdrcl.io.frames import decoder_stderr

        with decoder_stderr():
            data = inp.read_image(0, 0, 0, spec.nchannels, "float")
        problem = _read_error(inp, name)
        if problem is None and data is None:
            problem = f"{name}: cannot decode pixel data"
        if problem is not None:
            raise InputError(problem)
        metadata = _with_hdr_line(name, _spec_metadata(spec))
        exposure_line = _positive(spec.getattribute("hdr:exposure"))
        rgbe = _is_rgbe(name)
    finally:
        inp.close()
    data = np.asarray(data, dtype=np.float32)
    if data.ndim == 2:
        data = data[:, :, None]
    if rgbe:
        data = to_picture_order(data, rgbe_orientation(name))
        data = rgbe_centre(data)
        header = hdr_header(name)
        exposure_line = header["exposure"]
        metadata = dict(metadata)
        absolute_hdr = str(metadata.get("units", "")).startswith("cd/m2")
        if absolute_hdr:  # cd/m^2 = stored x 179 / EXPOSURE (or, older hdrcl, stored / EXPOSURE)
            exposure_line /= hdr_luminance_factor(metadata)
    pixels = np.ascontiguousarray(data[:, :, channels])
    if require_float:
        bad = int(np.count_nonzero(~np.isfinite(pixels)))
        if bad:
            raise InputError(f"{name}: not a usable radiance map ({bad} NaN or infinite sample(s))")
    divisor = stored_scale(metadata, exposure_line)
    if divisor != 1.0:
        with np.errstate(over="ignore", invalid="ignore"):
            scaled = (pixels.astype(np.float64) / divisor).astype(np.float32)
        _check_scaled(name, pixels, scaled, divisor, rgbe)
        pixels = scaled
    return pixels, metadata


def _check_scaled(name: str, stored: np.ndarray, scaled: np.ndarray, divisor: float, rgbe: bool) -> None:
    """Refuse a map whose stored scale (``EXPOSURE=``, ``hdrcl:referenceExposure``) takes
    finite samples beyond float32 (``EXPOSURE=1e-38``): the finiteness check above ran on
    the stored values, and an infinite radiance would reach every figure made of it."""
    bad = int(np.count_nonzero(np.isfinite(stored) & ~np.isfinite(scaled)))
    if bad:
        what = "its EXPOSURE= lines" if rgbe else "its stored scale (hdrcl:referenceExposure x halfScale)"
        raise InputError(f"{name}: {what} ({divisor:.6g} in all) take {bad} sample(s) beyond the largest float "
                         f"(3.4e38); not a usable radiance map (check the header)")


def rgbe_orientation(path) -> str:
    """The resolution line's axes of a Radiance picture, e.g. ``-Y+X`` (the standard: top
    scanline first, left to right) or ``+Y+X`` (bottom scanline first); ``-Y+X`` when the
    line cannot be read (the decoder then refuses the file)."""
    with open(os.fspath(path), "rb") as fh:
        head = fh.read(1 << 20)  # the header and the resolution line (headers are a few kB)
    _, _, rest = head.partition(b"\n\n")
    words = rest.split(b"\n", 1)[0].split()
    if len(words) == 4 and all(len(w) == 2 and w[:1] in b"+-" and w[1:] in b"XY" for w in words[::2]) \
            and words[0][1:] != words[2][1:]:
        return (words[0] + words[2]).decode("ascii")
    return "-Y+X"


def to_picture_order(data: np.ndarray, orientation: str) -> np.ndarray:
    """Scanlines as a file stores them (what OpenImageIO returns: ``(first axis, second
    axis, C)``) put in picture order, top row first, left to right, as Radiance's
    resolution line says (``+Y``: the first scanline is the bottom; ``-X``: right to
    left; ``X`` first: the scanlines are columns). OpenImageIO ignores the line, so a
    ``+Y 64 +X 64`` file was tone mapped upside down; ``ra_tiff``'s Orientation tag is
    the oracle (tests/test_radiance_conventions.py)."""
    if orientation == "-Y+X":
        return data
    if orientation[1] == "X":  # column-major: the scanlines are columns
        data = np.swapaxes(data, 0, 1)
    ysign = orientation[0] if orientation[1] == "Y" else orientation[2]
    xsign = orientation[2] if orientation[1] == "Y" else orientation[0]
    if ysign == "+":
        data = data[::-1]
    if xsign == "-":
        data = data[:, ::-1]
    return np.ascontiguousarray(data)


def _is_rgbe(name: str) -> bool:
    with open(name, "rb") as f:
        return f.read(2) == b"#?"


def rgbe_centre(data: np.ndarray) -> np.ndarray:
    """OpenImageIO's decoding of RGBE (``m x 2^(e-136)``) made Radiance's
    (``(m + 0.5) x 2^(e-136)``, ``colr_color`` in Radiance's color.c): the shared
    exponent is recovered from the largest channel (a normalised mantissa, 128..255, as
    every RGBE encoder writes) and half a step is added to each channel of a pixel that
    is not black. Exact in float32 (9 significant bits)."""
    rgb = np.asarray(data, np.float32)
    top = rgb.max(axis=-1, keepdims=True) if rgb.shape[-1] > 1 else rgb
    with np.errstate(divide="ignore", invalid="ignore"):
        step = np.where(top > 0, np.exp2(np.floor(np.log2(np.where(top > 0, top, 1.0))) - 7.0), 0.0)
    return (rgb + 0.5 * step).astype(np.float32)


def hdr_luminance_factor(metadata: dict) -> float:
    """cd/m^2 per stored unit (after EXPOSURE) of a ``.hdr`` hdrcl wrote in cd/m^2: 179
    (Radiance's convention: files with ``whiteEfficacy`` or ``luminanceChain`` on their
    HDRCL= line), or 1 for the ``--absolute``/``--reference-patch`` maps of older hdrcl,
    which stored cd/m^2 directly (their HDRCL= line has ``units`` cd/m2 and neither key)."""
    from hdrcl.io.outmeta import WHITE_EFFICACY_KEY

    if WHITE_EFFICACY_KEY in metadata or "luminanceChain" in metadata:
        return float(metadata.get(WHITE_EFFICACY_KEY) or 179.0)
    return 1.0


def _positive(value) -> Optional[float]:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    v = float(value)
    return v if (v > 0 and np.isfinite(v)) else None


def stored_scale(metadata: dict, exposure_line: Optional[float] = None) -> float:
    """What a file's values were multiplied by relative to radiance for a 1 s exposure:
    ``hdrcl:referenceExposure`` x ``hdrcl:halfScale`` (:mod:`hdrcl.core.encode`), or a
    Radiance file's ``EXPOSURE=`` (Radiance's convention: stored = original x EXPOSURE)."""
    ref = _positive(metadata.get("referenceExposure"))
    half = _positive(metadata.get("halfScale"))
    if ref is None and half is None:
        return exposure_line if exposure_line is not None else 1.0
    return (ref or 1.0) * (half or 1.0)


def _check_float_format(spec, name: str) -> None:
    """Refuse an integer image where radiance is expected."""
    import OpenImageIO as oiio

    if spec.format.basetype not in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE):
        bits = 8 * spec.format.size()
        raise InputError(f"{name}: {'an' if bits == 8 else 'a'} {bits}-bit photograph, not a radiance map; give the .exr, .hdr, "
                         ".pfm or float TIFF that 'hdrcl merge' wrote")


def _spec_metadata(spec) -> dict:
    """``hdrcl:*`` attributes of a header, and the JSON some formats keep in ImageDescription."""
    metadata = {}
    desc = spec.getattribute("ImageDescription")
    if isinstance(desc, str) and desc.startswith('{"hdrcl"'):
        try:
            parsed = json.loads(desc).get("hdrcl", {})
        except (ValueError, AttributeError):
            parsed = {}
        if isinstance(parsed, dict):
            metadata.update(parsed)
    for p in spec.extra_attribs:
        if p.name.startswith(METADATA_PREFIX):
            metadata[p.name[len(METADATA_PREFIX):]] = p.value
    return metadata


def read_metadata(path) -> dict:
    """The ``hdrcl:*`` metadata of a file, from its header only (no pixels decoded).

    Reads what :func:`write_radiance` and :func:`write_ldr` store: EXR ``hdrcl:*``
    attributes, or the JSON kept in ImageDescription (TIFF, JPEG). ``hdrcl batch``
    uses it to decide, cheaply, whether an existing output is already up to date.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    dict
        Keys without the ``hdrcl:`` prefix; empty when the file carries none.

    Raises
    ------
    InputError
        The file is missing or its header cannot be read.
    """
    name = os.fspath(path)
    inp = open_input(name)
    try:
        spec = inp.spec()
        metadata = _with_hdr_line(name, _spec_metadata(spec))
    finally:
        inp.close()
    return metadata


def _with_hdr_line(name: str, metadata: dict) -> dict:
    """A Radiance file's ``HDRCL=`` header line (:func:`hdrcl.io.outmeta.hdr_metadata`)
    added to ``metadata``. Its scale keys are left out: the ``EXPOSURE=`` lines say the
    scale (Radiance tools that rescale a picture add to them)."""
    if not name.lower().endswith(".hdr"):
        return metadata
    from hdrcl.io.outmeta import hdr_metadata

    try:
        extra = hdr_metadata(name)
    except OSError:
        return metadata
    for key in ("referenceExposure", "halfScale"):
        extra.pop(key, None)
    return {**extra, **metadata}


def white_luminance(path) -> Optional[float]:
    """OpenEXR's ``whiteLuminance`` of a file (cd/m^2 of RGB 1, 1, 1), or None."""
    inp = open_input(os.fspath(path))
    try:
        value = inp.spec().getattribute("whiteLuminance")
    finally:
        inp.close()
    return _positive(value)
