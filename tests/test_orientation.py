"""EXIF Orientation (issue 32 item 5): read from every frame, written into the output
(EXR and TIFF ``Orientation``, the Radiance resolution line), a batch's preview turned
upright, a note on every set whose frames are turned, a check where the frames differ.
All on generated frames; Radiance's pvalue and Pillow are the oracles of the geometry."""
import json
import os
import subprocess

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.core import synthetic as s
from hdrcl.io.exif import common_orientation, hdr_resolution, to_display

TIMES = (1 / 60, 1 / 15, 1 / 4)


@pytest.fixture(scope="module")
def frames():
    rad = s.radiance_field(24, 32, decades=3.0, seed=3)
    return s.bracket(rad, TIMES, s.Camera(a=1.1, bits=8), noise=0.3, seed=4)


def _photos(folder, frames, tags):
    """One JPEG per frame, camera EXIF and the given Orientation tags (None: no tag)."""
    from hdrcl.io.ldr import write_photo

    folder.mkdir(exist_ok=True)
    paths = []
    for k, (frame, tag) in enumerate(zip(frames, tags)):
        exif = {"ExposureTime": TIMES[k], "FNumber": 8.0, "Exif:PhotographicSensitivity": 100, "Make": "Canon",
                "Model": "EOS", "Exif:DateTimeOriginal": f"2024:06:01 10:00:0{k}"}
        if tag is not None:
            exif["Orientation"] = tag
        paths.append(str(folder / f"IMG_{k}.jpg"))
        write_photo(paths[-1], frame, exif)
    return paths


@pytest.mark.parametrize("o", range(1, 9))
def test_to_display_is_what_viewers_show(o, tmp_path):
    """Pillow's exif_transpose (what viewers do with the tag) of a tagged PNG."""
    from PIL import Image, ImageOps

    from hdrcl.io.ldr import write_photo

    a = np.random.default_rng(o).integers(0, 255, (5, 7, 3), dtype=np.uint8)
    write_photo(str(tmp_path / "p.png"), a, {"Orientation": o})
    shown = np.asarray(ImageOps.exif_transpose(Image.open(tmp_path / "p.png")))
    np.testing.assert_array_equal(to_display(a, o), shown)


def test_frame_info_reads_orientation(frames, tmp_path):
    from hdrcl.io.frames import read_info

    paths = _photos(tmp_path, frames, (6, None, 9))
    assert [read_info(p).orientation for p in paths] == [6, 1, 1]  # 9 is no orientation: as stored
    assert common_orientation([1, 6, 6]) == 6 and common_orientation([6, 1]) == 6 and common_orientation([]) == 1


@pytest.mark.parametrize("o", range(1, 9))
def test_hdr_resolution_line_places_pixels_as_radiance_does(o, radiance_bin, tmp_path):
    """pvalue (Radiance's own reader) puts every stored pixel where to_display does."""
    from hdrcl.io.outmeta import read_orientation
    from hdrcl.io.writers import write_radiance

    a = np.arange(4 * 6, dtype=np.float32).reshape(4, 6, 1) + 1.0
    path = tmp_path / f"o{o}.hdr"
    write_radiance(path, np.repeat(a, 3, axis=2), camera={"orientation": o})
    assert read_orientation(path) == o
    out = subprocess.run([str(radiance_bin / "pvalue"), "-h", "-o", str(path)], capture_output=True, text=True,
                         check=True).stdout.splitlines()
    assert out[0].split() == hdr_resolution(o, 4, 6).split()
    want = to_display(a[..., 0], o)
    got = np.zeros_like(want)
    for line in out[1:]:
        x, y, r = line.split()[:3]
        got[want.shape[0] - 1 - int(y), int(x)] = float(r)  # pvalue: x right, y up
    np.testing.assert_allclose(got, want, rtol=0.01)  # RGBE: 8-bit mantissas, pvalue adds half a step


@pytest.mark.parametrize("ext", [".exr", ".hdr", ".tif", ".pfm"])
def test_turned_set_is_tagged_and_noted(frames, tmp_path, ext):
    """Every frame Orientation 6: the pixels as stored (the same as untagged frames
    give), the output says 6 where its format can, one note names the file and what."""
    from hdrcl.io.outmeta import read_orientation
    from hdrcl.io.radiance import read_radiance

    turned = _photos(tmp_path / "turned", frames, (6, 6, 6))
    plain = _photos(tmp_path / "plain", frames, (None,) * 3)
    runs = {}
    for name, paths in (("turned", turned), ("plain", plain)):
        out = tmp_path / f"{name}{ext}"
        res = CliRunner().invoke(main, ["merge", *paths, "-o", str(out)])
        assert res.exit_code == 0, res.output
        runs[name] = (out, res.stderr)
    lines = [ln for ln in runs["turned"][1].splitlines() if "Orientation" in ln]
    assert len(lines) == 1 and lines[0].startswith("hdrcl: warning: IMG_0.jpg: EXIF Orientation 6 (rotate 90"), lines
    assert "Orientation" not in runs["plain"][1]
    plain_map = read_radiance(runs["plain"][0])[0]
    if ext == ".hdr":  # Radiance's resolution line says 6, and a .hdr is read as Radiance places it
        from hdrcl.io.exif import to_display

        plain_map = to_display(plain_map, 6)
    np.testing.assert_array_equal(read_radiance(runs["turned"][0])[0], plain_map)
    assert read_orientation(runs["turned"][0]) == (1 if ext == ".pfm" else 6)
    assert read_orientation(runs["plain"][0]) == 1
    assert ("cannot say so" in lines[0]) == (ext == ".pfm")


def test_frames_that_differ_are_a_check(frames, tmp_path):
    """One frame turned among upright ones: a check naming it; the output keeps the
    majority's orientation (1)."""
    import hdrcl
    from hdrcl.io.outmeta import read_orientation

    paths = _photos(tmp_path, frames, (1, 6, 1))
    res = hdrcl.merge_files(paths, str(tmp_path / "m.exr"))
    found = [f for f in res.findings if f.check == "orientation"]
    assert len(found) == 1 and found[0].severity == "check" and found[0].file == "IMG_1.jpg"
    assert found[0].message.startswith("IMG_1.jpg: EXIF Orientation 6") and "2 of the 3 frames have 1" in found[0].message
    assert found[0].message in res.warnings
    assert read_orientation(tmp_path / "m.exr") == 1


def test_batch_preview_upright_and_mixed_set_checked(frames, tmp_path):
    """hdrcl batch: the preview of a turned set is the untagged set's, turned; its EXR
    says 6 and the set is done with a note; a set whose frames differ is 'check'."""
    from PIL import Image

    from hdrcl.io.outmeta import read_orientation

    sets = {"turned": (6, 6, 6), "plain": (None,) * 3, "mixed": (1, 8, 1)}
    report = {}
    for name, tags in sets.items():
        _photos(tmp_path / name, frames, tags)
        res = CliRunner().invoke(main, ["batch", str(tmp_path / name), "-o", str(tmp_path / f"out_{name}")])
        assert res.exit_code == 0, res.output
        report[name] = json.loads((tmp_path / f"out_{name}" / "report.json").read_text())["sets"][0]
    previews = {k: np.asarray(Image.open(report[k]["preview"]), np.float64) for k in sets}
    assert previews["turned"].shape[:2] == (32, 24)
    err = {o: np.abs(previews["turned"] - to_display(previews["plain"], o)).mean() for o in (6, 8)}
    assert err[6] < 1.0 < err[8], err  # the same picture (JPEG's own rounding apart), turned clockwise
    assert read_orientation(report["turned"]["output"]) == 6
    assert report["turned"]["status"] == "done"
    assert [f["severity"] for f in report["turned"]["findings"]] == ["note"]
    assert report["plain"].get("findings", []) == []
    assert report["mixed"]["status"] == "check"
    assert report["mixed"]["findings"][0]["file"] == "IMG_1.jpg"


@pytest.mark.parametrize("fmt", ["exr", "hdr"])
def test_rebuilt_preview_is_turned_once(frames, tmp_path, fmt):
    """A preview made again from the output (lost, or of another size) is the one the merge
    wrote: a .hdr is read upright already and was turned a second time (review)."""
    from PIL import Image

    _photos(tmp_path / "turned", frames, (6, 6, 6))
    args = ["batch", str(tmp_path / "turned"), "-o", str(tmp_path / "out"), "--format", fmt]
    assert CliRunner().invoke(main, args).exit_code == 0
    entry = json.loads((tmp_path / "out" / "report.json").read_text())["sets"][0]
    first = np.asarray(Image.open(entry["preview"]), np.float64)
    os.remove(entry["preview"])
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0 and "rebuilt" in res.output, res.output
    again = np.asarray(Image.open(entry["preview"]), np.float64)
    assert again.shape == first.shape == (32, 24, 3)
    assert np.abs(again - first).mean() < 2.0
