"""A bracket set in memory (:class:`Bracket`): frames, masks and relative exposures,
loaded from files or arrays; the decimated sampling grid; the memory budget.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import List, Optional, Sequence, Union

import numpy as np

from hdrcl.errors import InputError, UsageError

PathOrArray = Union[str, os.PathLike, np.ndarray]


@dataclass
class Bracket:
    """Decoded frames of one bracket set with their exposures.

    ``times`` are effective exposure times in seconds, relative to the first frame's
    aperture and ISO; ``valid`` holds one ``(H, W)`` mask per frame (or None: all valid).
    """

    frames: List[np.ndarray]
    times: np.ndarray
    valid: List[Optional[np.ndarray]]
    paths: List[str] = field(default_factory=list)
    infos: list = field(default_factory=list)
    grid: bool = False  # frames are the decimated sampling grid, not whole images

    @property
    def valid_all(self) -> Optional[np.ndarray]:
        masks = [v for v in self.valid if v is not None]
        if not masks:
            return None
        out = masks[0].copy()
        for m in masks[1:]:
            out &= m
        return out

    @property
    def camera(self) -> dict:
        if not self.infos:
            return {}
        i = self.infos[0]
        return {k: v for k, v in (("make", i.make), ("model", i.model), ("iso", i.iso)) if v is not None}


def _parse_ignore_color(ignore_color):
    if ignore_color is None:
        return None
    if isinstance(ignore_color, str):
        try:
            vals = tuple(int(v) for v in ignore_color.split(","))
        except ValueError:
            vals = ()
        if len(vals) != 3:
            raise UsageError(f"--ignore-color: expected R,G,B in 8-bit units, not '{ignore_color}'")
        ignore_color = vals
    vals = tuple(int(v) for v in ignore_color)
    if len(vals) != 3 or not all(0 <= v <= 255 for v in vals):
        raise UsageError(f"--ignore-color: expected three values 0-255, not {ignore_color}")
    return vals


def load_bracket(
    images: Sequence[PathOrArray],
    times: Optional[Sequence[float]] = None,
    *,
    times_file=None,
    ignore_color=None,
    valid: Optional[Sequence[Optional[np.ndarray]]] = None,
    channel_order: str = "rgb",
) -> Bracket:
    """Read (or wrap) a bracket set and resolve its exposures.

    Parameters
    ----------
    images : sequence of paths or arrays
        Paths are decoded with OpenImageIO (8/16-bit JPEG, PNG, TIFF; grey, RGB, RGBA);
        arrays must be ``(H, W)`` or ``(H, W, C)`` uint8/uint16.
    times : sequence of float, optional
        Exposure times in seconds (required for arrays). For files, the precedence is
        ``times``, then ``times_file``, then EXIF.
    times_file : path, optional
        HDRShop-style list or ``file seconds`` lines.
    ignore_color : (R, G, B) or "R,G,B", optional
        Pixels of exactly this colour (8-bit units) are invalid in that frame.
    valid : sequence of (H, W) bool arrays, optional
        Extra per-frame validity masks.
    channel_order : {"rgb", "bgr"}
        The channel order of array frames: ``"bgr"`` for OpenCV's (``cv2.imread``),
        turned into RGB here. Files are always read as RGB.
    """
    from hdrcl.core.params import check_images, check_options, to_rgb
    from hdrcl.io import metadata

    check_options(ignore_color=ignore_color, channel_order=channel_order)
    images = check_images(images)
    if len(images) < 2:
        name = os.fspath(images[0]) if images and not isinstance(images[0], np.ndarray) else "input"
        raise InputError(f"{name}: a bracket set needs at least two exposures")
    rgb = _parse_ignore_color(ignore_color)
    if all(isinstance(im, np.ndarray) for im in images):
        if times is None:
            raise UsageError("exposure times are required when the images are arrays")
        frames = []
        for k, im in enumerate(images):
            a = np.asarray(im)
            if a.ndim == 2:
                a = a[..., None]
            if a.dtype not in (np.uint8, np.uint16) or a.ndim != 3:
                raise UsageError(f"image {k}: expected (H, W[, C]) uint8 or uint16, got {a.dtype} {a.shape}")
            if a.shape != np.shape(frames[0] if frames else a):
                raise InputError(f"image {k}: size {a.shape} differs from image 0 {frames[0].shape}")
            frames.append(np.ascontiguousarray(a))
        frames = to_rgb(frames, channel_order)
        exposures = metadata.resolve_exposures([f"image {k}" for k in range(len(frames))], times=times)
        masks: List[Optional[np.ndarray]] = [None] * len(frames)
        paths: List[str] = []
        infos: list = []
    elif any(isinstance(im, np.ndarray) for im in images):
        raise UsageError("give either file paths or arrays, not a mix")
    else:
        from hdrcl.io.reader import BracketReader

        from hdrcl.io.frames import check_orientation

        paths = [os.fspath(p) for p in images]
        infos = read_infos(paths)
        exposures = metadata.resolve_exposures(paths, infos, times=times, times_file=times_file)
        check_orientation(infos)  # arrays come back as stored (a file merge: hdrcl.core.orientation)
        with BracketReader(paths, infos) as reader:
            frames, masks = reader.read_all()
    if rgb is not None:
        from hdrcl.io.reader import ignore_color_mask

        masks = [(~ignore_color_mask(f, rgb)) if m is None else (m & ~ignore_color_mask(f, rgb))
                 for f, m in zip(frames, masks)]
    if valid is not None:
        masks = [m if v is None else (np.asarray(v, bool) if m is None else m & np.asarray(v, bool))
                 for m, v in zip(masks, valid)]
    rel = metadata.relative_exposures(exposures)
    return Bracket(frames=frames, times=np.asarray(rel, np.float64), valid=masks, paths=paths, infos=infos)


def read_infos(paths: Sequence[str]) -> list:
    """Headers of ``paths`` (no pixels decoded), read in parallel; InputError names the file
    (also a frame over the pixel limit, :func:`hdrcl.io.frames.max_pixels`)."""
    import concurrent.futures

    from hdrcl.io.frames import check_pixel_limit, read_info

    if len(paths) < 2:
        from hdrcl.io.metadata import resolve_exposures

        resolve_exposures(paths)  # raises the "needs at least two exposures" error
    with concurrent.futures.ThreadPoolExecutor(max_workers=min(8, len(paths))) as pool:
        infos = list(pool.map(read_info, paths))
    for info in infos:
        check_pixel_limit(info)
    return infos


def memory_budget() -> int:
    """Bytes of decoded frames a quality report may hold whole (``HDRCL_MEMORY_MB``).

    Above it, the report measures the decimated sampling grid instead. (Merging never
    holds whole frames, except with ``--align``: calibration streams.)
    """
    from hdrcl.env import number

    return int(number("HDRCL_MEMORY_MB") * (1 << 20))


def _with_ignore(frames, valid, rgb):
    if rgb is None:
        return list(valid)
    from hdrcl.io.reader import ignore_color_mask

    return [(~ignore_color_mask(f, rgb)) if v is None else (v & ~ignore_color_mask(f, rgb))
            for f, v in zip(frames, valid)]


def _all_raw(paths) -> bool:
    from hdrcl.io.raw import is_raw

    return bool(paths) and all(is_raw(p) for p in paths)


def _open_files(paths, times, times_file):
    from hdrcl.io import metadata
    from hdrcl.io.frames import check_compatible

    paths = [os.fspath(p) for p in paths]
    infos = read_infos(paths)
    exposures = metadata.resolve_exposures(paths, infos, times=times, times_file=times_file)
    check_compatible(infos)  # orientation: a merge's finding (hdrcl.core.orientation), calibrate's warning
    return paths, infos, np.asarray(metadata.relative_exposures(exposures), np.float64)


def _grid_bracket(paths, infos, rel, rgb, reader=None, keep: bool = False, hold: bool = False) -> Bracket:
    """The decimated grid that sample selection uses, read in one streaming pass
    (through ``reader`` when given: it is rewound for a later pass, not closed; with
    ``keep`` it also keeps the decoded frames for that pass, so they are decoded once).

    With ``hold`` (and no ``reader``), the frames decoded are held for the set's own merge
    within the memory budget (:func:`hdrcl.io.ahead.read_and_hold`: a batch's pooled
    calibration), which then takes them instead of decoding the set again."""
    from hdrcl.core.sampling import grid_stride
    from hdrcl.io.reader import BracketReader

    if reader is None:
        with BracketReader(paths, infos) as own:
            if hold:
                from hdrcl.io.ahead import read_and_hold

                frames, valid = read_and_hold(own, grid_stride(own.height, own.width))
                return Bracket(frames=frames, times=rel, valid=_with_ignore(frames, valid, rgb), paths=paths,
                               infos=infos, grid=True)
            return _grid_bracket(paths, infos, rel, rgb, reader=own)
    frames, valid = reader.read_grid(grid_stride(reader.height, reader.width), keep=keep)
    return Bracket(frames=frames, times=rel, valid=_with_ignore(frames, valid, rgb), paths=paths, infos=infos,
                   grid=True)


# Public names for the layers above (shoot, report): the same functions.
parse_ignore_color = _parse_ignore_color
with_ignore = _with_ignore
grid_bracket = _grid_bracket
