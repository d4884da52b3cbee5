"""``hdrcl scan``: listing a folder's images, reading their headers and grouping them
into a manifest; the table shown to the user.
"""
from __future__ import annotations

import logging
import os
from typing import List, Optional, Sequence, Tuple
from hdrcl.errors import InputError
from hdrcl.shoot.batch.manifest import Manifest, Unmerged, _rel, set_findings
from hdrcl.shoot.grouping.damaged import DAMAGED, mark_damaged, place_damaged
from hdrcl.shoot.grouping.rules import _exposure_range, _fmt_bias, group_frames
from hdrcl.shoot.grouping.strays import place_duplicates, split_duplicates

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


def _with_exposure_lists(infos, times_file):
    """Frames named in ``times_file`` take their exposure from it (it wins over EXIF);
    frames without EXIF exposure time take theirs from a list beside them
    (:func:`hdrcl.io.metadata.header_exposures`), their f-number too.

    Returns the frames and, by list file, the frames each list beside them named (in
    the list's order): a folder whose list names its frames is one set.

    Raises
    ------
    InputError
        A list beside the frames cannot be read or has a bad line (the message names
        the list and the line).
    """
    from dataclasses import replace

    from hdrcl.io.metadata import header_exposures
    from hdrcl.io.exposure_lists import read_times_file

    given = read_times_file(times_file, [i.path for i in infos]) if times_file is not None else {}
    listed = {}  # frames without EXIF exposure time, by folder: one read of its list
    for info in infos:
        if os.path.basename(info.path) not in given and info.exposure_time is None:
            listed.setdefault(os.path.dirname(os.path.abspath(info.path)), []).append(info)
    from_lists, source = {}, {}
    for folder, group in listed.items():
        exposures, used = header_exposures([i.path for i in group], group)
        for u in used:
            logger.info("%s: exposures of the frames it lists", u)
        for i, e in zip(group, exposures):
            if e is not None:
                from_lists[i.path] = e
                source[i.path] = used[0]
    out, named = [], {}
    for info in infos:
        e = given.get(os.path.basename(info.path)) or from_lists.get(info.path)
        if e is not None:
            info = replace(info, exposure_time=float(e.factor), fnumber=info.fnumber or e.fnumber)
        if info.path in source and os.path.basename(info.path) not in given:
            named.setdefault(source[info.path], []).append(info)
        out.append(info)
    return out, {lst: _in_list_order(lst, frames) for lst, frames in named.items()}


def _in_list_order(lst: str, frames):
    from hdrcl.io.exposure_lists import read_times_file

    order = {name: k for k, name in enumerate(read_times_file(lst))}
    return sorted(frames, key=lambda f: order.get(os.path.basename(f.path), len(order)))


def photos_below(root: str, extensions: Sequence[str] = DEFAULT_EXTENSIONS,
                 exclude: Sequence[str] = ()) -> Tuple[int, List[str]]:
    """Photographs in the subfolders of ``root`` (not ``root`` itself, nor the ``exclude``
    folders: a batch's output inside the shoot), and those subfolders (relative to
    ``root``) that hold some: what a scan without ``recursive`` leaves out."""
    skip = tuple(os.path.abspath(e) + os.sep for e in exclude if e)
    top = os.path.abspath(root)  # "shoot/" and "shoot" alike
    below = [p for p in _list_files(root, True, extensions)
             if os.path.dirname(os.path.abspath(p)) != top and not os.path.abspath(p).startswith(skip)]
    folders = sorted({os.path.relpath(os.path.dirname(p), root) for p in below})
    return len(below), folders


def descends(root, recursive: bool = False, extensions: Sequence[str] = DEFAULT_EXTENSIONS,
             exclude: Sequence[str] = ()) -> Optional[str]:
    """Whether a scan of ``root`` goes into its subfolders without being asked, and the
    line that says so (None: it does not).

    A folder that holds no photographs itself while its subfolders do (a shoot copied
    as one folder per set, a card's DCIM) is scanned recursively, as ``-r`` does.
    """
    root = os.fspath(root)
    if recursive or not os.path.isdir(root) or _list_files(root, False, extensions):
        return None
    n, folders = photos_below(root, extensions, exclude)
    if not n:
        return None
    shown = ", ".join(folders[:3]) + (", ..." if len(folders) > 3 else "")
    return (f"{root}: no photographs at its top; scanning its {len(folders)} subfolder(s) "
            f"({shown}; {n} photographs), as -r does")


def left_below(root, recursive: bool = False, extensions: Sequence[str] = DEFAULT_EXTENSIONS,
               exclude: Sequence[str] = ()) -> Optional[str]:
    """The line telling to add ``-r`` when a scan of ``root`` leaves photographs in
    subfolders out (None: it leaves none out)."""
    root = os.fspath(root)
    if recursive or not os.path.isdir(root) or not _list_files(root, False, extensions):
        return None
    n, folders = photos_below(root, extensions, exclude)
    if not n:
        return None
    shown = ", ".join(folders[:3]) + (", ..." if len(folders) > 3 else "")
    return f"{root}: {n} photographs in subfolders ({shown}) are left out; add -r to include them"


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
        Hidden files and folders (names starting with ".") are skipped. A folder with
        no photographs at its top but some in its subfolders is scanned recursively
        without it (:func:`descends`).
    frames_per_set, gap
        Overrides, see :func:`group_frames`.
    extensions : sequence of str
        File name endings to read, compared case-insensitively.
    content : bool
        Also compare the frames' content (small exposure-normalised thumbnails,
        :mod:`hdrcl.shoot.grouping.scene`); False groups by the headers alone.
    times_file : path, optional
        Exposure list (wins over EXIF for the frames it names).

    Exposure lists: a frame named in ``times_file``, or one without EXIF exposure time
    named in an ``image_list.txt`` (HDRShop columns) or ``times.txt`` (``file seconds``)
    in its own folder, takes its exposure (time, with gain and ND folded in) from the
    list; its f-number too when its header has none. The frames such a list beside them
    names are exactly one set, in the list's order (a folder per set).

    Frames from different folders join one set only in one camera's stream (make,
    model, serial and capture times; a converted PNG's or TIFF's ``DateTime`` is no
    capture time: :func:`hdrcl.io.exif.capture_time`).

    Returns
    -------
    Manifest
        With ``root`` set to ``path``; unreadable files are in ``unmerged`` with a
        reason starting ``"corrupt: "``, after the groups of readable frames.

    Raises
    ------
    InputError
        ``path`` is not a folder; an exposure list beside the frames cannot be read or
        has a bad line (a negative time: the message names the list, the line and the
        value).
    UsageError
        Invalid overrides.
    """
    from hdrcl.io.frames import read_info  # lazy: keeps OpenImageIO out of ``import hdrcl``

    root = os.fspath(path)
    if not os.path.isdir(root):
        raise InputError(f"{root}: no such folder" if not os.path.exists(root)
                         else f"{root}: not a folder")
    note = descends(root, recursive, extensions)
    if note:
        logger.info("%s", note)
        recursive = True
    files = _list_files(root, recursive, extensions)
    infos, bad, salvaged = [], [], []
    for p in files:
        try:
            infos.append(read_info(p))
        except (InputError, OSError) as e:
            msg = _cause(str(e), p)
            info = _salvage(p)
            if info is not None:  # its EXIF still places it in its set, which then fails
                salvaged.append((info, msg))
                continue
            logger.info("not grouped: %s: %s", p, msg)
            bad.append(Unmerged(files=[p], reason=f"corrupt: {msg}"))
    infos, named = _with_exposure_lists(infos, times_file)
    compare, damaged = None, {}
    if content and frames_per_set is None:
        from hdrcl.shoot.grouping.scene import SceneCache

        cache = SceneCache()
        compare = cache.compare
        cache.read_all(infos)  # read once each anyway (on every core); a frame whose pixels fail is known first
        damaged = {p: _cause(m, p) for p, m in cache.damaged.items()}
    listed = {id(f) for fs in named.values() for f in fs}
    aside = [(i, damaged[os.fspath(i.path)]) for i in infos
             if os.fspath(i.path) in damaged and id(i) not in listed]
    gone = {id(a) for a, _ in aside}
    kept = [i for i in infos if id(i) not in gone]
    dups = []
    if frames_per_set is None:  # a copy on the card is left out, its set notes it
        kept, dups = split_duplicates(kept, cache.thumb if compare is not None else None)
        gone = {id(c) for c, _o, _h in dups}
        named = {lst: [f for f in fs if id(f) not in gone] for lst, fs in named.items()}
    manifest = group_frames(kept, frames_per_set=frames_per_set, gap=gap, compare=compare, listed=named)
    place_duplicates(manifest, dups)
    mark_damaged(manifest, damaged)  # frames an exposure list put in their set
    place_damaged(manifest, kept, aside + salvaged)
    manifest.unmerged.extend(bad)
    manifest.root = root
    return manifest


def _cause(msg: str, path: str) -> str:
    """The message without the path it starts with (the file is named where it is shown)."""
    msg = msg.splitlines()[0] if msg else "unreadable"
    return msg[len(path) + 2:] if msg.startswith(path + ": ") else msg


def _salvage(path: str):
    from hdrcl.io.salvage import salvage_info

    return salvage_info(path)


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
    hurt = [(s, f, c) for s in manifest.sets for f, c in s.extra.get(DAMAGED, {}).items()]
    if hurt:
        lines.append("")
        lines.append(f"damaged ({len(hurt)}):")
        for s, f, c in hurt:
            lines.append(f"  {f}: {c}; set {s.index} fails until the file is replaced or taken out of it")
    said = [(s, f) for s in manifest.sets for f in set_findings(s)]  # hdrcl.shoot.grouping.strays
    if said:
        lines.append("")
        lines.append(f"found ({len(said)}):")
        for s, f in said:
            lines.append(f"  set {s.index} ({f.get('severity', 'check')}): {f['message']}")
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
