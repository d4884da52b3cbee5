"""White balance and absolute scale of a merge: per-channel factors from a neutral
patch, a reference patch or the EXIF exposure.
"""
from __future__ import annotations

import numpy as np

from hdrcl.core.bracket import _with_ignore
from hdrcl.errors import UsageError


def radiometric_factors(paths, infos, source, rel, resp, options, nch, h, w, exposure_reference=None):
    """Per-channel factors (or None) and metadata for white balance and absolute scale.

    ``options`` is a :class:`hdrcl.core.options.MergeOptions` (``neutral``,
    ``reference_patch``, ``absolute``, ``weight``, ``ignore_color``, ``device``);
    ``exposure_reference`` is the ``(f-number, ISO)`` that the exposures ``rel`` are
    relative to when that is not the first frame's (a batch: the shoot's reference);
    the absolute scale must use the same."""
    o = options
    weight, rgb, device = o.weight, o.ignore_color, o.device
    neutral, reference_patch, absolute = o.neutral, o.reference_patch, o.absolute
    from hdrcl.core import radiometry as rm

    if reference_patch is not None and absolute:
        raise UsageError("--absolute and --reference-patch both set the scale; give one")
    units = {"units": "relative"}
    if neutral is None and reference_patch is None and not absolute:
        return None, units
    factors = np.ones(nch)  # h, w: the output's size (cropped when aligned with --crop)

    def patch_radiance(patch):
        from hdrcl.core.fusion import fuse_frames

        x, y, pw, ph = patch
        if hasattr(source, "frames"):  # in memory already
            frames = [f[y:y + ph, x:x + pw] for f in source.frames]
            valid = [None if v is None else v[y:y + ph, x:x + pw] for v in source.valid]
        else:
            from hdrcl.io.reader import BracketReader

            with BracketReader(paths, infos) as reader:
                fs, vs = reader.read_rows(y, y + ph)
            frames = [np.ascontiguousarray(f[:, x:x + pw]) for f in fs]
            valid = _with_ignore(frames, [None if v is None else v[:, x:x + pw] for v in vs], rgb)
        return fuse_frames(frames, rel, resp, weight=weight, valid=valid, device=device).radiance

    if neutral is not None:
        patch = rm.parse_patch(neutral, "--neutral")
        rm.check_patch(patch, h, w, "--neutral")
        gains = rm.neutral_gains(patch_radiance(patch))
        factors *= gains
        units["whiteBalance"] = [round(float(g), 6) for g in gains]
    if reference_patch is not None:
        patch, value = rm.parse_reference_patch(reference_patch)
        rm.check_patch(patch, h, w, "--reference-patch")
        scale = rm.patch_scale(patch_radiance(patch) * factors, value)
        factors *= scale
        units.update({"units": "cd/m2", "scaleSource": f"reference patch {patch} = {value:g} cd/m2",
                      "scale": float(scale)})
    elif absolute:
        ref_n, ref_iso = exposure_reference or (None, None)
        fnumber, iso = ref_n or infos[0].fnumber, ref_iso or infos[0].iso
        scale = rm.exif_scale(fnumber, iso)
        factors *= scale
        units.update({"units": "cd/m2 (approximate)",
                      "scaleSource": f"K N^2/ISO, K={rm.METER_K:g}, N={fnumber:g}, ISO={iso:g}",
                      "scale": float(scale)})
    return factors, units
