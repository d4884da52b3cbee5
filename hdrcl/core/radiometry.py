"""Beyond relative radiance: absolute scale, white balance, and linear filtering.

The fused map is relative (``g(Zmid) = 0`` per channel). Three corrections give it
physical meaning:

* **Absolute scale from the camera settings** (approximate). A reflected-light meter
  sets ``N^2 / t = L S / K`` for a scene of average luminance ``L`` (cd/m^2), with the
  ISO 2720 calibration constant ``K = 12.5`` (Canon, Nikon, Sekonic). A camera renders
  that metered grey near the middle code, where hdrcl's radiance is ``1 / t`` (at the
  first frame's aperture ``N0`` and ISO ``S0``). So one radiance unit is about
  ``K N0^2 / S0`` cd/m^2. Expect errors of a third of a stop or so: cameras place grey
  differently and lens transmission is not f-number.
* **A reference patch** of known luminance fixes the scale exactly: the mean Rec.709
  luminance over the patch is made equal to the given value.
* **White balance from a neutral patch**: per-channel gains make the patch's mean
  R = G = B while keeping its luminance.

Patches are ``x,y,w,h`` in pixels of the merged image.
"""
from __future__ import annotations

from typing import Optional, Sequence, Tuple

import numpy as np

from hdrcl.errors import UsageError

#: Reflected-light meter calibration constant (cd/m^2 * s * ISO), ISO 2720.
METER_K = 12.5
LUMA = np.array([0.2126, 0.7152, 0.0722])


def parse_patch(text, what: str = "--neutral") -> Tuple[int, int, int, int]:
    """``"x,y,w,h"`` (or a 4-tuple) as integers, validated."""
    if isinstance(text, str):
        try:
            vals = tuple(int(v) for v in text.split(","))
        except ValueError:
            vals = ()
    else:
        vals = tuple(int(v) for v in text)
    if len(vals) != 4 or vals[0] < 0 or vals[1] < 0 or vals[2] < 1 or vals[3] < 1:
        raise UsageError(f"{what}: expected x,y,w,h in pixels (w, h > 0), not '{text}'")
    return vals


def parse_reference_patch(text) -> Tuple[Tuple[int, int, int, int], float]:
    """``"x,y,w,h=VALUE"`` -> (patch, cd/m^2)."""
    if isinstance(text, str):
        box, sep, value = text.partition("=")
        try:
            v = float(value)
        except ValueError:
            v = float("nan")
        if not sep or not (v > 0 and np.isfinite(v)):
            raise UsageError(f"--reference-patch: expected x,y,w,h=VALUE (cd/m^2 > 0), not '{text}'")
        return parse_patch(box, "--reference-patch"), v
    box, v = text
    return parse_patch(box, "--reference-patch"), float(v)


def check_patch(patch, height: int, width: int, what: str) -> None:
    x, y, w, h = patch
    if x + w > width or y + h > height:
        raise UsageError(f"{what}: patch {x},{y},{w},{h} runs outside the {width}x{height} image")


def luminance(rgb: np.ndarray) -> np.ndarray:
    rgb = np.asarray(rgb, np.float64)
    return rgb[..., 0] if rgb.shape[-1] == 1 else rgb @ LUMA


def exif_scale(fnumber: Optional[float], iso: Optional[float]) -> float:
    """cd/m^2 per radiance unit from the first frame's f-number and ISO."""
    if not fnumber or not iso:
        raise UsageError("the absolute scale (--absolute, or a luminance map's --lens-circle) needs the first "
                         "frame's f-number and ISO (EXIF FNumber, ISO); use --reference-patch instead")
    return METER_K * float(fnumber) ** 2 / float(iso)


def neutral_gains(patch_rgb: np.ndarray) -> np.ndarray:
    """Per-channel gains that make the patch's mean neutral at the same luminance."""
    mean = np.asarray(patch_rgb, np.float64).reshape(-1, patch_rgb.shape[-1]).mean(axis=0)
    if mean.size == 1:
        return np.ones(1)
    if np.any(mean <= 0):
        raise UsageError("--neutral: the patch has no signal in some channel (black or invalid)")
    y = float(mean @ LUMA)
    return y / mean


def patch_scale(patch_rgb: np.ndarray, value: float) -> float:
    """Scale that makes the patch's mean luminance equal ``value``."""
    y = float(luminance(np.asarray(patch_rgb, np.float64).reshape(-1, patch_rgb.shape[-1]).mean(axis=0)))
    if not y > 0:
        raise UsageError("--reference-patch: the patch has no signal (black or invalid)")
    return value / y


class ScaledSink:
    """Multiplies every strip by per-channel factors before passing it on."""

    def __init__(self, sink, factors: Sequence[float]):
        self.sink = sink
        self.factors = np.asarray(factors, np.float32)

    def write_rows(self, y0, y1, data):
        data *= self.factors  # the strip buffer is ours to change
        self.sink.write_rows(y0, y1, data)


def motion_blur(radiance: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """Linear motion blur along ``(dx, dy)`` pixels: the mean of the image shifted along
    the segment, sampled at one-pixel steps with bilinear interpolation.

    Done on radiance this is physically right (light adds); the paper's point is that
    the same blur on an 8-bit photo loses the energy of clipped highlights.
    """
    from scipy import ndimage

    img = np.asarray(radiance, np.float32)
    n = int(np.ceil(max(abs(dx), abs(dy)))) + 1
    if n <= 1:
        return img.copy()
    acc = np.zeros(img.shape, np.float64)
    for s in np.linspace(0.0, 1.0, n):
        shift = (s * dy, s * dx) + (0,) * (img.ndim - 2)
        acc += ndimage.shift(img, shift, order=1, mode="nearest")
    return (acc / n).astype(np.float32)
