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
