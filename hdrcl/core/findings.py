"""Findings: what a check learnt about a merge's result, carried to the result itself.

A merge runs checks (the exposure metadata against the pixels, the response's shape, the
alignment of each frame, the frames' agreement after fusion, the frames' orientation...).
Each check that finds something makes a :class:`Finding`: which check, the file or cause it
is about, the figure that tripped it and one line a user can act on. The merge engine
collects them on the :class:`hdrcl.core.result.MergeResult`; ``hdrcl merge`` prints their
lines as warnings, and a batch writes them into the set's ``report.json`` entry and its
summary, so that a warning cannot get lost on the way.

A finding's ``severity`` says what it means for the result:

``note``
    Something was found and corrected (an exposure measured instead of the label, a frame
    left out); the result stands.
``check``
    The result cannot be vouched for: a batch marks the set ``check`` instead of ``done``
    (its output is still written), and names the finding in its summary.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Iterable, List, Optional

#: Severities, mildest first.
NOTE, CHECK = "note", "check"
SEVERITIES = (NOTE, CHECK)


@dataclass(frozen=True)
class Finding:
    """One thing a check found.

    Attributes
    ----------
    check : str
        The check that found it: ``exposure``, ``response``, ``alignment``, ``agreement``,
        ``orientation``, ``frames``, ``ghosts``, ...
    message : str
        One line naming the file or the cause, the figure and what to try.
    severity : {"note", "check"}
        ``check``: the result cannot be vouched for.
    file : str, optional
        The frame (or list) it is about, as the user named it.
    figure : float, optional
        The figure that tripped the check (stops, pixels, per cent...; ``message`` says which).
    """

    check: str
    message: str
    severity: str = CHECK
    file: Optional[str] = None
    figure: Optional[float] = None

    def __post_init__(self):
        if self.severity not in SEVERITIES:
            raise ValueError(f"finding severity {self.severity!r} is not one of {SEVERITIES}")

    def to_dict(self) -> dict:
        d = asdict(self)
        if d["figure"] is not None:
            d["figure"] = round(float(d["figure"]), 4)
        return {k: v for k, v in d.items() if v is not None}

    @classmethod
    def from_dict(cls, d: dict) -> "Finding":
        return cls(check=str(d.get("check", "")), message=str(d.get("message", "")),
                   severity=d.get("severity", CHECK) if d.get("severity") in SEVERITIES else CHECK,
                   file=d.get("file"), figure=d.get("figure"))


def needs_check(findings: Iterable[Finding]) -> bool:
    """Whether any finding says the result cannot be vouched for."""
    return any(f.severity == CHECK for f in findings)


def causes(findings: Iterable[Finding]) -> List[str]:
    """The messages of the findings that need a check, in order, each once."""
    seen: List[str] = []
    for f in findings:
        if f.severity == CHECK and f.message not in seen:
            seen.append(f.message)
    return seen
