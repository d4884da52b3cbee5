"""Where the sets of a batch run: worker processes on this machine, or a Dask cluster.

Both run the ``task`` they are given (the batch passes
:func:`hdrcl.shoot.batch.setrun.process_set`) once per set and hand each result to ``emit`` as
it completes; ``failed(job, exc)`` makes the result of a set whose task could not run.
This module knows nothing of batches: it receives the functions to run. The in-process
pipeline (``jobs=1``) lives in :mod:`hdrcl.shoot.batch.run`.

**Worker processes** start with ``spawn``: a forked child would inherit the parent's
OpenCL driver state, which no OpenCL implementation supports. Each worker creates its
own context and builds the kernels once, on its first set, and reuses them for every
later set (:func:`hdrcl.cl.backend.get_processor` caches them per process). Workers
die with the batch whatever kills it (:func:`hdrcl.shoot.batch.claims.tie_to_parent`), and
an exception in the batch (SIGTERM, Ctrl-C) kills them at once (:func:`_kill_pool`)
instead of waiting for the queued sets.

**Dask**: the sets are submitted as tasks to an existing scheduler; each worker
process makes its own OpenCL context the same way. A task that raises an unexpected
error (lost mount, device fault, a worker that died) is retried ``retries`` times by
the scheduler; a set's own problem (a corrupt frame) is not an error here but a
result with status ``failed``, and is not retried. Workers must see the photographs and
the output folder at the same paths as the submitting machine (a shared file system).
"""
from __future__ import annotations

import concurrent.futures
import logging
import multiprocessing
import os
import secrets
from typing import Callable, List

logger = logging.getLogger(__name__)

__all__ = ["run_processes", "run_dask", "dask_client"]


def _worker_init(level: int, parent: int, share: int = 1) -> None:
    """Worker processes die with their parent and log like it: one line, same level;
    each holds decoded frames within its ``share`` of ``HDRCL_MEMORY_MB``
    (:mod:`hdrcl.io.framecache`)."""
    from hdrcl.shoot.batch.claims import tie_to_parent

    os.environ["HDRCL_MEMORY_SHARE"] = str(max(1, int(share)))

    tie_to_parent(parent)
    from hdrcl.errors import WarningsBridge

    log = logging.getLogger("hdrcl")
    log.handlers[:] = [h for h in log.handlers if not isinstance(h, WarningsBridge)]  # print, don't warn
    if not log.handlers:
        h = logging.StreamHandler()
        h.setFormatter(logging.Formatter("hdrcl: %(levelname)s: %(message)s"))
        log.addHandler(h)
        log.propagate = False
    log.setLevel(level)


def run_processes(set_jobs: List, ctx, emit: Callable, *, task: Callable, failed: Callable, jobs: int = 2) -> None:
    """Run ``set_jobs`` in ``jobs`` spawned worker processes.

    A worker that dies (killed, out of memory) breaks the pool, and the pool cannot
    tell which set it was running: the sets that had not finished are run again, each
    alone in a fresh one-worker pool (their claims died with the worker, so the new run
    removes its temporary files). So a set that kills its worker every time fails by
    itself ("died twice") and every other set completes. Any exception here (SIGTERM,
    Ctrl-C) kills the workers of the current pool at once and is raised.
    """
    mp = multiprocessing.get_context("spawn")
    level = logging.getLogger("hdrcl").getEffectiveLevel()

    def run_round(batch: List, workers: int) -> List:
        """Run ``batch``; emit every result; return the sets a dying worker took down."""
        pool = concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=mp,
                                                      initializer=_worker_init,
                                                      initargs=(level, os.getpid(), workers))
        lost = []
        try:
            futures = {pool.submit(task, job, ctx): job for job in batch}
            for fut in concurrent.futures.as_completed(futures):
                job = futures[fut]
                try:
                    res = fut.result()
                except concurrent.futures.process.BrokenProcessPool:
                    lost.append(job)
                    continue
                except Exception as exc:  # pickling problems and the like
                    res = failed(job, exc)
                emit(res)
        except BaseException:
            _kill_pool(pool)
            raise
        if lost:
            _kill_pool(pool)  # what is left of the broken pool
        else:
            pool.shutdown(wait=True)
        return lost

    lost = run_round(list(set_jobs), min(jobs, len(set_jobs)))
    if lost:
        logger.warning("a worker process died: running %d unfinished set(s) again, one at a time", len(lost))
    for job in sorted(lost, key=lambda j: j.index):
        if run_round([job], 1):
            emit(failed(job, RuntimeError("its worker process died twice while merging it "
                                          "(killed, or out of memory)")))


def _kill_pool(pool) -> None:
    """Kill the pool's workers now (SIGKILL) and let the pool go without waiting for
    queued work; their sets' temporary files are left to the claims' cleanup."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for p in procs:
        try:
            p.kill()
        except (OSError, ValueError):
            pass
    for p in procs:
        try:
            p.join(1.0)
        except (OSError, ValueError, AssertionError):
            pass
    try:
        pool.shutdown(wait=False, cancel_futures=True)
    except Exception:  # a broken pool may complain; the workers are gone either way
        pass


def dask_client(scheduler):
    """A ``distributed.Client`` for ``scheduler`` (an address or a Client), and
    whether the caller owns it (and closes it).

    Raises
    ------
    UsageError
        Dask is not installed, or the scheduler cannot be reached.
    """
    from hdrcl.errors import UsageError

    try:
        import distributed
    except ImportError:
        raise UsageError("--scheduler needs Dask: pip install 'hdrcl[dask]'") from None
    if isinstance(scheduler, distributed.Client):
        return scheduler, False
    from hdrcl.env import text

    timeout = text("HDRCL_DASK_TIMEOUT")
    try:
        return distributed.Client(str(scheduler), timeout=timeout, set_as_default=False), True
    except (OSError, TimeoutError) as exc:
        raise UsageError(f"--scheduler {scheduler}: cannot connect ({exc})") from None


def run_dask(set_jobs: List, ctx, scheduler, emit: Callable, *, task: Callable, failed: Callable,
             retries: int = 2) -> None:
    """Run ``set_jobs`` as tasks on a Dask cluster, retrying failed tasks.

    Task keys name the set and its output (``hdrcl-set-3-IMG_0009-...``) so the
    dashboard shows what runs; ``pure=False`` because each run must really happen.
    ``task(job, ctx, strict)`` runs one set on a worker (it must be importable there).
    """
    from distributed import as_completed

    run_id = secrets.token_hex(4)  # keys must not meet those of another run on the cluster
    client, owned = dask_client(scheduler)
    try:
        futures = {}
        for job in set_jobs:
            stem = os.path.splitext(os.path.basename(job.output))[0]
            fut = client.submit(task, job, ctx, True, key=f"hdrcl-set-{job.index}-{stem}-{run_id}",
                                retries=retries, pure=False)
            futures[fut] = job
        for fut in as_completed(list(futures), loop=client.loop):
            job = futures[fut]
            try:
                res = fut.result()
            except Exception as exc:  # retries exhausted, or the task could not run
                res = failed(job, RuntimeError(f"failed on the Dask cluster after {retries} retries: "
                                                f"{type(exc).__name__}: {exc}"))
            emit(res)
    finally:
        if owned:
            client.close()
