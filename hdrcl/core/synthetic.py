"""Synthetic scenes with known truth: a radiance field, a camera curve, a bracket.

Used by the tests, the demo and the benchmarks. Everything is seeded.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np


@dataclass
class Camera:
    """A monotonic S-shaped camera: ``f(X) = 1 / (1 + (x0 / X)^a)`` per channel.

    In log exposure this is a logistic curve, the shape of film and of cameras'
    built-in tone curves. ``x0`` (per channel) shifts each channel, like a colour cast.
    """

    a: float = 1.1
    x0: Sequence[float] = (1.0, 1.0, 1.0)
    bits: int = 8

    @property
    def levels(self) -> int:
        return 1 << self.bits

    def forward(self, x: np.ndarray, channel: int = 0) -> np.ndarray:
        """Normalised output in (0, 1) for exposure ``x``."""
        x0 = self.x0[channel % len(self.x0)]
        with np.errstate(divide="ignore", over="ignore"):
            return 1.0 / (1.0 + (x0 / np.maximum(x, 1e-300)) ** self.a)

    def g(self, z: np.ndarray, channel: int = 0) -> np.ndarray:
        """True ``g(z) = ln f^-1(z / (L-1))`` for codes strictly inside the range."""
        y = np.asarray(z, np.float64) / (self.levels - 1)
        x0 = self.x0[channel % len(self.x0)]
        return np.log(x0) - np.log(1.0 / y - 1.0) / self.a


def radiance_field(height: int, width: int, decades: float = 4.5, channels: int = 3,
                   seed: int = 0) -> np.ndarray:
    """A smooth, textured scene spanning ``decades`` orders of magnitude.

    A diagonal ramp in log radiance carries the range; soft blobs (a "sun", shadows)
    and low-contrast texture make it look like a scene rather than a gradient. Channels
    differ slightly in colour. Returns float64 ``(H, W, C)`` with median about 1.
    """
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    u = xx / max(width - 1, 1)
    v = yy / max(height - 1, 1)
    log10 = decades * (0.65 * u + 0.35 * v) - decades / 2.0
    for _ in range(6):
        cx, cy = rng.uniform(0, 1, 2)
        r = rng.uniform(0.05, 0.25)
        amp = rng.uniform(-1.0, 1.0)
        log10 += amp * np.exp(-((u - cx) ** 2 + (v - cy) ** 2) / (2 * r * r))
    tex = np.zeros_like(log10)
    for k in (3, 7, 17):
        phase = rng.uniform(0, 2 * np.pi, 2)
        tex += np.sin(2 * np.pi * k * u + phase[0]) * np.cos(2 * np.pi * k * v + phase[1]) / k
    log10 += 0.15 * tex
    lo, hi = log10.min(), log10.max()
    log10 = (log10 - lo) / max(hi - lo, 1e-12) * decades - decades / 2.0
    tint = np.array([1.0, 0.9, 0.75])[:channels] if channels == 3 else np.ones(channels)
    return (10.0 ** log10)[..., None] * tint


def bracket(radiance: np.ndarray, times: Sequence[float], camera: Camera, noise: float = 0.5,
            seed: int = 0) -> list:
    """Photographs of ``radiance`` at ``times`` through ``camera``, quantised.

    ``noise`` is the standard deviation of Gaussian read noise in output codes (before
    quantisation).
    """
    rng = np.random.default_rng(seed)
    levels = camera.levels
    dtype = np.uint8 if camera.bits == 8 else np.uint16
    frames = []
    for t in times:
        y = np.empty(radiance.shape)
        for c in range(radiance.shape[2]):
            y[..., c] = camera.forward(radiance[..., c] * t, c) * (levels - 1)
        y += rng.normal(0.0, noise * (levels / 256.0), y.shape)
        frames.append(np.clip(np.floor(y + 0.5), 0, levels - 1).astype(dtype))
    return frames


def stops(n: int, step: float = 1.0, centre: float = 1.0) -> np.ndarray:
    """``n`` exposure times ``step`` stops apart, geometrically centred on ``centre``."""
    k = np.arange(n) - (n - 1) / 2.0
    return centre * 2.0 ** (k * step)


@dataclass
class NightScene:
    """A night bracket with a moon and wind-blown leaves (:func:`night_scene`).

    ``truth[k]`` is the radiance frame ``k`` saw (float64 ``(H, W, 3)``), ``frames[k]`` its
    8-bit photograph, ``times`` increasing, ``moon`` the (H, W) bool of the disc's
    interior in the middle frame (2 px inside its limb, leaves excluded).
    """

    truth: list
    frames: list
    times: np.ndarray
    camera: Camera
    moon: np.ndarray


def _coverage(dist: np.ndarray) -> np.ndarray:
    """Anti-aliased coverage of a shape from the signed distance to its edge (px, < 0 in)."""
    return np.clip(0.5 - dist, 0.0, 1.0)


def night_scene(height: int = 360, width: int = 480, frames: int = 5, step: float = 2.0, seed: int = 0,
                noise: float = 0.5, sway: float = 3.0) -> NightScene:
    """A moon saturating the longer frames above a dim sky, behind leaves that sway by up
    to ``sway`` px between frames (the moon drifts 0.6 px a frame).

    The moon (about 3 decades above the sky, limb-darkened, with soft darker maria) is
    measured only by the shorter frames; the leaves (a decade below the sky, thin,
    high-contrast edges) only by the longer ones: the scene of issue 32's real moon set,
    where ``--deghost`` left dark blotches at leaf edges and under the moon and a banded
    moon. Everything is seeded; sizes may be odd.
    """
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    scale = min(height, width)
    sky = 0.02 * (1.0 + 0.5 * yy / height) * np.exp(0.1 * np.sin(xx / (0.3 * scale)))
    mx, my, mr = 0.62 * width, 0.35 * height, 0.16 * scale
    maria = [(rng.uniform(-0.5, 0.5) * mr, rng.uniform(-0.5, 0.5) * mr, rng.uniform(0.15, 0.35) * mr)
             for _ in range(5)]
    leaves = []
    for _ in range(max(12, int(height * width / 2500))):
        cx, cy = rng.uniform(0, width), rng.uniform(0.15 * height, height)
        leaves.append((cx, cy, rng.uniform(3.0, 0.04 * scale + 4.0), rng.uniform(1.5, 6.0),
                       rng.uniform(0, np.pi)))
    times = stops(frames, step, centre=1.0)
    times = times / times[-1] * 64.0  # the longest frame: sky near mid-grey
    cam = Camera(a=1.1, x0=(1.0, 1.0, 1.0))
    truth, shots = [], []
    for k in range(frames):
        ox = mx + 0.6 * (k - frames // 2)
        d = np.hypot(xx - ox, yy - my)
        disc = _coverage(d - mr)
        limb = np.sqrt(np.clip(1.0 - (d / mr) ** 2, 0.0, 1.0))
        moon = 24.0 * (0.55 + 0.45 * limb)
        for ax, ay, ar in maria:
            moon = moon * (1.0 - 0.45 * np.exp(-((xx - ox - ax) ** 2 + (yy - my - ay) ** 2) / (ar * ar)))
        rad = sky * (1 - disc) + moon * disc
        dx, dy = rng.uniform(-sway, sway, 2) if k != frames // 2 else (0.0, 0.0)
        cover = np.zeros_like(rad)
        for cx, cy, a, b, th in leaves:  # each in its own window: big scenes stay quick
            x0, x1 = max(0, int(cx + dx - a - 2)), min(width, int(cx + dx + a + 3))
            y0, y1 = max(0, int(cy + dy - a - 2)), min(height, int(cy + dy + a + 3))
            if x0 >= x1 or y0 >= y1:
                continue
            u, v = xx[y0:y1, x0:x1] - cx - dx, yy[y0:y1, x0:x1] - cy - dy
            pu, pv = u * np.cos(th) + v * np.sin(th), -u * np.sin(th) + v * np.cos(th)
            near = np.hypot(pu / a, pv / b)
            win = cover[y0:y1, x0:x1]
            np.maximum(win, _coverage((near - 1.0) * b), out=win)
        rad = rad * (1 - cover) + 0.002 * cover
        rad = rad[..., None] * np.array([1.0, 0.95, 0.85])
        truth.append(rad)
        shots.append(bracket(rad, [times[k]], cam, noise=noise, seed=seed * 100 + k)[0])
    mid = frames // 2
    from scipy import ndimage

    inside = np.hypot(xx - mx, yy - my) < mr - 2.0
    inside &= truth[mid][..., 1] > 1.0
    inside = ndimage.binary_erosion(inside, iterations=2)
    return NightScene(truth, shots, times, cam, inside)
