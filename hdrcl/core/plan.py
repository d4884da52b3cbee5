"""A merge as data: a frozen :class:`MergePlan` per set, made by one function
(:func:`plan_merge`) and run by :func:`hdrcl.core.executor.execute`.

The plan says what to read (the frame source: files streamed strip by strip, files held
whole for alignment, or arrays in memory), which response (:class:`ResponsePlan`: solved
from the set itself, given, a batch's pooled or cached curve, or deferred to this set's
merge), which sinks see the fused strips besides the file (a preview, a kept map, masks,
a luminance chain), where to write and the metadata the file gets beyond the merge's own.
``hdrcl merge`` (:func:`hdrcl.core.merge.merge_files`), each set of ``hdrcl batch``
(:mod:`hdrcl.shoot.batch.setrun`) and the API on arrays all make one; nothing in a plan
changes while it runs (the executor's run state, :class:`hdrcl.core.runstate.RunState`,
holds what the stages find).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Optional, Sequence, Tuple

from hdrcl.core.options import MergeOptions
from hdrcl.core.sources import GivenResponse, Inputs, ResponseSource

#: The frame sources: files decoded strip by strip as the fusion needs them, files decoded
#: whole (alignment needs every frame at once), or frames already in memory.
STREAMED, HELD, MEMORY = "streamed", "held", "memory"

#: Where a response comes from.
RESPONSE_KINDS = ("own", "given", "pooled", "cached", "deferred")


@dataclass(frozen=True)
class Extras:
    """What a merge keeps or writes besides its radiance file (the keywords of
    :func:`hdrcl.merge_files` that are not options)."""

    keep_radiance: bool = False
    keep_frames: bool = False
    thumbnail: int = 0
    ghost_mask: Optional[str] = None
    clip_mask: Optional[str] = None
    owner: Optional[str] = None
    save_response: Optional[str] = None
    chain: object = None
    sinks: Sequence = ()  # more sinks of the scaled radiance (first pass)


@dataclass(frozen=True)
class ResponsePlan:
    """Which response a merge uses: ``own`` (solved from the set, or linear for RAW),
    ``given`` (a file or object), ``pooled`` / ``cached`` (a batch's camera curve), or
    ``deferred`` (a batch camera's only set solves it). ``trust``, when set, says what
    the curve's pool found about this set's exposure metadata (findings from the grid)."""

    kind: str
    source: ResponseSource
    trust: Optional[Callable] = None

    @property
    def name(self) -> str:
        return self.source.name


@dataclass(frozen=True)
class MergePlan:
    """One merge, decided before anything is decoded (see the module's docstring).

    ``sinks`` are ``(name, make)`` pairs: ``make(h, w, nch)`` builds a sink of the first
    fusion pass once the image's size is known (after any crop); the run state holds them
    by name (``run.sinks``). ``tap``, when set, wraps a streamed source for the first pass
    (``tap(source, h, w, nch)``: a batch keeps the quality report's frames as they stream
    past). ``metadata`` is what the file gets besides the merge's own;
    ``record_findings`` adds the findings known when the file is opened. ``checks`` off:
    a merge run as a measuring device (a leave-one-out), not of the user's frames.
    """

    inputs: Inputs
    options: MergeOptions
    response: ResponsePlan
    frames: str
    output: Optional[str]
    extras: Extras = Extras()
    bracket: Any = None  # with MEMORY: the hdrcl.core.bracket.Bracket
    sinks: Tuple = ()
    tap: Optional[Callable] = None
    metadata: Tuple = ()  # (key, value) pairs
    record_findings: bool = False
    findings: Tuple = ()  # hdrcl.core.findings.Finding known before the merge (a batch's scan)
    reference_from_exposures: bool = False  # the reference exposure from the exposures measured
    checks: bool = True  # the checks of the user's frames (brightness order, agreement); off to measure

    def describe(self) -> dict:
        """The plan in words (a dry run's line)."""
        return {"files": [str(p) for p in self.inputs.paths], "frames": self.frames,
                "response": self.response.kind, "response_name": self.response.name, "output": self.output,
                "sinks": [name for name, _ in self.sinks] + (["thumbnail"] if self.extras.thumbnail else [])
                + (["radiance"] if self.extras.keep_radiance else [])}


def response_plan(source: ResponseSource, kind: Optional[str] = None, trust=None) -> ResponsePlan:
    """The response plan of ``source``: ``own`` when it solves, else ``given`` (or ``kind``)."""
    if kind is None:
        kind = "given" if isinstance(source, GivenResponse) or not source.solves else "own"
    if kind not in RESPONSE_KINDS:
        raise ValueError(f"response kind {kind!r}: one of {', '.join(RESPONSE_KINDS)}")
    return ResponsePlan(kind, source, trust)


def plan_merge(inputs: Optional[Inputs], options: MergeOptions, response, output: Optional[str] = None, *,
               extras: Optional[Extras] = None, bracket=None, **fields) -> MergePlan:
    """The one place a :class:`MergePlan` is made. ``response`` is a
    :class:`ResponsePlan` or a :class:`hdrcl.core.sources.ResponseSource`; ``bracket`` (a
    loaded :class:`hdrcl.core.bracket.Bracket`) makes an in-memory merge (``inputs`` from it
    when None). ``fields`` are the plan's other fields (a batch's sinks, tap, metadata,
    findings)."""
    import numpy as np

    if not isinstance(response, ResponsePlan):
        response = response_plan(response)
    if bracket is not None:
        frames = MEMORY
        if inputs is None:
            inputs = Inputs(list(bracket.paths), list(bracket.infos), np.asarray(bracket.times, np.float64))
        extras = extras or Extras(keep_radiance=True)
    else:
        frames = HELD if options.align else STREAMED
    return MergePlan(inputs=inputs, options=options, response=response, frames=frames, output=output,
                     extras=extras or Extras(), bracket=bracket, **fields)
