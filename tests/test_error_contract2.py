"""The error contract on every input (issue 18): each class of the audit reproduced.

Every bad value of every option ends as one stderr line with the README's exit code and
no output, *before any file is decoded* (options are checked by one table,
:mod:`hdrcl.core.params`, shared by the command line and the API); warnings that only
describe the failure the error reports are not printed; the Python API raises
:class:`hdrcl.HdrclError` subclasses (or a :class:`TypeError` that is also a
``UsageError``) naming the parameter. Rows of CASES are (id, command line, exit code,
pattern of the line, outputs that must not exist, whether the files may be decoded).
"""
import json
import math
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hdrcl.cli import main
from hdrcl.core import params
from hdrcl.core import synthetic as s
from hdrcl.errors import HdrclError, InputError, ParameterTypeError, UsageError

TIMES = (1 / 60, 1 / 15, 1 / 4)
LINE = re.compile(r"^hdrcl: error: \S.*$")
MEMORIAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "memorial"


@pytest.fixture(scope="module")
def fx(tmp_path_factory):
    """Small files: an 8-bit bracket (32x24) and its response, a one-channel radiance
    map, black / white / transparent brackets, folders a batch finds nothing in."""
    from hdrcl.core.response import Response, knot_positions
    from hdrcl.io.writers import write_radiance
    from hdrcl.io.ldr import write_ldr, write_photo

    d = tmp_path_factory.mktemp("contract2")
    rad = s.radiance_field(24, 32, decades=3.0, seed=3)
    cam = s.Camera(a=1.1, bits=8)
    f = {"dir": d, "rad3": rad}
    frames = s.bracket(rad, TIMES, cam, noise=0.3, seed=4)
    f["frames"] = frames
    f["f8"] = []
    for k, frame in enumerate(frames):
        f["f8"].append(str(d / f"f{k}.png"))
        write_ldr(f["f8"][-1], frame)
    (d / "times.txt").write_text("".join(f"f{k}.png {t!r}\n" for k, t in enumerate(TIMES)))
    f["t8"] = str(d / "times.txt")
    z = knot_positions(8)
    g = np.stack([cam.g(np.clip(z, 1, 254))] * 3)
    g -= g[:, [128]]
    Response(bits=8, g=g, knots=z).save(d / "rgb.json")
    f["rgb"] = str(d / "rgb.json")
    write_radiance(str(d / "one.exr"), rad[..., :1].astype(np.float32), dtype="float")
    f["one"] = str(d / "one.exr")
    write_radiance(str(d / "rad.exr"), rad.astype(np.float32), dtype="float")
    f["rad"] = str(d / "rad.exr")
    for kind in ("black", "white", "transparent"):
        f[kind] = []
        for k in range(3):
            a = np.zeros((24, 32, 3), np.uint8) if kind == "black" else np.full((24, 32, 3), 255, np.uint8)
            if kind == "transparent":
                a = np.concatenate([frames[k], np.zeros((24, 32, 1), np.uint8)], axis=2)
            f[kind].append(str(d / f"{kind}{k}.png"))
            write_ldr(f[kind][-1], a)
    (d / "empty").mkdir()
    (d / "nonimages").mkdir()
    (d / "nonimages" / "notes.txt").write_text("not a photograph")
    (d / "nonimages" / "data.bin").write_bytes(b"\0" * 64)
    (d / "noexif").mkdir()
    exif = {"FNumber": 8.0, "Exif:PhotographicSensitivity": 100, "Make": "Canon", "Model": "EOS",
            "Exif:DateTimeOriginal": "2024:06:01 10:00:00"}
    write_photo(str(d / "noexif" / "IMG_0001.jpg"), frames[0], {**exif, "ExposureTime": 1 / 60})
    write_photo(str(d / "noexif" / "IMG_0002.jpg"), frames[1], {})  # no EXIF at all
    nl = d / "new\nline.png"
    shutil.copy(f["f8"][0], nl)
    f["newline"] = str(nl)
    return f


def _m5():
    if not (MEMORIAL / "image_list.txt").is_file():
        pytest.skip("Memorial set not found")
    return [str(MEMORIAL / f"memorial00{n}.png") for n in (61, 63, 65, 67, 69)] + ["--times", "32,8,2,0.5,0.125"]


def _merge(x, *extra):
    return ["merge", *x["f8"], "--times-file", x["t8"], "-o", "{o}/a.exr", *extra]


def _calibrate(x, *extra):
    return ["calibrate", *x["f8"], "--times-file", x["t8"], "-o", "{o}/r.json", *extra]


NO = False  # the files must not be decoded
YES = True  # decoding is needed to find the problem

CASES = [
    # 1. internal errors
    *[(f"smoothness-{v}", (lambda v: lambda x: _calibrate(x, "--smoothness", v))(v), 2,
       rf"^hdrcl: error: --smoothness: {v} is out of range \(0.001 <= smoothness <= 1e6\)", ["r.json"], NO)
      for v in ("1e308", "1e200")],
    ("seed-negative", lambda x: _calibrate(x, "--seed", "-5"), 2, r"--seed: -5 is out of range \(0 <= seed",
     ["r.json"], NO),
    # 2. silently wrong
    ("smoothness-1e30-flat-curve", lambda x: _calibrate(x, "--smoothness", "1e30"), 2,
     r"--smoothness: 1e30 is out of range .*straight line", ["r.json"], NO),
    ("exposure-tolerance-nan", lambda x: _calibrate(x, "--exposure-tolerance", "nan"), 2,
     r"--exposure-tolerance: nan is not a finite number of stops", ["r.json"], NO),
    ("exposure-tolerance-nan-merge", lambda x: _merge(x, "--response", x["rgb"], "--exposure-tolerance", "nan"), 2,
     r"--exposure-tolerance: nan is not a finite", ["a.exr"], NO),
    # 3. wrong exit code, no file named
    ("expose-one-channel-rgb-response", lambda x: ["expose", x["one"], "--response", x["rgb"], "--time", "1/4",
                                                   "-o", "{o}/o.png"], 3,
     r"rgb.json: a response with 3 channel\(s\), but .*one.exr has 1$", ["o.png"], NO),
    # 4. batch with nothing to merge: the reason on stderr, exit 1, no output folder
    ("batch-empty-folder", lambda x: ["batch", str(x["dir"] / "empty"), "-o", "{o}/out"], 1,
     r"empty: no photographs to merge .*it is empty", ["out"], NO),
    ("batch-empty-folder-quiet", lambda x: ["batch", str(x["dir"] / "empty"), "-o", "{o}/out", "-q"], 1,
     r"empty: no photographs to merge", ["out"], NO),
    ("batch-non-images", lambda x: ["batch", str(x["dir"] / "nonimages"), "-o", "{o}/out"], 1,
     r"nonimages: no photographs to merge .*2 other file\(s\), such as data.bin", ["out"], NO),
    ("batch-no-exposure-time", lambda x: ["batch", str(x["dir"] / "noexif"), "-o", "{o}/out", "-q"], 1,
     r"noexif: no bracket sets to merge \(.*IMG_0002.jpg: single frame, without an exposure time", ["out"], YES),
    # 5. options checked after the work started: now before any decoding
    ("compression-bogus", lambda x: _merge(x, "--compression", "bogus"), 2,
     r"^hdrcl: error: --compression: 'bogus' is not one of none, rle", ["a.exr"], NO),
    ("neutral-empty", lambda x: _merge(x, "--neutral", "0,0,0,0"), 2,
     r"--neutral: expected x,y,w,h in pixels \(w, h > 0\), not '0,0,0,0'", ["a.exr"], NO),
    ("neutral-outside", lambda x: _merge(x, "--neutral", "500,500,10,10"), 2,
     r"--neutral: patch 500,500,10,10 runs outside the 32x24 image", ["a.exr"], NO),
    ("reference-patch-nan", lambda x: _merge(x, "--reference-patch", "0,0,10,10=nan"), 2,
     r"--reference-patch: expected x,y,w,h=VALUE", ["a.exr"], NO),
    ("reference-patch-outside", lambda x: _merge(x, "--reference-patch", "30,0,10,10=100"), 2,
     r"--reference-patch: patch 30,0,10,10 runs outside the 32x24 image", ["a.exr"], NO),
    ("ghost-reference-99", lambda x: _merge(x, "--deghost", "--ghost-reference", "99"), 2,
     r"--ghost-reference: frame 99 does not exist \(0..2\)", ["a.exr"], NO),
    ("ghost-reference-negative", lambda x: _merge(x, "--deghost", "--ghost-reference=-1"), 2,
     r"--ghost-reference: frame -1 does not exist", ["a.exr"], NO),
    *[(f"ghost-threshold-{v}", (lambda v: lambda x: _merge(x, "--deghost", "--ghost-threshold", v))(v), 2,
       rf"--ghost-threshold: {v} is not a finite number", ["a.exr"], NO) for v in ("nan", "inf")],
    *[(f"merge-smoothness-{v}", (lambda v: lambda x: _merge(x, "--smoothness", v))(v), 2,
       rf"^hdrcl: error: --smoothness: {re.escape(v)} is (out of range|not a finite number)", ["a.exr"], NO)
      for v in ("0", "-1", "nan", "inf")],
    ("ghost-threshold-without-deghost", lambda x: _merge(x, "--ghost-threshold", "4", "-o", "{o}/b.pfm"), 2,
     r"--ghost-threshold and --ghost-reference need --deghost", ["a.exr", "b.pfm"], NO),
    ("expose-motion-blur-longer-than-image", lambda x: ["expose", x["rad"], "--response", x["rgb"], "--time", "1",
                                                        "--motion-blur", "100,0", "-o", "{o}/o.png"], 2,
     r"--motion-blur: 100,0 is longer than the image \(32x24\)", ["o.png"], NO),
    ("expose-time-out-of-range", lambda x: ["expose", x["rad"], "--response", x["rgb"], "--time", "1e308",
                                            "-o", "{o}/o.png"], 2,
     r"--time: '1e308' is not an exposure time between", ["o.png"], NO),
    # 6. frames with nothing to measure: one line, no warnings first
    *[(f"calibrate-{k}", (lambda k: lambda x: ["merge", *x[k], "--times", "1,2,4", "-o", "{o}/a.exr"])(k), 3,
       rf"{k}0.png, {k}1.png, {k}2.png: .*nothing to calibrate from", ["a.exr"], YES)
      for k in ("black", "white", "transparent")],
    # 9. a file name holding a line break: the whole name, escaped, on the one line
    ("newline-in-name", lambda x: ["merge", x["newline"], *x["f8"][1:], "-o", "{o}/a.exr"], 3,
     r"new\\nline.png: no exposure time in EXIF", ["a.exr"], NO),
    ("newline-in-missing-name", lambda x: ["merge", x["f8"][0], str(x["dir"] / "gone\nfile.png"), "--times", "1,2",
                                           "-o", "{o}/a.exr"], 3, r"gone\\nfile.png: no such file$", ["a.exr"], NO),
]

M5_CASES = [
    # the audit's own command lines on five Memorial frames
    ("m5-smoothness-1e308", ["--smoothness", "1e308"], r"--smoothness: 1e308 is out of range"),
    ("m5-seed-negative", ["--seed", "-5"], r"--seed: -5 is out of range"),
    ("m5-smoothness-1e30", ["--smoothness", "1e30"], r"--smoothness: 1e30 is out of range"),
    ("m5-exposure-tolerance-nan", ["--exposure-tolerance", "nan"], r"--exposure-tolerance: nan is not"),
]


@pytest.fixture
def decoded(monkeypatch):
    """Records every decode of pixels (frames or radiance maps) while a command runs."""
    import hdrcl.io.radiance as radiance
    import hdrcl.io.reader as reader

    seen = []
    init = reader.BracketReader.__init__
    read = radiance.read_radiance

    def tracking_init(self, *a, **k):
        seen.append("frames")
        return init(self, *a, **k)

    def tracking_read(*a, **k):
        seen.append("radiance")
        return read(*a, **k)

    monkeypatch.setattr(reader.BracketReader, "__init__", tracking_init)
    monkeypatch.setattr(radiance, "read_radiance", tracking_read)
    return seen


def _check_one_line(res, code, pattern, tmp_path, outputs):
    err = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.exit_code == code, (res.exit_code, res.stderr, res.stdout)
    assert len(err) == 1, res.stderr  # no warning before the error
    assert LINE.match(err[0]) and "internal error" not in err[0], err[0]
    assert re.search(pattern, err[0]), err[0]
    assert res.stdout == "" or code == 0, res.stdout
    for name in outputs:
        assert not (tmp_path / name).exists(), f"{name} was written although the exit code is {code}"
    assert not list(tmp_path.rglob(".*tmp*")), "temporary file left behind"


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_every_case_is_one_line_before_decoding(case, fx, tmp_path, decoded):
    _id, argv, code, pattern, outputs, may_decode = case
    args = [a.replace("{o}", str(tmp_path)) for a in argv(fx)]
    res = CliRunner().invoke(main, args)
    _check_one_line(res, code, pattern, tmp_path, outputs)
    if not may_decode:
        assert decoded == [], f"the files were decoded before the error: {decoded}"


@pytest.mark.parametrize("case", M5_CASES, ids=[c[0] for c in M5_CASES])
def test_memorial_five_frames(case, tmp_path, decoded):
    _id, extra, pattern = case
    res = CliRunner().invoke(main, ["calibrate", *_m5(), *extra, "-o", str(tmp_path / "r.json")])
    _check_one_line(res, 2, pattern, tmp_path, ["r.json"])
    assert decoded == []


# ------------------------------------------------------- the table: every numeric option

SPECIAL = ("0", "-1", "nan", "inf", "-inf", "1e308")
NUMERIC = sorted(n for n, o in params.TABLE.items() if o.numeric)


def _accepts(opt, v) -> bool:
    lo_ok = opt.lo is None or (v > opt.lo if opt.lo_open else v >= opt.lo)
    return math.isfinite(v) and lo_ok and (opt.hi is None or v <= opt.hi)


@pytest.mark.parametrize("name", NUMERIC)
@pytest.mark.parametrize("text", SPECIAL)
def test_special_values_of_every_numeric_option(name, text):
    """0, -1, NaN, +-inf and 1e308, as typed: in range and accepted, or one UsageError
    naming the flag; never anything else."""
    opt = params.TABLE[name]
    v = float(text)
    ok = _accepts(opt, v) and (opt.kind == "float" or text.lstrip("-").isdigit())
    if name == "bits":
        ok = False
    if ok:
        assert params.check(name, text) == v
    else:
        with pytest.raises(UsageError, match=rf"^{opt.flag}: "):
            params.check(name, text)


ANYTHING = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(10 ** 30), max_value=10 ** 30),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=20),
    st.sampled_from(["1e308", "-0", "nan", "1/0", "1/30", "0,0,10,10", "0,0,10,10=5", "middle", "zip",
                     "dwaa:45", "64x48", "1,2", "1,2,3", "rgb", "bgr", "half", "reinhard"]),
    st.lists(st.integers(-5, 300), max_size=5), st.tuples(st.integers(-5, 40), st.floats()),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2), st.binary(max_size=4),
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(name=st.sampled_from(sorted(params.TABLE)), value=ANYTHING, frames=st.one_of(st.none(), st.integers(1, 9)))
def test_table_accepts_or_names_the_option(name, value, frames):
    """Whatever the value, :func:`params.check` returns a sane value or raises a
    UsageError (ParameterTypeError for a wrong type) whose message names the option."""
    opt = params.TABLE[name]
    try:
        out = params.check(name, value, frames=frames)
    except UsageError as exc:
        assert str(exc).startswith(opt.flag + ":"), str(exc)
        assert "\n" not in str(exc)
        if isinstance(exc, ParameterTypeError):
            assert isinstance(exc, TypeError)
        return
    if value is None:
        assert out is None
    elif opt.numeric:
        assert isinstance(out, (int, float)) and not isinstance(out, bool)
        assert math.isfinite(out) and _accepts(opt, out)
    elif opt.kind == "seconds":
        assert opt.lo <= out <= opt.hi
    elif opt.kind == "ghost_reference" and isinstance(out, int):
        assert out >= 0 and (frames is None or out < frames)


#: (command line, option, where the value goes): each numeric option of each command.
SWEEP = [
    (lambda x: _calibrate(x), "--samples"), (lambda x: _calibrate(x), "--smoothness"),
    (lambda x: _calibrate(x), "--seed"), (lambda x: _calibrate(x), "--exposure-tolerance"),
    (lambda x: _merge(x, "--deghost"), "--ghost-threshold"), (lambda x: _merge(x), "--reference-exposure"),
    (lambda x: ["expose", x["rad"], "--response", x["rgb"], "-o", "{o}/e.png"], "--time"),
    (lambda x: ["tonemap", x["rad"], "-o", "{o}/t.png"], "--exposure"),
    (lambda x: ["batch", str(x["dir"] / "noexif"), "-o", "{o}/out"], "--jobs"),
    (lambda x: ["batch", str(x["dir"] / "noexif"), "-o", "{o}/out"], "--preview-size"),
    (lambda x: ["batch", str(x["dir"] / "noexif"), "-o", "{o}/out"], "--frames-per-set"),
    (lambda x: ["scan", str(x["dir"] / "noexif")], "--gap"),
    (lambda x: ["--max-pixels", "{v}", "scan", str(x["dir"] / "noexif")], None),
    (lambda x: ["demo", "{o}/demo", "--no-shoot"], "--frames"),
]


@pytest.mark.parametrize("text", SPECIAL)
@pytest.mark.parametrize("row", SWEEP, ids=[r[1] or "--max-pixels" for r in SWEEP])
def test_cli_sweep_special_values(row, text, fx, tmp_path, decoded):
    """Each numeric option of each command, given 0, -1, NaN, +-inf, 1e308: exit 0 (the
    value is valid) or exit 2 with one line naming the flag, before any decoding."""
    argv, flag = row
    args = [a.replace("{o}", str(tmp_path)).replace("{v}", text) for a in argv(fx)]
    if flag is not None:
        args += [f"{flag}={text}"]
    opt = params.TABLE[(flag or "--max-pixels")[2:].replace("-", "_")]
    v = float(text)
    valid = _accepts(opt, v) and (opt.kind == "float" or text.lstrip("-").isdigit()) and opt.kind != "seconds"
    res = CliRunner().invoke(main, args)
    if valid:
        assert res.exit_code in (0, 1), (res.exit_code, res.stderr)  # 1: the noexif folder has no set
        assert "internal error" not in res.stderr
        return
    _check_one_line(res, 2, rf"^hdrcl: error: {flag or '--max-pixels'}: ", tmp_path, [])
    assert decoded == []


def test_smoothness_range_ends_give_sane_curves():
    """The ends of the accepted range still solve (8 and 16 bits): finite, rising curves."""
    import hdrcl

    rad = s.radiance_field(48, 64, decades=3.0, seed=3)
    for bits in (8, 16):
        frames = s.bracket(rad, (1 / 60, 1 / 15, 1 / 4, 1), s.Camera(a=1.1, bits=bits), noise=0.3, seed=4)
        for lam in params.SMOOTHNESS_RANGE:
            resp = hdrcl.calibrate(frames, (1 / 60, 1 / 15, 1 / 4, 1), smoothness=lam)
            assert np.all(np.isfinite(resp.g)) and resp.span_decades() > 1.0, (bits, lam, resp.span_decades())


# ------------------------------------------------------------------------------ the API


def _api_cases():
    f8 = (np.zeros((4, 4, 3), np.uint8), np.full((4, 4, 3), 100, np.uint8), np.full((4, 4, 3), 200, np.uint8))
    mixed = [f8[0], f8[1].astype(np.uint16) * 257, f8[2]]
    return [
        ("uint16-among-uint8", lambda h, x: h.calibrate(mixed, TIMES), UsageError,
         r"^images: image 1 is uint16 but image 0 is uint8"),
        ("uint16-among-uint8-merge", lambda h, x: h.merge(mixed, TIMES), UsageError, r"^images: image 1 is uint16"),
        ("bytes-paths", lambda h, x: h.calibrate([os.fsencode(p) for p in x["f8"]], TIMES), None, None),
        ("zero-height", lambda h, x: h.calibrate([np.zeros((0, 5, 3), np.uint8)] * 3, TIMES), UsageError,
         r"^images: image 0 is empty \(shape \(0, 5, 3\)\)"),
        ("nested-lists", lambda h, x: h.calibrate([f.tolist() for f in x["frames"]], TIMES), ParameterTypeError,
         r"^images: image 0 is a list, not a path or a NumPy array"),
        ("one-string", lambda h, x: h.merge(x["f8"][0], TIMES), ParameterTypeError,
         r"^images: expected a list of images, not one path"),
        ("one-string-calibrate", lambda h, x: h.calibrate(x["f8"][0], TIMES), ParameterTypeError,
         r"^images: expected a list of images"),
        ("not-iterable", lambda h, x: h.merge(5, TIMES), ParameterTypeError, r"^images: expected a list"),
        ("tonemap-nan", lambda h, x: h.tonemap(np.full((4, 4, 3), np.nan, np.float32)), UsageError,
         r"^radiance: 48 NaN or infinite value\(s\)"),
        ("tonemap-inf", lambda h, x: h.tonemap(np.full((4, 4, 3), np.inf, np.float32)), UsageError,
         r"^radiance: 48 NaN or infinite"),
        ("tonemap-empty", lambda h, x: h.tonemap(np.zeros((0, 4, 3), np.float32)), UsageError,
         r"^radiance: expected a non-empty"),
        ("times-dict", lambda h, x: h.merge(x["f8"], {"a": 1}), ParameterTypeError,
         r"^times: expected a list of exposure times, one per image in their order, not a dict"),
        ("seed-negative", lambda h, x: h.calibrate(x["frames"], TIMES, seed=-5), UsageError, r"^seed: -5 is out"),
        ("smoothness-1e308", lambda h, x: h.calibrate(x["frames"], TIMES, smoothness=1e308), UsageError,
         r"^smoothness: 1e308 is out of range"),
        ("samples-0", lambda h, x: h.calibrate(x["frames"], TIMES, samples=0), UsageError, r"^samples: 0 is out"),
        ("samples-float", lambda h, x: h.calibrate(x["frames"], TIMES, samples=1.5), ParameterTypeError,
         r"^samples: expected an integer, not float"),
        ("tolerance-nan", lambda h, x: h.calibrate(x["frames"], TIMES, exposure_tolerance=float("nan")), UsageError,
         r"^exposure_tolerance: nan is not a finite"),
        ("neutral-nan", lambda h, x: h.merge(x["frames"], TIMES, neutral=(0, 0, float("nan"), 1)),
         ParameterTypeError, r"^neutral: expected 4 integers"),
        ("neutral-outside", lambda h, x: h.merge(x["frames"], TIMES, neutral=(30, 0, 10, 10)), UsageError,
         r"^neutral: patch 30,0,10,10 runs outside the 32x24 image"),
        ("ghost-reference", lambda h, x: h.merge_files(x["f8"], x["dir"] / "never.exr", times=TIMES, deghost=True,
                                                       ghost_reference=3), UsageError,
         r"^ghost_reference: frame 3 does not exist \(0..2\)"),
        ("compression", lambda h, x: h.merge_files(x["f8"], x["dir"] / "never.exr", times=TIMES,
                                                   compression="bogus"), UsageError, r"^compression: 'bogus'"),
        ("expose-time", lambda h, x: h.expose(x["rad3"], x["rgb"], float("inf")), UsageError,
         r"^time: 'inf' is not a positive exposure time"),
        ("expose-channels", lambda h, x: h.expose(x["rad3"][..., :1], x["rgb"], 1.0), UsageError,
         r"rgb.json: a response with 3 channel\(s\), but radiance has 1"),
        ("expose-file-channels", lambda h, x: h.expose_file(x["one"], x["dir"] / "never.png", x["rgb"], 1.0),
         InputError, r"rgb.json: a response with 3 channel\(s\), but .*one.exr has 1"),
        ("align-not-bool", lambda h, x: h.merge(x["frames"], TIMES, align="yes"), ParameterTypeError,
         r"^align: expected True or False"),
    ]


API = _api_cases()


@pytest.mark.parametrize("case", API, ids=[c[0] for c in API])
def test_api_raises_typed_errors_naming_parameters(case, fx):
    import hdrcl

    _id, call, kind, pattern = case
    if kind is None:  # accepted: no exception at all
        call(hdrcl, fx)
        return
    with pytest.raises(HdrclError) as err:
        call(hdrcl, fx)
    assert isinstance(err.value, kind), type(err.value)
    assert re.search(pattern, str(err.value)), str(err.value)
    assert "--" not in str(err.value)


def test_bytes_paths_give_the_same_response(fx):
    import hdrcl

    a = hdrcl.calibrate(fx["f8"], TIMES)
    b = hdrcl.calibrate([os.fsencode(p) for p in fx["f8"]], TIMES)
    np.testing.assert_array_equal(a.g, b.g)


def test_bgr_arrays_with_channel_order(fx):
    """OpenCV's BGR arrays: channel_order="bgr" gives the RGB result, returned as BGR."""
    import hdrcl

    rgb = hdrcl.merge(fx["frames"], TIMES, fx["rgb"])
    bgr = hdrcl.merge([f[..., ::-1] for f in fx["frames"]], TIMES, fx["rgb"], channel_order="bgr")
    np.testing.assert_array_equal(bgr, rgb[..., ::-1])
    r1 = hdrcl.calibrate(fx["frames"], TIMES)
    r2 = hdrcl.calibrate([np.ascontiguousarray(f[..., ::-1]) for f in fx["frames"]], TIMES, channel_order="bgr")
    np.testing.assert_allclose(r1.g, r2.g)
    photo = hdrcl.expose(rgb[..., ::-1], fx["rgb"], 1 / 15, channel_order="bgr")
    np.testing.assert_array_equal(photo, hdrcl.expose(rgb, fx["rgb"], 1 / 15)[..., ::-1])
    with pytest.raises(UsageError, match="^channel_order: 'brg' is not one of rgb, bgr"):
        hdrcl.merge(fx["frames"], TIMES, fx["rgb"], channel_order="brg")


def test_orientation_that_differs_between_frames_is_said(fx, tmp_path):
    """Frames whose EXIF Orientation tags differ get one warning (a finding: the pixels are
    merged as stored, tests/test_orientation.py)."""
    from hdrcl.io.ldr import write_photo

    paths = []
    for k, frame in enumerate(fx["frames"]):
        paths.append(str(tmp_path / f"o{k}.jpg"))
        write_photo(paths[-1], frame, {"ExposureTime": TIMES[k], "Orientation": 6 if k == 1 else 1})
    res = CliRunner().invoke(main, ["merge", *paths, "-o", str(tmp_path / "o.exr"), "--response", fx["rgb"]])
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.stderr.splitlines() if "Orientation" in ln]
    assert len(lines) == 1 and "o1.jpg: EXIF Orientation 6 (" in lines[0] and "merged as stored" in lines[0], res.stderr


def test_quiet_batch_still_says_why_nothing_was_merged(fx, tmp_path):
    res = CliRunner().invoke(main, ["-q", "batch", str(fx["dir"] / "empty"), "-o", str(tmp_path / "out")])
    assert res.exit_code == 1 and res.stdout == ""
    assert res.stderr.startswith("hdrcl: error: ") and res.stderr.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_api_run_batch_raises_for_nothing_to_merge(fx, tmp_path):
    from hdrcl.errors import ProcessingError
    from hdrcl.shoot.batch.run import run_batch

    with pytest.raises(ProcessingError, match="no photographs to merge"):
        run_batch(str(fx["dir"] / "empty"), tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_api_and_cli_share_the_words(fx, tmp_path):
    """One table: the CLI's line is the API's message with the flag for the parameter."""
    import hdrcl

    res = CliRunner().invoke(main, ["calibrate", *fx["f8"], "--times-file", fx["t8"], "-o", str(tmp_path / "r.json"),
                                    "--smoothness", "1e308"])
    with pytest.raises(UsageError) as err:
        hdrcl.calibrate(fx["f8"], TIMES, smoothness=1e308)
    assert res.stderr.strip() == "hdrcl: error: " + str(err.value).replace("smoothness:", "--smoothness:", 1)
    assert json.dumps(str(err.value))  # plain text


def test_bytes_paths_everywhere(fx, tmp_path):
    """``bytes`` paths (os.fsencode) work as ``str`` ones do, in and out."""
    import hdrcl

    out = hdrcl.merge_files([os.fsencode(p) for p in fx["f8"]], os.fsencode(str(tmp_path / "m.exr")), times=TIMES,
                            response=fx["rgb"])
    assert out.output == str(tmp_path / "m.exr") and (tmp_path / "m.exr").is_file()
    hdrcl.expose_file(os.fsencode(fx["rad"]), os.fsencode(str(tmp_path / "e.png")), fx["rgb"], "1/15")
    hdrcl.tonemap_file(os.fsencode(fx["rad"]), os.fsencode(str(tmp_path / "t.png")))
    assert (tmp_path / "e.png").is_file() and (tmp_path / "t.png").is_file()
