"""The one place a merge's stages run, in this order, and its result is built:

    open -> load (align) -> sample -> respond -> measure       (prepare: "open", "calibrate")
         -> agreement -> stage the response file -> scale -> fuse   (proceed; start = prepare + proceed:
                                                                     the writer left open)
         -> commit -> the response file, the kept frames          (finish: the result)

:func:`execute` runs a :class:`hdrcl.core.plan.MergePlan` whole. :func:`start` and
:func:`finish` split it at the commit, so that a caller can do its own work between
the fusion and the commit (a batch writes the set's preview and deliverables before the
EXR, which marks the set complete, is moved into place) and, later, commit one set while
the next fuses; :func:`abort` undoes a started run. :func:`prepare` runs only the stages
before the fusion (a quality report of a set merged earlier). The stages are
:mod:`hdrcl.core.stages` and :mod:`hdrcl.core.fusestage`; what they find is held by
:class:`hdrcl.core.runstate.RunState`. Each stage is timed on it (``run.seconds``).

The fusion backend is decided once per run, by its size and the device asked for
(:func:`hdrcl.core.pipeline.fusion_processor`), never by what the process ran before: the
same set gives the same bytes first or after other sets.
"""
from __future__ import annotations

import logging
import time

from hdrcl.core import fusestage, stages
from hdrcl.core.plan import MEMORY, MergePlan
from hdrcl.core.runstate import RunState

logger = logging.getLogger(__name__)


def prepare(plan: MergePlan) -> RunState:
    """The stages before the fusion: open, load (align), sample, respond, measure. The
    caller closes the run's source (``run.close()``) unless :func:`start` follows."""
    run = RunState(plan)
    try:
        _prepare(run)
    except BaseException:
        run.close()
        raise
    return run


def _prepare(run: RunState) -> None:
    with run.timed("open"):
        stages.open_frames(run)
    t1 = time.perf_counter()
    stages.load(run)
    stages.sample(run)
    stages.respond(run)
    stages.measure(run)
    run.add_time("calibrate", time.perf_counter() - t1)


def start(plan: MergePlan) -> RunState:
    """Every stage up to the fusion; for a file, the writer is left open for :func:`finish`
    (or :func:`abort`)."""
    return proceed(prepare(plan))


def proceed(run: RunState) -> RunState:
    """A prepared run (:func:`prepare`) on to the fusion, as :func:`start` goes on: the
    agreement check, the response file staged, the scale, the fusion (a caller that
    shares a device between threads prepares on several at once and proceeds on one)."""
    plan = run.plan
    try:
        if plan.checks:
            stages.agreement(run)  # do the frames agree? (findings; hdrcl.core.agreement)
        run.t_fuse = time.perf_counter()
        if plan.extras.save_response is not None:
            # A second output is staged first: a full disk fails here, before the radiance exists.
            from hdrcl.io.atomic import stage_text

            run.staged = stage_text(plan.extras.save_response, run.response.to_json())
        stages.scale(run)
        fusestage.fuse(run)
    except BaseException:
        abort(run)
        raise
    return run


def finish(run: RunState):
    """Commit a started run: the file moved into place, the masks, the response file;
    the sources closed whatever happens. Returns the :class:`hdrcl.core.result.MergeResult`."""
    try:
        fusestage.commit(run)
        if run.staged is not None:
            run.staged.commit()
            run.staged = None
        if run.plan.extras.keep_frames:
            run.result.kept = fusestage.kept_frames(run.source, run.grid)
    finally:
        if run.staged is not None:
            run.staged.discard()
        run.close()
    return _result(run)


def abort(run: RunState) -> None:
    """Undo a started run: nothing it would write is left; its sources closed."""
    try:
        if run.writer is not None:
            run.writer.abort()
            run.writer = None
    finally:
        if run.staged is not None:
            run.staged.discard()
            run.staged = None
        run.close()


def execute(plan: MergePlan):
    """Run the plan whole: :func:`start`, then :func:`finish`."""
    return finish(start(plan))


def _result(run: RunState):
    res, counts, plan = run.result, run.counts, run.plan
    res.counts = counts
    res.findings = list(run.findings)
    res.warnings += [f.message for f in run.findings if f.message not in res.warnings]
    res.radiance = run.keep.array if run.keep is not None else None
    res.thumbnail = run.thumb.array if run.thumb is not None else None
    s = run.seconds
    if plan.frames == MEMORY:
        if counts.get("no_data"):
            res.warnings.append(f"{counts['no_data']} pixel-channels are invalid in every frame and were set to 0")
        res.stages = {k: v for k, v in s.items() if k in ("solve", "fuse", "align")}
        res.seconds = {"calibrate": s.get("calibrate", 0.0), "fuse": time.perf_counter() - run.t0}
        return res
    if counts.get("no_data"):
        msg = f"{run.output}: {counts['no_data']} pixel-channels are invalid in every frame and were set to 0"
        logger.warning(msg)
        res.warnings.append(msg)
    if run.options.deghost:
        logger.info("%s: ghost pixels %.2f %%", run.output, 100.0 * counts.get("ghost", 0) / max(run.h * run.w, 1))
    res.stages = {k: s[k] for k in ("decode", "solve", "fuse", "encode", "write", "align") if k in s}
    res.seconds = {"open": s.get("open", 0.0), "calibrate": s.get("calibrate", 0.0),
                   "fuse_and_write": time.perf_counter() - run.t_fuse}
    return res
