"""``hdrcl batch --scheduler``: a local Dask cluster of worker processes.

Skipped when the optional extra is not installed (``pip install 'hdrcl[dask]'``).
"""
from __future__ import annotations

import json
import os

import pytest
from click.testing import CliRunner

distributed = pytest.importorskip("distributed")

from hdrcl.cli import main  # noqa: E402
from hdrcl.shoot.batch.setrun import process_set  # noqa: E402

try:
    import shootgen
except ImportError:  # tests/ made a package
    from tests import shootgen


@pytest.fixture(scope="module")
def cluster():
    # Worker processes, as on a real cluster: each makes its own OpenCL context.
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None, silence_logs=40) as c:
        yield c


@pytest.fixture(scope="module")
def manifest(tmp_path_factory):
    folder = tmp_path_factory.mktemp("shoot")
    shootgen.make_shoot(folder)
    path = folder / "manifest.json"
    res = CliRunner().invoke(main, ["scan", str(folder), "-o", str(path)])
    assert res.exit_code == 0, res.output
    return str(path)


def _files(out, ends=(".exr", ".jpg")):
    return sorted(n for n in os.listdir(out) if n.endswith(ends) and not n.startswith("."))


def test_dask_outputs_identical_to_local(cluster, manifest, tmp_path):
    local, remote = tmp_path / "local", tmp_path / "dask"
    res = CliRunner().invoke(main, ["batch", manifest, "-o", str(local)])
    assert res.exit_code == 1  # the shoot's corrupt file
    res = CliRunner().invoke(main, ["batch", manifest, "-o", str(remote), "--scheduler", cluster.scheduler_address])
    assert res.exit_code == 1, res.output
    rep = json.loads((remote / "report.json").read_text())
    assert [s["status"] for s in rep["sets"]] == ["done"] * 8
    assert _files(local) == _files(remote) and len(_files(local)) == 16
    for name in _files(local):
        assert (local / name).read_bytes() == (remote / name).read_bytes(), name
    # Run again on the cluster: everything is up to date.
    res = CliRunner().invoke(main, ["batch", manifest, "-o", str(remote), "--scheduler", cluster.scheduler_address,
                                    "--sets", "0-7"])
    assert res.exit_code == 0 and "8 up to date" in res.stdout


def flaky_process_set(job, ctx, strict):
    """Fails the first attempt of every set with an unexpected error, then works."""
    marker = job.output + ".attempts"
    with open(marker, "a") as fh:
        fh.write("x")
    with open(marker) as fh:
        if len(fh.read()) == 1:
            raise RuntimeError("transient: the file server went away")
    return process_set(job, ctx, strict)


def always_broken(job, ctx, strict):
    raise RuntimeError("this worker cannot reach the files")


@pytest.mark.parametrize("task, retries, status", [(flaky_process_set, 1, "done"), (always_broken, 1, "failed")])
def test_failed_tasks_are_retried(cluster, manifest, tmp_path, task, retries, status):
    from hdrcl.shoot.batch.executors import run_dask
    from hdrcl.shoot.batch.jobs import BatchOptions, _Context
    from hdrcl.shoot.batch.plan import _plan, load_source
    from hdrcl.shoot.batch.pooling import _prepare_responses

    out = str(tmp_path)
    plan = _plan(load_source(manifest), out, BatchOptions(), [(0, 1)])
    ctx = _Context(options=BatchOptions(), responses=_prepare_responses(plan, out, BatchOptions()))
    results = []
    from hdrcl.shoot.batch.setrun import _failed

    run_dask(plan.selected, ctx, cluster.scheduler_address, results.append, retries=retries, task=task,
             failed=_failed)
    assert sorted(r.index for r in results) == [0, 1]
    assert {r.status for r in results} == {status}
    if status == "done":
        for job in plan.selected:
            with open(job.output + ".attempts") as fh:
                assert fh.read() == "xx"  # failed once, retried once
    else:
        assert all("after 1 retries" in r.error and "cannot reach" in r.error for r in results)


def test_unreachable_scheduler_is_a_usage_error(manifest, tmp_path, monkeypatch):
    monkeypatch.setenv("HDRCL_DASK_TIMEOUT", "1s")
    res = CliRunner().invoke(main, ["batch", manifest, "-o", str(tmp_path), "--scheduler", "tcp://127.0.0.1:9"])
    assert res.exit_code == 2
    assert "cannot connect" in res.stderr
