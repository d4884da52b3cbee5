"""Radiance's .cal language (hdrcl/io/calexpr.py): the grammar, the lab's real files, the
errors, and Radiance itself (rcalc's and pcomb's calc library) as the oracle."""
import random
import subprocess

import numpy as np
import pytest

from hdrcl.errors import InputError, UsageError
from hdrcl.io import calexpr, radcal

# The real files of radiantlab/HDRICalibrationTool (example/vignetting.cal,
# examples/inputs/parameters/calibration_files/vignetting_f8.cal, CF_f5d6.cal,
# NDfilter_no_transform.cal, example/NDfilter_transform.cal) and of
# ZAWAJAN/Acapulco-Sensors (Camera/src/code/VignettingCorrection.cal), text unchanged.
LAB_VIG = """sq(x)=x*x;
r=sqrt(sq(x-500)+sq(y-500))/500;
sf=(1/(((-0.528613562104476)*(r^4))+((0.000000000000000052147170934049)*(r^3))+((0.1755458928191)*(r^2))+((0.000000000000000007599040843632)*r)+1));
ro=sf*ri(1);
go=sf*gi(1);
bo=sf*bi(1);
"""
LAB_VIG_F8 = """sq(x)=x*x;
r=sqrt(sq(x-500)+sq(y-500))/500;
sf=(1/(((-2.11151841208553)*(r^8))+((-0.00000000000000295190265753503)*(r^7))+((3.66825171388962)*(r^6))+((0.0000000000000030452457684329)*(r^5))+((-2.24835515006869)*(r^4))+((-0.000000000000000631163653663639)*(r^3))+((0.390822570028146)*(r^2))+((-0.000000000000000446250553333187)*r)+1));
ro=sf*ri(1);
go=sf*gi(1);
bo=sf*bi(1);
\t
"""
ACAPULCO_VIG = """xr=(x-1500/2);
yr=(y- 1500/2);
sq(xr)=xr*xr;
sq(yr)=yr*yr;
r=(sqrt(sq(xr)+sq(yr)))/750;
ro=(ri(1)*(1/((1.0006*r^6+(-0.0099*r^5)+0.0004*r^4+0*r^3+0*r^2+0*r+1))));
go=(gi(1)*(1/((1.0006*r^6+(-0.0099*r^5)+0.0004*r^4+0*r^3+0*r^2+0*r+1))));
bo=(bi(1)*(1/((1.0006*r^6+(-0.0099*r^5)+0.0004*r^4+0*r^3+0*r^2+0*r+1))));"""
LAB_CF = "ro=ri(1)*1.18;\ngo=gi(1)*1.18;\nbo=bi(1)*1.18;\n"
LAB_ND_IDENTITY = "ro=ri(1);\ngo=gi(1);\nbo=bi(1);\n"
LAB_ND = "ro=793.2549*ri(1);\ngo=811.7736*gi(1);\nbo=1196.992*bi(1);"


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def _lab_poly(r):
    return 1 / (-0.528613562104476 * r ** 4 + 5.2147170934049e-17 * r ** 3 + 0.1755458928191 * r ** 2
                + 7.599040843632e-18 * r + 1)


def test_the_lab_files_are_read(tmp_path):
    v = radcal.read_vignetting(_write(tmp_path, "vignetting_f5d6.cal", LAB_VIG))
    assert (v.xc, v.yc, v.radius) == (500.0, 500.0, 500.0)
    f = v.factors(1000)
    rows, cols = np.array([0, 499, 250, 999]), np.array([0, 500, 900, 10])
    r = np.hypot(cols - 500, (999 - rows) - 500) / 500  # y from the bottom
    np.testing.assert_allclose(f[rows, cols, 1], _lab_poly(r), rtol=1e-12)
    assert radcal.read_vignetting(_write(tmp_path, "vignetting_f8.cal", LAB_VIG_F8)).radius == 500.0
    a = radcal.read_vignetting(_write(tmp_path, "VignettingCorrection.cal", ACAPULCO_VIG))
    assert (a.xc, a.yc, a.radius) == (750.0, 750.0, 750.0)
    assert radcal.read_calibration_factor(_write(tmp_path, "CF_f5d6.cal", LAB_CF)) == 1.18
    assert radcal.read_nd_filter(_write(tmp_path, "NDfilter_no_transform.cal", LAB_ND_IDENTITY)) == (1.0, 1.0, 1.0)
    assert radcal.read_nd_filter(_write(tmp_path, "NDfilter_transform.cal", LAB_ND)) == (793.2549, 811.7736, 1196.992)


def test_xres_forms_nested_comments_and_constants(tmp_path):
    text = """{ measured {lab B} f/5.6 }
    xc : xres/2; yc : yres/2; R = xres/2;
    r = sqrt((x-xc)^2 + (y-yc)^2)/R;
    sf = 1/(1 - .1*r^2 + 1.5E-2*r^4)
    ; ro = sf*ri(1); go = gi(1)*sf; bo = +sf*bi(1)
    """
    v = radcal.read_vignetting(_write(tmp_path, "v.cal", text))
    assert v.check_geometry(800) is None and v.check_geometry(1000) is None  # follows the map
    f = v.factors(800)
    r = np.hypot(0 - 400, 799 - 400) / 400  # row 0, column 0: y = 799
    np.testing.assert_allclose(f[0, 0], 1 / (1 - 0.1 * r ** 2 + 0.015 * r ** 4), rtol=1e-12)


@pytest.mark.parametrize("expr,want", [
    ("-2^2", 4.0), ("2^-2", 0.25), ("2^3^2", 512.0), ("3 - -2", 5.0), ("2*-3", -6.0), ("-(-3)", 3.0),
    (".5e1", 5.0), ("1.e2", 100.0), ("5E-1", 0.5), ("1e+2", 100.0), ("((((((1+2))))))*3", 9.0),
    ("select(2,5,6,7)", 6.0), ("select(0,4,5)", 2.0), ("select(1.6,7,8)", 8.0), ("if(-1,2,3)", 3.0),
    ("if(0,1,2)", 2.0), ("floor(-1.5)", -2.0), ("ceil(1.2)", 2.0), ("atan2(1,2)", 0.4636476090008061),
    ("log10(1000)", 3.0), ("(x-x)/(x-x)", 0.0), ("PI", np.pi), ("WE", 179.0), ("abs(-3)", 3.0), ("sq(3)", 9.0),
    ("max(1,5,2)", 5.0), ("min(4,2)", 2.0), ("f(2,3)", 2.0 - 3.0 * 3.0), ("xres+yres", 7.0),
])
def test_values_as_radiance_computes_them(expr, want):
    prog = calexpr.parse(f"f(a,b) = a - b*3; v = {expr};")
    got = prog.evaluate(["v"], xres=3, yres=4)["v"]
    np.testing.assert_allclose(got, want, rtol=1e-15)


def test_pixel_variables_and_inputs():
    prog = calexpr.parse("ro = x + 10*y; go = li(1); bo = ri(1)*gi(1) - bi(1); lo = 7;")
    rgb = np.arange(24, dtype=float).reshape(3, 4, 2).transpose(2, 0, 1)[:, :3, :4] if False else \
        (np.full((3, 4), 2.0), np.full((3, 4), 3.0), np.full((3, 4), 5.0))
    out = prog.evaluate(["ro", "go", "bo"], xres=4, yres=3, inputs=rgb)
    assert out["ro"][0, 0] == 20.0 and out["ro"][2, 3] == 3.0  # top row is y = 2
    np.testing.assert_allclose(out["go"], 0.265 * 2 + 0.670 * 3 + 0.065 * 5)
    np.testing.assert_allclose(out["bo"], 1.0)
    # pcomb: an undefined output is lo, or 0
    assert calexpr.parse("lo = 7;").evaluate(["go"], xres=1, yres=1)["go"][0, 0] == 7.0
    assert calexpr.parse("ro = 1;").evaluate(["bo"], xres=1, yres=1)["bo"][0, 0] == 0.0


@pytest.mark.parametrize("text,line,token", [
    ("a = 1;\nb = 3 $ 4;", 2, "$"),
    ("a = 1;\n\nb = 3 +;", 3, ";"),
    ("a = (3;", 1, ";"),
    ("a = 3\nb = 4;", 2, "b"),
    ("a = - -3;", 1, "-"),
    ("a = 3 < 4;", 1, "<"),
    ("{ x \n a = 1;", 1, "{"),
    ("a = 1; }", 1, "}"),
    ("x = 3;", 1, "x"),
    ("a = 2;\nb = foo(a);", 2, "foo"),
    ("b = c + 1;", 1, "c"),
    ("ro = ri(2);", 1, "ri(2"),
    ("f(a) = a; b = f(1, 2);", 1, "f()"),
    ("a = b; b = a;", 1, "a"),
    ("3 = a;", 1, "3"),
])
def test_anything_outside_the_language_is_one_line_naming_file_line_token(tmp_path, text, line, token):
    path = _write(tmp_path, "bad.cal", text)
    with pytest.raises(InputError) as err:
        prog = calexpr.parse_file(path)
        prog.evaluate(list(prog.definitions), xres=2, yres=2, inputs=(1.0, 1.0, 1.0))
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{path}, line {line}: ") and token in msg, msg


@pytest.mark.parametrize("text", [
    "a = " + "(" * 20001 + "1" + ")" * 20001 + ";",
    "a = " + "^".join(["x"] * 20002) + ";",
    "f(x) = f(x); a = f(1);",
    "f(x) = 1 + f(x - 1); a = f(x + 1);",
])
def test_deep_nesting_is_one_line_not_a_recursion_error(tmp_path, text):
    path = _write(tmp_path, "deep.cal", text)
    with pytest.raises(InputError) as err:
        calexpr.parse_file(path).evaluate(["a"], xres=2, yres=2)
    assert str(err.value).startswith(str(path)) and "\n" not in str(err.value)
    vig = _write(tmp_path, "vig.cal", text.replace("a = ", "r = ") + "ro=ri(1)*r; go=gi(1)*r; bo=bi(1)*r;")
    with pytest.raises(InputError):
        radcal.read_vignetting(vig)


def test_radcal_reports_the_language_error_with_file_line_and_token(tmp_path):
    path = _write(tmp_path, "vignetting_f5d6.cal", "sq(x)=x*x;\nr=sqrt(sq(x-500)+sq(y-500))/500;\nsf=1/(1+r#2);")
    with pytest.raises(InputError, match=r"vignetting_f5d6.cal, line 3: .*'#"):
        radcal.read_vignetting(path)


def test_large_coefficients_are_one_error_without_numpy_warnings(tmp_path, recwarn):
    """A valid file whose polynomial overflows outside the circle: no RuntimeWarning leaks
    (issue 29); the chain's check names the flag when the factor is not finite inside."""
    from hdrcl.core.luminance.fisheye import LuminanceChain

    text = LAB_VIG.replace("500", "32").replace("(-0.528613562104476)*(r^4)", "(1e-10)*(r^2500)")  # overflows outside
    path = _write(tmp_path, "big.cal", text)
    chain = LuminanceChain.from_options(lens_circle="32,32,64", resize=64, vignetting=str(path))
    assert chain.vignetting.program is not None
    assert not [w for w in recwarn.list if issubclass(w.category, RuntimeWarning)]
    bad = _write(tmp_path, "bad.cal", LAB_VIG.replace("500", "32").replace("(-0.528613562104476)*(r^4)",
                                                                          "(-1e300)*(r^4)"))
    with pytest.raises(UsageError, match="^--vignetting: .*bad.cal"):
        LuminanceChain.from_options(lens_circle="32,32,64", resize=64, vignetting=str(bad))
    assert not [w for w in recwarn.list if issubclass(w.category, RuntimeWarning)]


def test_vignetting_factors_the_output_cannot_hold_are_refused(tmp_path, recwarn):
    """1 / (1 + 1e300 r^8) is finite and positive but would underflow every value to 0."""
    from hdrcl.core.luminance.fisheye import LuminanceChain

    path = _write(tmp_path, "tiny.cal", LAB_VIG.replace("500", "32").replace("(-0.528613562104476)*(r^4)",
                                                                            "(1e300)*(r^8)"))
    with pytest.raises(UsageError, match=r"^--vignetting \(.*tiny.cal"):
        LuminanceChain.from_options(lens_circle="32,32,64", resize=64, vignetting=str(path))
    assert not [w for w in recwarn.list if issubclass(w.category, RuntimeWarning)]


def test_a_file_made_for_another_size_is_warned_about(tmp_path, caplog):
    from hdrcl.core.luminance.fisheye import LuminanceChain

    path = _write(tmp_path, "vignetting_f5d6.cal", LAB_VIG)
    with caplog.at_level("WARNING", logger="hdrcl"):
        LuminanceChain.from_options(lens_circle="400,400,800", resize=1000, vignetting=str(path))
    assert not [r for r in caplog.records if r.levelname == "WARNING"]
    with caplog.at_level("WARNING", logger="hdrcl"):
        LuminanceChain.from_options(lens_circle="400,400,800", resize=800, vignetting=str(path))
    msgs = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(msgs) == 1 and "vignetting_f5d6.cal" in msgs[0] and "1000-pixel" in msgs[0] and "800x800" in msgs[0]


def test_chain_applies_the_lab_vignetting_file_as_pcomb(tmp_path):
    """The file's factors on the resized map, x = column and y = N-1-row."""
    from hdrcl.core.luminance.fisheye import LuminanceChain

    n = 40
    text = LAB_VIG.replace("500", "20")
    path = _write(tmp_path, "v.cal", text)
    chain = LuminanceChain.from_options(lens_circle=f"{n / 2},{n / 2},{n}", resize=n, vignetting=str(path))
    img = np.ones((n, n, 3), np.float32) * 100.0
    chain.bind(n, n, 3)
    chain.write_rows(0, n, img)
    out = chain.finish()
    i, j = 5, 30
    r = np.hypot(j - 20, (n - 1 - i) - 20) / 20
    np.testing.assert_allclose(out[i, j], 100.0 * _lab_poly(r), rtol=1e-6)


# -- range checks of issue 29 --------------------------------------------------------------

@pytest.mark.parametrize("k", ["1e300", "1e38", "1e-300", "1e30"])
def test_calibration_factor_out_of_what_the_format_holds_is_refused(tmp_path, k):
    with pytest.raises(UsageError, match="^--calibration-factor: ") as err:
        radcal.calibration_factor_option(k)
    assert "\n" not in str(err.value)
    path = _write(tmp_path, "K.cal", f"ro=ri(1)*{k}; go=gi(1)*{k}; bo=bi(1)*{k};")
    with pytest.raises(UsageError, match="^--calibration-factor: "):
        radcal.calibration_factor_option(str(path))


def test_factor_range_follows_the_output_format():
    assert radcal.check_factor_range(1.18, output="o.hdr") == 1.18
    with pytest.raises(UsageError, match=r"\.hdr"):
        radcal.check_factor_range(1e-30, output="o.hdr")  # 1e-36 / 179 is below RGBE's smallest
    from hdrcl.core.luminance.fisheye import LuminanceChain

    with pytest.raises(UsageError, match="^--nd-filter with --calibration-factor: "):
        LuminanceChain.from_options(lens_circle="10,10,20", resize=20, nd_filter="1e20,1,1", calibration_factor="1e10")
    # with the output known, its format's range: 1e-30 fits float32 (an EXR) but not RGBE's /179
    LuminanceChain.from_options(lens_circle="10,10,20", resize=20, calibration_factor="1e-30", output="o.exr")
    with pytest.raises(UsageError, match=r"^--calibration-factor: .*\.hdr"):
        LuminanceChain.from_options(lens_circle="10,10,20", resize=20, calibration_factor="1e-30", output="o.hdr")


@pytest.mark.parametrize("view", ["-vtv -vh 180 -vv 180", "-vth -vh 181 -vv 180", "-vta -vh 361 -vv 180",
                                  "-vtc -vh 360 -vv 180", "-vts -vh 360 -vv 100", "-vtv -vh 90 -vv 0",
                                  "-vta -vd 0 0 0", "-vta -vu 0 1 0", "-vta -vd 0 0 1"])
def test_views_radiance_rejects_are_refused(view):
    from hdrcl.core.luminance.fisheye import parse_view

    with pytest.raises(UsageError, match="^--view: "):
        parse_view(view)


@pytest.mark.parametrize("view", ["-vtv -vh 179 -vv 179", "-vth -vh 180 -vv 180", "-vta -vh 360 -vv 360",
                                  "-vtc -vh 360 -vv 179.9", "-vts -vh 359 -vv 359", "-vta -vh 186 -vv 186"])
def test_views_radiance_takes_are_taken(view):
    from hdrcl.core.luminance.fisheye import parse_view

    assert parse_view(view)[0] == view


def test_huge_lens_circle_names_the_option():
    from hdrcl.core.luminance.fisheye import LuminanceChain

    with pytest.raises(UsageError, match="^--lens-circle: "):
        LuminanceChain.from_options(lens_circle="100,66,1e9", resize=64)
    chain = LuminanceChain.from_options(lens_circle="100,66,90000", resize=64)
    with pytest.raises(UsageError, match="^--lens-circle: the diameter"):
        chain.bind(426, 640, 3)


# -- Radiance as the oracle -----------------------------------------------------------------

_F1 = ("sin", "cos", "atan", "floor", "ceil")


def _random_expr(rng: random.Random, depth: int) -> str:
    if depth <= 0 or rng.random() < 0.2:
        return rng.choice(["x", "y", f"{rng.uniform(0.1, 9):.6g}", f"{rng.randint(1, 9)}", "PI",
                           f"{rng.uniform(1, 9):.3g}e-1", f".{rng.randint(1, 99)}"])
    a, b = _random_expr(rng, depth - 1), _random_expr(rng, depth - 1)
    kind = rng.randrange(12)
    if kind < 4:
        return f"({a}{rng.choice('+-*')}{b})"
    if kind == 4:
        return f"({a})/(1.5+sq({b}))"
    if kind == 5:
        return f"-({a})"
    if kind == 6:
        return f"(1.1+sin({a}))^({b}/(9+abs({b})))"
    if kind == 7:
        return f"{rng.choice(_F1)}({a})"
    if kind == 8:
        return f"sqrt(1+sq({a}))+log(2+sq({b}))+exp(-sq({a})/10)"
    if kind == 9:
        return f"if({a}-{b},{a},{b})"
    if kind == 10:
        return f"atan2({a},1+sq({b}))"
    return f"select(1+floor(abs(sin({a}))*2.99),{a},{b},3)"


def test_random_expressions_equal_radiance_rcalc(radiance_bin):
    """rcalc and pcomb share Radiance's calc library (calexpr.c, calfunc.c); rcalc prints
    9 significant digits, so the two agree to 1e-6 relative where pcomb's RGBE cannot."""
    rng = random.Random(28)
    defs = "sq(a)=a*a; abs(a)=if(a,a,-a);"  # pcomb has neither: rayinit.cal's definitions
    exprs = [_random_expr(rng, 4) for _ in range(60)]
    pts = [(rng.uniform(-3, 3), rng.uniform(-3, 3)) for _ in range(25)]
    stdin = "".join(f"{x!r} {y!r}\n" for x, y in pts)
    checked = 0
    for e in exprs:
        run = subprocess.run([str(radiance_bin / "rcalc"), "-e", defs + "x=$1;y=$2;", "-e", f"$1={e}"],
                             input=stdin, capture_output=True, text=True, timeout=60)
        assert run.returncode == 0, (e, run.stderr)
        want = np.array([float(v) for v in run.stdout.split()])
        prog = calexpr.parse(f"v = {e};")
        got = prog.evaluate(["v"], xres=1, yres=1, x=np.array([p[0] for p in pts]),
                            y=np.array([p[1] for p in pts]))["v"]
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-8, err_msg=e)
        checked += want.size
    assert checked == 60 * 25


def _read_hdr_floats(path, radiance_bin):
    """Radiance's own decoding of a picture (pvalue -h -H -df, rows top to bottom)."""
    out = subprocess.run([str(radiance_bin / "pvalue"), "-h", "-H", "-df", str(path)], capture_output=True,
                         timeout=60, check=True).stdout
    return np.frombuffer(out, np.float32)


def test_pcomb_coordinates_and_inputs_equal_ours(tmp_path, radiance_bin):
    """pcomb on a picture with the lab's vignetting file: x = column, y from the bottom;
    equal to hdrcl's evaluation within RGBE's quantisation (1/256 of a pixel's largest channel)."""
    w, h = 37, 23
    rng = np.random.default_rng(3)
    src = rng.uniform(0.5, 4.0, (h, w, 3)).astype(np.float32)
    inp = tmp_path / "in.hdr"
    _write_rgbe_via_pvalue(inp, src, radiance_bin)
    decoded = _read_hdr_floats(inp, radiance_bin).reshape(h, w, 3).astype(np.float64)
    cal = _write(tmp_path, "v.cal", LAB_VIG.replace("sq(x-500)+sq(y-500))/500", "sq(x-18)+sq(y-11))/30") +
                 "\n{ position terms }\nro = sf*ri(1)*(1+x/10); go = sf*gi(1)*(1+y/10); bo = li(1);")
    out = tmp_path / "out.hdr"
    with open(out, "wb") as f:
        subprocess.run([str(radiance_bin / "pcomb"), "-f", str(cal), str(inp)], stdout=f, check=True, timeout=60)
    want = _read_hdr_floats(out, radiance_bin).reshape(h, w, 3)
    prog = calexpr.parse_file(cal)
    got = prog.evaluate(["ro", "go", "bo"], xres=w, yres=h, inputs=(decoded[..., 0], decoded[..., 1], decoded[..., 2]))
    got = np.stack([got["ro"], got["go"], got["bo"]], -1)
    tol = got.max(axis=-1, keepdims=True) / 128.0
    assert np.all(np.abs(got - want) <= tol), float(np.max(np.abs(got - want) / tol))


def _write_rgbe_via_pvalue(path, img, radiance_bin):
    h, w, _ = img.shape
    with open(path, "wb") as f:
        subprocess.run([str(radiance_bin / "pvalue"), "-r", "-h", "-df", "-y", str(h), "+x", str(w)],
                       input=img.astype(np.float32).tobytes(), stdout=f, check=True, timeout=60)


def test_a_function_chain_is_evaluated_and_endless_recursion_is_one_error_line(tmp_path):
    """call_function (--fisheye-projection's rad(r)): 190 chained functions are evaluated
    (Radiance does; a RecursionError once), a rad() that calls itself forever is one line."""
    lines = ["f0(r) = r;"] + [f"f{i}(r) = f{i - 1}(r)+0+0+0+0+0+0+0+0;" for i in range(1, 190)] + ["rad(r) = f189(r);"]
    prog = calexpr.parse_file(_write(tmp_path, "deep.cal", "\n".join(lines)))
    r = np.linspace(0, 0.5, 5)
    np.testing.assert_array_equal(calexpr.call_function(prog, "rad", r), r)
    prog = calexpr.parse_file(_write(tmp_path, "endless.cal", "rad(r) = if(r - 1, 1, rad(r * 0.5 + 0.25));"))
    with pytest.raises(InputError, match="endless.cal, line 1: rad\\(\\) calls itself more than") as err:
        calexpr.call_function(prog, "rad", r)
    assert "\n" not in str(err.value)
