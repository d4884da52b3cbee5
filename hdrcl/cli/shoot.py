"""Commands on a whole shoot: scan, batch, sample-shoot.

Exit codes of ``batch``: 0 every selected set done or up to date; 1 some set (or, for
a whole-folder run, some input file) failed while the rest completed; 2 usage error;
3 the folder, manifest or response file cannot be read.
"""
from __future__ import annotations

import json
import os
import sys
import time

import click

from hdrcl.cli.group import main, say
from hdrcl.cli.group import quiet as is_quiet
from hdrcl.cli.options import (
    FOR_THE_FRAMES_IT_LISTS,
    Checked,
    InputPath,
    OutputFile,
    OutputFolder,
    sets_callback,
    deliver_options,
    field_option,
    grouping_options,
    json_option,
    luminance_options,
    merge_options,
    output_format_option,
    report_option,
    response_cache_option,
    response_option,
    size_option,
    times_file_option,
)

# ------------------------------------------------------------------------- scan


@main.command()
@click.argument("source", type=InputPath("manifest"))
@grouping_options
@click.option("-o", "--output", type=OutputFile((".json",), "manifest"),
              help="Write the manifest (JSON, paths relative to its folder) for 'hdrcl batch'.")
@json_option(help="Print the grouping as one JSON object.")
@click.option("--explain", is_flag=True,
              help="Show every frame with the reason it joined its set, and why each set ended.")
@click.option("--content/--no-content", default=True, show_default=True,
              help="Compare the frames' content (small exposure-normalised thumbnails) as well as their headers.")
@times_file_option(help=FOR_THE_FRAMES_IT_LISTS)
@click.pass_context
def scan(ctx, source, recursive, frames_per_set, gap, output, as_json, explain, content, times_file):
    """Group the photographs of a folder into bracket sets.

    SOURCE is a folder, or a manifest written by 'scan -o' (possibly edited by hand:
    move files between sets, split or join sets, add "exposures"), which is then
    checked and shown. Exit code 1 when a set of a manifest cannot be merged.

    \b
    hdrcl scan shoot/ -o shoot/manifest.json
    hdrcl scan shoot/manifest.json          # after editing it
    """
    from hdrcl.api.batch import check_manifest, format_explain, format_table, load_source, save_manifest

    recursive = _descend(source, recursive)
    manifest = load_source(source, recursive=recursive, frames_per_set=frames_per_set, gap=gap,
                           times_file=times_file, content=content)
    problems = {} if os.path.isdir(source) else check_manifest(manifest)
    if output:
        save_manifest(manifest, output)
    if as_json:
        d = manifest.to_dict()
        for s in d["sets"]:
            if s["index"] in problems:
                s["problem"] = problems[s["index"]]
        click.echo(json.dumps(d, indent=1))
    else:
        if explain:
            click.echo(format_explain(manifest))
            click.echo("")
        click.echo(format_table(manifest))
        for i in sorted(problems):
            click.echo(f"set {i} cannot be merged: {problems[i]}")
    if output:
        say(f"wrote {output}: {len(manifest.sets)} set(s)", err=as_json)
    if problems:
        ctx.exit(1)


def _descend(source, recursive: bool, exclude=()) -> bool:
    """``recursive`` for scanning ``source``: True also when the folder holds no photographs
    but its subfolders do; one line on stderr says so, or says to add -r when
    photographs in subfolders (other than the ``exclude`` folders) are left out."""
    from hdrcl.api.batch import descends, left_below

    if not os.path.isdir(source):
        return recursive
    note = descends(source, recursive, exclude=exclude)
    line = note or left_below(source, recursive, exclude=exclude)
    if line and not is_quiet():
        click.echo(f"hdrcl: {line}", err=True)
    return recursive or note is not None


# ------------------------------------------------------------------------ batch
#: How the summary and the progress lines call a set's status (report.json keeps the
#: status values themselves).
SHOWN = {"skipped": "up to date", "check": "done, check it"}


class _Progress:
    """A progress bar on a terminal, one plain line per set otherwise (farm logs).

    Both go to stderr so that stdout carries only the summary (or the JSON report).
    """

    def __init__(self, stream, tty: bool, quiet: bool):
        self.stream, self.tty, self.quiet = stream, tty, quiet
        self.total = 0
        self.counts = {"done": 0, "check": 0, "skipped": 0, "failed": 0}  # "skipped": up to date
        self.t0 = time.monotonic()
        self.drawn = False

    def __call__(self, res, completed: int, total: int):
        self.total = total
        if res is None:
            self.t0 = time.monotonic()
            if self.tty and not self.quiet and total:
                self._draw(0)
            return
        self.counts[res.status] = self.counts.get(res.status, 0) + 1
        name = os.path.basename(res.output or res.files[0])
        if self.tty:
            if res.status == "failed":
                self._clear()
                self.stream.write(f"hdrcl: set {res.index} ({name}) failed: {res.error}\n")
            elif res.status == "check":
                self._clear()
                self.stream.write(f"hdrcl: set {res.index} ({name}) merged, check it: {'; '.join(res.causes())}\n")
            if not self.quiet:
                self._draw(completed)
        elif not self.quiet or res.status == "failed":
            width = len(str(total))
            shown = SHOWN.get(res.status, res.status)
            line = (f"hdrcl: [{completed:{width}d}/{total}] set {res.index} {name}: {shown} "
                    f"({res.seconds.get('total', 0.0):.2f} s)")
            if res.error:
                line += f": {res.error}"
            elif res.status == "check":
                line += f": {'; '.join(res.causes())}"
            self.stream.write(line + "\n")
            self.stream.flush()

    def _clear(self):
        if self.drawn:
            self.stream.write("\r\033[K")
            self.drawn = False

    def _draw(self, completed: int):
        width = 24
        fill = int(width * completed / self.total) if self.total else width
        elapsed = time.monotonic() - self.t0
        eta = f", {elapsed / completed * (self.total - completed):.0f} s left" if 0 < completed < self.total else ""
        c = self.counts
        self.stream.write(f"\r\033[K[{'#' * fill}{'-' * (width - fill)}] {completed}/{self.total} sets "
                          f"({c['done']} done, {c['check']} to check, {c['skipped']} up to date, "
                          f"{c['failed']} failed{eta})")
        self.stream.flush()
        self.drawn = True

    def close(self):
        if self.tty and self.drawn:
            self.stream.write("\n")
            self.stream.flush()
            self.drawn = False


@main.command()
@click.argument("source", type=InputPath("manifest"))
@click.option("-o", "--output", "out_dir", required=True, type=OutputFolder("output folder"),
              help="Output folder (created): one EXR and one JPEG preview per set, report.json.")
@response_option(help="Response JSON for every set [default: calibrate one per camera and ISO (sets without "
                   "camera make and model: one per folder), pooled over the shoot].")
@click.option("--sets", "sets", metavar="A-B[,C...]", callback=sets_callback,
              help="Only these manifest indices (ranges are clamped to the sets that exist), "
                   "e.g. a farm chunk #START#-#END#.")
@click.option("-j", "--jobs", type=Checked("jobs"), default=1, show_default=True,
              help="Worker processes (1: one process, reading, fusing and writing overlapped).")
@click.option("--scheduler", metavar="ADDRESS",
              help="Run the sets on this Dask cluster, e.g. tcp://head:8786 (pip install 'hdrcl[dask]').")
@click.option("--retries", type=Checked("retries"), default=2, show_default=True,
              help="With --scheduler: retries of a task that failed unexpectedly.")
@click.option("--force", is_flag=True, help="Rebuild outputs that are already up to date.")
@click.option("--name", "name", metavar="TEMPLATE",
              help="Output names: {folder} (the set's folder), {first} (first frame, capture order), "
                   "{date} (capture date, YYYY-MM-DD), {index} (set number from 1, zero-padded), {camera} "
                   "(make-model) [default: {folder} when every set has a folder of its own, else {first}]. "
                   "Characters unsafe in file names become _; two sets named alike are refused.")
@click.option("--dry-run", is_flag=True,
              help="Print the plan (each set's frames, exposures, output, response) and exit; nothing is "
                   "merged or written. With --json, as JSON.")
@response_cache_option(type=OutputFolder("response cache"),
                       help="Folder of responses, one per camera and ISO (<camera>_ISO_<n>.response.json): one found "
                   "there that fits is used as it is, else the curve is calibrated and saved there.")
@click.option("--calibrate-only", is_flag=True,
              help="Only solve (or load) and save the responses, e.g. once before submitting farm chunks.")
@report_option("report_dir", help="Write a quality report into this folder: per set a response plot, a coverage map, a "
                   "preview and the figures; an HTML contact sheet (index.html) over the shoot.")
@click.option("--report-json", "report_json", type=OutputFile((".json",), "JSON report", check_folder=False),
              help="Write the JSON report here [default: OUT_DIR/report.json].")
@json_option(help="Print the report JSON on stdout.")
@click.option("--preview/--no-preview", default=True, show_default=True,
              help="Write a tone-mapped JPEG beside each EXR.")
@click.option("--preview-size", type=Checked("preview_size"), default=512, show_default=True, metavar="PIXELS",
              help="Long side of the previews.")
@click.option("--tonemap", type=click.Choice(["reinhard", "reinhard-local", "drago", "filmic"]), default="reinhard",
              show_default=True, help="Tone-mapping operator of the previews (as 'hdrcl tonemap').")
@grouping_options
@times_file_option(help=FOR_THE_FRAMES_IT_LISTS)
@merge_options
@output_format_option
@luminance_options
@deliver_options
@click.pass_context
def batch(ctx, source, out_dir, response, sets, jobs, scheduler, retries, force, name, dry_run, response_cache,
          calibrate_only, report_dir, report_json, as_json, preview, preview_size, tonemap, recursive, frames_per_set,
          gap, times_file, output_format, lens_circle, resize, fisheye_projection, vignetting, nd_filter,
          calibration_factor, view, deliver, headroom, hdr_transfer, hdr_bits, **options):
    """Merge every bracket set of a folder or manifest into OUT_DIR.

    SOURCE is a folder of photographs (grouped as 'hdrcl scan' does; a folder whose
    photographs are all in subfolders is scanned with them) or a manifest from
    'hdrcl scan -o'. Each set becomes OUT_DIR/<name>.exr plus a JPEG preview (see
    --name); outputs that are already up to date are left as they are, so an
    interrupted run is finished by running it again.

    \b
    Exit codes: 0 every set done or up to date; 1 some sets failed (the others
    completed; see report.json), or nothing could be merged; 2 usage error;
    3 unreadable folder, manifest or response file; 143 / 130 stopped by
    SIGTERM / Ctrl-C (report.json holds the sets that finished; run again to
    finish the rest).
    """
    from hdrcl.api.batch import BatchOptions, Cancelled, run_batch
    from hdrcl.api.options import MergeOptions
    from hdrcl.api.support import chain_or_none

    def _cal(value):  # a .cal file by its absolute path: workers may run elsewhere
        return os.path.abspath(value) if isinstance(value, str) and value.lower().endswith(".cal") else value

    luminance = dict(lens_circle=lens_circle, resize=resize, projection=fisheye_projection,
                     vignetting=_cal(vignetting), nd_filter=_cal(nd_filter), calibration_factor=_cal(calibration_factor),
                     view=view)
    # every option checked here, before any set; the factors against what the outputs' format holds
    if chain_or_none(**luminance, output=f".{output_format}") is None:
        luminance = None
    quiet = is_quiet()
    recursive = _descend(source, recursive, exclude=(out_dir, report_dir))
    if report_json and os.path.dirname(os.path.abspath(report_json)) != os.path.abspath(out_dir):
        from hdrcl.api.support import check_output

        check_output(report_json, what="JSON report")  # before any set is merged
    opts = BatchOptions(MergeOptions.from_params(options), preview=preview, preview_size=preview_size,
                        tonemap=tonemap, report_dir=report_dir, output_format=output_format, luminance=luminance,
                        deliver=deliver, headroom=headroom, hdr_transfer=hdr_transfer.lower(), hdr_bits=int(hdr_bits))
    if dry_run:
        from hdrcl.api.batch import describe_batch

        plan = describe_batch(source, out_dir, options=opts, sets=sets, response=response,
                              response_cache=response_cache, name=name, recursive=recursive,
                              frames_per_set=frames_per_set, gap=gap, times_file=times_file)
        click.echo(json.dumps(plan, indent=1) if as_json else _format_plan(plan, out_dir))
        ctx.exit(0)
    progress = _Progress(sys.stderr, sys.stderr.isatty(), quiet)
    try:
        rep = run_batch(source, out_dir, options=opts, sets=sets, response=response, jobs=jobs,
                        scheduler=scheduler, retries=retries, force=force, report=report_json,
                        calibrate_only=calibrate_only, recursive=recursive, frames_per_set=frames_per_set,
                        gap=gap, progress=progress, times_file=times_file, handle_signals=True,
                        name=name, response_cache=response_cache)
    except Cancelled as exc:  # before any set ran (scanning, calibrating): nothing to report
        progress.close()
        click.echo(f"hdrcl: {_stopped(exc.signum)}", err=True)
        ctx.exit(exc.exit_code)
    finally:
        progress.close()
    if rep.cancelled:  # the one line, in the words of every command (README: exit codes)
        click.echo(f"hdrcl: {_stopped(rep.cancelled)} ({len(rep.results)} set(s) finished; report: {rep.path})",
                   err=True)
    if as_json:
        click.echo(json.dumps(rep.to_dict(run_only=True), indent=1))
    elif calibrate_only:
        for r in rep.responses:
            state = f"error: {r.error}" if r.error else f"{r.source} {r.file}"
            say(f"{r.group}: {state}")
    elif not quiet:
        _summary(rep)
    if calibrate_only:
        ctx.exit(1 if any(r.error for r in rep.responses) else 0)
    ctx.exit(rep.exit_code)


def _format_plan(plan: dict, out_dir: str) -> str:
    """``batch --dry-run``: two lines per set, then what is left out."""
    from hdrcl.api.support import format_time

    lines = []
    for r in plan["sets"]:
        span = (f"{format_time(r['exposures'][0])} .. {format_time(r['exposures'][1])}"
                if r["exposures"] else "exposures from EXIF")
        lines.append(f"set {r['index']}: {r['frames']} frames, {os.path.basename(r['first'])} .. "
                     f"{os.path.basename(r['last'])}, {span} -> {r['output']}"
                     + (" (+ preview)" if r["preview"] else ""))
        resp, cal = r["response"], r["calibration"]
        how = {"given": "given", "cached": "from the cache", "own": "calibrated from this set alone",
               "pooled": f"calibrated, pooled over sets {', '.join(map(str, cal.get('sets', [])))}"}[cal["kind"]]
        state = {"saved": " (saved; reused while its calibration is current)",
                 "calibrate": " (to be written)"}.get(resp["source"], "")
        lines.append(f"  response {resp['group']}: {resp['file']}{state}, {how}")
    for u in plan["unmerged"]:
        more = f" (+{len(u['files']) - 1} more)" if len(u["files"]) > 1 else ""
        lines.append(f"not merged: {os.path.basename(u['files'][0])}{more}: {u['reason']}")
    lines.append(f"dry run: {len(plan['sets'])} set(s) would be merged into {out_dir} "
                 f"(reference {plan['reference']}); nothing was written")
    return "\n".join(lines)


def _stopped(signum: int) -> str:
    """``terminated`` (SIGTERM) or ``interrupted`` (Ctrl-C), as the other commands say it."""
    import signal

    return "interrupted" if signum == signal.SIGINT else "terminated"


def _summary(rep) -> None:
    n = len(rep.results)
    if n == 0 and rep.cancelled:
        click.echo(f"no set finished before the cancel; report: {rep.path}")
    elif n == 0:
        click.echo("no bracket sets to merge" + (f"; report: {rep.path}" if rep.path else ""))
        if rep.sets_in_manifest == 0 and rep.unmerged:
            for u in rep.unmerged[:5]:
                more = f" (+{len(u['files']) - 1} more)" if len(u["files"]) > 1 else ""
                click.echo(f"  not merged: {os.path.basename(u['files'][0])}{more}: {u['reason']}")
    else:
        check = f"{rep.to_check} to check, " if rep.to_check else ""
        click.echo(f"{n} set(s): {rep.count('done')} done, {check}{rep.count('skipped')} up to date, "
                   f"{rep.count('failed')} failed in {rep.seconds:.1f} s; report: {rep.path}")
    if rep.quality_report:
        click.echo(f"quality report: {rep.quality_report}")
    for r in rep.results:
        if r.status == "failed":
            click.echo(f"  failed: set {r.index} ({os.path.basename(r.files[0])}): {r.error}")
        elif r.needs_check:  # merged now, or up to date from a run that found the same
            for cause in r.causes():
                click.echo(f"  check: set {r.index} ({os.path.basename(r.files[0])}): {cause}")
    for r in rep.responses:
        if r.error:
            click.echo(f"  no response for {r.group}: {r.error}")
    if rep.unreadable:
        click.echo(f"  unreadable, not merged: {', '.join(os.path.basename(f) for f in rep.unreadable)}")
    others = [u for u in rep.unmerged if not u["reason"].startswith("corrupt")]
    if others:
        click.echo(f"  {len(others)} group(s) not merged (single frames and the like; see report)")


# ------------------------------------------------------------------ sample-shoot


@main.command("sample-shoot")
@click.argument("folder", type=OutputFolder("folder"))
@size_option(default="192x128", help="Size of each photograph.")
@field_option("seed", help=None)
def sample_shoot(folder, size, seed):
    """Write a small sample shoot of JPEGs with EXIF to try scan and batch on.

    \b
    hdrcl sample-shoot shoot/ && hdrcl batch shoot/ -o out/
    """
    from hdrcl.api.batch import write_sample_shoot

    w, h = (int(v) for v in size.lower().split("x"))  # checked by the option's type
    paths = write_sample_shoot(folder, width=w, height=h, seed=seed)
    say(f"wrote {len(paths)} photographs to {folder} (3 bracket sets and a stray frame)")
    say(f"next: hdrcl scan {folder}   or   hdrcl batch {folder} -o hdr/")
