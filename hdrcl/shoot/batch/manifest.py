"""Manifests: bracket sets and unmerged frames as JSON a user can edit and feed back
(:func:`load_manifest`, :func:`save_manifest`).
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from typing import List, Optional
from hdrcl.errors import InputError


# --------------------------------------------------------------------------- records
@dataclass
class BracketSet:
    """One group of frames to merge into one radiance map.

    Attributes
    ----------
    index : int
        Position of the set in the manifest (0-based; kept as written in a hand-edited
        manifest).
    files : list of str
        Frame paths in capture order.
    exposures : list of float
        Exposure time of each frame in seconds. Empty in a hand-edited manifest that
        leaves them out: the frames' EXIF is then used.
    reason : str
        Why the set ended: ``"gap 12.3 s"``, ``"exposure repeats first frame"``,
        ``"camera changed"``, ``"end of files"``, ``"frames-per-set 3"``...
    start : str, optional
        Capture time of the first frame (ISO 8601, local time).
    camera, serial, lens : str, optional
        Camera body ("Make Model"), its serial number and the lens.
    focal_length : float, optional
        Millimetres.
    fnumber : float, optional
        Aperture, common to all frames of a mergeable set.
    iso : list
        ISO of each frame (``None`` where unknown).
    ev : list
        Exposure bias of each frame in EV (``None`` where unknown).
    gaps : list
        End-to-start gap in seconds before each frame after the first (``None`` where a
        capture time is missing).
    joins : list
        Why each frame after the first joined the set (``"gap 1.2 s, same scene (match
        0.98, +0.1 EV)"``, ``"gap 42.0 s bridged: exposure ladder, 1 EV steps, ascending,
        same scene ..."``); empty in a hand-edited manifest.
    width, height : int, optional
        Image size in pixels.
    extra : dict
        Unknown keys of a hand-edited manifest, written back unchanged.
    """

    index: int
    files: List[str]
    exposures: List[float]
    reason: str
    start: Optional[str] = None
    camera: Optional[str] = None
    serial: Optional[str] = None
    lens: Optional[str] = None
    focal_length: Optional[float] = None
    fnumber: Optional[float] = None
    iso: list = field(default_factory=list)
    ev: list = field(default_factory=list)
    gaps: list = field(default_factory=list)
    joins: list = field(default_factory=list)
    width: Optional[int] = None
    height: Optional[int] = None
    extra: dict = field(default_factory=dict)

    def to_dict(self, relative_to: Optional[str] = None) -> dict:
        """JSON-ready dictionary; file paths made relative to ``relative_to`` if given."""
        d = {
            "index": self.index,
            "files": [_rel(f, relative_to) for f in self.files],
            "exposures": list(self.exposures),
            "reason": self.reason,
        }
        for name in _SET_OPTIONAL:
            d[name] = getattr(self, name)
        for k, v in self.extra.items():
            d.setdefault(k, v)
        return d


#: Key of :attr:`BracketSet.extra` holding what the scan found about the set: a list of
#: :meth:`hdrcl.core.findings.Finding.to_dict` (a frame left out of it, a duplicate...;
#: :mod:`hdrcl.shoot.grouping.strays`). The batch carries them to the set's result.
FINDINGS = "findings"


def add_finding(s: BracketSet, finding: dict) -> None:
    """Add ``finding`` (a Finding's dict) to the set's :data:`FINDINGS`, once."""
    have = s.extra.setdefault(FINDINGS, [])
    if not any(isinstance(f, dict) and f.get("message") == finding.get("message") for f in have):
        have.append(dict(finding))


def set_findings(s: BracketSet) -> List[dict]:
    """The set's :data:`FINDINGS` that are findings (a hand-edited manifest may hold
    anything there): dicts with a ``message`` string."""
    got = s.extra.get(FINDINGS) if isinstance(s.extra, dict) else None
    if not isinstance(got, list):
        return []
    return [dict(f) for f in got if isinstance(f, dict) and isinstance(f.get("message"), str) and f["message"]]


_SET_OPTIONAL = ("start", "camera", "serial", "lens", "focal_length", "fnumber", "joins",
                 "iso", "ev", "gaps", "width", "height")


@dataclass
class Unmerged:
    """Frames that will not be merged, and why.

    Attributes
    ----------
    files : list of str
        The frames.
    reason : str
        Starts with the kind: ``"single frame"``, ``"all frames share one exposure"``,
        ``"aperture bracketing"``, ``"mixed cameras"``, ``"no exposure time"``,
        ``"corrupt: <message>"``; details follow in parentheses.
    ended : str, optional
        Why the group ended (as :attr:`BracketSet.reason`), from a scan.
    joins : list
        Why each frame after the first joined the group, from a scan.
    """

    files: List[str]
    reason: str
    ended: Optional[str] = None
    joins: list = field(default_factory=list)

    def to_dict(self, relative_to: Optional[str] = None) -> dict:
        """JSON-ready dictionary; file paths made relative to ``relative_to`` if given."""
        d = {"files": [_rel(f, relative_to) for f in self.files], "reason": self.reason}
        if self.ended is not None:
            d["ended"] = self.ended
        if self.joins:
            d["joins"] = list(self.joins)
        return d


@dataclass
class Manifest:
    """The grouping of a folder: bracket sets to merge and frames left out.

    Attributes
    ----------
    sets : list of BracketSet
    unmerged : list of Unmerged
    root : str, optional
        The folder that was scanned.
    """

    sets: List[BracketSet] = field(default_factory=list)
    unmerged: List[Unmerged] = field(default_factory=list)
    root: Optional[str] = None

    def to_dict(self, relative_to: Optional[str] = None) -> dict:
        """JSON-ready dictionary.

        Parameters
        ----------
        relative_to : str, optional
            Write file paths (and ``root``) relative to this folder, so the manifest can
            move together with the photographs. Paths are written as stored otherwise.

        Returns
        -------
        dict
            ``{"root": ..., "sets": [...], "unmerged": [...]}``.
        """
        return {
            "root": None if self.root is None else _rel(self.root, relative_to),
            "sets": [s.to_dict(relative_to) for s in self.sets],
            "unmerged": [u.to_dict(relative_to) for u in self.unmerged],
        }

    def to_json(self, indent: Optional[int] = 2, relative_to: Optional[str] = None) -> str:
        """The manifest as one JSON object (see :meth:`to_dict`)."""
        return json.dumps(self.to_dict(relative_to), indent=indent)

    @classmethod
    def from_dict(cls, d, *, base: Optional[str] = None, source: str = "manifest"
                  ) -> "Manifest":
        """Build and validate a manifest from its dictionary form.

        Only ``sets[i].files`` is required; ``index`` values are kept, and sets without
        one are numbered after the largest given index in the order they appear.
        Unknown keys of a set are kept in :attr:`BracketSet.extra`.

        Parameters
        ----------
        d : dict
            As written by :meth:`to_dict`, possibly edited by hand.
        base : str, optional
            Folder against which relative file paths (and ``root``) are resolved.
        source : str
            Name used at the start of error messages (the manifest's file name).

        Returns
        -------
        Manifest

        Raises
        ------
        InputError
            ``"<source>: sets[2] has no 'files'"`` and similar: the first problem found.
        """
        def fail(msg):
            raise InputError(f"{source}: {msg}")

        if not isinstance(d, dict):
            fail(f"expected a JSON object with 'sets', got {type(d).__name__}")
        if "sets" not in d:
            fail("no 'sets' list")
        raw_sets = d["sets"]
        if not isinstance(raw_sets, list):
            fail("'sets' is not a list")
        raw_unmerged = d.get("unmerged", [])
        if raw_unmerged is None:
            raw_unmerged = []
        if not isinstance(raw_unmerged, list):
            fail("'unmerged' is not a list")
        root = d.get("root")
        if root is not None and not isinstance(root, str):
            fail("'root' is not a string")

        sets, seen_files, given = [], {}, []
        for i, s in enumerate(raw_sets):
            where = f"sets[{i}]"
            if not isinstance(s, dict):
                fail(f"{where} is not an object")
            files = _check_files(s, where, fail)
            files = [_resolve(f, base) for f in files]
            for f in files:
                if f in seen_files:
                    fail(f"{where}: {f} is also in {seen_files[f]}")
                seen_files[f] = where
            exposures = s.get("exposures")
            if exposures is None:
                exposures = []
            if not isinstance(exposures, list):
                fail(f"{where}.exposures is not a list")
            if exposures and len(exposures) != len(files):
                fail(f"{where}.exposures has {len(exposures)} values for {len(files)} files")
            for j, t in enumerate(exposures):
                if not _is_number(t) or not t > 0 or not math.isfinite(t):
                    fail(f"{where}.exposures[{j}] is not a positive number of seconds: {t!r}")
            index = s.get("index")
            if index is not None and (not isinstance(index, int) or isinstance(index, bool)
                                      or index < 0):
                fail(f"{where}.index is not a non-negative integer: {index!r}")
            reason = s.get("reason", "manifest")
            if not isinstance(reason, str):
                fail(f"{where}.reason is not a string")
            kwargs = {}
            for name in _SET_OPTIONAL:
                if s.get(name) is not None:
                    kwargs[name] = s[name]
            for name in ("iso", "ev", "gaps", "joins"):
                if name in kwargs and not isinstance(kwargs[name], list):
                    fail(f"{where}.{name} is not a list")
            extra = {k: v for k, v in s.items()
                     if k not in _SET_OPTIONAL and k not in ("index", "files", "exposures",
                                                             "reason")}
            sets.append(BracketSet(index=index, files=files,
                                   exposures=[float(t) for t in exposures],
                                   reason=reason, extra=extra, **kwargs))
            if index is not None:
                given.append((index, i))

        indices = {}
        for index, i in given:
            if index in indices:
                fail(f"sets[{i}].index {index} is also the index of sets[{indices[index]}]")
            indices[index] = i
        # Number only the sets that have no index, after the largest one given.
        nxt = max(indices, default=-1) + 1
        for s in sets:
            if s.index is None:
                s.index = nxt
                nxt += 1

        unmerged = []
        for i, u in enumerate(raw_unmerged):
            where = f"unmerged[{i}]"
            if not isinstance(u, dict):
                fail(f"{where} is not an object")
            files = [_resolve(f, base) for f in _check_files(u, where, fail)]
            reason = u.get("reason", "")
            if not isinstance(reason, str):
                fail(f"{where}.reason is not a string")
            ended, joins = u.get("ended"), u.get("joins") or []
            if ended is not None and not isinstance(ended, str):
                fail(f"{where}.ended is not a string")
            if not isinstance(joins, list):
                fail(f"{where}.joins is not a list")
            unmerged.append(Unmerged(files=files, reason=reason, ended=ended, joins=list(joins)))
        return cls(sets=sets, unmerged=unmerged,
                   root=None if root is None else _resolve(root, base))


def _check_files(s: dict, where: str, fail) -> list:
    if "files" not in s:
        fail(f"{where} has no 'files'")
    files = s["files"]
    if not isinstance(files, list):
        fail(f"{where}.files is not a list")
    if not files:
        fail(f"{where}.files is empty")
    for j, f in enumerate(files):
        if not isinstance(f, str) or not f.strip():
            fail(f"{where}.files[{j}] is not a file name: {f!r}")
    return files


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _resolve(p: str, base: Optional[str]) -> str:
    p = os.path.expanduser(p)
    if base is not None and not os.path.isabs(p):
        p = os.path.normpath(os.path.join(base, p))
    return p


def _rel(p: str, relative_to: Optional[str]) -> str:
    if relative_to is None:
        return p
    try:
        return os.path.relpath(os.path.abspath(p), os.path.abspath(relative_to))
    except ValueError:  # another drive on Windows: keep it absolute
        return os.path.abspath(p)


# --------------------------------------------------------------------- manifest files
def load_manifest(path, *, check_files: bool = True) -> Manifest:
    """Read a (possibly hand-edited) manifest and validate it.

    Parameters
    ----------
    path : str or os.PathLike
        JSON file as written by :func:`save_manifest` or ``hdrcl scan -o``.
    check_files : bool
        Also check that every file of every set exists.

    Returns
    -------
    Manifest
        Relative file paths resolved against the manifest's folder.

    Raises
    ------
    InputError
        The file cannot be read, is not JSON, or does not describe sets; the message
        names the file and the problem, e.g. ``"manifest.json: sets[2] has no 'files'"``.
    """
    from hdrcl.io.jsondoc import MANIFEST_SCHEMA, read_json, validate

    name = os.fspath(path)
    d = read_json(name, "manifest file")  # binary files, BOM, nesting bombs: one line
    base = os.path.dirname(os.path.abspath(name))
    manifest = Manifest.from_dict(d, base=base, source=name)
    validate(d, MANIFEST_SCHEMA, name)  # the types from_dict does not look at, by field path
    if check_files:
        for s in manifest.sets:
            for f in s.files:
                if not os.path.isfile(f):
                    raise InputError(f"{name}: set {s.index}: no such file {f}")
    return manifest


def save_manifest(manifest: Manifest, path) -> None:
    """Write a manifest as JSON, atomically.

    File paths are written relative to the manifest's folder so that the folder can be
    moved as a whole. The JSON goes to a temporary file in the same folder that then
    replaces ``path``, so a reader never sees half a manifest.

    Parameters
    ----------
    manifest : Manifest
    path : str or os.PathLike
    """
    from hdrcl.io.atomic import write_text

    name = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(name))
    write_text(name, manifest.to_json(indent=2, relative_to=folder) + "\n")  # umask, not 0600
