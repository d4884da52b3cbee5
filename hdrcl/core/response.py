"""The camera response ``g = ln f^-1``: one table per channel, its knots, its JSON file
format (:class:`Response`), and the linear response of RAW data. :meth:`Response.load`
and :meth:`Response.save` also read and write hdrgen's ``.rsp`` polynomials
(:mod:`hdrcl.io.rsp`), chosen by the file's extension.
"""
from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from hdrcl.errors import InputError, UsageError

logger = logging.getLogger(__name__)

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


#: Codes (8-bit units) between which a curve's span is measured, and the span in
#: decades beyond which an 8-bit curve is reported as stretched.
SPAN_LOW, SPAN_HIGH = 10, 245
SPAN_WARN_DECADES = 4.0
#: The body of the curve (codes 25..230) and the decades beyond which it counts as
#: stretched. A uniform stretch (wrong exposure times) widens the body as much as the
#: ends; a steep toe or shoulder that few samples constrain (film scans: the Memorial
#: set spans 6.5 decades over 10..245 but 2.2 over 25..230) widens only the ends. A
#: camera JPEG's body spans about 1.9 decades.
SPAN_BODY = (25, 230)
SPAN_BODY_WARN_DECADES = 2.8


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

    def span_decades(self, low: Optional[int] = None, high: Optional[int] = None) -> float:
        """Decades of exposure between codes ``low`` and ``high`` (8-bit units, scaled
        for 16-bit; default :data:`SPAN_LOW`, :data:`SPAN_HIGH`), the largest over the
        channels. A camera JPEG spans about 2.5."""
        low = SPAN_LOW if low is None else low
        high = SPAN_HIGH if high is None else high
        t = self.tables()
        scale = (self.levels - 1) / 255.0
        lo, hi = int(round(low * scale)), int(round(high * scale))
        return float(np.max(t[:, hi] - t[:, lo]) / np.log(10.0))

    def span_problem(self) -> Optional[str]:
        """A warning when an 8-bit curve spans more than :data:`SPAN_WARN_DECADES`
        between codes 10 and 245 *and* its body (:data:`SPAN_BODY`) more than
        :data:`SPAN_BODY_WARN_DECADES`: the mark of exposure times that stretched it, not
        of a steep, weakly constrained toe."""
        span = self.span_decades()
        if (self.bits == 8 and span > SPAN_WARN_DECADES
                and self.span_decades(*SPAN_BODY) > SPAN_BODY_WARN_DECADES):
            return (f"the response spans {span:.1f} decades between codes {SPAN_LOW} and {SPAN_HIGH} "
                    f"(camera JPEGs span about 2.5): wrong exposure times stretch a curve so; "
                    f"check them unless this is film")
        return None

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
            bad = np.flatnonzero(depth > 0)
            if not np.any(steps > 0):  # no rising step to measure the dip in levels by
                out.append(
                    f"channel {name}: recovered curve does not rise between codes 10 and 245 (it turns "
                    f"back by {worst:.3g} between levels {bad[0] - 1} and {bad[-1]}): the frames do not "
                    "constrain it; check that they differ and that their exposure times are right"
                )
                continue
            levels = worst / float(np.median(steps[steps > 0]))
            if levels <= tolerance_levels:
                continue
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
        """Build a response from its JSON form, checked against
        :data:`hdrcl.io.jsondoc.RESPONSE_SCHEMA`; :class:`InputError` names ``source``
        and the bad field."""
        from hdrcl.io.jsondoc import RESPONSE_SCHEMA, validate

        if not isinstance(d, dict) or d.get("format") != RESPONSE_FORMAT:
            raise InputError(f"{source}: not an hdrcl response file (no \"format\": \"{RESPONSE_FORMAT}\")")
        version = d.get("version", 1)
        # 2.0 and 1e300 are JSON Schema integers too: any number above the version known
        # is a newer format (a fraction such as 1.5 fails the schema's integer check).
        if (isinstance(version, int) and not isinstance(version, bool)
                or isinstance(version, float) and version.is_integer()) and version > RESPONSE_VERSION:
            shown = f"{version:g}" if isinstance(version, float) else str(version)
            raise InputError(
                f"{source}: response file version {shown} is newer than this hdrcl "
                f"understands ({RESPONSE_VERSION}); upgrade hdrcl"
            )
        validate(d, RESPONSE_SCHEMA, source)
        channels = tuple(d["channels"])
        if len(set(channels)) != len(channels):
            raise InputError(f"{source}: channels: a channel is listed twice")
        missing = [c for c in channels if c not in d["g"]]
        if missing:
            raise InputError(f"{source}: g: no curve for channel {missing[0]}")
        bits = int(d["bits"])
        knots = np.asarray(d["knots"], np.float64)
        g = np.asarray([d["g"][c] for c in channels], np.float64)
        levels = 1 << bits
        if "levels" in d and int(d["levels"]) != levels:
            raise InputError(f"{source}: levels: {d['levels']} does not match bits {bits}")
        if knots.size > levels or np.any(np.diff(knots) <= 0) or knots[0] < 0 or knots[-1] > levels - 1:
            raise InputError(f"{source}: knots: expected increasing code values within 0..{levels - 1}")
        for c, name in enumerate(channels):
            if len(d["g"][name]) != knots.size:
                raise InputError(f"{source}: g.{name}: {len(d['g'][name])} values for {knots.size} knots")
        if not np.all(np.isfinite(g)) or np.any(np.abs(g) > 1e6):
            raise InputError(f"{source}: g: the curve holds non-finite or absurd values")
        resp = cls(
            bits=bits, g=g, knots=knots, channels=channels,
            smoothness=float(d.get("smoothness", 0.0)), weight=str(d.get("weight", "hat")),
            samples=int(d.get("samples", 0)), seed=int(d.get("seed", 0)), camera=dict(d.get("camera") or {}),
            exposures=list(d.get("exposures") or []), warnings=list(d.get("warnings") or []),
        )
        resp.check_given(source)
        return resp

    def check_given(self, source: str = "response") -> None:
        """Refuse a curve that does not increase; warn about local decreases.

        A response given to a merge (``--response``) is inverted: a flat or decreasing
        curve (between codes :data:`SPAN_LOW` and :data:`SPAN_HIGH`) would give
        meaningless radiance, so it raises InputError; a curve with a few decreasing
        steps is used with a warning naming ``source``.
        """
        t = self.tables()
        scale = (self.levels - 1) / 255.0
        lo, hi = int(round(SPAN_LOW * scale)), int(round(SPAN_HIGH * scale))
        for c, name in enumerate(self.channels):
            if not t[c, hi] - t[c, lo] > 0.01:
                raise InputError(
                    f"{source}: channel {name} of the response does not increase between codes "
                    f"{SPAN_LOW} and {SPAN_HIGH} (g goes from {t[c, lo]:.3g} to {t[c, hi]:.3g}); "
                    "it cannot be inverted"
                )
        for msg in self.monotonic_problems():
            logger.warning("%s: %s", source, msg)

    def to_json(self) -> str:
        """The response file's text (see :meth:`to_dict`)."""
        return json.dumps(self.to_dict(), indent=1) + "\n"

    def save(self, path):
        """Write the response atomically (temporary file, then rename), with the
        permissions the umask allows: JSON, or hdrgen's polynomial form when ``path``
        ends in ``.rsp`` (:mod:`hdrcl.io.rsp`; returns its :class:`~hdrcl.io.rsp.RspFit`,
        the order and fit error per channel, else None)."""
        from hdrcl.io.atomic import write_text

        if os.fspath(path).lower().endswith(".rsp"):
            from hdrcl.io.rsp import write_rsp

            if self.bits != 8:  # hdrgen's polynomials are read back as 8-bit codes
                raise UsageError(f"{os.fspath(path)}: hdrgen's .rsp holds 8-bit responses; this one is "
                                 f"{self.bits}-bit: write it as .json")

            return write_rsp(self.tables(), self.levels, path)
        write_text(path, self.to_json())
        return None

    @classmethod
    def load(cls, path) -> "Response":
        """Read a response file, hdrcl's JSON or (``.rsp``) hdrgen's polynomials
        (:mod:`hdrcl.io.rsp`); :class:`InputError` names the file and the problem (a UTF-8
        byte-order mark is accepted)."""
        from hdrcl.io.jsondoc import read_json

        path = os.fspath(path)
        if path.lower().endswith(".rsp"):
            from hdrcl.io.rsp import read_rsp

            g, channels = read_rsp(path)
            resp = cls(bits=8, g=g, knots=np.arange(256, dtype=np.float64), channels=channels, smoothness=0.0,
                       camera={"responseFile": os.path.basename(path)})
            resp.check_given(path)
            return resp
        return cls.from_dict(read_json(path, "response file"), source=path)


def as_response(response) -> Optional[Response]:
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


_as_response = as_response  # the earlier private name (core modules still use it)
