"""hdrcl: OpenCL-accelerated HDR radiance maps from bracketed photographs.

Implements Debevec & Malik, "Recovering High Dynamic Range Radiance Maps from
Photographs" (SIGGRAPH 1997): the response curve is solved on the CPU (scipy), fusion
and virtual exposures run as OpenCL kernels (``kernels/``), with float64 NumPy twins in
:mod:`hdrcl.core.reference`.

Importing hdrcl is cheap: no OpenCL device scan, no NumPy and no OpenImageIO load happen
until a function is used (the public names below are loaded on first access; ``dir(hdrcl)``
lists them). Errors are :class:`HdrclError` subclasses; warnings are issued as
:class:`HdrclWarning` through :mod:`warnings` and logged on the ``hdrcl`` logger.
"""
from hdrcl.errors import (
    HdrclError,
    HdrclWarning,
    InputError,
    ProcessingError,
    UsageError,
)
from hdrcl.version import __version__

#: Public names from :mod:`hdrcl.api`, imported on first use.
_API = ("calibrate", "merge", "expose", "merge_files", "expose_file", "load_bracket", "merge_bracket",
        "write_quality_report", "tonemap", "tonemap_file", "Response", "Bracket", "MergeResult")

__all__ = sorted(_API + ("HdrclError", "HdrclWarning", "InputError", "ProcessingError", "UsageError",
                         "__version__"))


def __getattr__(name):
    if name in _API:
        from hdrcl import api  # installs the warnings bridge (first use of the API)

        value = getattr(api, name)
        globals()[name] = value  # later look-ups skip this function
        return value
    raise AttributeError(f"module 'hdrcl' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
