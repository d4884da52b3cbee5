"""``hdrcl falsecolor``: a false-colour picture of a luminance map as Radiance's
``falsecolor`` draws it, with a legend in cd/m^2."""
from __future__ import annotations

import click

from hdrcl.cli.group import main, say
from hdrcl.cli.options import InputFile, OutputFile, check_inputs_not_outputs


@main.command()
@click.argument("luminance_map", type=InputFile("luminance map"))
@click.option("-o", "--output", required=True, type=OutputFile((".png", ".jpg", ".jpeg", ".tif", ".tiff"), "picture"),
              help="Picture to write (.png, .jpg or .tif, 8-bit), the legend on its right.")
@click.option("--scale", type=click.Choice(["linear", "log"]), default="linear", show_default=True,
              help="Colour scale of the luminance (log: Radiance's -log, decades = log10(max/min)).")
@click.option("--max", "hi", type=float, default=None, metavar="CD",
              help="Top of the scale (Radiance's -s) [default: linear, the 99th percentile rounded up to "
                   "1, 2 or 5 x 10^k; log, the largest rounded up to a power of ten].")
@click.option("--min", "lo", type=float, default=None, metavar="CD",
              help="Bottom of the scale [default: 0 linear; log, decades down to the 1st percentile].")
@click.option("--palette", "palette_name", type=click.Choice(["def", "spec", "hot", "pm3d", "eco"]), default="def",
              show_default=True, help="Radiance's palettes (-pal): def is its default, spec the older one.")
@click.option("--contour", type=click.Choice(["lines", "bands"]), default=None,
              help="Radiance's contour lines (-cl) or bands (-cb) at the divisions, black between.")
@click.option("--divisions", "ndivs", type=click.IntRange(1, 100), default=8, show_default=True,
              help="Steps of the legend and contours (Radiance's -n).")
@click.option("--extrema", "show_extrema", is_flag=True, help="Label the smallest and largest value at their pixels (-e).")
@click.option("--multiplier", type=float, default=1.0, show_default=True, metavar="M",
              help="Multiply the luminance (Radiance's -m, whose 179 is already applied: cd/m2 x M).")
@click.option("--label", default="cd/m2", show_default=True, help="Unit shown in the legend (-l).")
def falsecolor(luminance_map, output, scale, hi, lo, palette_name, contour, ndivs, show_extrema, multiplier, label):
    """False-colour picture of a luminance map (.hdr in Radiance's 179 lm/W convention,
    or an EXR in cd/m2 written by 'hdrcl merge --absolute' or the fisheye chain), in
    Radiance's colours."""
    from hdrcl.api.pictures import falsecolor_file

    check_inputs_not_outputs([luminance_map], output)
    lo, hi = falsecolor_file(luminance_map, output, scale=scale, lo=lo, hi=hi, palette_name=palette_name,
                             contour=contour, ndivs=ndivs, show_extrema=show_extrema, multiplier=multiplier,
                             label=label)
    say(f"wrote {output}: {scale} scale {lo:g} .. {hi:g} {label}")
