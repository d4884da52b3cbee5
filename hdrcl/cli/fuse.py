"""``hdrcl fuse``: exposure fusion (Mertens et al. 2007) of a bracket into one 8- or
16-bit picture, with no radiance map (OpenCV's MergeMertens, ``enfuse``)."""
from __future__ import annotations

import click

from hdrcl.cli.group import main, say
from hdrcl.cli.options import InputFile, OutputFile, check_inputs_not_outputs, device_option, field_option

_EXPONENT = click.FloatRange(0, 100)


@main.command()
@click.argument("images", nargs=-1, required=True, type=InputFile("image"))
@click.option("-o", "--output", required=True, type=OutputFile((".jpg", ".jpeg", ".png", ".tif", ".tiff"), "picture"),
              help="Picture to write: .jpg (8-bit), .png or .tif (the frames' depth).")
@click.option("--contrast", type=_EXPONENT, default=1.0, show_default=True, metavar="W",
              help="Exponent of the contrast measure (|Laplacian| of the grey); 0 turns it off.")
@click.option("--saturation", type=_EXPONENT, default=1.0, show_default=True, metavar="W",
              help="Exponent of the saturation measure (spread of R, G, B); 0 turns it off.")
@click.option("--exposedness", type=_EXPONENT, default=1.0, show_default=True, metavar="W",
              help="Exponent of the well-exposedness measure (closeness to mid-grey, sigma 0.2); "
                   "0 turns it off (OpenCV's MergeMertens default).")
@field_option("align", help=("Align hand-held frames to the middle exposure (shift, rotation, scale; see "
                             "--align-model) before fusing; a frame that cannot be aligned fails the fusion."))
@field_option("align_model")
@field_option("ignore_color")
@device_option
def fuse(images, output, contrast, saturation, exposedness, align, align_model, ignore_color, device):
    """Fuse bracketed photographs into one natural-looking picture (exposure fusion:
    weights of contrast, saturation and well-exposedness blended in a Laplacian pyramid;
    no exposure times and no response curve needed)."""
    from hdrcl.api.mertens import fuse_files

    check_inputs_not_outputs(images, output)
    done = fuse_files(images, output, contrast=contrast, saturation=saturation, exposedness=exposedness,
                      align=align, align_model=align_model, ignore_color=ignore_color, device=device)
    say(f"wrote {output}: {done['frames']} frames fused, {done['width']}x{done['height']}, {done['bits']}-bit "
        f"in {done['seconds']:.2f} s")
