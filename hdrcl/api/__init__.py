"""The public API of hdrcl: what scripts, pipelines and the command line call.

Nothing is loaded until a name is used (the command line's start-up stays light):

- :mod:`hdrcl.api.merging` -- one bracket: ``calibrate``, ``merge``, ``merge_files``,
  ``merge_bracket``, ``load_bracket``, ``expose``, ``expose_file``, ``tonemap``,
  ``tonemap_file``, ``write_quality_report``, and the records ``MergeOptions``,
  ``MergeResult``, ``Response``, ``Bracket``;
- :mod:`hdrcl.api.batch` -- a whole shoot: ``run_batch``, ``describe_batch``,
  ``BatchOptions``, scanning and manifests;
- :mod:`hdrcl.api.devices` -- the OpenCL devices;
- :mod:`hdrcl.api.options` -- ``MergeOptions`` (each merge option declared once) and
  ``DeliverOptions``;
- :mod:`hdrcl.api.support`, :mod:`hdrcl.api.reports`, :mod:`hdrcl.api.pictures` -- the
  library's functions as the command line calls them (messages naming its flags), and the
  helpers it shares with the library (time formats, output checks), imported plainly.

The command line (:mod:`hdrcl.cli`) imports only this package, the option table
(:mod:`hdrcl.core.params`) and :mod:`hdrcl.errors` (``tests/test_layers.py``)::

    import hdrcl
    resp = hdrcl.calibrate(["a.jpg", "b.jpg", "c.jpg"], times=["1/250", "1/60", "1/15"])
    radiance = hdrcl.merge(["a.jpg", "b.jpg", "c.jpg"], times="1/250,1/60,1/15", response=resp)
"""
from __future__ import annotations

#: The names of :mod:`hdrcl.api.merging`, loaded on first use.
_MERGING = ("Bracket", "MergeOptions", "MergeResult", "Response", "calibrate", "expose", "expose_file",
            "exposures_used", "load_bracket", "memory_budget", "merge", "merge_bracket", "merge_files",
            "read_infos", "tonemap", "tonemap_file", "write_quality_report", "python_words")

__all__ = sorted(n for n in _MERGING if n != "python_words")


def __getattr__(name):
    if name in _MERGING:
        from hdrcl.api import merging

        value = getattr(merging, name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'hdrcl.api' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
