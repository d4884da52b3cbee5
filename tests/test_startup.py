"""Starting fast: small jobs skip OpenCL, the command line loads only what a command uses."""
import json
import logging
import os
import subprocess
import sys

import pytest

from hdrcl.cl import backend

#: Variables that name a device or force OpenCL: the small-job rule steps aside for them.
_FORCING = ("PYOPENCL_CTX", "HDRCL_REQUIRE_OPENCL", "HDRCL_OPENCL", "HDRCL_SMALL_WORK", "HDRCL_REQUIRE_DRIVER")


def _python(code, **env):
    full = {k: v for k, v in os.environ.items() if k not in _FORCING}
    full.update(env)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=full, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    return r


SMALL = """
import json, logging, sys
logging.basicConfig(level=logging.INFO, format="%(levelname)s %(message)s")
from hdrcl.cl.backend import SMALL_WORK, get_processor
first = get_processor("fusion", work=SMALL_WORK - 1)
again = get_processor("fusion", work=1000)
print(json.dumps({"numpy": first is None and again is None, "pyopencl": "pyopencl" in sys.modules}))
"""


def test_a_small_job_takes_the_numpy_path_without_loading_pyopencl():
    r = _python(SMALL)
    assert json.loads(r.stdout) == {"numpy": True, "pyopencl": False}
    lines = [ln for ln in r.stderr.splitlines() if "NumPy path" in ln]
    assert len(lines) == 1 and lines[0].startswith("INFO") and "HDRCL_SMALL_WORK" in lines[0], r.stderr


def test_the_threshold_can_be_changed_and_turned_off():
    r = _python(SMALL, HDRCL_SMALL_WORK="100")  # both jobs are above 100
    assert json.loads(r.stdout)["pyopencl"] is True
    r = _python(SMALL, HDRCL_SMALL_WORK="0")
    assert json.loads(r.stdout)["pyopencl"] is True


@pytest.fixture
def fresh(monkeypatch, cl_device):
    """No processor open yet, no forcing variable, messages not said yet."""
    for var in _FORCING:
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setattr(backend, "_processors", {})
    monkeypatch.setattr(backend, "_warned", set())
    return monkeypatch


@pytest.fixture
def records(monkeypatch):
    """Records of the backend's logger (a handler of its own: the command line's set-up,
    run in-process by other tests, stops propagation at ``hdrcl``)."""
    got = []
    handler = logging.Handler()
    handler.emit = got.append
    log = logging.getLogger("hdrcl.cl.backend")
    monkeypatch.setattr(log, "level", logging.INFO)
    log.addHandler(handler)
    yield got
    log.removeHandler(handler)


def test_small_job_rule(fresh, records):
    assert backend.get_processor("fusion", work=1000) is None
    assert backend.get_processor("fusion", work=backend.small_work() - 1) is None
    said = [r for r in records if "NumPy path" in r.getMessage()]
    assert len(said) == 1 and said[0].levelno == logging.INFO  # said once
    # no size given: OpenCL as before
    assert backend.get_processor("fusion") is not None
    # OpenCL open already: a small job still takes the NumPy path (the job alone decides,
    # never what the process ran before: issue 25)
    assert backend.get_processor("exposure", work=1000) is None


@pytest.mark.parametrize("force", ["device", "PYOPENCL_CTX", "HDRCL_REQUIRE_OPENCL", "large"])
def test_what_keeps_opencl_for_a_small_job(fresh, cl_device, force):
    device, work = None, 1000
    if force == "device":
        device = _device_id(cl_device)
    elif force == "PYOPENCL_CTX":
        fresh.setenv("PYOPENCL_CTX", _device_id(cl_device))
    elif force == "HDRCL_REQUIRE_OPENCL":
        fresh.setenv("HDRCL_REQUIRE_OPENCL", "1")
    else:
        work = backend.small_work()
    assert backend.get_processor("fusion", device, work=work) is not None


def _device_id(ctx):
    from hdrcl.cl.context import _device_id

    return _device_id(ctx.device)


def test_opencl_off_still_wins(fresh):
    fresh.setenv("HDRCL_OPENCL", "0")
    assert backend.get_processor("fusion", work=10 ** 9) is None


def test_a_bad_threshold_is_refused_naming_it(fresh, records):
    """hdrcl.env's one rule (issue 34): a value the variable does not take is a UsageError
    (it used to warn and go on with the default)."""
    from hdrcl.errors import UsageError

    fresh.setenv("HDRCL_SMALL_WORK", "lots")
    with pytest.raises(UsageError, match="HDRCL_SMALL_WORK='lots'"):
        backend.small_work()
    fresh.setenv("HDRCL_SMALL_WORK", "2e6")
    assert backend.small_work() == 2_000_000


# ------------------------------------------------------------------- command line


def test_version_loads_no_command_module():
    code = ("import sys, runpy; sys.argv = ['hdrcl', '--version']\n"
            "try:\n    runpy.run_module('hdrcl', run_name='__main__')\n"
            "except SystemExit:\n    pass\n"
            "bad = [m for m in ('numpy', 'hdrcl.cli.core', 'hdrcl.cli.shoot', 'hdrcl.cli.output', "
            "'importlib.metadata', 'pyopencl', 'OpenImageIO') if m in sys.modules]\n"
            "print('loaded:' + ','.join(bad))")
    r = _python(code)
    assert "hdrcl, version " in r.stdout and r.stdout.strip().endswith("loaded:"), r.stdout


def test_version_is_the_installed_one():
    from importlib.metadata import PackageNotFoundError, version

    from hdrcl.version import __version__

    try:
        assert version("hdrcl") == __version__
    except PackageNotFoundError:
        pytest.skip("hdrcl is not installed")


def test_every_command_is_listed_where_it_is_defined():
    from hdrcl.cli.group import COMMAND_MODULES, main

    main.load_all()
    assert set(main.commands) == set(COMMAND_MODULES)
    for name, cmd in main.commands.items():
        assert cmd.callback.__module__ == COMMAND_MODULES[name], name


def test_merge_loads_only_its_module():
    code = ("import sys\nfrom click.testing import CliRunner\nfrom hdrcl.cli import main\n"
            "r = CliRunner().invoke(main, ['merge', '--help'])\nassert r.exit_code == 0, r.output\n"
            "print(','.join(m for m in ('hdrcl.cli.core', 'hdrcl.cli.shoot', 'hdrcl.cli.output', 'pyopencl') "
            "if m in sys.modules))")
    assert _python(code).stdout.strip() == "hdrcl.cli.core"


CALIBRATE = """
import json, sys
import numpy as np
from hdrcl.core.solve import recover_response
rng = np.random.default_rng(0)
scene = rng.uniform(-3, 3, (60, 80, 3))
frames = [np.clip(255 / (1 + np.exp(-(scene + t))), 0, 255).astype(np.uint8) for t in (-1.5, 0.0, 1.5)]
resp = recover_response(frames, [0.25, 1.0, 4.0], samples=400)
print(json.dumps({"finite": bool(np.isfinite(resp.g).all()),
                  "scipy": sorted(m for m in sys.modules if m == "scipy" or m.startswith("scipy."))[:3]}))
"""


def test_the_response_solve_and_sample_choice_load_no_scipy():
    """The curve solve is a small dense system and the sample choice box sums: a small
    set's calibration must not pay for importing scipy (0.15-0.2 s of CPU here)."""
    r = _python(CALIBRATE)
    assert json.loads(r.stdout) == {"finite": True, "scipy": []}


def test_the_dense_solve_matches_the_whole_least_squares_system():
    """The Schur-complement normal equations built with bincount give the paper's
    least-squares solution: the same curve as lstsq on the whole (g, ln E) system."""
    import numpy as np

    from hdrcl.core.response import _segments, knot_positions
    from hdrcl.core.solve import solve_curve
    from hdrcl.core.weights import weight_values

    rng = np.random.default_rng(3)
    n, p, lam = 120, 4, 10.0
    log_e = rng.uniform(-2, 2, n)
    lt = np.log([0.1, 0.4, 1.6, 6.4])
    z = np.clip(np.round(255 / (1 + np.exp(-(log_e[:, None] + lt)))), 0, 255).astype(np.int64)
    usable = rng.random((n, p)) > 0.1
    g = solve_curve(z, lt, 8, smoothness=lam, weight="hat", usable=usable)
    knots = knot_positions(8)
    k = knots.size
    rows, rhs = [], []
    for i in range(n):
        for j in range(p):
            w = weight_values(np.array([float(z[i, j])]), 256, "hat")[0] * usable[i, j]
            r = np.zeros(k + n)
            seg, f = _segments(np.array([float(z[i, j])]), knots)
            r[seg[0]] += w * (1 - f[0])
            r[seg[0] + 1] += w * f[0]
            r[k + i] = -w
            rows.append(r)
            rhs.append(w * lt[j])
    for c in range(1, k - 1):
        r = np.zeros(k + n)
        wk = lam * weight_values(knots[c:c + 1], 256, "hat")[0]
        r[c - 1:c + 2] = [wk, -2 * wk, wk]
        rows.append(r)
        rhs.append(0.0)
    r = np.zeros(k + n)
    r[k // 2] = 1.0
    rows.append(r)
    rhs.append(0.0)
    x = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)[0]
    want = x[:k] - x[k // 2]
    assert np.abs(g - want).max() < 1e-6
