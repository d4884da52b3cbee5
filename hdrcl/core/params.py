"""Every option's type and range in one table, checked before any file is decoded.

The command line builds its option types from :data:`TABLE` (``hdrcl.cli.options``), and
the library's entry points (``calibrate``, ``merge``, ``merge_files``, ``merge_bracket``,
``load_bracket``, ``expose``, ``tonemap``) call :func:`check_options` first, so
``--smoothness 1e308`` and ``smoothness=1e308`` are refused by one rule, in the same
words, before any pixel is read. Messages name the command line's flag
(``--smoothness: ...``); the API rewrites it as the parameter (``smoothness: ...``).

A value is refused with :class:`~hdrcl.errors.UsageError` (exit code 2) when it is out
of range, not finite, or not of the option's kind; a Python object of the wrong type
with :class:`~hdrcl.errors.ParameterTypeError` (a UsageError that is also a TypeError).
Strings are parsed as the command line parses them, so the API takes ``"1e3"`` too.

Checks that need the image (a patch inside it, a response for its depth and channels)
are in :func:`check_image_size` and :func:`check_response_fits`; they need only the
files' headers.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any, Dict, Optional, Tuple

from hdrcl.errors import InputError, ParameterTypeError, UsageError

#: Tone-mapping operators (:mod:`hdrcl.report.tonemap`).
OPERATORS = ("reinhard", "reinhard-local", "drago", "filmic")
#: Largest ``--exposure`` (EV) of tone mapping: 2^64 is far beyond any useful change.
MAX_EXPOSURE_EV = 64.0
#: The response solve's smoothness range. Above 1e6 every curve is already a straight
#: line, and from about 1e8 the data rows are lost in rounding (a flat curve, g = 0);
#: below 1e-3 the normal equations become singular where samples are sparse.
SMOOTHNESS_RANGE = (1e-3, 1e6)
#: Exposure times of a virtual photograph, as for the frames' exposures (seconds).
TIME_RANGE = (1e-9, 1e7)
#: A reference patch's luminance (cd/m^2): the sun's disc is about 1.6e9.
MAX_LUMINANCE = 1e10
#: Patch coordinates and image sizes beyond this many pixels are typing errors.
MAX_PIXELS_SIDE = 1 << 20


@dataclass(frozen=True)
class Option:
    """One option: its kind and the range of its values.

    ``kind`` is ``int``, ``float``, ``choice``, ``bool``, or one of the parsed kinds
    (``seconds``, ``patch``, ``reference_patch``, ``ghost_reference``, ``rgb``,
    ``compression``, ``vector``, ``size``, ``text``). ``lo``/``hi`` bound numbers
    (``lo_open``: ``lo`` itself excluded); ``why`` ends the range message.
    """

    name: str
    kind: str
    lo: Optional[float] = None
    hi: Optional[float] = None
    lo_open: bool = False
    choices: Tuple[str, ...] = ()
    why: str = ""
    what: str = "a number"
    unit: str = ""
    range_text: str = ""

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")

    @property
    def numeric(self) -> bool:
        return self.kind in ("int", "float")


def choices(name: str) -> Tuple[str, ...]:
    """The values option ``name`` takes (a ``choice`` option; the weightings from
    :mod:`hdrcl.core.weights`)."""
    if name == "weight":
        from hdrcl.core.weights import WEIGHTS

        return tuple(WEIGHTS)
    return TABLE[name].choices


_O = Option
TABLE: Dict[str, Option] = {o.name: o for o in (
    _O("samples", "int", 1, 10_000_000, what="a number of pixels"),
    _O("smoothness", "float", *SMOOTHNESS_RANGE, why="above 1e6 the curve is a straight line already, and larger "
       "values lose the data in rounding"),
    _O("seed", "int", 0, 2 ** 32 - 1, what="a seed"),
    _O("exposure_tolerance", "float", 0, 30, lo_open=True, what="a number of stops"),
    _O("ghost_threshold", "float", 0, 1000, lo_open=True, what="a number of spreads"),
    _O("ghost_reference", "ghost_reference"),
    _O("reference_exposure", "seconds", *TIME_RANGE),
    _O("time", "seconds", *TIME_RANGE),
    _O("exposure", "float", -MAX_EXPOSURE_EV, MAX_EXPOSURE_EV, what="a number of stops", unit=" stops",
       range_text=f"at most {MAX_EXPOSURE_EV:g} either way"),
    _O("neutral", "patch"),
    _O("reference_patch", "reference_patch"),
    _O("ignore_color", "rgb"),
    _O("motion_blur", "vector"),
    _O("compression", "compression"),
    _O("weight", "choice"),
    _O("fit_exposures", "choice", choices=("auto", "on", "off")),
    _O("dtype", "choice", choices=("auto", "half", "float")),
    _O("colorspace", "choice", choices=("rec709", "acescg")),
    _O("align_model", "choice", choices=("auto", "shift", "similarity", "homography")),
    _O("operator", "choice", choices=OPERATORS),
    _O("channel_order", "choice", choices=("rgb", "bgr")),
    _O("bits", "int", 8, 16, what="8 or 16"),
    _O("jobs", "int", 1, 4096, what="a number of processes"),
    _O("retries", "int", 0, 1000, what="a number of retries"),
    _O("preview_size", "int", 16, 65536, what="a number of pixels"),
    # HDR-screen deliverables (hdrcl.core.options.DeliverOptions): PQ ends at 10000 cd/m^2, 5.6
    # stops above its 203 cd/m^2 reference white.
    _O("headroom", "float", 0, 5.6, lo_open=True, what="a number of stops"),
    _O("hdr_transfer", "choice", choices=("pq", "hlg")),
    _O("hdr_bits", "choice", choices=("10", "12")),
    _O("frames_per_set", "int", 1, 100_000, what="a number of frames"),
    _O("frames", "int", 2, 32, what="a number of frames"),
    _O("gap", "float", 0, 1e9, what="a number of seconds"),
    _O("max_pixels", "int", 1, 10 ** 12, what="a number of pixels"),
    _O("size", "size"),
    _O("align", "bool"), _O("crop", "bool"), _O("deghost", "bool"), _O("absolute", "bool"),
    _O("device", "text"), _O("owner", "text"),
)}


def _show(value: Any) -> str:
    """A value as a message shows it: one line, at most 40 characters."""
    if isinstance(value, float):
        text = _num(value)
    elif isinstance(value, str):
        text = value
    else:
        text = repr(value)
    text = "".join(ch if ch.isprintable() else "?" for ch in text)
    return text if len(text) <= 40 else text[:37] + "..."


def _num(x: float) -> str:
    """A bound as people write it: 16, 0.001, 1e6."""
    if isinstance(x, int):
        return str(x)
    return f"{x:.6g}".replace("e+0", "e").replace("e+", "e").replace("e-0", "e-")


def _number(opt: Option, value: Any, integer: bool):
    """``value`` (a number, or a string as typed) as int/float; kind errors raised."""
    if isinstance(value, bool) or value is None:
        raise ParameterTypeError(f"{opt.flag}: expected {opt.what}, not {value!r}")
    if isinstance(value, str):
        text = value.strip()
        try:
            v = int(text, 10) if integer else float(text)
        except ValueError:
            kind = "an integer" if integer else "a number"
            raise UsageError(f"{opt.flag}: '{_show(value)}' is not {kind}") from None
        return v
    try:
        import numbers

        if integer:
            if not isinstance(value, numbers.Integral):
                raise TypeError
            return int(value)
        if not isinstance(value, numbers.Real):
            raise TypeError
        return float(value)
    except (TypeError, ValueError, OverflowError):
        kind = "an integer" if integer else "a number"
        raise ParameterTypeError(f"{opt.flag}: expected {kind}, not {type(value).__name__} "
                                 f"({_show(value)})") from None


def _range(opt: Option, v, text: Optional[str] = None):
    text = _show(v) if text is None else text
    if isinstance(v, float) and not math.isfinite(v):
        noun = opt.what[2:] if opt.what.startswith("a number") else "number"
        raise UsageError(f"{opt.flag}: {text} is not a finite {noun}")
    lo_bad = opt.lo is not None and (v <= opt.lo if opt.lo_open else v < opt.lo)
    hi_bad = opt.hi is not None and v > opt.hi
    if lo_bad or hi_bad:
        if opt.name == "bits":
            raise UsageError(f"{opt.flag}: {text} is not 8 or 16")
        word = opt.name.replace("_", " ")
        if opt.hi is None:
            span = f"{word} {'>' if opt.lo_open else '>='} {_num(opt.lo)}"
        else:
            span = f"{_num(opt.lo)} {'<' if opt.lo_open else '<='} {word} <= {_num(opt.hi)}"
        span = opt.range_text or span
        why = f"; {opt.why}" if opt.why and hi_bad else ""
        raise UsageError(f"{opt.flag}: {text}{opt.unit} is out of range ({span}){why}")
    return v


def _ints(opt: Option, value, n: int, text: str):
    """``n`` integers from ``"a,b,..."`` or a sequence of integers."""
    if isinstance(value, str):
        parts = [p.strip() for p in value.split(",")]
        try:
            vals = tuple(int(p, 10) for p in parts)
        except ValueError:
            vals = ()
    elif isinstance(value, (list, tuple)) or type(value).__name__ == "ndarray":
        import numbers

        if not all(isinstance(v, numbers.Integral) and not isinstance(v, bool) for v in value):
            raise ParameterTypeError(f"{opt.flag}: expected {n} integers, not {_show(value)}")
        vals = tuple(int(v) for v in value)
    else:
        raise ParameterTypeError(f"{opt.flag}: expected {text} (a string or a tuple), not {type(value).__name__}")
    return vals if len(vals) == n else None


def _patch(opt: Option, value, label: str = "x,y,w,h in pixels (w, h > 0)"):
    vals = _ints(opt, value, 4, "x,y,w,h")
    if vals is None or vals[0] < 0 or vals[1] < 0 or vals[2] < 1 or vals[3] < 1:
        raise UsageError(f"{opt.flag}: expected {label}, not '{_show(value)}'")
    if max(vals[0] + vals[2], vals[1] + vals[3]) > MAX_PIXELS_SIDE:
        raise UsageError(f"{opt.flag}: patch {_show(value)} runs outside any image")
    return vals


def check(name: str, value: Any, *, frames: Optional[int] = None):
    """``value`` of option ``name`` checked and normalised (None passes: the default).

    ``frames`` (the number of images, when known) bounds ``ghost_reference``.
    Returns the value in the form the engine takes (numbers as int/float, patches as
    their original text or tuple, choices lower-cased where the CLI is case-blind).
    """
    opt = TABLE[name]
    if value is None:
        return None
    kind = opt.kind
    if opt.numeric:
        v = _number(opt, value, kind == "int")
        v = _range(opt, v, _show(value.strip()) if isinstance(value, str) else None)
        if name == "bits" and v not in (8, 16):
            raise UsageError(f"{opt.flag}: {_show(value)} is not 8 or 16")
        return v
    if kind == "choice":
        allowed = choices(name)
        if not isinstance(value, str):
            raise ParameterTypeError(f"{opt.flag}: expected one of {', '.join(allowed)}, not {type(value).__name__}")
        v = value.strip().lower() if name in ("colorspace", "channel_order", "align_model") else value
        if v not in allowed:
            raise UsageError(f"{opt.flag}: '{_show(value)}' is not one of {', '.join(allowed)}")
        return v
    if kind == "bool":
        if type(value).__name__ not in ("bool", "bool_"):
            raise ParameterTypeError(f"{opt.flag}: expected True or False, not {_show(value)}")
        return bool(value)
    if kind == "text":
        if not isinstance(value, str):
            raise ParameterTypeError(f"{opt.flag}: expected a string, not {type(value).__name__}")
        return value
    return _CHECKS[kind](opt, value, frames)


def _seconds(opt: Option, value, frames):
    if isinstance(value, bool) or not isinstance(value, (str, int, float)) and type(value).__module__ != "numpy":
        raise ParameterTypeError(f"{opt.flag}: expected a time in seconds (a number or '1/30'), "
                                 f"not {type(value).__name__}")
    from hdrcl.io.exposure_lists import parse_times

    try:
        if isinstance(value, str):
            ts = parse_times(value, opt.flag)
            t = ts[0] if len(ts) == 1 else None
        else:
            t = float(value)
    except (TypeError, ValueError, OverflowError, UsageError):
        t = None
    if t is None or not math.isfinite(t) or t <= 0:
        raise UsageError(f"{opt.flag}: '{_show(value)}' is not a positive exposure time")
    if not opt.lo <= t <= opt.hi:
        raise UsageError(f"{opt.flag}: '{_show(value)}' is not an exposure time between {opt.lo:g} and {opt.hi:g} s")
    return float(t)


def _ghost_reference(opt: Option, value, frames):
    if isinstance(value, str) and value.strip() in ("middle", "shortest", "longest"):
        return value.strip()
    if isinstance(value, bool) or not isinstance(value, (str, int)) and type(value).__module__ != "numpy":
        raise ParameterTypeError(f"{opt.flag}: expected middle, shortest, longest or a frame number, "
                                 f"not {type(value).__name__}")
    try:
        k = int(value.strip(), 10) if isinstance(value, str) else int(value)
    except (TypeError, ValueError):
        raise UsageError(f"{opt.flag}: '{_show(value)}' is not middle, shortest, longest or a frame number") from None
    if k < 0 or (frames is not None and k >= frames):
        span = f" (0..{frames - 1})" if frames else ""
        raise UsageError(f"{opt.flag}: frame {k} does not exist{span}")
    return k


def _reference_patch(opt: Option, value, frames):
    if isinstance(value, str):
        box, sep, val = value.partition("=")
        try:
            v = float(val)
        except ValueError:
            v = float("nan")
        if not sep or not (v > 0 and math.isfinite(v)):
            raise UsageError(f"{opt.flag}: expected x,y,w,h=VALUE (cd/m^2 > 0), not '{_show(value)}'")
        _patch(opt, box, "x,y,w,h=VALUE in pixels (w, h > 0)")
    elif isinstance(value, (tuple, list)) and len(value) == 2:
        _patch(opt, value[0])
        v = _number(opt, value[1], False)
        if not (v > 0 and math.isfinite(v)):
            raise UsageError(f"{opt.flag}: the luminance must be a positive number of cd/m^2, not {_show(v)}")
    else:
        raise ParameterTypeError(f"{opt.flag}: expected 'x,y,w,h=VALUE' or ((x, y, w, h), VALUE), "
                                 f"not {_show(value)}")
    if v > MAX_LUMINANCE:
        raise UsageError(f"{opt.flag}: {v:g} cd/m^2 is out of range (at most {MAX_LUMINANCE:g}, brighter than the sun)")
    return value


def _rgb(opt: Option, value, frames):
    vals = _ints(opt, value, 3, "R,G,B")
    if vals is None or not all(0 <= v <= 255 for v in vals):
        raise UsageError(f"{opt.flag}: expected R,G,B with values 0-255, not '{_show(value)}'")
    return vals


def _vector(opt: Option, value, frames):
    if isinstance(value, str):
        try:
            vals = tuple(float(v) for v in value.split(","))
        except ValueError:
            vals = ()
    elif isinstance(value, (tuple, list)):
        vals = tuple(_number(opt, v, False) for v in value)
    else:
        raise ParameterTypeError(f"{opt.flag}: expected DX,DY (a string or a pair), not {type(value).__name__}")
    if len(vals) != 2 or not all(math.isfinite(v) for v in vals):
        raise UsageError(f"{opt.flag}: expected DX,DY in pixels, not '{_show(value)}'")
    return vals


def _compression(opt: Option, value, frames):
    from hdrcl.io.writers import EXR_COMPRESSIONS

    if not isinstance(value, str):
        raise ParameterTypeError(f"{opt.flag}: expected a compression name, not {type(value).__name__}")
    base, _, level = value.strip().lower().partition(":")
    if base not in EXR_COMPRESSIONS or (level and not level.replace(".", "", 1).isdigit()):
        raise UsageError(f"{opt.flag}: '{_show(value)}' is not one of {', '.join(EXR_COMPRESSIONS)}")
    return value


def _size(opt: Option, value, frames):
    if not isinstance(value, str):
        raise ParameterTypeError(f"{opt.flag}: expected WxH, not {type(value).__name__}")
    try:
        w, h = (int(v, 10) for v in value.lower().split("x"))
    except ValueError:
        raise UsageError(f"{opt.flag}: expected WxH, not '{_show(value)}'") from None
    if not (16 <= w <= 16384 and 16 <= h <= 16384):
        raise UsageError(f"{opt.flag}: {_show(value)} is out of range (16 to 16384 pixels a side)")
    return value


_CHECKS = {"seconds": _seconds, "ghost_reference": _ghost_reference, "patch": lambda o, v, f: (_patch(o, v), v)[1],
           "reference_patch": _reference_patch, "rgb": _rgb, "vector": _vector, "compression": _compression,
           "size": _size}


def check_options(frames: Optional[int] = None, **values) -> Dict[str, Any]:
    """:func:`check` every ``name=value`` given (None passes); the normalised values.

    Combinations are checked too: ``crop`` needs ``align``; ``ghost_threshold`` and
    ``ghost_reference`` need ``deghost``; ``absolute`` and ``reference_patch`` exclude
    each other.
    """
    out = {k: check(k, v, frames=frames) for k, v in values.items() if k in TABLE}
    unknown = [k for k in values if k not in TABLE]
    if unknown:
        raise ValueError(f"no such option in the table: {', '.join(unknown)}")
    if out.get("crop") and "align" in values and not out.get("align"):
        raise UsageError("--crop needs --align")
    if "deghost" in values and not out.get("deghost") and (
            out.get("ghost_threshold") is not None or out.get("ghost_reference") is not None):
        raise UsageError("--ghost-threshold and --ghost-reference need --deghost")
    if out.get("absolute") and out.get("reference_patch") is not None:
        raise UsageError("--absolute and --reference-patch both set the scale; give one")
    return out


def check_image_size(width: int, height: int, *, neutral=None, reference_patch=None) -> None:
    """UsageError when a patch runs outside a ``width`` x ``height`` image (from the
    frames' headers, before decoding)."""
    for flag, value in (("--neutral", neutral), ("--reference-patch", reference_patch)):
        if value is None:
            continue
        if flag == "--neutral":
            x, y, w, h = _patch(TABLE["neutral"], value)
        else:
            box = value.partition("=")[0] if isinstance(value, str) else value[0]
            x, y, w, h = _patch(TABLE["reference_patch"], box)
        if x + w > width or y + h > height:
            raise UsageError(f"{flag}: patch {x},{y},{w},{h} runs outside the {width}x{height} image")


def check_response_fits(resp, source: str, image: str, bits: Optional[int], nch: int) -> None:
    """InputError naming the response file and an image when ``resp`` is for other
    frames: another bit depth (``bits``, None for a radiance map) or channel count."""
    if bits is not None and resp.bits != bits:
        raise InputError(f"{source}: a response for {resp.bits}-bit frames, but {image} is {bits}-bit")
    if resp.nchannels not in (1, nch):
        raise InputError(f"{source}: a response with {resp.nchannels} channel(s), but {image} has {nch}")


def radiance_header(path) -> Tuple[int, int, int]:
    """``(width, height, channels)`` of a radiance file, from its header (no pixels):
    :func:`hdrcl.io.radiance.radiance_header`."""
    from hdrcl.io.radiance import radiance_header as header

    return header(path)


def check_expose(radiance_path, response, *, motion_blur=None, source: Optional[str] = None):
    """Before ``expose`` decodes anything: the response fits the radiance map's
    channels, and a motion blur is no longer than the image (both from the header)."""
    from hdrcl.errors import check_regular

    name = os.fsdecode(os.fspath(radiance_path))
    check_regular(name, "radiance map")
    w, h, nch = radiance_header(name)
    if response is not None:
        check_response_fits(response, source or "response", name, None, nch)
    if motion_blur is not None:
        dx, dy = check("motion_blur", motion_blur)
        text = f"{dx:g},{dy:g}"
        if max(abs(dx), abs(dy)) > max(w, h):
            raise UsageError(f"--motion-blur: {text} is longer than the image ({w}x{h})")
    return w, h, nch


def check_images(images, name: str = "images", *, arrays: bool = True) -> list:
    """The frames of a bracket as a list of ``str`` paths or checked arrays.

    Refuses, naming ``name``: one path given as a string (it would be read letter by
    letter), anything that is not a path or an array (a nested list), empty arrays,
    arrays that are not (H, W[, C]) uint8/uint16, arrays of mixed bit depth, and a mix
    of paths and arrays. ``bytes`` paths are decoded as the file system does.
    """
    if isinstance(images, (str, bytes, os.PathLike)):
        raise ParameterTypeError(f"{name}: expected a list of images, not one path ({_show(os.fsdecode(images))}); "
                                 "a bracket needs at least two")
    if type(images).__name__ == "ndarray":
        raise ParameterTypeError(f"{name}: expected a list of arrays (one per frame), not one array; "
                                 "use list(stack) for a stack of frames")
    try:
        items = list(images)
    except TypeError:
        raise ParameterTypeError(f"{name}: expected a list of paths or arrays, not {type(images).__name__}") from None
    out = []
    for k, im in enumerate(items):
        if isinstance(im, (str, bytes, os.PathLike)):
            p = os.fsdecode(os.fspath(im))
            if not p:
                raise UsageError(f"{name}: image {k} is an empty path")
            out.append(p)
        elif type(im).__name__ == "ndarray" and arrays:
            out.append(_check_array(im, k, name))
        else:
            what = "a path or a NumPy array (uint8 or uint16)" if arrays else "a path"
            raise ParameterTypeError(f"{name}: image {k} is {_article(type(im).__name__)}, not {what}")
    kinds = {isinstance(x, str) for x in out}
    if len(kinds) > 1:
        raise UsageError(f"{name}: give either file paths or arrays, not a mix")
    if out and not isinstance(out[0], str):
        first = out[0]
        for k, a in enumerate(out[1:], 1):
            if a.dtype != first.dtype:
                raise UsageError(f"{name}: image {k} is {a.dtype} but image 0 is {first.dtype}; "
                                 "give frames of one bit depth")
    return out


def _article(word: str) -> str:
    return ("an " if word[:1].lower() in "aeiou" else "a ") + word


def _check_array(a, k: int, name: str):
    if a.dtype.name not in ("uint8", "uint16") or a.ndim not in (2, 3) or (a.ndim == 3 and not 1 <= a.shape[2] <= 4):
        raise UsageError(f"{name}: image {k}: expected (H, W[, C]) uint8 or uint16 with C <= 4, "
                         f"got {a.dtype} {a.shape}")
    if a.size == 0:
        raise UsageError(f"{name}: image {k} is empty (shape {a.shape})")
    return a


def to_rgb(arrays, channel_order: Optional[str]):
    """Arrays in ``channel_order`` (``"bgr"``: OpenCV's) as RGB(A); the inverse too (it
    is its own inverse). Grey and two-channel arrays are unchanged."""
    if check("channel_order", channel_order) != "bgr":
        return arrays
    out = []
    for a in arrays:
        if a.ndim == 3 and a.shape[2] >= 3:
            import numpy as np

            a = np.ascontiguousarray(np.concatenate([a[..., 2::-1], a[..., 3:]], axis=2))
        out.append(a)
    return out
