"""Issue 16: each frame decoded once, radiance normalised to a reference exposure, the
half/float decision measured on the data, one radiometric scale per camera in a batch.
"""
from __future__ import annotations

import datetime as dt
import json
import os

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.core import synthetic as s
from hdrcl.core.encode import RangeMeter, default_reference, fuse_to_file, reference_for
from hdrcl.io.framecache import FrameCache
from hdrcl.io.ldr import write_photo

CAM = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))


@pytest.fixture
def decoded(monkeypatch):
    """Every decode call as ``(path, frame index, rows)``: tests count rows decoded."""
    import hdrcl.io.reader as reader

    calls = []
    real = reader.BracketReader._read

    def counting(self, k, y0, y1):
        calls.append((self.paths[k], k, y1 - y0))
        return real(self, k, y0, y1)

    monkeypatch.setattr(reader.BracketReader, "_read", counting)
    return calls


def _rows_of_frame(calls, k):
    return sum(n for _p, kk, n in calls if kk == k)


def _spec(path):
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    px = inp.read_image("float")
    inp.close()
    return px, spec


# ------------------------------------------------------------------ frame cache
@pytest.mark.parametrize("in_memory", [True, False])
def test_frame_cache_round_trip(tmp_path, monkeypatch, in_memory):
    """Rows written by several frames come back bit for bit, in memory or spilled to an
    anonymous temporary file that leaves nothing in the scratch folder."""
    monkeypatch.setenv("HDRCL_SCRATCH_DIR", str(tmp_path))
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 65535, (37, 23, 3), dtype=np.uint16) for _ in range(3)]
    cache = FrameCache(3, 37, 23, 3, np.uint16, in_memory=in_memory)
    assert cache.in_memory == in_memory
    alpha = rng.random((37, 23)) > 0.5
    for k, f in enumerate(frames):
        for y0 in range(0, 37, 8):
            cache.put(k, y0, f[y0:y0 + 8], alpha[y0:y0 + 8] if k == 1 else None)
    cache.finish()
    assert os.listdir(tmp_path) == []  # unlinked from the start: nothing to leave behind
    got, valid = cache.rows(5, 30)
    for k in range(3):
        np.testing.assert_array_equal(got[k], frames[k][5:30])
    assert valid[0] is None and valid[2] is None
    np.testing.assert_array_equal(valid[1], alpha[5:30])
    cache.close()


def test_frame_cache_spills_beyond_its_share_of_the_budget(monkeypatch):
    monkeypatch.setenv("HDRCL_MEMORY_MB", "1")
    assert not FrameCache(4, 512, 512, 3, np.uint8).in_memory  # 3 MB > a quarter of 1 MB
    assert FrameCache(2, 16, 16, 3, np.uint8).in_memory
    monkeypatch.setenv("HDRCL_MEMORY_MB", "100")
    assert FrameCache(4, 512, 512, 3, np.uint8).in_memory
    monkeypatch.setenv("HDRCL_MEMORY_SHARE", "40")  # a batch worker's share: 2.5 MB
    assert not FrameCache(4, 512, 512, 3, np.uint8).in_memory


@pytest.fixture(scope="module")
def bracket(tmp_path_factory, write_frames):
    d = tmp_path_factory.mktemp("set")
    rad = s.radiance_field(96, 128, decades=4.0, seed=3)
    times = s.stops(5, 2.0, centre=1.0 / float(np.median(rad)))
    frames = s.bracket(rad, times, CAM, noise=0.5, seed=4)
    return write_frames(d, frames), times / 10.0  # labelled so that the middle is not 1 s


def test_calibrating_merge_spilled_equals_in_memory(bracket, tmp_path, monkeypatch, decoded, cl_device):
    """A calibrating merge whose decoded frames do not fit the budget spills them to the
    scratch file and gives the same file, bit for bit, decoding every row once."""
    from hdrcl.core.merge import merge_files

    paths, times = bracket
    a = merge_files(paths, tmp_path / "a.exr", times=times, dtype="float", keep_radiance=True)
    decoded.clear()
    monkeypatch.setenv("HDRCL_MEMORY_MB", "0.01")
    monkeypatch.setenv("HDRCL_SCRATCH_DIR", str(tmp_path))
    b = merge_files(paths, tmp_path / "b.exr", times=times, dtype="float", keep_radiance=True)
    np.testing.assert_array_equal(a.radiance, b.radiance)
    for k in range(len(paths)):
        assert _rows_of_frame(decoded, k) == 96  # every row of every frame, once
    assert sorted(os.listdir(tmp_path)) == ["a.exr", "b.exr"]
    assert b.stages["decode"] > 0 and b.stages["solve"] > 0 and b.stages["fuse"] > 0


# ------------------------------------------------------------ reference exposure
def test_default_reference_is_a_power_of_two_near_the_middle():
    assert default_reference([1 / 1000, 1 / 250, 1 / 60, 1 / 15, 1 / 4]) == 2.0 ** -6  # middle 1/60
    assert default_reference([0.125, 1, 8]) == 1.0
    assert default_reference([1 / 1024, 32, 1 / 512, 1 / 256]) == 2.0 ** -8  # the median, not the mean
    assert reference_for("x.pfm", [0.01], None, "relative") == 1.0  # PFM cannot say: 1 s
    assert reference_for("x.exr", [0.01], None, "cd/m^2") == 1.0  # absolute units as they are
    assert reference_for("x.exr", [0.01], 0.5, "relative") == 0.5


@pytest.mark.parametrize("ext", [".exr", ".hdr", ".tif"])
def test_file_holds_radiance_times_the_reference(bracket, tmp_path, ext, cl_device):
    """What 1.0 means is recorded where other tools look (expTime, EXPOSURE=), the
    scaling is exact (a power of two) and hdrcl's reader returns 1 s radiance."""
    from hdrcl.core.merge import merge_files
    from hdrcl.io.radiance import read_radiance

    paths, times = bracket
    out = tmp_path / f"m{ext}"
    res = merge_files(paths, out, times=times, keep_radiance=True)
    t_ref = default_reference(times)
    px, spec = _spec(out)
    if ext == ".exr":
        assert spec.getattribute("ExposureTime") == t_ref == spec.getattribute("hdrcl:referenceExposure")
        assert spec.format == "half"
        np.testing.assert_allclose(px, res.radiance * t_ref, rtol=2 ** -11, atol=2 ** -24)
    elif ext == ".hdr":
        assert spec.getattribute("hdr:exposure") == pytest.approx(t_ref)
        head = open(out, "rb").read(200)
        assert f"EXPOSURE={t_ref:.6e}".encode() in head
        want = res.radiance * t_ref  # RGBE: 8-bit mantissas sharing the largest channel's exponent
        assert np.all(np.abs(px - want) <= want.max(axis=2, keepdims=True) / 128)
    else:
        np.testing.assert_array_equal(px, (res.radiance * np.float32(t_ref)))
    back, _ = read_radiance(out)
    if ext == ".hdr":
        assert np.all(np.abs(back - res.radiance) <= res.radiance.max(axis=2, keepdims=True) / 128)
    else:
        np.testing.assert_allclose(back, res.radiance, rtol=1e-3)


def test_half_equals_float_within_half_rounding(bracket, tmp_path, cl_device):
    from hdrcl.core.merge import merge_files

    paths, times = bracket
    merge_files(paths, tmp_path / "h.exr", times=times)
    merge_files(paths, tmp_path / "f.exr", times=times, dtype="float")
    h, sh = _spec(tmp_path / "h.exr")
    f, sf = _spec(tmp_path / "f.exr")
    assert sh.format == "half" and sf.format == "float"
    np.testing.assert_allclose(h, f.astype(np.float16).astype(np.float32), rtol=0, atol=0)
    np.testing.assert_allclose(h, f, rtol=2 ** -11, atol=2 ** -24)


def test_other_tools_read_the_values_hdrcl_means(bracket, tmp_path, cl_device):
    """OpenImageIO's pixel statistics (what ``oiiotool --stats`` prints) of the file are the
    file's values, which are hdrcl's radiance times the recorded reference, nothing hidden."""
    import OpenImageIO as oiio

    from hdrcl.core.merge import merge_files
    from hdrcl.io.radiance import read_radiance, stored_scale

    paths, times = bracket
    merge_files(paths, tmp_path / "m.exr", times=times)
    stats = oiio.ImageBufAlgo.computePixelStats(oiio.ImageBuf(str(tmp_path / "m.exr")))
    back, meta = read_radiance(tmp_path / "m.exr")
    scale = stored_scale(meta)
    assert "halfScale" not in meta
    np.testing.assert_allclose(stats.max, (back * scale).reshape(-1, 3).max(axis=0), rtol=1e-3)
    np.testing.assert_allclose(stats.avg, (back * scale).reshape(-1, 3).astype(np.float64).mean(axis=0), rtol=1e-3)


def test_range_meter_measures_and_stops_forwarding():
    got = []

    class Sink:
        def write_rows(self, y0, y1, data):
            got.append((y0, data.copy()))

    m = RangeMeter(Sink(), 0.5, check=True)
    m.write_rows(0, 1, np.array([[[0.0, 2.0, 4.0]]], np.float32))
    assert not m.overflow and m.lo == 1.0 and m.hi == 2.0 and got[0][1].max() == 2.0
    m.write_rows(1, 2, np.array([[[1e6, 1.0, 1.0]]], np.float32))
    assert m.overflow and m.hi == 5e5 and len(got) == 1  # measured, not forwarded
    m.write_rows(2, 3, np.array([[[1e-9, 1.0, 1.0]]], np.float32))
    assert m.lo == pytest.approx(5e-10) and len(got) == 1


def test_fuse_to_file_second_pass_only_when_the_data_do_not_fit():
    class Writer:
        def __init__(self, dt, scale):
            self.dt, self.scale, self.rows, self.aborted = dt, scale, [], False

        def write_rows(self, y0, y1, data):
            self.rows.append(data.copy())

        def abort(self):
            self.aborted = True

    opened, passes = [], []

    def open_writer(dt, scale):
        opened.append(Writer(dt, scale))
        return opened[-1]

    def run_with(values):
        def run(sink, first):
            passes.append(first)
            sink.write_rows(0, 1, np.asarray(values, np.float32).reshape(1, 1, -1))
            return {"clipped_high": 0}
        return run

    w, _, st = fuse_to_file(open_writer, run_with([1.0, 2.0, 3.0]), output="x.exr", dtype="auto", reference=0.25,
                            keep_units=False)
    assert w.dt == "half" and st.passes == 1 and passes == [True] and st.hi == 0.75
    opened.clear(), passes.clear()
    w, _, st = fuse_to_file(open_writer, run_with([1.0, 1e6, 3.0]), output="x.exr", dtype="auto", reference=1.0,
                            keep_units=False)
    assert opened[0].aborted and w.dt == "float" and passes == [True, False] and "written as float" in st.note
    opened.clear(), passes.clear()
    w, _, st = fuse_to_file(open_writer, run_with([1.0, 1e6, 3.0]), output="x.exr", dtype="half", reference=1.0,
                            keep_units=False)
    assert w.dt == "half" and w.scale < 1 and w.rows[0].max() <= 65504 and st.half_scale == w.scale
    opened.clear(), passes.clear()
    w, _, st = fuse_to_file(open_writer, run_with([1.0, 1e6, 3.0]), output="x.hdr", dtype="auto", reference=1.0,
                            keep_units=False)
    assert passes == [True] and not opened[0].aborted  # RGBE holds it: no second pass


# -------------------------------------------------------------------- the batch
def _shoot(folder, cameras=(("Canon", "EOS R6"),), sets_per_camera=1, centres=None, size=(48, 64)):
    """Hand brackets of one scene: ``centres`` shifts each set's exposure ladder."""
    h, w = size
    scene = s.radiance_field(h, w, decades=3.0, seed=5) * 60.0
    when = dt.datetime(2024, 6, 1, 9, 0, 0)
    n = 0
    base = np.array([1 / 1000, 1 / 250, 1 / 60, 1 / 15, 1 / 4])
    for ci, (make, model) in enumerate(cameras):
        for si in range(sets_per_camera):
            k = (centres or [1.0] * sets_per_camera)[si]
            sub = os.path.join(folder, f"{model.replace(' ', '_')}_{si}")
            os.makedirs(sub, exist_ok=True)
            for t in base * k:
                frame = s.bracket(scene, [t], CAM, noise=0.3, seed=n)[0]
                n += 1
                write_photo(os.path.join(sub, f"IMG_{n:04d}.jpg"), frame,
                            {"ExposureTime": float(t), "FNumber": 8.0, "Exif:PhotographicSensitivity": 100,
                             "Make": make, "Model": model, "Exif:ExposureMode": 1,
                             "Exif:DateTimeOriginal": when.strftime("%Y:%m:%d %H:%M:%S")})
                when += dt.timedelta(seconds=2)
            when += dt.timedelta(minutes=5)


def test_batch_one_set_per_camera_decodes_each_frame_once(tmp_path, decoded, cl_device):
    """A camera with one set calibrates from the decode that feeds its fusion; its
    response file is written as before, and a rerun loads it and skips the set."""
    from hdrcl.cli import main

    _shoot(tmp_path / "shoot", cameras=(("Canon", "EOS R6"), ("Nikon", "D750")))
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["batch", str(tmp_path / "shoot"), "-r", "-o", str(out), "--no-preview"])
    assert res.exit_code == 0, res.output
    rows = {}
    for p, _k, n in decoded:
        rows[p] = rows.get(p, 0) + n
    assert len(rows) == 10 and set(rows.values()) == {48}  # every frame's 48 rows, once
    rep = json.loads((out / "report.json").read_text())
    assert [e["status"] for e in rep["sets"]] == ["done", "done"]
    assert sorted(p.name for p in out.glob("*.response.json")) == ["Canon_EOS_R6_ISO_100.response.json",
                                                                   "Nikon_D750_ISO_100.response.json"]
    assert all(e["seconds"].get("decode", 0) > 0 and e["seconds"].get("solve", 0) > 0 for e in rep["sets"])
    decoded.clear()
    res = CliRunner().invoke(main, ["batch", str(tmp_path / "shoot"), "-r", "-o", str(out), "--no-preview"])
    assert res.exit_code == 0, res.output
    rep = json.loads((out / "report.json").read_text())
    assert [e["status"] for e in rep["sets"]] == ["skipped", "skipped"] and not decoded


def test_batch_one_scale_per_camera(tmp_path, cl_device):
    """Two sets of one camera bracketed around different exposures (a panorama's bright
    and dark views) come out on one radiometric scale: the same scene point within
    0.05 stops, with the same reference exposure in both files."""
    from hdrcl.cli import main

    _shoot(tmp_path / "shoot", sets_per_camera=2, centres=[1.0, 4.0])
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["batch", str(tmp_path / "shoot"), "-r", "-o", str(out), "--no-preview"])
    assert res.exit_code == 0, res.output
    (a, b) = sorted(out.glob("*.exr"))
    pa, sa = _spec(a)
    pb, sb = _spec(b)
    assert sa.getattribute("ExposureTime") == sb.getattribute("ExposureTime") == 2.0 ** -5
    ok = (pa > 0.05) & (pb > 0.05) & (pa < 20) & (pb < 20)
    stops = np.log2(pa[ok] / pb[ok])
    assert ok.mean() > 0.5 and abs(float(np.median(stops))) < 0.05
    # --reference-exposure sets it for the whole shoot
    out2 = tmp_path / "out2"
    res = CliRunner().invoke(main, ["batch", str(tmp_path / "shoot"), "-r", "-o", str(out2), "--no-preview",
                                    "--reference-exposure", "1/125"])
    assert res.exit_code == 0, res.output
    for p in sorted(out2.glob("*.exr")):
        assert _spec(p)[1].getattribute("ExposureTime") == pytest.approx(1 / 125)


def test_merge_with_a_report_decodes_each_frame_once(bracket, tmp_path, decoded, cl_device):
    """``merge --report``: the quality report measures the frames the merge decoded
    (kept in memory) instead of decoding them again."""
    from hdrcl.cli import main

    paths, times = bracket
    res = CliRunner().invoke(main, ["merge", *paths, "--times", ",".join(repr(float(t)) for t in times),
                                    "-o", str(tmp_path / "m.exr"), "--report", str(tmp_path / "rep")])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "rep" / "index.html").exists()
    for k in range(len(paths)):
        assert _rows_of_frame(decoded, k) == 96


def test_lost_response_of_a_one_set_camera_is_solved_again(tmp_path, cl_device):
    """The response file of a camera whose only set is up to date is written again on a
    rerun (report.json names it), and the set is still skipped."""
    from hdrcl.cli import main

    _shoot(tmp_path / "shoot")
    out = tmp_path / "out"
    args = ["batch", str(tmp_path / "shoot"), "-r", "-o", str(out), "--no-preview"]
    assert CliRunner().invoke(main, args).exit_code == 0
    (resp,) = out.glob("*.response.json")
    first = resp.read_bytes()
    resp.unlink()
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
    assert resp.read_bytes() == first
    rep = json.loads((out / "report.json").read_text())
    assert [e["status"] for e in rep["sets"]] == ["skipped"]


def test_warm_up_opens_the_device_while_the_frames_decode(monkeypatch):
    """The warm-up thread opens the device the job will use, decided by the job's size
    alone (hdrcl.core.pipeline.fusion_processor): a large job opens it, a small one not."""
    import hdrcl.cl.backend as backend
    from hdrcl.core.stages import warm_up as _warm_up

    seen = []
    monkeypatch.setattr(backend, "get_processor", lambda kind, device=None, work=None: seen.append(kind))
    monkeypatch.delenv("HDRCL_REQUIRE_OPENCL", raising=False)
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    monkeypatch.delenv("HDRCL_OPENCL", raising=False)
    _warm_up(None, work=backend.small_work() + 1).join()
    assert seen == ["fusion"]
    _warm_up(None, work=12345).join()
    assert seen == ["fusion"]


def test_range_meter_never_lets_nan_or_inf_through_to_half():
    got = []

    class Sink:
        def write_rows(self, y0, y1, data):
            got.append(data)

    m = RangeMeter(Sink(), 1.0, check=True)
    m.write_rows(0, 1, np.array([[[np.nan, 1e6, 1.0]]], np.float32))
    assert m.overflow and not got
