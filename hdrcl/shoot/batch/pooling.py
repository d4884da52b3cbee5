"""One response per camera body and ISO for a batch: the pool of sets it is solved from,
the solve, and the saved curve reused while its calibration key matches.
"""
from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import dataclass, replace
from typing import Dict, List, Sequence, Tuple

import numpy as np

from hdrcl.core.exposure.fit import UNTRUSTED
from hdrcl.core.response import Response
from hdrcl.core.response_cache import misfit
from hdrcl.core.sources import GivenResponse
from hdrcl.errors import HdrclError, InputError
from hdrcl.io.jsondoc import read_state
from hdrcl.shoot.batch.jobs import (
    MAX_POOL_SETS,
    BatchOptions,
    ResponseEntry,
    SetJob,
)
from hdrcl.shoot.batch.names import response_path, response_to_read
from hdrcl.shoot.batch.plan import _camera_label, _Plan, _shoot_scale
from hdrcl.shoot.batch.state import (
    DIGEST_RECIPE,
    _atomic_json,
    _file_digest,
    _json_digest,
    response_digest,
)
from hdrcl.version import __version__

logger = logging.getLogger(__name__)


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
    from hdrcl.core.bracket import read_infos
    from hdrcl.io.frames import check_compatible
    from hdrcl.io.metadata import relative_exposures, resolve_exposures

    from hdrcl.shoot.batch.claims import check_regular

    if len(job.files) < 2:
        raise InputError(f"{job.files[0]}: a bracket set needs at least two exposures")
    for f in job.files:
        check_regular(f)  # a FIFO or /dev/zero fails its set at once
    if job.exposures and len(job.exposures) != len(job.files):
        raise InputError(f"set {job.index}: {len(job.exposures)} exposures for {len(job.files)} files")
    infos = read_infos(job.files)
    check_compatible(infos)
    timed = []
    for k, info in enumerate(infos):
        t = job.exposures[k] if job.exposures else info.exposure_time
        if t is None or not t > 0:
            raise InputError(f"{info.path}: no exposure time in EXIF; add \"exposures\" to the set in the manifest")
        timed.append(replace(info, exposure_time=float(t), fnumber=info.fnumber or job.fnumber))
    exposures = resolve_exposures(job.files, timed)
    k, notes = _shoot_scale(exposures, job.reference)
    times = np.asarray(relative_exposures(exposures), np.float64) * k
    t0 = infos[0].capture_time
    stamp = "" if t0 is None else t0.strftime("%Y:%m:%d %H:%M:%S")
    return _Opened(infos=timed, times=times, ev_offset=math.log2(k), notes=notes, stamp=stamp)


def _unopened(job: SetJob) -> _Opened:
    """A set as its job lists it, no frame opened (the dry run's plan of it): no headers,
    the manifest's exposures (when it lists them) as its times, no offset yet."""
    return _Opened(infos=[None] * len(job.files), times=np.asarray(list(job.exposures or []), np.float64),
                   ev_offset=0.0, notes=[], stamp="")


def _calibration_grid(job: SetJob, opened: _Opened, ignore_color, hold: bool = False):
    """The decimated grid of a set that sample selection works on (one streaming read);
    with ``hold``, the frames decoded for it are held for the set's merge
    (:func:`hdrcl.io.ahead.read_and_hold`: in memory, else spilled, within the budget;
    a set beyond it keeps only its grid and its merge decodes it again)."""
    from hdrcl.core.bracket import grid_bracket

    return grid_bracket(list(job.files), opened.infos, opened.times, ignore_color, hold=hold)


# -------------------------------------------------------------------- responses
def _normalised(resp: Response) -> dict:
    """The response as its JSON file holds it (so solved and loaded curves agree)."""
    return json.loads(json.dumps(resp.to_dict()))


def _response_of(entry: ResponseEntry) -> Response:
    resp = _response_cache.get(entry.digest)
    if resp is None:
        resp = Response.from_dict(entry.payload, source=entry.file or entry.group)
        _response_cache[entry.digest] = resp
    return resp


class EntryResponse(GivenResponse):
    """A group's curve as a merge plan's response source: read from its entry when the
    merge asks for it (so a plan of a curve not solved yet, a dry run's, can be made)."""

    def __init__(self, entry: ResponseEntry):
        self.entry = entry
        self.name = os.path.basename(entry.file) if entry.file else entry.group

    @property
    def response(self) -> Response:
        return _response_of(self.entry)


def _pool_of(indices: Sequence[int]) -> List[int]:
    """At most MAX_POOL_SETS indices, evenly spaced, deterministic."""
    idx = sorted(indices)
    if len(idx) <= MAX_POOL_SETS:
        return idx
    m = MAX_POOL_SETS
    return sorted({idx[round(i * (len(idx) - 1) / (m - 1))] for i in range(m)})


def _key_digest(key: str) -> str:
    """The digest of a batch-calibrated response: its calibration key (the pooled files'
    contents and the solve's parameters determine the curve), so a curve solved now, one
    loaded from its file and one its set's merge will solve all give the same set digests."""
    return _json_digest({"calibration": key})


def saved_response(group: str, jobs: List[SetJob], out_dir: str, options: BatchOptions):
    """``(entry, usable sets)``: the group's entry with its calibration key, ``source``
    ``"loaded"`` (and its curve) when the file beside the outputs was saved for this
    very key and reads back, else to be solved (:func:`decide_responses` asks)."""
    path = response_path(group, out_dir)
    entry = ResponseEntry(group=group, file=path, sets=[j.index for j in jobs])
    usable, keyed = [], []
    for j in jobs:
        try:
            keyed.append([j.index, [[os.path.basename(f), _file_digest(f)] for f in j.files], j.exposures])
            usable.append(j)
        except InputError as exc:
            entry.warnings.append(f"set {j.index} not pooled: {exc}")
    # "trust": sets whose exposure metadata cannot be trusted are left out of the pool (a
    # curve saved before that was known is solved again).
    key = _json_digest({"recipe": DIGEST_RECIPE, "hdrcl": __version__, "solve": options.solve_params(),
                        "reference": list(jobs[0].reference) if jobs else None, "sets": keyed, "trust": 1})
    entry.key = key
    found = response_to_read(group, out_dir)  # an older version's hyphenated name too
    saved = read_state(found, "pooled response") or {}  # absent or damaged: solve again
    calib = saved.get("calibration")
    if isinstance(calib, dict) and calib.get("key") == key:
        warns = calib.get("warnings", [])
        try:
            if not isinstance(warns, list) or not all(isinstance(w, str) for w in warns):
                raise InputError(f"{found}: calibration.warnings: expected a list of strings")
            Response.from_dict(saved, source=found)  # validates
        except HdrclError as exc:  # stale or damaged: solve again
            logger.info("%s; the response is solved again", str(exc).splitlines()[0])
        else:
            entry.payload = {k: v for k, v in saved.items() if k != "calibration"}
            entry.digest = _key_digest(key)
            entry.source = "loaded"
            entry.file = found
            entry.warnings += warns
            _restore_trust(entry, calib)
    return entry, usable


def _solve_pool(entry: ResponseEntry, usable: List[SetJob], options: BatchOptions, grids=None,
                hold=frozenset()) -> ResponseEntry:
    """Solve the pooled response of ``usable`` (their sampling grids read here, or given
    as ``grids``: ``{index: (infos, (frames, times, valid), paths)}``) and save it with its key.
    The frames of the sets ``hold`` (indices) read here are held for their merges, so that
    each frame is decoded once (:func:`_calibration_grid`)."""
    from hdrcl.core.solve import recover_response_pooled

    from hdrcl.core.bracket import Bracket

    group, path, key = entry.group, entry.file, entry.key
    brackets, pooled, first_info = [], [], None
    for j in usable:
        if grids is not None:
            infos, grid, paths = grids[j.index]
            frames, times, valid = grid
            if not len(frames) == len(paths) == len(infos):
                raise HdrclError(f"set {j.index}: {len(frames)} frames on the grid for {len(paths)} paths")
            br = Bracket(frames=list(frames), times=times, valid=[valid] * len(frames), paths=list(paths),
                         infos=list(infos), grid=True)
        else:
            try:
                opened = _open_set(j)
                br = _calibration_grid(j, opened, options.ignore_color, hold=j.index in hold)
            except HdrclError as exc:
                entry.warnings.append(f"set {j.index} not pooled: {str(exc).splitlines()[0]}")
                continue
            infos = opened.infos
        first_info = first_info or infos[0]
        verdict = set_verdict(br, options)
        if verdict is not None:
            entry.untrusted[j.index] = list(verdict)
        brackets.append((br.frames, br.times, br.valid_all))
        pooled.append(j.index)
    good = [k for k, i in enumerate(pooled) if i not in entry.untrusted]
    if good and len(good) < len(pooled):
        # A set whose times cannot be trusted would bend the camera's curve: the good sets alone shape it.
        for i in pooled:
            if i in entry.untrusted:
                entry.warnings.append(f"set {i} not pooled: {UNTRUSTED} (its findings say why)")
        brackets, pooled = [brackets[k] for k in good], [pooled[k] for k in good]
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
    entry.digest = _key_digest(key)
    entry.source = "calibrated"
    entry.sets = pooled
    entry.warnings += list(resp.warnings)
    saved = dict(entry.payload)
    saved["calibration"] = {"key": key, "group": group, "pooled_sets": pooled, "warnings": entry.warnings,
                            "untrusted": {str(i): v for i, v in sorted(entry.untrusted.items())}}
    _atomic_json(path, saved)
    logger.info("%s: response calibrated from sets %s -> %s", group, pooled, path)
    return entry


# ------------------------------------------------------------------------ trust
def set_verdict(bracket, options: BatchOptions):
    """``(verdict, span)`` when a set's exposure metadata cannot be trusted (what
    ``hdrcl calibrate`` of its frames would warn, :func:`hdrcl.core.calibrate.metadata_verdict`,
    and the span in decades of its own curve), else None. ``bracket``: its sampling grid."""
    from hdrcl.core.calibrate import metadata_verdict

    try:
        verdict, span = metadata_verdict(bracket, samples=options.samples, smoothness=options.smoothness,
                                         weight=options.weight, seed=options.seed,
                                         fit_exposures=options.fit_exposures,
                                         exposure_tolerance=options.exposure_tolerance)
    except HdrclError as exc:  # nothing to measure: the pool's solve or the merge says so
        logger.debug("trust check: %s", exc)
        return None
    return None if verdict is None else (verdict, round(span, 4))


def _restore_trust(entry: ResponseEntry, calib: dict) -> None:
    """The pooled sets and the untrusted ones of a saved calibration (a loaded curve)."""
    pooled = calib.get("pooled_sets")
    if isinstance(pooled, list) and pooled and all(isinstance(i, int) for i in pooled):
        entry.sets = list(pooled)
    for k, v in (calib.get("untrusted") or {}).items() if isinstance(calib.get("untrusted"), dict) else ():
        if str(k).isdigit() and isinstance(v, list) and len(v) == 2 and isinstance(v[0], str) \
                and isinstance(v[1], (int, float)):
            entry.untrusted[int(k)] = [v[0], float(v[1])]


def _sets_text(indices) -> str:
    idx = sorted(indices)
    return ("set " if len(idx) == 1 else "sets ") + ", ".join(str(i) for i in idx)


def trust_findings(entry: "ResponseEntry | None", job: SetJob, grid=None,
                   options: "BatchOptions | None" = None) -> list:
    """The findings on a set's exposure metadata (:class:`hdrcl.core.findings.Finding`,
    check ``exposure``), as its merge with its group's curve is to report them.

    A set the pool checked carries its verdict on ``entry``; one the pool's sample left
    out is checked now, on the merge's sampling ``grid``. A set whose metadata cannot be
    trusted is a ``note`` when the curve comes from good sets of its camera (its exposures
    are then measured through that curve), a ``check`` when there is none (the curve is
    its own, or that of sets no better). Given and cached curves are not asked about.
    """
    from hdrcl.core.exposure.fit import PREFER_GOOD
    from hdrcl.core.findings import CHECK, NOTE, Finding

    if entry is None or entry.source not in ("calibrated", "loaded"):
        return []
    v = entry.untrusted.get(job.index)
    if v is None and job.index not in entry.sets and grid is not None and options is not None:
        v = set_verdict(grid, options)  # a set the pool's sample left out
    if v is None:
        return []
    verdict, span = v
    reason = verdict[:-len(PREFER_GOOD)] if verdict.endswith(PREFER_GOOD) else verdict
    name = f"set {job.index} ({os.path.splitext(os.path.basename(job.output))[0]})"
    from hdrcl.core.bracket import read_infos
    from hdrcl.core.sources import times_source

    where = times_source(job.files, read_infos(job.files))  # the list the times came from, if any
    listed = os.path.basename(where) if where else None
    good = [i for i in entry.sets if i not in entry.untrusted]
    if good and job.index not in entry.sets:
        curve = os.path.basename(entry.file) if entry.file else entry.group
        return [Finding("exposure", f"{name}: {reason}; merged with the pooled response of {_sets_text(good)} "
                        f"of this camera ({curve}) instead, its exposures measured through it",
                        severity=NOTE, file=listed, figure=span)]
    times = f"the exposure times in {listed}" if listed else "the exposure times"
    return [Finding("exposure", f"{name}: {reason}; no good set of this camera in this batch to take a "
                    f"response from: check {times} or give --response from a good set of this camera",
                    severity=CHECK, file=listed, figure=span)]


def _cached(group: str, cache: str, first_info) -> "ResponseEntry | None":
    """The group's curve from the ``--response-cache`` folder when there is one that fits
    the frames (its bit depth); None (with a warning for one that does not) otherwise.

    A curve this batch calibrated into the cache keeps the digest it was merged with
    (its calibration key), so a rerun finds its sets up to date."""
    path = response_to_read(group, cache)  # an older version's hyphenated name too
    if not os.path.isfile(path):
        return None
    saved = read_state(path, "cached response")  # damaged: None, said by read_state
    try:
        resp = Response.from_dict(saved, source=path) if saved is not None else None
    except HdrclError as exc:
        logger.warning("%s; calibrating %s again", str(exc).splitlines()[0], group)
        resp = None
    if resp is None:
        return None
    why = None if first_info is None else misfit(resp, path, os.path.basename(getattr(first_info, "path", "") or group),
                                                   first_info)
    if why is not None:  # the rule merge --response-cache applies too (hdrcl.core.response_cache)
        logger.warning("%s; calibrating %s again", why, group)
        return None
    payload = {k: v for k, v in saved.items() if k != "calibration"}
    calib = saved.get("calibration")
    key = calib.get("key") if isinstance(calib, dict) and isinstance(calib.get("key"), str) else None
    logger.info("%s: response from the cache %s", group, path)
    return ResponseEntry(group=group, payload=payload, file=path, source="cached",
                         digest=_key_digest(key) if key else response_digest(payload))


def _prepare_responses(plan: _Plan, out_dir: str, options: BatchOptions, response=None,
                       defer: bool = False, cache=None, hold: bool = False) -> Dict[str, ResponseEntry]:
    """Every needed group's response, as :func:`decide_responses` decides it: given, from
    the ``cache`` folder, loaded, solved now, or (``defer``) left to the merge of a group's
    only set (saved into ``cache`` when given, else ``out_dir``).

    ``hold``: the sets are merged next in this process, so the frames a pooled solve
    decodes of the selected sets are held for their merges (:mod:`hdrcl.io.ahead`: taken
    when the merge opens them, dropped by ``cancel_all`` at the end of the run); an error
    or a cancel here drops them at once."""
    if not hold:
        return _responses(plan, out_dir, options, response, defer, cache, frozenset())
    from hdrcl.io import ahead

    merging = list(plan.selected)
    try:
        return _responses(plan, out_dir, options, response, defer, cache, frozenset(j.index for j in merging))
    except BaseException:
        for j in merging:
            ahead.discard(j.files)
        raise


def _responses(plan: _Plan, out_dir: str, options: BatchOptions, response, defer: bool, cache,
               hold: frozenset) -> Dict[str, ResponseEntry]:
    """Decide every needed group's response (:func:`decide_responses`), then carry it out."""
    decided = decide_responses(plan, out_dir, options, response, defer=defer, cache=cache)
    payload = None
    if response is not None:  # one curve for every group: read once
        payload = _normalised(response if isinstance(response, Response) else Response.load(os.fspath(response)))
    return {g: _carry_out(gp, options, hold, payload) for g, gp in decided.items()}


# -------------------------------------------------------------------- decisions
#: What a group's response plan does: the curve given (``--response``), taken from the
#: ``--response-cache`` folder, loaded from the file saved for this very calibration key,
#: solved now from the pooled sets, or left to the merge of the group's only set.
GIVEN, CACHED, LOADED, SOLVE, DEFERRED = "given", "cached", "loaded", "solve", "deferred"


@dataclass(frozen=True)
class GroupPlan:
    """One camera group's response, decided before any frame is decoded or any curve is
    solved (:func:`decide_responses`); the batch carries it out (:func:`_carry_out`), its
    dry run describes it.

    ``entry`` is the group's :class:`ResponseEntry` as decided: the file read or to be
    written, the calibration key, the curve of a cached or loaded one, the warnings so far.
    ``members`` are the group's sets in the manifest, ``pool`` those its curve is solved
    from (at most :data:`MAX_POOL_SETS`), ``usable`` their jobs whose files could be hashed.
    """

    group: str
    action: str
    entry: ResponseEntry
    members: Tuple[int, ...] = ()
    pool: Tuple[int, ...] = ()
    usable: Tuple[SetJob, ...] = ()

    @property
    def kind(self) -> str:
        """The merge plan's response kind (:data:`hdrcl.core.plan.RESPONSE_KINDS`)."""
        return {GIVEN: "given", CACHED: "cached", DEFERRED: "deferred"}.get(self.action, "pooled")

    def describe(self) -> dict:
        """The decision in the dry run's words: ``response`` (group, file, source: given,
        cached, saved or calibrate) and ``calibration`` (kind: given, cached, own, or
        pooled with its sets)."""
        source = {GIVEN: "given", CACHED: "cached", LOADED: "saved"}.get(self.action, "calibrate")
        if self.action in (GIVEN, CACHED):
            calib = {"kind": self.action}
        elif len(self.members) == 1:
            calib = {"kind": "own"}
        else:
            calib = {"kind": "pooled", "sets": list(self.pool)}
        return {"response": {"group": self.group, "file": self.entry.file, "source": source}, "calibration": calib}


def decide_responses(plan: _Plan, out_dir: str, options: BatchOptions, response=None, defer: bool = False,
                     cache=None) -> Dict[str, GroupPlan]:
    """Each needed group's response plan (:class:`GroupPlan`), without decoding a frame or
    solving a curve: the given one; the ``cache`` folder's when one there fits the frames;
    the file saved beside the outputs (or in ``cache``) for this very calibration key;
    else solved from the pool, or (``defer``) by the merge of a group's only set. Reads
    only the response files and the pooled files' bytes (their digests make the key)."""
    needed = sorted({j.group for j in plan.selected})
    if response is not None:
        name = "given" if isinstance(response, Response) else os.fspath(response)
        return {g: GroupPlan(g, GIVEN, ResponseEntry(group=g, file=name, source="given"),
                             tuple(plan.groups[g]), tuple(_pool_of(plan.groups[g]))) for g in needed}
    out = {}
    for g in needed:
        members = plan.groups[g]
        first, pool = plan.firsts.get(members[0]), _pool_of(members)
        if len(members) > 1 and first is not None and _camera_label(first) == "unknown camera":
            logger.info("%s: %s name no camera in their EXIF and share size and bit depth: one camera, one "
                        "response", g, _sets_text(members))
        folder = cache_for(first, cache)
        cached = _cached(g, folder, first) if folder is not None else None
        if cached is not None:
            out[g] = GroupPlan(g, CACHED, cached, tuple(members), tuple(pool))
            continue
        jobs = [plan.jobs[i] for i in pool]
        entry, usable = saved_response(g, jobs, folder or out_dir, options)
        if entry.source == "loaded":
            action = LOADED
        elif defer and len(usable) == 1 and len(jobs) == 1:
            # The set's merge solves it from the decode that feeds its fusion (solve_deferred).
            action = DEFERRED
            entry.deferred, entry.digest, entry.source = True, _key_digest(entry.key), "calibrated"
            entry.sets = [usable[0].index]
        else:
            action = SOLVE
        out[g] = GroupPlan(g, action, entry, tuple(members), tuple(pool), tuple(usable))
    return out


def _carry_out(gp: GroupPlan, options: BatchOptions, hold=frozenset(), given=None) -> ResponseEntry:
    """The group's entry as its plan says: ``given`` (the curve's payload) attached, a loaded
    one said, a pool solved and saved (the frames of the sets ``hold`` held for their
    merges); the plan itself is left as decided."""
    e = gp.entry
    entry = replace(e, sets=list(e.sets), warnings=list(e.warnings), untrusted=dict(e.untrusted))
    if gp.action == GIVEN:
        entry.payload, entry.digest = given, response_digest(given)
    elif gp.action == LOADED:
        logger.info("%s: response loaded from %s", gp.group, entry.file)
    elif gp.action == SOLVE:
        entry = _solve_pool(entry, list(gp.usable), options, hold=hold)
    return entry


def cache_for(first_info, cache):
    """The ``--response-cache`` folder for a group whose first frame is ``first_info``,
    or None: a group whose frames name no camera is one camera only within its shoot (by
    size and bit depth; another shoot's converted frames may be another camera's), so it
    is calibrated each time and saved beside the outputs, never cached."""
    if cache is None or first_info is None or _camera_label(first_info) == "unknown camera":
        return None
    return cache


def solve_deferred(entry: ResponseEntry, job: SetJob, infos, grid, options: BatchOptions,
                   paths=None) -> Response:
    """The response of a one-set group, solved by that set's merge from the sampling grid
    of the decode that feeds its fusion, and saved (as :func:`_carry_out` saves a pool's).

    Raises
    ------
    HdrclError
        The solve failed (the set fails with the reason).
    """
    # ``paths``: the frames the grid holds (a merge may have left some out: alignment)
    _solve_pool(entry, [job], options, grids={job.index: (infos, grid, list(paths or job.files))})
    if entry.payload is None:
        raise HdrclError(f"no response for {entry.group}: {entry.error}")
    entry.deferred = False  # solved: a later use in this process loads it like any other
    return _response_of(entry)


_response_cache: Dict[str, Response] = {}
