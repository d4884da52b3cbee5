"""Planning a batch: the manifest's source, set selection (``--sets``), camera/ISO groups
and the shoot-wide exposure reference; the sets' output names are
:mod:`hdrcl.shoot.batch.setnames`'.
"""
from __future__ import annotations

import logging
import os
import re
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Dict, List, Optional, Sequence, Tuple, Union

from hdrcl.errors import InputError, UsageError
from hdrcl.shoot.batch.jobs import BatchOptions, SetJob
from hdrcl.shoot.batch.names import response_path
from hdrcl.shoot.batch.manifest import set_findings
from hdrcl.shoot.batch.setnames import output_stems, set_folder

logger = logging.getLogger(__name__)


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


# ------------------------------------------------------------------------ sources
def load_source(source, *, recursive: bool = False, frames_per_set: Optional[int] = None,
                gap: Optional[float] = None, exclude: Union[str, Sequence[str], None] = None, times_file=None,
                content: bool = True):
    """The manifest of ``source``: a folder (scanned) or a manifest JSON file.

    Files named in a manifest are not checked here: a missing file fails its own set.
    ``exclude`` (the output folder, the quality report's; one or a list) drops
    unmerged entries under it, such as the previews of an earlier run inside the
    scanned folder. ``times_file`` gives exposures to frames without EXIF (and to the
    sets of a manifest that list none); see :func:`hdrcl.shoot.scan.scan_directory`.

    Raises
    ------
    InputError
        ``source`` does not exist or the manifest cannot be read.
    UsageError
        Grouping overrides given with a manifest.
    """
    from hdrcl.shoot.batch.manifest import Manifest, load_manifest
    from hdrcl.shoot.scan import scan_directory

    if isinstance(source, Manifest):
        return source
    path = os.fspath(source)
    if os.path.isdir(path):
        manifest = scan_directory(path, recursive=recursive, frames_per_set=frames_per_set, gap=gap,
                                  times_file=times_file, content=content)
        _drop_one_exposure_sets(manifest)
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
    manifest = load_manifest(path, check_files=False)
    if times_file is not None:
        from hdrcl.io.exposure_lists import read_times_file

        table = read_times_file(times_file, [f for s in manifest.sets for f in s.files])
        for s in manifest.sets:
            if not s.exposures and all(os.path.basename(f) in table for f in s.files):
                s.exposures = [float(table[os.path.basename(f)].factor) for f in s.files]
    return manifest


def _drop_one_exposure_sets(manifest) -> None:
    """Sets whose frames all record one exposure (time x ISO: 4 s at ISO 2500 is 2 s at
    ISO 5000) are no bracket: they go to ``manifest.unmerged`` with that reason, as the
    merge would refuse them (:func:`hdrcl.io.metadata.relative_exposures`), so that scan
    and batch agree on the sets. The remaining sets are numbered again from 0."""
    from hdrcl.io.metadata import SAME_EXPOSURE_RTOL, format_time
    from hdrcl.shoot.batch.manifest import Unmerged

    kept = []
    for st in manifest.sets:
        isos = list(st.iso or [])
        times = list(st.exposures or [])
        if len(times) == len(st.files) >= 2 and len(isos) == len(times) and all(
                t and i for t, i in zip(times, isos)):
            eff = [float(t) * float(i) for t, i in zip(times, isos)]
            if max(eff) - min(eff) <= SAME_EXPOSURE_RTOL * max(eff):
                shown = ", ".join(f"{format_time(t)} at ISO {i:g}" for t, i in zip(times, isos))
                manifest.unmerged.append(Unmerged(files=list(st.files),
                                                  reason=f"all frames share one exposure ({shown})",
                                                  ended=st.reason))
                continue
        kept.append(st)
    if len(kept) != len(manifest.sets):
        for k, st in enumerate(kept):
            st.index = k
        manifest.sets = kept


def damaged_files(manifest) -> List[str]:
    """The files a batch counts as unreadable: the unmerged ones the scan could not read
    (``"corrupt: ..."``) and the damaged frames it placed in their sets
    (:mod:`hdrcl.shoot.grouping.damaged`; such a set fails naming the file)."""
    out = [f for u in manifest.unmerged if u.reason.startswith("corrupt") for f in u.files]
    for s in manifest.sets:
        names = set((s.extra or {}).get("damaged") or ())
        out += [f for f in s.files if os.path.basename(f) in names]
    return out


def check_manifest(manifest) -> Dict[int, str]:
    """What would stop each set of a (hand-edited) manifest from merging, by index.

    Reads the frames' headers only: a missing or unreadable file, or a group that
    :func:`hdrcl.shoot.grouping.rules.unmergeable_reason` rejects (single frame, one exposure,
    mixed cameras...). Exposures written in the manifest replace the EXIF times.

    Returns
    -------
    dict of int to str
        Only the sets with a problem.
    """
    from hdrcl.io.frames import read_info
    from hdrcl.shoot.grouping.rules import unmergeable_reason

    from hdrcl.shoot.batch.claims import check_regular

    problems = {}
    for s in manifest.sets:
        infos = []
        for f in s.files:
            try:
                check_regular(f)  # a FIFO would block the header read
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


def _group_of(info, folder: str = "") -> str:
    """Response group of a set from its first frame: camera body and ISO. Frames without
    camera make and model (converted PNG or TIFF, film scans) count as one camera in one
    shoot unless they differ in size (either orientation) or bit depth: their folders
    share one pooled curve, so overlapping views of one scene read alike (issue 32). The
    group then says so: ``unknown camera 1600x1200 8-bit``. (``folder`` is not used.)"""
    if info is None:
        return "unreadable"
    label = _camera_label(info)
    if label == "unknown camera":
        label += f" {max(info.width, info.height)}x{min(info.width, info.height)} {info.bits}-bit"
    if info.serial:
        label += f" #{info.serial}"
    return f"{label} ISO {info.iso:g}" if info.iso else label


def _folder_label(s, root) -> str:
    """The set's folder relative to the scanned ``root`` (its name when it is the root or
    outside it)."""
    folder = set_folder(s)
    if root:
        rel = os.path.relpath(folder, os.path.abspath(root))
        if rel != "." and not rel.startswith(".."):
            return rel.replace(os.sep, "/")
    return os.path.basename(folder) or "root"


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




def _camera_references(sets, firsts, groups, reference, given=None) -> Dict[str, float]:
    """One reference exposure per camera (response group) for the whole shoot, so that
    every set of a camera comes out on one radiometric scale (:mod:`hdrcl.core.encode`):
    ``given``, else the power of two nearest the median of the camera's exposures across
    its sets, on the shoot's scale (f-number and ISO of ``reference``). Groups whose
    frames name no camera (converted frames, grouped by folder: one folder per set of a
    scene, say) share one reference, taken over all of them: nothing tells their
    cameras apart, and a scene shot as two folders must come out on one scale."""
    from hdrcl.core.encode import default_reference

    by_index = {s.index: s for s in sets}
    ref_n, ref_iso = reference

    def times_of(indices) -> list:
        times = []
        for i in indices:
            info = firsts.get(i)
            k = 1.0
            if info is not None and ref_n and info.fnumber and info.fnumber > 0:
                k *= (ref_n / info.fnumber) ** 2
            if info is not None and ref_iso and info.iso and info.iso > 0:
                k *= info.iso / ref_iso
            exposures = list(by_index[i].exposures) or (
                [info.exposure_time] if info is not None and info.exposure_time else [])
            times += [float(t) * k for t in exposures if t and t > 0]
        return times

    if given is not None:
        return {group: float(given) for group in groups}
    anonymous = [g for g, indices in groups.items()
                 if not any(firsts.get(i) is not None and (firsts[i].make or firsts[i].model) for i in indices)]
    shared = times_of([i for g in anonymous for i in groups[g]])
    out = {}
    for group, indices in groups.items():
        times = shared if group in anonymous else times_of(indices)
        if times:
            out[group] = default_reference(times)
    return out


def _references_of_one_set(firsts, groups, given=None) -> set:
    """The groups whose reference exposure :func:`_camera_references` takes from one set's
    labels alone (a camera with one set in the shoot; the shoot's only camera-less set):
    that set's merge takes it from the exposures it measured instead, so that one wrong
    label does not move the whole map (:func:`hdrcl.shoot.batch.setrun.set_plan`)."""
    if given is not None:
        return set()
    named = {g for g, indices in groups.items()
             if any(firsts.get(i) is not None and (firsts[i].make or firsts[i].model) for i in indices)}
    anonymous_sets = sum(len(indices) for g, indices in groups.items() if g not in named)
    return {g for g, indices in groups.items() if len(indices) == 1 and (g in named or anonymous_sets == 1)}


@dataclass
class _Plan:
    jobs: Dict[int, SetJob]
    selected: List[SetJob]
    reference: Tuple[Optional[float], Optional[float]]
    groups: Dict[str, List[int]]
    firsts: Dict[int, object] = field(default_factory=dict)  # each set's first header (None: unreadable)


def _plan(manifest, out_dir: str, options: BatchOptions, ranges, name: Optional[str] = None) -> _Plan:
    from hdrcl.io.frames import read_info
    from hdrcl.shoot.batch.claims import check_regular

    sets = sorted(manifest.sets, key=lambda s: s.index)
    stems = output_stems(manifest, name)
    firsts, listed_fn = {}, {}
    for s in sets:
        try:
            check_regular(s.files[0])  # a FIFO would block the header read
            info = read_info(s.files[0])
        except (InputError, OSError) as exc:  # the set fails later with its own reason
            logger.debug("set %d: first frame unreadable: %s", s.index, exc)
            info = None
        if info is not None and not info.fnumber and s.fnumber:
            # The f-number of an exposure list (or a hand-edited manifest) where EXIF has none.
            listed_fn[s.index] = float(s.fnumber)
            info = replace(info, fnumber=float(s.fnumber))
        firsts[s.index] = info
    reference = _reference([firsts[s.index] for s in sets])
    jobs, groups = {}, {}
    group_of = {s.index: _group_of(firsts[s.index], _folder_label(s, manifest.root)) for s in sets}
    for s in sets:
        groups.setdefault(group_of[s.index], []).append(s.index)
    exposure_refs = _camera_references(sets, firsts, groups, reference, options.reference_exposure)
    own_refs = _references_of_one_set(firsts, groups, options.reference_exposure)
    for s in sets:
        group = group_of[s.index]
        stem = os.path.join(out_dir, stems[s.index])
        jobs[s.index] = SetJob(index=s.index, files=[os.path.abspath(f) for f in s.files],
                               exposures=[float(t) for t in s.exposures], output=f"{stem}.{options.output_format}",
                               preview=stem + ".jpg" if options.preview else None, group=group,
                               reference=reference, exposure_ref=exposure_refs.get(group),
                               exposure_ref_own=group in own_refs, fnumber=listed_fn.get(s.index),
                               findings=tuple(set_findings(s)),
                               damaged=tuple(sorted(dict((s.extra or {}).get("damaged") or {}).items())))
    selected = [jobs[s.index] for s in select_sets(sets, ranges)]
    return _Plan(jobs=jobs, selected=selected, reference=reference, groups=groups, firsts=firsts)


def _written_files(plan: _Plan, out_dir: str, *, report_path: str, report_dir: Optional[str],
                   responses: bool, response_dir: Optional[str] = None) -> List[Tuple[str, str]]:
    """Every file a run of ``plan`` may write, with what it is: outputs, previews, claim
    files, the groups' responses (when calibrated here), the JSON report and the
    quality report's files."""
    from hdrcl.report.inputs import file_stem
    from hdrcl.report.pages import INDEX_NAME

    out: List[Tuple[str, str]] = [(report_path, "JSON report")]
    for job in plan.selected:
        stem = os.path.splitext(os.path.basename(job.output))[0]
        out.append((job.output, "output"))
        if job.preview is not None:
            out.append((job.preview, "preview"))
        out.append((os.path.join(out_dir, f".{stem}.claim"), "claim file"))
        if report_dir is not None:
            fs = os.path.join(report_dir, file_stem(stem))
            out += [(fs + tail, "quality report") for tail in
                    (".json", "-preview.jpg", "-response.svg", "-histogram.svg", "-coverage.png")]
            out += [(f"{fs}-frame-{n:02d}.jpg", "quality report") for n in range(len(job.files))]
    if responses:
        out += [(response_path(g, response_dir or out_dir), "response")
                for g in sorted({j.group for j in plan.selected})]
    if report_dir is not None:
        out.append((os.path.join(report_dir, INDEX_NAME), "contact sheet"))
    return out


def check_outputs_spare_inputs(manifest, plan: _Plan, out_dir: str, *, report_path: str,
                               report_dir: Optional[str] = None, responses: bool = True,
                               source=None, response_dir: Optional[str] = None) -> None:
    """Refuse, before anything is written, a run that would write over one of its inputs.

    The inputs are every file of the manifest (its sets and the groups it does not
    merge) and the manifest file itself; the outputs are those of
    :func:`_written_files`. Two paths are the same file when ``os.stat`` says so (hard
    links, symbolic links, case-insensitive file systems) or, for a file not written
    yet, when their normalised real paths are equal. ``hdrcl batch SHOOT -o SHOOT``
    would otherwise replace each set's first JPEG by its preview.

    Raises
    ------
    UsageError
        One line naming the first output that is also an input.
    """
    inputs = [f for s in manifest.sets for f in s.files] + [f for u in manifest.unmerged for f in u.files]
    if source is not None and isinstance(source, (str, os.PathLike)) and os.path.isfile(source):
        inputs.append(os.fspath(source))
    ids, names = {}, {}
    for f in inputs:
        f = os.path.abspath(os.fspath(f))
        names.setdefault(os.path.normcase(os.path.realpath(f)), f)
        try:
            st = os.stat(f)
        except OSError:
            continue
        ids.setdefault((st.st_dev, st.st_ino), f)
    for path, what in _written_files(plan, out_dir, report_path=report_path, report_dir=report_dir,
                                     responses=responses, response_dir=response_dir):
        hit = names.get(os.path.normcase(os.path.realpath(path)))
        if hit is None:
            try:
                st = os.stat(path)
            except OSError:
                continue
            hit = ids.get((st.st_dev, st.st_ino))
        if hit is not None:
            raise UsageError(f"{path}: the {what} would overwrite the input {hit}; "
                             "choose another output folder")


# --------------------------------------------------------------------- loading sets
def _shoot_scale(exposures, reference) -> Tuple[float, List[str]]:
    """Factor from a set's own exposure scale to the shoot's, and notes on it.

    :func:`hdrcl.io.metadata.relative_exposures` expresses a set's exposures at its first
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
