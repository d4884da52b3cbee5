"""Calibrated fisheye luminance maps through ``hdrcl merge`` and ``hdrcl batch`` (issue 21):
the whole chain from the command line, against the same steps applied one by one to a
plain absolute merge."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.cli import main
from hdrcl.core.luminance import fisheye_math as fm
from hdrcl.io.radiance import read_metadata, read_radiance
from hdrcl.io.rsp import write_rsp
from hdrcl.io.ldr import write_photo

from test_fisheye import _one_by_one

H, W, N = 150, 200, 48
CX, CY, D = 101.0, 74.0, 136.0
VIG, ND, K = (0.02, -0.1, 0.05), (0.9, 1.0, 1.1), 1.2


def _srgb_g():
    z = np.arange(256.0) / 255.0
    lin = np.where(z <= 0.04045, z / 12.92, ((z + 0.055) / 1.055) ** 2.4)
    g = np.log(np.maximum(lin, 1e-4))
    return g - g[128]


def _fisheye_set(folder, seed, fnumber=8.0):
    """Three JPEGs of an equisolid sky (L = A + B cos(theta), textured), 2 stops apart;
    at another f-number the times change so that the frames stay the same."""
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W] + 0.5
    r = np.hypot(xx - CX, yy - CY) / D
    theta = 2.0 * np.arcsin(np.clip(math.sqrt(2.0) * r, 0.0, 1.0))
    lum = (1.0 + 2.0 * np.cos(theta)) * rng.uniform(0.8, 1.2, (H, W))
    lum = np.where(r <= 0.5, lum, 0.0)
    lin = np.exp(_srgb_g())
    for j, t in enumerate((1 / 400, 1 / 100, 1 / 25)):
        x = lum[..., None] * np.array([1.05, 1.0, 0.9]) * t * 40.0
        codes = np.searchsorted(lin, x).clip(0, 255).astype(np.uint8)
        write_photo(str(folder / f"F{seed}_{j}.jpg"), codes,
                    {"ExposureTime": t * (fnumber / 8.0) ** 2, "FNumber": fnumber, "Exif:PhotographicSensitivity": 100,
                     "Make": "hdrcl-test", "Model": "fisheye", "DateTimeOriginal": f"2026:06:0{seed} 12:00:0{j}"})


@pytest.fixture
def fisheye_shoot(tmp_path):
    shoot = tmp_path / "shoot"
    for seed in (1, 2):
        _fisheye_set(shoot / f"dome{seed}", seed)
    g = _srgb_g()
    write_rsp(np.stack([g, g, g]), 256, str(tmp_path / "cam.rsp"))
    terms = " + ".join(f"{a}*r^{i + 1}" for i, a in reversed(list(enumerate(VIG))))
    (tmp_path / "vig.cal").write_text(
        f"r = sqrt(sq(x-{N / 2})+sq(y-{N / 2}))/{N / 2};\nsf = 1/({terms} + 1);\n"
        "ro = sf*ri(1); go = sf*gi(1); bo = sf*bi(1);\n")
    (tmp_path / "nd.cal").write_text(f"ro={ND[0]}*ri(1); go={ND[1]}*gi(1); bo={ND[2]}*bi(1);\n")
    (tmp_path / "cf.cal").write_text(f"{{photometric calibration}}\nro=ri(1)*{K}; go=gi(1)*{K}; bo=bi(1)*{K};\n")
    return tmp_path


def _chain_args(d):
    return ["--response", str(d / "cam.rsp"), "--lens-circle", f"{CX},{CY},{D}", "--resize", str(N),
            "--fisheye-projection", "equisolid-to-equidistant", "--vignetting", str(d / "vig.cal"),
            "--nd-filter", str(d / "nd.cal"), "--calibration-factor", str(d / "cf.cal"),
            "--view", "-vta -vh 180 -vv 180"]


def test_batch_of_fisheye_sets_equals_the_steps_one_by_one(fisheye_shoot, cl_device):
    from hdrcl.core.luminance.glare import glare_of_file

    d = fisheye_shoot
    out = d / "out"
    res = CliRunner().invoke(main, ["batch", str(d / "shoot"), "-o", str(out), "--format", "hdr", "--no-preview",
                                    *_chain_args(d)])
    assert res.exit_code == 0, res.output
    rep = json.loads((out / "report.json").read_text())
    assert sorted(p.name for p in out.glob("*.hdr")) == ["dome1.hdr", "dome2.hdr"]
    for entry in rep["sets"]:
        name = entry["output"].rsplit("/", 1)[-1][:-4]
        # The reference: a plain absolute merge of the whole frame (float EXR, cd/m^2) ...
        full = d / f"{name}-full.exr"
        plain = CliRunner().invoke(main, ["merge", *sorted(str(p) for p in (d / "shoot" / name).glob("*.jpg")),
                                          "--response", str(d / "cam.rsp"), "--absolute", "--dtype", "float",
                                          "-o", str(full)])
        assert plain.exit_code == 0, plain.output
        img, meta = read_radiance(str(full))
        assert meta["units"].startswith("cd/m2")
        # ... with crop, resize, projection, vignetting, ND and K applied one after another.
        want = _one_by_one(img, CX, CY, D, N, VIG, ND, K)
        got, gmeta = read_radiance(entry["output"])
        assert got.shape == (N, N, 3) and gmeta["units"] == "cd/m2"
        # stored in Radiance's convention (179 lm/W), read back in cd/m^2; RGBE keeps 8 bits of mantissa.
        np.testing.assert_allclose(got, want, rtol=1.5e-2, atol=1e-3 * float(want.max()))
        assert entry["vertical_illuminance"] == pytest.approx(fm.vertical_illuminance(want, 180.0), rel=5e-3)
        head = open(entry["output"], "rb").read(4096).split(b"\n\n")[0].decode()
        assert "VIEW= -vta -vh 180 -vv 180" in head and "VERTICAL_ILLUMINANCE=" in head
        assert "EXPOSURE=" not in head
        # the glare figures per set are `hdrcl glare`'s on the written map (issue 28)
        g = glare_of_file(entry["output"])
        assert entry["glare"]["dgp"] == pytest.approx(g.dgp, abs=1e-5)
        assert entry["glare"]["ugr"] == pytest.approx(g.ugr, abs=1e-4)
        assert entry["glare"]["sources"] == len(g.sources)
        assert entry["glare"]["vertical_illuminance"] == pytest.approx(entry["vertical_illuminance"], rel=5e-3)
    # A rerun finds both maps up to date (the input hash is in the .hdr header) ...
    again = CliRunner().invoke(main, ["batch", str(d / "shoot"), "-o", str(out), "--format", "hdr",
                                      "--no-preview", *_chain_args(d)])
    assert again.exit_code == 0 and "2 up to date" in again.output, again.output
    # ... and the skipped sets keep their luminance figures in report.json (issue 34).
    kept = {e["index"]: e for e in json.loads((out / "report.json").read_text())["sets"]}
    for entry in rep["sets"]:
        assert kept[entry["index"]]["status"] == "skipped"
        assert kept[entry["index"]]["vertical_illuminance"] == entry["vertical_illuminance"]
        assert kept[entry["index"]]["glare"] == entry["glare"]
    # ... and a different calibration factor makes them out of date.
    changed = [a if a != str(d / "cf.cal") else "1.3" for a in _chain_args(d)]
    third = CliRunner().invoke(main, ["batch", str(d / "shoot"), "-o", str(out), "--format", "hdr",
                                      "--no-preview", *changed])
    assert third.exit_code == 0 and "2 done" in third.output, third.output
    assert json.loads(read_metadata(str(out / "dome1.hdr"))["luminanceChain"])["calibrationFactor"] == 1.3


def test_merge_with_the_chain_writes_the_same_map_as_batch(fisheye_shoot, cl_device):
    d = fisheye_shoot
    frames = sorted(str(p) for p in (d / "shoot" / "dome1").glob("*.jpg"))
    one = d / "one.hdr"
    res = CliRunner().invoke(main, ["merge", *frames, "-o", str(one), *_chain_args(d)])
    assert res.exit_code == 0, res.output
    assert f"wrote {one}: {N}x{N}" in res.output and "vertical illuminance" in res.output
    out = d / "out"
    assert CliRunner().invoke(main, ["batch", str(d / "shoot"), "-o", str(out), "--format", "hdr", "--no-preview",
                                     *_chain_args(d)]).exit_code == 0
    a, _ = read_radiance(str(one))
    b, _ = read_radiance(str(out / "dome1.hdr"))
    np.testing.assert_array_equal(a, b)


def test_chain_options_need_the_lens_circle(fisheye_shoot):
    d = fisheye_shoot
    res = CliRunner().invoke(main, ["batch", str(d / "shoot"), "-o", str(d / "out"), "--resize", "100"])
    assert res.exit_code == 2 and "--lens-circle" in res.output
    assert not (d / "out").exists()


def test_a_set_at_another_f_number_gets_the_same_luminance(fisheye_shoot, cl_device):
    """The batch's exposures are relative to the shoot's f-number and ISO; the absolute
    scale must be too (the same sky shot at f/4 and f/8 is the same map)."""
    d = fisheye_shoot
    _fisheye_set(d / "shoot" / "dome3", 1, fnumber=4.0)  # dome1's sky at f/4
    out = d / "out"
    res = CliRunner().invoke(main, ["batch", str(d / "shoot"), "-o", str(out), "--format", "hdr", "--no-preview",
                                    *_chain_args(d)])
    assert res.exit_code == 0, res.output
    a, _ = read_radiance(str(out / "dome1.hdr"))
    b, _ = read_radiance(str(out / "dome3.hdr"))
    inside = a[..., 1] > 0.05 * a[..., 1].max()
    ratio = float(np.median(b[..., 1][inside] / a[..., 1][inside]))
    assert ratio == pytest.approx(1.0, abs=0.03)


@pytest.mark.parametrize("n", [100, 111, 112, 239, 300, 1000])
def test_hdr_metadata_lines_of_any_length_read_back(tmp_path, n):
    """hdrcl's metadata on ``HDRCL=`` header lines: whatever its length (OpenImageIO
    cannot read a header line of a multiple of 128 bytes), the file and the metadata
    read back."""
    from hdrcl.io.writers import write_radiance

    img = np.full((4, 5, 3), 0.5, np.float32)
    p = tmp_path / "m.hdr"
    write_radiance(str(p), img, metadata={"note": "a" * n, "inputHash": "x"},
                   camera={"owner": "o" * (n + 8)})  # "# owner: " + n + 8: 128 and 256 too
    got, meta = read_radiance(str(p))
    np.testing.assert_allclose(got, img, rtol=1e-2)
    assert meta["note"] == "a" * n and read_metadata(str(p))["inputHash"] == "x"


def test_falsecolor_reads_every_kind_of_luminance_map(fisheye_shoot, cl_device):
    """An ``--absolute`` merge holds cd/m^2 as .exr and as .hdr alike, a chain's .hdr
    holds them in Radiance's 179 lm/W convention: false colour reads each as it is; a
    relative map is refused (exit 3), not drawn with a made-up scale."""
    from hdrcl.report.falsecolor import read_luminance

    d = fisheye_shoot
    frames = sorted(str(p) for p in (d / "shoot" / "dome1").glob("*.jpg"))
    for out, extra in (("abs.exr", ["--absolute"]), ("abs.hdr", ["--absolute"]), ("rel.hdr", []),
                       ("chain.hdr", _chain_args(d)[2:])):
        args = ["merge", *frames, "--response", str(d / "cam.rsp"), "-o", str(d / out), *extra]
        assert CliRunner().invoke(main, args).exit_code == 0
    exr, hdr = read_luminance(str(d / "abs.exr")), read_luminance(str(d / "abs.hdr"))
    lit = exr > 0.05 * exr.max()
    assert float(np.median(hdr[lit] / exr[lit])) == pytest.approx(1.0, abs=0.01)
    chain = read_luminance(str(d / "chain.hdr"))  # x K = 1.2, ND about 1, vignetting near 1 at the centre
    assert chain[N // 2, N // 2] == pytest.approx(K * exr[int(CY), int(CX)] * 1.0, rel=0.25)
    res = CliRunner().invoke(main, ["falsecolor", str(d / "rel.hdr"), "-o", str(d / "rel.png")])
    assert res.exit_code == 3 and "not a luminance map" in res.output and not (d / "rel.png").exists()


def test_merge_takes_a_projection_cal_file_on_the_command_line(fisheye_shoot, cl_device):
    """--fisheye-projection FILE.cal from the command line (it was a fixed choice that
    refused every file): Radiance's fisheye_corr.cal, whose default rad(r) is the
    equisolid-to-equidistant mapping, gives the built-in projection's map."""
    from test_projection_cal import FISHEYE_CORR

    d = fisheye_shoot
    (d / "fisheye_corr.cal").write_text(FISHEYE_CORR)
    frames = sorted(str(p) for p in (d / "shoot" / "dome1").glob("*.jpg"))
    args = _chain_args(d)
    builtin, user = d / "builtin.exr", d / "user.exr"
    assert CliRunner().invoke(main, ["merge", *frames, "-o", str(builtin), *args]).exit_code == 0
    args[args.index("--fisheye-projection") + 1] = str(d / "fisheye_corr.cal")
    res = CliRunner().invoke(main, ["merge", *frames, "-o", str(user), *args])
    assert res.exit_code == 0, res.output
    a, _ = read_radiance(str(builtin))
    b, _ = read_radiance(str(user))
    inside = a > 0
    assert np.median(np.abs(b[inside] / a[inside] - 1)) < 0.01


@pytest.mark.parametrize("cmd", ["merge", "batch"])
def test_calibration_factor_checked_against_the_output_format_before_decoding(fisheye_shoot, cmd):
    """1e-30 cd/m2 per unit fits a float EXR but not RGBE once divided by 179 (issue 29:
    every calibration input range-checked for what the output format holds): exit 2, one
    line naming the option, nothing written."""
    d = fisheye_shoot
    args = _chain_args(d)
    args[args.index("--calibration-factor") + 1] = "1e-30"
    if cmd == "merge":
        frames = sorted(str(p) for p in (d / "shoot" / "dome1").glob("*.jpg"))
        res = CliRunner().invoke(main, ["merge", *frames, "-o", str(d / "k.hdr"), *args])
    else:
        res = CliRunner().invoke(main, ["batch", str(d / "shoot"), "-o", str(d / "kout"), "--format", "hdr",
                                        "--no-preview", *args])
    assert res.exit_code == 2, res.output
    assert res.stderr.strip().count("\n") == 0 and "--calibration-factor" in res.stderr, res.stderr
    assert not (d / "k.hdr").exists()
    assert not (d / "kout").exists() or not list((d / "kout").glob("*.hdr"))
