"""Host side of ``kernels/fusion.cl``: a bracket in, a float32 radiance map out."""
from __future__ import annotations

import ctypes
import math
from collections import deque
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


#: Strips a plan keeps in flight (:class:`StripPipeline`): the kernels of the next strips
#: are queued while the host waits for one strip's results, so the device never idles
#: on the host; each holds its own counters, fix list and buffers (a few MB a strip).
PIPELINE_DEPTH = 3


def _ready(ev) -> bool:
    """Whether OpenCL event ``ev`` has completed (or failed: its ``wait`` raises)."""
    return ev.command_execution_status <= cl.command_execution_status.COMPLETE


class _Slot:
    """The device buffers of one strip in flight: counters, fix list, valid flags, the
    packed frames (beyond 16) and the output and clip mask where the host's own arrays
    cannot be used in place."""

    def __init__(self, plan: "FusionPlan", k: int):
        proc, mf = plan.proc, cl.mem_flags
        tag = "" if k == 0 else f".{k}"
        self.counts = np.zeros(4, np.uint32)
        # the kernels add to it (atomics): read-write, not a constant (READ_ONLY: undefined)
        self.counts_b = proc.buffer("counts" + tag, self.counts.nbytes, mf.READ_WRITE)
        cl.enqueue_copy(proc.queue, self.counts_b, self.counts)  # zeros, before any strip
        self.frames_b = proc.buffer("frames" + tag, 4 if plan.frame_args else plan.p * plan.plane * plan.dtype.itemsize,
                                    mf.READ_ONLY)
        self.valid_b = proc.buffer("valid" + tag, plan.p * plan.spix if plan.has_valid else 4, mf.READ_ONLY)
        # fuse and fuse_tail list the pixels fuse_fix must walk (counts[3] of them)
        self.todo_b = proc.buffer("todo" + tag, plan.spix * 4, mf.READ_WRITE)
        self._proc, self._tag, self._plane, self._spix = proc, tag, plan.plane, plan.spix
        self.busy = False

    # Made when first needed: a device sharing host memory writes into the host's arrays.
    @property
    def out_b(self):
        return self._proc.buffer("out" + self._tag, self._plane * 4, cl.mem_flags.READ_WRITE)

    @property
    def mask_b(self):
        return self._proc.buffer("clipmask" + self._tag, self._spix, cl.mem_flags.READ_WRITE)


class StripTicket:
    """One strip submitted to :meth:`FusionPlan.submit`: its slot, arrays, buffers and
    the event it waits on next (the count of pixels to fix, then the results)."""

    __slots__ = ("slot", "npix", "out", "clip_mask", "fargs", "out_b", "mask_b", "own_out", "own_mask", "held",
                 "events", "event", "stage")

    def __init__(self, slot, npix, out, clip_mask):
        self.slot, self.npix, self.out, self.clip_mask = slot, npix, out, clip_mask
        self.fargs = self.out_b = self.mask_b = self.event = None
        self.own_out = self.own_mask = False  # results in the slot's buffers, copied back
        self.held: list = []  # (host array, buffer or view over it): alive until the strip is done
        # non-blocking transfers: pyopencl's events keep their host arrays alive and wait
        # for them when dropped, so they are dropped only once the strip is done
        self.events: list = []
        self.stage = "fuse"  # fuse: counts being read back; final: results being made visible; done

    def release(self) -> None:
        """Let the strip's buffers, host arrays and events go and free its slot (the
        device is done with them)."""
        self.held.clear()
        self.events.clear()
        self.fargs = self.out_b = self.mask_b = self.event = None
        self.slot.busy = False


class FusionPlan:
    """Tables and device buffers for fusing many strips of one bracket.

    Strips go through :meth:`submit` and :meth:`poll` (or :class:`StripPipeline`, which
    keeps :data:`PIPELINE_DEPTH` of them in flight): every read-back is non-blocking, so
    the kernels of strip n+1 run while the host waits for strip n's counts and results.
    :meth:`fuse_strip` is one strip, blocking. The kernels and their arguments are the
    same either way: so are the results, bit for bit.
    """

    def __init__(self, proc: "FusionProcessor", nframes: int, width: int, nch: int, dtype,
                 log_times, tables: np.ndarray, weights: np.ndarray, has_valid: bool,
                 depth: Optional[int] = None):
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
        self.rows = proc.strip_rows(width)
        self.spix = self.rows * width
        self.plane = self.spix * nch
        self.frame_args = nframes <= 16
        self.zero_copy = proc.ctx.shares_host_memory
        self.depth = max(1, int(PIPELINE_DEPTH if depth is None else depth))
        self.slots = [_Slot(self, k) for k in range(self.depth)]
        self._next = 0
        s0 = self.slots[0]  # the first slot's buffers, by their old names (profile_kernel)
        self.counts, self.counts_b, self.valid_b = s0.counts, s0.counts_b, s0.valid_b
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
        and ``clip_mask`` where they are (buffers over the host arrays, no copies).
        Blocking: the results are in ``out`` on return (:meth:`submit` does not wait)."""
        self.poll(self.submit(frames, valid, out, clip_mask), wait=True)

    def submit(self, frames: Sequence[np.ndarray], valid: Optional[Sequence[Optional[np.ndarray]]],
               out: np.ndarray, clip_mask: Optional[np.ndarray] = None) -> StripTicket:
        """Queue one strip (arguments as :meth:`fuse_strip`) on the next free slot and
        return at once; :meth:`poll` moves it on. ``frames``, ``valid``, ``out`` and
        ``clip_mask`` must be left alone until the strip is done. At most
        :attr:`depth` strips in flight."""
        q = self.proc.queue
        npix = frames[0].shape[0] * self.w
        if npix > self.spix:
            raise ValueError("strip larger than the plan's strip size")
        slot = self.slots[self._next]
        if slot.busy:
            raise RuntimeError(f"more than {self.depth} strips in flight")
        self._next = (self._next + 1) % self.depth
        t = StripTicket(slot, npix, out, clip_mask)
        held = t.held
        t.fargs = fargs = self._frame_args(frames, held, slot, t.events)
        if self.has_valid:
            for j in range(self.p):
                v = self._ones[:npix] if valid[j] is None else np.ascontiguousarray(valid[j], dtype=np.uint8)
                t.events.append(cl.enqueue_copy(q, slot.valid_b, v, dst_offset=j * self.spix, is_blocking=False))
        out_b = self._host_buffer(out, np.float32, npix * self.c, held)
        t.own_out = out_b is None
        t.out_b = out_b = slot.out_b if out_b is None else out_b
        mask_b = None
        if clip_mask is not None:
            clip_mask[...] = 0  # fuse_fix writes the flagged pixels only
            mask_b = self._host_buffer(clip_mask, np.uint8, npix, held)
        t.own_mask = mask_b is None  # fuse_fix writes the slot's (dropped without a clip_mask)
        t.mask_b = mask_b = slot.mask_b if mask_b is None else mask_b
        args = (np.int32(npix), np.int32(self.p), np.int32(self.levels), np.int32(self.spix))
        tabs = (slot.valid_b, self.lut, self.lt2)
        slot.busy = True
        if npix >= 4:
            self.knl(q, (round_up(npix // 4),), None, *fargs, *tabs, out_b, slot.counts_b, slot.todo_b, *args)
        if npix % 4:
            self.tail(q, (round_up(npix % 4),), None, *fargs, *tabs, out_b, slot.counts_b, slot.todo_b, *args,
                      np.int32(npix - npix % 4))
        # non-blocking: the event keeps slot.counts alive; the fix list's length comes later
        t.event = cl.enqueue_copy(q, slot.counts, slot.counts_b, is_blocking=False)
        return t

    def poll(self, t: StripTicket, wait: bool = False) -> bool:
        """Move strip ``t`` on as far as its events allow (all the way with ``wait``):
        once its fix list's length is known, queue ``fuse_fix`` and the read-back; once
        that is done, let its buffers go. True when the results are in ``t.out``."""
        if t.stage == "fuse":
            if not (wait or _ready(t.event)):
                return False
            t.event.wait()
            self._fix(t)
        if t.stage == "final":
            if not (wait or _ready(t.event)):
                return False
            t.event.wait()
            t.release()
            t.stage = "done"
        return t.stage == "done"

    def _fix(self, t: StripTicket) -> None:
        """Queue the bound rules on the listed pixels and the results' way to the host."""
        q, slot, npix = self.proc.queue, t.slot, t.npix
        clip_mask, mask_b, out_b = t.clip_mask, t.mask_b, t.out_b
        copy_mask = clip_mask is not None and t.own_mask
        nfix = int(slot.counts[3])
        if nfix:  # the fast path listed pixels with values that need the bound rules
            if copy_mask:  # fuse_fix writes the listed pixels only
                cl.enqueue_fill_buffer(q, mask_b, np.uint8(0), 0, npix)
            self.fix(q, (round_up(nfix),), None, *t.fargs, slot.valid_b, self.lut, self.lt2, self.ghi, self.glo,
                     out_b, slot.counts_b, slot.todo_b, mask_b, np.int32(nfix), np.int32(self.p),
                     np.int32(self.levels), np.int32(self.spix))
            cl.enqueue_fill_buffer(q, slot.counts_b, np.uint32(0), 12, 4)  # the list starts empty again
            if copy_mask:
                t.events.append(cl.enqueue_copy(q, clip_mask, mask_b, is_blocking=False))
        if t.own_out:
            t.events.append(cl.enqueue_copy(q, t.out, out_b, is_blocking=False))
        for a, buf in t.held:
            if isinstance(buf, cl.Buffer):  # a map makes the kernels' writes visible in host memory
                m, _ = cl.enqueue_map_buffer(q, buf, cl.map_flags.READ, 0, a.shape, a.dtype, is_blocking=False)
                m.base.release(q)
        t.event = cl.enqueue_marker(q)  # everything of this strip (in-order queue)
        t.stage = "final"

    def _frame_args(self, frames, held: list, slot: Optional[_Slot] = None, events: Optional[list] = None) -> tuple:
        """Kernel arguments for the strip's frames: up to 16 frames, one buffer per frame
        (over the host array where the device shares host memory, from an aligned address
        at or before the strip: :func:`_aligned_view`) and the element offsets; beyond,
        one packed copy (the slot's)."""
        q = self.proc.queue
        size = self.dtype.itemsize
        if not self.frame_args:
            slot = slot or self.slots[0]
            for j, f in enumerate(frames):
                ev = cl.enqueue_copy(q, slot.frames_b, np.ascontiguousarray(f), dst_offset=j * self.plane * size,
                                     is_blocking=False)
                if events is not None:
                    events.append(ev)
            return (slot.frames_b, np.int32(self.plane))
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

    def _host_buffer(self, a: np.ndarray, dtype, n: int, held: list):
        """A read-write buffer over host array ``a`` (contiguous, of ``dtype``, ``n``
        elements), or None (the slot's own is used; the results are copied back) when
        ``a`` is not such an array or the device does not share host memory."""
        if (not self.zero_copy or a.dtype != dtype or not a.flags.c_contiguous or not a.flags.writeable
                or a.size != n):
            return None
        buf = cl.Buffer(self.proc.ctx.context, cl.mem_flags.READ_WRITE | cl.mem_flags.USE_HOST_PTR, hostbuf=a)
        held.append((a, buf))
        return buf

    def pipeline(self) -> "StripPipeline":
        return StripPipeline(self)

    def result_counts(self) -> dict:
        """Clipped high, clipped low and valid-nowhere pixel-channels of every strip so far."""
        total = np.zeros(3, np.int64)
        for slot in self.slots:
            cl.enqueue_copy(self.proc.queue, slot.counts, slot.counts_b, is_blocking=True)
            total += slot.counts[:3]
        return {"clipped_high": int(total[0]), "clipped_low": int(total[1]), "no_data": int(total[2])}


class StripPipeline:
    """Strips of one plan in flight, handed back in order as they complete.

    :meth:`put` queues a strip and returns the tags of the strips finished by then
    (oldest first) without waiting, unless :attr:`FusionPlan.depth` strips are already
    in flight (then it waits for the oldest: bounded memory); :meth:`drain` waits for the
    rest. Leave it through :meth:`close` (a ``with`` block): after an error it waits for
    the device before the host arrays the strips use may go.
    """

    def __init__(self, plan: FusionPlan):
        self.plan = plan
        self.flight: deque = deque()  # (ticket, tag), oldest first

    def put(self, frames, valid, out, clip_mask=None, tag=None) -> list:
        done = []
        while len(self.flight) >= self.plan.depth:
            t, g = self.flight.popleft()
            self.plan.poll(t, wait=True)
            done.append(g)
        self.flight.append((self.plan.submit(frames, valid, out, clip_mask), tag))
        return done + self._collect()

    def _collect(self) -> list:
        """Tags of the oldest strips now done; later strips moved on as far as they can."""
        done, oldest = [], True
        for t, g in list(self.flight):
            finished = self.plan.poll(t)
            if oldest and finished:
                self.flight.popleft()
                done.append(g)
            else:
                oldest = False
        return done

    def drain(self) -> list:
        done = []
        while self.flight:
            t, g = self.flight.popleft()
            self.plan.poll(t, wait=True)
            done.append(g)
        return done

    def close(self) -> None:
        """Wait for the device to be done with every strip still in flight (their results
        are dropped)."""
        if self.flight:
            self.plan.proc.queue.finish()
            for t, _ in self.flight:
                t.release()
            self.flight.clear()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class FusionProcessor(OpenCLProcessor):
    """Weighted log-domain fusion, streamed through the device in horizontal strips.

    The numeric contract is :func:`hdrcl.core.reference.fuse` (its docstring has the
    equations and the zero-weight rule).
    """

    source = "fusion"

    def ghost_departures(self, frames, valid, fused, tables: dict) -> np.ndarray:
        """See :func:`ghost_departures`."""
        return ghost_departures(self, frames, valid, fused, tables)

    def plan(self, nframes, width, nch, dtype, log_times, tables, weights, has_valid,
             depth: Optional[int] = None) -> FusionPlan:
        """A :class:`FusionPlan` keeping up to ``depth`` strips in flight (default
        :data:`PIPELINE_DEPTH`; 1: one strip at a time)."""
        return FusionPlan(self, nframes, width, nch, dtype, log_times, tables, weights, has_valid, depth)

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
        with plan.pipeline() as pipe:
            for r0 in range(0, h, plan.rows):
                r1 = min(h, r0 + plan.rows)
                pipe.put([f[r0:r1] for f in frames],
                         [None if v is None else v[r0:r1] for v in valid] if has_valid else None,
                         out[r0:r1], None if clip_mask is None else clip_mask[r0:r1])
            pipe.drain()
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
