"""Seeded, bounded fuzzing of every reader a user can feed: images, times files,
response and manifest JSON, and ``--sets``.

The contract: a reader returns or raises :class:`hdrcl.HdrclError` (never another
exception), and the command line prints at most one line on stderr. ``derandomize``
makes the examples the same on every run; ``max_examples`` keeps the whole file to a
few seconds.
"""
import json

import numpy as np
import pytest
from click.testing import CliRunner

hypothesis = pytest.importorskip("hypothesis")  # in the 'dev' extra
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from hdrcl.cli import main  # noqa: E402
from hdrcl.core import synthetic as s  # noqa: E402
from hdrcl.errors import HdrclError  # noqa: E402

FUZZ = settings(max_examples=60, derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
FEW = settings(FUZZ, max_examples=12)
TIMES = (1 / 60, 1 / 15, 1 / 4)


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    from hdrcl.core.response import Response, knot_positions
    from hdrcl.io.ldr import write_ldr

    d = tmp_path_factory.mktemp("fuzz")
    rad = s.radiance_field(12, 16, decades=2.0, seed=7)
    cam = s.Camera()
    paths = []
    for k, frame in enumerate(s.bracket(rad, TIMES, cam, noise=0.3, seed=8)):
        p = d / f"f{k}.png"
        write_ldr(str(p), frame)
        paths.append(str(p))
    write_ldr(str(d / "j.jpg"), s.bracket(rad, TIMES[:1], cam, seed=9)[0])
    write_ldr(str(d / "t.tif"), s.bracket(rad, TIMES[:1], cam, seed=9)[0])
    z = knot_positions(8)
    g = np.stack([cam.g(np.clip(z, 1, 254))] * 3)
    resp = Response(bits=8, g=g - g[:, [128]], knots=z)
    resp.save(d / "resp.json")
    return {"dir": d, "frames": paths, "resp": resp.to_dict(), "resp_path": str(d / "resp.json"),
            "bytes": {e: (d / n).read_bytes() for e, n in ((".png", "f0.png"), (".jpg", "j.jpg"), (".tif", "t.tif"))}}


def _one_line(res):
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) <= 1, res.stderr
    assert "Traceback" not in res.output and "internal error" not in res.stderr, res.output
    if res.exit_code != 0:
        assert len(lines) == 1 and lines[0].startswith("hdrcl: error: "), res.stderr


# ------------------------------------------------------------------------------ images

_mutation = st.one_of(
    st.tuples(st.just("truncate"), st.floats(0.0, 1.0)),
    st.tuples(st.just("flip"), st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 255)), min_size=1,
                                       max_size=8)),
    st.tuples(st.just("insert"), st.tuples(st.floats(0.0, 1.0), st.binary(min_size=1, max_size=64))),
    st.tuples(st.just("random"), st.binary(max_size=256)),
)


def _mutate(data: bytes, how) -> bytes:
    kind, arg = how
    if kind == "truncate":
        return data[: int(arg * len(data))]
    if kind == "flip":
        b = bytearray(data)
        for pos, val in arg:
            b[min(int(pos * len(b)), len(b) - 1)] = val
        return bytes(b)
    if kind == "insert":
        pos, extra = arg
        i = int(pos * len(data))
        return data[:i] + extra + data[i:]
    return arg


@FUZZ
@given(ext=st.sampled_from([".png", ".jpg", ".tif"]), how=_mutation)
def test_image_reader(base, tmp_path, ext, how):
    from hdrcl.io.frames import read_image, read_info

    p = tmp_path / f"x{ext}"
    p.write_bytes(_mutate(base["bytes"][ext], how))
    try:
        read_info(p)
        img = read_image(p)
        assert img.pixels.dtype in (np.uint8, np.uint16)
    except HdrclError as exc:
        assert str(exc).startswith(str(p)), str(exc)


@FEW
@given(how=_mutation)
def test_image_reader_through_the_cli(base, tmp_path, how):
    bad = tmp_path / "f1.png"
    bad.write_bytes(_mutate(base["bytes"][".png"], how))
    fr = base["frames"]
    res = CliRunner().invoke(main, ["merge", fr[0], str(bad), fr[2], "--times", "1/60,1/15,1/4",
                                    "--response", base["resp_path"], "-o", str(tmp_path / "o.exr")])
    _one_line(res)


# -------------------------------------------------------------------------- times files

_token = st.one_of(
    st.sampled_from(["f0.png", "f1.png", "f2.png", "1/30", "0.5", "2", "0", "-1", "1/0", "nan", "inf", "1e308",
                     "-1e308", "8", "#", "1/", "/2", "\t", "1e-320", "ÿ", "\x00"]),
    st.text(max_size=6),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
)
_times_text = st.lists(st.lists(_token, max_size=7).map(" ".join), max_size=6).map("\n".join)


@FUZZ
@given(text=_times_text, bom=st.booleans())
def test_times_file_reader(base, tmp_path, text, bom):
    from hdrcl.io.metadata import relative_exposures, resolve_exposures
    from hdrcl.io.exposure_lists import read_times_file

    p = tmp_path / "times.txt"
    p.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode("utf-8", "surrogatepass"))
    try:
        table = read_times_file(p)
        ex = resolve_exposures(base["frames"], times_file=table)
        rel = relative_exposures(ex)
        assert np.all(np.isfinite(rel)) and np.all(rel > 0)
    except HdrclError:
        pass


@FUZZ
@given(text=st.one_of(st.text(max_size=30), st.lists(_token, max_size=5).map(",".join)))
def test_times_option(base, text):
    from hdrcl.io.exposure_lists import coerce_times, parse_times

    for parse in (lambda t: parse_times(t, "--times"), coerce_times):
        try:
            vals = parse(text)
            assert all(np.isfinite(v) and v > 0 for v in vals)
        except HdrclError:
            pass


# ----------------------------------------------------------------------- JSON documents

_json = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-2 ** 70, 2 ** 70), st.floats(allow_nan=False),
              st.text(max_size=8)),
    lambda children: st.one_of(st.lists(children, max_size=4), st.dictionaries(st.text(max_size=6), children,
                                                                                max_size=4)),
    max_leaves=12,
)


def _edit(doc, paths_values):
    """Replace or delete values at paths inside a copy of ``doc``."""
    doc = json.loads(json.dumps(doc))
    for path, value, delete in paths_values:
        node = doc
        for step in path[:-1]:
            if isinstance(node, dict) and node:
                node = node[sorted(node)[step % len(node)]]
            elif isinstance(node, list) and node:
                node = node[step % len(node)]
        last = path[-1]
        if isinstance(node, dict) and node:
            key = sorted(node)[last % len(node)]
            if delete:
                del node[key]
            else:
                node[key] = value
        elif isinstance(node, list) and node:
            node[last % len(node)] = value
    return doc


_edits = st.lists(st.tuples(st.lists(st.integers(0, 50), min_size=1, max_size=4), _json, st.booleans()),
                  min_size=1, max_size=3)
_raw_text = st.one_of(st.text(max_size=60), st.binary(max_size=60).map(lambda b: b.decode("latin-1")),
                      st.integers(1, 200).map(lambda n: "[" * n + "]" * n))


@FUZZ
@given(edits=_edits, raw=st.one_of(st.none(), _raw_text))
def test_response_reader(base, tmp_path, edits, raw):
    from hdrcl.core.response import Response

    p = tmp_path / "r.json"
    p.write_text(raw if raw is not None else json.dumps(_edit(base["resp"], edits)), encoding="utf-8")
    try:
        r = Response.load(p)
        t = r.table_for(3)
        assert np.all(np.isfinite(t))
    except HdrclError as exc:
        assert str(exc).startswith(str(p)) or "channels" in str(exc), str(exc)


@FUZZ
@given(edits=_edits, raw=st.one_of(st.none(), _raw_text))
def test_manifest_reader(base, tmp_path, edits, raw):
    from hdrcl.shoot.batch.manifest import load_manifest

    doc = {"root": ".", "sets": [{"index": 0, "files": ["f0.png", "f1.png", "f2.png"], "exposures": list(TIMES),
                                  "reason": "manifest", "camera": "X", "iso": [100, 100, 100], "width": 16}],
           "unmerged": [{"files": ["z.png"], "reason": "single frame"}]}
    p = tmp_path / "m.json"
    p.write_text(raw if raw is not None else json.dumps(_edit(doc, edits)), encoding="utf-8")
    try:
        m = load_manifest(p, check_files=False)
        json.dumps(m.to_dict())
    except HdrclError as exc:
        assert str(exc).startswith(str(p)), str(exc)


@FEW
@given(edits=_edits)
def test_response_through_the_cli(base, tmp_path, edits):
    p = tmp_path / "r.json"
    p.write_text(json.dumps(_edit(base["resp"], edits)))
    fr = base["frames"]
    res = CliRunner().invoke(main, ["merge", *fr, "--times", "1/60,1/15,1/4", "--response", str(p),
                                    "-o", str(tmp_path / "o.exr")])
    _one_line(res)


# ------------------------------------------------------------------------------ --sets


@FUZZ
@given(text=st.text(alphabet="0123456789-, #x", max_size=12))
def test_sets_option(base, tmp_path, text):
    res = CliRunner().invoke(main, ["batch", f"--sets={text}", str(tmp_path / "missing.json"),
                                    "-o", str(tmp_path / "out")])
    _one_line(res)
    assert res.exit_code in (2, 3)
    assert not (tmp_path / "out").exists()


def test_schema_agrees_with_jsonschema(base):
    """The small validator accepts exactly what a full JSON Schema validator accepts."""
    jsonschema = pytest.importorskip("jsonschema")  # in the 'dev' extra

    from hdrcl.io.jsondoc import MANIFEST_SCHEMA, RESPONSE_SCHEMA, problem

    checked = []
    validators = {id(sch): jsonschema.Draft202012Validator(sch) for sch in (RESPONSE_SCHEMA, MANIFEST_SCHEMA)}

    @FUZZ
    @given(edits=_edits)
    def agree(edits):
        for schema, doc in ((RESPONSE_SCHEMA, base["resp"]),
                            (MANIFEST_SCHEMA, {"sets": [{"files": ["a"], "exposures": [0.1], "index": 0}]})):
            d = _edit(doc, edits)
            ours = problem(d, schema) is None
            theirs = validators[id(schema)].is_valid(d)
            assert ours == theirs, (d, problem(d, schema))
            checked.append(ours)

    agree()
    assert True in checked and False in checked
