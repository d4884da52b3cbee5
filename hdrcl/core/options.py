"""One options object for a merge: every option of ``hdrcl merge`` / :func:`hdrcl.merge_files`
that shapes the radiance, checked once, when the object is made, by the option table
(:mod:`hdrcl.core.params`).

Each option is declared once, as a field (:func:`option`: default, help, spelling; its kind
and range are the option table's). ``merge`` and ``batch`` (``BatchOptions`` holds one)
make their click options from the fields, and they, :func:`hdrcl.merge` and
:func:`hdrcl.merge_files` build a :class:`MergeOptions` and put it in the merge's plan
(:mod:`hdrcl.core.plan`, run by :mod:`hdrcl.core.executor`). The rules that tie options together live here and nowhere
else: ``crop`` needs ``align`` (refused), ``ghost_threshold``/``ghost_reference`` need
``deghost`` (refused), ``absolute`` and ``reference_patch`` exclude each other
(refused); an option that is ignored (``align_model`` without ``align``) is named in
:meth:`MergeOptions.ignored`, which the callers log once as a warning.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, fields
from typing import Any, Dict, List, Optional, Tuple

from hdrcl.core.deghost import THRESHOLD
from hdrcl.core.response import DEFAULT_SMOOTHNESS
from hdrcl.core.weights import DEFAULT_WEIGHT

#: What an option is part of in a batch's output identity (``BatchOptions.output_params``):
#: ``always`` recorded, ``changed`` recorded when it is not the default (the digests of
#: plain merges stay as they were), absent: not part of it (the solve's options are in the
#: calibration key instead; the device changes no pixel).
ALWAYS, CHANGED = "always", "changed"


def option(default: Any, help: str, *, metavar: Optional[str] = None, show_default: bool = False,
           case_sensitive: bool = True, solve: bool = False, identity: Optional[str] = None):
    """One option of a merge, declared once: its default, help and command-line spelling
    (``--`` + the field's name with dashes), its kind and range from the option table
    (:data:`hdrcl.core.params.TABLE`, by the field's name: no second copy of a range).

    ``case_sensitive``: of a choice, on the command line;
    ``solve``: an option of the response solve too (``hdrcl calibrate`` takes it);
    ``identity``: :data:`ALWAYS` or :data:`CHANGED` (part of a batch output's digest).
    The click options of ``merge``, ``batch`` and ``calibrate`` are made from these
    (:func:`hdrcl.cli.options.merge_options`); docs/development.md says how to add one.
    """
    return dataclasses.field(default=default, metadata={
        "help": help, "metavar": metavar, "show_default": show_default, "case_sensitive": case_sensitive, "solve": solve, "identity": identity})


@dataclass(frozen=True)
class MergeOptions:
    """How a bracket is merged and written: each option declared once, here (see :func:`option`).

    Every field is checked and normalised by :func:`hdrcl.core.params.check_options` when
    the object is made (``UsageError`` naming the option), once; ``ignore_color`` becomes an
    ``(R, G, B)`` tuple, ``colorspace`` and ``align_model`` lower case, a
    ``reference_exposure`` given as ``"1/125"`` seconds.
    """

    weight: str = option(DEFAULT_WEIGHT, "Weighting of code values: gaussian (measured best on real data), "
                         "or the paper's hat.", show_default=True, solve=True, identity=ALWAYS)
    ignore_color: Optional[Tuple[int, int, int]] = option(
        None, "Treat pixels of exactly this colour (8-bit units) as invalid, e.g. 0,0,255.", metavar="R,G,B",
        solve=True, identity=ALWAYS)
    samples: Optional[int] = option(None, "Calibration pixels [default: enough for the bit depth, at least 1000].",
                                    solve=True)
    smoothness: Optional[float] = option(
        None, "Smoothness lambda of the response solve [default: "
        + ", ".join(f"{v:g} with --weight {k}" for k, v in DEFAULT_SMOOTHNESS.items()) + "; 0.001 to 1e6].",
        solve=True)
    seed: int = option(0, "Seed of the sample choice (0 or more).", show_default=True, solve=True)
    fit_exposures: str = option(
        "auto", "Estimate each frame's exposure from the pixels (through a known curve: --response, or batch's "
        "pooled one): "
        "auto uses the estimate only where the metadata is clearly wrong, on always, off never.", show_default=True, solve=True, identity=CHANGED)
    exposure_tolerance: Optional[float] = option(
        None, "Report frames whose metadata the pixels contradict by more than this [default: 0.5].",
        metavar="STOPS", solve=True, identity=CHANGED)
    deghost: bool = option(False, "Take pixels where the frames disagree (moving objects) beyond the set's own "
                           "learnt residuals from one exposure alone.", identity=CHANGED)
    ghost_threshold: Optional[float] = option(
        None, "With --deghost: departure, in robust spreads of the set's own frame-to-frame "
        f"residuals, that makes a ghost [default: {THRESHOLD:g}].", identity=CHANGED)
    ghost_reference: Any = option(None, "With --deghost: the frame ghost pixels are taken from; N counts the images "
                                  "as given, from 0 [default: middle].", metavar="middle|shortest|longest|N",
                                  identity=CHANGED)
    neutral: Any = option(None, "White balance: make this patch (pixels) neutral grey (batch: in every set).", metavar="X,Y,W,H",
                          identity=CHANGED)
    reference_patch: Any = option(None, "Absolute scale: this patch's mean luminance is VALUE cd/m^2.",
                                  metavar="X,Y,W,H=VALUE", identity=CHANGED)
    absolute: bool = option(False, "Approximate absolute scale (cd/m^2) from f-number and ISO (meter constant "
                            "K = 12.5).", identity=CHANGED)
    align: bool = option(False, "Align hand-held frames to the middle exposure (shift, rotation, scale; see "
                         "--align-model) before merging; a frame that cannot be aligned is left out and named "
                         "(in a batch its set is marked to check).",
                         identity=CHANGED)
    align_model: str = option("auto", "With --align: the motion model; auto picks the simplest one the residuals "
                              "allow (shift, similarity, homography for wide lenses).", show_default=True,
                              identity=CHANGED)
    crop: bool = option(False, "With --align: crop to the area every frame covers.", identity=CHANGED)
    dtype: str = option("auto", "EXR sample type. auto: half when every merged value fits half floats "
                        "(measured on the data), else float. half: half always, rescaled by a power of two "
                        "recorded as hdrcl:halfScale when needed (other tools then read it scaled). "
                        "float: float.", show_default=True, identity=ALWAYS)
    compression: str = option("piz", "EXR compression: none, zip, zips, piz, pxr24, b44, b44a, dwaa, dwab (dwaa:45 "
                              "sets a level).", show_default=True, identity=ALWAYS)
    colorspace: str = option("rec709", "Colour space of the radiance file: linear Rec.709/sRGB primaries, or ACEScg "
                             "(AP1, for VFX pipelines; EXR or HDR), converted with OpenImageIO's colour "
                             "management and tagged.", show_default=True, case_sensitive=False,
                             identity=CHANGED)
    reference_exposure: Optional[float] = option(
        None, "A value of 1.0 in the output is what a frame of this exposure (at the first frame's f-number and "
        "ISO; batch: the shoot's) records as white [default: the power of two nearest the middle exposure; "
        "batch: one per camera for the whole shoot]. Recorded as expTime / EXPOSURE=.", metavar="SECONDS",
        identity=CHANGED)
    device: Optional[str] = option(
        None, "OpenCL device: 'P:D' from 'hdrcl devices', or part of its name [default: PYOPENCL_CTX, else the "
        "first GPU, else the first CPU driver that builds the kernels: Intel's CPU runtime, then PoCL "
        "(HDRCL_CPU_DRIVERS changes the order)].", metavar="ID|NAME")

    def __post_init__(self):
        from hdrcl.core.params import check_options

        values = self.asdict()
        o = check_options(**{k: v for k, v in values.items() if k != "device" or v is not None})
        for key, value in o.items():
            object.__setattr__(self, key, value)  # the normalised form (tuples, lower case, seconds)
        if isinstance(self.neutral, (tuple, list)):
            object.__setattr__(self, "neutral", ",".join(str(int(v)) for v in self.neutral))
        if self.seed is None:
            object.__setattr__(self, "seed", 0)

    @classmethod
    def declared(cls) -> Tuple[dataclasses.Field, ...]:
        """The options as declared (name, default, ``metadata``: see :func:`option`)."""
        return fields(cls)

    @classmethod
    def from_params(cls, params: dict) -> "MergeOptions":
        """The options among ``params`` (e.g. a command's parsed options), checked once;
        the other keys are left to the caller."""
        return cls.split(params)[0]

    @classmethod
    def split(cls, values: dict) -> Tuple["MergeOptions", dict]:
        """``(MergeOptions, rest)`` from keyword arguments: the option fields taken (and
        checked), the other keywords returned as they are."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in values.items() if k in names}), {k: v for k, v in values.items()
                                                                          if k not in names}

    def replace(self, **changes) -> "MergeOptions":
        """A copy with ``changes`` (checked again); ``self`` when nothing changes."""
        return dataclasses.replace(self, **changes) if changes else self

    def check_frames(self, frames: int) -> None:
        """UsageError when ``ghost_reference`` names a frame beyond the ``frames`` given
        (the one check that needs the number of images)."""
        if isinstance(self.ghost_reference, int):
            from hdrcl.core.params import check

            check("ghost_reference", self.ghost_reference, frames=frames)

    def identity(self) -> Dict[str, Any]:
        """The options that shape a batch's output beyond its response, as recorded in its
        digest: each field declared ``identity=ALWAYS``, and each ``CHANGED`` one given
        another value than its default (``align_model`` counts only with ``align``)."""
        out = {}
        for f in fields(self):
            how, value = f.metadata["identity"], getattr(self, f.name)
            if f.name == "align_model" and not self.align:
                value = f.default
            if how == ALWAYS or (how == CHANGED and value != f.default):
                out[f.name] = _plain(f.name, value)
        return out

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


def _plain(name: str, value: Any) -> Any:
    """An option's value as a digest records it (JSON: a list for a tuple, compression
    names as written lower case)."""
    if isinstance(value, tuple):
        return list(value)
    if name == "compression":
        return str(value).strip().lower()
    return value


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
