"""The camera response ``g = ln f^-1``: one table per channel, its knots, its JSON file
format (:class:`Response`), and the linear response of RAW data.
"""
from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from hdrcl.errors import InputError, UsageError

RESPONSE_FORMAT = "hdrcl-response"

#: A curve that turns back by less than this many code levels' worth of exposure is not
#: reported (:meth:`Response.monotonic_problems`).
MONOTONIC_TOLERANCE_LEVELS = 2.0


RESPONSE_VERSION = 1


#: Knots of the solved curve for 16-bit data.
BINS_16BIT = 1024


#: Default smoothness lambda per weighting (rows carry lambda * w(z) * [1, -2, 1]), for
#: the default sample count. Chosen on synthetic scenes (curve error) and the Memorial
#: set (leave-one-out error); see scripts/memorial_loo.py.
DEFAULT_SMOOTHNESS = {"hat": 40.0, "gaussian": 60.0}


def default_smoothness(weight: str = "hat") -> float:
    """The default lambda for a weighting function."""
    return DEFAULT_SMOOTHNESS.get(weight, DEFAULT_SMOOTHNESS["hat"])


def _check_smoothness(smoothness, weight: str) -> float:
    if smoothness is None:
        return default_smoothness(weight)
    smoothness = float(smoothness)
    if not (smoothness > 0 and np.isfinite(smoothness)):
        raise UsageError(f"--smoothness must be a positive number, not {smoothness:g}")
    return smoothness


def knot_positions(bits: int) -> np.ndarray:
    """Code values at which the curve is solved: every level for 8-bit, bin centres above."""
    levels = 1 << bits
    if levels <= BINS_16BIT:
        return np.arange(levels, dtype=np.float64)
    step = levels / BINS_16BIT
    return (np.arange(BINS_16BIT) + 0.5) * step - 0.5


def _segments(z: np.ndarray, knots: np.ndarray):
    """Knot segment index and fraction for code values ``z`` (uniform knots)."""
    step = knots[1] - knots[0]
    i = np.clip(np.floor((z - knots[0]) / step).astype(np.int64), 0, knots.size - 2)
    f = (z - knots[i]) / step
    return i, f


@dataclass
class Response:
    """A recovered response curve, one per channel, with its provenance.

    Attributes
    ----------
    bits : int
        Bits per sample of the photographs it describes (8 or 16).
    g : ndarray, shape (C, K)
        ``g = ln f^-1`` at ``knots``, natural-log exposure units, ``g(Zmid) = 0``.
    knots : ndarray, shape (K,)
        Code values of the samples of ``g``.
    channels : tuple of str
    smoothness, weight, samples, seed
        The solve's parameters.
    camera : dict
        Make, model, ISO of the source photographs where known.
    exposures : list of dict
        Per source frame: ``{"file", "nominal", "fitted"}`` (seconds).
    warnings : list of str
        Problems noticed, e.g. a non-monotonic curve.
    """

    bits: int
    g: np.ndarray
    knots: np.ndarray
    channels: tuple = ("R", "G", "B")
    smoothness: float = 40.0
    weight: str = "hat"
    samples: int = 0
    seed: int = 0
    camera: dict = field(default_factory=dict)
    exposures: list = field(default_factory=list)
    warnings: list = field(default_factory=list)

    @property
    def levels(self) -> int:
        return 1 << self.bits

    @property
    def nchannels(self) -> int:
        return int(self.g.shape[0])

    def tables(self) -> np.ndarray:
        """``g`` at every code value, shape ``(C, levels)``, float64.

        Between knots the curve is linear; beyond the outermost knots (16-bit only) it
        is extended along the last segment.
        """
        z = np.arange(self.levels, dtype=np.float64)
        if self.knots.size == self.levels:
            return np.array(self.g, dtype=np.float64, copy=True)
        i, f = _segments(z, self.knots)
        return self.g[:, i] * (1.0 - f) + self.g[:, i + 1] * f

    def table_for(self, nchannels: int) -> np.ndarray:
        """Tables matched to an image of ``nchannels`` colour channels."""
        t = self.tables()
        if t.shape[0] == nchannels:
            return t
        if t.shape[0] == 1:
            return np.repeat(t, nchannels, axis=0)
        raise UsageError(
            f"the response has {t.shape[0]} channels but the images have {nchannels}"
        )

    def monotonic_problems(self, tolerance_levels: float = MONOTONIC_TOLERANCE_LEVELS) -> List[str]:
        """Describe every channel whose curve turns back by more than noise explains.

        A decrease of ``g`` matters by its depth, ``max(running maximum of g - g)``:
        rendering and the coverage figures use the running maximum, so a dip of depth
        ``d`` moves a rendered code by at most ``d / slope`` levels, ``slope`` being
        the curve's median step per level over the working range (8-bit 10..245). A
        dip shallower than ``tolerance_levels`` such levels (default 2, below the
        8-bit data's own quantisation and noise) is left unreported; the Memorial
        set's curves have dips of 0.1 and 1.6 levels.
        """
        out = []
        t = self.tables()
        scale = (self.levels - 1) / 255.0
        lo, hi = int(round(10 * scale)), int(round(245 * scale))
        for c, name in enumerate(self.channels):
            g = t[c]
            depth = np.maximum.accumulate(g) - g
            worst = float(depth.max())
            if worst <= 0:
                continue
            steps = np.diff(g[lo:hi + 1])
            slope = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 0.0
            levels = worst / slope if slope > 0 else float("inf")
            if levels <= tolerance_levels:
                continue
            bad = np.flatnonzero(depth > 0)
            out.append(
                f"channel {name}: recovered curve is not monotonic: it turns back by {worst:.3g} "
                f"(about {levels:.1f} code levels) between levels {bad[0] - 1} and {bad[-1]}; "
                "try more --smoothness or more --samples"
            )
        return out

    # -- persistence -------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "format": RESPONSE_FORMAT,
            "version": RESPONSE_VERSION,
            "bits": self.bits,
            "levels": self.levels,
            "channels": list(self.channels),
            "knots": [float(k) for k in self.knots],
            "g": {name: [round(float(v), 9) for v in self.g[c]] for c, name in enumerate(self.channels)},
            "smoothness": self.smoothness,
            "weight": self.weight,
            "samples": self.samples,
            "seed": self.seed,
            "camera": self.camera,
            "exposures": self.exposures,
            "warnings": self.warnings,
        }

    @classmethod
    def from_dict(cls, d: dict, source: str = "response") -> "Response":
        if not isinstance(d, dict) or d.get("format") != RESPONSE_FORMAT:
            raise InputError(f"{source}: not an hdrcl response file (no \"format\": \"{RESPONSE_FORMAT}\")")
        if int(d.get("version", 0)) > RESPONSE_VERSION:
            raise InputError(
                f"{source}: response file version {d.get('version')} is newer than this hdrcl "
                f"understands ({RESPONSE_VERSION}); upgrade hdrcl"
            )
        try:
            channels = tuple(d["channels"])
            knots = np.asarray(d["knots"], np.float64)
            g = np.asarray([d["g"][c] for c in channels], np.float64)
            bits = int(d["bits"])
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{source}: malformed response file ({exc!s})") from None
        if bits not in (8, 16) or g.shape != (len(channels), knots.size) or knots.size < 3:
            raise InputError(f"{source}: malformed response file (bits {bits}, curve shape {g.shape})")
        if not np.all(np.isfinite(g)):
            raise InputError(f"{source}: response curve holds non-finite values")
        return cls(
            bits=bits, g=g, knots=knots, channels=channels,
            smoothness=float(d.get("smoothness", 0.0)), weight=str(d.get("weight", "hat")),
            samples=int(d.get("samples", 0)), seed=int(d.get("seed", 0)), camera=dict(d.get("camera", {})),
            exposures=list(d.get("exposures", [])), warnings=list(d.get("warnings", [])),
        )

    def save(self, path) -> None:
        """Write the response as JSON, atomically (temporary file, then rename)."""
        path = os.fspath(path)
        folder = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(folder):
            raise UsageError(f"{path}: output folder does not exist")
        fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp", dir=folder)
        try:
            with os.fdopen(fd, "w") as fh:
                json.dump(self.to_dict(), fh, indent=1)
                fh.write("\n")
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise

    @classmethod
    def load(cls, path) -> "Response":
        path = os.fspath(path)
        try:
            with open(path) as fh:
                d = json.load(fh)
        except FileNotFoundError:
            raise InputError(f"{path}: response file not found") from None
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: cannot read response file ({exc!s})") from None
        return cls.from_dict(d, source=path)


def _as_response(response) -> Optional[Response]:
    if response is None or isinstance(response, Response):
        return response
    return Response.load(response)


def linear_response(nchannels: int = 3):
    """The response of linear 16-bit data: ``g(z) = ln(max(z, 0.5) / 32768)`` per channel.

    Stored at every code (65536 knots), since ``ln z`` is far too curved near 0 for the
    1024 bins of a solved 16-bit curve. ``g(32768) = 0`` as hdrcl's curves require; code 0
    is given the value of 0.5 (it has zero weight anyway).

    Returns
    -------
    hdrcl.response.Response
        ``bits = 16``, channels R, G, B (or Y), ``smoothness = 0``, ``samples = 0``.
    """
    if nchannels not in (1, 3):
        raise ValueError(f"nchannels must be 1 or 3, not {nchannels}")
    knots = np.arange(1 << 16, dtype=np.float64)
    g = np.log(np.maximum(knots, 0.5) / 32768.0)
    return Response(bits=16, g=np.repeat(g[None, :], nchannels, axis=0), knots=knots,
                    channels=("R", "G", "B") if nchannels == 3 else ("Y",), smoothness=0.0,
                    weight="hat", samples=0, seed=0, camera={}, exposures=[], warnings=[])
