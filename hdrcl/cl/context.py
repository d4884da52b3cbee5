"""OpenCL device selection and the per-process context cache.

Devices are chosen without interaction: an explicit ``device`` string, else
``PYOPENCL_CTX`` (pyopencl's own convention, e.g. ``0`` or ``0:1``; ``portable``
selects PoCL), else the first GPU, else the first device of any kind.
"""
from __future__ import annotations

import logging
import os
import threading
from typing import Dict, List, Optional, Tuple

import pyopencl as cl

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
                try:
                    prg = cl.Program(self.context, kernel_source(source)).build(options=list(options))
                except cl.Error as exc:
                    raise HdrclError(
                        f"building kernels/{source}.cl for {self.name} failed: {_build_error(exc)}"
                    ) from exc
                for k in prg.all_kernels():
                    self._kernels[(source, k.function_name, key[2])] = k
                knl = self._kernels[key]
            return knl


def _build_error(exc: Exception) -> str:
    """The compiler's own error lines from a pyopencl build failure, on one line."""
    lines = [ln.strip() for ln in str(exc).splitlines()]
    errs = [ln for ln in lines if "error" in ln.lower() and "clBuildProgram failed" not in ln]
    return "; ".join(dict.fromkeys(errs)) or (lines[0] if lines else type(exc).__name__)


def _all_devices() -> List[Tuple[int, int, "cl.Device"]]:
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
            "compute_units": d.max_compute_units,
            "global_memory_mib": d.global_mem_size >> 20,
        })
    return rows


def select_device(spec: Optional[str] = None) -> "cl.Device":
    """Pick a device.

    Parameters
    ----------
    spec : str, optional
        ``"P:D"`` (platform and device index, as ``hdrcl devices`` lists them), ``"P"``,
        or a case-insensitive piece of the platform or device name (``"pocl"``,
        ``"nvidia"``). Default: ``PYOPENCL_CTX`` if set, else the first GPU, else the
        first device.
    """
    devices = _all_devices()
    if not devices:
        raise HdrclError(
            "no OpenCL device found: install a driver (on CPU-only machines: pip install 'hdrcl[pocl]') "
            "or set HDRCL_OPENCL=0 to use the slower NumPy path"
        )
    spec = spec if spec is not None else os.environ.get("PYOPENCL_CTX") or None
    if spec is None:
        gpus = [d for _, _, d in devices if d.type & cl.device_type.GPU]
        return gpus[0] if gpus else devices[0][2]
    s = spec.strip()
    if s.lower() == "portable":
        s = "portable computing language"
    parts = s.split(":")
    if all(p.isdigit() for p in parts if p) and parts[0]:
        pi = int(parts[0])
        di = int(parts[1]) if len(parts) > 1 and parts[1] else 0
        for p_, d_, dev in devices:
            if (p_, d_) == (pi, di):
                return dev
        raise UsageError(f"OpenCL device '{spec}' does not exist; 'hdrcl devices' lists them")
    for _, _, dev in devices:
        if s.lower() in f"{dev.platform.name} {dev.name}".lower():
            return dev
    raise UsageError(f"no OpenCL device matches '{spec}'; 'hdrcl devices' lists them")


_contexts: Dict[str, DeviceContext] = {}
_ctx_lock = threading.Lock()


def _candidates() -> List["cl.Device"]:
    """Devices in order of preference when none is named: GPUs first."""
    devs = [d for _, _, d in _all_devices()]
    return sorted(devs, key=lambda d: 0 if d.type & cl.device_type.GPU else 1)


def _usable(ctx: DeviceContext) -> Optional[str]:
    """None if the device builds our kernels, else the reason it does not."""
    try:
        # the variant an 8-bit RGB merge uses, so the probe's build is not wasted
        ctx.kernel("fusion", "fuse", ("-DPIXEL_T=uchar", "-DNCH=3", "-DLEVELS=256"))
        return None
    except HdrclError as exc:
        return str(exc).splitlines()[0]


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
            ctx = DeviceContext(select_device(spec))
            problem = _usable(ctx)
            if problem:
                raise HdrclError(problem)
        else:
            if not _all_devices():
                select_device(None)  # raises the "no OpenCL device" error
            problems = []
            for dev in _candidates():
                cand = DeviceContext(dev)
                problem = _usable(cand)
                if problem is None:
                    ctx = cand
                    break
                logger.info("skipping OpenCL device %s: %s", cand.name, problem)
                problems.append(problem)
            if ctx is None:
                raise HdrclError(
                    "no OpenCL device could build hdrcl's kernels (" + "; ".join(problems) + "); "
                    "see the README's troubleshooting section, or set HDRCL_OPENCL=0"
                )
        logger.info("OpenCL device: %s", ctx.name)
        _contexts[key] = ctx
        return ctx
