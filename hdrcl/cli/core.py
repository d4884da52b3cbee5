"""Commands on one bracket set: devices, calibrate, merge, expose, demo."""
from __future__ import annotations

import json
import math
import os

import click

from hdrcl.cli.group import main, say
from hdrcl.cli.options import (
    Checked,
    InputFile,
    OutputFile,
    OutputFolder,
    bits_option,
    check_inputs_not_outputs,
    deliver_options,
    device_option,
    exposure_options,
    field_option,
    json_option,
    luminance_options,
    merge_options,
    report_option,
    response_cache_option,
    response_option,
    seconds_callback,
    size_option,
    warn_inapplicable,
)


@main.command()
@json_option()
def devices(as_json):
    """List the OpenCL devices, the one hdrcl would use, and why the others were passed over.

    Exits non-zero when no device can be used.
    """
    from hdrcl.api.devices import device_report, opencl_enabled

    if not opencl_enabled():
        msg = "OpenCL disabled (HDRCL_OPENCL=0): the NumPy reference path is used."
        click.echo(json.dumps({"devices": [], "selected": None, "selected_id": None, "problem": None,
                               "disabled": msg}, indent=1) if as_json else msg)
        return
    d = device_report()
    rows, chosen, selected_id, problem, icd = d["devices"], d["selected"], d["selected_id"], d["problem"], d["icd"]
    if as_json:
        click.echo(json.dumps({"devices": rows, "selected": chosen, "selected_id": selected_id,
                               "problem": problem, "icd": icd}, indent=1))
    else:
        if not rows:
            click.echo("no OpenCL devices found")
        for r in rows:
            mark = "*" if r["status"] == "selected" else " "
            click.echo(f"{mark} {r['id']:5s} {r['platform']} / {r['device']}  [{r['type']}, "
                       f"{r['compute_units']} units, {r['global_memory_mib']} MiB, {r['version']}, "
                       f"driver {r['driver_version']}]")
            if r["status"] == "selected":
                click.echo(f"        selected: {r['reason']}")
            elif r["status"] == "failed":
                click.echo(f"        passed over: cannot build hdrcl's kernels: {r['reason']}")
            elif r["reason"]:
                click.echo(f"        passed over: {r['status']} ({r['reason']})")
        if icd.get("set_by") == "hdrcl":
            click.echo(f"ICD list: {icd['vendors']} (written by hdrcl: Intel's CPU runtime "
                       f"{icd['intel_cpu']} and the system's drivers)")
        elif icd.get("set_by"):
            click.echo(f"ICD list: OCL_ICD_VENDORS={icd.get('vendors')} (set by the {icd['set_by']})")
        if icd.get("note"):
            click.echo(f"note: {icd['note']}")
        if chosen:
            click.echo(f"selected: {chosen}")
        if problem:
            click.echo(f"problem: {problem}")
    if problem:
        raise SystemExit(1)


def _alignment_line(a: dict) -> str:
    """One frame of ``MergeResult.alignment``: model, rotation, scale, shift, residual."""
    res = "?" if a.get("residual_px") is None else f"{a['residual_px']:.2f}"
    dy, dx = a["shift_px"]
    return (f"{os.path.basename(a['file'])}: {a['model']}, rotation {a['rotation_deg']:+.2f} deg, "
            f"scale {a['scale']:.4f}, shift ({dy:+.1f}, {dx:+.1f}) px, residual {res} px")


@main.command()
@click.argument("images", nargs=-1, required=True, type=InputFile("image"))
@click.option("-o", "--output", required=True, type=OutputFile((".json", ".rsp"), "response curve"),
              help="Response to write: hdrcl's JSON, or hdrgen's polynomials (.rsp).")
@exposure_options
@merge_options(solve=True)
def calibrate(images, output, times, times_file, **solve):
    """Recover the camera response curve from one bracket set."""
    from hdrcl.api.support import calibrate as _calibrate

    check_inputs_not_outputs(list(images) + [times_file], output)
    if str(output).lower().endswith(".rsp"):  # from the headers, before the solve
        from hdrcl.api.support import read_infos
        from hdrcl.errors import UsageError

        bits = read_infos(list(images))[0].bits
        if bits != 8:
            raise UsageError(f"{output}: hdrgen's .rsp holds 8-bit responses; {images[0]} is {bits}-bit: "
                             "write the response as .json")
    if times is None and times_file is None:
        _say_exposure_lists(images)
    resp = _calibrate(list(images), times, times_file=times_file, **solve)
    fit = resp.save(output)
    t = resp.tables()
    say(f"wrote {output}: {resp.bits}-bit response, channels {''.join(resp.channels)}, "
               f"{resp.samples} samples, lambda {resp.smoothness:g}")
    for c, name in enumerate(resp.channels):
        lo, hi = 10 * (resp.levels // 256), 245 * (resp.levels // 256)
        say(f"  {name}: g({lo}) = {t[c, lo]:+.3f}, g({hi}) = {t[c, hi]:+.3f}  "
                   f"({(t[c, hi] - t[c, lo]) / 2.302585:.2f} decades of exposure)")
    if fit is not None:  # .rsp: a polynomial fit of the solved curve
        say(f"  .rsp: polynomial orders {', '.join(map(str, fit.orders))}, largest error "
            f"{100 * (math.exp(max(fit.max_error)) - 1):.2f} % of exposure over codes 10..245")


@main.command()
@click.argument("images", nargs=-1, required=True, type=InputFile("image"))
@click.option("-o", "--output", required=True,
              type=OutputFile((".exr", ".hdr", ".tif", ".tiff", ".pfm"), "radiance map"),
              help="Radiance file: .exr, .hdr, .tif or .pfm.")
@response_option(help="Response JSON from 'hdrcl calibrate' [default: calibrate from these images].")
@click.option("--save-response", type=OutputFile((".json",), "response curve"),
              help="Also write the response used.")
@response_cache_option(type=OutputFile((".json",), "response curve"),
                       help="Response JSON used as --response when it exists and fits these frames (bit depth, "
                            "channels, camera model); otherwise calibrate from them and write the curve there (as "
                            "hdrgen -r).")
@exposure_options
@merge_options
@click.option("--ghost-mask", type=OutputFile((".png", ".tif", ".tiff"), "ghost mask"),
              help="With --deghost: write the ghost mask (PNG).")
@click.option("--clip-mask", type=OutputFile((".png", ".tif", ".tiff"), "clip mask"),
              help="Write the pixels clipped in every frame (PNG): 255 clipped high (the value is the "
                   "lower bound the shortest frame proves), 128 black in every frame.")
@report_option(help="Write a quality report here (sets accumulate in one folder): preview, input frames, "
                    "camera settings, response, histogram and coverage plots, figures, index.html.")
@click.option("--owner", default=None, metavar="TEXT",
              help="Owner / copyright recorded in the file [default: the frames' EXIF Copyright].")
@luminance_options
@deliver_options
def merge(images, output, response, save_response, response_cache, times, times_file, ghost_mask, clip_mask, report,
          owner, lens_circle, resize, fisheye_projection, vignetting, nd_filter, calibration_factor, view, deliver,
          headroom, hdr_transfer, hdr_bits, **options):
    """Merge one bracket set into a radiance map."""
    from hdrcl.api.support import DeliverOptions, MergeOptions, chain_or_none, format_time, merge_files

    # Every option once, in the options object (hdrcl.core.options: the rules that tie
    # options together too), and a frame number against the images given, before any
    # warning or decoding.
    opts = MergeOptions.from_params(options)
    opts.check_frames(len(images))
    delivery = DeliverOptions(deliver, headroom, hdr_transfer.lower(), int(hdr_bits))
    check_inputs_not_outputs(list(images) + [response, times_file], output, save_response, ghost_mask, clip_mask,
                             response_cache)
    warn_inapplicable(output, "dtype", "compression")
    chain = chain_or_none(lens_circle=lens_circle, resize=resize, projection=fisheye_projection, vignetting=vignetting,
                          nd_filter=nd_filter, calibration_factor=calibration_factor, view=view, device=opts.device,
                          output=output)  # factors checked against what the output's format holds
    delivery.refuse_with_luminance(chain is not None)
    if times is None and times_file is None:
        _say_exposure_lists(images)
    if response_cache is not None:
        response, save_response = _from_cache(response_cache, images, response, save_response)
    res = merge_files(list(images), output, opts, times=times, times_file=times_file, response=response,
                      ghost_mask=ghost_mask, clip_mask=clip_mask, thumbnail=512 if report else 0,
                      keep_frames=bool(report) or "fusion" in delivery.kinds, owner=owner, save_response=save_response, chain=chain,
                      keep_radiance=bool(delivery))
    h, w_, c = res.shape
    if chain is not None:  # the file holds the calibrated N x N map
        h = w_ = chain.size
    total = sum(res.seconds.values())
    # The shutter times as recorded where every frame has one (the merge's own exposures are
    # relative to the first frame's f-number and ISO, and may be refined from the pixels).
    shown = res.recorded if res.recorded and all(res.recorded) and times is None and times_file is None \
        else list(res.times)
    say(f"wrote {output}: {w_}x{h}, {c} channel(s), {len(res.paths)} frames "
        f"({format_time(min(shown))} .. {format_time(max(shown))}), "
        f"{'OpenCL' if res.backend == 'opencl' else 'NumPy'}, {total:.2f} s")
    cnt = res.counts
    if response is None:
        say(f"  response: spans {res.response.span_decades():.2f} decades between codes 10 and 245")
    if res.storage_note:
        say(f"  storage: {res.storage_note}")
    if chain is not None:
        ev = "" if res.vertical_illuminance is None else f", vertical illuminance {res.vertical_illuminance:.1f} lx"
        say(f"  luminance map: cd/m2 from a {res.shape[1]}x{res.shape[0]} merge{ev}")
    if res.alignment:
        say("  aligned (to " + next((os.path.basename(a["file"]) for a in res.alignment
                                     if a["model"] == "reference"), "the middle exposure") + "):")
        for a in res.alignment:
            if a["model"] != "reference":
                say("    " + _alignment_line(a))
    elif res.shifts is not None:
        say("  aligned: " + ", ".join(f"{os.path.basename(p)} ({dy:+d}, {dx:+d})"
                                      for p, (dy, dx) in zip(res.paths, res.shifts)) + " (dy, dx px)")
    if opts.deghost:
        unresolved = cnt.get("ghost_unresolved")
        say(f"  ghosts: {100.0 * cnt.get('ghost', 0) / max(res.shape[0] * res.shape[1], 1):.2f} % of pixels taken from the "
            f"{opts.ghost_reference or 'middle'} exposure"
            + (f" ({unresolved} pixel-channels unresolved)" if unresolved else ""))
    if cnt.get("clipped_high") or cnt.get("clipped_low"):
        say(f"  clipped in every frame: {cnt['clipped_high']} high, {cnt['clipped_low']} low (pixel-channels)")
    if delivery:
        from hdrcl.api.reports import deliver_beside

        for d in deliver_beside(output, res.radiance, delivery, frames=_frames_of(res, opts.ignore_color)):
            say(f"  wrote {d['path']}: {d['kind']}, {d['bytes']} bytes"
                + (f", headroom {d['headroom']:g} stops" if "headroom" in d else ""))
        res.radiance = None
    if report:
        from hdrcl.api.reports import format_figures, write_quality_report

        fig, _entry = write_quality_report(res, report, ignore_color=opts.ignore_color, weight=opts.weight,
                                           device=opts.device)
        say(f"quality report: {os.path.join(report, 'index.html')}")
        for label, text in format_figures(fig):
            say(f"  {label}: {text}")


def _frames_of(res, ignore_color):
    """``frames()`` for ``--deliver fusion``: the whole frames the merge kept (aligned ones
    included), else the files decoded again."""
    def frames():
        if res.kept is not None and not res.kept[2]:  # whole frames, not the sampling grid
            valid = list(res.kept[1])
            return list(res.kept[0]), (None if all(v is None for v in valid) else valid)
        from hdrcl.api.mertens import read_frames

        return read_frames(res.paths, ignore_color)

    return frames


def _say_exposure_lists(images) -> None:
    """One line on stderr per exposure list beside the frames that merge will use (for
    frames without EXIF exposure time; :func:`hdrcl.io.metadata.header_exposures`)."""
    from hdrcl.cli.group import quiet
    from hdrcl.api.support import header_exposures, read_infos

    if quiet() or len(images) < 2:
        return
    exposures, used = header_exposures(list(images), read_infos(list(images)))
    if any(e is None for e in exposures):
        return  # merge stops on the frame no source times, in one line
    for u in used:
        click.echo(f"hdrcl: exposures from {u} (the frames carry no EXIF exposure time)", err=True)


def _from_cache(path, images, response, save_response):
    """``(response, save_response)`` for ``--response-cache PATH``: the file as the
    response when it exists and fits the frames, else PATH as where to save the curve
    calibrated from them (a file that does not fit is replaced, with a warning)."""
    import logging

    from hdrcl.api.support import Response, read_info
    from hdrcl.errors import HdrclError, UsageError

    if response is not None or save_response is not None:
        raise UsageError("--response-cache stands for --response and --save-response: give it alone")
    if not os.path.isfile(path):
        return None, path
    from hdrcl.api.support import misfit

    try:
        resp = Response.load(path)
        why = misfit(resp, path, images[0], read_info(images[0]))
    except HdrclError as exc:
        why = str(exc).splitlines()[0]
    if why is not None:
        logging.getLogger("hdrcl.cli").warning("%s; calibrating from these frames and replacing it", why)
        return None, path
    say(f"response: {path} (cached)")
    return path, None


@main.command()
@click.argument("radiance", type=InputFile("radiance map"))
@click.option("-o", "--output", required=True,
              type=OutputFile((".jpg", ".jpeg", ".png", ".tif", ".tiff"), "photograph"), help=".jpg, .png or .tif")
@response_option(required=True)
@click.option("--time", "time_", required=True, callback=seconds_callback, metavar="SECONDS",
              help="Exposure time of the virtual photograph, e.g. 1/30.")
@bits_option(default=None, help="Output depth [default: the response's; JPEG is always 8].")
@click.option("--motion-blur", type=Checked("motion_blur"), metavar="DX,DY", default=None,
              help="Blur the radiance along this vector (pixels) before the exposure, as a moving camera would.")
@device_option
def expose(radiance, output, response, time_, bits, motion_blur, device):
    """Render a virtual photograph from a radiance map."""
    from hdrcl.api.pictures import expose_file
    from hdrcl.api.support import Response
    from hdrcl.core.params import check_expose

    check_inputs_not_outputs([radiance, response], output)
    resp = Response.load(response)
    check_expose(radiance, resp, motion_blur=motion_blur, source=response)  # headers only, before decoding
    img = expose_file(radiance, output, resp, time_, bits=int(bits) if bits else None, device=device,
                      motion_blur=motion_blur)
    say(f"wrote {output}: {img.shape[1]}x{img.shape[0]}, {8 * img.dtype.itemsize}-bit")


@main.command()
@click.argument("folder", type=OutputFolder("demo folder"))
@size_option(default="768x512")
@click.option("--frames", type=Checked("frames"), default=7, show_default=True, help="2 to 32.")
@field_option("seed", help=None)
@click.option("--no-shoot", is_flag=True, help="Skip the sample shoot and its batch.")
@device_option
def demo(folder, size, frames, seed, no_shoot, device):
    """Synthesise a bracket with a known camera, merge it, and check the result; then
    batch a generated sample shoot.

    Writes FOLDER/frames/*.png with times.txt, FOLDER/demo.exr, FOLDER/response.json
    and FOLDER/preview.jpg, and prints how close the recovered curve and radiance are
    to the truth. Then writes a small shoot of JPEGs with EXIF to FOLDER/shoot, runs
    the batch into FOLDER/batch and writes its quality report (FOLDER/batch/report).
    """
    from hdrcl.api.batch import run_demo

    w, h = (int(v) for v in size.lower().split("x"))  # checked by the option's type
    rep = run_demo(folder, width=w, height=h, frames=frames, seed=seed, device=device, shoot=not no_shoot,
                   handle_signals=True)
    say(f"synthetic bracket: {len(rep.frames)} frames in {os.path.join(folder, 'frames')} "
               f"(scene spans {rep.dynamic_range:g} decades)")
    say(f"merged with {'OpenCL' if rep.backend == 'opencl' else 'NumPy'} -> {rep.radiance}")
    say(f"response curve error: {rep.curve_error:.4f} (max |g - g_true|, ln units, levels 10-245)")
    say(f"radiance error: {100 * rep.radiance_error:.2f} % (median, well-exposed pixels)")
    say(f"response: {rep.response}   preview: {rep.preview}")
    if rep.shoot:
        skipped = f", {rep.batch_skipped} up to date" if rep.batch_skipped else ""
        say(f"sample shoot: {rep.shoot} -> batch: {rep.batch_done} set(s) merged{skipped}, "
            f"{rep.batch_failed} failed into {rep.batch}")
        say(f"quality report: {rep.contact_sheet}")
    say("next: hdrcl expose {0} -o bright.jpg --response {1} --time {2:.4g}".format(
        rep.radiance, rep.response, rep.times[-1]))
