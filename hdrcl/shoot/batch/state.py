"""Batch state on disk: set digests (idempotence), up-to-date checks, atomic JSON, the
report lock, report.json entries and stale temporary files.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import re
import secrets
import stat
import time as _time
from typing import Dict, List, Sequence, Tuple


from hdrcl.errors import HdrclError, InputError
from hdrcl.shoot.batch.claims import check_regular
from hdrcl.shoot.batch.jobs import STATUS_SKIPPED, BatchOptions, SetJob, SetResult
from hdrcl.shoot.batch.plan import _Plan
from hdrcl.version import __version__

logger = logging.getLogger(__name__)


#: Version of the recipe of :func:`set_digest`; bump when outputs change meaning.
DIGEST_RECIPE = 2  # 2: files hold radiance x the reference exposure (hdrcl.core.encode)


#: EXR attribute (after the ``hdrcl:`` prefix) holding a set's digest.
DIGEST_KEY = "inputHash"


#: Temporary files of killed runs older than this (seconds) are removed.
STALE_TEMP_SECONDS = 3600.0


# --------------------------------------------------------------------- hashing
#: Bytes read per call while hashing a frame (one buffer, reused).
HASH_BLOCK = 4 << 20


def _content_hasher():
    """``(hasher, name)`` for frame contents: XXH3-128 when the ``xxhash`` package is
    installed (about 6 GB/s a core here, against 0.4-0.5 GB/s for SHA-256, which made
    hashing a shoot cost a tenth of its decoding), else SHA-256. The name is part of
    every file digest, so the two never pass for each other: a shoot hashed one way and
    rerun the other way is merged again once, never skipped on a wrong match. The digest
    guards against changed files, not against an adversary: a 128-bit hash is plenty."""
    try:
        import xxhash
    except ImportError:
        return hashlib.sha256(), "sha256"
    return xxhash.xxh3_128(), "xxh3-128"


def _file_digest(path: str) -> str:
    """``"<hash name>:<hex>"`` over every byte of the file at ``path``."""
    h, name = _content_hasher()
    check_regular(path)
    try:
        # O_NONBLOCK: a file swapped for a FIFO after the check still cannot block.
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            os.close(fd)
            check_regular(path)
            raise InputError(f"{path}: not a regular file")
        buf = bytearray(HASH_BLOCK)
        view = memoryview(buf)
        with os.fdopen(fd, "rb", buffering=0) as fh:
            while True:
                n = fh.readinto(buf)
                if not n:
                    break
                h.update(view[:n])
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, not an image") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    return f"{name}:{h.hexdigest()}"


def _json_digest(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def response_digest(payload: dict) -> str:
    """Digest of what fusion uses from a response: bit depth, channels, the curve."""
    return _json_digest({k: payload[k] for k in ("bits", "channels", "knots", "g")})


def set_digest(job: SetJob, options: BatchOptions, response_hash: str) -> str:
    """The identity of a set's output.

    SHA-256 over the frames' contents (every byte of each file, hashed with
    :func:`_content_hasher`: XXH3-128 where installed), their base names and order, the
    manifest's exposure times, the shoot's reference f-number and ISO, the response
    curve's digest, :meth:`BatchOptions.output_params`, the digest recipe and the hdrcl
    version. Moving the shoot to another folder keeps it; touching a file without
    changing it keeps it; anything that changes the EXR's pixels or format changes it.
    """
    payload = {
        "recipe": DIGEST_RECIPE,
        "hdrcl": __version__,
        "files": [[os.path.basename(f), _file_digest(f)] for f in job.files],
        "exposures": list(job.exposures),
        "reference": list(job.reference),
        "exposure_ref": job.exposure_ref,
        "response": response_hash,
        "output": options.output_params(),
    }
    if job.fnumber is not None:  # only then, so that the digests of EXIF shoots stay as they were
        payload["fnumber"] = job.fnumber
    return _json_digest(payload)


def _atomic_json(path: str, obj) -> None:
    """Write JSON through a temporary file and a rename (readers never see half)."""
    folder = os.path.dirname(os.path.abspath(path))
    tmp = os.path.join(folder, f".{os.path.basename(path)}.{secrets.token_hex(4)}.tmp")
    # os.open with 0o666 honours the umask (mkstemp would make the file private).
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(obj, fh, indent=1)
            fh.write("\n")
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _up_to_date(job: SetJob, digest: str, options: BatchOptions) -> Tuple[bool, bool, dict, dict]:
    """Whether the EXR and the preview carry ``digest`` (header reads only).

    Returns ``(exr_ok, preview_ok, exr_metadata, preview_metadata)``.
    """
    from hdrcl.io.radiance import read_metadata

    try:
        meta = read_metadata(job.output)
    except HdrclError:
        return False, False, {}, {}
    if meta.get(DIGEST_KEY) != digest:
        return False, False, {}, {}
    if job.preview is None:
        return True, True, meta, {}
    try:
        pmeta = read_metadata(job.preview)
    except HdrclError:
        return True, False, meta, {}
    ok = (pmeta.get(DIGEST_KEY) == digest and int(pmeta.get("previewSize", -1)) == int(options.preview_size)
          and pmeta.get("tonemap", "reinhard") == options.tonemap)
    return True, ok, meta, pmeta if ok else {}


def verify_exr(path: str) -> bool:
    """Whether every pixel of ``path`` can be read (strip by strip, bounded memory).

    A header that carries the right digest says nothing about the rest of the file: a
    truncated or damaged EXR fails here and its set is rebuilt.
    """
    from hdrcl.io.probe import pixels_readable

    return pixels_readable(path)


def _preview_metadata(digest: str, options: BatchOptions, counts: dict) -> dict:
    # The counts are known only after the EXR's header is written: the preview keeps
    # them for the report of later runs that skip the set.
    return {DIGEST_KEY: digest, "previewSize": int(options.preview_size), "tonemap": options.tonemap,
            "clippedHigh": int(counts.get("clipped_high", 0)), "clippedLow": int(counts.get("clipped_low", 0)),
            "noData": int(counts.get("no_data", 0))}


def _counts_of(meta: dict) -> Dict[str, int]:
    if "clippedHigh" not in meta:
        return {}
    return {"clipped_high": int(meta.get("clippedHigh", 0)), "clipped_low": int(meta.get("clippedLow", 0)),
            "no_data": int(meta.get("noData", 0))}


# ------------------------------------------------------------------------ report
def _report_lock(out_dir: str):
    """Serialise read-modify-write of the report between chunks sharing a folder: an
    ``flock`` on the folder itself, so no lock file can be a symbolic link."""
    from hdrcl.shoot.batch.claims import folder_lock

    return folder_lock(out_dir)


def _merge_entries(path: str, results: List[SetResult], plan: _Plan) -> List[dict]:
    """This run's entries plus earlier entries of other sets of the same manifest."""
    from hdrcl.io.jsondoc import read_state

    old = read_state(path, "batch report") or {}  # absent or damaged: this run's entries only
    old_sets = old.get("sets") if isinstance(old.get("sets"), list) else []
    _carry_over(results, old_sets)
    mine = {r.index: r.to_dict() for r in results}
    for e in old_sets:
        if not isinstance(e, dict) or not isinstance(e.get("index"), int) or isinstance(e["index"], bool):
            continue
        files = e.get("files")
        if not isinstance(files, list) or not all(isinstance(f, str) for f in files):
            continue
        i = e["index"]
        job = plan.jobs.get(i)
        if i not in mine and job is not None and [os.path.abspath(f) for f in files] == job.files:
            mine[i] = e
    return [mine[i] for i in sorted(mine)]


#: What an up-to-date (skipped) set keeps from the run that merged the same output: what
#: that run learnt of the result, which a skip does not measure again.
CARRIED = ("findings", "vertical_illuminance", "glare")


def _carry_over(results: List[SetResult], old_sets: list) -> None:
    """Skipped sets take :data:`CARRIED` from the earlier entry of the same output (same
    digest), so that a rerun neither forgets a finding nor the luminance figures."""
    by_hash = {e.get("hash"): e for e in old_sets if isinstance(e, dict) and e.get("hash")}
    for r in results:
        e = by_hash.get(r.digest) if r.status == STATUS_SKIPPED and r.digest else None
        if e is None:
            continue
        for key in CARRIED:
            value = e.get(key)
            if value is not None and not getattr(r, key):
                setattr(r, key, list(value) if isinstance(value, list) else value)
        for f in r.findings:
            if isinstance(f, dict) and f.get("message") and f["message"] not in r.warnings:
                r.warnings.append(f["message"])


def _remove_stale_temps(out_dir: str, stems: Sequence[str]) -> None:
    """Delete temporary files that killed runs left behind.

    A set's files (``stems``) are removed when nobody holds its claim (their writer is
    gone, :mod:`hdrcl.shoot.batch.claims`). Other temporary files (JSON, the sets of another
    chunk, the quality report's) only when older than :data:`STALE_TEMP_SECONDS`, as
    another chunk may be writing them right now, and never a file of a set whose claim
    a live process holds (a long merge of another chunk).
    """
    from hdrcl.shoot.batch.claims import SetClaim, remove_orphan_temps

    remove_orphan_temps(out_dir, stems)
    held: Dict[str, bool] = {}

    def is_held(stem: str) -> bool:
        if stem not in held:
            c = SetClaim(out_dir, stem)
            try:
                got = c.acquire(wait=False)
            except OSError:
                got = False
            if got:
                c.release()
            held[stem] = not got
        return held[stem]

    now = _time.time()
    from hdrcl.shoot.batch.claims import temp_infixes

    infix = "|".join(re.escape(x) for x in temp_infixes() if x)
    pat = re.compile(rf"^\.(?P<stem>.+?)(?:{infix})?\.tmp-[0-9a-f]{{8}}\.(exr|hdr|jpg|avif|jxl)$"
                     r"|^\..+\.json\.[^.]+\.tmp$")
    try:
        names = os.listdir(out_dir)
    except OSError:
        return
    for name in names:
        m = pat.match(name)
        if not m:
            continue
        p = os.path.join(out_dir, name)
        with contextlib.suppress(OSError):
            if now - os.path.getmtime(p) <= STALE_TEMP_SECONDS:
                continue
            if m.group("stem") is not None and is_held(m.group("stem")):
                continue
            os.remove(p)
            logger.debug("removed stale temporary file %s", p)
