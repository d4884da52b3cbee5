"""``hdrcl falsecolor``: a false-colour picture of a luminance map, with a legend in cd/m^2."""
from __future__ import annotations

import click

from hdrcl.cli.group import main, say
from hdrcl.cli.options import InputFile, OutputFile, check_inputs_not_outputs


@main.command()
@click.argument("luminance_map", type=InputFile("luminance map"))
@click.option("-o", "--output", required=True, type=OutputFile((".png", ".jpg", ".jpeg", ".tif", ".tiff"), "picture"),
              help="Picture to write (.png, .jpg or .tif, 8-bit), the legend on its right.")
@click.option("--scale", type=click.Choice(["linear", "log"]), default="linear", show_default=True,
              help="Colour scale of the luminance.")
@click.option("--max", "hi", type=float, default=None, metavar="CD",
              help="Luminance (cd/m2) at the top of the scale [default: the largest, rounded up to 1, 2 or 5 x 10^k].")
@click.option("--min", "lo", type=float, default=None, metavar="CD",
              help="Luminance (cd/m2) at the bottom of the scale [default: 0 linear, max/10^4 log].")
def falsecolor(luminance_map, output, scale, hi, lo):
    """False-colour picture of a luminance map (.hdr in Radiance's 179 lm/W convention,
    or an EXR in cd/m2 written by 'hdrcl merge --absolute' or the fisheye chain)."""
    from hdrcl.report.falsecolor import falsecolor_file

    check_inputs_not_outputs([luminance_map], output)
    lo, hi = falsecolor_file(luminance_map, output, scale=scale, lo=lo, hi=hi)
    say(f"wrote {output}: {scale} scale {lo:g} .. {hi:g} cd/m2")
