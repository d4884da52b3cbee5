"""The library's entry points as the command line calls them, loaded on first use.

The names of :mod:`hdrcl.api` itself rewrite their messages for Python callers
(``times: ...`` rather than ``--times: ...``); the command line takes the same
functions from here, where messages keep naming its flags. Besides them: the time
format, the option defaults, output checks, the luminance chain's options, the report's
figures. Each name is the library's own object (the table below says where it lives);
nothing here has behaviour of its own.
"""
from __future__ import annotations

import importlib

#: name -> module that defines it.
_WHERE = {
    "MergeOptions": "hdrcl.core.options",
    "DeliverOptions": "hdrcl.core.options",
    "deliver_beside": "hdrcl.report.deliver",
    "merge_files": "hdrcl.core.merge",
    "calibrate": "hdrcl.core.calibrate",
    "tonemap_file": "hdrcl.report.tonemap",
    "write_quality_report": "hdrcl.report.merge_report",
    "format_time": "hdrcl.io.metadata",
    "parse_times": "hdrcl.io.exposure_lists",
    "header_exposures": "hdrcl.io.metadata",
    "read_info": "hdrcl.io.frames",
    "read_infos": "hdrcl.core.bracket",
    "check_output": "hdrcl.io.atomic",
    "check_output_folder": "hdrcl.io.atomic",
    "inapplicable_options": "hdrcl.io.outmeta",
    "chain_or_none": "hdrcl.core.luminance.fisheye",
    "parse_patch": "hdrcl.core.radiometry",
    "Response": "hdrcl.core.response",
    "misfit": "hdrcl.core.response_cache",
    "DEFAULT_SMOOTHNESS": "hdrcl.core.response",
    "DEFAULT_WEIGHT": "hdrcl.core.weights",
    "WEIGHTS": "hdrcl.core.weights",
    "THRESHOLD": "hdrcl.core.deghost",
    "format_figures": "hdrcl.report.pages",
    "falsecolor_file": "hdrcl.report.falsecolor",
    "glare_of_file": "hdrcl.core.luminance.glare",
    "glare_metrics": "hdrcl.core.luminance.glare",
    "calibrate_luminance_file": "hdrcl.core.luminance.glare",
    "calibrate_luminance_file": "hdrcl.core.luminance.glare",
    "expose_file": "hdrcl.core.exposure.virtual",
}

__all__ = sorted(_WHERE)


def __getattr__(name):
    where = _WHERE.get(name)
    if where is None:
        raise AttributeError(f"module 'hdrcl.api.support' has no attribute {name!r}")
    value = getattr(importlib.import_module(where), name)
    globals()[name] = value
    return value
