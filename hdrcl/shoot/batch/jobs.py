"""Batch records: the options every set is merged with, one set's job and result, the
batch report, and the process-wide fusion lock.
"""
from __future__ import annotations

import functools
import threading
from collections import Counter
from dataclasses import dataclass, field, fields
from typing import Dict, List, Optional, Tuple

from hdrcl.core.options import MergeOptions
from hdrcl.core.response import default_smoothness
from hdrcl.version import __version__

#: Name of the report written into the output folder.
REPORT_NAME = "report.json"


#: Ending of the response files written beside the outputs.
RESPONSE_SUFFIX = ".response.json"


#: At most this many sets of one camera/ISO group are pooled for its response. The solve
#: takes the same number of samples however many sets share them, and its curve error on
#: synthetic shoots is the same from 1 to 8 pooled sets (0.027-0.031 ln); three spread
#: over the shoot keep one odd set from deciding the curve while holding the fewest frames
#: (a pooled set's frames, decoded for its grid, wait for its merge within the memory budget
#: or in the scratch file, :mod:`hdrcl.io.ahead`; beyond both they are decoded again).
MAX_POOL_SETS = 3


STATUS_DONE, STATUS_SKIPPED, STATUS_FAILED = "done", "skipped", "failed"
#: Merged, but a check found that the result cannot be vouched for (``findings`` say why).
STATUS_CHECK = "check"


# --------------------------------------------------------------------------- records
@dataclass(frozen=True, init=False)
class BatchOptions:
    """How every set is merged and written: the merge options (``hdrcl merge``'s, one
    :class:`hdrcl.core.options.MergeOptions`, declared there) and the batch's own.

    ``BatchOptions(dtype="float", preview=False)`` takes the merge options as keywords
    too (or ``merge=MergeOptions(...)``), and reads them as its own (``opts.dtype`` is
    ``opts.merge.dtype``).

    Attributes
    ----------
    merge : hdrcl.core.options.MergeOptions
        The options every set is merged with (weighting, the response solve's, deghost,
        alignment, white balance, EXR type, reference exposure, device...). Its
        ``reference_exposure`` is in seconds at the shoot's reference f-number and ISO
        (default: one per camera, the power of two nearest the middle of that camera's
        exposures across the shoot, :mod:`hdrcl.core.encode`); ``fit_exposures`` measures
        through the set's pooled or given response.
    preview : bool
        Also write a tone-mapped JPEG per set.
    preview_size : int
        Long side of the preview in pixels.
    tonemap : str
        Operator of the previews (:data:`hdrcl.report.tonemap.OPERATORS`).
    report_dir : str, optional
        Quality report folder (``--report``): each merged set's figures
        (:func:`hdrcl.report.quality.measure`), response plot, coverage map and preview, written
        by whoever merges the set, and an ``index.html`` contact sheet over the manifest,
        written by :func:`run_batch` at the end (:mod:`hdrcl.report`). Not part of any
        output's identity: the EXRs and previews are the same with or without it.
    output_format : {"exr", "hdr"}
        The outputs' file type (``.hdr``: Radiance RGBE).
    luminance : dict, optional
        The fisheye luminance chain's options (``lens_circle``, ``resize``,
        ``projection``, ``vignetting``, ``nd_filter``, ``calibration_factor``, ``view``;
        :func:`hdrcl.core.luminance.fisheye.chain_or_none`): every set becomes a calibrated
        luminance map.
    deliver, headroom, hdr_transfer, hdr_bits
        Pictures for HDR screens written beside each EXR (``--deliver uhdr,avif,jxl``;
        :class:`hdrcl.core.options.DeliverOptions`, :mod:`hdrcl.report.deliver`). Not part
        of the EXR's identity.
    """

    merge: MergeOptions
    preview: bool = True
    preview_size: int = 512
    tonemap: str = "reinhard"
    report_dir: Optional[str] = None
    output_format: str = "exr"
    luminance: Optional[dict] = None
    deliver: Tuple[str, ...] = ()
    headroom: float = 3.0
    hdr_transfer: str = "pq"
    hdr_bits: int = 10

    def __init__(self, merge: Optional[MergeOptions] = None, **values):
        own = {f.name: f.default for f in fields(BatchOptions) if f.name != "merge"}
        given = {k: v for k, v in values.items() if k not in own}
        if merge is None:
            merge = MergeOptions(**given)  # checked once, here; TypeError naming an unknown keyword
        elif given:
            merge = merge.replace(**given)
        object.__setattr__(self, "merge", merge)
        for name, default in own.items():
            object.__setattr__(self, name, values.get(name, default))
        self.deliver_options.refuse_with_luminance(bool(self.luminance))  # the deliverables checked too

    def __getattr__(self, name):
        """A merge option read as the batch's own (``opts.weight``)."""
        if name in _MERGE_NAMES:
            return getattr(self.merge, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @functools.cached_property
    def deliver_options(self):
        """The :class:`hdrcl.core.options.DeliverOptions` of every set (empty: none); the
        SDR base is tone-mapped as the previews (``tonemap``)."""
        from hdrcl.core.options import DeliverOptions

        return DeliverOptions(self.deliver, self.headroom, self.hdr_transfer, self.hdr_bits, self.tonemap)

    @classmethod
    def wrap(cls, merge: MergeOptions, **batch) -> "BatchOptions":
        """The batch's options around a :class:`hdrcl.core.options.MergeOptions` (``merge``)
        and the batch-only fields (``batch``: preview, preview_size, tonemap, report_dir,
        output_format, luminance, deliver...)."""
        return cls(merge, **batch)

    def luminance_chain(self):
        """A fresh :class:`hdrcl.core.luminance.fisheye.LuminanceChain` for one set (it holds that
        set's map), or None without the luminance options."""
        if not self.luminance:
            return None
        from hdrcl.core.luminance.fisheye import chain_or_none

        return chain_or_none(**self.luminance, device=self.device)

    def output_params(self) -> dict:
        """Parameters that shape an EXR beyond its response (part of its digest): the merge
        options' :meth:`~hdrcl.core.options.MergeOptions.identity`, and the luminance chain's."""
        out = self.merge.identity()
        if self.luminance:  # the calibration files' numbers, not their names
            out["luminance"] = dict(_luminance_identity(tuple(sorted(self.luminance.items()))))
        return out

    def solve_params(self) -> dict:
        """Parameters of the response solve (part of the calibration key)."""
        return {"weight": self.weight, "samples": self.samples,
                "smoothness": float(default_smoothness(self.weight) if self.smoothness is None else self.smoothness),
                "seed": int(self.seed), "ignore_color": list(self.ignore_color) if self.ignore_color else None}


#: The merge options a :class:`BatchOptions` reads as its own.
_MERGE_NAMES = frozenset(f.name for f in fields(MergeOptions))


@functools.lru_cache(maxsize=8)
def _luminance_identity(options: tuple) -> dict:
    """What a luminance chain's options mean (its ``describe()`` and view, the ``.cal``
    files read once per process), for the outputs' digest."""
    from hdrcl.core.luminance.fisheye import chain_or_none

    chain = chain_or_none(**dict(options))
    d = dict(chain.describe(), view=chain.view[0] if chain.view else None)
    for key in ("vignetting", "projection"):  # what a .cal file computes counts, not where it lies
        if isinstance(d.get(key), dict):
            d[key] = {k: v for k, v in d[key].items() if k != "source"}
    return d


@dataclass
class SetJob:
    """Everything a worker needs to merge one set (plain data, picklable).

    ``reference`` is the shoot's ``(f-number, ISO)`` (either may be None); ``group``
    names the set's response; ``output`` and ``preview`` are absolute paths.
    """

    index: int
    files: List[str]
    exposures: List[float]
    output: str
    preview: Optional[str]
    group: str
    reference: Tuple[Optional[float], Optional[float]]
    exposure_ref: Optional[float] = None  # seconds a value of 1.0 stands for (hdrcl.core.encode)
    exposure_ref_own: bool = False  # exposure_ref came from this set's labels alone: the measured exposures decide
    fnumber: Optional[float] = None  # f-number of an exposure list for frames whose header has none
    findings: Tuple[dict, ...] = ()  # what the scan found about the set (hdrcl.shoot.batch.manifest.FINDINGS)
    damaged: Tuple[Tuple[str, str], ...] = ()  # (file name, cause) the scan could not decode (grouping.damaged)


@dataclass
class SetResult:
    """What happened to one set.

    ``status`` is ``"done"`` (merged now), ``"skipped"`` (an up-to-date output exists)
    or ``"failed"`` (``error`` says why). ``seconds`` holds the time of each stage,
    ``counts`` the pixel-channels clipped high/low in every frame and without data,
    ``quality`` the set's quality figures (:meth:`hdrcl.report.quality.QualityFigures.to_dict`)
    when a quality report is written, ``storage`` the EXR storage decision when half
    floats could not hold the set as asked (information, not a warning).
    """

    index: int
    files: List[str]
    status: str
    output: Optional[str] = None
    preview: Optional[str] = None
    error: Optional[str] = None
    warnings: List[str] = field(default_factory=list)
    seconds: Dict[str, float] = field(default_factory=dict)
    counts: Dict[str, int] = field(default_factory=dict)
    ev_offset: Optional[float] = None
    digest: Optional[str] = None
    response: Optional[str] = None
    quality: Optional[dict] = None
    storage: Optional[str] = None  # how the EXR was stored when half could not hold it (a decision)
    alignment: Optional[list] = None  # with --align: per frame model, matrix, shift, residual (hdrcl.core.align.handheld)
    vertical_illuminance: Optional[float] = None  # lux at the lens, with a fisheye luminance map (-vta view)
    glare: Optional[dict] = None  # DGP, DGI, UGR, sources of that map (hdrcl.core.luminance.glare, as `hdrcl glare`)
    findings: List[dict] = field(default_factory=list)  # hdrcl.core.findings.Finding.to_dict of each
    deliverables: List[dict] = field(default_factory=list)  # --deliver: kind, path, bytes, ... (hdrcl.report.deliver)

    @property
    def needs_check(self) -> bool:
        """Whether a finding says the result cannot be vouched for."""
        return any(f.get("severity") == "check" for f in self.findings)

    def causes(self) -> List[str]:
        """The messages of the findings that need a check."""
        return [f["message"] for f in self.findings if f.get("severity") == "check"]

    def to_dict(self) -> dict:
        from hdrcl.report.sheet import status_label

        return {
            "index": self.index,
            "files": list(self.files),
            "status": self.status,
            "label": status_label(self.status),  # the words a page shows: "up to date" for skipped
            "output": self.output,
            "preview": self.preview,
            "error": self.error,
            "warnings": list(self.warnings),
            "seconds": {k: round(float(v), 4) for k, v in self.seconds.items()},
            "counts": dict(self.counts),
            "ev_offset": self.ev_offset,
            "hash": self.digest,
            "response": self.response,
            "quality": self.quality,
            "storage": self.storage,
            **({"alignment": self.alignment} if self.alignment is not None else {}),
            **({"vertical_illuminance": self.vertical_illuminance} if self.vertical_illuminance is not None else {}),
            **({"glare": self.glare} if self.glare is not None else {}),
            **({"deliverables": list(self.deliverables)} if self.deliverables else {}),
            "findings": [dict(f) for f in self.findings],
        }


@dataclass
class ResponseEntry:
    """The response of one camera/ISO group and where it came from."""

    group: str
    payload: Optional[dict] = None  # Response.to_dict() as written (None: unavailable)
    digest: Optional[str] = None
    file: Optional[str] = None
    source: str = ""  # "given", "cached" (--response-cache), "loaded", "calibrated"
    sets: List[int] = field(default_factory=list)
    error: Optional[str] = None
    warnings: List[str] = field(default_factory=list)
    # A group of one set is calibrated by that set's merge from the decode that feeds
    # its fusion (each frame decoded once); ``key`` is its calibration key.
    deferred: bool = False
    key: Optional[str] = None
    # Sets whose exposure metadata cannot be trusted, by index: [verdict, span of their own
    # curve in decades] (hdrcl.shoot.batch.pooling.trust_findings); never pooled when a good set is.
    untrusted: Dict[int, list] = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = {"group": self.group, "file": self.file, "source": self.source, "pooled_sets": self.sets,
             "hash": self.digest, "error": self.error, "warnings": self.warnings}
        if self.untrusted:
            d["untrusted_sets"] = sorted(self.untrusted)
        return d


@dataclass
class _Context:
    """Shared, picklable state of one run: options, responses, flags."""

    options: BatchOptions
    responses: Dict[str, ResponseEntry]
    force: bool = False


@dataclass
class BatchReport:
    """The outcome of :func:`run_batch`.

    Attributes
    ----------
    results : list of SetResult
        The sets this run handled, by index.
    entries : list of dict
        Every set in the written report (this run's, plus those earlier runs into the
        same folder recorded for sets of the same manifest).
    unmerged : list of dict
        Groups the manifest leaves out, with their reasons.
    responses : list of ResponseEntry
    path : str, optional
        Where the report was written.
    quality_report : str, optional
        The contact sheet (``index.html``) of the quality report, when one was asked for.
    unreadable : list of str
        Files the scan could not read; counted as failures when the whole manifest was
        selected.
    cancelled : int, optional
        The signal (SIGTERM, SIGINT) that stopped the run; the report holds the sets
        that finished before it.
    """

    results: List[SetResult] = field(default_factory=list)
    entries: List[dict] = field(default_factory=list)
    unmerged: List[dict] = field(default_factory=list)
    responses: List[ResponseEntry] = field(default_factory=list)
    path: Optional[str] = None
    quality_report: Optional[str] = None
    unreadable: List[str] = field(default_factory=list)
    reference: Tuple[Optional[float], Optional[float]] = (None, None)
    seconds: float = 0.0
    cancelled: Optional[int] = None
    sets_in_manifest: int = 0

    def count(self, status: str) -> int:
        return sum(1 for r in self.results if r.status == status)

    @property
    def to_check(self) -> int:
        """This run's sets whose findings need a check: merged now (status ``check``) or
        up to date from a run that found the same."""
        return sum(1 for r in self.results if r.needs_check)

    @property
    def failed(self) -> int:
        return self.count(STATUS_FAILED)

    @property
    def exit_code(self) -> int:
        """0 when every set is done, to check or skipped; 1 when a set (or an input file) failed,
        or when nothing could be merged (the folder holds no bracket set); 128 + the
        signal when cancelled (143 SIGTERM, 130 SIGINT)."""
        if self.cancelled:
            return 128 + int(self.cancelled)
        if self.failed or self.unreadable:
            return 1
        return 1 if self.sets_in_manifest == 0 else 0

    def to_dict(self, run_only: bool = False) -> dict:
        """The report: every set of the output folder's report (this run's and earlier
        runs' or other chunks' entries), or with ``run_only`` this run's sets alone
        (``hdrcl batch --json``: a farm chunk reports its own sets)."""
        entries = [r.to_dict() for r in self.results] if run_only else self.entries
        counts = Counter(e["status"] for e in entries)
        return {
            "hdrcl": __version__,
            "reference": _reference_text(self.reference),
            "sets": entries,
            "unmerged": self.unmerged,
            "responses": [r.to_dict() for r in self.responses],
            "summary": {"sets": len(entries), "done": counts.get(STATUS_DONE, 0),
                        # merged now with a finding to check (status "check"), or up to date
                        # from a run that found the same (status "skipped")
                        "check": sum(1 for e in entries if any(f.get("severity") == "check"
                                                                for f in e.get("findings") or ())),
                        "skipped": counts.get(STATUS_SKIPPED, 0), "failed": counts.get(STATUS_FAILED, 0),
                        "unreadable_files": len(self.unreadable),
                        **_deliverable_counts(entries),
                        **({"cancelled": signal_name(self.cancelled)} if self.cancelled else {})},
        }


def _deliverable_counts(entries) -> dict:
    """``{"deliverables": {kind: files}}`` over the sets' entries, when any was written."""
    kinds = Counter(d.get("kind") for e in entries for d in e.get("deliverables") or ())
    return {"deliverables": dict(sorted(kinds.items()))} if kinds else {}


def signal_name(signum: int) -> str:
    import signal

    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def _reference_text(ref) -> str:
    n, iso = ref if ref else (None, None)
    return f"f/{n:g} ISO {iso:g}" if n and iso else (
        f"f/{n:g}" if n else (f"ISO {iso:g}" if iso else "exposure time only"))


# One fusion at a time per process: the OpenCL processor's device buffers are shared
# (Dask workers may run several tasks in threads of one process).
_FUSE_LOCK = threading.Lock()
