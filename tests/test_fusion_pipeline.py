"""Fusion strips in flight (issue 33, item 4): the kernels of strip n+1 are queued before
strip n is read back, read-backs are non-blocking, at most ``depth`` strips are in
flight, and the results are the blocking path's, bit for bit."""
import numpy as np
import pytest

from hdrcl.core import reference as ref
from hdrcl.core import synthetic as s
from hdrcl.core.weights import weight_table


def _bracket(nframes=5, h=37, w=23, bits=8, seed=0, valid=True):
    """Frames spanning 5 decades (clipped and black pixels: the fix pass runs) with a
    few pixels valid nowhere."""
    cam = s.Camera(a=1.0, x0=(1.0, 1.3, 0.7), bits=bits)
    rad = s.radiance_field(h, w, decades=5.0, seed=seed)
    times = s.stops(nframes, 1.0 if nframes > 8 else 2.0, centre=1.0 / float(np.median(rad)))
    frames = s.bracket(rad, times, cam, noise=0.7, seed=seed + 1)
    levels = 1 << bits
    z = np.clip(np.arange(levels, dtype=np.float64), 0.5, levels - 1.5)
    tables = np.stack([cam.g(z, c) for c in range(3)])
    vv = None
    if valid:
        rng = np.random.default_rng(seed + 2)
        vv = [rng.random((h, w)) > 0.1 for _ in frames]
        for v in vv:
            v[0, :2] = False  # valid nowhere
    return frames, vv, np.log(times), tables, weight_table(levels)


class _Spy:
    """Records the order of a plan's submits and waits; the device is made to look busy
    (no event has completed unless waited for), so only waits move strips on."""

    def __init__(self, plan, monkeypatch):
        import hdrcl.cl.fusion as fusion

        self.log, self.inflight, self.most = [], 0, 0
        monkeypatch.setattr(fusion, "_ready", lambda ev: False)
        submit, poll = plan.submit, plan.poll

        def spy_submit(frames, valid, out, clip_mask=None):
            t = submit(frames, valid, out, clip_mask)
            self.log.append(("submit", id(t)))
            self.inflight += 1
            self.most = max(self.most, self.inflight)
            return t

        def spy_poll(t, wait=False):
            done = poll(t, wait)
            if wait:
                self.log.append(("wait", id(t)))
                self.inflight -= 1
            return done

        monkeypatch.setattr(plan, "submit", spy_submit)
        monkeypatch.setattr(plan, "poll", spy_poll)


def _strips(plan, frames, valid, h):
    for r0 in range(0, h, plan.rows):
        r1 = min(h, r0 + plan.rows)
        yield r0, r1, [f[r0:r1] for f in frames], None if valid is None else [v[r0:r1] for v in valid]


def test_next_strip_is_queued_before_a_strip_is_waited_for(cl_device, monkeypatch):
    from hdrcl.cl.fusion import FusionProcessor

    frames, valid, log_t, tables, wts = _bracket()
    h, w, _ = frames[0].shape
    proc = FusionProcessor(ctx=cl_device, strip_pixels=4 * w + 3)  # 4 rows a strip, 10 strips
    plan = proc.plan(len(frames), w, 3, np.uint8, log_t, tables, wts, True)
    assert plan.depth >= 2
    spy = _Spy(plan, monkeypatch)
    out = np.full((h, w, 3), np.nan, np.float32)
    handed = []
    with plan.pipeline() as pipe:
        for r0, r1, ff, vv in _strips(plan, frames, valid, h):
            for tag in pipe.put(ff, vv, out[r0:r1], tag=r0):
                handed.append(tag)
                assert not np.isnan(out[tag:tag + plan.rows]).any()  # handed over: its results are there
        handed += pipe.drain()
    assert handed == list(range(0, h, plan.rows))  # every strip, in order
    assert spy.most == plan.depth  # bounded: never more strips in flight
    # while the device is busy, a strip is waited for only once the next is queued (or at the end)
    order = [k for _, k in spy.log]
    submits = [k for what, k in spy.log if what == "submit"]
    for i, (what, k) in enumerate(spy.log):
        if what == "wait" and k != submits[-1]:
            later = submits[submits.index(k) + 1]
            assert order.index(later) < i, "waited for a strip before the next one was queued"
    want, wc = ref.fuse(frames, log_t, tables, wts, valid)
    np.testing.assert_allclose(out, want, rtol=2e-5)
    assert plan.result_counts() == wc


@pytest.mark.parametrize("nframes,zero_copy,valid", [(5, True, True), (5, False, True), (5, True, False),
                                                     (18, True, True), (18, False, False)])
def test_pipelined_strips_equal_blocking_strips_bit_for_bit(cl_device, nframes, zero_copy, valid):
    """Frames in place or copied (devices without shared memory), packed beyond 16,
    with and without valid masks, with the clip mask: the same bytes as one strip at a
    time, and the same counts."""
    from hdrcl.cl.fusion import FusionProcessor

    frames, vv, log_t, tables, wts = _bracket(nframes=nframes, valid=valid, seed=nframes)
    h, w, _ = frames[0].shape
    proc = FusionProcessor(ctx=cl_device, strip_pixels=3 * w + 1)
    results = []
    for depth in (1, 3):
        plan = proc.plan(len(frames), w, 3, np.uint8, log_t, tables, wts, valid, depth=depth)
        plan.zero_copy = zero_copy
        out = np.empty((h, w, 3), np.float32)
        mask = np.full((h, w), 7, np.uint8)
        with plan.pipeline() as pipe:
            for r0, r1, ff, vvs in _strips(plan, frames, vv, h):
                pipe.put(ff, vvs, out[r0:r1], mask[r0:r1])
            pipe.drain()
        results.append((out, mask, plan.result_counts()))
    (a, ma, ca), (b, mb, cb) = results
    np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32))
    np.testing.assert_array_equal(ma, mb)
    assert ca == cb
    tmask = np.zeros((h, w), np.uint8)
    want, wc = ref.fuse(frames, log_t, tables, wts, vv, clip_mask=tmask)
    np.testing.assert_allclose(b, want, rtol=2e-5)
    np.testing.assert_array_equal(mb, tmask)
    assert cb == wc


def test_stream_merge_pipelined_equals_one_strip_at_a_time(cl_device, monkeypatch):
    """The streaming merge (deghost, clip mask, valid pixels) hands the sink the same
    strips, in order, whatever the depth."""
    import hdrcl.cl.fusion as fusion
    from hdrcl.cl.fusion import FusionProcessor
    from hdrcl.core.pipeline import ArraySink, ArraySource, stream_merge
    from hdrcl.core.response import Response

    frames, vv, log_t, tables, wts = _bracket(nframes=5, h=61, w=29, seed=5)
    times = np.exp(log_t)
    resp = Response(bits=8, g=tables, knots=np.arange(256.0))
    proc = FusionProcessor(ctx=cl_device, strip_pixels=5 * 29 + 2)
    plans, plan_of = [], proc.plan
    proc.plan = lambda *a, **k: plans.append(plan_of(*a, **k)) or plans[-1]
    got = []
    for depth in (1, 3):
        monkeypatch.setattr(fusion, "PIPELINE_DEPTH", depth)
        sink = ArraySink(61, 29, 3)
        rows = []
        orig = sink.write_rows

        def write_rows(y0, y1, data, orig=orig, rows=rows):
            rows.append(y0)
            orig(y0, y1, data)

        sink.write_rows = write_rows
        clips, ghost = np.zeros((61, 29), np.uint8), np.zeros((61, 29), bool)
        counts, backend = stream_merge(ArraySource(frames, vv), times, resp, sink, processor=proc,
                                       has_valid=True, deghost=True, ghost_mask=ghost, clip_mask=clips)
        assert backend == "opencl" and plans[-1].depth == depth
        assert rows == sorted(rows) and rows[0] == 0
        got.append((sink.array, clips, ghost, counts))
    (a, ca, ga, na), (b, cb, gb, nb) = got
    np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32))
    np.testing.assert_array_equal(ca, cb)
    np.testing.assert_array_equal(ga, gb)
    assert na == nb


def test_a_failing_source_leaves_no_strip_on_the_device(cl_device):
    """An error while strips are in flight: the device is done with them before the error
    leaves stream_merge (their host arrays may then go), and the plan's slots are free."""
    from hdrcl.cl.fusion import FusionProcessor
    from hdrcl.core.pipeline import ArraySink, ArraySource, stream_merge
    from hdrcl.core.response import Response

    frames, vv, log_t, tables, wts = _bracket(nframes=5, h=40, w=20, seed=9)
    proc = FusionProcessor(ctx=cl_device, strip_pixels=2 * 20)
    plans = []
    plan_of = proc.plan

    def keep(*a, **k):
        plans.append(plan_of(*a, **k))
        return plans[-1]

    proc.plan = keep

    class Broken(ArraySource):
        def strips(self, rows):
            for n, strip in enumerate(super().strips(rows)):
                if n == 6:
                    raise OSError("card pulled")
                yield strip

    with pytest.raises(OSError, match="card pulled"):
        stream_merge(Broken(frames, vv), np.exp(log_t), Response(bits=8, g=tables, knots=np.arange(256.0)), ArraySink(40, 20, 3),
                     processor=proc, has_valid=True)
    assert plans and not any(slot.busy for slot in plans[0].slots)


def test_the_buffers_the_kernels_write_are_not_read_only(cl_device):
    """Every strip slot's counters take the kernels' atomic adds (clipped counts and the fix
    list's length): writing a buffer made CL_MEM_READ_ONLY is undefined in OpenCL (a GPU
    driver may place it where atomics do not reach), so none of them is."""
    import pyopencl as cl

    from hdrcl.cl.fusion import FusionProcessor

    frames, vv, log_t, tables, wts = _bracket(nframes=5)
    h, w, _ = frames[0].shape
    proc = FusionProcessor(ctx=cl_device, strip_pixels=3 * w + 1)
    plan = proc.plan(len(frames), w, 3, np.uint8, log_t, tables, wts, True, depth=3)
    for slot in plan.slots:
        for buf in (slot.counts_b, slot.todo_b):
            assert not buf.flags & cl.mem_flags.READ_ONLY
