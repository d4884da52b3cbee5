"""Standard metadata of radiance files: EXR attributes, Radiance header lines.

Besides hdrcl's own ``hdrcl:*`` attributes, a radiance file carries what other tools
read by standard names:

=====================  ==========================  =========================================
``camera`` key         EXR attribute (OIIO name)   meaning
=====================  ==========================  =========================================
(always)               ``Software``                ``hdrcl <version>``
``owner``              ``owner`` (``Copyright``)   the frames' copyright, or ``--owner``
(``timestamp``)        ``capDate`` (``DateTime``)  capture time of the first frame
``make``, ``model``    ``cameraMake``, ...Model    camera (OpenEXR 3.2 standard names)
``lens``               ``lensModel``
``focal_length``       ``nominalFocalLength``      mm
``fnumber``, ``iso``   ``aperture``, ``isoSpeed``  the capture's f-number and ISO (where all
                                                   frames share one); a value of 1 in the
``exposure_time``      ``expTime``                 map is what a frame of ``expTime`` at
                                                   them records as 1 (:mod:`hdrcl.core.encode`)
``reference_fnumber``  ``hdrcl:referenceFNumber``  the settings the exposures are relative
``reference_iso``      ``hdrcl:referenceISO``      to (a batch's shoot-wide ones), with
                                                   ``hdrcl:referenceExposure``
``units`` = ``cd/m2``  ``whiteLuminance`` = 1      a calibrated luminance map
                                                   (:mod:`hdrcl.core.luminance.fisheye`): 1.0 is 1
                                                   cd/m^2; ``.hdr``: no ``EXPOSURE=`` line
``view``               (``.hdr``: ``VIEW=``)       Radiance view, e.g. ``-vta -vh 180 -vv 180``
``vertical_illuminance``  (``.hdr``:               lux at the lens (EXR: ``hdrcl:*``
                       ``VERTICAL_ILLUMINANCE=``)  metadata of the chain)
``orientation``        ``Orientation`` (int)       the frames' EXIF Orientation (2..8; left
                       (``.hdr``: the resolution   out for 1); the pixels stay as stored
                       line, ``-X H -Y W`` for 6)  (:func:`orientation_carrier`)
=====================  ==========================  =========================================

The reference f-number and ISO are the first frame's (the merge expresses every frame's
exposure at its settings, :func:`hdrcl.io.metadata.relative_exposures`), or a batch's
shoot-wide ones; the standard attributes always describe the capture itself. All are left
out when the map has absolute units. Radiance (``.hdr``) files get the standard header lines
``SOFTWARE=``, ``EXPOSURE=`` (the reference exposure: Radiance tools divide the stored
values by it to get radiance relative to 1 s), ``PRIMARIES=`` and
``CAPDATE=``, which OpenImageIO's RGBE writer does not write, so they are inserted into
the header after writing. TIFF keeps ``Software``, ``Make``, ``Model``, ``Copyright``
and ``DateTime`` as TIFF tags.
"""
from __future__ import annotations

import os
import shutil
from typing import Mapping, Optional, Sequence

from hdrcl.io.colorspace import chromaticities
from hdrcl.io.colorspace import check as check_space
from hdrcl.io.exif import common_orientation, hdr_resolution, orientation_value
from hdrcl.errors import ProcessingError

__all__ = ["software", "standard_attributes", "hdr_header_lines", "patch_hdr_header", "hdr_colorspace", "hdr_header",
           "inapplicable_options", "camera_from_infos", "orientation_carrier", "read_orientation"]

#: Longest Radiance header we read back (bytes).
_HDR_HEADER_MAX = 1 << 16


def software() -> str:
    from hdrcl.version import __version__

    return f"hdrcl {__version__}"


def _clean(text) -> str:
    """One line of text (header values cannot hold newlines)."""
    return " ".join(str(text).split())


def standard_attributes(ext: str, camera: Optional[Mapping]) -> list:
    """``(name, value)`` OIIO attributes for a radiance file of extension ``ext``."""
    cam = dict(camera or {})
    out = [("Software", software())]
    if cam.get("owner"):
        out.append(("Copyright", _clean(cam["owner"])))
    if ext in (".exr", ".tif", ".tiff") and int(cam.get("orientation") or 1) != 1:
        out.append(("Orientation", int(cam["orientation"])))  # TIFF tag 274; an EXR int attribute
    if ext in (".tif", ".tiff"):
        out += [(name, _clean(cam[key])) for key, name in (("make", "Make"), ("model", "Model")) if cam.get(key)]
        return out
    if ext != ".exr":
        return out
    for key, name in (("make", "cameraMake"), ("model", "cameraModel"), ("lens", "lensModel")):
        if cam.get(key):
            out.append((name, _clean(cam[key])))
    if cam.get("units") == "cd/m2":  # a calibrated luminance map: 1.0 is 1 cd/m^2
        out.append(("whiteLuminance", 1.0))
    for key, name in (("focal_length", "nominalFocalLength"), ("fnumber", "FNumber"), ("iso", "isoSpeed"),
                      ("exposure_time", "ExposureTime"), ("reference_fnumber", "hdrcl:referenceFNumber"),
                      ("reference_iso", "hdrcl:referenceISO")):
        value = cam.get(key)
        if value is not None and float(value) > 0:
            out.append((name, float(value)))
    return out


#: The Radiance header line that carries hdrcl's own metadata (compact JSON; Radiance
#: tools pass unknown header lines through): ``hdrcl batch`` finds its input hash there.
HDR_METADATA_LINE = "HDRCL="


def hdr_header_lines(camera: Optional[Mapping], colorspace: str, timestamp: Optional[str],
                     metadata: Optional[Mapping] = None) -> list:
    """The Radiance header lines hdrcl adds after ``FORMAT=`` (without newlines);
    ``metadata`` (the ``hdrcl:*`` values) goes on one ``HDRCL=`` line as JSON."""
    prim = " ".join(f"{v:.4f}" for v in chromaticities(check_space(colorspace)))
    # Radiance's convention: stored value = original x EXPOSURE. hdrcl stores radiance
    # (relative to 1 s) times the reference exposure. A map in cd/m^2 (--absolute,
    # --reference-patch, the luminance chain) holds Radiance's radiance, cd/m^2 / 179
    # (:data:`WHITE_EFFICACY_KEY` on its HDRCL= line), with no EXPOSURE= line at all:
    # evalglare refuses a picture whose EXPOSURE= line a Radiance tool has indented.
    cam = camera or {}
    exposure = float(cam.get("reference_exposure") or cam.get("exposure_time") or 1.0)
    lines = [f"SOFTWARE={software()}"]
    absolute = str(cam.get("units", "")).startswith("cd/m2") or \
        str((metadata or {}).get("units", "")).startswith("cd/m2")
    if not absolute:  # EXPOSURE= only where it means what Radiance means (not 1 on a cd/m^2 map)
        lines.append(f"EXPOSURE={exposure:.6e}")
    lines.append(f"PRIMARIES= {prim}")
    if cam.get("view"):
        lines.append(f"VIEW= {_clean(cam['view'])}")
    if cam.get("vertical_illuminance") is not None:
        lines.append(f"VERTICAL_ILLUMINANCE= {float(cam['vertical_illuminance']):.6g}")
    if timestamp:
        lines.append(f"CAPDATE= {_clean(timestamp)}")
    owner = (camera or {}).get("owner")
    if owner:
        lines.append(f"# owner: {_clean(owner)}")
    # OpenImageIO's RGBE reader loses the header at a line of a multiple of 128 bytes.
    lines = [line + " " if len(line) % 128 == 0 else line for line in lines]
    if absolute:  # the values are Radiance's radiance: stored x 179 = cd/m^2 (hdrcl.core.encode)
        metadata = {**dict(metadata or {}), WHITE_EFFICACY_KEY: 179.0}
    if metadata:
        import json

        text = json.dumps(dict(metadata), separators=(",", ":"), sort_keys=True, default=str, ensure_ascii=True)
        # Lines of at most 96 characters of JSON (escaped: no line breaks), in order.
        lines += [f"{HDR_METADATA_LINE}{text[i:i + 96]}" for i in range(0, len(text), 96)]
    return lines


#: The HDRCL= key of a ``.hdr`` in cd/m^2 that stores Radiance's radiance (cd/m^2 / 179).
#: Older hdrcl wrote ``--absolute``/``--reference-patch`` maps in cd/m^2 directly (without
#: the key and without ``luminanceChain``); :func:`hdr_header` tells them apart.
WHITE_EFFICACY_KEY = "whiteEfficacy"


def _header_bytes(path) -> bytes:
    head = b""
    with open(path, "rb") as fh:
        while b"\n\n" not in head and len(head) < 1 << 20:
            chunk = fh.read(1 << 14)
            if not chunk:
                break
            head += chunk
    return head.split(b"\n\n", 1)[0]


def hdr_header(path) -> dict:
    """What a Radiance file's header says, as Radiance's programs read it:

    ``exposure``: the product of its ``EXPOSURE=`` lines at the start of a line (an
    indented one belongs to an input's header that a Radiance tool copied: Radiance
    ignores it), 1.0 when there is none; ``exposures``: the values; ``view``: the last
    ``VIEW=`` (or None); ``metadata``: hdrcl's ``HDRCL=`` JSON (:func:`hdr_metadata`)."""
    lines = _header_bytes(path).split(b"\n")
    exposures, view = [], None
    for raw in lines:
        if raw.startswith(b"EXPOSURE="):
            try:
                value = float(raw[len(b"EXPOSURE="):].split()[0])
            except (ValueError, IndexError):
                continue
            if value > 0 and value < float("inf"):
                exposures.append(value)
        elif raw.startswith(b"VIEW="):
            view = raw[len(b"VIEW="):].decode("ascii", "replace").strip()
    product = 1.0
    for v in exposures:
        product *= v
    return {"exposure": product, "exposures": exposures, "view": view, "metadata": _hdrcl_json(lines)}


def _hdrcl_json(lines) -> dict:
    """The ``HDRCL=`` lines joined; lines a Radiance tool indented (its input's header)
    count when there are none at the start of a line: the least indented set is read."""
    import json

    key = HDR_METADATA_LINE.encode()
    found = {}
    for raw in lines:
        body = raw.lstrip(b"\t ")
        if body.startswith(key):
            found.setdefault(len(raw) - len(body), []).append(body[len(key):])
    if not found:
        return {}
    parts = found[min(found)]
    try:
        value = json.loads(b"".join(parts).decode("ascii"))
    except (ValueError, UnicodeDecodeError):
        return {}
    return value if isinstance(value, dict) else {}


def hdr_metadata(path) -> dict:
    """The ``HDRCL=`` metadata of a Radiance file's header (its ``HDRCL=`` lines joined,
    before the first blank line; the header alone is read, at most 1 MB), or {}."""
    return _hdrcl_json(_header_bytes(path).split(b"\n"))


def patch_hdr_header(path: str, lines: Sequence[str]) -> None:
    """Insert ``lines`` into the header of the Radiance file ``path`` (in place, through
    a copy beside it), before the blank line that ends the header."""
    with open(path, "rb") as f:
        head = f.read(_HDR_HEADER_MAX)
    end = head.find(b"\n\n")
    if not head.startswith(b"#?") or end < 0:
        raise ProcessingError(f"{path}: not a Radiance header")
    extra = "".join(f"{line}\n" for line in lines).encode("utf-8")
    tmp = path + ".hdrhead"
    try:
        with open(path, "rb") as src, open(tmp, "wb") as dst:
            dst.write(head[:end + 1] + extra)
            src.seek(end + 1)
            shutil.copyfileobj(src, dst, 1 << 22)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def hdr_colorspace(path: str) -> Optional[str]:
    """``acescg`` or ``rec709`` from a Radiance file's ``PRIMARIES=`` line, or None."""
    try:
        with open(path, "rb") as f:
            head = f.read(_HDR_HEADER_MAX)
    except OSError:
        return None
    end = head.find(b"\n\n")
    for raw in head[:end if end >= 0 else len(head)].splitlines():
        if raw.startswith(b"PRIMARIES="):
            try:
                values = [float(v) for v in raw[len(b"PRIMARIES="):].split()]
            except ValueError:
                return None
            for name in ("acescg", "rec709"):
                ref = chromaticities(name)
                if len(values) == 8 and max(abs(a - b) for a, b in zip(values, ref)) < 2e-3:
                    return name
    return None


def inapplicable_options(path, dtype: Optional[str] = None, compression: Optional[str] = None) -> list:
    """Warnings for options given explicitly that the output type ignores (None: not given)."""
    target = os.fspath(path)
    ext = os.path.splitext(target)[1].lower()
    what = {".hdr": "Radiance RGBE (8-bit mantissas, shared exponent)", ".pfm": "32-bit float",
            ".tif": "32-bit float", ".tiff": "32-bit float"}.get(ext)
    out = []
    if dtype is not None and ext != ".exr" and what:
        out.append(f"{target}: --dtype {dtype} applies to EXR only; {ext} is written as {what}")
    if compression is not None and ext in (".hdr", ".pfm"):
        out.append(f"{target}: --compression {compression} applies to EXR and TIFF only; "
                   f"{ext} has {'run-length encoding' if ext == '.hdr' else 'no compression'}")
    return out


def camera_from_infos(infos: Sequence, *, owner: Optional[str] = None, units: str = "relative",
                      reference: Optional[tuple] = None, exposure_time: float = 1.0) -> dict:
    """The ``camera`` mapping of :func:`standard_attributes` from the frames' headers.

    Make, model, lens, focal length and owner come from the first frame that has them;
    the orientation is the one most frames carry (:func:`hdrcl.io.exif.common_orientation`);
    the reference exposure (``exposure_time`` seconds, see :mod:`hdrcl.core.encode`, at
    the first frame's f-number and ISO, or at ``reference = (f-number, ISO)`` where the
    caller set another, as ``hdrcl batch`` does for a shoot) only when the map is in
    relative units.
    """
    cam: dict = {}
    for key in ("make", "model", "lens", "focal_length"):
        cam[key] = next((getattr(i, key) for i in infos if getattr(i, key, None)), None)
    if owner is None:
        owner = next((i.extra.get("Copyright") for i in infos if (getattr(i, "extra", None) or {}).get("Copyright")),
                     None)
    cam["owner"] = owner
    o = common_orientation(getattr(i, "orientation", 1) for i in infos)
    cam["orientation"] = o if o != 1 else None
    if units == "relative" and infos:
        cam.update(_capture_exposure(infos, reference, float(exposure_time)))
    return {k: v for k, v in cam.items() if v not in (None, "")}


def _one_value(infos: Sequence, key: str) -> Optional[float]:
    """The frames' common value of ``key`` (f-number, ISO), None where they differ or
    any lacks it."""
    values = {round(float(v), 6) if v else None for v in (getattr(i, key, None) for i in infos)}
    return None if len(values) != 1 or None in values else values.pop()


def _capture_exposure(infos: Sequence, reference: Optional[tuple], t_ref: float) -> dict:
    """The standard exposure attributes describe the capture; the reference they stand
    for is hdrcl's own.

    A value of 1 is what a frame of ``t_ref`` seconds at the reference f-number and ISO
    records as white (``reference``: a batch's shoot-wide settings, else the first frame's).
    ``FNumber`` and ``isoSpeed`` are the frames' own where they all share one, and
    ``ExposureTime`` is the same reference at those settings (``t_ref (N/N_ref)^2
    ISO_ref/ISO``), so the three describe one photograph as the camera took it; the
    reference settings go to ``hdrcl:referenceFNumber`` / ``hdrcl:referenceISO`` (with
    ``hdrcl:referenceExposure``, which readers divide out)."""
    first = (getattr(infos[0], "fnumber", None), getattr(infos[0], "iso", None))
    n_ref, iso_ref = reference if reference is not None else first
    n_cap, iso_cap = _one_value(infos, "fnumber"), _one_value(infos, "iso")
    out = {"fnumber": n_cap, "iso": iso_cap, "reference_fnumber": n_ref, "reference_iso": iso_ref,
           "reference_exposure": t_ref}
    if n_cap is not None and iso_cap is not None and n_ref and iso_ref:
        out["exposure_time"] = t_ref * (n_cap / float(n_ref)) ** 2 * (float(iso_ref) / iso_cap)
    elif n_cap is None and iso_cap is None and not n_ref and not iso_ref:
        out["exposure_time"] = t_ref  # no settings recorded: the reference is the frames' own
    return out


def orientation_carrier(path, orientation: int) -> str:
    """What the output ``path`` says of EXIF ``orientation``, for a finding's message:
    EXR and TIFF carry an ``Orientation`` attribute, a Radiance file its resolution
    line, a PFM nothing."""
    name = os.path.basename(os.fspath(path))
    ext = os.path.splitext(name)[1].lower()
    o = orientation_value(orientation)
    if o == 1:
        return f"{name} keeps the stored layout"
    if ext == ".hdr":
        return f"{name}'s resolution line ({hdr_resolution(o, 'H', 'W')}) shows it turned in Radiance's programs"
    if ext == ".pfm":
        return f"{name} cannot say so and keeps the stored layout (write .exr, .hdr or .tif to keep the orientation)"
    return (f"{name} says Orientation {o} in its header (OpenImageIO tools and some viewers honour it; "
            "oiiotool --reorient turns the pixels)")


def orientation_after_reading(path) -> int:
    """The EXIF orientation still to apply to an output as :func:`hdrcl.io.radiance.read_radiance`
    returns it: 1 for a Radiance file (read as Radiance places it, upright already), else
    :func:`read_orientation` (other formats are read as stored)."""
    if os.path.splitext(os.fspath(path))[1].lower() == ".hdr":
        return 1
    return read_orientation(path)


def read_orientation(path) -> int:
    """The EXIF orientation an output says: a Radiance file's resolution line, or the
    ``Orientation`` attribute of another format (1 where it says none)."""
    name = os.fspath(path)
    if os.path.splitext(name)[1].lower() == ".hdr":
        with open(name, "rb") as fh:
            head = fh.read(_HDR_HEADER_MAX)
        end = head.find(b"\n\n")
        line = head[end + 2:].split(b"\n", 1)[0].decode("ascii", "replace").split() if end >= 0 else []
        if len(line) == 4:
            for o in range(1, 9):
                if hdr_resolution(o, line[1], line[3]).split() == line:
                    return o
        return 1
    from hdrcl.io.frames import open_input

    inp = open_input(name)
    try:
        return orientation_value(inp.spec().getattribute("Orientation"))
    finally:
        inp.close()
