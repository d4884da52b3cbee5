"""What becomes of a frame that registration cannot align
(:func:`hdrcl.core.align.handheld.estimate`): it never passes as aligned, and it never
costs a set that needs no alignment.

A frame registration refuses (:class:`hdrcl.core.align.trust.Unaligned`: no convergence,
a degenerate transform, rank images that do not correlate, a fit that lost the pixels it
shared with its neighbour at the start) is

* **unmoved** when block matching of its tiles against the same neighbour
  (:func:`hdrcl.core.align.check.tile_estimate`, searched around the identity) puts it
  within :data:`hdrcl.core.align.handheld.STATIC_PX` of where it is: a set on a tripod whose
  fit fails (leaves or water moving in half the frame, a noisy flat scene). It takes the
  neighbour's matrix (model ``none``) and a ``note`` says so;
* else **left out** of the merge (model ``left out``; the chain of registrations passes
  over it) with a ``check`` finding naming it, when the caller collects findings and
  at least :data:`MIN_KEPT` frames remain; otherwise refused (the refusal naming it).

A frame too dark to share pixels with its neighbour is neither: it takes the neighbour's
motion (model ``inherited``, :func:`hdrcl.core.align.trust.register`), with a ``note``.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import List, Optional

import numpy as np

from hdrcl.core.align.trust import INHERITED, LEFT_OUT, Unaligned, motion_px
from hdrcl.core.findings import CHECK, NOTE, Finding

#: A set merges when at least this many frames remain once those left out are.
MIN_KEPT = 2


@dataclass
class Event:
    """One frame registration did not align as fitted: ``kind`` ``unmoved``,
    :data:`LEFT_OUT` or :data:`INHERITED`; positions in exposure order; ``figure`` the
    block-matched motion (px) of an unmoved frame."""

    pos: int
    anchor: int
    kind: str
    cause: str
    figure: Optional[float] = None
    error: Optional[Unaligned] = None


def still_px(reg, anchor: int, j: int) -> Optional[float]:
    """How far frame ``j`` sits from ``anchor`` by block matching searched around the
    identity (median over the frame, full-size pixels), or None when too few tiles agree."""
    from hdrcl.core.align import check as RC

    va, vb = (reg.valid[k][0] if reg.valid[k] is not None else None for k in (anchor, j))
    est = RC.tile_estimate(reg.levels(anchor)[0], va, reg.levels(j)[0], vb, np.eye(3))
    if est is None:
        return None
    h, w = reg.shape
    return motion_px(est.full()[0], h, w)


def settle(reg, exc: Unaligned, j: int, static_px: float) -> Event:
    """The fate of frame ``j`` that registration refused (module docstring)."""
    d = still_px(reg, exc.anchor, j)
    if d is not None and d < static_px:
        return Event(j, exc.anchor, "unmoved", exc.cause, d, exc)
    return Event(j, exc.anchor, LEFT_OUT, exc.cause, None, exc)


def check_kept(events: List[Event], n: int) -> None:
    """Raise the first refusal when fewer than :data:`MIN_KEPT` frames would remain."""
    left = [e for e in events if e.kind == LEFT_OUT]
    if left and n - len(left) < MIN_KEPT:
        raise left[0].error


def findings(events: List[Event], names, static: bool) -> List[Finding]:
    """One :class:`~hdrcl.core.findings.Finding` per event (``names`` in exposure order);
    ``static``: the set was merged unaligned (no frame moved)."""
    out = []
    for e in events:
        name, anchor = names[e.pos], names[e.anchor]
        if e.kind == "unmoved":
            then = "merged unaligned" if static else f"merged with the alignment of {anchor}"
            msg = (f"{name}: frames do not move ({e.figure:.2f} px against {anchor} by block matching, where "
                   f"registration failed: {e.cause}); {then}")
            out.append(Finding("alignment", msg, NOTE, name, e.figure))
        elif e.kind == LEFT_OUT:
            msg = (f"{name}: left out of the merge: it cannot be aligned to {anchor}: {e.cause}; check that it "
                   "belongs to this bracket (a mirrored, blank or other scene's frame, or one moved too far)")
            out.append(Finding("alignment", msg, CHECK, name))
        else:  # INHERITED: a dark frame, nothing to measure
            out.append(Finding("alignment", f"{name}: {e.cause}; it takes the motion of {anchor}", NOTE, name))
    return out


def without(inputs, left_out):
    """``inputs`` (:class:`hdrcl.core.sources.Inputs`) without the frames at the indices
    ``left_out``: paths, headers and exposures stay in step with the frames merged."""
    keep = [i for i in range(len(inputs.paths)) if i not in set(left_out)]
    return replace(inputs, paths=[inputs.paths[i] for i in keep], infos=[inputs.infos[i] for i in keep],
                   times=np.asarray(inputs.times, np.float64)[keep])


__all__ = ["Event", "INHERITED", "LEFT_OUT", "MIN_KEPT", "check_kept", "findings", "settle", "still_px", "without"]
