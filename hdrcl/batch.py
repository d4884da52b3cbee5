"""Merging a whole shoot: every bracket set of a manifest, once, safely, in parallel.

``hdrcl batch`` is a thin layer over :func:`run_batch`. What it guarantees, and how:

**One response per camera body and ISO.** Sets are grouped by the first frame's
camera (make, model, serial) and ISO. Each group's curve is solved once from samples
pooled across the group's sets (:func:`hdrcl.response.recover_response_pooled`) and
saved beside the outputs as ``<camera>-ISO<n>.response.json``; ``--response`` gives one
curve for everything instead. The pool is chosen from the *whole manifest*, never from
the sets selected for this run (at most :data:`MAX_POOL_SETS` sets, evenly spaced in
index order), and the solve is deterministic, so every farm chunk, Dask worker or
rerun arrives at the same curve. A saved curve whose recorded calibration key (the
pooled files' contents and the solve's parameters) still matches is loaded instead
of solved again; chunks running at the same moment each solve and write the same
file atomically. The curve used is always the one as written to JSON (rounded the same
way), so a loaded curve and a freshly solved one give identical outputs.

**One exposure scale for the shoot.** Every frame's effective exposure is taken
relative to one reference f-number and ISO for the whole manifest (the most common
first-frame setting; ties go to the lower set index), so the radiance of all sets is
in the same units and the sets of a panorama match. Each output records
``hdrcl:evOffset``: ``log2`` of the factor between its units and those of ``hdrcl
merge`` on the same frames (``merge`` = ``batch * 2**evOffset``), and
``hdrcl:exposureRef``, the reference (``"f/8 ISO 100"``).

**Idempotent and crash-safe.** Each set has an identity: SHA-256 over the contents of
its frames, the manifest's exposures, the shoot's reference, the response curve, the
merge and output parameters and the hdrcl version (:func:`set_digest`). It is stored
in the EXR as ``hdrcl:inputHash``. An output whose header carries the same digest is
skipped (header only, no pixels decoded); ``force`` rebuilds. Both files are written
atomically (temporary file, then rename) and the EXR is moved into place last, so it is
the commit marker: a run killed at any moment leaves every output either complete or
absent, and the next run finishes the job. The EXR's ``DateTime`` is the capture time
of the first frame, so the same inputs always give the same bytes.

**Failures stay local.** A set that cannot be read, decoded or merged fails alone with
its reason; the others complete.

**Pipelined, in bounded memory.** Each set is merged strip by strip
(:func:`hdrcl.pipeline.stream_merge`): decoding the next strip, fusing the current one
on the OpenCL device and encoding the previous one overlap, and memory does not grow
with the image. Meanwhile a read-ahead thread hashes the next set, checks its outputs
and reads its headers. One OpenCL context and built program serve the process.
``jobs > 1`` runs sets in worker processes (``spawn``: each worker makes its own OpenCL
context once); ``scheduler`` runs them on a Dask cluster (:mod:`hdrcl.executors`).

Outputs, named after each set's first frame (:func:`output_stems`), go directly into
the output folder: ``<stem>.exr``, ``<stem>.jpg`` (preview) and ``report.json``.

**Quality report** (``BatchOptions.report_dir``, ``--report DIR``). Whoever merges a set
(this process, a worker process, a Dask worker) measures it (:func:`hdrcl.quality.measure`
on the frames kept as they stream past: whole when they fit
:func:`hdrcl.api.memory_budget`, else the sampling grid; the radiance reduced for the
preview) and writes its files into the folder (:func:`hdrcl.report.write_set_report`),
after its EXR is committed; the figures also go into ``report.json`` under
``quality``. A skipped set keeps its report when it was written for the same digest,
else it is measured again from its frames and EXR. At the end, :func:`run_batch` writes
``index.html`` over every set of the manifest. The EXRs and previews are the same bytes
with or without a report.

This module does not import click, OpenImageIO or pyopencl directly.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import math
import os
import re
import secrets
import threading
import time as _time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import __version__
from .errors import HdrclError, InputError, UsageError
from .response import Response, default_smoothness

logger = logging.getLogger(__name__)

__all__ = [
    "BatchOptions",
    "SetJob",
    "SetResult",
    "BatchReport",
    "run_batch",
    "load_source",
    "check_manifest",
    "parse_sets",
    "select_sets",
    "output_stems",
    "set_digest",
    "process_set",
    "REPORT_NAME",
    "MAX_POOL_SETS",
]

#: Name of the report written into the output folder.
REPORT_NAME = "report.json"
#: Ending of the response files written beside the outputs.
RESPONSE_SUFFIX = ".response.json"
#: At most this many sets of one camera/ISO group are pooled for its response.
MAX_POOL_SETS = 8
#: Version of the recipe of :func:`set_digest`; bump when outputs change meaning.
DIGEST_RECIPE = 1
#: EXR attribute (after the ``hdrcl:`` prefix) holding a set's digest.
DIGEST_KEY = "inputHash"
#: Temporary files of killed runs older than this (seconds) are removed.
STALE_TEMP_SECONDS = 3600.0

STATUS_DONE, STATUS_SKIPPED, STATUS_FAILED = "done", "skipped", "failed"

# One fusion at a time per process: the OpenCL processor's device buffers are shared
# (Dask workers may run several tasks in threads of one process).
_FUSE_LOCK = threading.Lock()


# --------------------------------------------------------------------------- records


@dataclass(frozen=True)
class BatchOptions:
    """How every set is merged and written (the options ``hdrcl merge`` also has).

    Attributes
    ----------
    weight : str
        Weighting of code values (``hat`` or ``gaussian``).
    samples, smoothness, seed
        Of the pooled response solve (``smoothness`` None: the weighting's default).
    ignore_color : tuple of int, optional
        Pixels of exactly this 8-bit colour are invalid.
    deghost : bool
        Take pixels where the frames disagree (moving objects) from the middle
        exposure alone (:mod:`hdrcl.deghost`).
    dtype, compression
        EXR sample type and compression.
    preview : bool
        Also write a tone-mapped JPEG per set.
    preview_size : int
        Long side of the preview in pixels.
    device : str, optional
        OpenCL device (see ``hdrcl devices``).
    report_dir : str, optional
        Quality report folder (``--report``): each merged set's figures
        (:func:`hdrcl.quality.measure`), response plot, coverage map and preview, written
        by whoever merges the set, and an ``index.html`` contact sheet over the manifest,
        written by :func:`run_batch` at the end (:mod:`hdrcl.report`). Not part of any
        output's identity: the EXRs and previews are the same with or without it.
    """

    weight: str = "hat"
    samples: Optional[int] = None
    smoothness: Optional[float] = None  # None: the default for the weighting
    seed: int = 0
    ignore_color: Optional[Tuple[int, int, int]] = None
    deghost: bool = False
    dtype: str = "half"
    compression: str = "zip"
    preview: bool = True
    preview_size: int = 512
    device: Optional[str] = None
    report_dir: Optional[str] = None

    def output_params(self) -> dict:
        """Parameters that shape an EXR beyond its response (part of its digest)."""
        out = {"weight": self.weight, "ignore_color": list(self.ignore_color) if self.ignore_color else None,
               "dtype": self.dtype, "compression": str(self.compression).strip().lower()}
        if self.deghost:  # only when on, so that digests of plain merges stay as they were
            out["deghost"] = True
        return out

    def solve_params(self) -> dict:
        """Parameters of the response solve (part of the calibration key)."""
        return {"weight": self.weight, "samples": self.samples,
                "smoothness": float(default_smoothness(self.weight) if self.smoothness is None else self.smoothness),
                "seed": int(self.seed), "ignore_color": list(self.ignore_color) if self.ignore_color else None}


@dataclass
class SetJob:
    """Everything a worker needs to merge one set (plain data, picklable).

    ``reference`` is the shoot's ``(f-number, ISO)`` (either may be None); ``group``
    names the set's response; ``output`` and ``preview`` are absolute paths.
    """

    index: int
    files: List[str]
    exposures: List[float]
    output: str
    preview: Optional[str]
    group: str
    reference: Tuple[Optional[float], Optional[float]]


@dataclass
class SetResult:
    """What happened to one set.

    ``status`` is ``"done"`` (merged now), ``"skipped"`` (an up-to-date output exists)
    or ``"failed"`` (``error`` says why). ``seconds`` holds the time of each stage,
    ``counts`` the pixel-channels clipped high/low in every frame and without data,
    ``quality`` the set's quality figures (:meth:`hdrcl.quality.QualityFigures.to_dict`)
    when a quality report is written.
    """

    index: int
    files: List[str]
    status: str
    output: Optional[str] = None
    preview: Optional[str] = None
    error: Optional[str] = None
    warnings: List[str] = field(default_factory=list)
    seconds: Dict[str, float] = field(default_factory=dict)
    counts: Dict[str, int] = field(default_factory=dict)
    ev_offset: Optional[float] = None
    digest: Optional[str] = None
    response: Optional[str] = None
    quality: Optional[dict] = None

    def to_dict(self) -> dict:
        return {
            "index": self.index,
            "files": list(self.files),
            "status": self.status,
            "output": self.output,
            "preview": self.preview,
            "error": self.error,
            "warnings": list(self.warnings),
            "seconds": {k: round(float(v), 4) for k, v in self.seconds.items()},
            "counts": dict(self.counts),
            "ev_offset": self.ev_offset,
            "hash": self.digest,
            "response": self.response,
            "quality": self.quality,
        }


@dataclass
class ResponseEntry:
    """The response of one camera/ISO group and where it came from."""

    group: str
    payload: Optional[dict] = None  # Response.to_dict() as written (None: unavailable)
    digest: Optional[str] = None
    file: Optional[str] = None
    source: str = ""  # "given", "loaded", "calibrated"
    sets: List[int] = field(default_factory=list)
    error: Optional[str] = None
    warnings: List[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"group": self.group, "file": self.file, "source": self.source, "pooled_sets": self.sets,
                "hash": self.digest, "error": self.error, "warnings": self.warnings}


@dataclass
class _Context:
    """Shared, picklable state of one run: options, responses, flags."""

    options: BatchOptions
    responses: Dict[str, ResponseEntry]
    force: bool = False


@dataclass
class BatchReport:
    """The outcome of :func:`run_batch`.

    Attributes
    ----------
    results : list of SetResult
        The sets this run handled, by index.
    entries : list of dict
        Every set in the written report (this run's, plus those earlier runs into the
        same folder recorded for sets of the same manifest).
    unmerged : list of dict
        Groups the manifest leaves out, with their reasons.
    responses : list of ResponseEntry
    path : str, optional
        Where the report was written.
    quality_report : str, optional
        The contact sheet (``index.html``) of the quality report, when one was asked for.
    unreadable : list of str
        Files the scan could not read; counted as failures when the whole manifest was
        selected.
    """

    results: List[SetResult] = field(default_factory=list)
    entries: List[dict] = field(default_factory=list)
    unmerged: List[dict] = field(default_factory=list)
    responses: List[ResponseEntry] = field(default_factory=list)
    path: Optional[str] = None
    quality_report: Optional[str] = None
    unreadable: List[str] = field(default_factory=list)
    reference: Tuple[Optional[float], Optional[float]] = (None, None)
    seconds: float = 0.0

    def count(self, status: str) -> int:
        return sum(1 for r in self.results if r.status == status)

    @property
    def failed(self) -> int:
        return self.count(STATUS_FAILED)

    @property
    def exit_code(self) -> int:
        """0 when every set is done or skipped, 1 when a set (or an input file) failed."""
        return 1 if self.failed or self.unreadable else 0

    def to_dict(self) -> dict:
        counts = Counter(e["status"] for e in self.entries)
        return {
            "hdrcl": __version__,
            "reference": _reference_text(self.reference),
            "sets": self.entries,
            "unmerged": self.unmerged,
            "responses": [r.to_dict() for r in self.responses],
            "summary": {"sets": len(self.entries), "done": counts.get(STATUS_DONE, 0),
                        "skipped": counts.get(STATUS_SKIPPED, 0), "failed": counts.get(STATUS_FAILED, 0),
                        "unreadable_files": len(self.unreadable)},
        }


# ------------------------------------------------------------------ selecting sets


def parse_sets(text: str) -> List[Tuple[int, Optional[int]]]:
    """Parse a set selection such as ``"3-7"``, ``"5"``, ``"10-"`` or ``"0-3,8,12-"``.

    Ranges are inclusive manifest indices; an open end runs to the last set. A farm
    frame range ``#START#-#END#`` is used as is.

    Raises
    ------
    UsageError
        Not numbers, a negative index, or a range whose start exceeds its end.
    """
    out = []
    items = [t.strip() for t in str(text).split(",")]
    if not any(items):
        raise UsageError("--sets: empty selection")
    for item in items:
        m = re.fullmatch(r"(\d+)?\s*(-)?\s*(\d+)?", item)
        if not item or m is None or (m.group(1) is None and m.group(3) is None):
            raise UsageError(f"--sets: '{item}' is not an index or a range like 3-7")
        a = int(m.group(1)) if m.group(1) is not None else 0
        if m.group(2) is None:
            b: Optional[int] = a
        else:
            b = int(m.group(3)) if m.group(3) is not None else None
        if b is not None and a > b:
            raise UsageError(f"--sets: range '{item}' starts after it ends")
        out.append((a, b))
    return out


def select_sets(sets: Sequence, ranges: Optional[Sequence[Tuple[int, Optional[int]]]]) -> list:
    """The sets whose ``index`` falls in any of ``ranges`` (all when None), by index.

    Ranges beyond the last set are clamped: they select what exists, possibly nothing.
    """
    chosen = sorted(sets, key=lambda s: s.index)
    if ranges is None:
        return chosen
    return [s for s in chosen if any(a <= s.index and (b is None or s.index <= b) for a, b in ranges)]


# ------------------------------------------------------------------------- naming


def output_stems(manifest) -> Dict[int, str]:
    """Output name (without extension) of every set of ``manifest``, by index.

    A set is named after its first frame (``IMG_0001``). Names that would collide
    (compared case-insensitively, for macOS and Windows) are made unique from the
    whole manifest, so the name never depends on which sets a run selects: first with
    the folders that tell the frames apart (``day1_IMG_0001``), then with the file's
    extension (``IMG_0001_tif``), and as a last resort with the set index.
    """
    sets = sorted(manifest.sets, key=lambda s: s.index)
    first = {s.index: os.path.abspath(s.files[0]) for s in sets}
    stems = {i: os.path.splitext(os.path.basename(p))[0].lstrip(".") or f"set{i}" for i, p in first.items()}

    def clashes(names):
        seen = Counter(n.casefold() for n in names.values())
        return {i for i, n in names.items() if seen[n.casefold()] > 1}

    bad = clashes(stems)
    if bad:
        common = os.path.commonpath([os.path.dirname(first[i]) for i in bad])
        for i in bad:
            rel = os.path.relpath(os.path.dirname(first[i]), common)
            parts = [p for p in rel.split(os.sep) if p not in (".", "")]
            stems[i] = "_".join(parts + [stems[i]])
    bad = clashes(stems)
    for i in bad:
        ext = os.path.splitext(first[i])[1].lstrip(".").lower()
        if ext:
            stems[i] = f"{stems[i]}_{ext}"
    for i in clashes(stems):
        stems[i] = f"{stems[i]}-set{i}"
    return stems


# ------------------------------------------------------------------------ sources


def load_source(source, *, recursive: bool = False, frames_per_set: Optional[int] = None,
                gap: Optional[float] = None, exclude: Union[str, Sequence[str], None] = None):
    """The manifest of ``source``: a folder (scanned) or a manifest JSON file.

    Files named in a manifest are not checked here: a missing file fails its own set.
    ``exclude`` (the output folder, the quality report's; one or a list) drops
    unmerged entries under it, such as the previews of an earlier run inside the
    scanned folder.

    Raises
    ------
    InputError
        ``source`` does not exist or the manifest cannot be read.
    UsageError
        Grouping overrides given with a manifest.
    """
    from .grouping import Manifest, load_manifest, scan_directory

    if isinstance(source, Manifest):
        return source
    path = os.fspath(source)
    if os.path.isdir(path):
        manifest = scan_directory(path, recursive=recursive, frames_per_set=frames_per_set, gap=gap)
        if exclude:
            folders = [exclude] if isinstance(exclude, (str, os.PathLike)) else exclude
            exs = tuple(os.path.abspath(e) + os.sep for e in folders)
            manifest.unmerged = [u for u in manifest.unmerged
                                 if not all(os.path.abspath(f).startswith(exs) for f in u.files)]
        return manifest
    if not os.path.exists(path):
        raise InputError(f"{path}: no such folder or manifest file")
    if recursive or frames_per_set is not None or gap is not None:
        raise UsageError("--recursive, --frames-per-set and --gap apply when scanning a folder, "
                         "not to a manifest (edit the manifest instead)")
    return load_manifest(path, check_files=False)


def check_manifest(manifest) -> Dict[int, str]:
    """What would stop each set of a (hand-edited) manifest from merging, by index.

    Reads the frames' headers only: a missing or unreadable file, or a group that
    :func:`hdrcl.grouping.unmergeable_reason` rejects (single frame, one exposure,
    mixed cameras...). Exposures written in the manifest replace the EXIF times.

    Returns
    -------
    dict of int to str
        Only the sets with a problem.
    """
    from .grouping import unmergeable_reason
    from .io import read_info

    problems = {}
    for s in manifest.sets:
        infos = []
        for f in s.files:
            try:
                infos.append(read_info(f))
            except (InputError, OSError) as exc:
                problems[s.index] = str(exc).splitlines()[0]
                break
        else:
            if s.exposures and len(s.exposures) == len(infos):
                infos = [replace(i, exposure_time=float(t)) for i, t in zip(infos, s.exposures)]
            why = unmergeable_reason(infos)
            if why:
                problems[s.index] = why
    return problems


# --------------------------------------------------------------------- planning


def _camera_label(info) -> str:
    make = " ".join((info.make or "").split())
    model = " ".join((info.model or "").split())
    if make and model.lower().startswith(make.split()[0].lower()):
        label = model
    else:
        label = f"{make} {model}".strip()
    return label or "unknown camera"


def _group_of(info) -> str:
    """Response group of a set from its first frame: camera body and ISO."""
    if info is None:
        return "unreadable"
    label = _camera_label(info)
    if info.serial:
        label += f" #{info.serial}"
    iso = f"ISO {info.iso:g}" if info.iso else "ISO ?"
    return f"{label} {iso}"


def _slug(text: str) -> str:
    s = re.sub(r"[^A-Za-z0-9]+", "-", text.replace("#", "")).strip("-")
    return s or "camera"


def _reference(infos: Sequence) -> Tuple[Optional[float], Optional[float]]:
    """Most common first-frame (f-number, ISO) of the shoot; ties to the earliest set."""
    fn = [round(i.fnumber, 2) for i in infos if i is not None and i.fnumber and i.fnumber > 0]
    iso = [round(i.iso, 1) for i in infos if i is not None and i.iso and i.iso > 0]

    def mode(vals):
        if not vals:
            return None
        counts = Counter(vals)
        best = max(counts.values())
        return next(v for v in vals if counts[v] == best)

    return mode(fn), mode(iso)


def _reference_text(ref) -> str:
    n, iso = ref if ref else (None, None)
    return f"f/{n:g} ISO {iso:g}" if n and iso else (
        f"f/{n:g}" if n else (f"ISO {iso:g}" if iso else "exposure time only"))


@dataclass
class _Plan:
    jobs: Dict[int, SetJob]
    selected: List[SetJob]
    reference: Tuple[Optional[float], Optional[float]]
    groups: Dict[str, List[int]]


def _plan(manifest, out_dir: str, options: BatchOptions, ranges) -> _Plan:
    from .io import read_info

    sets = sorted(manifest.sets, key=lambda s: s.index)
    stems = output_stems(manifest)
    firsts = {}
    for s in sets:
        try:
            firsts[s.index] = read_info(s.files[0])
        except (InputError, OSError) as exc:  # the set fails later with its own reason
            logger.debug("set %d: first frame unreadable: %s", s.index, exc)
            firsts[s.index] = None
    reference = _reference([firsts[s.index] for s in sets])
    jobs, groups = {}, {}
    for s in sets:
        group = _group_of(firsts[s.index])
        stem = os.path.join(out_dir, stems[s.index])
        jobs[s.index] = SetJob(index=s.index, files=[os.path.abspath(f) for f in s.files],
                               exposures=[float(t) for t in s.exposures], output=stem + ".exr",
                               preview=stem + ".jpg" if options.preview else None, group=group,
                               reference=reference)
        groups.setdefault(group, []).append(s.index)
    selected = [jobs[s.index] for s in select_sets(sets, ranges)]
    return _Plan(jobs=jobs, selected=selected, reference=reference, groups=groups)


# --------------------------------------------------------------------- hashing


def _file_digest(path: str) -> str:
    h = hashlib.sha256()
    try:
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, not an image") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    return h.hexdigest()


def _json_digest(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def response_digest(payload: dict) -> str:
    """Digest of what fusion uses from a response: bit depth, channels, the curve."""
    return _json_digest({k: payload[k] for k in ("bits", "channels", "knots", "g")})


def set_digest(job: SetJob, options: BatchOptions, response_hash: str) -> str:
    """The identity of a set's output.

    SHA-256 over the frames' contents (with their base names and order), the
    manifest's exposure times, the shoot's reference f-number and ISO, the response
    curve's digest, :meth:`BatchOptions.output_params`, the digest recipe and the hdrcl
    version. Moving the shoot to another folder keeps it; touching a file without
    changing it keeps it; anything that changes the EXR's pixels or format changes it.
    """
    payload = {
        "recipe": DIGEST_RECIPE,
        "hdrcl": __version__,
        "files": [[os.path.basename(f), _file_digest(f)] for f in job.files],
        "exposures": list(job.exposures),
        "reference": list(job.reference),
        "response": response_hash,
        "output": options.output_params(),
    }
    return _json_digest(payload)


# --------------------------------------------------------------------- loading sets


def _shoot_scale(exposures, reference) -> Tuple[float, List[str]]:
    """Factor from a set's own exposure scale to the shoot's, and notes on it.

    :func:`hdrcl.metadata.relative_exposures` expresses a set's exposures at its first
    frame's f-number and ISO (leaving out a factor some frame lacks); this converts
    them to the shoot's reference f-number and ISO.
    """
    ref_n, ref_iso = reference
    e0 = exposures[0]
    k, notes = 1.0, []
    if all(e.fnumber and e.fnumber > 0 for e in exposures):
        if ref_n:
            k *= (ref_n / e0.fnumber) ** 2
    elif ref_n:
        notes.append(f"no f-number in EXIF: exposure scale assumes the shoot's f/{ref_n:g}")
    if all(e.iso and e.iso > 0 for e in exposures):
        if ref_iso:
            k *= e0.iso / ref_iso
    elif ref_iso:
        notes.append(f"no ISO in EXIF: exposure scale assumes the shoot's ISO {ref_iso:g}")
    return k, notes


@dataclass
class _Opened:
    """A set's headers and its exposures on the shoot's scale (no pixels decoded)."""

    infos: list
    times: np.ndarray
    ev_offset: float
    notes: List[str]
    stamp: str  # first frame's capture time as EXIF DateTime text, or ""


def _open_set(job: SetJob) -> _Opened:
    """Read a set's headers, check the frames agree, and scale its exposures.

    Raises
    ------
    InputError
        A frame is missing or unreadable, the frames differ in size, channels or
        depth, an exposure time is missing, or two frames share one exposure.
    """
    from .api import read_infos
    from .io import check_compatible
    from .metadata import relative_exposures, resolve_exposures

    if len(job.files) < 2:
        raise InputError(f"{job.files[0]}: a bracket set needs at least two exposures")
    if job.exposures and len(job.exposures) != len(job.files):
        raise InputError(f"set {job.index}: {len(job.exposures)} exposures for {len(job.files)} files")
    infos = read_infos(job.files)
    check_compatible(infos)
    timed = []
    for k, info in enumerate(infos):
        t = job.exposures[k] if job.exposures else info.exposure_time
        if t is None or not t > 0:
            raise InputError(f"{info.path}: no exposure time in EXIF; add \"exposures\" to the set in the manifest")
        timed.append(replace(info, exposure_time=float(t)))
    exposures = resolve_exposures(job.files, timed)
    k, notes = _shoot_scale(exposures, job.reference)
    times = np.asarray(relative_exposures(exposures), np.float64) * k
    t0 = infos[0].capture_time
    stamp = "" if t0 is None else t0.strftime("%Y:%m:%d %H:%M:%S")
    return _Opened(infos=timed, times=times, ev_offset=math.log2(k), notes=notes, stamp=stamp)


def _calibration_grid(job: SetJob, opened: _Opened, ignore_color):
    """The decimated grid of a set that sample selection works on (one streaming read)."""
    from .api import _grid_bracket

    return _grid_bracket(list(job.files), opened.infos, opened.times, ignore_color)


# -------------------------------------------------------------------- responses


def _normalised(resp: Response) -> dict:
    """The response as its JSON file holds it (so solved and loaded curves agree)."""
    return json.loads(json.dumps(resp.to_dict()))


_response_cache: Dict[str, Response] = {}


def _response_of(entry: ResponseEntry) -> Response:
    resp = _response_cache.get(entry.digest)
    if resp is None:
        resp = Response.from_dict(entry.payload, source=entry.file or entry.group)
        _response_cache[entry.digest] = resp
    return resp


def _atomic_json(path: str, obj) -> None:
    """Write JSON through a temporary file and a rename (readers never see half)."""
    folder = os.path.dirname(os.path.abspath(path))
    tmp = os.path.join(folder, f".{os.path.basename(path)}.{secrets.token_hex(4)}.tmp")
    # os.open with 0o666 honours the umask (mkstemp would make the file private).
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(obj, fh, indent=1)
            fh.write("\n")
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _pool_of(indices: Sequence[int]) -> List[int]:
    """At most MAX_POOL_SETS indices, evenly spaced, deterministic."""
    idx = sorted(indices)
    if len(idx) <= MAX_POOL_SETS:
        return idx
    m = MAX_POOL_SETS
    return sorted({idx[round(i * (len(idx) - 1) / (m - 1))] for i in range(m)})


def _calibrate_group(group: str, jobs: List[SetJob], out_dir: str, options: BatchOptions) -> ResponseEntry:
    """Load the group's saved response if its key matches, else solve and save it."""
    from .response import recover_response_pooled

    path = os.path.join(out_dir, _slug(group) + RESPONSE_SUFFIX)
    entry = ResponseEntry(group=group, file=path, sets=[j.index for j in jobs])
    usable, keyed = [], []
    for j in jobs:
        try:
            keyed.append([j.index, [[os.path.basename(f), _file_digest(f)] for f in j.files], j.exposures])
            usable.append(j)
        except InputError as exc:
            entry.warnings.append(f"set {j.index} not pooled: {exc}")
    key = _json_digest({"recipe": DIGEST_RECIPE, "hdrcl": __version__, "solve": options.solve_params(),
                        "reference": list(jobs[0].reference) if jobs else None, "sets": keyed})
    try:
        with open(path, encoding="utf-8") as fh:
            saved = json.load(fh)
        if isinstance(saved, dict) and saved.get("calibration", {}).get("key") == key:
            Response.from_dict(saved, source=path)  # validates
            entry.payload = {k: v for k, v in saved.items() if k != "calibration"}
            entry.digest = response_digest(entry.payload)
            entry.source = "loaded"
            entry.warnings += list(saved.get("calibration", {}).get("warnings", []))
            logger.info("%s: response loaded from %s", group, path)
            return entry
    except (OSError, ValueError, HdrclError):
        pass  # absent, stale or damaged: solve again
    brackets, pooled, first_info = [], [], None
    for j in usable:
        try:
            opened = _open_set(j)
            br = _calibration_grid(j, opened, options.ignore_color)
        except HdrclError as exc:
            entry.warnings.append(f"set {j.index} not pooled: {str(exc).splitlines()[0]}")
            continue
        if first_info is None:
            first_info = opened.infos[0]
        brackets.append((br.frames, br.times, br.valid_all))
        pooled.append(j.index)
    if not brackets:
        entry.error = "no set of this camera and ISO could be read to calibrate its response"
        return entry
    try:
        resp = recover_response_pooled(brackets, samples=options.samples, smoothness=options.smoothness,
                                       weight=options.weight, seed=options.seed)
    except HdrclError as exc:
        entry.error = f"calibration failed: {str(exc).splitlines()[0]}"
        return entry
    resp.camera = {k: v for k, v in (("make", first_info.make), ("model", first_info.model),
                                     ("iso", first_info.iso)) if v is not None}
    entry.payload = _normalised(resp)
    entry.digest = response_digest(entry.payload)
    entry.source = "calibrated"
    entry.sets = pooled
    entry.warnings += list(resp.warnings)
    saved = dict(entry.payload)
    saved["calibration"] = {"key": key, "group": group, "pooled_sets": pooled, "warnings": entry.warnings}
    _atomic_json(path, saved)
    logger.info("%s: response calibrated from sets %s -> %s", group, pooled, path)
    return entry


def _prepare_responses(plan: _Plan, out_dir: str, options: BatchOptions, response=None) -> Dict[str, ResponseEntry]:
    needed = sorted({j.group for j in plan.selected})
    if response is not None:
        if isinstance(response, Response):
            payload, name = _normalised(response), "given"
        else:
            name = os.fspath(response)
            payload = _normalised(Response.load(name))
        digest = response_digest(payload)
        return {g: ResponseEntry(group=g, payload=payload, digest=digest, file=name, source="given")
                for g in needed}
    out = {}
    for g in needed:
        out[g] = _calibrate_group(g, [plan.jobs[i] for i in _pool_of(plan.groups[g])], out_dir, options)
    return out


# ------------------------------------------------------------------------ stages


@dataclass
class _Opening:
    """A set that needs merging: its digest and headers, read ahead of the merge."""

    job: SetJob
    digest: str
    opened: _Opened
    seconds: Dict[str, float]


def _failed(job: SetJob, exc: BaseException, seconds=None, digest=None) -> SetResult:
    if isinstance(exc, HdrclError):
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    else:
        first = str(exc).splitlines()[0] if str(exc) else ""
        msg = f"internal error: {type(exc).__name__}: {first}"
        logger.debug("set %d failed", job.index, exc_info=exc)
    return SetResult(index=job.index, files=list(job.files), status=STATUS_FAILED, output=job.output,
                     preview=job.preview, error=msg, seconds=dict(seconds or {}), digest=digest,
                     response=job.group)


def _up_to_date(job: SetJob, digest: str, options: BatchOptions) -> Tuple[bool, bool, dict, dict]:
    """Whether the EXR and the preview carry ``digest`` (header reads only).

    Returns ``(exr_ok, preview_ok, exr_metadata, preview_metadata)``.
    """
    from .writers import read_metadata

    try:
        meta = read_metadata(job.output)
    except HdrclError:
        return False, False, {}, {}
    if meta.get(DIGEST_KEY) != digest:
        return False, False, {}, {}
    if job.preview is None:
        return True, True, meta, {}
    try:
        pmeta = read_metadata(job.preview)
    except HdrclError:
        return True, False, meta, {}
    ok = pmeta.get(DIGEST_KEY) == digest and int(pmeta.get("previewSize", -1)) == int(options.preview_size)
    return True, ok, meta, pmeta if ok else {}


def _preview_metadata(digest: str, options: BatchOptions, counts: dict) -> dict:
    # The counts are known only after the EXR's header is written: the preview keeps
    # them for the report of later runs that skip the set.
    return {DIGEST_KEY: digest, "previewSize": int(options.preview_size), "tonemap": "reinhard",
            "clippedHigh": int(counts.get("clipped_high", 0)), "clippedLow": int(counts.get("clipped_low", 0)),
            "noData": int(counts.get("no_data", 0))}


def _counts_of(meta: dict) -> Dict[str, int]:
    if "clippedHigh" not in meta:
        return {}
    return {"clipped_high": int(meta.get("clippedHigh", 0)), "clipped_low": int(meta.get("clippedLow", 0)),
            "no_data": int(meta.get("noData", 0))}


def _rebuild_preview(job: SetJob, digest: str, options: BatchOptions) -> None:
    """A lost or stale preview, made again from its (current) EXR."""
    from .preview import downscale, encode
    from .writers import read_metadata, read_radiance, write_ldr

    rad, _ = read_radiance(job.output)
    try:  # a stale preview of this very EXR (another size) still knows its counts
        old = read_metadata(job.preview)
        counts = _counts_of(old) if old.get(DIGEST_KEY) == digest else {}
    except HdrclError:
        counts = {}
    write_ldr(job.preview, encode(downscale(rad, options.preview_size)),
              metadata=_preview_metadata(digest, options, counts))


def _read_stage(job: SetJob, ctx: _Context, strict: bool = False):
    """Hash the set, skip it if its outputs are current, else read its headers."""
    seconds: Dict[str, float] = {}
    digest = None
    try:
        entry = ctx.responses.get(job.group)
        if entry is None or entry.payload is None:
            # A set's own problem (its first frame is missing...) explains this best.
            _open_set(job)
            why = entry.error if entry is not None else "no response"
            raise HdrclError(f"no response for {job.group}: {why}")
        t0 = _time.perf_counter()
        digest = set_digest(job, ctx.options, entry.digest)
        seconds["hash"] = _time.perf_counter() - t0
        if not ctx.force:
            exr_ok, preview_ok, meta, pmeta = _up_to_date(job, digest, ctx.options)
            if exr_ok:
                res = SetResult(index=job.index, files=list(job.files), status=STATUS_SKIPPED, output=job.output,
                                preview=job.preview, seconds=seconds, digest=digest, response=job.group,
                                counts=_counts_of(pmeta), ev_offset=_float_or_none(meta.get("evOffset")))
                if not preview_ok:
                    t1 = _time.perf_counter()
                    _rebuild_preview(job, digest, ctx.options)
                    seconds["preview"] = _time.perf_counter() - t1
                    res.warnings.append("preview was missing or stale: rebuilt from the EXR")
                if ctx.options.report_dir:
                    res.quality = _current_quality(ctx.options.report_dir, job, digest)
                    if res.quality is None:
                        t1 = _time.perf_counter()
                        _rebuild_quality(res, job, ctx)
                        seconds["quality"] = _time.perf_counter() - t1
                return res
        t1 = _time.perf_counter()
        opened = _open_set(job)
        seconds["open"] = _time.perf_counter() - t1
        return _Opening(job, digest, opened, seconds)
    except Exception as exc:
        if strict and not isinstance(exc, HdrclError):
            raise
        return _failed(job, exc, seconds, digest)


# ----------------------------------------------------------------- quality report

#: Long side of the reduced radiance map the report is made from when no preview is written.
REPORT_IMAGE_SIZE = 512


def _quality_stride(n: int, h: int, w: int, nch: int, dtype) -> int:
    """1 (whole frames) when the set's frames fit :func:`hdrcl.api.memory_budget`, else
    the stride of the sampling grid, as for ``hdrcl merge --report``."""
    from .api import memory_budget
    from .sampling import grid_stride

    return 1 if n * h * w * nch * np.dtype(dtype).itemsize <= memory_budget() else grid_stride(h, w)


class _KeptFrames:
    """A :class:`hdrcl.io.BracketReader` whose strips pass through unchanged while every
    ``stride``-th row and column of each frame (all of it for stride 1) is kept, so the
    quality figures need no second decode. Same grid as ``BracketReader.read_grid``."""

    def __init__(self, reader, stride: int):
        self._reader = reader
        self.stride = s = max(1, int(stride))
        hh, ww = len(range(0, reader.height, s)), len(range(0, reader.width, s))
        self._shape = (hh, ww)
        self.kept = [np.empty((hh, ww, reader.nch), reader.dtype) for _ in reader.paths]
        self.kept_valid: list = [None] * len(reader.paths)

    def __getattr__(self, name):
        return getattr(self._reader, name)

    def strips(self, rows: int):
        s = self.stride
        for y0, y1, frames, valid in self._reader.strips(rows):
            first = (-y0) % s
            g0 = (y0 + first) // s
            for k, (f, v) in enumerate(zip(frames, valid)):
                part = f[first::s, ::s]
                self.kept[k][g0:g0 + part.shape[0]] = part
                if v is not None:
                    if self.kept_valid[k] is None:
                        self.kept_valid[k] = np.ones(self._shape, bool)
                    self.kept_valid[k][g0:g0 + part.shape[0]] = v[first::s, ::s]
            yield y0, y1, frames, valid

    def bracket(self, files, infos, times, ignore_color):
        from .api import Bracket, _with_ignore

        return Bracket(frames=self.kept, times=np.asarray(times, np.float64),
                       valid=_with_ignore(self.kept, self.kept_valid, ignore_color), paths=list(files),
                       infos=list(infos), grid=self.stride > 1)


def _report_stem(job: SetJob) -> str:
    return os.path.splitext(os.path.basename(job.output))[0]


def _quality_for(res: SetResult, job: SetJob, bracket, resp: Response, times, radiance, opts: BatchOptions) -> None:
    """Measure the set, write its report files and put the figures into ``res``.

    The figures' JSON is stamped with the set's digest, so that a later run that skips
    the set knows whether they describe its current output. A failure here is a
    warning: the merge itself succeeded.
    """
    from .quality import measure
    from .report import file_stem, write_set_report

    try:
        with _FUSE_LOCK:  # leave-one-out fuses on the process's OpenCL device
            fig = measure(bracket, resp, radiance, weight=opts.weight, times=times, device=opts.device)
        stem = _report_stem(job)
        entry = write_set_report(opts.report_dir, stem, fig, resp, radiance, fig.coverage, warnings=res.warnings)
        payload = entry.to_dict()
        payload[DIGEST_KEY] = res.digest
        _atomic_json(os.path.join(opts.report_dir, file_stem(stem) + ".json"), payload)
        res.quality = fig.to_dict()
    except Exception as exc:
        if not isinstance(exc, (HdrclError, OSError, ValueError)):
            logger.debug("set %d: quality report failed", job.index, exc_info=exc)
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        res.warnings.append(f"quality report not written: {first}")


def _current_quality(folder: str, job: SetJob, digest: Optional[str]) -> Optional[dict]:
    """The figures of a report written for this very output (same digest, every file
    present), or None."""
    from .report import REPORT_FORMAT, file_stem

    try:
        with open(os.path.join(folder, file_stem(_report_stem(job)) + ".json"), encoding="utf-8") as fh:
            d = json.load(fh)
    except (OSError, ValueError):
        return None
    if not isinstance(d, dict) or d.get("format") != REPORT_FORMAT or digest is None or d.get(DIGEST_KEY) != digest:
        return None
    files = d.get("files") or {}
    if not isinstance(d.get("figures"), dict) or not all(
            isinstance(f, str) and os.path.isfile(os.path.join(folder, f)) for f in files.values()):
        return None
    return d["figures"]


def _rebuild_quality(res: SetResult, job: SetJob, ctx: _Context) -> None:
    """The report of a skipped set that has none (or a stale one): the frames are read
    again (whole or the sampling grid) and the radiance from its EXR."""
    from .api import Bracket, _with_ignore
    from .io import BracketReader
    from .preview import downscale
    from .writers import read_radiance

    opts = ctx.options
    try:
        opened = _open_set(job)
        resp = _response_of(ctx.responses[job.group])
        first = opened.infos[0]
        h, w = first.height, first.width
        with BracketReader(job.files, opened.infos) as reader:
            stride = _quality_stride(len(job.files), h, w, reader.nch, reader.dtype)
            frames, valid = reader.read_all() if stride == 1 else reader.read_grid(stride)
        bracket = Bracket(frames=frames, times=opened.times, valid=_with_ignore(frames, valid, opts.ignore_color),
                          paths=list(job.files), infos=opened.infos, grid=stride > 1)
        rad, _ = read_radiance(job.output)
        small = downscale(rad, opts.preview_size if job.preview is not None else REPORT_IMAGE_SIZE)
        del rad
    except Exception as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        res.warnings.append(f"quality report not written: {first}")
        return
    _quality_for(res, job, bracket, resp, opened.times, small, opts)


def _contact_sheet(plan: "_Plan", entries: List[dict], folder: str) -> str:
    """``index.html`` over every set of the manifest, in index order.

    ``entries`` are the report's (this run's and earlier runs' into the same folder).
    A set's figures and pictures come from the report folder when they describe its
    current output; failed sets show their reason; sets no run has handled yet are
    "pending".
    """
    from .report import ReportEntry, load_set_report, write_contact_sheet

    known = {e.get("index"): e for e in entries}
    cards = []
    for i in sorted(plan.jobs):
        job = plan.jobs[i]
        stem = _report_stem(job)
        e = known.get(i) or {}
        status = e.get("status")
        if status == STATUS_FAILED:
            cards.append(ReportEntry(stem, STATUS_FAILED, error=e.get("error") or "failed",
                                     warnings=list(e.get("warnings") or [])))
            continue
        card = None
        if status is None or _current_quality(folder, job, e.get("hash")) is not None:
            card = load_set_report(folder, stem)
        if card is None:
            card = ReportEntry(stem, status or "pending", warnings=list(e.get("warnings") or []))
            if status is not None:
                card.warnings.append("no quality figures for this output: run the batch again with --report")
        elif status is not None:
            card.status = status
        cards.append(card)
    return write_contact_sheet(folder, cards)


class _Tee:
    """Hands every strip to several sinks (the EXR writer, the preview)."""

    def __init__(self, *sinks):
        self.sinks = [s for s in sinks if s is not None]

    def write_rows(self, y0, y1, data):
        for s in self.sinks:
            s.write_rows(y0, y1, data)


def _merge_stage(step: _Opening, ctx: _Context, strict: bool = False) -> SetResult:
    """Decode, fuse and write the set strip by strip; preview; commit the EXR.

    Memory stays bounded by the strip height whatever the image size: decoding the
    next strip, fusing the current one on the device and encoding the previous one
    overlap (:func:`hdrcl.pipeline.stream_merge`).
    """
    from .api import MergeResult, _provenance
    from .backend import get_processor
    from .io import BracketReader
    from .pipeline import stream_merge
    from .preview import AreaAverage, encode
    from .writers import RadianceWriter, write_ldr

    job, opened, opts = step.job, step.opened, ctx.options
    seconds = step.seconds
    try:
        entry = ctx.responses[job.group]
        resp = _response_of(entry)
        first = opened.infos[0]
        h, w = first.height, first.width
        t0 = _time.perf_counter()
        with _FUSE_LOCK, BracketReader(job.files, opened.infos) as reader:
            nch = reader.nch
            backend = "numpy" if get_processor("fusion", opts.device) is None else "opencl"
            about = MergeResult(radiance=None, response=resp, counts={}, times=opened.times, paths=list(job.files),
                                backend=backend, shape=(h, w, nch))
            meta = _provenance(about, os.path.basename(entry.file) if entry.file else entry.group)
            meta.update({DIGEST_KEY: step.digest, "evOffset": round(opened.ev_offset, 6),
                         "exposureRef": _reference_text(job.reference)})
            small = AreaAverage(h, w, nch, opts.preview_size) if job.preview is not None else None
            # The quality report keeps the frames (or their sampling grid) as they stream
            # past, and a reduced radiance map: the preview's, or its own without one.
            kept = _KeptFrames(reader, _quality_stride(len(job.files), h, w, nch, reader.dtype)) \
                if opts.report_dir else None
            thumb = small if small is not None or not opts.report_dir else AreaAverage(h, w, nch, REPORT_IMAGE_SIZE)
            writer = RadianceWriter(job.output, w, h, nch, dtype=opts.dtype, compression=opts.compression,
                                    metadata=meta, timestamp=opened.stamp)
            try:
                has_valid = opts.ignore_color is not None or any(i.nchannels in (2, 4) for i in opened.infos)
                counts, _ = stream_merge(reader if kept is None else kept, opened.times, resp, _Tee(writer, thumb),
                                         weight=opts.weight, ignore_color=opts.ignore_color, has_valid=has_valid,
                                         device=opts.device, deghost=opts.deghost)
                t1 = _time.perf_counter()
                # Preview first: the EXR, moved into place last, marks the set complete.
                if small is not None:
                    write_ldr(job.preview, encode(small.result()),
                              metadata=_preview_metadata(step.digest, opts, counts))
                t2 = _time.perf_counter()
                warnings = writer.close()
            except BaseException:
                writer.abort()
                raise
        seconds.update({"merge": t1 - t0, "preview": t2 - t1, "write": _time.perf_counter() - t2})
        notes = list(opened.notes) + list(resp.warnings) + list(warnings)
        if counts.get("no_data"):
            notes.append(f"{counts['no_data']} pixel-channels are invalid in every frame and were set to 0")
        keys = ("clipped_high", "clipped_low", "no_data") + (("ghost", "ghost_unresolved") if opts.deghost else ())
        res = SetResult(index=job.index, files=list(job.files), status=STATUS_DONE, output=job.output,
                        preview=job.preview, warnings=notes, seconds=seconds,
                        counts={k: int(counts.get(k, 0)) for k in keys},
                        ev_offset=round(opened.ev_offset, 6), digest=step.digest, response=job.group)
        if kept is not None:
            # After the EXR is committed: the report never holds back or spoils an output.
            t3 = _time.perf_counter()
            bracket = kept.bracket(job.files, opened.infos, opened.times, opts.ignore_color)
            del kept
            _quality_for(res, job, bracket, resp, opened.times, thumb.result(), opts)
            seconds["quality"] = _time.perf_counter() - t3
        return res
    except Exception as exc:
        if strict and not isinstance(exc, HdrclError):
            raise
        return _failed(job, exc, seconds, step.digest)


def _float_or_none(v) -> Optional[float]:
    try:
        return None if v is None else float(v)
    except (TypeError, ValueError):
        return None


def process_set(job: SetJob, ctx: _Context, strict: bool = False) -> SetResult:
    """Hash, open, merge and write one set in the calling process.

    The task that worker processes and Dask workers run. With ``strict``, errors
    that are not :class:`~hdrcl.errors.HdrclError` (a bug, a lost mount, a device
    fault) are raised so that the scheduler retries the task; a set's own problems
    (corrupt frame, missing exposure) always come back as a failed result.
    """
    t0 = _time.perf_counter()
    step = _read_stage(job, ctx, strict)
    if isinstance(step, _Opening):
        step = _merge_stage(step, ctx, strict)
    step.seconds["total"] = _time.perf_counter() - t0
    return step


def _run_pipelined(jobs: List[SetJob], ctx: _Context, emit: Callable[[SetResult], None]) -> None:
    """Run sets in this process, hashing and opening the next set during the merge.

    The merge itself overlaps decoding, fusion (on this thread, which owns the
    OpenCL queue) and encoding strip by strip; the read-ahead thread meanwhile hashes
    the next set's files, checks whether its outputs are current and reads its
    headers, so consecutive sets follow each other without a gap.
    """
    if not jobs:
        return
    started: Dict[int, float] = {}

    def read(job):
        started[job.index] = _time.perf_counter()
        return _read_stage(job, ctx)

    with ThreadPoolExecutor(1, thread_name_prefix="hdrcl-readahead") as reader:
        ahead = reader.submit(read, jobs[0])
        for i in range(len(jobs)):
            step = ahead.result()
            if i + 1 < len(jobs):
                ahead = reader.submit(read, jobs[i + 1])
            if isinstance(step, _Opening):
                step = _merge_stage(step, ctx)
            step.seconds["total"] = _time.perf_counter() - started[step.index]
            emit(step)


# ------------------------------------------------------------------------ report


@contextlib.contextmanager
def _report_lock(out_dir: str):
    """Serialise read-modify-write of the report between chunks sharing a folder."""
    try:
        import fcntl
    except ImportError:  # Windows: chunks there should use --report-json per chunk
        yield
        return
    path = os.path.join(out_dir, ".report.lock")
    with open(path, "a+") as fh:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def _merge_entries(path: str, results: List[SetResult], plan: _Plan) -> List[dict]:
    """This run's entries plus earlier entries of other sets of the same manifest."""
    mine = {r.index: r.to_dict() for r in results}
    try:
        with open(path, encoding="utf-8") as fh:
            old = json.load(fh)
        old_sets = old.get("sets", []) if isinstance(old, dict) else []
    except (OSError, ValueError):
        old_sets = []
    for e in old_sets:
        try:
            i = int(e["index"])
        except (KeyError, TypeError, ValueError):
            continue
        job = plan.jobs.get(i)
        if i not in mine and job is not None and [os.path.abspath(f) for f in e.get("files", [])] == job.files:
            mine[i] = e
    return [mine[i] for i in sorted(mine)]


def _remove_stale_temps(out_dir: str, stems: Sequence[str]) -> None:
    """Delete temporary files that killed runs left behind.

    Those of the sets this run writes go at once (no other process writes them);
    others only when older than :data:`STALE_TEMP_SECONDS`, as another chunk may be
    writing them right now.
    """
    mine = set(stems)
    now = _time.time()
    pat = re.compile(r"^\.(?P<stem>.+)\.tmp-[0-9a-f]{8}\.(exr|jpg)$|^\..+\.json\.[^.]+\.tmp$")
    try:
        names = os.listdir(out_dir)
    except OSError:
        return
    for name in names:
        m = pat.match(name)
        if not m:
            continue
        p = os.path.join(out_dir, name)
        with contextlib.suppress(OSError):
            if m.group("stem") in mine or now - os.path.getmtime(p) > STALE_TEMP_SECONDS:
                os.remove(p)
                logger.debug("removed stale temporary file %s", p)


# --------------------------------------------------------------------------- run


def run_batch(
    source,
    out_dir,
    *,
    options: Optional[BatchOptions] = None,
    sets: Union[str, Sequence[Tuple[int, Optional[int]]], None] = None,
    response=None,
    jobs: int = 1,
    scheduler=None,
    retries: int = 2,
    force: bool = False,
    report: Union[str, os.PathLike, None] = None,
    calibrate_only: bool = False,
    recursive: bool = False,
    frames_per_set: Optional[int] = None,
    gap: Optional[float] = None,
    progress: Optional[Callable[[Optional[SetResult], int, int], None]] = None,
) -> BatchReport:
    """Merge every bracket set of a shoot into ``out_dir``.

    Parameters
    ----------
    source : str, os.PathLike or Manifest
        A folder of photographs (scanned with ``recursive``, ``frames_per_set``,
        ``gap``), a manifest file from ``hdrcl scan -o``, or a Manifest.
    out_dir : str or os.PathLike
        Output folder, created if needed: ``<stem>.exr`` and ``<stem>.jpg`` per set,
        the pooled responses and ``report.json``.
    options : BatchOptions, optional
    sets : str or list of (start, end), optional
        Manifest indices to run (:func:`parse_sets`); the rest of the manifest still
        decides the response pool, the exposure reference and the output names.
    response : Response or path, optional
        One response for every set instead of the pooled calibration.
    jobs : int
        Worker processes; 1 runs the pipeline in this process. The workers are
        started with ``spawn``, so a script calling this with ``jobs > 1`` needs the
        ``if __name__ == "__main__":`` guard.
    scheduler : str or distributed.Client, optional
        Run the sets on this Dask cluster (``tcp://host:8786``).
    retries : int
        Dask: times a task that raised an unexpected error is retried.
    force : bool
        Rebuild outputs even when they are up to date.
    report : path, optional
        Where to write the JSON report [default: ``out_dir/report.json``] (the CLI's
        ``--report-json``; the quality report folder is ``options.report_dir``).
    calibrate_only : bool
        Prepare (solve or load) the responses of the selected sets and stop.
    progress : callable, optional
        ``progress(result, completed, total)``; called once with ``result=None``
        before the first set, then after each set.

    Returns
    -------
    BatchReport

    Raises
    ------
    InputError
        The folder or manifest cannot be read, or the response file is unreadable.
    UsageError
        Conflicting options or an unusable output folder.
    """
    t_start = _time.perf_counter()
    options = options or BatchOptions()
    if jobs < 1:
        raise UsageError(f"--jobs must be at least 1, not {jobs}")
    if scheduler is not None and jobs > 1:
        raise UsageError("--jobs and --scheduler exclude each other: the Dask cluster decides the parallelism")
    if options.dtype not in ("half", "float"):
        raise UsageError(f"--dtype: '{options.dtype}' is not one of half, float")
    if options.preview_size < 16:
        raise UsageError("--preview-size must be at least 16 pixels")
    from .writers import _exr_compression  # validates the name before any work

    _exr_compression(options.compression)
    ranges = parse_sets(sets) if isinstance(sets, str) else (list(sets) if sets is not None else None)
    out_dir = os.path.abspath(os.fspath(out_dir))
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise UsageError(f"{out_dir}: output is not a folder")
    report_dir = None
    if options.report_dir is not None:
        report_dir = os.path.abspath(os.fspath(options.report_dir))
        if os.path.exists(report_dir) and not os.path.isdir(report_dir):
            raise UsageError(f"{report_dir}: --report is not a folder")
        options = replace(options, report_dir=report_dir)
    manifest = load_source(source, recursive=recursive, frames_per_set=frames_per_set, gap=gap,
                           exclude=[out_dir] + ([report_dir] if report_dir else []))
    for folder, what in ((out_dir, "output"), (report_dir, "report")):
        if folder is None:
            continue
        try:
            os.makedirs(folder, exist_ok=True)
        except OSError as exc:
            raise UsageError(f"{folder}: cannot create the {what} folder ({exc.strerror or exc})") from None

    plan = _plan(manifest, out_dir, options, ranges)
    logger.info("%d set(s) in the manifest, %d selected; reference %s", len(plan.jobs), len(plan.selected),
                _reference_text(plan.reference))
    responses = _prepare_responses(plan, out_dir, options, response)
    unreadable = [f for u in manifest.unmerged if u.reason.startswith("corrupt") for f in u.files] \
        if ranges is None else []
    rep = BatchReport(unmerged=[{"files": [os.path.abspath(f) for f in u.files], "reason": u.reason}
                                for u in manifest.unmerged],
                      responses=[responses[g] for g in sorted(responses)], unreadable=unreadable,
                      reference=plan.reference)
    if calibrate_only:
        rep.seconds = _time.perf_counter() - t_start
        return rep

    _remove_stale_temps(out_dir, [os.path.splitext(os.path.basename(j.output))[0] for j in plan.selected])
    ctx = _Context(options=options, responses=responses, force=force)
    total = len(plan.selected)
    results: List[SetResult] = []

    def emit(res: SetResult):
        results.append(res)
        # A progress callback reports failures itself; without one, the log does.
        lvl = logging.WARNING if res.status == STATUS_FAILED and progress is None else logging.INFO
        logger.log(lvl, "set %d: %s%s", res.index, res.status, f": {res.error}" if res.error else "")
        if progress is not None:
            progress(res, len(results), total)

    if progress is not None:
        progress(None, 0, total)
    if scheduler is not None:
        from .executors import run_dask

        run_dask(plan.selected, ctx, scheduler, emit, retries=retries)
    elif jobs > 1 and total > 1:
        from .executors import run_processes

        run_processes(plan.selected, ctx, emit, jobs=min(jobs, total))
    else:
        _run_pipelined(plan.selected, ctx, emit)

    rep.results = sorted(results, key=lambda r: r.index)
    report_path = os.path.abspath(os.fspath(report)) if report is not None else os.path.join(out_dir, REPORT_NAME)
    if not os.path.isdir(os.path.dirname(report_path)):
        raise UsageError(f"{report_path}: report folder does not exist")
    with _report_lock(os.path.dirname(report_path)):
        rep.entries = _merge_entries(report_path, rep.results, plan)
        _atomic_json(report_path, rep.to_dict())
        if report_dir is not None:
            # Under the report's lock: of chunks finishing together, the last one to
            # write the contact sheet sees every other's sets.
            rep.quality_report = _contact_sheet(plan, rep.entries, report_dir)
    rep.path = report_path
    rep.seconds = _time.perf_counter() - t_start
    return rep
