"""Exposure times: parsing, times files, relative exposure, choosing the source."""
from pathlib import Path

import numpy as np
import pytest

from hdrcl.errors import InputError, UsageError
from hdrcl.io.metadata import FrameInfo, check_exposures, format_time, relative_exposures, resolve_exposures
from hdrcl.io.exposure_lists import Exposure, parse_times, read_times_file

MEMORIAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "memorial"


def test_parse_times():
    assert parse_times("1/30,0.5,2") == [1 / 30, 0.5, 2.0]
    assert parse_times(" 1/1000 , 1e-2,30 ") == [0.001, 0.01, 30.0]


@pytest.mark.parametrize("bad", ["1/0", "0", "-1", "nan", "inf", "abc", "1/x", ""])
def test_parse_times_rejects(bad):
    with pytest.raises(UsageError) as err:
        parse_times(f"1/30,{bad},2")
    assert str(err.value) == f"--times: '{bad}' is not a positive exposure time"
    assert err.value.exit_code == 2


def test_parse_times_empty():
    with pytest.raises(UsageError, match="no exposure times"):
        parse_times("  ")


def test_times_file_simple_and_hdrshop(tmp_path):
    path = tmp_path / "times.txt"
    path.write_text(
        "# my bracket\n"
        "\n"
        "IMG_1.JPG 1/30   # comment\n"
        "sub/IMG_2.JPG 0.25\n"
        "scan.png 2 0.5 5.6 6 0.3\n"
    )
    table = read_times_file(path)
    assert table["IMG_1.JPG"] == Exposure(1 / 30)
    assert table["IMG_2.JPG"] == Exposure(0.25)
    assert table["scan.png"] == Exposure(2.0, fnumber=5.6, gain_db=6.0, nd=0.3)


@pytest.mark.parametrize("line", ["a.jpg", "a.jpg 1/0", "a.jpg x 1 8 0 0",
                                  "a.jpg 1 1 8 0 0 extra", "a.jpg 1 1 f8"])
def test_times_file_malformed_line(tmp_path, line):
    path = tmp_path / "image_list.txt"
    path.write_text("# header\nb.jpg 1\n\n" + line + "\n")
    with pytest.raises(InputError) as err:
        read_times_file(path)
    assert str(err.value) == (
        f"{path} line 4: expected 'file seconds' or HDRShop columns")


@pytest.mark.parametrize("value", ["-2", "0", "-0.5", "-1e3"])
def test_times_file_time_not_positive_names_line_and_value(tmp_path, value):
    path = tmp_path / "image_list.txt"
    path.write_text(f"# header\nb.jpg 1 1 8 0 0\nc.jpg {value} 0.5 8 0 0\n")
    with pytest.raises(InputError) as err:
        read_times_file(path)
    assert str(err.value) == f"{path} line 3: c.jpg: exposure time {value} s is not a positive time"


def test_times_file_duplicate_and_missing(tmp_path):
    path = tmp_path / "t.txt"
    path.write_text("a.jpg 1\na.jpg 2\n")
    with pytest.raises(InputError, match="line 2: a.jpg is already listed on line 1"):
        read_times_file(path)
    with pytest.raises(InputError, match=r"nothere\.txt: no such file"):
        read_times_file(tmp_path / "nothere.txt")


def test_memorial_image_list():
    listing = MEMORIAL / "image_list.txt"
    if not listing.is_file():
        pytest.skip(f"shared data not found at {MEMORIAL} (clone shared/ beside the repo)")
    table = read_times_file(listing)
    assert len(table) == 16
    assert table["memorial0061.png"] == Exposure(32.0, fnumber=8.0)
    assert table["memorial0076.png"].time == 1 / 1024
    names = sorted(table)
    rel = relative_exposures([table[n] for n in names])
    np.testing.assert_allclose(rel, 32.0 / 2.0 ** np.arange(16))
    exposures = resolve_exposures([MEMORIAL / n for n in names], times_file=listing)
    assert [e.time for e in exposures] == [table[n].time for n in names]


def test_relative_exposures_settings():
    base = Exposure(1 / 60, fnumber=8.0, iso=100)
    stopped_down = Exposure(1 / 15, fnumber=16.0, iso=100)  # 4x time, 1/4 light
    iso = Exposure(1 / 60, fnumber=8.0, iso=400)
    gain = Exposure(1 / 60, fnumber=8.0, iso=100, gain_db=20.0)
    nd = Exposure(1 / 60, fnumber=8.0, iso=100, nd=0.9)
    rel = relative_exposures([base, stopped_down, iso, gain, nd])
    assert rel.dtype == np.float64
    np.testing.assert_allclose(rel, [1 / 60, 1 / 60, 4 / 60, 10 / 60, 10 ** -0.9 / 60])
    assert stopped_down.relative_to(base) == pytest.approx(1 / 60)


def test_relative_exposures_ignore_missing_factors():
    rel = relative_exposures([Exposure(1.0, fnumber=8.0, iso=100),
                              Exposure(2.0, fnumber=None, iso=200),
                              Exposure(4.0, fnumber=4.0, iso=None)])
    np.testing.assert_allclose(rel, [1.0, 2.0, 4.0])


def _infos(*exif):
    return [FrameInfo(path=f"IMG_000{i}.JPG", width=4, height=3, nchannels=3,
                      exposure_time=t, fnumber=n, iso=s)
            for i, (t, n, s) in enumerate(exif, 1)]


def test_resolve_precedence():
    paths = ["IMG_0001.JPG", "IMG_0002.JPG"]
    infos = _infos((1 / 30, 8.0, 100), (1 / 8, 8.0, 100))
    assert [e.time for e in resolve_exposures(paths, infos)] == [1 / 30, 1 / 8]
    table = {"IMG_0001.JPG": Exposure(1.0), "IMG_0002.JPG": Exposure(2.0)}
    assert [e.time for e in resolve_exposures(paths, infos, times_file=table)] == [1.0, 2.0]
    got = resolve_exposures(paths, infos, times=[0.5, 4.0], times_file=table)
    assert got == [Exposure(0.5), Exposure(4.0)]


def test_resolve_errors(tmp_path):
    paths = ["IMG_0001.JPG", "IMG_0002.JPG", "IMG_0003.JPG"]
    infos = _infos((1 / 30, 8.0, 100), (1 / 8, 8.0, 100), (None, 8.0, 100))
    with pytest.raises(InputError) as err:
        resolve_exposures(paths, infos)
    assert str(err.value) == "IMG_0003.JPG: no exposure time in EXIF; give --times or --times-file"
    with pytest.raises(UsageError, match="2 exposure time"):
        resolve_exposures(paths, infos, times=[1, 2])
    listing = tmp_path / "times.txt"
    listing.write_text("IMG_0001.JPG 1\nIMG_0002.JPG 2\n")
    with pytest.raises(InputError, match=rf"IMG_0003.JPG: not listed in {listing}"):
        resolve_exposures(paths, infos, times_file=listing)
    with pytest.raises(InputError, match="a bracket set needs at least two exposures"):
        resolve_exposures(paths[:1], infos[:1])


def test_equal_exposures_merge_and_fewer_than_two_distinct_are_refused(caplog):
    """Issue 9: an auto-ISO ladder (1/30 s at ISO 100 = 1/60 s at ISO 200) is a normal
    bracket; only a set with fewer than two distinct exposures is refused."""
    import logging

    infos = [FrameInfo(path=p, width=4, height=3, nchannels=3, exposure_time=t, fnumber=n,
                       iso=s)
             for p, t, n, s in [("a.jpg", 1 / 30, 8.0, 100), ("c.jpg", 1 / 4, 8.0, 100),
                                ("b.jpg", 1 / 60, 8.0, 200)]]
    caplog.set_level(logging.INFO, logger="hdrcl")
    exposures = resolve_exposures([i.path for i in infos], infos)
    assert len(exposures) == 3
    assert any("a.jpg, b.jpg share one exposure (1/30 s)" in r.getMessage() for r in caplog.records)
    assert check_exposures(["a", "c", "b"], relative_exposures(exposures)) == [[0, 2]]
    with pytest.raises(InputError, match="a.jpg: all 2 frames have the same exposure"):
        resolve_exposures(["a.jpg", "c.jpg"], None, times=[0.5, 0.5])


def test_absurd_times_and_the_same_file_twice_are_refused(tmp_path, caplog):
    with pytest.raises(InputError, match="b.jpg: effective exposure 1e.300 s is outside"):
        resolve_exposures(["a.jpg", "b.jpg"], None, times=[1.0, 1e300])
    f = tmp_path / "a.png"
    f.write_bytes(b"x")
    g = tmp_path / "g.png"
    g.write_bytes(b"x")
    with pytest.raises(InputError, match="a.png: the same file is given 2 times with different exposures"):
        resolve_exposures([f, g, f], None, times=[1.0, 2.0, 4.0])
    resolve_exposures([f, g, f], None, times=[1.0, 2.0, 1.0])
    assert any("the same file is given 2 times" in r.getMessage() for r in caplog.records)


def test_format_time():
    assert format_time(1 / 30) == "1/30 s"
    assert format_time(0.0333333) == "1/30 s"
    assert format_time(2) == "2 s"
    assert format_time(0.4) == "0.4 s"
    assert format_time(1.5) == "1.5 s"
    assert format_time(1 / 1024) == "1/1024 s"
