"""The library's entry points as the command line's ``merge`` and ``calibrate`` call them,
and the helpers every command shares: time formats, exposure lists, the frames' headers,
output checks, the luminance chain's options.

The names of :mod:`hdrcl.api` itself rewrite their messages for Python callers
(``times: ...`` rather than ``--times: ...``); the command line takes the same
functions from here, where messages keep naming its flags. Each name is the library's
own object, imported plainly (the layer test sees what the command line depends on);
nothing here has behaviour of its own. The command line imports this module inside its
commands, not at start-up. What only some commands need is in :mod:`hdrcl.api.reports`
(``merge --report``, ``--deliver``) and :mod:`hdrcl.api.pictures` (``expose``,
``tonemap``, ``falsecolor``, ``glare``, ``calibrate-luminance``).
"""
from __future__ import annotations

from hdrcl.core.bracket import read_infos
from hdrcl.core.calibrate import calibrate
from hdrcl.core.luminance.fisheye import chain_or_none
from hdrcl.core.merge import merge_files
from hdrcl.core.options import DeliverOptions, MergeOptions
from hdrcl.core.response import Response
from hdrcl.core.response_cache import misfit
from hdrcl.io.atomic import check_output, check_output_folder
from hdrcl.io.exposure_lists import parse_times
from hdrcl.io.frames import read_info
from hdrcl.io.metadata import format_time, header_exposures
from hdrcl.io.outmeta import inapplicable_options

__all__ = ["DeliverOptions", "MergeOptions", "Response", "calibrate", "chain_or_none", "check_output",
           "check_output_folder", "format_time", "header_exposures", "inapplicable_options",
           "merge_files", "misfit", "parse_times", "read_info", "read_infos"]
