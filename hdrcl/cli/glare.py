"""``hdrcl glare``: vertical illuminance, DGP, DGI, UGR and the glare sources of a
calibrated fisheye luminance map, by evalglare's method (:mod:`hdrcl.core.luminance.glare`);
``hdrcl calibrate-luminance``: the calibration factor from a measurement, as a ``.cal``."""
from __future__ import annotations

import json

import click

from hdrcl.cli.group import main, say
from hdrcl.cli.options import InputFile, OutputFile, check_inputs_not_outputs, json_option, view_option


@main.command()
@click.argument("luminance_map", type=InputFile("luminance map"))
@json_option(help="Print the figures and the sources as one JSON object.")
@view_option(help="Radiance view of the map (e.g. '-vta -vh 180 -vv 180') [default: its VIEW=].")
@click.option("--threshold", type=float, default=2000.0, show_default=True, metavar="B",
              help="Glare source threshold as evalglare's -b: above 100 a luminance in cd/m2, "
                   "otherwise a factor of the map's average luminance (evalglare's older default: 5).")
def glare(luminance_map, as_json, view, threshold):
    """Glare metrics of a calibrated fisheye map with VIEW= (hdrcl's luminance chain, or a
    Radiance picture in its 179 lm/W convention): as evalglare computes them."""
    from hdrcl.api.pictures import glare_of_file

    res = glare_of_file(luminance_map, view=view, threshold=threshold)
    if as_json:
        click.echo(json.dumps(res.as_dict(), indent=1))
        return
    say(f"{luminance_map}: VIEW= {res.view}")
    say(f"vertical illuminance {res.vertical_illuminance:.1f} lx; DGP {res.dgp:.4f}, DGI {res.dgi:.2f}, "
        f"UGR {res.ugr:.2f}")
    say(f"average luminance {res.average_luminance:.1f} cd/m2, background {res.background_luminance:.1f} cd/m2, "
        f"threshold {res.threshold:g} cd/m2, {len(res.sources)} glare source(s)")
    for i, s in enumerate(res.sources, 1):
        say(f"  {i}: {s.luminance:.6g} cd/m2, {s.solid_angle:.4g} sr, position index {s.position_index:.3f}, "
            f"at column {s.column:.1f}, row {s.row:.1f} ({s.pixels} pixels, up to {s.max_luminance:.6g} cd/m2)")


@main.command(name="calibrate-luminance")
@click.argument("luminance_map", type=InputFile("luminance map"))
@click.option("-o", "--output", required=True, type=OutputFile((".cal",), "calibration factor"),
              help="The calibration factor .cal to write (ro=ri(1)*K; ...: the lab tools and pcomb read it).")
@click.option("--illuminance", type=float, default=None, metavar="LUX",
              help="Vertical illuminance measured at the lens (lux), against the map's (as evalglare -V).")
@click.option("--luminance", type=float, default=None, metavar="CD",
              help="Luminance measured on a patch (cd/m2), against the map's mean over --patch.")
@click.option("--patch", default=None, metavar="COLUMN,ROW,RADIUS",
              help="The measured spot in pixels of the map (from its top left).")
@view_option(help="Radiance view of the map [default: its VIEW=].")
def calibrate_luminance(luminance_map, output, illuminance, luminance, patch, view):
    """Derive the calibration factor K from a measured vertical illuminance or patch
    luminance and write it as a .cal (give it to --calibration-factor, or to pcomb -f)."""
    from hdrcl.api.pictures import calibrate_luminance_file

    check_inputs_not_outputs([luminance_map], output)
    r = calibrate_luminance_file(luminance_map, output, illuminance=illuminance, luminance=luminance, patch=patch,
                                 view=view)
    say(f"wrote {output}: calibration factor {r['calibration_factor']:.6g} (measured {r['measured']:g} / map "
        f"{r['map_value']:.6g} {r['quantity']}, x the map's own {r['previous_factor']:g})")
