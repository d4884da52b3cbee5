"""hdrcl's environment variables, declared once: name, kind, default, meaning.

The one rule for all of them: **unset or empty** is the default; **set to a value the
variable does not take** is a :class:`~hdrcl.errors.UsageError` (exit code 2) whose one
line names the variable, the value and what it takes — never a silent fallback, never a
warning that the run goes on without. The command line checks every variable before it
does anything (:func:`check_all`, from ``hdrcl/cli/group.py``); the library reads them
through :func:`flag`, :func:`number` and :func:`text`, which apply the same rule where
they are read (a script that never runs the CLI gets the same error).

Kinds: ``flag`` (``1/true/yes/on`` or ``0/false/no/off``, any case), ``int`` / ``float``
(a number at least the variable's minimum; ``_`` allowed as a digit separator), ``dir``
(an existing folder), ``text`` (anything). ``docs/cli.md`` ("Environment") lists them;
a test checks that the list and the table below agree.

Cheap to import (no NumPy, no logging): :mod:`hdrcl.cli.group` imports it at start-up.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Dict, Optional, Union

__all__ = ["Variable", "VARIABLES", "flag", "number", "text", "check", "check_all"]

_TRUE = ("1", "true", "yes", "on")
_FALSE = ("0", "false", "no", "off")


@dataclass(frozen=True)
class Variable:
    name: str
    kind: str  # flag, int, float, dir, text
    default: Union[bool, int, float, str, None]
    meaning: str
    minimum: Optional[float] = None  # int and float: the smallest value taken
    positive: bool = False  # float: more than 0 (0 itself refused)


def _table(*rows: Variable) -> Dict[str, Variable]:
    return {v.name: v for v in rows}


#: Every ``HDRCL_*`` variable the package reads (tests/conftest.py's ``HDRCL_REQUIRE_*``
#: are the test suite's own, documented in docs/development.md).
VARIABLES: Dict[str, Variable] = _table(
    Variable("HDRCL_OPENCL", "flag", True, "0: the NumPy reference path instead of OpenCL (much slower)"),
    Variable("HDRCL_REQUIRE_OPENCL", "flag", False, "1: no usable OpenCL device is an error, not a NumPy fallback"),
    Variable("HDRCL_SMALL_WORK", "int", 600_000,
             "pixel-samples below which a job takes the NumPy path (0: never)", minimum=0),
    Variable("HDRCL_MAX_PIXELS", "int", 1_000_000_000, "pixels one frame may have (also --max-pixels)", minimum=1),
    Variable("HDRCL_MEMORY_MB", "float", 1024.0,
             "megabytes of decoded frames a process holds before spilling to the scratch folder", positive=True),
    Variable("HDRCL_MEMORY_SHARE", "int", 1, "set by batch for its workers: the share of HDRCL_MEMORY_MB",
             minimum=1),
    Variable("HDRCL_SCRATCH_DIR", "dir", None, "folder of the spill files [default: the system's temporary folder]"),
    Variable("HDRCL_DECODE_AHEAD", "flag", True, "0: no decoding of the next set's frames ahead"),
    Variable("HDRCL_REPORT_THREADS", "int", None, "threads of the quality report's leave-one-out solves "
             "[default: the cores, at most 4]", minimum=1),
    Variable("HDRCL_CACHE_DIR", "text", None, "hdrcl's cache folder [default: $XDG_CACHE_HOME/hdrcl]"),
    Variable("HDRCL_PROGRAM_CACHE", "flag", True, "0: no cache of built OpenCL programs"),
    Variable("HDRCL_KERNEL_DIR", "dir", None, "folder of the .cl kernel sources (kernel development)"),
    Variable("HDRCL_ICD_SETUP", "flag", True, "0: the OpenCL ICD loader's own search, not hdrcl's"),
    Variable("HDRCL_CPU_DRIVERS", "text", None, "order of the CPU OpenCL drivers, e.g. pocl,intel-cpu"),
    Variable("HDRCL_ICD_VENDORS", "text", None, "set by hdrcl beside OCL_ICD_VENDORS (internal)"),
    Variable("HDRCL_DASK_TIMEOUT", "text", "30s", "batch --executor dask: how long to wait for the scheduler"),
)


def _what(v: Variable) -> str:
    if v.kind == "flag":
        return "1/true/yes/on or 0/false/no/off"
    if v.kind in ("int", "float"):
        whole = "a whole number" if v.kind == "int" else "a number"
        if v.positive:
            return f"{whole} > 0"
        return f"{whole} >= {v.minimum:g}" if v.minimum is not None else whole
    if v.kind == "dir":
        return "an existing folder"
    return "text"


def _fail(v: Variable, raw: str):
    from hdrcl.errors import UsageError

    if v.default is None:
        default = ""
    elif v.kind == "flag":
        default = f"; unset: {int(bool(v.default))}"
    else:
        default = f"; unset: {v.default:g}" if isinstance(v.default, (int, float)) else f"; unset: {v.default}"
    raise UsageError(f"{v.name}={raw!r} is not {_what(v)} ({v.meaning}{default}): set it so, or unset it")


def _parse(v: Variable, raw: str):
    s = raw.strip()
    if v.kind == "flag":
        low = s.lower()
        if low in _TRUE:
            return True
        if low in _FALSE:
            return False
        _fail(v, raw)
    if v.kind in ("int", "float"):
        try:
            x = float(s.replace("_", ""))
        except ValueError:
            x = math.nan
        if not math.isfinite(x) or (v.minimum is not None and x < v.minimum) or (v.positive and not x > 0) \
                or (v.kind == "int" and x != int(x)):
            _fail(v, raw)
        return int(x) if v.kind == "int" else x
    if v.kind == "dir":
        if not os.path.isdir(s):
            _fail(v, raw)
        return s
    return s


def check(name: str):
    """The value of variable ``name`` (its default when unset or empty); UsageError when
    it is set to something the variable does not take."""
    v = VARIABLES[name]
    raw = os.environ.get(name)
    if raw is None or raw.strip() == "":
        return v.default
    return _parse(v, raw)


def flag(name: str) -> bool:
    """A ``flag`` variable's value (:func:`check`)."""
    assert VARIABLES[name].kind == "flag", name
    return bool(check(name))


def number(name: str):
    """An ``int`` or ``float`` variable's value (:func:`check`), or its default (may be None)."""
    assert VARIABLES[name].kind in ("int", "float"), name
    return check(name)


def text(name: str) -> Optional[str]:
    """A ``text`` or ``dir`` variable's value (:func:`check`), or its default."""
    assert VARIABLES[name].kind in ("text", "dir"), name
    return check(name)


def check_all() -> None:
    """Check every declared variable that is set (the CLI, before anything runs)."""
    for name in VARIABLES:
        check(name)
