"""``hdrcl scan``: listing a folder's images, reading their headers and grouping them
into a manifest; the table shown to the user.
"""
from __future__ import annotations

import logging
import os
from typing import List, Optional, Sequence

from hdrcl.errors import InputError
from hdrcl.shoot.grouping import _exposure_range, _fmt_bias, group_frames
from hdrcl.shoot.manifest import Manifest, Unmerged, _rel

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
    return found


def scan_directory(path, *, recursive: bool = False, frames_per_set: Optional[int] = None,
                   gap: Optional[float] = None,
                   extensions: Sequence[str] = DEFAULT_EXTENSIONS) -> Manifest:
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
    from hdrcl.io.frames import (
        read_info,  # lazy: keeps OpenImageIO out of ``import hdrcl``
    )

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
    manifest = group_frames(infos, frames_per_set=frames_per_set, gap=gap)
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
