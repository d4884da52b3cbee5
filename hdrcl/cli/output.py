"""Commands that turn a radiance map into a picture for people: tonemap."""
from __future__ import annotations

import click

from hdrcl.cli.group import main, say
from hdrcl.cli.options import Checked, InputFile, OutputFile, bits_option, check_inputs_not_outputs, device_option


@main.command()
@click.argument("radiance", type=InputFile("radiance map"))
@click.option("-o", "--output", required=True,
              type=OutputFile((".jpg", ".jpeg", ".png", ".tif", ".tiff"), "picture"),
              help="Picture to write: .jpg, .png or .tif (sRGB-encoded).")
@click.option("--operator", type=click.Choice(["reinhard", "reinhard-local", "drago", "filmic"]),
              default="reinhard", show_default=True,
              help="Tone-mapping operator: Reinhard 2002 global or local (dodging and burning), "
                   "Drago 2003 adaptive logarithmic, or Hable's filmic curve.")
@click.option("--exposure", type=Checked("exposure"), default=0.0, show_default=True, metavar="EV",
              help="Brighten (+) or darken (-) the scene by this many stops before the operator.")
@bits_option(default="8", show_default=True, help="Output depth (JPEG holds 8 bits only).")
@device_option
def tonemap(radiance, output, operator, exposure, bits, device):
    """Tone-map a radiance map (EXR, HDR, TIFF, PFM) into a picture for display.

    ACEScg files are converted to Rec.709 first. The global operators run as an OpenCL
    kernel; reinhard-local runs on the CPU.
    """
    import time

    from hdrcl.api.pictures import tonemap_file

    check_inputs_not_outputs([radiance], output)
    t0 = time.perf_counter()
    img = tonemap_file(radiance, output, operator, exposure=exposure, bits=int(bits), device=device)
    say(f"wrote {output}: {img.shape[1]}x{img.shape[0]}, {8 * img.dtype.itemsize}-bit sRGB, "
               f"{operator}{f', {exposure:+g} EV' if exposure else ''}, {time.perf_counter() - t0:.2f} s")
