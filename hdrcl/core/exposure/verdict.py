"""Whether a set's exposure metadata can be trusted, from its own calibration: the verdict
(:func:`untrusted_metadata`) that ``hdrcl calibrate`` prints and a batch turns into a
finding, and the name lists its messages use."""
from __future__ import annotations

import os
from typing import Optional, Sequence

import numpy as np

from hdrcl.core.exposure.fit import ExposureFit
from hdrcl.core.response import SPAN_BODY, Response


def list_names(names: Sequence[str], limit: int = 8) -> str:
    """``a, b, c`` for messages: at most ``limit`` names, then how many more."""
    names = list(names)
    if len(names) > limit:
        return ", ".join(names[:limit]) + f" and {len(names) - limit} more"
    return ", ".join(names)


def untrusted_metadata(response: Response, fit: Optional[ExposureFit] = None,
                       names: Optional[Sequence[str]] = None) -> Optional[str]:
    """Why a calibrating set's exposure metadata cannot be trusted, naming the frames; None
    when nothing says so.

    Two signs, either enough: the exposure check found no group of three or more frames
    whose metadata agree with the pixels (``fit.trusted`` all False), and an 8-bit curve
    whose body is stretched (:meth:`hdrcl.core.response.Response.span_problem`: wrong
    times widen it). Every frame is named in both: without a known curve the pixels tell
    the exposures only up to ``a + b ln dt``, so which time is wrong cannot be told. The caller warns, or prefers a
    response from a good set of the same camera (``--response``, a batch's pooled one).

    Parameters
    ----------
    response : hdrcl.core.response.Response
        The curve calibrated from the set.
    fit : hdrcl.core.exposure.fit.ExposureFit, optional
        The calibration's exposure check (None when it was off or had two frames).
    names : sequence of str, optional
        The files; default the ``file`` of ``response.exposures``, else ``image k``.

    Returns
    -------
    str or None
    """
    p = len(fit.nominal) if fit is not None else len(response.exposures or [])
    if names is None:
        ex = response.exposures or []
        names = [e.get("file", f"image {k}") for k, e in enumerate(ex)] if len(ex) == p else None
    names = [f"image {k}" for k in range(p)] if names is None else [os.path.basename(os.fspath(n)) for n in names]
    reasons = []
    if fit is not None and fit.trusted is not None and p >= 3 and not np.any(fit.trusted):
        # Which frame is wrong cannot be told: the pixels fix the exposures only up to
        # a + b ln dt, so every frame is named.
        reasons.append(f"no three of its {p} frames ({list_names(names)}) agree with each other's metadata")
    problem = response.span_problem()
    if problem is not None:
        body = response.span_decades(*SPAN_BODY)
        who = f" of {list_names(names)}" if names else ""
        reasons.append(f"the exposure times{who} stretch the response to {response.span_decades():.1f} decades "
                       f"between codes 10 and 245 ({body:.1f} in its body, codes {SPAN_BODY[0]}..{SPAN_BODY[1]}; "
                       "camera JPEGs about 2.5 and 1.9)")
    if not reasons:
        return None
    from hdrcl.core.exposure.fit import PREFER_GOOD, UNTRUSTED

    return UNTRUSTED + ": " + "; ".join(reasons) + PREFER_GOOD
