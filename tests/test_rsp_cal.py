"""hdrgen .rsp responses (read, write, round trip) and the three Radiance .cal forms."""
import numpy as np
import pytest

from hdrcl.core.response import Response
from hdrcl.errors import InputError, UsageError
from hdrcl.io import radcal
from hdrcl.io.rsp import FIT_TOLERANCE, g_from_polynomial, rsp_text

# hdrgen's form: "N cN ... c1 c0" per channel, p(1) = 1.
RSP = ("3 0.6317 0.2405 0.1278 0.0\n"
       "4 -0.1052 0.7291 0.2514 0.1247 0.0\n"
       "3 0.5922 0.2791 0.1287 0.0\n")


def _poly(line):
    f = line.split()
    return [float(v) for v in f[1:]][::-1]  # c0 .. cN


def test_rsp_read_gives_ln_polynomial_normalised_at_mid_grey(tmp_path):
    path = tmp_path / "cam.rsp"
    path.write_text(RSP)
    resp = Response.load(path)
    assert resp.bits == 8 and resp.channels == ("R", "G", "B")
    x = np.arange(256) / 255.0
    for c, line in enumerate(RSP.splitlines()):
        p = np.polynomial.polynomial.polyval(x, _poly(line))
        want = np.log(p[1:]) - np.log(p[128])
        np.testing.assert_allclose(resp.g[c, 1:], want, rtol=0, atol=1e-12)
        assert resp.g[c, 128] == 0.0
    # p(0) = 0: code 0 gets the straight line to 0 from code 1, p(0) = p(1/255) / 3
    p1 = np.polynomial.polynomial.polyval(1 / 255.0, _poly(RSP.splitlines()[0]))
    p_mid = np.polynomial.polynomial.polyval(128 / 255.0, _poly(RSP.splitlines()[0]))
    assert resp.g[0, 0] == pytest.approx(np.log(p1 * 0.5 / 1.5 / p_mid), abs=1e-12)


def test_rsp_negative_near_black_extends_linearly():
    coeffs = [-0.004, 0.3, 0.5, 0.204]  # p < 0 below code ~3
    g = g_from_polynomial(coeffs)
    assert np.all(np.isfinite(g)) and np.all(np.diff(g) > 0)
    x = np.arange(256) / 255.0
    p = np.polynomial.polynomial.polyval(x, coeffs)
    z1 = int(np.flatnonzero(p <= 0)[-1]) + 1
    np.testing.assert_allclose(np.exp(g[:z1] - g[z1]), (np.arange(z1) + 0.5) / (z1 + 0.5), rtol=1e-12)


def test_rsp_round_trip(tmp_path):
    src = tmp_path / "cam.rsp"
    src.write_text(RSP)
    first = Response.load(src)
    out = tmp_path / "again.rsp"
    fit = first.save(out)
    assert max(fit.max_error) < 1e-6  # a polynomial is fitted exactly by its own order
    again = Response.load(out)
    np.testing.assert_allclose(again.g[:, 1:], first.g[:, 1:], atol=1e-6)


def _srgb_response():
    """A camera JPEG's curve (sRGB decoding) in every channel."""
    z = np.arange(256.0) / 255.0
    lin = np.where(z <= 0.04045, z / 12.92, ((z + 0.055) / 1.055) ** 2.4)
    g = np.log(np.maximum(lin, 1e-4))
    g = np.stack([g - g[128]] * 3)
    return Response(bits=8, g=g, knots=np.arange(256.0))


def test_rsp_write_of_a_camera_curve_states_its_fit_error(tmp_path):
    resp = _srgb_response()
    text, fit = rsp_text(resp.tables(), resp.levels)
    lines = text.splitlines()
    assert len(lines) == 3 and [int(v.split()[0]) for v in lines] == fit.orders
    assert all(3 <= o <= 6 for o in fit.orders) and max(fit.max_error) <= FIT_TOLERANCE
    path = tmp_path / "camera.rsp"
    resp.save(path)
    back = Response.load(path)
    t = resp.tables()
    err = np.abs((back.g - back.g[:, -1:]) - (t - t[:, -1:]))[:, 10:246].max(axis=1)
    np.testing.assert_allclose(err, fit.max_error, rtol=1e-9, atol=1e-12)  # the error stated is the error


@pytest.mark.parametrize("text", ["", "3 0.5 0.5\n", "x 1 2 3 4\n", "3 0.5 0.3 0.2 0\n3 0.5 0.3 0.2 0\n",
                                  "2 -1.0 0.5 0.0\n"])
def test_rsp_refuses_other_forms(tmp_path, text):
    path = tmp_path / "bad.rsp"
    path.write_text(text)
    with pytest.raises(InputError, match="bad.rsp"):
        Response.load(path)


VIG = """{ Sigma 8mm, measured }
r = sqrt(sq(x-500)+sq(y-500))/500;
sf = 1/(-1.2e-3*r^8 + 0.05*r^7 - 0.21*r^6 + 0.32*r^5
        - 0.2*r^4 + 0.03*r^3 - 0.1*r^2 + 0.01*r + 1);
ro = sf*ri(1); go = sf*gi(1);
bo = sf*bi(1);
"""


def test_cal_readers_on_their_forms(tmp_path):
    v = tmp_path / "vig.cal"
    v.write_text(VIG)
    got = radcal.read_vignetting(v)
    assert (got.xc, got.yc, got.radius) == (500.0, 500.0, 500.0)
    a = (1.0, 0.01, -0.1, 0.03, -0.2, 0.32, -0.21, 0.05, -1.2e-3)
    f = got.factors(1000)
    # pcomb's coordinates: x = column, y = 999 - row (0 at the bottom)
    for row, col in ((0, 0), (499, 500), (100, 730), (999, 3)):
        r = np.hypot(col - 500, (999 - row) - 500) / 500
        np.testing.assert_allclose(f[row, col], 1 / np.polyval(a[::-1], r), rtol=1e-12)
    nd = tmp_path / "nd.cal"
    nd.write_text("ro=812.3*ri(1);\n go = 905.1 * gi(1) ; bo=1.1e3*bi(1);")
    assert radcal.read_nd_filter(nd) == (812.3, 905.1, 1100.0)
    k = tmp_path / "k.cal"
    k.write_text("{ meter: LS-110 }\nro=ri(1)*1.18; go=gi(1)*1.18; bo=bi(1)*1.18;\n")
    assert radcal.read_calibration_factor(k) == 1.18
    # the options take the files or the numbers
    assert radcal.calibration_factor_option(str(k)) == 1.18
    assert radcal.calibration_factor_option("1.21") == 1.21
    assert radcal.nd_filter_option("800,900,1e3") == (800.0, 900.0, 1000.0)
    assert radcal.vignetting_option("0.1,-0.2").coefficients == (1.0, 0.1, -0.2) + (0.0,) * 6


R_LINE = "r = sqrt(sq(x-500)+sq(y-500))/500;"
TAIL = "ro=sf*ri(1); go=sf*gi(1); bo=sf*bi(1);"


@pytest.mark.parametrize("reader,text", [
    (radcal.read_vignetting, "r = sqrt(sq(x-500)+sq(y-500))/0; sf = 1/(0.1*r^2 + 1);" + TAIL),  # radius 0
    (radcal.read_vignetting, "ro=ri(1)*1.2; go=gi(1)*1.2; bo=bi(1)*1.2;"),  # no position
    (radcal.read_vignetting, R_LINE + "sf = 1/(0.1*r^2 + 1);" + "ro=sf*ri(1)+0.1; go=sf*gi(1); bo=sf*bi(1);"),
    (radcal.read_vignetting, R_LINE + "sf = 1/(0.1*r^2 + 1);" + "ro=sf*gi(1); go=sf*gi(1); bo=sf*bi(1);"),
    (radcal.read_vignetting, R_LINE + "sf = 1/(0.1*r^2 + 1) ro=sf*ri(1);"),  # ';' missing
    (radcal.read_nd_filter, "ro=812*ri(1); go=905*gi(1);"),
    (radcal.read_nd_filter, "ro=812*ri(1)+1; go=905*gi(1); bo=1000*bi(1);"),
    (radcal.read_nd_filter, "ro=-812*ri(1); go=905*gi(1); bo=1000*bi(1);"),
    (radcal.read_nd_filter, "ro=x*ri(1); go=905*gi(1); bo=1000*bi(1);"),  # depends on the position
    (radcal.read_nd_filter, "ro=li(1); go=gi(1); bo=bi(1);"),  # not a factor of its channel
    (radcal.read_calibration_factor, "ro=ri(1)*1.18; go=gi(1)*1.2; bo=bi(1)*1.18;"),
    (radcal.read_calibration_factor, "ro=ri(1)*1.18; go=gi(1)*1.18; bo=bi(1)*1.18; { unclosed"),
    (radcal.read_calibration_factor, "ro=ri(1)*K; go=gi(1)*K; bo=bi(1)*K;"),  # K undefined
    (radcal.read_calibration_factor, "ro=ri(1)*1.18; go=gi(1)*1.18; bo=bi(1)*1.18 $"),
    (radcal.read_calibration_factor, "ro=ri(1)*1.18; go=gi(1)*1.18; bo=bi(1)*1.18 }"),
    (radcal.read_calibration_factor, "ro=ri(2)*1.18; go=gi(1)*1.18; bo=bi(1)*1.18;"),
    (radcal.read_calibration_factor, "ro=foo(1)*1.18; go=gi(1)*1.18; bo=bi(1)*1.18;"),
])
def test_cal_readers_refuse_other_forms_in_one_line(tmp_path, reader, text):
    path = tmp_path / "other.cal"
    path.write_text(text)
    with pytest.raises(InputError) as err:
        reader(path)
    msg = str(err.value)
    assert msg.startswith(str(path)) and "\n" not in msg


@pytest.mark.parametrize("option,value,flag", [
    (radcal.vignetting_option, "0.1,x", "--vignetting"),
    (radcal.vignetting_option, ",".join(["0.1"] * 9), "--vignetting"),
    (radcal.nd_filter_option, "800,900", "--nd-filter"),
    (radcal.nd_filter_option, "800,-900,1000", "--nd-filter"),
    (radcal.calibration_factor_option, "0", "--calibration-factor"),
    (radcal.calibration_factor_option, "1.2,1.3", "--calibration-factor"),
])
def test_inline_values_refused_name_the_flag(option, value, flag):
    with pytest.raises(UsageError, match=f"^{flag}: "):
        option(value)


def test_missing_cal_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="nope.cal"):
        radcal.nd_filter_option(str(tmp_path / "nope.cal"))


def test_rsp_with_huge_coefficients_is_one_error_without_numpy_warnings(tmp_path):
    """Issue 29: 1e308 coefficients printed two NumPy overflow warnings before the error."""
    import warnings

    path = tmp_path / "huge.rsp"
    path.write_text("3 1e308 1e308 1e308 0.0\n" * 3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError) as err:
            Response.load(path)
    msg = str(err.value)
    assert msg.startswith(str(path)) and "\n" not in msg and "overflows" in msg
