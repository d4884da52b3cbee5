"""The options objects of a merge, for the command line's option declarations (loaded at
start-up, so kept light): :class:`MergeOptions`, each option declared once with its help
and spelling, from which ``hdrcl merge``, ``batch`` and ``calibrate`` make their click
options (:mod:`hdrcl.cli.options`), and :class:`DeliverOptions`."""
from __future__ import annotations

from hdrcl.core.options import DeliverOptions, MergeOptions

__all__ = ["DeliverOptions", "MergeOptions"]
