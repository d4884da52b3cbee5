"""Radiance's ``.cal`` expression language as ``pcomb -f`` reads it: a parser and a
vectorised NumPy evaluator (Radiance's ``calexpr.c`` / ``caldefn.c`` / ``calfunc.c``).

The language (everything else is refused with one line naming the file, the line and
the token; :class:`~hdrcl.errors.InputError`, exit code 3):

* statements ``name = expr;`` and ``name : expr;`` (a constant; evaluated alike here),
  functions ``f(a, b) = expr;``; the last ``;`` may be left out, empty statements are
  skipped; a later definition of a name replaces the earlier one;
* ``+ - * /`` (left associative), ``^`` (right associative, ``2^3^2 = 512``), a unary
  ``-`` or ``+`` binds tighter than ``^`` as in Radiance (``-2^2 = 4``), parentheses at
  any depth; ``/`` by 0 is 0 (Radiance prints "Division by zero" and goes on);
* comments ``{ ... }``, nested ``{ a {b} c }`` (Radiance's scanner nests them);
* numbers as Radiance's ``getnum``: ``12``, ``1.5``, ``.5``, ``2.``, ``1e-3``, ``1.E+2``;
* names: a letter, then letters, digits, ``_`` and ``.``;
* built-in functions ``sqrt exp log log10 sin cos tan asin acos atan atan2 floor ceil
  if select min max``, and ``abs`` and ``sq`` (not in pcomb's library: hdrcl accepts them
  as Radiance's ``rayinit.cal`` defines them; a file's own ``sq(x)=x*x;`` takes
  precedence); ``if(c, a, b)`` is ``a`` where ``c > 0``;
  ``select(n, a1, a2, ...)`` is ``a_round(n)`` (``select(0, ...)`` the count);
* constants ``PI`` and ``WE`` (179, Radiance's white efficacy), pcomb's variables ``x``,
  ``y`` (pixel column and row, integers, ``y = 0`` the BOTTOM row), ``xres``, ``yres``
  and inputs ``ri(1) gi(1) bi(1) li(1)`` (``li`` = ``0.265 ri + 0.670 gi + 0.065 bi``,
  Radiance's luminance; only input 1: one picture), also at an offset ``ri(1, dx, dy)``
  (the pixel at ``x + round(dx), y + round(dy)``, edges repeated, as pcomb); outputs ``ro go bo`` (or ``lo`` for
  all three; 0 when none is defined, as pcomb).

Evaluation is over whole arrays at once: every expression is computed for every pixel
(both branches of ``if``, where NumPy's results of the discarded one are ignored).
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np

from hdrcl.errors import InputError

__all__ = ["CalProgram", "parse", "parse_file", "Node", "LUMA", "call_function", "geometry_constants"]

#: Radiance's ``li()`` weights (``bright()`` of its standard primaries, as pcomb prints them).
LUMA = (0.265, 0.670, 0.065)
MAX_TEXT = 1 << 20
MAX_DEPTH = 100  # parentheses, calls and ^ nested in one expression (Python's recursion stays bounded)
MAX_HEIGHT = 150  # operators in one expression's longest chain (1+1+...: Radiance recurses as deep)
MAX_EVAL_DEPTH = 200  # definitions and function calls nested while evaluating

_FUNCS1 = {"sqrt": np.sqrt, "exp": np.exp, "log": np.log, "log10": np.log10, "sin": np.sin, "cos": np.cos,
           "tan": np.tan, "asin": np.arcsin, "acos": np.arccos, "atan": np.arctan, "floor": np.floor,
           "ceil": np.ceil, "abs": np.abs, "sq": np.square}
_SPECIAL = ("if", "select", "atan2", "min", "max")
_INPUTS = {"ri": 0, "gi": 1, "bi": 2, "li": None}
_CONSTS = {"PI": math.pi, "WE": 179.0}
_PIXEL_VARS = ("x", "y", "xres", "yres")
BUILTINS = frozenset(_FUNCS1) | frozenset(_SPECIAL) | frozenset(_INPUTS)


@dataclass(frozen=True)
class Node:
    """An expression node: ``kind`` is ``num``, ``var``, ``call``, ``neg`` or an
    operator ``+ - * / ^``; ``line`` is where it starts in the file."""

    kind: str
    value: object = None  # the number, or the name
    kids: Tuple["Node", ...] = ()
    line: int = 0

    def text(self) -> str:
        """The expression written back (fully parenthesised: for digests and messages)."""
        if self.kind == "num":
            return repr(float(self.value))
        if self.kind == "var":
            return str(self.value)
        if self.kind == "call":
            return f"{self.value}({','.join(k.text() for k in self.kids)})"
        if self.kind == "neg":
            return f"(-{self.kids[0].text()})"
        return f"({self.kids[0].text()}{self.kind}{self.kids[1].text()})"


@dataclass
class Definition:
    name: str
    params: Tuple[str, ...]
    body: Node
    constant: bool
    line: int
    is_function: bool = False


_TOKEN = re.compile(r"""
    (?P<num>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d*)?)
  | (?P<name>[A-Za-z][A-Za-z0-9_.]*)
  | (?P<op>[-+*/^(),;=:])
""", re.X)


def _strip_comments(text: str, path: str) -> str:
    """Nested ``{...}`` comments replaced by spaces (newlines kept for line numbers)."""
    out, depth, line, start_line = [], 0, 1, 0
    for ch in text:
        if ch == "{":
            if depth == 0:
                start_line = line
            depth += 1
            out.append(" ")
        elif ch == "}":
            if depth == 0:
                raise InputError(f"{path}, line {line}: '}}' without its '{{' (a Radiance comment)")
            depth -= 1
            out.append(" ")
        else:
            out.append(ch if depth == 0 or ch == "\n" else " ")
        if ch == "\n":
            line += 1
    if depth:
        raise InputError(f"{path}, line {start_line}: comment '{{' not closed ('}}' expected)")
    return "".join(out)


def _printable(text: str) -> str:
    """``text`` with control characters written as escapes (one error line, readable)."""
    return "".join(ch if ch.isprintable() else ch.encode("unicode_escape").decode("ascii") for ch in text)


def _height(node: Node) -> int:
    """The longest chain of nodes below ``node`` (iterative: no recursion)."""
    best, stack = 0, [(node, 1)]
    while stack:
        n, h = stack.pop()
        best = max(best, h)
        stack.extend((k, h + 1) for k in n.kids)
    return best


def _tokens(text: str, path: str) -> List[Tuple[str, str, int]]:
    toks, pos, line = [], 0, 1
    while pos < len(text):
        ch = text[pos]
        if ch.isspace():
            line += ch == "\n"
            pos += 1
            continue
        m = _TOKEN.match(text, pos)
        if not m:
            bad = _printable(re.match(r"\S+", text[pos:]).group(0)[:20])
            raise InputError(f"{path}, line {line}: '{bad}' is not in Radiance's .cal language "
                             f"(unexpected character '{_printable(ch)}')")
        kind = m.lastgroup
        toks.append((kind, m.group(0), line))
        pos = m.end()
    toks.append(("end", "end of file", line))
    return toks


class _Parser:
    """Recursive descent over Radiance's grammar (``getE1`` .. ``getE5``)."""

    def __init__(self, toks, path):
        self.toks, self.i, self.path, self.params = toks, 0, path, ()

    @property
    def tok(self):
        return self.toks[self.i]

    def fail(self, what: str, tok=None):
        kind, text, line = tok or self.tok
        raise InputError(f"{self.path}, line {line}: {what} at '{text}'")

    def take(self, text: str, what: str):
        if self.tok[1] != text or self.tok[0] not in ("op",):
            self.fail(f"{what} expected")
        self.i += 1

    def statements(self) -> List[Definition]:
        defs = []
        while self.tok[0] != "end":
            if self.tok[1] == ";":
                self.i += 1
                continue
            defs.append(self.statement())
            if self.tok[0] != "end":
                self.take(";", "';'")
        return defs

    def statement(self) -> Definition:
        kind, name, line = self.tok
        if kind != "name":
            self.fail("a name to define expected")
        self.i += 1
        params: Tuple[str, ...] = ()
        is_function = self.tok[1] == "("
        if is_function:
            self.i += 1
            names = []
            while True:
                if self.tok[0] != "name":
                    self.fail("a parameter name expected")
                names.append(self.tok[1])
                self.i += 1
                if self.tok[1] != ",":
                    break
                self.i += 1
            self.take(")", "')'")
            params = tuple(names)
        if name in _PIXEL_VARS or name in _INPUTS:
            self.fail(f"'{name}' is pcomb's own and cannot be defined", (kind, name, line))
        if self.tok[1] not in ("=", ":") or self.tok[0] != "op":
            self.fail("'=' or ':' expected")
        constant = self.tok[1] == ":"
        self.i += 1
        self.params = params
        body = self.e1(0)
        self.params = ()
        return Definition(name, params, body, constant, line, is_function)

    def e1(self, depth):
        if depth > MAX_DEPTH:
            self.fail("expression nested too deeply")
        left = self.e2(depth)
        while self.tok[0] == "op" and self.tok[1] in "+-":
            op, line = self.tok[1], self.tok[2]
            self.i += 1
            left = Node(op, None, (left, self.e2(depth)), line)
        return left

    def e2(self, depth):
        left = self.e3(depth)
        while self.tok[0] == "op" and self.tok[1] in "*/":
            op, line = self.tok[1], self.tok[2]
            self.i += 1
            left = Node(op, None, (left, self.e3(depth)), line)
        return left

    def e3(self, depth):
        if depth > MAX_DEPTH:
            self.fail("expression nested too deeply")
        left = self.e4(depth)
        if self.tok[0] == "op" and self.tok[1] == "^":
            line = self.tok[2]
            self.i += 1
            return Node("^", None, (left, self.e3(depth + 1)), line)
        return left

    def e4(self, depth):
        if self.tok[0] == "op" and self.tok[1] in "+-":
            sign, line = self.tok[1], self.tok[2]
            self.i += 1
            kid = self.e5(depth)
            if sign == "+":
                return kid
            if kid.kind == "num":
                return Node("num", -kid.value, (), kid.line)
            return kid.kids[0] if kid.kind == "neg" else Node("neg", None, (kid,), line)
        return self.e5(depth)

    def e5(self, depth):
        kind, text, line = self.tok
        if kind == "op" and text == "(":
            self.i += 1
            node = self.e1(depth + 1)
            self.take(")", "')'")
            return node
        if kind == "num":
            self.i += 1
            return Node("num", _number(text), (), line)
        if kind == "name":
            self.i += 1
            if self.tok[0] == "op" and self.tok[1] == "(":
                self.i += 1
                args = [self.e1(depth + 1)]
                while self.tok[0] == "op" and self.tok[1] == ",":
                    self.i += 1
                    args.append(self.e1(depth + 1))
                self.take(")", "')'")
                return Node("call", text, tuple(args), line)
            return Node("var", text, (), line)
        self.fail("unexpected token" if kind != "end" else "unexpected end of file")


def _number(text: str) -> float:
    if text[-1] in "eE+-":  # Radiance's atof("1e") is 1
        text = text.rstrip("eE+-")
    return float(text)


@dataclass
class CalProgram:
    """A parsed ``.cal`` text; :meth:`evaluate` computes names over a picture."""

    path: str
    definitions: Dict[str, Definition] = field(default_factory=dict)

    def canonical(self) -> str:
        """The definitions written back in order (a digest of what the file means)."""
        parts = []
        for d in self.definitions.values():
            head = f"{d.name}({','.join(d.params)})" if d.is_function else d.name
            parts.append(f"{head}{':' if d.constant else '='}{d.body.text()};")
        return "".join(parts)

    def defines(self, name: str) -> bool:
        return name in self.definitions and not self.definitions[name].is_function

    def check_names(self) -> None:
        """Every name used is defined, built in or pcomb's own; calls match arities."""
        for d in self.definitions.values():
            self._check(d.body, set(d.params))

    def _check(self, node: Node, params) -> None:
        if node.kind == "var":
            name = node.value
            d = self.definitions.get(name)
            if name in params or name in _PIXEL_VARS or (name in _CONSTS and (d is None or d.is_function)):
                return
            if d is None or d.is_function:
                what = "a function used as a variable" if d is not None or name in BUILTINS else "undefined variable"
                raise InputError(f"{self.path}, line {node.line}: {what} '{name}'")
            return
        if node.kind == "call":
            self._check_call(node, params)
        for k in node.kids:
            self._check(k, params)

    def _check_call(self, node: Node, params) -> None:
        name, n = node.value, len(node.kids)
        d = self.definitions.get(name)
        if d is not None and d.is_function:
            if n != len(d.params):
                raise InputError(f"{self.path}, line {node.line}: {name}() takes {len(d.params)} "
                                 f"argument(s), not {n}")
            return
        if name in _INPUTS:
            arg = node.kids[0]
            if n not in (1, 3) or arg.kind != "num" or arg.value != 1:
                raise InputError(f"{self.path}, line {node.line}: only the one input picture exists: "
                                 f"'{name}(1)' or '{name}(1,dx,dy)', not '{node.text()}'")
            return
        wanted = {"if": (3, 3), "atan2": (2, 2), "select": (2, 10 ** 6), "min": (1, 10 ** 6),
                  "max": (1, 10 ** 6)}.get(name, (1, 1) if name in _FUNCS1 else None)
        if wanted is None:
            raise InputError(f"{self.path}, line {node.line}: undefined function '{name}' "
                             f"(not in Radiance's .cal language as pcomb reads it)")
        if not wanted[0] <= n <= wanted[1]:
            raise InputError(f"{self.path}, line {node.line}: {name}() with {n} argument(s)")

    # -- evaluation ------------------------------------------------------------------
    def evaluate(self, names, *, xres: int, yres: int, inputs=None, x=None, y=None) -> Dict[str, np.ndarray]:
        """``{name: array}`` of the ``names`` over an ``xres x yres`` picture (rows top
        to bottom; pcomb's ``y`` counts from the bottom) or over given ``x``, ``y``
        arrays; ``inputs``: ``(R, G, B)`` arrays broadcastable to the picture (or None:
        a file that reads them is then an error). Undefined outputs ``ro go bo`` are
        ``lo`` or 0 as in pcomb."""
        if x is None:
            x = np.arange(xres, dtype=np.float64)[None, :]
            y = (yres - 1 - np.arange(yres, dtype=np.float64))[:, None]
        env = _Env(self, np.asarray(x, np.float64), np.asarray(y, np.float64), float(xres), float(yres), inputs)
        shape = np.broadcast_shapes(np.shape(env.x), np.shape(env.y))
        out = {}
        with np.errstate(all="ignore"), _no_recursion_error(self.path):
            for name in names:
                if name in self.definitions:
                    value = env.var(name, self.definitions[name].line, 0)
                elif name in ("ro", "go", "bo") and "lo" in self.definitions:
                    value = env.var("lo", self.definitions["lo"].line, 0)
                elif name in ("ro", "go", "bo", "lo"):
                    value = 0.0
                else:
                    raise InputError(f"{self.path}: defines no '{name}'")
                out[name] = np.broadcast_to(np.asarray(value, np.float64), shape)
        return out


class _no_recursion_error:
    """A RecursionError while evaluating becomes one InputError line naming the file."""

    def __init__(self, path: str):
        self.path = path

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is RecursionError:
            raise InputError(f"{self.path}: definitions nested too deeply to evaluate") from None
        return False


class _Env:
    """One evaluation: pixel variables, the inputs, the memo of global variables."""

    def __init__(self, prog: CalProgram, x, y, xres, yres, inputs):
        self.prog, self.x, self.y, self.xres, self.yres = prog, x, y, xres, yres
        self.inputs = None if inputs is None else tuple(np.asarray(c, np.float64) for c in inputs)
        self.memo: Dict[str, object] = {}
        self.active: set = set()

    def var(self, name: str, line: int, depth: int):
        if name in self.memo:
            return self.memo[name]
        if name == "x":
            return self.x
        if name == "y":
            return self.y
        if name in ("xres", "yres"):
            return getattr(self, name)
        d = self.prog.definitions.get(name)
        if (d is None or d.is_function) and name in _CONSTS:
            return _CONSTS[name]
        if d is None or d.is_function:
            raise InputError(f"{self.prog.path}, line {line}: undefined variable '{name}'")
        if name in self.active:
            raise InputError(f"{self.prog.path}, line {d.line}: '{name}' is defined by itself (recursion)")
        self.active.add(name)
        value = self.eval(d.body, {}, depth + 1)
        self.active.discard(name)
        self.memo[name] = value
        return value

    def eval(self, node: Node, args: dict, depth: int):
        if depth > MAX_EVAL_DEPTH:
            raise InputError(f"{self.prog.path}, line {node.line}: definitions nested too deeply (recursion?)")
        k = node.kind
        if k == "num":
            return node.value
        if k == "var":
            return args[node.value] if node.value in args else self.var(node.value, node.line, depth)
        if k == "neg":
            return -np.asarray(self.eval(node.kids[0], args, depth))
        if k == "call":
            return self.call(node, args, depth)
        a = np.asarray(self.eval(node.kids[0], args, depth), np.float64)
        b = np.asarray(self.eval(node.kids[1], args, depth), np.float64)
        if k == "+":
            return a + b
        if k == "-":
            return a - b
        if k == "*":
            return a * b
        if k == "/":
            return np.where(b == 0.0, 0.0, a / np.where(b == 0.0, 1.0, b))
        return np.power(a, b)

    def call(self, node: Node, args: dict, depth: int):
        name = node.value
        d = self.prog.definitions.get(name)
        if d is not None and d.is_function:
            vals = {p: self.eval(a, args, depth + 1) for p, a in zip(d.params, node.kids)}
            return self.eval(d.body, vals, depth + 1)
        if name in _INPUTS:
            if self.inputs is None:
                raise InputError(f"{self.prog.path}, line {node.line}: '{name}(1)' reads the picture, "
                                 f"which this file's role does not allow")
            chans = self.inputs
            if len(node.kids) == 3:  # pcomb's ri(1, dx, dy): the pixel at the nearest offset, edges repeated
                chans = self.shifted(node, args, depth)
            c = _INPUTS[name]
            if c is None:
                r, g, b = chans
                return LUMA[0] * r + LUMA[1] * g + LUMA[2] * b
            return chans[c]
        vals = [np.asarray(self.eval(a, args, depth + 1), np.float64) for a in node.kids]
        if name in _FUNCS1:
            return _FUNCS1[name](vals[0])
        if name == "if":
            return np.where(vals[0] > 0, vals[1], vals[2])
        if name == "atan2":
            return np.arctan2(vals[0], vals[1])
        if name == "min":
            return np.minimum.reduce(np.broadcast_arrays(*vals))
        if name == "max":
            return np.maximum.reduce(np.broadcast_arrays(*vals))
        return self.select(node, vals)

    def shifted(self, node: Node, args: dict, depth: int):
        """The inputs at ``(x + round(dx), y + round(dy))``, clamped to the picture (pcomb)."""
        # non-finite offsets (the discarded branch of an if(), evaluated here for every pixel) read the pixel itself
        dx, dy = (np.nan_to_num(np.asarray(self.eval(a, args, depth + 1), np.float64), nan=0.0, posinf=0.0,
                                neginf=0.0) for a in node.kids[1:])
        h, w = int(self.yres), int(self.xres)
        full = [np.broadcast_to(ch, (h, w)) for ch in self.inputs]
        xx = np.clip(self.x + np.floor(dx + 0.5), 0, w - 1).astype(np.int64)
        yy = np.clip(self.y + np.floor(dy + 0.5), 0, h - 1).astype(np.int64)
        xx, yy = np.broadcast_arrays(xx, yy)
        return tuple(ch[h - 1 - yy, xx] for ch in full)

    def select(self, node: Node, vals):
        n = np.floor(vals[0] + 0.5)
        choices = vals[1:]
        if np.any((n < 0) | (n > len(choices))):
            raise InputError(f"{self.prog.path}, line {node.line}: select() index out of 0..{len(choices)}")
        out = np.where(n == 0, float(len(choices)), 0.0)
        for i, c in enumerate(choices, 1):
            out = np.where(n == i, c, out)
        return out


def call_function(prog: CalProgram, name: str, *values) -> np.ndarray:
    """A function the program defines (``rad(r)``), evaluated on arrays ``values``."""
    d = prog.definitions.get(name)
    if d is None or not d.is_function:
        raise InputError(f"{prog.path}: defines no function {name}()")
    if len(d.params) != len(values):
        raise InputError(f"{prog.path}, line {d.line}: {name}() takes {len(d.params)} argument(s)")
    env = _Env(prog, np.zeros(1), np.zeros(1), 1.0, 1.0, None)
    with np.errstate(all="ignore"), _no_recursion_error(prog.path):
        return np.asarray(env.eval(d.body, dict(zip(d.params, (np.asarray(v, np.float64) for v in values))), 0),
                          np.float64)


def parse(text: str, path: str = "<expression>") -> CalProgram:
    """The program of ``.cal`` text (:class:`InputError` naming ``path``, line, token)."""
    toks = _tokens(_strip_comments(text, path), path)
    prog = CalProgram(path)
    try:
        for d in _Parser(toks, path).statements():
            if _height(d.body) > MAX_HEIGHT:
                raise InputError(f"{path}, line {d.line}: the expression of '{d.name}' is nested more than "
                                 f"{MAX_HEIGHT} operators deep")
            prog.definitions.pop(d.name, None)
            prog.definitions[d.name] = d
        prog.check_names()
    except RecursionError:
        raise InputError(f"{path}: expressions nested too deeply") from None
    return prog


def parse_file(path) -> CalProgram:
    """The program of a ``.cal`` file."""
    path = os.fspath(path)
    try:
        with open(path, "r", encoding="utf-8-sig") as f:
            text = f.read(MAX_TEXT + 1)
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text .cal file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(text) > MAX_TEXT:
        raise InputError(f"{path}: a .cal file of more than {MAX_TEXT} characters")
    return parse(text, path)


def geometry_constants(prog: CalProgram) -> Dict[str, float]:
    """The constants a file compares pixel positions with: ``xc`` of ``x - C``, ``yc`` of
    ``y - C`` and ``radius`` of ``... / R`` over an expression of ``x`` and ``y``
    (None where the file has none or writes them with ``xres``/``yres``)."""
    found: Dict[str, Optional[float]] = {}

    def constant(node: Node) -> Optional[float]:
        """The value of a subexpression of numbers and + - * / alone, else None."""
        if node.kind == "num":
            return float(node.value)
        if node.kind == "neg":
            v = constant(node.kids[0])
            return None if v is None else -v
        if node.kind in ("+", "-", "*", "/"):
            a, b = constant(node.kids[0]), constant(node.kids[1])
            if a is None or b is None or (node.kind == "/" and b == 0):
                return None if node.kind != "/" or a is None or b is None else 0.0
            return {"+": a + b, "-": a - b, "*": a * b, "/": a / b if b else 0.0}[node.kind]
        return None

    def uses_xy(node: Node, seen) -> bool:
        if node.kind == "var":
            if node.value in ("x", "y"):
                return True
            d = prog.definitions.get(node.value)
            if d is not None and node.value not in seen:
                return uses_xy(d.body, seen | {node.value})
        return any(uses_xy(k, seen) for k in node.kids)

    def walk(node: Node) -> None:
        if node.kind == "-" and node.kids[0].kind == "var" and constant(node.kids[1]) is not None:
            name = {"x": "xc", "y": "yc"}.get(node.kids[0].value)
            if name:
                found.setdefault(name, constant(node.kids[1]))
        if node.kind == "/" and constant(node.kids[1]) is not None and uses_xy(node.kids[0], frozenset()):
            found.setdefault("radius", constant(node.kids[1]))
        for k in node.kids:
            walk(k)

    try:
        for d in prog.definitions.values():
            walk(d.body)
    except RecursionError:  # definitions chained thousands deep: no geometry to compare
        return {}
    return found
