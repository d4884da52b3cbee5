"""OpenCL CPU drivers installed from PyPI, made visible to the ICD loader.

Two CPU drivers come from PyPI (``pip install "hdrcl[cpu]"``):

* **PoCL** (``pocl-binary-distribution``, bundled in pyopencl's wheel as
  ``pyopencl/.libs/pocl.icd``): pyopencl's ICD loader always finds it. Built on LLVM 14,
  it cannot compile for processors newer than LLVM 14 knows (AMD Zen 5: "unknown target
  CPU 'generic'").
* **Intel's OpenCL CPU runtime** (``intel-opencl-rt`` with ``intel-cmplr-lib-rt``): runs
  on any x86-64 processor with SSE4.2, AMD included. Its wheel puts ``libintelocl.so`` in
  ``<prefix>/lib`` but its ``etc/OpenCL/vendors/intel-cpu.icd`` names a placeholder path
  (``/opt/anaconda1anaconda2anaconda3/lib/libintelocl.so``), so no loader finds it.

:func:`prepare_icd_environment` (called by :mod:`hdrcl.cl.context` before the first
``clGetPlatformIDs``) writes a private vendors folder holding an ICD file that names the
real library, plus copies of the system's ICD files (``/etc/OpenCL/vendors`` or
``OPENCL_VENDOR_PATH``) so GPU drivers are still found, and points ``OCL_ICD_VENDORS``
at it. It does nothing when the user has set ``OCL_ICD_VENDORS`` or
``OCL_ICD_FILENAMES`` (their choice stands), off Linux, or when no Intel runtime is
installed in this environment. ``HDRCL_ICD_SETUP=0`` turns it off.

The ICD loader reads these variables once, at the process's first OpenCL call, so they
must be set before then; child processes inherit them.
"""
from __future__ import annotations

import hashlib
import os
import site
import sys
import tempfile
from typing import Dict, List, Optional

from hdrcl.env import flag as env_flag

#: Platform names of the CPU drivers, in hdrcl's order of preference when no GPU builds
#: the kernels. Intel's runtime first: it builds on every x86-64 processor and its fusion
#: kernel was faster than the PyPI PoCL's where both work (docs/install.md, "Which OpenCL
#: device runs"). ``HDRCL_CPU_DRIVERS`` reorders them.
CPU_DRIVER_PREFERENCE = ("Intel(R) OpenCL", "Portable Computing Language")

#: Short names accepted by ``--device`` / ``PYOPENCL_CTX`` for a driver's platform.
DRIVER_ALIASES = {
    "pocl": "Portable Computing Language",
    "portable": "Portable Computing Language",
    "intel-cpu": "Intel(R) OpenCL",
    "intel": "Intel(R) OpenCL",
}

_MARK = "HDRCL_ICD_VENDORS"  # set beside OCL_ICD_VENDORS when hdrcl set it
_state: Dict[str, Optional[str]] = {}


def _prefixes() -> List[str]:
    out = []
    for p in (sys.prefix, sys.exec_prefix, getattr(site, "USER_BASE", None) or site.getuserbase()):
        if p and p not in out:
            out.append(p)
    return out


def find_intel_cpu_runtime() -> Optional[str]:
    """Absolute path of ``libintelocl.so`` installed in this environment, or None."""
    for prefix in _prefixes():
        lib = os.path.join(prefix, "lib", "libintelocl.so")
        if os.path.isfile(lib):
            return os.path.realpath(lib)
    return None


def _missing_intel_deps(lib: str) -> List[str]:
    """Libraries the Intel runtime needs beside it that are not there (a partial install)."""
    here = os.path.dirname(lib)
    return [n for n in ("libimf.so", "libsvml.so", "libirng.so", "libintlc.so.5", "libtbb.so.12")
            if not os.path.exists(os.path.join(here, n))]


def system_vendors_dir() -> str:
    return os.environ.get("OPENCL_VENDOR_PATH") or "/etc/OpenCL/vendors"


def _system_icds() -> Dict[str, str]:
    d = system_vendors_dir()
    out = {}
    try:
        names = sorted(os.listdir(d))
    except OSError:
        return out
    for n in names:
        if n.endswith(".icd"):
            try:
                with open(os.path.join(d, n)) as f:
                    out[n] = f.read()
            except OSError:
                continue
    return out


def cache_root() -> str:
    """hdrcl's cache folder: ``HDRCL_CACHE_DIR``, else ``$XDG_CACHE_HOME/hdrcl``, else
    ``~/.cache/hdrcl`` (the OpenCL vendors list, built kernel binaries)."""
    from hdrcl.env import text

    own = text("HDRCL_CACHE_DIR")
    if own:
        return own
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "hdrcl")


def _write_vendors(files: Dict[str, str]) -> str:
    """A folder holding exactly ``files`` (name -> content), reused across processes."""
    digest = hashlib.sha1(repr(sorted(files.items())).encode()).hexdigest()[:16]
    for root in (cache_root(), os.path.join(tempfile.gettempdir(), f"hdrcl-{os.getuid()}")):
        final = os.path.join(root, f"opencl-vendors-{digest}")
        try:
            if all(_read(os.path.join(final, n)) == c for n, c in files.items()):
                return final
            os.makedirs(root, mode=0o700, exist_ok=True)
            tmp = tempfile.mkdtemp(prefix=".vendors-", dir=root)
            for n, c in files.items():
                with open(os.path.join(tmp, n), "w") as f:
                    f.write(c)
            try:
                os.rename(tmp, final)  # atomic; another process may have won the race
            except OSError:
                for n in files:
                    os.remove(os.path.join(tmp, n))
                os.rmdir(tmp)
            if all(_read(os.path.join(final, n)) == c for n, c in files.items()):
                return final
        except OSError:
            continue
    raise OSError("no writable folder for the OpenCL vendors list")


def _read(path: str) -> Optional[str]:
    try:
        with open(path) as f:
            return f.read()
    except OSError:
        return None


def prepare_icd_environment() -> Dict[str, Optional[str]]:
    """Make the Intel CPU runtime installed in this environment visible (once per process).

    Returns what was done, for ``hdrcl devices``: ``vendors`` (the folder the loader
    reads), ``set_by`` (``"hdrcl"``, ``"user"``, ``"parent"`` or None), ``intel_cpu``
    (the library found, or None) and ``note`` (why nothing was done, if so).
    """
    if _state:
        return dict(_state)
    st: Dict[str, Optional[str]] = {"vendors": None, "set_by": None, "intel_cpu": None, "note": None}
    try:
        st["intel_cpu"] = find_intel_cpu_runtime()
        user = os.environ.get("OCL_ICD_VENDORS") or os.environ.get("OCL_ICD_FILENAMES")
        if user:
            ours = os.environ.get(_MARK)
            st["set_by"] = "parent" if ours and ours == os.environ.get("OCL_ICD_VENDORS") else "user"
            st["vendors"] = os.environ.get("OCL_ICD_VENDORS")
            if st["set_by"] == "user":
                st["note"] = "OCL_ICD_VENDORS/OCL_ICD_FILENAMES set by the user: left as they are"
        elif not env_flag("HDRCL_ICD_SETUP"):
            st["note"] = "HDRCL_ICD_SETUP=0: the ICD loader's own search is used"
        elif not sys.platform.startswith("linux"):
            st["note"] = "not Linux: the ICD loader's own search is used"
        elif st["intel_cpu"] is None:
            st["note"] = "Intel's OpenCL CPU runtime is not installed in this environment"
        else:
            lib = st["intel_cpu"]
            missing = _missing_intel_deps(lib)
            system = _system_icds()
            if any("libintelocl" in c for c in system.values()):
                st["note"] = f"{system_vendors_dir()} already lists an Intel CPU runtime"
            else:
                if missing:  # the loader will skip it; say why rather than fail silently
                    st["note"] = (f"{lib} lacks {', '.join(missing)} beside it "
                                  "(pip install intel-cmplr-lib-rt)")
                files = dict(system)
                files["hdrcl-intel-cpu.icd"] = lib + "\n"
                d = _write_vendors(files)
                os.environ["OCL_ICD_VENDORS"] = d
                os.environ[_MARK] = d
                st["vendors"], st["set_by"] = d, "hdrcl"
    except Exception as exc:  # never stop OpenCL because of this convenience
        st["note"] = f"could not prepare the OpenCL vendors list: {exc}"
    _state.update(st)
    return dict(st)


def cpu_driver_order() -> List[str]:
    """Platform names of the CPU drivers in the order they are tried:
    ``HDRCL_CPU_DRIVERS`` (comma-separated short or platform names, e.g. ``pocl,intel-cpu``)
    first, then :data:`CPU_DRIVER_PREFERENCE`."""
    order: List[str] = []
    from hdrcl.env import text

    for item in (text("HDRCL_CPU_DRIVERS") or "").split(","):
        name = DRIVER_ALIASES.get(item.strip().lower(), item.strip())
        if name and name not in order:
            order.append(name)
    return order + [p for p in CPU_DRIVER_PREFERENCE if p not in order]


def driver_rank(platform_name: str) -> int:
    """Position of a CPU driver in :func:`cpu_driver_order` (unknown ones last)."""
    name = platform_name.strip().lower()
    order = [p.lower() for p in cpu_driver_order()]
    return order.index(name) if name in order else len(order)
