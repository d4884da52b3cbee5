"""User projections: --fisheye-projection FILE.cal with rad(r) as Radiance's fisheye_corr.cal,
and the .cal language's pcomb offsets ri(1, dx, dy) against pcomb itself."""
import subprocess

import numpy as np
import pytest

from hdrcl.core.luminance import fisheye_math as fm
from hdrcl.core.luminance.fisheye import LuminanceChain
from hdrcl.errors import InputError, UsageError
from hdrcl.io import calexpr, radcal

# Radiance's fisheye_corr.cal as radiantlab/HDRICalibrationTool ships it
# (submodules/radiance_pipeline/Inputs/Parameters/fisheye_corr.cal), unchanged.
FISHEYE_CORR = """{ RCSid $Id: fisheye_corr.cal,v 1.5 2016/09/14 20:39:08 greg Exp $ }
{
\tCorrect fisheye image using a distortion function:

\t\trad(r) =\tfunction of r in [0,.5] range, returing same

\tThis function takes the pixel distance from the image center, where
\t1.0 is the full width of the image constituting 180-degrees of view.
\tThe output is the corrected distance from the center for the output.
\t(If your function is the inverse of this, set map_inverse=1.)

\t\tpcomb -f fisheye_corr.cal -e 'rad(r)=my_function(r)' \\
\t\t\t-o fisheye.hdr > corrected.hdr

\tWe also clear the region outside the r=[0,.5] circle to black.
\tIf this is all you want to do, use "rad(r)=r".

\tIf you know you have a solid-angle preserving distortion, use
\t"rad(r)=mapsolid(r)" or leave off definition, as this is the default.

\tNote that you will need to add back the VIEW= line to the header, e.g.:

\t\techo "VIEW= -vta -vh 180 -vv 180" > corrected.hdr
\t\t(above_command) >> corrected.hdr

\tOr:

\t\t(above_command) | getinfo -a "VIEW= -vta -vh 180 -vv 180" \\
\t\t\t> corrected.hdr
}
xc : xres/2;
yc : yres/2;
sq(x) : x*x;
map_inverse = -1;\t\t{ change to 1 if rad(r) is inverse mapping }
inp_r = sqrt(sq((x-xc)/xres) + sq((y-yc)/yres));
mapped_r = rad(inp_r);
rmult = if(map_inverse, inp_r/(mapped_r+1e-7), mapped_r/(inp_r+1e-7));
xoff = (x-xc)*(1-rmult);
yoff = (y-yc)*(1-rmult);
ro = if(.5-inp_r, ri(1,xoff,yoff), 1);
go = if(.5-inp_r, gi(1,xoff,yoff), 1);
bo = if(.5-inp_r, bi(1,xoff,yoff), 1);

{ Radius adjustment for equisolid-angle projection to equidistant (-vta) }
mapsolid(r) : 2/PI*asin(sqrt(2)*r);

{ Default correction function }
rad(r) = mapsolid(r);
"""


def _sky(n=96, seed=4):
    rng = np.random.default_rng(seed)
    img = rng.uniform(50, 500, (n, n, 3))
    img[..., 1] += np.linspace(0, 300, n)[None, :]
    return img


def test_fisheye_corr_default_equals_the_built_in_projection(tmp_path):
    path = tmp_path / "fisheye_corr.cal"
    path.write_text(FISHEYE_CORR)
    proj = radcal.read_projection(path)
    assert not proj.inverse
    img = _sky()
    got = fm.project_radial(img, proj.source_radius)
    want = fm.equisolid_to_equidistant(img)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)  # the exact inverse, from a table
    chain = LuminanceChain.from_options(lens_circle="48,48,96", resize=96, projection=str(path))
    assert chain.describe()["projection"]["program"].startswith("xc:")


def test_identity_and_inverse_files(tmp_path):
    ident = tmp_path / "ident.cal"
    ident.write_text("rad(r) = r;")
    img = _sky(64)
    got = fm.project_radial(img, radcal.read_projection(ident).source_radius)
    inside = fm.inside_view(64)
    np.testing.assert_allclose(got[inside], img[inside], rtol=1e-9)
    inv = tmp_path / "inv.cal"
    inv.write_text("map_inverse = 1; rad(r) = sin(PI*r/2)/sqrt(2);  { the output radius -> the input radius }")
    proj = radcal.read_projection(inv)
    assert proj.inverse
    np.testing.assert_allclose(fm.project_radial(img, proj.source_radius), fm.equisolid_to_equidistant(img),
                               rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("text", ["ro=ri(1);", "rad(a, b) = a;", "rad(r) = log(r - 1);", "rad(r) = ri(2);"])
def test_bad_projection_files_are_one_error(tmp_path, text):
    path = tmp_path / "p.cal"
    path.write_text(text)
    with pytest.raises(InputError) as err:
        radcal.read_projection(path)
    assert str(err.value).startswith(str(path)) and "\n" not in str(err.value)


def test_projection_option_names_itself():
    with pytest.raises(UsageError, match="^--fisheye-projection: 'stereographic'"):
        LuminanceChain.from_options(lens_circle="10,10,20", resize=20, projection="stereographic")
    with pytest.raises(InputError, match="nope.cal: no such file"):
        LuminanceChain.from_options(lens_circle="10,10,20", resize=20, projection="nope.cal")


def test_whole_fisheye_corr_equals_pcomb(tmp_path, radiance_bin):
    """pcomb -f fisheye_corr.cal (its nearest-pixel offsets ri(1,xoff,yoff)) and hdrcl's
    evaluation of the same file: equal within RGBE's precision."""
    n = 41
    img = _sky(n).astype(np.float32)
    inp = tmp_path / "in.hdr"
    with open(inp, "wb") as f:
        subprocess.run([str(radiance_bin / "pvalue"), "-r", "-h", "-df", "-y", str(n), "+x", str(n)],
                       input=img.tobytes(), stdout=f, check=True)
    cal = tmp_path / "fisheye_corr.cal"
    cal.write_text(FISHEYE_CORR)
    out = subprocess.run([str(radiance_bin / "pcomb"), "-f", str(cal), str(inp)], capture_output=True,
                         check=True).stdout
    want = np.frombuffer(subprocess.run([str(radiance_bin / "pvalue"), "-h", "-H", "-df"], input=out,
                                        capture_output=True, check=True).stdout, np.float32).reshape(n, n, 3)
    held = np.frombuffer(subprocess.run([str(radiance_bin / "pvalue"), "-h", "-H", "-df", str(inp)],
                                        capture_output=True, check=True).stdout, np.float32).reshape(n, n, 3)
    prog = calexpr.parse_file(cal)
    got = prog.evaluate(["ro", "go", "bo"], xres=n, yres=n, inputs=tuple(held[..., c].astype(np.float64)
                                                                          for c in range(3)))
    got = np.stack([got["ro"], got["go"], got["bo"]], -1)
    tol = got.max(axis=-1, keepdims=True) / 128.0
    assert np.all(np.abs(got - want) <= tol)
