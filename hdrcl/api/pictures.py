"""Commands on a radiance map, as the command line calls them (messages name its flags):
virtual photographs (``hdrcl expose``), tone mapping (``tonemap``), false colour
(``falsecolor``), glare figures (``glare``) and the luminance calibration factor
(``calibrate-luminance``)."""
from __future__ import annotations

from hdrcl.core.exposure.virtual import expose_file
from hdrcl.core.luminance.glare import calibrate_luminance_file, glare_of_file
from hdrcl.report.falsecolor import falsecolor_file
from hdrcl.report.tonemap import tonemap_file

__all__ = ["calibrate_luminance_file", "expose_file", "falsecolor_file", "glare_of_file", "tonemap_file"]
