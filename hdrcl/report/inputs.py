"""What went into a merge, for the report: thumbnails of the input frames, the camera
settings, and the frames a batch left unmerged (with their thumbnails and reason).
"""
from __future__ import annotations

import logging
import os
import re
from typing import List, Optional, Sequence

import numpy as np

logger = logging.getLogger(__name__)

#: Long side of a frame thumbnail in pixels.
THUMB_SIZE = 160


def file_stem(name: str) -> str:
    """A file-name-safe stem for a set name (letters, digits, ``._-``; no leading dot)."""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", str(name)).lstrip(".")
    return stem or "set"


def thumbnail(frame: np.ndarray, size: int = THUMB_SIZE) -> np.ndarray:
    """An 8-bit thumbnail (area average) of an 8- or 16-bit frame, as it was shot."""
    from hdrcl.report.preview import downscale

    a = np.asarray(frame)
    scale = 1.0 if a.dtype == np.uint8 else 1.0 / 257.0
    small = downscale(a.astype(np.float64) * scale, size)
    return np.clip(np.round(small), 0, 255).astype(np.uint8)


def _fmt_number(v: float) -> str:
    return f"{v:.1f}".rstrip("0").rstrip(".")


def _one_or_range(values, fmt) -> Optional[str]:
    vals = sorted({round(float(v), 6) for v in values if v})
    if not vals:
        return None
    return fmt(vals[0]) if len(vals) == 1 else f"{fmt(vals[0])}–{fmt(vals[-1])}"


def camera_summary(infos: Sequence) -> dict:
    """Camera, lens, focal length, ISO, f-number and capture time of a set's frames
    (ranges where the frames differ); only the fields some frame has."""
    infos = [i for i in infos if i is not None]
    out = {}
    if not infos:
        return out
    first = next((i for i in infos if i.make or i.model), None)
    if first is not None:
        make, model = (first.make or "").strip(), (first.model or "").strip()
        out["camera"] = model if make and model.lower().startswith(make.lower()) else " ".join(
            v for v in (make, model) if v)
    lens = next((i.lens for i in infos if i.lens), None)
    if lens:
        out["lens"] = lens
    focal = _one_or_range([i.focal_length for i in infos], lambda v: f"{_fmt_number(v)} mm")
    if focal:
        out["focal_length"] = focal
    iso = _one_or_range([i.iso for i in infos], lambda v: f"ISO {v:g}")
    if iso:
        out["iso"] = iso
    fnum = _one_or_range([i.fnumber for i in infos], lambda v: f"f/{_fmt_number(v)}")
    if fnum:
        out["fnumber"] = fnum
    times = [i.capture_time for i in infos if i.capture_time is not None]
    if times:
        out["captured"] = min(times).strftime("%Y-%m-%d %H:%M:%S")
    return out


#: Relative tolerance within which the camera's recorded settings must explain the
#: exposures a merge used before the report labels the frames with them.
SETTINGS_RTOL = 0.01


def shot_settings(infos: Sequence, times=None) -> Optional[List[dict]]:
    """Each frame's exposure as its camera recorded it: ``{"shutter", "fnumber",
    "iso"}`` (seconds; f-number and ISO None where unknown), or None when a frame has no
    shutter time or the headers do not explain ``times``.

    ``times``, when given, are the exposures a merge was given for the frames (relative;
    from ``--times`` or a times file they override EXIF): the recorded settings count
    only when their effective exposures (:func:`hdrcl.io.metadata.relative_exposures`)
    are proportional to ``times`` within :data:`SETTINGS_RTOL`.
    """
    from hdrcl.io.metadata import relative_exposures
    from hdrcl.io.exposure_lists import Exposure

    infos = list(infos or [])
    if not infos or any(i is None or not i.exposure_time or not np.isfinite(i.exposure_time)
                        or i.exposure_time <= 0 for i in infos):
        return None
    if times is not None:
        t = np.asarray(times, np.float64)
        if t.size != len(infos):
            return None
        rel = relative_exposures([Exposure(time=float(i.exposure_time), fnumber=i.fnumber, iso=i.iso)
                                  for i in infos])
        ratio = rel / t
        if not np.all(np.isfinite(ratio)) or not np.all(ratio > 0) or np.ptp(np.log(ratio)) > SETTINGS_RTOL:
            return None
    return [{"shutter": float(i.exposure_time), "fnumber": i.fnumber, "iso": i.iso} for i in infos]


def setting_parts(shutter: Optional[float], fnumber: Optional[float] = None,
                  iso: Optional[float] = None) -> List[str]:
    """``["1/8 s", "f/8", "ISO 100"]``: a frame's settings in words, the unknown ones left
    out (shutter time as :func:`hdrcl.io.metadata.format_time`)."""
    from hdrcl.io.metadata import format_time

    parts = [] if shutter is None else [format_time(float(shutter))]
    if fnumber:
        parts.append(f"f/{_fmt_number(float(fnumber))}")
    if iso:
        parts.append(f"ISO {float(iso):g}")
    return parts


def write_inputs(folder: str, stem: str, bracket, size: int = THUMB_SIZE) -> List[dict]:
    """Thumbnails of ``bracket``'s frames (``<stem>-frame-NN.jpg``) and one row per
    frame, shortest exposure first: ``file``, ``time`` (nominal, relative seconds: in a
    batch rescaled to the shoot's reference aperture and ISO), ``fnumber``, ``iso``,
    ``shutter`` (the time ``bracket.infos`` records, None when a frame has none),
    ``label`` (the frame's exposure in its own camera's terms, e.g. ``"1/8 s f/8 ISO
    100"``, from the infos when every frame has a shutter time, else the nominal time)
    and ``thumb``. The caller leaves out of the infos the times the merge did not use
    (:func:`shot_settings` with the times given)."""
    from hdrcl.io.metadata import format_time
    from hdrcl.io.ldr import write_ldr

    rows = []
    infos = list(getattr(bracket, "infos", None) or [])
    paths = list(getattr(bracket, "paths", None) or [])
    shots = shot_settings(infos)
    order = np.argsort(np.asarray(bracket.times, np.float64), kind="stable")
    for n, k in enumerate(order):
        name = f"{stem}-frame-{n:02d}.jpg"
        write_ldr(os.path.join(folder, name), thumbnail(bracket.frames[k], size))
        info = infos[k] if k < len(infos) else None
        shot = shots[k] if shots else {}
        label = " ".join(setting_parts(**shot)) if shot else format_time(float(bracket.times[k]))
        rows.append({"file": os.path.basename(paths[k]) if k < len(paths) else f"frame {k}",
                     "time": float(bracket.times[k]),
                     "fnumber": getattr(info, "fnumber", None), "iso": getattr(info, "iso", None),
                     "shutter": shot.get("shutter"), "label": label, "thumb": name})
    return rows


def write_unmerged(folder: str, unmerged: Sequence[dict], size: int = THUMB_SIZE) -> List[dict]:
    """The frames a batch did not merge, for the contact sheet.

    ``unmerged``: ``{"files": [...], "reason": ...}`` per group (as ``BatchReport``).
    Each readable file gets a thumbnail ``unmerged-<name>.jpg`` (kept across runs);
    returns per group ``{"reason", "files": [{"file", "thumb" or None, "problem"}]}``.
    """
    from hdrcl.io.frames import read_image
    from hdrcl.io.ldr import write_ldr
    groups = []
    for u in unmerged or []:
        files = []
        for path in u.get("files") or []:
            base = os.path.basename(str(path))
            thumb = f"unmerged-{file_stem(base.replace('.', '_'))}.jpg"
            target = os.path.join(folder, thumb)
            problem = None
            if not os.path.isfile(target):
                try:
                    write_ldr(target, thumbnail(read_image(path).pixels, size))
                except Exception as exc:  # an unreadable frame is exactly what is reported here
                    problem = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                    thumb = None
            files.append({"file": base, "thumb": thumb, "problem": problem})
        groups.append({"reason": str(u.get("reason") or "not merged"), "files": files})
    return groups
