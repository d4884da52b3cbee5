"""One options object for a merge: every option of ``hdrcl merge`` / :func:`hdrcl.merge_files`
that shapes the radiance, checked once, when the object is made, by the option table
(:mod:`hdrcl.core.params`).

``merge`` (CLI), ``batch`` (``BatchOptions`` wraps one), :func:`hdrcl.merge` and
:func:`hdrcl.merge_files` all build a :class:`MergeOptions` and hand it to the merge engine
(:mod:`hdrcl.core.engine`). The rules that tie options together live here and nowhere
else: ``crop`` needs ``align`` (refused), ``ghost_threshold``/``ghost_reference`` need
``deghost`` (refused), ``absolute`` and ``reference_patch`` exclude each other
(refused); an option that is ignored (``align_model`` without ``align``) is named in
:meth:`MergeOptions.ignored`, which the callers log once as a warning.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, fields
from typing import Any, List, Optional, Tuple

from hdrcl.core.weights import DEFAULT_WEIGHT


@dataclass(frozen=True)
class MergeOptions:
    """How a bracket is merged and written (the option table's names and defaults).

    Every field is checked and normalised by :func:`hdrcl.core.params.check_options` when
    the object is made (``UsageError`` naming the option); ``ignore_color`` becomes an
    ``(R, G, B)`` tuple, ``colorspace`` and ``align_model`` lower case, a
    ``reference_exposure`` given as ``"1/125"`` seconds.
    """

    weight: str = DEFAULT_WEIGHT
    ignore_color: Optional[Tuple[int, int, int]] = None
    samples: Optional[int] = None
    smoothness: Optional[float] = None
    seed: int = 0
    fit_exposures: str = "auto"
    exposure_tolerance: Optional[float] = None
    deghost: bool = False
    ghost_threshold: Optional[float] = None
    ghost_reference: Any = None
    neutral: Any = None
    reference_patch: Any = None
    absolute: bool = False
    align: bool = False
    align_model: str = "auto"
    crop: bool = False
    dtype: str = "auto"
    compression: str = "piz"
    colorspace: str = "rec709"
    reference_exposure: Optional[float] = None
    device: Optional[str] = None

    def __post_init__(self):
        from hdrcl.core.params import check_options

        values = {f.name: getattr(self, f.name) for f in fields(self)}
        o = check_options(**{k: v for k, v in values.items() if k != "device" or v is not None})
        for key in ("samples", "smoothness", "seed", "exposure_tolerance", "ghost_threshold", "ghost_reference",
                    "reference_exposure", "colorspace", "align_model", "ignore_color", "absolute", "align", "crop",
                    "deghost"):
            if key in o:
                object.__setattr__(self, key, o[key])
        if isinstance(self.neutral, (tuple, list)):
            object.__setattr__(self, "neutral", ",".join(str(int(v)) for v in self.neutral))
        if self.seed is None:
            object.__setattr__(self, "seed", 0)

    @classmethod
    def split(cls, values: dict) -> Tuple["MergeOptions", dict]:
        """``(MergeOptions, rest)`` from keyword arguments: the option fields taken (and
        checked), the other keywords returned as they are."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in values.items() if k in names}), {k: v for k, v in values.items()
                                                                          if k not in names}

    def replace(self, **changes) -> "MergeOptions":
        """A copy with ``changes`` (checked again)."""
        return dataclasses.replace(self, **changes)

    def ignored(self, output=None, chain: bool = False) -> List[str]:
        """One line per option given that this merge ignores, each logged once as a
        warning: ``align_model`` without ``align``; ``reference_exposure`` when the file
        holds absolute units (``absolute``, ``reference_patch``, a luminance ``chain``) or
        is of a type that holds radiance relative to 1 s (``output``'s extension: PFM)."""
        out = []
        if not self.align and self.align_model != "auto":
            out.append(f"--align-model {self.align_model} is ignored without --align")
        if self.reference_exposure is not None:
            why = None
            if self.absolute or self.reference_patch is not None or chain:
                why = "the file holds absolute units (cd/m^2)"
            elif output is not None:
                import os

                from hdrcl.core.encode import SCALED_EXTENSIONS

                ext = os.path.splitext(os.fspath(output))[1].lower()
                if ext not in SCALED_EXTENSIONS:
                    why = f"a {ext} file holds radiance relative to 1 s"
            if why:
                out.append(f"--reference-exposure is ignored: {why}")
        return out

    def asdict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


#: Pictures for HDR screens a merge can deliver beside its radiance map
#: (:mod:`hdrcl.report.deliver` holds what each is and its writer; docs/deliver.md).
DELIVERABLE_NAMES = ("uhdr", "avif", "jxl", "fusion")


@dataclass(frozen=True)
class DeliverOptions:
    """What ``--deliver`` writes beside each radiance map, checked when made.

    ``kinds``: names from :data:`DELIVERABLE_NAMES` (a comma list is accepted);
    ``headroom``: stops above reference white that the HDR renderings keep (clipped
    beyond); ``transfer`` (``pq``/``hlg``) and ``bits`` (10/12) of AVIF and JPEG XL;
    ``tonemap``: operator of the SDR base of the Ultra HDR JPEG (as the previews').
    """

    kinds: Tuple[str, ...] = ()
    headroom: float = 3.0
    transfer: str = "pq"
    bits: int = 10
    tonemap: str = "reinhard"

    def __post_init__(self):
        from hdrcl.core.params import check_options
        from hdrcl.errors import UsageError

        kinds = self.kinds
        if isinstance(kinds, str):
            kinds = [k for k in kinds.replace(" ", "").split(",") if k]
        kinds = tuple(dict.fromkeys(str(k).strip().lower() for k in kinds or ()))
        bad = [k for k in kinds if k not in DELIVERABLE_NAMES]
        if bad:
            raise UsageError(f"--deliver: unknown '{bad[0]}'; use a comma list of {', '.join(DELIVERABLE_NAMES)}")
        object.__setattr__(self, "kinds", kinds)
        o = check_options(headroom=self.headroom, hdr_transfer=self.transfer, hdr_bits=str(self.bits),
                          operator=self.tonemap)
        object.__setattr__(self, "headroom", float(o["headroom"]))
        object.__setattr__(self, "transfer", str(o["hdr_transfer"]))
        object.__setattr__(self, "bits", int(o["hdr_bits"]))
        if any(k != "fusion" for k in kinds):  # refused before any merge, not after it (fusion needs no codec)
            from hdrcl.io.hdrdisplay import codecs_available

            why = codecs_available()
            if why:
                raise UsageError(f"--deliver: {why}")

    def identity(self) -> str:
        """What the pictures are made with, as text (recorded beside the map: a rerun remakes
        the deliverables when it differs)."""
        return f"headroom {self.headroom:g}; {self.transfer} {self.bits}-bit; base {self.tonemap}"

    def refuse_with_luminance(self, luminance: bool) -> None:
        """UsageError when deliverables are asked of luminance maps (``--lens-circle``):
        the map is cropped, projected and calibrated after the fusion, so the pictures
        would show another image than the file."""
        if self.kinds and luminance:
            from hdrcl.errors import UsageError

            raise UsageError("--deliver: not with a luminance map (--lens-circle): the map is cropped, projected "
                             "and calibrated after the fusion; deliver pictures from a plain merge of the set")
    def __bool__(self) -> bool:
        return bool(self.kinds)
