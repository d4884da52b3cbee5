"""JSON documents hdrcl reads (response curves, manifests): decoding and schema checks.

Every problem becomes one :class:`~hdrcl.errors.InputError` line that names the file and,
for a document that decodes, the path of the bad field (``sets[2].files[0]``):

* the bytes are decoded as UTF-8 with or without a byte-order mark; a binary file (a
  JPEG given as a manifest) is named as such instead of a codec's complaint;
* nesting deeper than :data:`MAX_DEPTH` is refused before any recursion can overflow;
* :func:`validate` checks a document against a schema written in JSON Schema's
  vocabulary. Only the keywords hdrcl's schemas use are implemented (``type``,
  ``enum``, ``const``, ``minimum``, ``exclusiveMinimum``, ``maximum``, ``minItems``,
  ``maxItems``, ``items``, ``properties``, ``required``, ``additionalProperties``,
  ``minLength``); the schemas stay valid JSON Schema, so a full validator accepts
  exactly the same documents (``tests/test_fuzz_readers.py`` cross-checks this when the
  ``jsonschema`` package is installed). A library dependency was not worth it for two
  small schemas: its messages would need rewording anyway.
"""
from __future__ import annotations

import json
import logging
import math
import os
from typing import Any, Optional

from hdrcl.errors import InputError, check_regular

logger = logging.getLogger(__name__)

#: Deepest nesting of arrays and objects accepted in a document.
MAX_DEPTH = 64
#: Largest document read (bytes); response curves of 16-bit cameras are ~1 MB.
MAX_BYTES = 64 << 20

_MAGIC = (
    (b"\xff\xd8\xff", "a JPEG image"), (b"\x89PNG", "a PNG image"), (b"II*\x00", "a TIFF image"),
    (b"MM\x00*", "a TIFF image"), (b"v/1\x01", "an OpenEXR image"), (b"#?RADIANCE", "a Radiance HDR image"),
    (b"#?RGBE", "a Radiance HDR image"), (b"PF\n", "a PFM image"), (b"Pf\n", "a PFM image"),
    (b"PK\x03\x04", "a ZIP archive"), (b"%PDF", "a PDF document"),
)


def read_json(path, what: str) -> Any:
    """Read and decode the JSON document ``path``.

    Parameters
    ----------
    path : str or os.PathLike
    what : str
        The kind of document, for messages (``"response file"``, ``"manifest"``).

    Returns
    -------
    object
        The decoded document (not yet validated: see :func:`validate`).

    Raises
    ------
    InputError
        Missing, a folder, a FIFO or device, unreadable, binary, not UTF-8, not JSON, or nested deeper
        than :data:`MAX_DEPTH`; the message names ``path``.
    """
    name = os.fspath(path)
    if not os.path.lexists(name):
        raise InputError(f"{name}: no such {what}")
    check_regular(name, what)  # a FIFO or a device would block or never end
    try:
        with open(name, "rb") as fh:
            data = fh.read(MAX_BYTES + 1)
    except FileNotFoundError:
        raise InputError(f"{name}: no such {what}") from None
    except PermissionError:
        raise InputError(f"{name}: permission denied") from None
    except OSError as exc:
        raise InputError(f"{name}: cannot read {what} ({exc.strerror or exc})") from None
    return loads(data, name, what)


def read_state(path, what: str) -> Optional[dict]:
    """One of hdrcl's own state files (a batch's report, a pooled response, a set's
    report) as a dict, or None when it is absent or damaged.

    The same guards as :func:`read_json` (size, nesting, binary data, FIFOs) apply; any
    problem means "absent or stale": it is logged (info for a damaged file, debug for a
    missing one) and the caller rebuilds the file. The caller still checks the types of
    the fields it uses.
    """
    name = os.fspath(path)
    try:
        d = read_json(name, what)
    except InputError as exc:
        level = logging.DEBUG if not os.path.lexists(name) else logging.INFO
        logger.log(level, "%s; it is rebuilt", exc)
        return None
    if not isinstance(d, dict):
        logger.info("%s: damaged %s (not a JSON object); it is rebuilt", name, what)
        return None
    return d


def loads(data: bytes, name: str, what: str) -> Any:
    """Decode ``data`` (bytes of the file ``name``) as :func:`read_json` does."""
    if len(data) > MAX_BYTES:
        raise InputError(f"{name}: too large for a {what} (over {MAX_BYTES >> 20} MiB)")
    for magic, kind in _MAGIC:
        if data.startswith(magic):
            raise InputError(f"{name}: not a {what} (it is {kind})")
    if not data.strip():
        raise InputError(f"{name}: empty file, not a {what}")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"{name}: not a {what} (not UTF-8 text: byte {exc.start})") from None
    if "\x00" in text:
        raise InputError(f"{name}: not a {what} (binary data)")
    depth = _bracket_depth(text)
    if depth > MAX_DEPTH:
        raise InputError(f"{name}: {what} nested too deeply ({depth} levels, at most {MAX_DEPTH})")
    try:
        return json.loads(text, parse_constant=_no_constant)
    except json.JSONDecodeError as exc:
        raise InputError(f"{name}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})") from None
    except ValueError as exc:  # NaN/Infinity literals, huge integers
        raise InputError(f"{name}: not valid JSON ({str(exc).splitlines()[0]})") from None
    except RecursionError:  # unreachable after the depth check; kept as a guard
        raise InputError(f"{name}: {what} nested too deeply") from None


def _no_constant(token: str):
    raise ValueError(f"{token} is not a JSON number")


def _bracket_depth(text: str) -> int:
    """Deepest nesting of [ and { outside strings (an upper bound for valid JSON)."""
    depth = best = 0
    in_str = esc = False
    for ch in text:
        if in_str:
            if esc:
                esc = False
            elif ch == "\\":
                esc = True
            elif ch == '"':
                in_str = False
        elif ch == '"':
            in_str = True
        elif ch in "[{":
            depth += 1
            if depth > best:
                best = depth
                if best > MAX_DEPTH:
                    return best
        elif ch in "]}":
            depth -= 1
    return best


_TYPES = {
    "object": lambda v: isinstance(v, dict),
    "array": lambda v: isinstance(v, list),
    "string": lambda v: isinstance(v, str),
    "integer": lambda v: (isinstance(v, int) and not isinstance(v, bool))
    or (isinstance(v, float) and math.isfinite(v) and v.is_integer()),
    "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v),
    "boolean": lambda v: isinstance(v, bool),
    "null": lambda v: v is None,
}
_NAMES = {"object": "an object", "array": "a list", "string": "a string", "integer": "an integer",
          "number": "a number", "boolean": "true or false", "null": "null"}


def problem(value: Any, schema: dict, path: str = "") -> Optional[str]:
    """The first way ``value`` breaks ``schema``, as ``"path: problem"``; None if it fits."""
    where = path or "the document"
    if "const" in schema and not _equal(value, schema["const"]):
        return f"{where}: expected {json.dumps(schema['const'])}, not {_show(value)}"
    if "enum" in schema and not any(_equal(value, e) for e in schema["enum"]):
        return f"{where}: expected one of {', '.join(json.dumps(e) for e in schema['enum'])}, not {_show(value)}"
    types = schema.get("type")
    if types is not None:
        types = [types] if isinstance(types, str) else list(types)
        if not any(_TYPES[t](value) for t in types):
            return f"{where}: expected {' or '.join(_NAMES[t] for t in types)}, not {_show(value)}"
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if "minimum" in schema and not value >= schema["minimum"]:
            return f"{where}: must be at least {schema['minimum']}, not {_show(value)}"
        if "exclusiveMinimum" in schema and not value > schema["exclusiveMinimum"]:
            return f"{where}: must be greater than {schema['exclusiveMinimum']}, not {_show(value)}"
        if "maximum" in schema and not value <= schema["maximum"]:
            return f"{where}: must be at most {schema['maximum']}, not {_show(value)}"
    if isinstance(value, str) and len(value) < schema.get("minLength", 0):
        return f"{where}: must not be empty"
    if isinstance(value, list):
        if len(value) < schema.get("minItems", 0):
            return f"{where}: needs at least {schema['minItems']} item(s), has {len(value)}"
        if "maxItems" in schema and len(value) > schema["maxItems"]:
            return f"{where}: at most {schema['maxItems']} item(s), has {len(value)}"
        if "items" in schema:
            for i, item in enumerate(value):
                p = problem(item, schema["items"], f"{path}[{i}]")
                if p:
                    return p
    if isinstance(value, dict):
        for key in schema.get("required", ()):
            if key not in value:
                return f"{where}: missing '{key}'"
        props = schema.get("properties", {})
        extra = schema.get("additionalProperties", True)
        for key, item in value.items():
            sub = f"{path}.{key}" if path else str(key)
            if key in props:
                p = problem(item, props[key], sub)
            elif extra is False:
                p = f"{sub}: unknown field"
            elif isinstance(extra, dict):
                p = problem(item, extra, sub)
            else:
                p = None
            if p:
                return p
    return None


def validate(value: Any, schema: dict, source: str) -> None:
    """Raise :class:`InputError` ``"<source>: <path>: <problem>"`` unless ``value`` fits."""
    p = problem(value, schema)
    if p:
        raise InputError(f"{source}: {p}")


def _equal(a, b) -> bool:
    return type(a) is type(b) and a == b if isinstance(a, bool) or isinstance(b, bool) else a == b


def _show(value: Any) -> str:
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, list):
        return "a list"
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:37] + "..."


# --------------------------------------------------------------------------- schemas
_NUM = {"type": "number"}
_POS = {"type": "number", "exclusiveMinimum": 0}
_OPT_NUM = {"type": ["number", "null"]}
_SCALAR = {"type": ["string", "number", "boolean", "null"]}

#: Response curve files (``hdrcl calibrate -o``, ``--save-response``), format version 1.
#: Cross-field checks (one curve per channel, as long as ``knots``) follow in
#: ``Response.from_dict``.
RESPONSE_SCHEMA = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "hdrcl response curve",
    "type": "object",
    "required": ["format", "bits", "channels", "knots", "g"],
    "properties": {
        "format": {"const": "hdrcl-response"},
        "version": {"type": "integer", "minimum": 1, "maximum": 1},  # RESPONSE_VERSION
        "bits": {"enum": [8, 16]},
        "levels": {"enum": [256, 65536]},
        "channels": {"type": "array", "minItems": 1, "maxItems": 4,
                     "items": {"type": "string", "minLength": 1}},
        "knots": {"type": "array", "minItems": 3, "maxItems": 65536, "items": _NUM},
        "g": {"type": "object",
              "additionalProperties": {"type": "array", "minItems": 3, "maxItems": 65536, "items": _NUM}},
        "smoothness": {"type": "number", "minimum": 0},
        "weight": {"enum": ["hat", "gaussian"]},
        "samples": {"type": "integer", "minimum": 0},
        "seed": {"type": "integer"},
        "camera": {"type": ["object", "null"], "additionalProperties": _SCALAR},
        "exposures": {"type": ["array", "null"], "items": {
            "type": "object",
            "required": ["nominal", "used"],
            "properties": {"file": {"type": ["string", "null"]}, "nominal": _POS, "used": _POS,
                           "fitted": {"type": ["number", "null"], "exclusiveMinimum": 0}},
            "additionalProperties": _SCALAR}},
        "warnings": {"type": ["array", "null"], "items": {"type": "string"}},
    },
}

_FILES = {"type": "array", "minItems": 1, "items": {"type": "string", "minLength": 1}}

#: Manifests (``hdrcl scan -o``, possibly edited by hand). Cross-field checks (a file in
#: two sets, repeated indices, as many exposures as files) follow in ``Manifest.from_dict``.
MANIFEST_SCHEMA = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "hdrcl manifest",
    "type": "object",
    "required": ["sets"],
    "properties": {
        "root": {"type": ["string", "null"]},
        "sets": {"type": "array", "items": {
            "type": "object",
            "required": ["files"],
            "properties": {
                "index": {"type": ["integer", "null"], "minimum": 0},
                "files": _FILES,
                "exposures": {"type": ["array", "null"], "items": _POS},
                "reason": {"type": "string"},
                "start": {"type": ["string", "null"]},
                "camera": {"type": ["string", "null"]},
                "serial": {"type": ["string", "null"]},
                "lens": {"type": ["string", "null"]},
                "focal_length": _OPT_NUM,
                "fnumber": _OPT_NUM,
                "iso": {"type": ["array", "null"], "items": _OPT_NUM},
                "ev": {"type": ["array", "null"], "items": _OPT_NUM},
                "gaps": {"type": ["array", "null"], "items": _OPT_NUM},
                "width": {"type": ["integer", "null"], "minimum": 0},
                "height": {"type": ["integer", "null"], "minimum": 0},
            }}},
        "unmerged": {"type": ["array", "null"], "items": {
            "type": "object", "required": ["files"],
            "properties": {"files": _FILES, "reason": {"type": "string"}}}},
    },
}
