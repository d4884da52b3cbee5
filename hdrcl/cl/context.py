"""OpenCL device selection and the per-process context cache.

Devices are chosen without interaction: an explicit ``device`` string, else
``PYOPENCL_CTX`` (pyopencl's own convention, e.g. ``0`` or ``0:1``; ``pocl`` or
``portable`` selects PoCL, ``intel-cpu`` Intel's CPU runtime), else the first GPU, else
the first CPU driver in :func:`~hdrcl.cl.drivers.cpu_driver_order`, each
only if it builds hdrcl's kernels. Before the first OpenCL call,
:func:`~hdrcl.cl.drivers.prepare_icd_environment` makes an Intel CPU runtime installed
from PyPI visible to the ICD loader.
"""
from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import tempfile
import threading
import time
import warnings
from typing import Dict, List, Optional, Tuple

import pyopencl as cl

from hdrcl.cl.drivers import (
    DRIVER_ALIASES,
    cache_root,
    cpu_driver_order,
    driver_rank,
    prepare_icd_environment,
)
from hdrcl.cl.resources import kernel_source
from hdrcl.errors import HdrclError, UsageError

logger = logging.getLogger(__name__)


class DeviceContext:
    """A context and in-order queue on one device, with its built programs.

    Programs are built once per (source, options) and their kernel objects fetched
    once, then reused for every image the process handles.
    """

    def __init__(self, device: "cl.Device"):
        self.device = device
        self.context = cl.Context([device])
        self.queue = cl.CommandQueue(self.context)
        self._kernels: Dict[Tuple[str, str, str], "cl.Kernel"] = {}
        self._lock = threading.Lock()

    @property
    def name(self) -> str:
        return f"{self.device.platform.name.strip()} / {self.device.name.strip()}"

    @property
    def shares_host_memory(self) -> bool:
        """True for CPU devices and integrated GPUs (zero-copy host buffers pay off)."""
        try:
            return bool(self.device.host_unified_memory)
        except cl.LogicError:
            return self.device.type & cl.device_type.CPU != 0

    def kernel(self, source: str, name: str, options: Tuple[str, ...] = ()) -> "cl.Kernel":
        """The kernel ``name`` of ``kernels/<source>.cl`` built with ``options``."""
        key = (source, name, " ".join(options))
        with self._lock:
            knl = self._kernels.get(key)
            if knl is None:
                prg = self._program(source, list(options))
                for k in prg.all_kernels():
                    self._kernels[(source, k.function_name, key[2])] = k
                knl = self._kernels[key]
            return knl

    def _program(self, source: str, options: List[str]) -> "cl.Program":
        """``kernels/<source>.cl`` built for this device: from the program cache when it
        holds a binary the driver accepts, else from source (then stored there)."""
        text = kernel_source(source)
        path = _cache_path(self.device, text, options)
        binary = _load_binary(path) if path else None
        if binary is not None:
            try:
                prg = _quiet_build(lambda: cl.Program(self.context, [self.device], [binary]).build(options=options),
                                   source, self.name)
                prg.all_kernels()  # a binary the driver half-accepts fails here, not at first use
                build_counts["cached"] += 1
                logger.debug("kernels/%s.cl for %s: loaded from the program cache", source, self.name)
                return prg
            except Exception as exc:  # noqa: BLE001 - a stale or foreign binary: build from source
                build_counts["rejected"] += 1
                logger.debug("kernels/%s.cl: the driver rejected the cached binary %s (%s); building "
                             "from source", source, path, str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
        t0 = time.perf_counter()
        try:
            # cache_dir=False: with hdrcl's cache on, pyopencl's own would store it twice
            prg = _quiet_build(lambda: cl.Program(self.context, text).build(
                options=options, **({"cache_dir": False} if path else {})), source, self.name)
        except cl.Error as exc:
            raise HdrclError(
                f"building kernels/{source}.cl for {self.name} failed: {_build_error(exc)}"
            ) from exc
        build_counts["source"] += 1
        logger.debug("kernels/%s.cl for %s: built from source in %.2f s", source, self.name, time.perf_counter() - t0)
        if path:
            _store_binary(path, prg)
        return prg


def _quiet_build(build, source: str, device_name: str):
    """``build()``, with pyopencl's CompilerWarnings sent to the debug log.

    Intel's runtime always logs its progress and vectoriser remarks: pyopencl's
    CompilerWarning about them is noise, kept at debug level.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", cl.CompilerWarning)
        prg = build()
    for w in caught:
        if issubclass(w.category, cl.CompilerWarning):
            logger.debug("building kernels/%s.cl for %s: %s", source, device_name, w.message)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return prg


# ---------------------------------------------------------------- program cache
#
# Built programs are kept on disk, one file per (kernel source, build options, driver):
# ``<cache>/programs/<sha256>.bin``, where <cache> is HDRCL_CACHE_DIR, else
# $XDG_CACHE_HOME/hdrcl, else ~/.cache/hdrcl. A later process loads the binary instead
# of compiling (PoCL: 0.4-2 s a file cold, still 40-100 ms through its own kernel cache;
# a binary loads in a few ms). HDRCL_PROGRAM_CACHE=0 turns it off (pyopencl's own cache,
# which skips PoCL and NVIDIA, then applies as before). A missing, unreadable, corrupt or
# rejected file only means a build from source; a folder that cannot be written only
# means nothing is stored.

#: Programs this process built from source and loaded from the cache; cache files found
#: damaged, binaries the driver rejected, and binaries stored (for tests and ``-vv``).
build_counts: Dict[str, int] = {"source": 0, "cached": 0, "damaged": 0, "rejected": 0, "stored": 0}

_MAGIC = b"hdrcl-program-1\n"
#: Files kept in the cache folder; the least recently used go beyond this.
CACHE_ENTRIES = 256
#: Environment variables that change what the drivers compile: part of the key.
_COMPILER_ENV = ("PYOPENCL_BUILD_OPTIONS",)
_COMPILER_ENV_PREFIXES = ("POCL_", "CL_CONFIG_")


def program_cache_dir() -> Optional[str]:
    """The folder of cached program binaries, or None when HDRCL_PROGRAM_CACHE=0."""
    from hdrcl.env import flag

    if not flag("HDRCL_PROGRAM_CACHE"):
        return None
    return os.path.join(cache_root(), "programs")


def _cache_path(device: "cl.Device", text: str, options: List[str]) -> Optional[str]:
    folder = program_cache_dir()
    if folder is None:
        return None
    try:
        plat = device.platform
        ident = [plat.name, plat.version, device.name, device.version, device.driver_version]
    except cl.Error:
        return None
    env = sorted((k, v) for k, v in os.environ.items()
                 if k in _COMPILER_ENV or k.startswith(_COMPILER_ENV_PREFIXES))
    h = hashlib.sha256()
    for part in [_MAGIC.decode(), text, "\0".join(options), *ident, repr(env)]:
        h.update(part.encode("utf-8", "surrogateescape"))
        h.update(b"\0\1")
    return os.path.join(folder, h.hexdigest() + ".bin")


def _load_binary(path: str) -> Optional[bytes]:
    """The binary stored at ``path``, or None if there is none or it is damaged."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError:
        return None
    head, digest, body = data[:len(_MAGIC)], data[len(_MAGIC):len(_MAGIC) + 32], data[len(_MAGIC) + 32:]
    if head != _MAGIC or not body or hashlib.sha256(body).digest() != digest:
        build_counts["damaged"] += 1
        logger.debug("program cache: %s is damaged; building from source", path)
        return None
    try:
        os.utime(path)  # recently used: pruned last
    except OSError:
        pass
    return body


def _store_binary(path: str, prg: "cl.Program") -> None:
    """Write ``prg``'s binary to ``path`` (temporary file, then rename); never raises."""
    try:
        binaries = prg.get_info(cl.program_info.BINARIES)
        if len(binaries) != 1 or not binaries[0]:
            return
        body = bytes(binaries[0])
        folder = os.path.dirname(path)
        os.makedirs(folder, mode=0o700, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".bin", dir=folder)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(_MAGIC + hashlib.sha256(body).digest() + body)
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.remove(tmp)
            raise
        build_counts["stored"] += 1
        _prune(folder)
    except Exception as exc:  # noqa: BLE001 - a cache that cannot be written is no error
        logger.debug("program cache: not stored (%s)", exc)


def _prune(folder: str, keep: int = CACHE_ENTRIES) -> None:
    """Remove the least recently used binaries beyond ``keep`` (and stale temporaries)."""
    try:
        entries = []
        for e in os.scandir(folder):
            st = e.stat()
            if e.name.startswith(".tmp-") and time.time() - st.st_mtime > 3600:
                os.remove(e.path)
            elif e.name.endswith(".bin") and not e.name.startswith("."):
                entries.append((st.st_mtime, e.path))
        entries.sort(reverse=True)
        for _, p in entries[keep:]:
            with contextlib.suppress(OSError):
                os.remove(p)
    except OSError:
        pass


def _build_error(exc: Exception) -> str:
    """The compiler's own error lines from a pyopencl build failure, on one line."""
    lines = [ln.strip() for ln in str(exc).splitlines()]
    errs = [ln for ln in lines if any(w in ln.lower() for w in ("error", "invalid build option", "unknown target"))
            and "clBuildProgram failed" not in ln]
    return "; ".join(dict.fromkeys(errs)) or (lines[0] if lines else type(exc).__name__)


def _all_devices() -> List[Tuple[int, int, "cl.Device"]]:
    prepare_icd_environment()  # before the loader's first clGetPlatformIDs reads its variables
    out = []
    try:
        platforms = cl.get_platforms()
    except cl.Error:
        return out
    for pi, plat in enumerate(platforms):
        try:
            devs = plat.get_devices()
        except cl.Error:
            continue
        for di, dev in enumerate(devs):
            out.append((pi, di, dev))
    return out


def _device_id(dev: "cl.Device") -> Optional[str]:
    for pi, di, d in _all_devices():
        if d == dev:
            return f"{pi}:{di}"
    return None


def list_devices() -> List[dict]:
    """Every OpenCL device visible to this process, as plain dicts."""
    rows = []
    for pi, di, d in _all_devices():
        rows.append({
            "id": f"{pi}:{di}",
            "platform": d.platform.name.strip(),
            "device": d.name.strip(),
            "type": cl.device_type.to_string(d.type),
            "version": d.version.strip(),
            "driver_version": d.driver_version.strip(),
            "compute_units": d.max_compute_units,
            "global_memory_mib": d.global_mem_size >> 20,
        })
    return rows


def _match(spec: str, devices) -> Optional["cl.Device"]:
    """The first device whose platform, else whose device name, matches ``spec``."""
    s = DRIVER_ALIASES.get(spec.strip().lower(), spec.strip()).lower()
    for test in (lambda d: d.platform.name.strip().lower() == s,
                 lambda d: s in d.platform.name.lower(),
                 lambda d: s in f"{d.platform.name} {d.name}".lower()):
        for _, _, dev in devices:
            if test(dev):
                return dev
    return None


def select_device(spec: Optional[str] = None) -> "cl.Device":
    """Pick a device.

    Parameters
    ----------
    spec : str, optional
        ``"P:D"`` (platform and device index, as ``hdrcl devices`` lists them), ``"P"``,
        a driver's short name (``"pocl"``, ``"intel-cpu"``), or a case-insensitive piece
        of the platform name, else of the device name (``"nvidia"``). Default:
        ``PYOPENCL_CTX`` if set, else the first GPU, else the preferred CPU driver
        (without checking that it builds the kernels: :func:`get_context` does).
    """
    devices = _all_devices()
    if not devices:
        raise HdrclError(
            "no OpenCL device found: install a driver (on CPU-only machines: pip install 'hdrcl[cpu]') "
            "or set HDRCL_OPENCL=0 to use the slower NumPy path"
        )
    spec = spec if spec is not None else os.environ.get("PYOPENCL_CTX") or None
    if spec is None:
        return _candidates()[0]
    s = spec.strip()
    parts = s.split(":")
    if all(p.isdigit() for p in parts if p) and parts[0]:
        pi = int(parts[0])
        di = int(parts[1]) if len(parts) > 1 and parts[1] else 0
        for p_, d_, dev in devices:
            if (p_, d_) == (pi, di):
                return dev
        raise UsageError(f"OpenCL device '{spec}' does not exist; 'hdrcl devices' lists them")
    dev = _match(s, devices)
    if dev is None:
        raise UsageError(f"no OpenCL device matches '{spec}'; 'hdrcl devices' lists them")
    return dev


_contexts: Dict[str, DeviceContext] = {}
_ctx_lock = threading.Lock()
#: How the last selection went, per device id: (status, reason); for ``hdrcl devices``.
_report: Dict[str, Tuple[str, str]] = {}


def _candidates() -> List["cl.Device"]:
    """Devices in order of preference when none is named: GPUs first, then CPU drivers
    in :func:`~hdrcl.cl.drivers.cpu_driver_order`, then the rest."""
    devs = [d for _, _, d in _all_devices()]

    def rank(d):
        if d.type & cl.device_type.GPU:
            return (0, 0)
        return (1, driver_rank(d.platform.name))

    return sorted(devs, key=rank)  # stable: the loader's order within a rank


def _usable(ctx: DeviceContext) -> Optional[str]:
    """None if the device builds our kernels, else the reason it does not."""
    try:
        # the variant an 8-bit RGB merge uses, so the probe's build is not wasted
        ctx.kernel("fusion", "fuse", ("-DPIXEL_T=uchar", "-DNCH=3", "-DLEVELS=256"))
        return None
    except HdrclError as exc:
        return str(exc).splitlines()[0]
    except cl.Error as exc:  # context or queue creation failed
        return f"{ctx.name}: {str(exc).splitlines()[0]}"


def _open(dev: "cl.Device") -> Tuple[Optional[DeviceContext], Optional[str]]:
    try:
        ctx = DeviceContext(dev)
    except cl.Error as exc:
        return None, f"creating a context failed: {str(exc).splitlines()[0]}"
    return ctx, _usable(ctx)


def selection_report() -> Dict[str, Tuple[str, str]]:
    """Device id -> (status, reason) from the last default selection: ``selected``,
    ``failed`` (with the build error's first line), ``not preferred`` or ``not named``."""
    return dict(_report)


def get_context(spec: Optional[str] = None) -> DeviceContext:
    """The process's :class:`DeviceContext` for ``spec`` (created on first use).

    Without a ``spec`` (nor ``PYOPENCL_CTX``), a device that cannot build hdrcl's
    kernels is passed over for the next one: an OpenCL driver too old to know the
    processor (PoCL with LLVM 14 on AMD Zen 5 says "unknown target CPU 'generic'") must
    not stop the work when another driver on the machine can do it.
    """
    env = os.environ.get("PYOPENCL_CTX") or None
    key = spec if spec is not None else (env or "")
    with _ctx_lock:
        ctx = _contexts.get(key)
        if ctx is not None:
            return ctx
        if spec is not None or env is not None:
            named = select_device(spec)
            ctx, problem = _open(named)
            who = "--device" if spec is not None else "PYOPENCL_CTX"
            _report.clear()
            for pi, di, dev in _all_devices():
                _report[f"{pi}:{di}"] = (("not named", f"{who} names another device") if dev != named
                                         else ("failed", problem) if problem else ("selected", f"named by {who}"))
            if problem:
                raise HdrclError(problem)
        else:
            if not _all_devices():
                select_device(None)  # raises the "no OpenCL device" error
            problems = []
            _report.clear()
            any_gpu = any(d.type & cl.device_type.GPU for _, _, d in _all_devices())
            for dev in _candidates():
                did = _device_id(dev) or "?"
                if ctx is not None:
                    _report[did] = ("not preferred", "a device earlier in the order builds the kernels")
                    continue
                cand, problem = _open(dev)
                if problem is None:
                    ctx = cand
                    _report[did] = ("selected", "the first GPU that builds the kernels"
                                    if dev.type & cl.device_type.GPU else
                                    ("no GPU builds the kernels" if any_gpu else "no GPU")
                                    + "; the first CPU driver that builds them, in hdrcl's order: "
                                    + ", then ".join(cpu_driver_order()))
                    continue
                name = f"{dev.platform.name.strip()} / {dev.name.strip()}"
                logger.info("skipping OpenCL device %s: %s", name, problem)
                _report[did] = ("failed", problem)
                problems.append(problem)
            if ctx is None:
                raise HdrclError(
                    "no OpenCL device could build hdrcl's kernels (" + "; ".join(problems) + "); "
                    "see the README's troubleshooting section, or set HDRCL_OPENCL=0"
                )
        logger.info("OpenCL device: %s", ctx.name)
        _contexts[key] = ctx
        return ctx
