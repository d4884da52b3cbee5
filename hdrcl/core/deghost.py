"""Ghost removal: pixels where the frames disagree with a static scene.

With a moving subject (leaves, water, people) each frame sees something different at
some pixels, and the weighted average of the paper blends them into semi-transparent
"ghosts". Here every frame's own radiance estimate, ``ln E_j = g(Z_j) - ln dt_j``, is
compared with the reference frame's. Where a frame that measures the pixel well
differs from the reference by more than its noise allows, the pixel is a ghost and its
radiance is taken from the reference exposure alone. Where the reference itself is out
of its working range at a ghost pixel (per channel), the nearest exposure on the side
that measures it (longer for dark, shorter for bright) stands in; where none does, the
fused value is kept and the pixel-channel is counted as unresolved.

Noise model: a code carries about ``sigma_z`` code values of noise (read noise plus
quantisation), so ``ln E_j`` is uncertain by ``g'(Z_j) * sigma_z``; a difference beyond
``k`` times the combined uncertainty, and beyond ``floor`` in ln units, flags the pixel.
The mask is dilated by ``grow`` pixels so the edges of a moving object go too.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

#: Noise of one code value (8-bit units), the combined-uncertainty factor, and the
#: smallest ln-radiance difference that counts as a ghost (0.25 ~ 1/3 stop).
SIGMA_Z = 2.0
K_SIGMA = 4.0
FLOOR = 0.25
GROW = 2
#: Codes within this fraction of either end are too near clipping to judge.
MARGIN = 0.04


@dataclass
class GhostResult:
    mask: np.ndarray  # (H, W) bool, pixels taken from the reference
    fraction: float
    unresolved: int  # ghost pixels where the reference itself is clipped


def reference_index(times: Sequence[float]) -> int:
    """The middle exposure (frames ordered by time): the default reference."""
    order = np.argsort(np.asarray(times, np.float64), kind="stable")
    return int(order[len(order) // 2])


def _estimates(frames, log_times, tables, valid, j):
    levels = tables.shape[1]
    lo, hi = MARGIN * (levels - 1), (1 - MARGIN) * (levels - 1)
    chan = np.arange(tables.shape[0])
    z = frames[j].astype(np.int64)
    ln_e = tables[chan, z] - log_times[j]
    ok = (z >= lo) & (z <= hi)
    if valid is not None and valid[j] is not None:
        ok &= valid[j][..., None]
    return z, ln_e, ok


def grow(raw: np.ndarray, above: Optional[np.ndarray] = None, below: Optional[np.ndarray] = None) -> np.ndarray:
    """Dilate a raw ghost mask by ``GROW`` pixels. ``above``/``below`` are the raw masks'
    neighbouring rows from the strips before and after (up to ``GROW`` rows each), so
    that strips grow exactly as the whole image would."""
    if not GROW:
        return raw
    parts = [p for p in (above, raw, below) if p is not None]
    stack = np.concatenate(parts) if len(parts) > 1 else raw
    if not stack.any():
        return np.zeros_like(raw)
    from scipy import ndimage

    top = 0 if above is None else above.shape[0]
    return ndimage.binary_dilation(stack, iterations=GROW)[top:top + raw.shape[0]]


def detect(frames: Sequence[np.ndarray], log_times: Sequence[float], tables: np.ndarray,
           valid: Optional[Sequence[Optional[np.ndarray]]], fused: np.ndarray, dilate: bool = True) -> np.ndarray:
    """Ghost mask ``(H, W)`` of a strip or image.

    ``fused`` is the radiance the plain weighted average gave; a frame that measures a
    pixel within its working range and departs from it by more than
    ``max(K_SIGMA * g'(Z) * SIGMA_Z, FLOOR)`` (ln units) marks the pixel.
    ``dilate=False`` returns the raw mask, for :func:`grow` across strips.
    """
    levels = tables.shape[1]
    scale = levels / 256.0
    slope = np.gradient(tables, axis=1)  # dg/dz per channel
    chan = np.arange(tables.shape[0])
    with np.errstate(divide="ignore"):
        ln_f = np.log(np.maximum(fused, 1e-30))
    ghost = np.zeros(frames[0].shape[:2], bool)
    for j in range(len(frames)):
        z, ln_e, ok = _estimates(frames, log_times, tables, valid, j)
        sig = slope[chan, z] * SIGMA_Z * scale
        bad = ok & (fused > 0) & (np.abs(ln_e - ln_f) > np.maximum(K_SIGMA * sig, FLOOR))
        ghost |= bad.any(axis=2)
    return grow(ghost) if dilate else ghost


def replace(radiance: np.ndarray, frames, log_times, tables, ghost: np.ndarray, valid, ref: int) -> int:
    """Give ghost pixels the reference exposure's own estimate (in place).

    Returns the number of ghost pixel-channels no single frame could serve.
    """
    if not ghost.any():
        return 0
    levels = tables.shape[1]
    rz, r_ln, r_ok = _estimates(frames, log_times, tables, valid, ref)
    sel = ghost[..., None] & np.ones(r_ok.shape[-1:], bool)
    done = sel & r_ok
    radiance[done] = np.exp(r_ln[done])
    todo = sel & ~r_ok
    dark = rz < levels // 2
    for step, side in ((1, dark), (-1, ~dark)):  # longer exposures for dark, shorter for bright
        j = ref + step
        while 0 <= j < len(frames) and (todo & side).any():
            _, ln_e, ok = _estimates(frames, log_times, tables, valid, j)
            use = todo & side & ok
            radiance[use] = np.exp(ln_e[use])
            todo &= ~use
            j += step
    return int(np.count_nonzero(todo))
