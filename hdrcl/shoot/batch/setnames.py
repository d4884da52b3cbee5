"""The output names of a batch's sets: ``--name`` templates and their fields, the default
name (the set's folder, else its first frame), characters unsafe in file names replaced,
and names that would collide made unique from the whole manifest (:func:`output_stems`).
"""
from __future__ import annotations

import os
import re
from collections import Counter
from typing import Dict, Optional

from hdrcl.errors import UsageError
from hdrcl.shoot.batch.names import slug

#: Fields of ``--name`` templates (:func:`output_stems`).
NAME_FIELDS = ("folder", "first", "date", "index", "camera")

#: Characters no output name keeps (unsafe on some file system, or a path separator).
_UNSAFE = re.compile(r'[\x00-\x1f\x7f<>:"/\\|?*]')


def check_template(template: str) -> str:
    """Refuse a ``--name`` template with an unknown field, a format spec or a stray brace.

    Raises
    ------
    UsageError
        One line naming the problem and the fields there are.
    """
    import string

    known = ", ".join("{" + f + "}" for f in NAME_FIELDS)
    try:
        parts = list(string.Formatter().parse(str(template)))
    except ValueError as exc:
        raise UsageError(f"--name '{template}': {exc} (fields: {known})") from None
    fields = [(f, spec, conv) for _text, f, spec, conv in parts if f is not None]
    for f, spec, conv in fields:
        if f not in NAME_FIELDS:
            raise UsageError(f"--name '{template}': unknown field {{{f}}}; the fields are {known}")
        if spec or conv:
            raise UsageError(f"--name '{template}': {{{f}}} takes no format or conversion")
    if not fields and not _safe(template):
        raise UsageError(f"--name '{template}': names no field and is empty once sanitised")
    return str(template)


#: Longest output name in bytes (UTF-8): file systems take 255 bytes a name, and the
#: hidden temporary name (``.<name>.tmp-1a2b3c4d.exr``) and the report's files
#: (``<name>-coverage.png``) add up to about 40.
MAX_NAME_BYTES = 200


def _cut(name: str, limit: int = MAX_NAME_BYTES) -> str:
    """``name`` cut to at most ``limit`` bytes of UTF-8, on a character boundary."""
    return name.encode("utf-8")[:limit].decode("utf-8", "ignore")


def _safe(name: str) -> str:
    """``name`` without characters unsafe in file names (each becomes ``_``), leading or
    trailing dots and spaces, at most :data:`MAX_NAME_BYTES` bytes."""
    return _cut(_UNSAFE.sub("_", name).strip(" .")).strip(" .")


def set_folder(s) -> str:
    """The absolute folder of the set's first frame."""
    return os.path.dirname(os.path.abspath(s.files[0]))


def own_folders(manifest) -> bool:
    """Whether every set lies in a subfolder of its own (one folder per set, none the
    scanned folder itself): the outputs are then named after the folders."""
    root = os.path.abspath(manifest.root) if manifest.root else None
    folders = []
    for s in manifest.sets:
        where = {os.path.dirname(os.path.abspath(f)) for f in s.files}
        if len(where) != 1 or where == {root}:
            return False
        folders.append(where.pop())
    return bool(folders) and len(set(folders)) == len(folders)


def default_template(manifest) -> str:
    """``{folder}`` when each set has its own folder (:func:`own_folders`), else ``{first}``."""
    return "{folder}" if own_folders(manifest) else "{first}"


def name_fields(manifest) -> Dict[int, Dict[str, str]]:
    """The values of :data:`NAME_FIELDS` for every set, by index: ``folder`` (the first
    frame's folder name), ``first`` (the first frame's stem, capture order), ``date``
    (capture date YYYY-MM-DD, ``undated`` without one), ``index`` (1-based, zero-padded
    to the widest number), ``camera`` (make-model slug, ``unknown_camera``)."""
    sets = sorted(manifest.sets, key=lambda s: s.index)
    width = len(str(max([len(sets)] + [s.index + 1 for s in sets])))
    out = {}
    for s in sets:
        start = str(s.start or "")
        out[s.index] = {
            "folder": os.path.basename(set_folder(s)) or "root",
            "first": os.path.splitext(os.path.basename(s.files[0]))[0].lstrip(".") or f"set{s.index}",
            "date": start[:10] if re.match(r"\d{4}-\d\d-\d\d", start) else "undated",
            "index": str(s.index + 1).zfill(width),
            "camera": slug(s.camera) if s.camera else "unknown_camera",
        }
    return out


def _clashes(names: Dict[int, str]) -> set:
    seen = Counter(n.casefold() for n in names.values())
    return {i for i, n in names.items() if seen[n.casefold()] > 1}


def output_stems(manifest, template: Optional[str] = None) -> Dict[int, str]:
    """Output name (without extension) of every set of ``manifest``, by index.

    ``template`` (``--name``) uses the fields of :func:`name_fields`; characters unsafe
    in file names become ``_``. Two sets it names alike (compared case-insensitively,
    for macOS and Windows) are a usage error. Without a template, sets in folders of
    their own are named after the folder and others after their first frame
    (:func:`default_template`); names that would collide are made unique from the whole
    manifest, so the name never depends on which sets a run selects: first with the
    folders that tell the sets apart (``day1_IMG_0001``, ``day1_bracket``), then with
    the file's extension (``IMG_0001_tif``), and as a last resort with the set index.

    Raises
    ------
    UsageError
        ``template`` has an unknown field, or names two sets alike.
    """
    explicit = template is not None
    template = check_template(template) if explicit else default_template(manifest)
    sets = sorted(manifest.sets, key=lambda s: s.index)
    fields = name_fields(manifest)
    stems = {i: _safe(template.format(**f)) or f"set{i}" for i, f in fields.items()}
    if explicit:  # a name the file system cannot hold is the template's problem: said before any work
        for i, f in sorted(fields.items()):
            full = _UNSAFE.sub("_", template.format(**f)).strip(" .")
            size = len(full.encode("utf-8"))
            if size > MAX_NAME_BYTES:
                raise UsageError(f"--name '{_cut(template, 60)}': set {i}'s name is {size} bytes; at most "
                                 f"{MAX_NAME_BYTES} (a file name holds 255 bytes with hdrcl's temporary suffix)")
    bad = _clashes(stems)
    if bad and explicit:
        a, b = sorted(i for i in bad if stems[i].casefold() == stems[min(bad)].casefold())[:2]
        raise UsageError(f"--name '{template}': sets {a} and {b} would both be named '{stems[a]}'; "
                         "add {index} or {first} to tell them apart")
    first = {s.index: os.path.abspath(s.files[0]) for s in sets}
    if bad:
        common = os.path.commonpath([os.path.dirname(first[i]) for i in bad])
        for i in bad:
            rel = os.path.relpath(os.path.dirname(first[i]), common)
            parts = [p for p in rel.split(os.sep) if p not in (".", "")]
            if template == "{folder}":
                stems[i] = _safe("_".join(parts)) or stems[i]
            else:
                stems[i] = _safe("_".join(parts + [stems[i]]))
    for i in _clashes(stems):
        ext = os.path.splitext(first[i])[1].lstrip(".").lower()
        if ext:
            stems[i] = f"{stems[i]}_{ext}"
    for i in _clashes(stems):
        stems[i] = f"{stems[i]}-set{i}"
    return stems
