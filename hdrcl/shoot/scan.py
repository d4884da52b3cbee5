"""``hdrcl scan``: listing a folder's images, reading their headers and grouping them
into a manifest; the table shown to the user.
"""
from __future__ import annotations

import logging
import os
from typing import List, Optional, Sequence
from hdrcl.errors import InputError
from hdrcl.shoot.manifest import Manifest, Unmerged, _rel
from hdrcl.shoot.grouping import _exposure_range, _fmt_bias, group_frames

logger = logging.getLogger(__name__)


#: File name endings :func:`scan_directory` looks at (compared case-insensitively).
DEFAULT_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff",
                      ".cr2", ".cr3", ".nef", ".arw", ".dng", ".raf", ".rw2", ".orf", ".pef", ".srw")


def _list_files(root: str, recursive: bool, extensions: Sequence[str]) -> List[str]:
    exts = tuple(e.lower() if e.startswith(".") else "." + e.lower() for e in extensions)

    def wanted(name):
        # Dot files include macOS "._IMG_0001.JPG" resource forks, which are not images.
        return not name.startswith(".") and name.lower().endswith(exts)

    found = []
    if recursive:
        for folder, dirs, names in os.walk(root):
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
            found.extend(os.path.join(folder, n) for n in sorted(names) if wanted(n))
    else:
        with os.scandir(root) as it:
            found = sorted(e.path for e in it if wanted(e.name) and e.is_file())
    # A FIFO or device named like a photograph would block the header read.
    found = [p for p in found if _regular(p)]
    return found


def _regular(p: str) -> bool:
    import stat

    try:
        return stat.S_ISREG(os.stat(p).st_mode)
    except OSError:
        return True  # let the reader report it


#: Exposure lists found beside the frames, in this order of preference.
EXPOSURE_LISTS = ("image_list.txt", "times.txt")


def _with_exposure_lists(infos, times_file):
    """Frames named in an exposure list take their exposure from it."""
    from dataclasses import replace

    from hdrcl.io.metadata import read_times_file

    given = read_times_file(times_file) if times_file is not None else None
    tables = {}
    out = []
    for info in infos:
        folder = os.path.dirname(os.path.abspath(info.path))
        if folder not in tables:
            tables[folder] = {}
            for name in EXPOSURE_LISTS:
                p = os.path.join(folder, name)
                if os.path.isfile(p):
                    try:
                        tables[folder] = read_times_file(p)
                        logger.info("%s: exposures of the frames it lists", p)
                    except InputError as exc:
                        logger.warning("exposure list not used: %s", exc)
                    break
        name = os.path.basename(info.path)
        e = (given or {}).get(name) or tables[folder].get(name)
        if e is not None:
            info = replace(info, exposure_time=float(e.factor),
                           fnumber=info.fnumber if info.fnumber else e.fnumber)
        out.append(info)
    return out


def scan_directory(path, *, recursive: bool = False, frames_per_set: Optional[int] = None,
                   gap: Optional[float] = None,
                   extensions: Sequence[str] = DEFAULT_EXTENSIONS, content: bool = True,
                   times_file=None) -> Manifest:
    """Read the headers of a folder's photographs and group them into bracket sets.

    Parameters
    ----------
    path : str or os.PathLike
        Folder to scan.
    recursive : bool
        Include subfolders (a set may span folders, e.g. at a file-number rollover).
        Hidden files and folders (names starting with ".") are skipped.
    frames_per_set, gap
        Overrides, see :func:`group_frames`.
    extensions : sequence of str
        File name endings to read, compared case-insensitively.
    content : bool
        Also compare the frames' content (small exposure-normalised thumbnails,
        :mod:`hdrcl.shoot.scene`); False groups by the headers alone.
    times_file : path, optional
        Exposure list for frames without EXIF (see :data:`EXPOSURE_LISTS`).

    Exposure lists: a frame named in ``times_file``, or in an ``image_list.txt``
    (HDRShop columns) or ``times.txt`` (``file seconds``) in its own folder, takes its
    exposure (time, with gain and ND folded in) from the list; its f-number too when its
    header has none.

    Returns
    -------
    Manifest
        With ``root`` set to ``path``; unreadable files are in ``unmerged`` with a
        reason starting ``"corrupt: "``, after the groups of readable frames.

    Raises
    ------
    InputError
        ``path`` is not a folder.
    UsageError
        Invalid overrides.
    """
    from hdrcl.io.frames import read_info  # lazy: keeps OpenImageIO out of ``import hdrcl``

    root = os.fspath(path)
    if not os.path.isdir(root):
        raise InputError(f"{root}: no such folder" if not os.path.exists(root)
                         else f"{root}: not a folder")
    files = _list_files(root, recursive, extensions)
    infos, bad = [], []
    for p in files:
        try:
            infos.append(read_info(p))
        except (InputError, OSError) as e:
            msg = str(e)
            if msg.startswith(p + ": "):
                msg = msg[len(p) + 2:]
            logger.info("not grouped: %s: %s", p, msg)
            bad.append(Unmerged(files=[p], reason=f"corrupt: {msg}"))
    infos = _with_exposure_lists(infos, times_file)
    compare = None
    if content and frames_per_set is None:
        from hdrcl.shoot.scene import SceneCache

        compare = SceneCache().compare
    manifest = group_frames(infos, frames_per_set=frames_per_set, gap=gap, compare=compare)
    manifest.unmerged.extend(bad)
    manifest.root = root
    return manifest


# ------------------------------------------------------------------------ display
def format_table(manifest: Manifest) -> str:
    """A human-readable table of the sets, then the frames that will not be merged.

    Parameters
    ----------
    manifest : Manifest

    Returns
    -------
    str
        One line per set (index, frames, first file, exposure range, EV, why it ended),
        then one line per unmerged group. File names are relative to ``root``.
    """
    def name(p):
        return _rel(p, manifest.root) if manifest.root else p

    rows = [("set", "frames", "first file", "exposures", "EV", "ended by")]
    for s in manifest.sets:
        ev = ",".join(_fmt_bias(b) for b in s.ev) if any(b is not None for b in s.ev) else "-"
        rows.append((str(s.index), str(len(s.files)), name(s.files[0]),
                     _exposure_range(s.exposures) if s.exposures else "(EXIF)", ev,
                     s.reason))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = []
    for r in rows:
        cells = [r[0].rjust(widths[0]), r[1].rjust(widths[1])]
        cells += [c.ljust(w) for c, w in zip(r[2:-1], widths[2:-1])] + [r[-1]]
        lines.append("  ".join(cells).rstrip())
    if manifest.unmerged:
        lines.append("")
        lines.append(f"not merged ({len(manifest.unmerged)}):")
        for u in manifest.unmerged:
            files = name(u.files[0]) if u.files else "?"
            if len(u.files) > 1:
                files += f" (+{len(u.files) - 1} more)"
            lines.append(f"  {files}: {u.reason}")
    lines.append("")
    lines.append(f"{len(manifest.sets)} set(s), "
                 f"{sum(len(s.files) for s in manifest.sets)} frame(s) to merge, "
                 f"{sum(len(u.files) for u in manifest.unmerged)} file(s) not merged")
    return "\n".join(lines)


def format_explain(manifest: Manifest) -> str:
    """Every decision of the grouping: per set and unmerged group, each frame with the
    reason it joined, and why the group ended (``hdrcl scan --explain``)."""
    def name(p):
        return _rel(p, manifest.root) if manifest.root else p

    groups = [(s.files[0], f"set {s.index}", s.files, s.joins, s.reason) for s in manifest.sets]
    groups += [(u.files[0], f"not merged: {u.reason}", u.files, u.joins, u.ended or "")
               for u in manifest.unmerged if u.files]
    lines = []
    for _first, title, files, joins, ended in groups:
        lines.append(f"{title} ({len(files)} frame(s)):")
        for k, f in enumerate(files):
            why = "first frame" if k == 0 else (joins[k - 1] if k - 1 < len(joins) else "joined")
            lines.append(f"  {name(f)}: {why}")
        if ended:
            lines.append(f"  ended: {ended}")
    return "\n".join(lines)
