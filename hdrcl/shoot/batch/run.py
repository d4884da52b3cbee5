"""Merging a whole shoot: every bracket set of a manifest, once, safely, in parallel.

``hdrcl batch`` is a thin layer over :func:`run_batch`. What it guarantees, and how:

**One response per camera body and ISO.** Sets are grouped by the first frame's
camera (make, model, serial) and ISO. Each group's curve is solved once from samples
pooled across the group's sets (:func:`hdrcl.core.solve.recover_response_pooled`) and
saved beside the outputs as ``<camera>_ISO_<n>.response.json`` (a set without camera
make and model is its folder's: ``<folder>.response.json``); ``--response`` gives one
curve for everything instead, ``--response-cache DIR`` keeps the curves in DIR and uses
one found there as it is. The pool is chosen from the *whole manifest*, never from
the sets selected for this run (at most :data:`MAX_POOL_SETS` sets, evenly spaced in
index order), and the solve is deterministic, so every farm chunk, Dask worker or
rerun arrives at the same curve. A saved curve whose recorded calibration key (the
pooled files' contents and the solve's parameters) still matches is loaded instead
of solved again; chunks running at the same moment each solve and write the same
file atomically. A camera with a single set in the manifest is solved by that set's
merge, from the sampling grid of the decode that also feeds its fusion, so its frames
are decoded once (:func:`hdrcl.shoot.batch.pooling.solve_deferred`); the set digests name the
calibration key, so a curve solved either way or loaded from its file gives the same
digests. The curve used is always the one as written to JSON (rounded the same
way), so a loaded curve and a freshly solved one give identical outputs.

**One exposure scale for the shoot.** Every frame's effective exposure is taken
relative to one reference f-number and ISO for the whole manifest (the most common
first-frame setting; ties go to the lower set index), so the radiance of all sets is
in the same units and the sets of a panorama match. Each output records
``hdrcl:evOffset``: ``log2`` of the factor between its units and those of ``hdrcl
merge`` on the same frames (``merge`` = ``batch * 2**evOffset``), and
``hdrcl:exposureRef``, the reference (``"f/8 ISO 100"``).

**Idempotent and crash-safe.** Each set has an identity: SHA-256 over the contents of
its frames (every byte of each file, hashed with XXH3-128 where ``xxhash`` is installed), the manifest's exposures, the shoot's reference, the response curve, the
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
(:func:`hdrcl.core.pipeline.stream_merge`): decoding the next strip, fusing the current one
on the OpenCL device and encoding the previous one overlap, and memory does not grow
with the image. Meanwhile a read-ahead thread hashes the next set, checks its outputs
and reads its headers, and each set's tail (preview, deliverables, the EXR moved into
place, its record and report) runs on a commit thread while the next set fuses
(:mod:`hdrcl.shoot.batch.overlap`). One OpenCL context and built program serve the process.
``jobs > 1`` runs sets in worker processes (``spawn``: each worker makes its own OpenCL
context once); ``scheduler`` runs them on a Dask cluster (:mod:`hdrcl.shoot.batch.executors`).

Outputs, named after each set's folder when every set has its own, else after its first
frame, or by a ``name`` template (:func:`output_stems`), go directly into the output
folder: ``<stem>.exr``, ``<stem>.jpg`` (preview) and ``report.json``.

**Quality report** (``BatchOptions.report_dir``, ``--report DIR``). Whoever merges a set
(this process, a worker process, a Dask worker) measures it (:func:`hdrcl.report.quality.measure`
on the frames kept as they stream past: whole when they fit
:func:`hdrcl.core.bracket.memory_budget`, else the sampling grid; the radiance reduced for the
preview) and writes its files into the folder (:func:`hdrcl.report.pages.write_set_report`),
after its EXR is committed; the figures also go into ``report.json`` under
``quality``. A skipped set keeps its report when it was written for the same digest,
else it is measured again from its frames and EXR. At the end, :func:`run_batch` writes
``index.html`` over every set of the manifest. The EXRs and previews are the same bytes
with or without a report.

This module does not import click, OpenImageIO or pyopencl directly.
"""
from __future__ import annotations

import contextlib
import logging
import os
import threading
import time as _time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Callable, Dict, List, Optional, Sequence, Tuple, Union

from hdrcl.errors import ProcessingError, UsageError
from hdrcl.shoot.batch.claims import Cancelled, cancel_signals, remove_orphan_temps
from hdrcl.shoot.batch.jobs import (
    REPORT_NAME,
    STATUS_FAILED,
    BatchOptions,
    BatchReport,
    SetJob,
    SetResult,
    _Context,
    _reference_text,
)
from hdrcl.shoot.batch.plan import _plan, check_outputs_spare_inputs, damaged_files, load_source, parse_sets
from hdrcl.shoot.batch.pooling import _prepare_responses
from hdrcl.shoot.batch.setquality import _contact_sheet
from hdrcl.shoot.batch.overlap import Committer
from hdrcl.shoot.batch.setrun import _failed, _Opening, _read_stage, process_set
from hdrcl.shoot.batch.state import (
    _atomic_json,
    _merge_entries,
    _remove_stale_temps,
    _report_lock,
)

logger = logging.getLogger(__name__)




#: How long the read-ahead waits for the set before it to be taken before it gives up
#: decoding the next one ahead (the merge takes it when it opens its frames, or drops it
#: after its turn): a bound, never reached by a merge that runs.
AHEAD_WAIT_SECONDS = 600.0


def _run_pipelined(jobs: List[SetJob], ctx: _Context, emit: Callable[[SetResult], None]) -> None:
    """Run sets in this process, hashing and opening the next set during the merge.

    The merge itself overlaps decoding, fusion (on this thread, which owns the
    OpenCL queue) and encoding strip by strip; each set's tail (preview, deliverables,
    the EXR's rename, its record and quality report) runs on a commit thread while the
    next set opens and fuses (:mod:`hdrcl.shoot.batch.overlap`: one set committing at a
    time, within the memory budget, results in set order); the read-ahead thread meanwhile hashes
    the next set's files, checks whether its outputs are current and reads its
    headers, so consecutive sets follow each other without a gap; and a set that needs
    merging has its frames decoded ahead on a low-priority thread, within the memory
    budget (:mod:`hdrcl.io.ahead`), in the cycles the current set leaves.
    """
    if not jobs:
        return
    started: Dict[int, float] = {}

    def read(job, ahead: bool):
        started[job.index] = _time.perf_counter()
        step = _read_stage(job, ctx)
        if ahead and isinstance(step, _Opening) and wait_turn(stop, timeout=AHEAD_WAIT_SECONDS):
            # Decode its frames too, at low priority, while the current set fuses and encodes
            # (once the merge before has taken its own: one set ahead at a time).
            decode_ahead(job.files, step.opened.infos, open_reader, stop)
        return step

    from functools import partial

    from hdrcl.io.ahead import cancel_all, decode_ahead, discard, wait_turn
    from hdrcl.io.reader import BracketReader

    open_reader = partial(BracketReader, ahead=False)
    stop = threading.Event()  # set before cancel_all: a read still running starts nothing after it

    reader = ThreadPoolExecutor(1, thread_name_prefix="hdrcl-readahead")
    # Set n's tail (preview, deliverables, the EXR's last strips and rename, its record and
    # report) on one commit thread while set n+1 starts here (hdrcl.shoot.batch.overlap).
    committer = Committer(ctx, emit)
    ok = False
    try:
        ahead = reader.submit(read, jobs[0], False)
        for i in range(len(jobs)):
            step = ahead.result()
            if i + 1 < len(jobs):
                ahead = reader.submit(read, jobs[i + 1], True)
            if isinstance(step, _Opening):
                committer.make_room(step)
                step = committer.merge(step, started[jobs[i].index])  # None: committing on its thread
            discard(jobs[i].files)  # decoded ahead or held but never opened (up to date, merged elsewhere, failed)
            if step is None:
                continue
            committer.drain()  # the set before, first: results in set order
            step.seconds["total"] = _time.perf_counter() - started[step.index]
            emit(step)
        committer.drain()
        ok = True
    finally:
        # Cancelled: do not wait for the read-ahead of a set that will not be merged.
        stop.set()
        reader.shutdown(wait=False, cancel_futures=True)
        try:
            committer.close(cancelled=not ok)  # a commit in progress stops and undoes its set
        finally:
            cancel_all()  # frames decoded ahead for a set that will not be merged: dropped


# --------------------------------------------------------------------------- run
@dataclass
class RunSettings:
    """How :func:`run_batch` runs (its keywords besides the source, output, options,
    selection, response and progress).

    Attributes
    ----------
    jobs : int
        Worker processes; 1 runs the pipeline in this process. The workers are
        started with ``spawn``, so a script calling this with ``jobs > 1`` needs the
        ``if __name__ == "__main__":`` guard. 1 is the default because it measured
        fastest on a 2-core machine (``scripts/batch_pipeline_bench.py SHOOT`` and
        ``scripts/shoot_bench.py``: ``--jobs 2`` took 8-50 % longer, the workers'
        decoders, OpenCL pools and encoders fighting for the same two cores, each
        worker with half the memory budget); one process already overlaps decoding,
        fusion and encoding, and decodes the next set ahead.
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
    times_file : path, optional
        Exposure list (HDRShop ``image_list.txt`` or ``file seconds`` lines) for frames
        without EXIF; lists named ``image_list.txt`` or ``times.txt`` beside the frames
        are found without it.

    handle_signals : bool
        Install handlers for SIGTERM and SIGINT for the duration of the run (the CLI
        does); by default the caller's handlers are left alone.
    name : str, optional
        Output name template (``--name``; fields ``{folder}``, ``{first}``, ``{date}``,
        ``{index}``, ``{camera}``, :func:`hdrcl.shoot.batch.setnames.output_stems`) [default:
        ``{folder}`` when every set has a folder of its own, else ``{first}``].
    response_cache : path, optional
        Folder of responses, one per camera group (``<group>.response.json``): one found
        there that fits the frames' bit depth is used as it is; otherwise the group is
        calibrated as usual and its curve written there (instead of into ``out_dir``).
    """

    jobs: int = 1
    scheduler: object = None
    retries: int = 2
    force: bool = False
    report: Union[str, os.PathLike, None] = None
    calibrate_only: bool = False
    recursive: bool = False
    frames_per_set: Optional[int] = None
    gap: Optional[float] = None
    times_file: Union[str, os.PathLike, None] = None
    handle_signals: bool = False
    name: Optional[str] = None
    response_cache: Union[str, os.PathLike, None] = None


def run_batch(source, out_dir, *, options: Optional[BatchOptions] = None,
              sets: Union[str, Sequence[Tuple[int, Optional[int]]], None] = None, response=None,
              progress: Optional[Callable[[Optional[SetResult], int, int], None]] = None,
              **settings) -> BatchReport:
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
    progress : callable, optional
        ``progress(result, completed, total)``; called once with ``result=None``
        before the first set, then after each set.
    settings
        :class:`RunSettings`: ``jobs``, ``scheduler``, ``retries``, ``force``, ``report``,
        ``calibrate_only``, ``recursive``, ``frames_per_set``, ``gap``, ``times_file``,
        ``handle_signals``, ``name``, ``response_cache``.

    With ``handle_signals`` (in the main thread), SIGTERM and SIGINT stop the run
    within a couple of seconds: worker processes are killed, temporary files of
    unfinished sets removed, and the report written for the sets that finished;
    ``BatchReport.cancelled`` holds the signal (exit code 143 or 130). Without it, an
    exception raised while the sets run (``KeyboardInterrupt`` from Ctrl-C, or
    whatever the caller's handler raises) kills the worker processes, removes the
    temporary files of unfinished sets and reaches the caller; no report is written.

    Returns
    -------
    BatchReport

    Raises
    ------
    InputError
        The folder or manifest cannot be read, or the response file is unreadable.
    UsageError
        Conflicting options or an unusable output folder.
    ProcessingError
        Nothing to merge: the folder holds no photographs, or no bracket set (the
        message names the frames and why), or the manifest lists no set. Raised before
        the output folder is created (exit code 1 on the command line).
    """
    t_start = _time.perf_counter()
    options = options or BatchOptions()
    s = RunSettings(**settings)  # TypeError naming an unknown keyword
    _check_run(options, s, response)
    # With handle_signals, SIGTERM / Ctrl-C raise Cancelled in the main thread from here on.
    with cancel_signals(install=s.handle_signals), _dropping_held():
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
        manifest = _manifest(source, s.recursive, s.frames_per_set, s.gap, s.times_file,
                             [out_dir] + ([report_dir] if report_dir else []))
        plan = _plan(manifest, out_dir, options, ranges, s.name)  # before any folder: a bad --name is exit 2
        cache = os.path.abspath(os.fspath(s.response_cache)) if s.response_cache is not None else None
        _make_folders(((out_dir, "output"), (report_dir, "report"), (cache, "response cache")))
        report_path = os.path.abspath(os.fspath(s.report)) if s.report is not None else \
            os.path.join(out_dir, REPORT_NAME)
        check_outputs_spare_inputs(manifest, plan, out_dir, report_path=report_path, report_dir=report_dir,
                                   responses=response is None, source=source, response_dir=cache)
        logger.info("%d set(s) in the manifest, %d selected; reference %s", len(plan.jobs), len(plan.selected),
                    _reference_text(plan.reference))
        # A camera with one set in the manifest is calibrated by that set's merge, from the
        # decode that feeds its fusion (each frame decoded once).
        responses = _prepare_responses(plan, out_dir, options, response, defer=not s.calibrate_only, cache=cache,
                                       hold=_pipelined(s, plan))  # frames decoded to calibrate serve the merges
        unreadable = damaged_files(manifest) if ranges is None else []
        rep = BatchReport(unmerged=[{"files": [os.path.abspath(f) for f in u.files], "reason": u.reason}
                                    for u in manifest.unmerged],
                          responses=[responses[g] for g in sorted(responses)], unreadable=unreadable,
                          reference=plan.reference, sets_in_manifest=len(plan.jobs))
        if s.calibrate_only:
            rep.seconds = _time.perf_counter() - t_start
            return rep
        _remove_stale_temps(out_dir, [os.path.splitext(os.path.basename(j.output))[0] for j in plan.selected])
        ctx = _Context(options=options, responses=responses, force=s.force)
        results = _run_sets(plan, ctx, s, rep, out_dir, progress)
        rep.results = sorted(results, key=lambda r: r.index)
        _write_report(rep, plan, report_path, report_dir)
        rep.seconds = _time.perf_counter() - t_start
        return rep


def _check_run(options: BatchOptions, s: RunSettings, response) -> None:
    """The run's own options, before anything is read (the merge options were checked
    when ``options`` was made)."""
    if s.jobs < 1:
        raise UsageError(f"--jobs must be at least 1, not {s.jobs}")
    if response is not None and s.response_cache is not None:
        raise UsageError("--response and --response-cache exclude each other: the given curve serves every set")
    if s.scheduler is not None and s.jobs > 1:
        raise UsageError("--jobs and --scheduler exclude each other: the Dask cluster decides the parallelism")
    if options.preview_size < 16:
        raise UsageError("--preview-size must be at least 16 pixels")
    for line in options.merge.ignored(chain=bool(options.luminance)):
        logger.warning("%s", line)


def _make_folders(folders) -> None:
    for folder, what in folders:
        if folder is None:
            continue
        try:
            os.makedirs(folder, exist_ok=True)
        except OSError as exc:
            raise UsageError(f"{folder}: cannot create the {what} folder ({exc.strerror or exc})") from None


@contextlib.contextmanager
def _dropping_held():
    """Whatever ends the run, the frames the pooled calibration held for the sets' merges
    (and any set decoded ahead) are dropped: an error before the sets' loop left them
    held in a long-lived process (:mod:`hdrcl.io.ahead`)."""
    try:
        yield
    finally:
        from hdrcl.io.ahead import cancel_all

        cancel_all()


def _pipelined(s: RunSettings, plan) -> bool:
    """Whether the sets run in this process (:func:`_run_pipelined`, as :func:`_run_sets` decides)."""
    return not s.calibrate_only and s.scheduler is None and (s.jobs <= 1 or len(plan.selected) <= 1)


def _run_sets(plan, ctx: _Context, s: RunSettings, rep: BatchReport, out_dir: str, progress) -> List[SetResult]:
    """Every selected set, in this process, worker processes or on a Dask cluster; a
    cancel stops the run with the results so far (``rep.cancelled``)."""
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
    stems = [os.path.splitext(os.path.basename(j.output))[0] for j in plan.selected]
    try:
        if s.scheduler is not None:
            from hdrcl.shoot.batch.executors import run_dask

            run_dask(plan.selected, ctx, s.scheduler, emit, task=process_set, failed=_failed, retries=s.retries)
        elif s.jobs > 1 and total > 1:
            from hdrcl.shoot.batch.executors import run_processes

            run_processes(plan.selected, ctx, emit, task=process_set, failed=_failed, jobs=min(s.jobs, total))
        else:
            _run_pipelined(plan.selected, ctx, emit)
    except Cancelled as exc:
        rep.cancelled = exc.signum
        # Said once, by the caller (the CLI's one line; rep.cancelled for the API).
        logger.info("%s: %d of %d set(s) finished; stopping", exc, len(results), total)
        # The workers are dead and their claims released: their temporary files go.
        remove_orphan_temps(out_dir, stems)
    except BaseException:
        # KeyboardInterrupt in API mode (or the caller's own signal exception): the
        # workers are dead; clean up after them and let the caller have it.
        remove_orphan_temps(out_dir, stems)
        raise
    return results


def _write_report(rep: BatchReport, plan, report_path: str, report_dir) -> None:
    """report.json (merged with earlier runs' entries) and the contact sheet, under the lock."""
    if not os.path.isdir(os.path.dirname(report_path)):
        raise UsageError(f"{report_path}: report folder does not exist")
    with _report_lock(os.path.dirname(report_path)):
        rep.entries = _merge_entries(report_path, rep.results, plan)
        _atomic_json(report_path, rep.to_dict())
        if report_dir is not None:
            # Under the report's lock: of chunks finishing together, the last one to
            # write the contact sheet sees every other's sets.
            rep.quality_report = _contact_sheet(plan, rep.entries, report_dir, rep.unmerged)
    rep.path = report_path


def describe_batch(source, out_dir, *, options: Optional[BatchOptions] = None, sets=None, response=None,
                   response_cache=None, name: Optional[str] = None, recursive: bool = False,
                   frames_per_set: Optional[int] = None, gap: Optional[float] = None, times_file=None) -> dict:
    """What :func:`run_batch` would do with the same arguments, without merging or writing
    anything (``hdrcl batch --dry-run``): per selected set its frames, exposure span,
    output, response and how that is calibrated.

    Returns
    -------
    dict
        ``{"sets": [...], "unmerged": [...], "reference": "f/8 ISO 100"}``; each set has
        ``index``, ``frames``, ``first``, ``last``, ``exposures`` (``[shortest, longest]``
        seconds, or None when EXIF decides at merge time), ``output``, ``preview``,
        ``response`` (group, file, source: given / cached / saved / calibrate) and
        ``calibration`` (``given``, ``cached``, ``own`` or ``pooled`` with its sets).

    Raises
    ------
    As :func:`run_batch` before it writes anything.
    """
    from hdrcl.shoot.batch.pooling import _unopened, decide_responses
    from hdrcl.shoot.batch.setrun import set_plan

    options = options or BatchOptions()
    if response is not None and response_cache is not None:
        raise UsageError("--response and --response-cache exclude each other: the given curve serves every set")
    ranges = parse_sets(sets) if isinstance(sets, str) else (list(sets) if sets is not None else None)
    out_dir = os.path.abspath(os.fspath(out_dir))
    report_dir = os.path.abspath(options.report_dir) if options.report_dir else None
    manifest = _manifest(source, recursive, frames_per_set, gap, times_file,
                         [out_dir] + ([report_dir] if report_dir else []))  # as run_batch
    plan = _plan(manifest, out_dir, options, ranges, name)
    cache = os.path.abspath(os.fspath(response_cache)) if response_cache is not None else None
    check_outputs_spare_inputs(manifest, plan, out_dir, report_path=os.path.join(out_dir, REPORT_NAME),
                               report_dir=report_dir, responses=response is None, source=source,
                               response_dir=cache or out_dir)
    # The run's own decision (run_batch defers a camera's only set to its merge), and each
    # set's merge plan made from it as the run makes it, its frames not opened.
    decided = decide_responses(plan, out_dir, options, response, defer=True, cache=cache)
    ctx = _Context(options=options, responses={g: gp.entry for g, gp in decided.items()})
    rows = []
    for job in plan.selected:
        d = set_plan(_Opening(job, None, _unopened(job), {}), ctx).describe()
        times = [t for t in job.exposures if t > 0]
        rows.append({"index": job.index, "frames": len(d["files"]), "first": d["files"][0],
                     "last": d["files"][-1], "exposures": [min(times), max(times)] if times else None,
                     "output": d["output"], "preview": job.preview, **decided[job.group].describe()})
    return {"sets": rows, "reference": _reference_text(plan.reference),
            "unmerged": [{"files": [os.path.abspath(f) for f in u.files], "reason": u.reason}
                         for u in manifest.unmerged]}


def _manifest(source, recursive, frames_per_set, gap, times_file, exclude):
    """The source's manifest with at least one set (else ProcessingError: one line, and
    no output folder or report)."""
    manifest = load_source(source, recursive=recursive, frames_per_set=frames_per_set, gap=gap,
                           exclude=exclude, times_file=times_file)
    if not manifest.sets:
        raise ProcessingError(nothing_to_merge(source, manifest, recursive))
    return manifest


def nothing_to_merge(source, manifest, recursive: bool = False) -> str:
    """Why a source yields no bracket set, in one line naming it: no photographs (and
    what the folder holds instead), or the groups it did find and why each is not a set
    (a single frame without an exposure time says so)."""
    name = os.fspath(source) if isinstance(source, (str, os.PathLike)) else "manifest"
    if not os.path.isdir(name):
        return f"{name}: the manifest lists no bracket set"
    if manifest.unmerged:
        parts = []
        for u in manifest.unmerged[:3]:
            reason = u.reason
            if reason == "single frame" and _lacks_exposure(u.files[0]):
                reason = "single frame, without an exposure time (EXIF ExposureTime or a times file)"
            more = f" (+{len(u.files) - 1} more)" if len(u.files) > 1 else ""
            parts.append(f"{os.path.basename(u.files[0])}{more}: {reason}")
        rest = f"; {len(manifest.unmerged) - 3} more group(s)" if len(manifest.unmerged) > 3 else ""
        return f"{name}: no bracket sets to merge ({'; '.join(parts)}{rest})"
    from hdrcl.shoot.scan import DEFAULT_EXTENSIONS

    try:
        entries = sorted(os.scandir(name), key=lambda e: e.name)
    except OSError:
        entries = []
    files = [e.name for e in entries if not e.name.startswith(".") and e.is_file()]
    folders = [e.name for e in entries if not e.name.startswith(".") and e.is_dir()]
    kinds = ", ".join(e.lstrip(".").upper() for e in DEFAULT_EXTENSIONS[:5])
    if files:
        what = f"{len(files)} other file(s), such as {files[0]}"
    elif folders:  # a folder with photographs in its subfolders is scanned with them
        what = f"only subfolders without photographs ({folders[0]}{', ...' if len(folders) > 1 else ''})"
    else:
        what = "it is empty"
    return f"{name}: no photographs to merge ({kinds} or camera RAW); {what}"


def _lacks_exposure(path) -> bool:
    try:
        from hdrcl.io.frames import read_info

        return read_info(path).exposure_time is None
    except Exception:  # unreadable: the scan said so already
        return False
