"""Host side of ``kernels/fusion.cl``: a bracket in, a float32 radiance map out."""
from __future__ import annotations

import ctypes
import math
from typing import Optional, Sequence

import numpy as np
import pyopencl as cl
import pyopencl.cltypes as cltypes

from hdrcl.cl.processing import OpenCLProcessor, round_up

_PIXEL_T = {np.dtype(np.uint8): "uchar", np.dtype(np.uint16): "ushort"}
_LOG2E = 1.0 / math.log(2.0)
#: PAT_B of kernels/fusion.cl: a black sample's scale in the pattern term beyond 12
#: frames (up to 12 it is 2^P, PAT_SCALE).
_PAT_B = 4096.0


def clip_codes(levels: int) -> tuple:
    """``(low, high)``: the noise-floor and clip codes, :func:`hdrcl.core.weights.clip_levels`
    written again (this layer does not import ``core``; a test holds the two equal)."""
    high = int(round(250 * (levels - 1) / 255.0))
    return levels - 1 - high, high


#: Intel's CPU runtime works in host memory only from 128-byte aligned addresses (else it
#: copies, at about 3 GB/s); a frame strip is passed from the aligned address at or below
#: its start, with its offset (:func:`_aligned_view`).
_HOST_ALIGN = 128


def _aligned_view(a: np.ndarray):
    """``(view, offset)``: a ctypes byte array over ``a``'s memory (C-contiguous) that
    starts at the :data:`_HOST_ALIGN`-byte boundary at or below ``a``'s first byte, and
    the bytes from there to that first byte. The bytes before it are in the same memory
    page (4096 is a multiple of the alignment), so they can be read; the kernels read
    only from the offset on."""
    addr = a.ctypes.data
    start = addr - addr % _HOST_ALIGN
    return (ctypes.c_ubyte * (a.nbytes + addr - start)).from_address(start), addr - start


class FusionPlan:
    """Tables and device buffers for fusing many strips of one bracket."""

    def __init__(self, proc: "FusionProcessor", nframes: int, width: int, nch: int, dtype,
                 log_times, tables: np.ndarray, weights: np.ndarray, has_valid: bool):
        self.proc = proc
        self.p, self.w, self.c = nframes, width, nch
        self.dtype = np.dtype(dtype)
        if self.dtype not in _PIXEL_T:
            raise TypeError(f"frames must be uint8 or uint16, not {self.dtype}")
        if nch not in (1, 3):
            raise ValueError(f"fusion handles 1 or 3 channels, not {nch}")
        self.levels = tables.shape[1]
        self.has_valid = has_valid
        zlo, zhi = clip_codes(self.levels)
        opts = (f"-DPIXEL_T={_PIXEL_T[self.dtype]}", f"-DNCH={nch}", f"-DLEVELS={self.levels}", f"-DNFRAMES={nframes}",
                f"-DZLO={zlo}", f"-DZHI={zhi}") + (("-DHAS_VALID",) if has_valid else ())
        self.knl = proc.ctx.kernel("fusion", "fuse", opts)
        self.tail = proc.ctx.kernel("fusion", "fuse_tail", opts)
        self.fix = proc.ctx.kernel("fusion", "fuse_fix", opts)
        log_t = np.asarray(log_times, np.float64)
        tables = np.asarray(tables, np.float64)
        code = np.arange(self.levels)
        wt = np.where((code > zlo) & (code < zhi), np.asarray(weights, np.float64), 0.0)
        # Table per channel (kernels/fusion.cl, "lut"): weight times g in log2 units, the
        # weight twice (times 1 and times -ln dt_p / ln 2 per frame in the kernel), and
        # the clipped / black pattern term (times 2^p, or A + p beyond 12 frames); the
        # weight is 0 outside (zlo, zhi). One 16-byte gather per sample.
        lut = np.empty((nch, self.levels, 4), np.float32)
        lut[..., 0] = wt[None, :] * tables * _LOG2E
        lut[..., 1] = wt[None, :]
        lut[..., 2] = wt[None, :]
        lut[..., 3] = (code >= zhi) + (2.0 ** nframes if nframes <= 12 else _PAT_B) * (code <= zlo)
        self.lut = proc.constant("lut", lut)
        self.lt2 = proc.constant("lt2", (log_t * _LOG2E).astype(np.float32))
        # Bound tables (hdrcl.core.reference.bound_tables): running max of g from code 0,
        # running min from the top code.
        ghi = np.maximum.accumulate(tables, axis=1)
        glo = np.minimum.accumulate(tables[:, ::-1], axis=1)[:, ::-1]
        self.ghi = proc.constant("ghi", (ghi * _LOG2E).astype(np.float32))
        self.glo = proc.constant("glo", (glo * _LOG2E).astype(np.float32))
        self.counts = np.zeros(4, np.uint32)
        self.counts_b = proc.constant("counts", self.counts)
        self.rows = proc.strip_rows(width)
        self.spix = self.rows * width
        self.plane = self.spix * nch
        self.frames_b = proc.buffer("frames", 4 if nframes <= 16 else nframes * self.plane * self.dtype.itemsize,
                                    cl.mem_flags.READ_ONLY)
        self.valid_b = proc.buffer("valid", nframes * self.spix if has_valid else 4, cl.mem_flags.READ_ONLY)
        self.out_b = proc.buffer("out", self.plane * 4, cl.mem_flags.READ_WRITE)
        self.mask_b = proc.buffer("clipmask", self.spix, cl.mem_flags.READ_WRITE)
        # fuse and fuse_tail list the pixels fuse_fix must walk (counts[3] of them)
        self.todo_b = proc.buffer("todo", self.spix * 4, cl.mem_flags.READ_WRITE)
        self.frame_args = nframes <= 16
        self.zero_copy = proc.ctx.shares_host_memory
        self._dummy = proc.buffer("nothing", 128, cl.mem_flags.READ_ONLY)
        self._ones = np.ones(self.spix, np.uint8) if has_valid else None
        self._zero = np.zeros(1, np.uint32)

    def fuse_strip(self, frames: Sequence[np.ndarray], valid: Optional[Sequence[Optional[np.ndarray]]],
                   out: np.ndarray, clip_mask: Optional[np.ndarray] = None) -> None:
        """Fuse one strip: ``frames`` are ``(rows, W, C)`` slices, ``out`` the matching
        float32 ``(rows, W, C)`` destination (contiguous). ``clip_mask``, a contiguous
        uint8 ``(rows, W)`` array, receives the pixels' clip flags (1 some channel clipped
        high, 2 clipped low; see :func:`hdrcl.core.reference.fuse`).

        On a device that shares host memory the kernels read ``frames`` and write ``out``
        and ``clip_mask`` where they are (buffers over the host arrays, no copies)."""
        q = self.proc.queue
        npix = frames[0].shape[0] * self.w
        if npix > self.spix:
            raise ValueError("strip larger than the plan's strip size")
        held = []  # host views and buffers that must live until the queue is done with them
        fargs = self._frame_args(frames, held)
        if self.has_valid:
            for j in range(self.p):
                v = self._ones[:npix] if valid[j] is None else np.ascontiguousarray(valid[j], dtype=np.uint8)
                cl.enqueue_copy(q, self.valid_b, v, dst_offset=j * self.spix, is_blocking=False)
        out_b = self._host_buffer(out, np.float32, npix * self.c, self.out_b, held)
        mask_b = self.mask_b
        if clip_mask is not None:
            clip_mask[...] = 0  # fuse_fix writes the flagged pixels only
            mask_b = self._host_buffer(clip_mask, np.uint8, npix, self.mask_b, held)
        args = (np.int32(npix), np.int32(self.p), np.int32(self.levels), np.int32(self.spix))
        tabs = (self.valid_b, self.lut, self.lt2)
        if npix >= 4:
            self.knl(q, (round_up(npix // 4),), None, *fargs, *tabs, out_b, self.counts_b, self.todo_b, *args)
        if npix % 4:
            self.tail(q, (round_up(npix % 4),), None, *fargs, *tabs, out_b, self.counts_b, self.todo_b, *args,
                      np.int32(npix - npix % 4))
        cl.enqueue_copy(q, self.counts, self.counts_b, is_blocking=True)
        nfix = int(self.counts[3])
        if nfix:  # the fast path listed pixels with values that need the bound rules
            if clip_mask is not None and mask_b is self.mask_b:  # fuse_fix writes the listed pixels only
                cl.enqueue_fill_buffer(q, self.mask_b, np.uint8(0), 0, npix)
            self.fix(q, (round_up(nfix),), None, *fargs, *tabs, self.ghi, self.glo, out_b, self.counts_b,
                     self.todo_b, mask_b, np.int32(nfix), *args[1:])
            cl.enqueue_copy(q, self.counts_b, self._zero, dst_offset=12, is_blocking=False)
            if clip_mask is not None and mask_b is self.mask_b:
                cl.enqueue_copy(q, clip_mask, self.mask_b, is_blocking=False)
        self._finish(out, out_b, held)

    def _frame_args(self, frames, held: list) -> tuple:
        """Kernel arguments for the strip's frames: up to 16 frames, one buffer per frame
        (over the host array where the device shares host memory, from an aligned address
        at or before the strip: :func:`_aligned_view`) and the element offsets; beyond,
        one packed copy."""
        q = self.proc.queue
        size = self.dtype.itemsize
        if not self.frame_args:
            for j, f in enumerate(frames):
                cl.enqueue_copy(q, self.frames_b, np.ascontiguousarray(f), dst_offset=j * self.plane * size,
                                is_blocking=False)
            return (self.frames_b, np.int32(self.plane))
        mf = cl.mem_flags
        bufs, offs = [], np.zeros(16, np.int32)
        for j, f in enumerate(frames):
            f = np.ascontiguousarray(f)
            if self.zero_copy:
                view, off = _aligned_view(f)
                held.append((f, view))
                bufs.append(cl.Buffer(self.proc.ctx.context, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=view))
                offs[j] = off // size
            else:
                bufs.append(cl.Buffer(self.proc.ctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=f))
        bufs += [self._dummy] * (16 - len(bufs))
        return (*bufs, offs.view(cltypes.int16)[0])

    def _host_buffer(self, a: np.ndarray, dtype, n: int, fallback, held: list):
        """A read-write buffer over host array ``a`` (contiguous, of ``dtype``, ``n``
        elements), or ``fallback`` (the plan's own; the caller copies back) when ``a`` is
        not such an array or the device does not share host memory."""
        if (not self.zero_copy or a.dtype != dtype or not a.flags.c_contiguous or not a.flags.writeable
                or a.size != n):
            return fallback
        buf = cl.Buffer(self.proc.ctx.context, cl.mem_flags.READ_WRITE | cl.mem_flags.USE_HOST_PTR, hostbuf=a)
        held.append((a, buf))
        return buf

    def _finish(self, out: np.ndarray, out_b, held: list) -> None:
        """Wait for the strip: results in host memory (a map of each host buffer, or the
        copy back from the plan's own), then drop the buffers over host arrays."""
        q = self.proc.queue
        if out_b is self.out_b:
            cl.enqueue_copy(q, out, self.out_b, is_blocking=True)
        for a, buf in held:
            if isinstance(buf, cl.Buffer):  # a map makes the kernels' writes visible in host memory
                m, _ = cl.enqueue_map_buffer(q, buf, cl.map_flags.READ, 0, a.shape, a.dtype, is_blocking=False)
                m.base.release(q)
        q.finish()
        held.clear()

    def result_counts(self) -> dict:
        cl.enqueue_copy(self.proc.queue, self.counts, self.counts_b, is_blocking=True)
        return {"clipped_high": int(self.counts[0]), "clipped_low": int(self.counts[1]),
                "no_data": int(self.counts[2])}


class FusionProcessor(OpenCLProcessor):
    """Weighted log-domain fusion, streamed through the device in horizontal strips.

    The numeric contract is :func:`hdrcl.core.reference.fuse` (its docstring has the
    equations and the zero-weight rule).
    """

    source = "fusion"

    def ghost_departures(self, frames, valid, fused, tables: dict) -> np.ndarray:
        """See :func:`ghost_departures`."""
        return ghost_departures(self, frames, valid, fused, tables)

    def plan(self, nframes, width, nch, dtype, log_times, tables, weights, has_valid) -> FusionPlan:
        return FusionPlan(self, nframes, width, nch, dtype, log_times, tables, weights, has_valid)

    def fuse(
        self,
        frames: Sequence[np.ndarray],
        log_times: Sequence[float],
        tables: np.ndarray,
        weights: np.ndarray,
        valid: Optional[Sequence[Optional[np.ndarray]]] = None,
        out: Optional[np.ndarray] = None,
        clip_mask: Optional[np.ndarray] = None,
    ):
        """Fuse whole in-memory ``frames`` (ordered by increasing exposure).

        Parameters are those of :func:`hdrcl.core.reference.fuse` (``clip_mask``: an
        ``(H, W)`` uint8 array to fill); ``out`` may be a preallocated ``(H, W, C)``
        float32 array.

        Returns
        -------
        radiance : ndarray (H, W, C) float32
        counts : dict
        """
        h, w, c = frames[0].shape
        has_valid = valid is not None and any(v is not None for v in valid)
        plan = self.plan(len(frames), w, c, frames[0].dtype, log_times, tables, weights, has_valid)
        if out is None:
            out = np.empty((h, w, c), np.float32)
        for r0 in range(0, h, plan.rows):
            r1 = min(h, r0 + plan.rows)
            plan.fuse_strip([f[r0:r1] for f in frames],
                            [None if v is None else v[r0:r1] for v in valid] if has_valid else None,
                            out[r0:r1], None if clip_mask is None else clip_mask[r0:r1])
        return out, plan.result_counts()


def ghost_departures(proc: "FusionProcessor", frames, valid, fused: np.ndarray, tables: dict) -> np.ndarray:
    """Raw ghost mask ``(H, W)`` bool of frames ``(H, W, C)`` (exposure order), ``valid``
    (list of ``(H, W)`` bool or None, or None) and the fused ``(H, W, C)`` radiance, by
    ``ghost_raw`` of ``kernels/fusion.cl``; ``tables`` as
    :func:`hdrcl.core.deghost.ghost_tables` gives them (its twin is
    :func:`hdrcl.core.deghost.departures`)."""
    ctx, q = proc.ctx, proc.queue
    h, w, c = fused.shape
    dtype = np.dtype(frames[0].dtype)
    if dtype not in _PIXEL_T:
        raise TypeError(f"frames must be uint8 or uint16, not {dtype}")
    levels = tables["tab"].shape[1]
    nbins = tables["bias"].shape[2]
    opts = (f"-DPIXEL_T={_PIXEL_T[dtype]}", f"-DNCH={c}", f"-DLEVELS={levels}", f"-DBINS={nbins}",
            f"-DFLOOR={float(tables['floor']):.9g}f")
    knl = ctx.kernel("fusion", "ghost_raw", opts)
    mf = cl.mem_flags
    ro = mf.READ_ONLY | mf.COPY_HOST_PTR

    def buf(a):
        return cl.Buffer(ctx.context, ro, hostbuf=np.ascontiguousarray(a))

    packed = np.stack([np.ascontiguousarray(f) for f in frames])
    has_valid = valid is not None and any(v is not None for v in valid)
    vb = buf(np.stack([np.ones((h, w), np.uint8) if v is None else v.astype(np.uint8) for v in valid])
             if has_valid else np.zeros(4, np.uint8))
    raw = np.empty((h, w), np.uint8)
    rb = cl.Buffer(ctx.context, mf.WRITE_ONLY, raw.nbytes)
    knl(q, (round_up(w, 16), round_up(h, 4)), (16, 4), buf(packed), np.int32(h * w * c), vb, np.int32(has_valid),
        buf(np.asarray(fused, np.float32)), buf(tables["tab"]), buf(tables["lt"]), buf(tables["edges"]),
        buf(tables["bias"]), buf(tables["tol"]), buf(tables["screen"]), rb, np.int32(h), np.int32(w), np.int32(len(frames)),
        np.int32(tables["zlo"]), np.int32(tables["zhi"]))
    cl.enqueue_copy(q, raw, rb, is_blocking=True)
    return raw.view(bool)


def profile_kernel(proc: FusionProcessor, frames, log_times, tables, weights, repeats: int = 3) -> float:
    """Seconds the ``fuse`` kernel alone takes over whole in-memory ``frames`` (best of
    ``repeats``), measured by OpenCL profiling events with the frames given in place as
    the strips are: the figure behind "kernel bandwidth" in ``scripts/bench.py``
    (``npix % 4`` pixels at the end, fuse_tail's, are left out)."""
    ctx = proc.ctx
    h, w, c = frames[0].shape
    dtype = frames[0].dtype
    plan = FusionPlan(proc, len(frames), w, c, dtype, log_times, tables, weights, False)
    q = cl.CommandQueue(ctx.context, properties=cl.command_queue_properties.PROFILING_ENABLE)
    npix = h * w
    mf = cl.mem_flags
    held: list = []
    if plan.frame_args:
        fargs = plan._frame_args([np.ascontiguousarray(f) for f in frames], held)
    else:
        packed = np.stack([np.ascontiguousarray(f).reshape(-1) for f in frames])
        fargs = (cl.Buffer(ctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=packed), np.int32(npix * c))
    ob = cl.Buffer(ctx.context, mf.READ_WRITE, npix * c * 4)
    todo = cl.Buffer(ctx.context, mf.READ_WRITE, npix * 4)  # one int per pixel put on the fix list
    best = float("inf")
    for _ in range(max(1, repeats)):
        cl.enqueue_copy(q, plan.counts_b, plan._zero, dst_offset=12, is_blocking=True)  # the list starts empty
        ev = plan.knl(q, (round_up(npix // 4),), None, *fargs, plan.valid_b, plan.lut, plan.lt2, ob, plan.counts_b,
                      todo, np.int32(npix), np.int32(len(frames)), np.int32(plan.levels), np.int32(npix))
        ev.wait()
        best = min(best, (ev.profile.end - ev.profile.start) * 1e-9)
    held.clear()
    return best
