"""The scene itself: small exposure-normalised thumbnails of frames, compared.

Two frames of one bracket show the same scene from a tripod (or nearly so, hand held);
the next set usually shows another. :func:`compare` tells them apart from thumbnails
of :data:`GRID` cells (luminance, area-averaged, so a few pixels of hand shake do not
matter), using the cells well exposed in both frames: above each frame's own floor (its
darkest cell, up to a pedestal's level, plus a margin, :func:`floor`: a sensor's pedestal
and its noise are no exposure) and below the clip:

* the **rank correlation of the local structure**: the differences between neighbouring
  cells of the exposure-normalised log values. A camera's response is monotonic, so one
  scene keeps the order (and nearly the size) of its local contrasts at any exposure,
  whatever the tone curve; another view does not, even when both share a global
  gradient (sky above, ground below) that would make the values themselves correlate;
* the **offset** after normalising by the relative exposure (``t * ISO / N**2``,
  values linearised with gamma 2.2): one scene lines up within a few stops (the tone
  curve is not exactly 2.2); the same framing lit 6 stops brighter is another scene.

The verdict is ``"same"``, ``"changed"`` or ``"unknown"`` (too few pixels well exposed
in both frames, e.g. 4 stops apart, or no thumbnail).

When fewer cells are well exposed in both than the main test needs (the darkest frames
of a night ladder, 3-4 stops from their neighbour), a **strict match over the few cells**
there are still vouches: a rank correlation of at least :data:`RHO_FEW` within
:data:`OFFSET_FEW` stops gives ``"same"`` (``basis="few cells"``); the fallback never
says ``"changed"``: so few cells cannot prove another scene.

Thumbnails are read cheaply (:func:`hdrcl.io.probe.reduced_pixels`): a JPEG's embedded
EXIF thumbnail when it has one, else (with OpenCV installed) the JPEG decoded at 1/8
scale by libjpeg's DCT scaling, else the smallest MIP level of a tiled TIFF/EXR, else a
full decode, then reduced by area averaging. Camera RAW files give no thumbnail here
(their verdict is ``"unknown"``).
"""
from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass
from typing import Dict, Optional

import numpy as np

logger = logging.getLogger(__name__)

__all__ = ["GRID", "Thumb", "Verdict", "read_thumb", "compare", "floor", "SceneCache"]

#: Thumbnail size (rows, columns).
GRID = (24, 32)
# Code values (0..1) that count as well exposed: above the frame's own floor (its darkest
# cell, the sensor's pedestal in a dark frame, up to _PEDESTAL, plus _LO) and below _HI.
_LO, _HI = 0.04, 0.94
# Highest pedestal (code value) a frame's darkest cell is taken for: sensors' black levels
# in 8-bit renderings lie at 0-20 codes; a darker cell above this is the scene itself.
_PEDESTAL = 0.08
#: Same scene: rank correlation of the local structure at least this; changed: below
#: RHO_CHANGED. (Measured: one scene 1-2 stops apart 0.77-1.0 on the real sets and 0.79-1.0
#: on the synthetic cards; different scenes at most 0.27 real and 0.39 synthetic.)
RHO_SAME, RHO_CHANGED = 0.6, 0.45
#: Exposure-normalised offset (stops) beyond which the scene changed.
OFFSET_CHANGED = 5.0
# A low correlation says "changed" only over at least this fraction of the thumbnail.
_MIN_CHANGED = 0.12
#: Few cells (see the module docstring): from _FEW_MIN cells and neighbour pairs well
#: exposed in both, a match of at least RHO_FEW within OFFSET_FEW stops is the same scene.
#: (Measured on the synthetic scenes 1.3-3.7 stops apart: 15 of 7735 pairs of different
#: scenes pass, 42 of the 283 pairs of one scene that the main test cannot compare.)
RHO_FEW, OFFSET_FEW = 0.75, 2.0
_FEW_MIN = 16


@dataclass
class Thumb:
    """A frame's luminance on :data:`GRID` (code values 0..1) and its exposure."""

    lum: np.ndarray
    exposure: float  # t * ISO/100 / N**2 (relative; 1 where unknown)


@dataclass
class Verdict:
    """Outcome of :func:`compare`: ``kind`` is ``"same"``, ``"changed"`` or ``"unknown"``."""

    kind: str
    rho: Optional[float] = None
    offset: Optional[float] = None
    pixels: int = 0
    basis: str = "structure"  # or "few cells": the strict match over few cells (module docstring)

    @property
    def doubtful(self) -> bool:
        """Compared over a quarter of the thumbnail or more and found neither alike nor
        different (a match between :data:`RHO_CHANGED` and :data:`RHO_SAME`): unlike a
        frame too dark to compare, such a pair gives no reason to join across a gap."""
        return self.kind == "unknown" and self.rho is not None and self.pixels >= GRID[0] * GRID[1] // 4

    def describe(self) -> str:
        if self.kind == "unknown":
            return "scene not comparable" if self.pixels else "no thumbnail"
        word = "same scene" if self.kind == "same" else "scene changed"
        few = ", few cells" if self.basis == "few cells" else ""
        return f"{word} (match {self.rho:.2f}, {self.offset:+.1f} EV{few})"


def _reduce(y: np.ndarray) -> np.ndarray:
    """Area-average a 2-D array onto :data:`GRID`."""
    gh, gw = GRID
    h, w = y.shape
    if h < gh or w < gw:
        ys = np.minimum((np.arange(gh) * h) // gh, h - 1)
        xs = np.minimum((np.arange(gw) * w) // gw, w - 1)
        return y[np.ix_(ys, xs)].astype(np.float64)
    yb = np.linspace(0, h, gh + 1).astype(int)
    xb = np.linspace(0, w, gw + 1).astype(int)
    s = np.add.reduceat(np.add.reduceat(y.astype(np.float64), yb[:-1], 0), xb[:-1], 1)
    return s / np.outer(np.diff(yb), np.diff(xb))


def _lum(a: np.ndarray) -> np.ndarray:
    if a.ndim == 2:
        return a
    if a.shape[2] >= 3:
        return a[:, :, :3].mean(axis=2)
    return a[:, :, 0]


def _to_unit(a: np.ndarray) -> np.ndarray:
    if a.dtype == np.uint8:
        return a.astype(np.float32) / 255.0
    if a.dtype == np.uint16:
        return a.astype(np.float32) / 65535.0
    return a.astype(np.float32)


def read_thumb(info) -> Optional[Thumb]:
    """The thumbnail of a frame described by ``info`` (a FrameInfo), or None."""
    from hdrcl.shoot.grouping.ladder import exposure_value

    from hdrcl.io.probe import Damaged, reduced_pixels

    try:
        a = reduced_pixels(info.path, GRID)
    except Damaged:
        raise  # the scan sets the frame aside and fails its set (SceneCache.damaged)
    except Exception as exc:  # a damaged file: the header reader reports it elsewhere
        logger.debug("%s: no thumbnail (%s)", info.path, exc)
        return None
    if a is None or a.size == 0:
        return None
    ev = exposure_value(info)
    return Thumb(lum=_reduce(_lum(_to_unit(np.asarray(a)))), exposure=2.0 ** ev if ev is not None else 1.0)


def _read_or_damaged(info):
    """``(thumb or None, None)``, or ``(None, reason)`` for a frame whose pixels do not decode."""
    from hdrcl.io.probe import Damaged

    try:
        return read_thumb(info), None
    except Damaged as exc:
        return None, str(exc).splitlines()[0]


def _ranks(x: np.ndarray) -> np.ndarray:
    r = np.empty(len(x))
    r[np.argsort(x, kind="stable")] = np.arange(len(x))
    return r


def _structure(a: Thumb, b: Thumb, ok: np.ndarray):
    """Rank correlation of the local structure, the exposure-normalised offset and the
    number of neighbour pairs, over the cells ``ok``; rho is None where it is undefined."""
    la = 2.2 * np.log2(np.maximum(a.lum, 1e-6)) - math.log2(a.exposure)
    lb = 2.2 * np.log2(np.maximum(b.lum, 1e-6)) - math.log2(b.exposure)
    offset = float(np.median(lb[ok] - la[ok]))
    # Local structure: differences between neighbouring cells well exposed in both.
    hx, vy = ok[:, 1:] & ok[:, :-1], ok[1:, :] & ok[:-1, :]
    da = np.concatenate([np.diff(la, axis=1)[hx], np.diff(la, axis=0)[vy]])
    db = np.concatenate([np.diff(lb, axis=1)[hx], np.diff(lb, axis=0)[vy]])
    ra, rb = _ranks(da), _ranks(db)
    if len(da) < 2 or ra.std() == 0 or rb.std() == 0:
        return None, offset, len(da)
    return float(np.corrcoef(ra, rb)[0, 1]), offset, len(da)


def floor(t: Thumb) -> float:
    """The code value above which a cell of ``t`` counts as exposed: :data:`_LO` above
    the frame's darkest cell (up to :data:`_PEDESTAL`). A sensor's pedestal (black at
    15 codes of 255) and its noise fill a dark frame; counted as well exposed they would
    "change the scene" between two dark frames of one bracket. A frame whose darkest
    cell is black keeps the plain floor :data:`_LO`; in a bright frame, whose darkest
    cell lies above the pedestal, every cell counts as before."""
    return min(float(t.lum.min()), _PEDESTAL) + _LO


def compare(a: Optional[Thumb], b: Optional[Thumb]) -> Verdict:
    """Whether two thumbnails show the same scene (see the module docstring)."""
    if a is None or b is None or a.lum.shape != b.lum.shape:
        return Verdict("unknown")
    ok = (a.lum > floor(a)) & (a.lum < _HI) & (b.lum > floor(b)) & (b.lum < _HI)
    n = int(ok.sum())
    if n < max(24, 0.06 * ok.size):
        return _few_cells(a, b, ok, n)
    rho, offset, used = _structure(a, b, ok)
    if rho is None or used < 24:
        return Verdict("unknown", pixels=n)
    pairs = (ok.shape[0] * (ok.shape[1] - 1)) + ((ok.shape[0] - 1) * ok.shape[1])
    # A low correlation over few cells (frames far apart in exposure) proves little.
    if abs(offset) > OFFSET_CHANGED or (rho < RHO_CHANGED and used >= _MIN_CHANGED * pairs):
        kind = "changed"
    elif rho >= RHO_SAME:
        kind = "same"
    else:
        kind = "unknown"
    return Verdict(kind, rho=round(rho, 3), offset=round(offset, 2), pixels=n)


def _few_cells(a: Thumb, b: Thumb, ok: np.ndarray, n: int) -> Verdict:
    """Few cells well exposed in both: ``"same"`` on a strict match, else unknown."""
    if n < _FEW_MIN:
        return Verdict("unknown", pixels=n)
    rho, offset, used = _structure(a, b, ok)
    if rho is None or used < _FEW_MIN or rho < RHO_FEW or abs(offset) > OFFSET_FEW:
        return Verdict("unknown", pixels=n)
    return Verdict("same", rho=round(rho, 3), offset=round(offset, 2), pixels=n, basis="few cells")


class SceneCache:
    """Thumbnails read once per frame, on first use or all at once (:meth:`read_all`), by path."""

    def __init__(self):
        self._cache: Dict[str, Optional[Thumb]] = {}
        #: Frames whose pixels do not decode, by path: the one-line reason naming the file.
        self.damaged: Dict[str, str] = {}

    def thumb(self, info) -> Optional[Thumb]:
        key = os.fspath(info.path)
        if key not in self._cache:
            self._store(key, _read_or_damaged(info))
        return self._cache[key]

    def _store(self, key: str, got) -> None:
        thumb, why = got
        self._cache[key] = thumb
        if why is not None:
            self.damaged[key] = why

    def read_all(self, infos, workers: Optional[int] = None) -> None:
        """Read the thumbnails of ``infos`` not read yet, on ``workers`` threads [default:
        one per core] (the decoders release the GIL: a scan's reduced JPEG decodes, 40 ms
        each at 12 MP, take both cores of a 2-core machine instead of one). The results are
        stored in the order of ``infos``, as reading them one by one would."""
        todo, seen = [], set()
        for info in infos:
            key = os.fspath(info.path)
            if key not in self._cache and key not in seen:
                seen.add(key)
                todo.append((key, info))
        workers = max(1, min(len(todo), workers or os.cpu_count() or 1))
        if workers == 1:
            got = [_read_or_damaged(info) for _key, info in todo]
        else:
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(workers, thread_name_prefix="hdrcl-thumb") as pool:
                got = list(pool.map(_read_or_damaged, [info for _key, info in todo]))
        for (key, _info), g in zip(todo, got):
            self._store(key, g)

    def compare(self, a, b) -> Verdict:
        """:func:`compare` of two frames (FrameInfo)."""
        return compare(self.thumb(a), self.thumb(b))
