"""Streaming merge: files decoded, fused and written strip by strip."""
import numpy as np
import pytest

import hdrcl
from hdrcl.core import synthetic as s
from hdrcl.io.radiance import read_radiance
from hdrcl.io.writers import RadianceWriter


@pytest.fixture()
def files(tmp_path):
    from hdrcl.io.ldr import write_ldr

    cam = s.Camera(a=1.1, x0=(1.0, 1.2, 0.8))
    rad = s.radiance_field(131, 97, decades=4.0, seed=8)
    times = s.stops(5, 2.0, centre=1.0 / float(np.median(rad)))
    paths = []
    for k, img in enumerate(s.bracket(rad, times, cam, noise=0.5, seed=3)):
        alpha = np.full(img.shape[:2] + (1,), 255, np.uint8)
        alpha[:4, :7] = 0  # some pixels carry no measurement in this frame
        p = tmp_path / f"f{k}.png"
        write_ldr(str(p), np.concatenate([img, alpha], axis=2))
        paths.append(str(p))
    return paths, [float(t) for t in times], tmp_path


@pytest.mark.parametrize("grid_rows", [64, 5])  # one grid strip; many, ragged
def test_file_merge_equals_in_memory_merge(files, grid_rows, monkeypatch, cl_device):
    import hdrcl.cl.processing as proc
    import hdrcl.core.sampling as sampling
    import hdrcl.io.reader as reader

    paths, times, d = files
    monkeypatch.setattr(proc, "STRIP_PIXELS", 1000)  # many strips, a ragged last one
    monkeypatch.setattr(reader, "GRID_STRIP_ROWS", grid_rows)
    monkeypatch.setattr(sampling, "MAX_GRID_PIXELS", 2000)  # a grid of stride 3
    from hdrcl.cl.backend import _processors

    _processors.clear()
    try:
        res = hdrcl.merge_files(paths, d / "out.exr", times=times, dtype="float", keep_radiance=True,
                                ignore_color=(0, 0, 255))
        _processors.clear()
        whole = hdrcl.merge(paths, times=times, ignore_color=(0, 0, 255))
    finally:
        _processors.clear()  # no processor with tiny strips outlives the test
    np.testing.assert_allclose(res.radiance, whole, rtol=1e-6)
    back, meta = read_radiance(str(d / "out.exr"))
    np.testing.assert_array_equal(back, res.radiance)
    assert res.radiance is not None and res.shape == (131, 97, 3)


def test_streaming_calibration_gives_the_in_memory_curve(files, monkeypatch):
    """Calibration from files keeps only each frame's sampling grid, read strip by
    strip; the curve equals the one calibrated from the whole frames in memory."""
    import hdrcl.core.sampling as sampling
    import hdrcl.io.reader as reader
    from hdrcl.core.bracket import load_bracket

    paths, times, d = files
    monkeypatch.setattr(sampling, "MAX_GRID_PIXELS", 2000)  # stride 3: the grid is not the image
    monkeypatch.setattr(reader, "GRID_STRIP_ROWS", 7)  # rounded up to 9 rows: many strips, a ragged last
    whole = hdrcl.calibrate(load_bracket(paths, times=times, ignore_color=(0, 0, 255)))
    streamed = hdrcl.calibrate(paths, times=times, ignore_color=(0, 0, 255))
    assert whole.samples == streamed.samples
    np.testing.assert_allclose(streamed.tables(), whole.tables(), atol=1e-9)
    merged = hdrcl.merge_files(paths, d / "out.hdr", times=times, ignore_color=(0, 0, 255))
    np.testing.assert_allclose(merged.response.tables(), whole.tables(), atol=1e-9)


def test_reader_prefetch_then_other_strip_size(files):
    """A first strip started early but then not used (other strip height) is dropped and
    the frames are read again from the top."""
    from hdrcl.io.reader import BracketReader

    paths = files[0]
    with BracketReader(paths) as r:
        whole, _ = r.read_all()
    with BracketReader(paths) as r:
        grid, _ = r.read_grid(2)
        np.testing.assert_array_equal(grid[1], whole[1][::2, ::2])
        r.prefetch(10)
        got = [np.concatenate(fs) for fs in zip(*[f for _, _, f, _ in r.strips(16)])]
    for a, b in zip(got, whole):
        np.testing.assert_array_equal(a, b)


def test_writer_is_atomic_on_failure(tmp_path):
    target = tmp_path / "r.exr"
    target.write_bytes(b"old")
    w = RadianceWriter(target, 10, 8, 3)
    w.write_rows(0, 4, np.ones((4, 10, 3), np.float32))
    with pytest.raises(ValueError):
        w.close()  # rows 4..8 missing
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["r.exr"]


@pytest.mark.parametrize("ext", ["exr", "hdr", "tif", "pfm"])
def test_writer_formats_round_trip(tmp_path, ext):
    img = np.random.default_rng(0).uniform(0.01, 50, (23, 17, 3)).astype(np.float32)
    p = tmp_path / f"x.{ext}"
    with RadianceWriter(p, 17, 23, 3, dtype="float") as w:
        for y0 in range(0, 23, 5):
            w.write_rows(y0, min(23, y0 + 5), img[y0:y0 + 5].copy())
    back, _ = read_radiance(str(p))
    if ext == "hdr":  # RGBE: one shared exponent, so error scales with the brightest channel
        assert np.all(np.abs(back - img) <= 0.01 * img.max(axis=2, keepdims=True))
    else:
        np.testing.assert_allclose(back, img, rtol=1e-6)


def test_rows_out_of_order(tmp_path):
    w = RadianceWriter(tmp_path / "y.exr", 4, 4, 1)
    with pytest.raises(ValueError):
        w.write_rows(2, 4, np.zeros((2, 4, 1), np.float32))
    w.abort()
    assert not list(tmp_path.iterdir())


def test_thumbnail_is_a_subsample(files, cl_device):
    paths, times, d = files
    res = hdrcl.merge_files(paths, d / "t.exr", times=times, dtype="float", keep_radiance=True, thumbnail=30)
    stride = int(np.ceil(131 / 30))
    np.testing.assert_array_equal(res.thumbnail, res.radiance[::stride, ::stride])


def test_calibrating_deghost_merge_reuses_the_grid(files, monkeypatch):
    """A calibrating --deghost merge: the ghost model reads the sampling grid again
    (given back from the calibration pass, not decoded a third time), while the first
    fusion strip is already decoding; the result equals the same merge with the
    response given."""
    import hdrcl.io.reader as reader

    paths, times, d = files
    calls = []
    real = reader.BracketReader._read

    def counting(self, k, y0, y1):
        calls.append((k, y0, y1))
        return real(self, k, y0, y1)

    monkeypatch.setattr(reader.BracketReader, "_read", counting)
    a = hdrcl.merge_files(paths, d / "a.exr", times=times, dtype="float", keep_radiance=True, deghost=True)
    rows_a = sum(y1 - y0 for k, y0, y1 in calls if k == 0)
    calls.clear()
    b = hdrcl.merge_files(paths, d / "b.exr", times=times, dtype="float", keep_radiance=True, deghost=True,
                          response=a.response)
    rows_b = sum(y1 - y0 for k, y0, y1 in calls if k == 0)
    np.testing.assert_array_equal(a.radiance, b.radiance)
    assert a.counts == b.counts
    height = a.shape[0]
    # Either way one pass decodes every row once: its grid serves the solve (or, with the
    # response, the exposures measured through it) and the ghost model, its decoded
    # codes the fusion.
    assert rows_a == height
    assert rows_b == height
