"""Issue 34: the .cal language follows Radiance's rules, with Radiance's own rcalc and pcomb
as the oracle: if/select compute only the branch taken, recursion, errors inside a
function's arguments, Radiance's parse-time refusals, any nesting depth, and files whose
comments are not UTF-8."""
import logging
import subprocess

import numpy as np
import pytest

from hdrcl.errors import InputError
from hdrcl.io import calexpr, radcal

PTS = [(1.0, 2.0), (3.0, 4.0), (0.25, -1.5), (2.0, 0.5), (7.0, 3.0)]


def _rcalc(radiance_bin, text, pts=PTS):
    """rcalc's $1 of ``v`` for each (x, y) (``z`` = 0 at run time); its stderr; its status."""
    run = subprocess.run([str(radiance_bin / "rcalc"), "-e", "x=$1;y=$2;z=x-x;" + text, "-e", "$1=v"],
                         input="".join(f"{x!r} {y!r}\n" for x, y in pts), capture_output=True, text=True,
                         timeout=60)
    vals = np.array([float(v) for v in run.stdout.split()]) if run.returncode == 0 else None
    return vals, run.stderr, run.returncode


def _ours(text, pts=PTS):
    prog = calexpr.parse("z = x - x;" + text)
    xs, ys = (np.array([p[i] for p in pts]) for i in (0, 1))
    return prog.evaluate(["v"], xres=1, yres=1, x=xs, y=ys)["v"]


@pytest.mark.parametrize("text", [
    # only the branch taken is computed (select out of range in the branch not taken)
    "v = if(x - 2, select(x*10, 1, 1), x);",
    "v = if(x - 2.5, x, select(x*10, 1, 2));",
    # out of range where taken: 0 (rcalc: "select(): domain error"), and if() around it 0
    "v = select(x, 5, 6) + 1;",
    "v = if(x - 2, select(5*x, 1, 2), 7);",
    "v = select(x - 0.5, 10, 20, 30) + select(-0.4*x, 8, 9);",
    # recursion
    "fact(n) = if(n - 1.5, n*fact(n - 1), 1); v = fact(5);",
    "fact(n) = if(n - 1.5, n*fact(n - 1), 1); v = fact(floor(x) + 2);",
    "fib(n) = if(n - 1.5, fib(n - 1) + fib(n - 2), 1); v = fib(floor(x) + 3);",
    # a division by 0 inside a library function's arguments: the whole call is 0
    "v = sin(x/z + 1);",
    "f(a) = a + 1; v = f(x/z);",
    "f(a) = a + 1; v = sin(f(x/z)) + 5;",
    "v = max(x/z, 5) + 1;",
    "h(a) = a; v = max(x/z, sin(x)) + max(x/z, h(x)) + sin(x/z + sin(x)) + (x/z + x^y)^2;",
    "v = if(x - 2, 5, x/z);",
    "v = if(x/z, 5, 6);",
    "v = (x/z + 1)^2;",
    "v = (x/z + 1)^1 + 1^(x/z) + (x/z)^0;",
    "w = x/z + 1; v = sin(w) + w;",
    "v = floor(x/z) + atan2(x/z, 1) + select(x, x/z, 3);",
    "g(a, b) = if(a, b, 0); v = sin(g(x - 2, x/z) + 1);",
    # Radiance drops 0*E, E*0, 0/E, 0^E without computing E
    "v = sin(x + 0*sin(x/z)) + 5 + sin(x + (x/z)*0) + 0/z + 0^(x/z);",
    "a : 0; v = sin(x + a*sin(x/z));",
    # NaN and infinities as Radiance's C library gives them
    "v = (-8*x)^(1/3);",
    "v = sqrt(-x) + log(z) + 1;",
    # any depth
    "v = " + "(" * 400 + "x" + ")" * 400 + ";",
    "v = " + "+".join(["x*0.5"] * 5000) + ";",
    "f(a) = a*1.001; v = " + "f(" * 400 + "x" + ")" * 400 + ";",
])
def test_values_equal_rcalc(radiance_bin, text):
    want, err, rc = _rcalc(radiance_bin, text)
    assert rc == 0, err
    np.testing.assert_allclose(_ours(text), want, rtol=1e-6, atol=1e-8, equal_nan=True, err_msg=text)


@pytest.mark.parametrize("text,why", [
    ("v = sin(1/0 + 1);", "bad constant expression"),
    ("v = x/0;", "divide by zero constant"),
    ("v = x/(1 - 1);", "divide by zero constant"),
    ("v = if(x, 1, select(5, 1, 2));", "bad constant expression"),
    ("v = 1e;", "missing exponent"),
    ("v = 2.5E+ * x;", "missing exponent"),
])
def test_what_rcalc_refuses_is_refused(radiance_bin, text, why):
    _, err, rc = _rcalc(radiance_bin, text)
    assert rc != 0 and why in err
    with pytest.raises(InputError) as exc:
        _ours(text)
    msg = str(exc.value)
    assert msg.startswith("<expression>, line 1: ") and "\n" not in msg
    assert why in msg or why == "missing exponent" and "missing exponent" in msg


def test_select_out_of_range_warns_once(radiance_bin, caplog):
    """rcalc prints 'select(): domain error' per record; hdrcl warns once per cause,
    naming the file, the line, the count and what the value is."""
    text = "v = if(x - 2, select(x*10, 1, 2), 3);"
    _, err, _ = _rcalc(radiance_bin, text)
    assert "select(): domain error" in err
    prog = calexpr.parse("\n" + text, "v.cal")
    with caplog.at_level(logging.WARNING, logger="hdrcl"):
        for _ in range(3):
            got = prog.evaluate(["v"], xres=1, yres=1, x=np.array([1.0, 3.0, 4.0]), y=np.zeros(3))["v"]
    np.testing.assert_array_equal(got, [3.0, 0.0, 0.0])
    msgs = [r.getMessage() for r in caplog.records]
    assert len(msgs) == 1 and msgs[0].startswith("v.cal, line 2: select() index out of 0..2 at 2 of 3 pixels"), msgs


VIG = """{ gemessen von Jürgen, 21 °C }
sq(x)=x*x;
r=sqrt(sq(x-18)+sq(y-11))/30;
sf=1/(1 + 0.1*r^2 - 0.02*r^4);
ro=sf*ri(1);
go=sf*gi(1)*(1+x/40);
bo=sf*bi(1);
"""


def _pcomb(radiance_bin, cal, inp):
    out = subprocess.run([str(radiance_bin / "pcomb"), "-f", str(cal), str(inp)], capture_output=True,
                         check=True, timeout=60).stdout
    return np.frombuffer(subprocess.run([str(radiance_bin / "pvalue"), "-h", "-H", "-df"], input=out,
                                        capture_output=True, check=True, timeout=60).stdout, np.float32)


def test_a_latin1_comment_reads_as_pcomb_reads_it(tmp_path, radiance_bin):
    """The lab's vignetting file saved by a Latin-1 editor was "not a text .cal file"
    (exit 3); pcomb -f reads it, with the same pixels as the UTF-8 copy."""
    latin, utf = tmp_path / "vignetting_latin1.cal", tmp_path / "vignetting_utf8.cal"
    latin.write_bytes(VIG.encode("latin-1"))
    utf.write_bytes(VIG.encode("utf-8"))
    w, h = 37, 23
    img = np.random.default_rng(5).uniform(0.5, 4.0, (h, w, 3)).astype(np.float32)
    inp = tmp_path / "in.hdr"
    with open(inp, "wb") as f:
        subprocess.run([str(radiance_bin / "pvalue"), "-r", "-h", "-df", "-y", str(h), "+x", str(w)],
                       input=img.tobytes(), stdout=f, check=True, timeout=60)
    want = _pcomb(radiance_bin, latin, inp)
    np.testing.assert_array_equal(want, _pcomb(radiance_bin, utf, inp))
    vl, vu = radcal.read_vignetting(latin), radcal.read_vignetting(utf)
    np.testing.assert_array_equal(vl.factors(64), vu.factors(64))
    held = _pcomb(radiance_bin, tmp_path / "ident.cal", inp) if (tmp_path / "ident.cal").write_text(
        "ro=ri(1);go=gi(1);bo=bi(1);") else None
    held = held.reshape(h, w, 3).astype(np.float64)
    got = calexpr.parse_file(latin).evaluate(["ro", "go", "bo"], xres=w, yres=h,
                                             inputs=tuple(held[..., c] for c in range(3)))
    got = np.stack([got["ro"], got["go"], got["bo"]], -1)
    assert np.all(np.abs(got - want.reshape(h, w, 3)) <= got.max(axis=-1, keepdims=True) / 128.0)
    binary = tmp_path / "photo.cal"
    binary.write_bytes(b"\xff\xd8\xff\xe0\0\x10JFIF\0")
    with pytest.raises(InputError, match="photo.cal: not a text .cal file"):
        radcal.read_vignetting(binary)


def test_branches_not_taken_do_not_fail_the_files(tmp_path):
    """sf = if(r-2, select(r*10,1,1), ...) and rad(r) = if(r-10, select(r*100,1,2),
    mapsolid(r)) were exit 3 "select() index out of 0..2" for a branch never taken."""
    vig = tmp_path / "v.cal"
    vig.write_text("sq(x)=x*x; r=sqrt(sq(x-32)+sq(y-32))/32;\nsf = if(r-2, select(r*10,1,1), 1/(1+0.1*r^2));\n"
                   "ro=sf*ri(1); go=sf*gi(1); bo=sf*bi(1);")
    f = radcal.read_vignetting(vig).factors(64)
    r = np.hypot(np.arange(64)[None, :] - 32, (63 - np.arange(64))[:, None] - 32) / 32
    np.testing.assert_allclose(f[..., 0], np.where(r > 2, 1.0, 1 / (1 + 0.1 * r ** 2)), rtol=1e-12)
    proj = tmp_path / "p.cal"
    proj.write_text("mapsolid(r) : 2/PI*asin(sqrt(2)*r);\nrad(r) = if(r-10, select(r*100,1,2), mapsolid(r));")
    p = radcal.read_projection(proj)
    rd = np.linspace(0, 0.5, 11)
    np.testing.assert_allclose(calexpr.call_function(p.program, "rad", rd), 2 / np.pi * np.arcsin(np.sqrt(2) * rd))


def test_a_negative_number_to_a_fractional_power_is_named(tmp_path, radiance_bin):
    """(-8)^(1/3) is NaN (rcalc prints nan): the factor file's error says so, not that it
    "depends on the pixel position"."""
    want, _, rc = _rcalc(radiance_bin, "v = (-8)^(1/3);")
    assert rc == 0 and np.all(np.isnan(want))
    path = tmp_path / "CF.cal"
    path.write_text("{ K }\nk : (-8)^(1/3);\nro=ri(1)*k; go=gi(1)*k; bo=bi(1)*k;\n")
    for read in (radcal.read_calibration_factor, radcal.read_nd_filter, radcal.read_vignetting):
        with pytest.raises(InputError) as err:
            read(path)
        msg = str(err.value)
        assert msg.startswith(f"{path}, line 2: ((-8)^(1/3)) raises a negative number to a fractional power"), msg
        assert "pixel position" not in msg and "\n" not in msg


def _random_expr(rng, depth: int) -> str:
    """Expressions that reach Radiance's rules: division by a zero known only at run time,
    select() indices out of range, if() on both sides, recursion."""
    if depth <= 0 or rng.random() < 0.2:
        return rng.choice(["x", "y", "z", f"{rng.uniform(0.1, 9):.4g}", f"{rng.randint(1, 4)}"])
    a, b = _random_expr(rng, depth - 1), _random_expr(rng, depth - 1)
    return rng.choice([
        f"({a}+{b})", f"({a}-{b})", f"({a}*{b})", f"({a})/({b})", f"({a})/(z)", f"sin({a})", f"atan({b})",
        f"if({a}-{b},{a},{b})", f"select(floor(abs({a}))*0.5,{a},{b},1)", f"f({a})", f"g({a},{b})",
        f"fact(floor(abs(sin({a}))*6))", f"max({a},{b})", f"floor({a})",
    ])


def test_random_expressions_with_radiance_rules_equal_rcalc(radiance_bin):
    """100 random expressions over 12 points: hdrcl's values are rcalc's (NaN where rcalc
    prints nan)."""
    import random

    rng = random.Random(34)
    defs = "abs(a)=if(a,a,-a); f(a)=sin(a)+a/(z+1); g(a,b)=if(a,b,a/z); fact(n)=if(n-0.5,n*fact(n-1),1);"
    pts = [(rng.uniform(-3, 3), rng.uniform(-3, 3)) for _ in range(12)]
    for _ in range(100):
        text = defs + f"v = {_random_expr(rng, 4)};"
        want, err, rc = _rcalc(radiance_bin, text, pts)
        if rc != 0:  # Radiance refuses it at parse time (a constant select out of range): so do we
            with pytest.raises(InputError):
                _ours(text, pts)
            continue
        with np.errstate(all="ignore"):
            np.testing.assert_allclose(_ours(text, pts), want, rtol=1e-6, atol=1e-8, equal_nan=True, err_msg=text)
