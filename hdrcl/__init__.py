"""hdrcl: OpenCL-accelerated HDR radiance maps from bracketed photographs.

Implements Debevec & Malik, "Recovering High Dynamic Range Radiance Maps from
Photographs" (SIGGRAPH 1997): the response curve is solved on the CPU (scipy), fusion
and virtual exposures run as OpenCL kernels (``kernels/``), with float64 NumPy twins in
:mod:`hdrcl.core.reference`.

Importing hdrcl is cheap: no OpenCL device scan and no OpenImageIO load happen until
they are needed.
"""
from hdrcl.version import __version__

__all__ = [
    "calibrate", "merge", "expose", "merge_files", "expose_file", "load_bracket", "tonemap", "tonemap_file",
    "Response", "HdrclError", "__version__",
]


def __getattr__(name):
    if name in ("calibrate", "merge", "expose", "merge_files", "expose_file", "load_bracket", "merge_bracket",
                "tonemap", "tonemap_file"):
        from hdrcl import api

        return getattr(api, name)
    if name == "Response":
        from hdrcl.core.response import Response

        return Response
    if name == "HdrclError":
        from hdrcl.errors import HdrclError

        return HdrclError
    raise AttributeError(f"module 'hdrcl' has no attribute {name!r}")
