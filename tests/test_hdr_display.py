"""Pictures for HDR screens (``--deliver``): Ultra HDR gain-map JPEG, AVIF and JPEG XL.

Oracles: the files are decoded back by the codec libraries (libultrahdr, libavif, libjxl
through imagecodecs) and compared with the radiance map scaled to reference white; the
gain-map metadata (ISO 21496-1 binary, hdrgm XMP, MPF) and AVIF's nclx/pixi boxes are
parsed here, by the test, from the bytes. The tests need imagecodecs 2026.3 (the
``hdr-display`` extra): without it they skip, unless ``HDRCL_REQUIRE_HDR_DISPLAY=1`` (CI),
where that is a failure. The Chromium check uses ``chromium_path`` (``HDRCL_REQUIRE_BROWSER``).
"""
from __future__ import annotations

import json
import os
import re
import struct
import subprocess

import numpy as np
import pytest
from click.testing import CliRunner

from hdrcl.core.options import DELIVERABLE_NAMES, DeliverOptions
from hdrcl.core.synthetic import radiance_field
from hdrcl.errors import HdrclError, UsageError


@pytest.fixture(scope="module")
def ic():
    try:
        import imagecodecs
    except ImportError:
        imagecodecs = None
    if imagecodecs is None or not all(getattr(imagecodecs, n).available for n in ("ULTRAHDR", "AVIF", "JPEGXL")):
        if os.environ.get("HDRCL_REQUIRE_HDR_DISPLAY", "") not in ("", "0"):
            pytest.fail("HDRCL_REQUIRE_HDR_DISPLAY is set but imagecodecs (with libultrahdr, libavif, libjxl) "
                        "is missing: pip install 'hdrcl[hdr-display]'")
        pytest.skip("imagecodecs with libultrahdr/libavif/libjxl not installed; set HDRCL_REQUIRE_HDR_DISPLAY=1 "
                    "to make this an error")
    return imagecodecs


H, W = 61, 97  # odd sizes catch strip and bounds errors
HEADROOM = 2.5


@pytest.fixture(scope="module")
def scene_map():
    """4.5 decades of radiance, float32, an arbitrary scale (the rendering finds white)."""
    return (radiance_field(H, W, decades=4.5, seed=3) * 37.0).astype(np.float32)


def _reference(rad, options):
    from hdrcl.report.deliver import Rendering

    r = Rendering(rad, options)
    return r, r.hdr(0, r.h, headroom=99.0)  # unclipped, in reference-white units


def _stops(a, b):
    return np.abs(np.log2(np.maximum(a, 1e-9) / np.maximum(b, 1e-9)))


# ----------------------------------------------------------------- JPEG parsing (independent)
def _segments(jpeg: bytes, start: int = 0):
    """(marker, payload offset, payload) of the APPn segments of the JPEG at ``start``."""
    assert jpeg[start:start + 2] == b"\xff\xd8"
    i = start + 2
    while jpeg[i] == 0xFF and jpeg[i + 1] not in (0xDA, 0xD9):
        m = jpeg[i + 1]
        n = struct.unpack(">H", jpeg[i + 2:i + 4])[0]
        yield m, i + 4, jpeg[i + 4:i + 2 + n]
        i += 2 + n


def _iso21496(payload: bytes) -> dict:
    """ISO 21496-1 gain-map metadata, parsed from its APP2 payload."""
    urn = b"urn:iso:std:iso:ts:21496:-1\x00"
    assert payload.startswith(urn)
    d = payload[len(urn):]
    min_version, _writer, flags = struct.unpack(">HHB", d[:5])
    assert min_version == 0
    p = 5
    channels = 3 if flags & 0x80 else 1
    common = bool(flags & 0x08)

    def take(fmt):
        nonlocal p
        v = struct.unpack(">" + fmt, d[p:p + struct.calcsize(fmt)])
        p += struct.calcsize(fmt)
        return v

    den = take("I")[0] if common else None

    def frac(signed):
        if common:
            return take("i" if signed else "I")[0] / den
        n, m = take(("i" if signed else "I") + "I")
        return n / m

    out = {"channels": channels, "base_colour_space": bool(flags & 0x40),
           "base_headroom": frac(False), "alternate_headroom": frac(False), "per_channel": []}
    for _ in range(channels):
        out["per_channel"].append({k: frac(s) for k, s in (("gain_min", True), ("gain_max", True),
                                                          ("gamma", False), ("base_offset", True),
                                                          ("alternate_offset", True))})
    assert p == len(d)
    return out


def _gainmap_parts(data: bytes) -> dict:
    """The MPF index, the second image and its metadata, read from the bytes."""
    segs = list(_segments(data))
    mpf = [(off, p) for m, off, p in segs if m == 0xE2 and p.startswith(b"MPF\x00")]
    assert len(mpf) == 1
    off, p = mpf[0]
    tiff = off + 4
    assert p[4:8] == b"MM\x00\x2a"
    (ifd,) = struct.unpack(">I", p[8:12])
    (count,) = struct.unpack(">H", p[4 + ifd:6 + ifd])
    tags = {}
    for k in range(count):
        tag, typ, n, val = struct.unpack(">HHII", p[6 + ifd + 12 * k:18 + ifd + 12 * k])
        tags[tag] = (n, val)
    assert tags[0xB001][1] == 2  # two images
    n, entries = tags[0xB002]
    e = [struct.unpack(">IIIHH", p[4 + entries + 16 * k:20 + entries + 16 * k]) for k in range(n // 16)]
    second_at = tiff + e[1][2]
    assert e[0][1] == second_at  # the primary ends where the gain map starts
    assert second_at + e[1][1] == len(data)
    xmp1 = [p for m, _, p in segs if m == 0xE1 and p.startswith(b"http://ns.adobe.com/xap/1.0/")]
    segs2 = list(_segments(data, second_at))
    iso = [p for m, _, p in segs2 if m == 0xE2 and p.startswith(b"urn:iso:std:iso:ts:21496")]
    xmp2 = [p for m, _, p in segs2 if m == 0xE1 and p.startswith(b"http://ns.adobe.com/xap/1.0/")]
    return {"second": data[second_at:], "iso": _iso21496(iso[0]), "xmp_primary": xmp1[0].decode(),
            "xmp_gain": xmp2[0].decode(), "gain_length": e[1][1]}


# ------------------------------------------------------------------------------ tests
def test_options_are_checked_once():
    o = DeliverOptions("UHDR, avif,uhdr", headroom="2", bits=12, transfer="hlg")
    assert o.kinds == ("uhdr", "avif") and o.headroom == 2.0 and o.bits == 12 and o.transfer == "hlg"
    assert not DeliverOptions()
    for bad, words in ((dict(kinds="webp"), "--deliver: unknown 'webp'"), (dict(headroom=6), "--headroom"),
                       (dict(headroom=0), "--headroom"), (dict(bits=8), "--hdr-bits"),
                       (dict(transfer="srgb"), "--hdr-transfer")):
        with pytest.raises(UsageError, match=re.escape(words)):
            DeliverOptions(**bad)


def test_missing_codecs_are_refused_before_merging(monkeypatch, tmp_path):
    from hdrcl.cli import main
    from hdrcl.io import hdrdisplay

    monkeypatch.setattr(hdrdisplay, "_imagecodecs", lambda: (_ for _ in ()).throw(
        UsageError("HDR-screen outputs need imagecodecs 2026.3 or later: pip install 'hdrcl[hdr-display]'")))
    with pytest.raises(UsageError, match=r"--deliver: HDR-screen outputs need imagecodecs"):
        DeliverOptions("avif")
    assert not DeliverOptions()  # nothing asked, nothing needed
    from hdrcl.io.ldr import write_ldr

    frames = [str(tmp_path / f"f{k}.png") for k in range(2)]
    for k, f in enumerate(frames):
        write_ldr(f, np.full((5, 7, 3), 60 * (k + 1), np.uint8))
    res = CliRunner().invoke(main, ["merge", *frames, "--times", "1,2", "-o", str(tmp_path / "m.exr"),
                                    "--deliver", "uhdr"])
    assert res.exit_code == 2 and "hdr-display" in res.stderr and not (tmp_path / "m.exr").exists()


def test_registry_names_the_options_deliverables():
    from hdrcl.report.deliver import DELIVERABLES

    assert tuple(DELIVERABLES) == DELIVERABLE_NAMES
    assert len({d.suffix for d in DELIVERABLES.values()}) == len(DELIVERABLES)


def test_transfer_functions():
    from hdrcl.io.hdrdisplay import hlg_decode, hlg_encode, pq_decode, pq_encode

    assert pq_encode(203.0) == pytest.approx(0.5807, abs=2e-4)  # BT.2408's PQ reference white
    assert pq_encode(10000.0) == pytest.approx(1.0)
    assert hlg_encode(0.26496) == pytest.approx(0.75, abs=1e-4)
    x = np.geomspace(1e-4, 1e4, 200)
    np.testing.assert_allclose(pq_decode(pq_encode(x)), x, rtol=1e-9)
    s = np.linspace(0, 1, 101)
    np.testing.assert_allclose(hlg_encode(hlg_decode(s)), s, atol=1e-12)


def test_ultrahdr_decodes_to_the_radiance(ic, scene_map, tmp_path):
    """Done when: libultrahdr's HDR rendering equals the map in reference-white units within
    0.1 stops (median) inside the headroom and clips at 2^headroom outside it; its SDR
    rendering is our base; the metadata read from the bytes is what was asked."""
    from hdrcl.report.deliver import deliver

    opts = DeliverOptions("uhdr", headroom=HEADROOM)
    recs = deliver(str(tmp_path / "m.exr"), scene_map, opts)
    assert [r["kind"] for r in recs] == ["uhdr"] and recs[0]["path"] == str(tmp_path / "m.uhdr.jpg")
    data = (tmp_path / "m.uhdr.jpg").read_bytes()
    assert recs[0]["bytes"] == len(data)
    r, ref = _reference(scene_map, opts)
    hdr = ic.ultrahdr_decode(data).astype(np.float64)[..., :3]  # full boost: linear, 1.0 = SDR white
    assert hdr.shape == (H, W, 3)
    top = 2.0 ** HEADROOM
    inside = (ref.max(axis=2) < top * 0.97) & (ref.min(axis=2) > 0.01)
    outside = ref.min(axis=2) > top * 1.1
    assert inside.sum() > 0.5 * H * W and outside.sum() > 20
    assert np.median(_stops(hdr, ref)[inside]) < 0.1
    assert np.median(_stops(hdr, np.full_like(hdr, top))[outside]) < 0.1  # clipped at the headroom
    sdr = ic.ultrahdr_decode(data, dtype=np.uint8)[..., :3].astype(int)
    assert np.median(np.abs(sdr - r.base().astype(int))) <= 2
    # an independent reading of the metadata
    parts = _gainmap_parts(data)
    iso = parts["iso"]
    assert iso["channels"] == 3 and iso["base_colour_space"]
    assert iso["base_headroom"] == 0.0 and iso["alternate_headroom"] == pytest.approx(HEADROOM, abs=1e-5)
    for c in iso["per_channel"]:
        assert c["gamma"] == 1.0 and c["base_offset"] == c["alternate_offset"] == pytest.approx(1 / 64, abs=1e-6)
        assert -8 < c["gain_min"] < c["gain_max"] <= np.log2((top + 1 / 64) / (1 / 64)) + 1e-6
    assert re.search(r'hdrgm:HDRCapacityMax="([0-9.]+)"', parts["xmp_gain"]).group(1) == f"{HEADROOM:.6f}"
    assert 'hdrgm:Version="1.0"' in parts["xmp_primary"]
    assert f'Item:Length="{parts["gain_length"]}"' in parts["xmp_primary"]
    gain = ic.jpeg8_decode(parts["second"])
    assert gain.shape == (H, W, 3)


@pytest.mark.parametrize("kind,transfer,bits", [("avif", "pq", 10), ("avif", "hlg", 12), ("jxl", "pq", 10),
                                                ("jxl", "hlg", 12)])
def test_avif_and_jxl_decode_to_the_radiance(ic, scene_map, tmp_path, kind, transfer, bits):
    """Done when: decoded by the codec library, the PQ or HLG picture equals the map in
    reference-white units (203 cd/m^2 in PQ; HLG 0.75) within 0.1 stops median inside
    the headroom (HLG: at most 1.92 stops), clips there, and says its CICP."""
    from hdrcl.io.hdrdisplay import REFERENCE_WHITE_NITS, hlg_decode, pq_decode
    from hdrcl.report.deliver import HLG_HEADROOM, deliver

    opts = DeliverOptions(kind, headroom=HEADROOM, transfer=transfer, bits=bits)
    (rec,) = deliver(str(tmp_path / "m.exr"), scene_map, opts)
    data = open(rec["path"], "rb").read()
    if kind == "avif":
        codes = ic.avif_decode(data).astype(np.float64) / ((1 << bits) - 1)
    else:
        codes = ic.jpegxl_decode(data).astype(np.float64) / 65535.0  # full-range uint16
    assert codes.shape == (H, W, 3)
    got = pq_decode(codes) / REFERENCE_WHITE_NITS if transfer == "pq" else hlg_decode(codes) / 0.26496
    headroom = HEADROOM if transfer == "pq" else min(HEADROOM, HLG_HEADROOM)
    assert rec["headroom"] == pytest.approx(headroom, abs=1e-4)
    _, ref = _reference(scene_map, opts)
    top = 2.0 ** headroom
    inside = (ref.max(axis=2) < top * 0.97) & (ref.min(axis=2) > 0.01)
    outside = ref.min(axis=2) > top * 1.1
    assert np.median(_stops(got, ref)[inside]) < 0.1
    assert np.median(_stops(got, np.full_like(got, top))[outside]) < 0.1
    assert rec["max_cll"] == pytest.approx(REFERENCE_WHITE_NITS * top, rel=1e-3)
    code = 16 if transfer == "pq" else 18
    if kind == "avif":  # the nclx colour box and the pixel depth, read from the bytes
        i = data.index(b"colrnclx") + 8
        prim, trc, matrix = struct.unpack(">HHH", data[i:i + 6])
        assert (prim, trc, matrix) == (1, code, 1)
        i = data.index(b"pixi") + 8
        assert list(data[i + 1:i + 1 + data[i]]) == [bits] * 3
    else:
        import OpenImageIO as oiio

        inp = oiio.ImageInput.open(rec["path"])
        try:
            assert tuple(inp.spec().getattribute("CICP")) == (1, code, 0, 1)
        finally:
            inp.close()


def test_upright_as_the_preview(ic, scene_map, tmp_path):
    from hdrcl.report.deliver import deliver

    (rec,) = deliver(str(tmp_path / "m.exr"), scene_map, DeliverOptions("avif"), orientation=6)
    assert ic.avif_decode(open(rec["path"], "rb").read()).shape == (W, H, 3)


def test_a_failed_encode_leaves_no_file(ic, scene_map, tmp_path, monkeypatch):
    from hdrcl.report.deliver import deliver

    def broken(*a, **k):
        raise RuntimeError("libavif: out of memory")

    monkeypatch.setattr(ic, "avif_encode", broken)
    with pytest.raises(HdrclError, match=r"m\.avif: AVIF encoding failed"):
        deliver(str(tmp_path / "m.exr"), scene_map, DeliverOptions("avif"))
    assert os.listdir(tmp_path) == []


def test_black_and_grey_maps(ic, tmp_path):
    """A map without light and a one-channel map: files, no NaN, no warnings."""
    from hdrcl.report.deliver import deliver

    with np.errstate(all="raise"):
        recs = deliver(str(tmp_path / "k.exr"), np.zeros((9, 11, 3), np.float32), DeliverOptions("uhdr,avif"))
        grey = radiance_field(9, 11, channels=1, seed=2).astype(np.float32)
        recs += deliver(str(tmp_path / "g.exr"), grey, DeliverOptions("uhdr,jxl"))
    assert all(os.path.getsize(r["path"]) == r["bytes"] > 0 for r in recs)
    assert np.isfinite(ic.ultrahdr_decode((tmp_path / "g.uhdr.jpg").read_bytes()).astype(np.float32)).all()


# ------------------------------------------------------------------------------ CLI
def _shoot(tmp_path_factory):
    import shootgen

    folder = tmp_path_factory.mktemp("hdrshoot")
    shootgen.make_shoot(folder)
    return str(folder)


@pytest.fixture(scope="module")
def shoot(tmp_path_factory):
    return _shoot(tmp_path_factory)


def test_batch_delivers_beside_every_exr(ic, shoot, tmp_path):
    """Done when: a batch with --deliver writes each deliverable beside each EXR, counts
    them in report.json, the Ultra HDR base is the preview's rendering (within 2 code
    levels, compared at the preview's size), and a rerun makes only the missing ones."""
    from hdrcl.cli import main
    from hdrcl.report.preview import downscale

    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["batch", shoot, "-o", str(out), "--deliver", "uhdr,avif", "--headroom", "2"])
    assert res.exit_code == 1, res.output  # the shoot's corrupt file; every set merges
    rep = json.loads((out / "report.json").read_text())
    assert rep["summary"]["failed"] == 0 and rep["summary"]["unreadable_files"] == 1
    merged = [s for s in rep["sets"] if s["status"] in ("done", "check")]
    assert merged and rep["summary"]["deliverables"] == {"avif": len(merged), "uhdr": len(merged)}
    for s in merged:
        stem = os.path.splitext(s["output"])[0]
        assert [d["kind"] for d in s["deliverables"]] == ["uhdr", "avif"]
        for d in s["deliverables"]:
            assert d["path"] == stem + (".uhdr.jpg" if d["kind"] == "uhdr" else ".avif")
            assert os.path.getsize(d["path"]) == d["bytes"] and d["headroom"] == 2.0
        sdr = ic.ultrahdr_decode(open(stem + ".uhdr.jpg", "rb").read(), dtype=np.uint8)[..., :3]
        preview = ic.imread(s["preview"])
        small = downscale(sdr.astype(np.float64), max(preview.shape[:2]))
        assert small.shape == preview.shape
        assert np.median(np.abs(small - preview)) <= 2
    assert not [f for f in os.listdir(out) if ".tmp-" in f]  # atomic writes leave no temporary file
    first = merged[0]["deliverables"][1]["path"]
    os.remove(first)
    res = CliRunner().invoke(main, ["batch", shoot, "-o", str(out), "--deliver", "uhdr,avif", "--headroom", "2"])
    assert res.exit_code == 1, res.output
    rep = json.loads((out / "report.json").read_text())
    assert os.path.isfile(first) and rep["summary"]["deliverables"] == {"avif": len(merged), "uhdr": len(merged)}
    assert any("avif missing: made from the EXR" in w for s in rep["sets"] for w in s["warnings"])
    # Other settings (not part of the EXR's identity) remake the deliverables from the EXR:
    # the headroom they keep is the one asked (review: they were kept as they were).
    args = ["batch", shoot, "-o", str(out), "--deliver", "uhdr,avif", "--headroom", "4"]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 1, res.output
    rep = json.loads((out / "report.json").read_text())
    assert all(d["headroom"] == 4.0 for s in rep["sets"] for d in s.get("deliverables", []))
    assert any("made with other settings" in w for s in rep["sets"] for w in s["warnings"])


def test_no_deliverables_of_luminance_maps(ic, shoot, tmp_path):
    """A luminance map (--lens-circle) is cropped and calibrated after the fusion: the
    pictures would show another image than the file, so --deliver is refused (review)."""
    from hdrcl.cli import main

    frames = sorted(os.path.join(shoot, f) for f in os.listdir(shoot) if f.startswith("IMG_000") and
                    f[4:8] in ("0001", "0002", "0003"))
    for cmd in (["merge", *frames, "-o", str(tmp_path / "m.hdr")], ["batch", shoot, "-o", str(tmp_path / "b")]):
        res = CliRunner().invoke(main, [*cmd, "--lens-circle", "20,20,30", "--deliver", "uhdr"])
        assert res.exit_code == 2 and "--deliver: not with a luminance map" in res.stderr, res.output
        assert not (tmp_path / "m.hdr").exists() and not (tmp_path / "b").exists()


def test_merge_cli(ic, shoot, tmp_path):
    from hdrcl.cli import main

    frames = sorted(os.path.join(shoot, f) for f in os.listdir(shoot) if f.startswith("IMG_000") and
                    f[4:8] in ("0001", "0002", "0003"))
    res = CliRunner().invoke(main, ["merge", *frames, "-o", str(tmp_path / "m.exr"), "--deliver", "jxl,uhdr"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "m.jxl").is_file() and (tmp_path / "m.uhdr.jpg").is_file()
    res = CliRunner().invoke(main, ["merge", *frames, "-o", str(tmp_path / "n.exr"), "--deliver", "png"])
    assert res.exit_code == 2 and "--deliver: unknown 'png'" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and not (tmp_path / "n.exr").exists()


def test_ultrahdr_opens_in_chromium(ic, scene_map, tmp_path, chromium_path):
    """Done when: Chromium decodes the Ultra HDR JPEG; on an SDR screen it shows the base."""
    from hdrcl.report.deliver import Rendering, deliver

    opts = DeliverOptions("uhdr", headroom=HEADROOM)
    deliver(str(tmp_path / "m.exr"), scene_map, opts)
    base = Rendering(scene_map, opts).base()
    (tmp_path / "p.html").write_text('<html><body style="margin:0;background:#000">'
                                     f'<img src="m.uhdr.jpg" width="{W}" height="{H}"></body></html>')
    shot = tmp_path / "shot.png"
    cmd = [chromium_path, "--headless", "--no-sandbox", "--disable-gpu", f"--user-data-dir={tmp_path / 'profile'}",
           "--force-color-profile=srgb", "--hide-scrollbars", "--window-size=400,300",  # smaller: cut short
           "--virtual-time-budget=5000", f"--screenshot={shot}", "file://" + str(tmp_path / "p.html")]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    px = ic.imread(str(shot))[:H, :W, :3].astype(int)
    assert np.median(np.abs(px - base.astype(int))) <= 2  # Chromium's decoder, the base's JPEG error


def test_deliverables_temporary_files_are_the_sets(tmp_path):
    """A killed run's temporary deliverables are the set's: its claim removes them, and the
    stale sweep knows their names (review: .uhdr.tmp-*.jpg and .avif/.jxl were missed)."""
    import time

    from hdrcl.shoot.batch.claims import SetClaim, set_temps
    from hdrcl.shoot.batch.state import STALE_TEMP_SECONDS, _remove_stale_temps

    names = [".IMG_1.tmp-1a2b3c4d.exr", ".IMG_1.uhdr.tmp-1a2b3c4d.jpg", ".IMG_1.tmp-0a0b0c0d.avif",
             ".IMG_1.tmp-1111aaaa.jxl", ".IMG_1.5.tmp-1a2b3c4d.exr"]
    for n in names:
        (tmp_path / n).write_bytes(b"x")
    assert sorted(os.path.basename(p) for p in set_temps(str(tmp_path), "IMG_1")) == sorted(names[:4])
    c = SetClaim(str(tmp_path), "IMG_1")
    assert c.acquire(wait=False) and c.remove_temps() == 4
    c.release()
    assert sorted(os.listdir(tmp_path)) == [".IMG_1.5.tmp-1a2b3c4d.exr"]
    for n in names[1:4]:  # the stale sweep of another run: old files of a set nobody holds
        p = tmp_path / n
        p.write_bytes(b"x")
        os.utime(p, (time.time() - STALE_TEMP_SECONDS - 10,) * 2)
    _remove_stale_temps(str(tmp_path), [])
    assert sorted(os.listdir(tmp_path)) == [".IMG_1.5.tmp-1a2b3c4d.exr"]
