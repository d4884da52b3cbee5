"""Radiance's ``.cal`` expression language as ``pcomb -f`` reads it: a parser and a
vectorised NumPy evaluator (Radiance's ``calexpr.c`` / ``caldefn.c`` / ``calfunc.c``).

The language (everything else is refused with one line naming the file, the line and
the token; :class:`~hdrcl.errors.InputError`, exit code 3):

* statements ``name = expr;`` and ``name : expr;`` (a constant: folded where its value is
  constant, as Radiance folds it; one that depends on ``x``, ``y`` is evaluated per pixel
  here, where Radiance keeps the first pixel's value and warns),
  functions ``f(a, b) = expr;``; the last ``;`` may be left out, empty statements are
  skipped; a later definition of a name replaces the earlier one;
* ``+ - * /`` (left associative), ``^`` (right associative, ``2^3^2 = 512``), a unary
  ``-`` or ``+`` binds tighter than ``^`` as in Radiance (``-2^2 = 4``), parentheses at
  any depth (up to :data:`MAX_DEPTH` levels; Radiance's own stack gives out near 50000);
  a division by a constant 0 (``x/0``, ``x/(1-1)``) and a constant expression that fails
  (``1/0``, ``select(5, 1, 2)``) are refused as Radiance refuses them ("divide by zero
  constant", "bad constant expression"); the rest of the errors happen per pixel, as
  :mod:`hdrcl.io.caleval` describes (``x/0`` at run time is 0, ``sin()`` of it 0);
* comments ``{ ... }``, nested ``{ a {b} c }`` (Radiance's scanner nests them), holding any
  bytes: a file is read as bytes and decoded as UTF-8, else Latin-1 (``{ gemessen von
  Jürgen, 21 °C }`` written by a Latin-1 editor reads as pcomb reads it);
* numbers as Radiance's ``getnum``: ``12``, ``1.5``, ``.5``, ``2.``, ``1e-3``, ``1.E+2``
  (``1e`` is "missing exponent", as in Radiance);
* names: a letter, then letters, digits, ``_`` and ``.``;
* built-in functions ``sqrt exp log log10 sin cos tan asin acos atan atan2 floor ceil
  if select min max``, user functions calling themselves (``fact(n) = if(n - 1.5,
  n * fact(n - 1), 1)``, to :data:`~hdrcl.io.caleval.MAX_CALLS` deep), and ``abs`` and
  ``sq`` (not in pcomb's library: hdrcl accepts them as Radiance's ``rayinit.cal`` defines
  them; a file's own ``sq(x)=x*x;`` takes precedence); ``if(c, a, b)`` is ``a`` where ``c > 0``;
  ``select(n, a1, a2, ...)`` is ``a_round(n)`` (``select(0, ...)`` the count);
* constants ``PI`` and ``WE`` (179, Radiance's white efficacy), pcomb's variables ``x``,
  ``y`` (pixel column and row, integers, ``y = 0`` the BOTTOM row), ``xres``, ``yres``
  and inputs ``ri(1) gi(1) bi(1) li(1)`` (``li`` = ``0.265 ri + 0.670 gi + 0.065 bi``,
  Radiance's luminance; only input 1: one picture), also at an offset ``ri(1, dx, dy)``
  (the pixel at ``x + round(dx), y + round(dy)``, edges repeated, as pcomb); outputs
  ``ro go bo`` (or ``lo`` for all three; 0 when none is defined, as pcomb).

Evaluation is over whole arrays at once, each branch of ``if``/``select`` on the pixels
that take it (:mod:`hdrcl.io.caleval`). The parser runs on an explicit stack (no Python
recursion), so 400 nested parentheses or a 100000-term sum are read.
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np

from hdrcl.errors import InputError
from hdrcl.io import caleval
from hdrcl.io.caleval import LUMA

__all__ = ["CalProgram", "parse", "parse_file", "Node", "LUMA", "call_function", "decode"]

MAX_TEXT = 1 << 20
MAX_DEPTH = 20000  # parentheses, calls and ^ nested in one expression (rcalc reads 20000, crashes at 100000)

_FUNCS1 = caleval.FUNCS1
_INPUTS = caleval.INPUTS
_CONSTS = caleval.CONSTS
_PIXEL_VARS = caleval.PIXEL_VARS
BUILTINS = caleval.LIBRARY


@dataclass(frozen=True)
class Node:
    """An expression node: ``kind`` is ``num``, ``var``, ``call``, ``neg``, an operator
    ``+ - * / ^`` or ``alias`` (evaluated as its first kid, written as its second: ``E^1``);
    a ``num`` with a kid is a constant folded as Radiance folds it, written as the kid;
    ``line`` is where it starts in the file."""

    kind: str
    value: object = None  # the number, or the name
    kids: Tuple["Node", ...] = ()
    line: int = 0

    def text(self, readable: bool = False) -> str:
        """The expression written back, fully parenthesised, for digests (``repr`` of the
        numbers) or ``readable`` for messages (``(-8)^(1/3)``); iterative, so a
        100000-term sum is written too."""
        out, stack = [], [self]
        while stack:
            n = stack.pop()
            if isinstance(n, str):
                out.append(n)
            elif n.kind == "num" and n.kids:  # a folded constant: written as it was
                stack.append(n.kids[0])
            elif n.kind == "alias":  # evaluated as kids[0], written as kids[1]
                stack.append(n.kids[1])
            elif n.kind == "num":
                v = float(n.value)
                out.append(repr(v) if not readable else f"({v:.12g})" if v < 0 else f"{v:.12g}")
            elif n.kind == "var":
                out.append(str(n.value))
            elif n.kind == "call":
                parts = [f"{n.value}("]
                for i, k in enumerate(n.kids):
                    parts += [","] * (i > 0) + [k]
                stack.extend(reversed(parts + [")"]))
            elif n.kind == "neg":
                stack.extend((")", n.kids[0], "(-"))
            else:
                stack.extend((")", n.kids[1], n.kind, n.kids[0], "("))
        return "".join(out)


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
        if kind == "num" and m.group(0)[-1] in "eE+-":
            raise InputError(f"{path}, line {line}: missing exponent in the number '{m.group(0)}' "
                             f"(Radiance refuses it too)")
        toks.append((kind, m.group(0), line))
        pos = m.end()
    toks.append(("end", "end of file", line))
    return toks


class _Parser:
    """Radiance's grammar (``getE1`` .. ``getE5``) as generators run on an explicit stack
    (:func:`hdrcl.io.caleval.run`): a sub-expression is ``yield``-ed, not called."""

    def __init__(self, toks, path):
        self.toks, self.i, self.path, self.params = toks, 0, path, ()
        self.cv: Dict[int, tuple] = {}  # (node, value) of each constant node, by id (kept alive)
        self.const_vars: Dict[str, float] = {}  # 'name : constant' definitions read so far
        # functions the file defines (its own abs(), sq() are not library functions to fold)
        self.functions = {t[1] for i, t in enumerate(toks[:-1]) if t[0] == "name" and toks[i + 1][1] == "("
                          and (i == 0 or toks[i - 1][1] == ";")}

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
        body = caleval.run(self.e1(0), self._too_deep)
        self.params = ()
        if constant and not is_function and id(body) in self.cv:
            self.const_vars[name] = self.cv[id(body)][1]
        else:
            self.const_vars.pop(name, None)
        self.cv = {}
        return Definition(name, params, body, constant, line, is_function)

    def make(self, kind, value, kids, line) -> Node:
        return _constant(self, Node(kind, value, kids, line))

    def _too_deep(self):
        self.fail(f"expression nested more than {MAX_DEPTH} deep")

    def e1(self, depth):
        if depth > MAX_DEPTH:
            self._too_deep()
        left = yield self.e2(depth)
        while self.tok[0] == "op" and self.tok[1] in "+-":
            op, line = self.tok[1], self.tok[2]
            self.i += 1
            left = self.make(op, None, (left, (yield self.e2(depth))), line)
        return left

    def e2(self, depth):
        left = yield self.e3(depth)
        while self.tok[0] == "op" and self.tok[1] in "*/":
            op, line = self.tok[1], self.tok[2]
            self.i += 1
            left = self.make(op, None, (left, (yield self.e3(depth))), line)
        return left

    def e3(self, depth):
        if depth > MAX_DEPTH:
            self._too_deep()
        left = yield self.e4(depth)
        if self.tok[0] == "op" and self.tok[1] == "^":
            line = self.tok[2]
            self.i += 1
            return self.make("^", None, (left, (yield self.e3(depth + 1))), line)
        return left

    def e4(self, depth):
        if self.tok[0] == "op" and self.tok[1] in "+-":
            sign, line = self.tok[1], self.tok[2]
            self.i += 1
            kid = yield self.e5(depth)
            if sign == "+":
                return kid
            if kid.kind == "num" and not kid.kids:
                return self.make("num", -kid.value, (), kid.line)
            return kid.kids[0] if kid.kind == "neg" else self.make("neg", None, (kid,), line)
        return (yield self.e5(depth))

    def e5(self, depth):
        kind, text, line = self.tok
        if kind == "op" and text == "(":
            self.i += 1
            node = yield self.e1(depth + 1)
            self.take(")", "')'")
            return node
        if kind == "num":
            self.i += 1
            return self.make("num", float(text), (), line)
        if kind == "name":
            self.i += 1
            if self.tok[0] == "op" and self.tok[1] == "(":
                self.i += 1
                args = [(yield self.e1(depth + 1))]
                while self.tok[0] == "op" and self.tok[1] == ",":
                    self.i += 1
                    args.append((yield self.e1(depth + 1)))
                self.take(")", "')'")
                return self.make("call", text, tuple(args), line)
            return self.make("var", text, (), line)
        self.fail("unexpected token" if kind != "end" else "unexpected end of file")


_LIB_CONST = frozenset(_FUNCS1) | {"if", "atan2", "min", "max", "select"}


def _constant(parser, node: Node) -> Node:
    """Radiance's parse-time rules for a new node (``rconst`` and the simplifications of
    ``getE2``/``getE3``): the value of a constant node is noted (a failing one is "bad
    constant expression"); a division by a constant 0 is "divide by zero constant";
    ``0*E``, ``E*0``, ``0/E`` are 0, ``E^0`` and ``1^E`` are 1, ``0^E`` is 0 and ``E^1``
    is ``E``, without computing ``E`` (as Radiance: ``0*sin(x/0)`` warns of nothing)."""
    cv, k = parser.cv, node.kind
    if k == "num":
        cv[id(node)] = (node, float(node.value))
        return node
    if k == "var":
        if node.value in parser.const_vars and node.value not in parser.params:
            out = Node("num", parser.const_vars[node.value], (node,), node.line)
            cv[id(out)] = (out, out.value)
            return out
        return node
    vals = [cv.get(id(kid), (None, None))[1] for kid in node.kids]
    const = all(v is not None for v in vals)
    if k == "/" and vals[1] == 0.0:
        what = "division by zero in a constant expression" if const else "division by the constant 0"
        why = "bad constant expression" if const else "divide by zero constant"
        raise InputError(f"{parser.path}, line {node.line}: {what} at '{_clip(node.text(True))}' "
                         f"(Radiance refuses it: '{why}')")
    if const and (k != "call" or (node.value in _LIB_CONST and node.value not in parser.functions)):
        if k == "call" and node.value == "select":
            n = math.floor(vals[0] + 0.5) if math.isfinite(vals[0]) else -1
            if not 0 <= n < len(vals):
                raise InputError(f"{parser.path}, line {node.line}: select() index {vals[0]:g} out of "
                                 f"0..{len(vals) - 1} in a constant expression at '{_clip(node.text(True))}' "
                                 f"(Radiance refuses it: 'bad constant expression')")
            value = float(len(vals) - 1) if n == 0 else vals[n]
        else:
            value = _fold(node, vals)
        # folded as Radiance folds it (no library call at run time, which would clear the
        # errno marks), the original kept for the digest's text and to explain a NaN
        out = Node("num", value, (node,), node.line)
        cv[id(out)] = (out, value)
        return out
    a, b = (vals + [None, None])[:2]
    value = None
    if k == "*" and (a == 0.0 or b == 0.0):
        value = a if a == 0.0 else b
    elif k == "/" and a == 0.0:
        value = a
    elif k == "^":
        if b == 0.0 or a == 1.0:
            value = 1.0
        elif b == 1.0:
            return Node("alias", None, (node.kids[0], node), node.line)  # E, written as E^1 still
        elif a == 0.0:
            value = a
    if value is None:
        return node
    out = Node("num", value, (node,), node.line)  # written as it was (the digest's text stays)
    cv[id(out)] = (out, value)
    return out


def _fold(node: Node, vals) -> float:
    """The value of an operator or library function of constants (NumPy's float64)."""
    with np.errstate(all="ignore"):
        k = node.kind
        if k == "neg":
            return -vals[0]
        if k in ("+", "-", "*", "/", "^"):
            a, b = np.float64(vals[0]), np.float64(vals[1])
            return float({"+": a + b, "-": a - b, "*": a * b, "/": a / b, "^": np.power(a, b)}[k])
        if node.value == "if":
            return vals[1] if vals[0] > 0 else vals[2]
        if node.value == "atan2":
            return float(np.arctan2(vals[0], vals[1]))
        if node.value in ("min", "max"):
            return float(min(vals) if node.value == "min" else max(vals))
        return float(_FUNCS1[node.value](np.float64(vals[0])))


def _clip(text: str, limit: int = 60) -> str:
    return text if len(text) <= limit else text[:limit - 3] + "..."


@dataclass
class CalProgram:
    """A parsed ``.cal`` text; :meth:`evaluate` computes names over a picture."""

    path: str
    definitions: Dict[str, Definition] = field(default_factory=dict)
    warned: set = field(default_factory=set, repr=False, compare=False)  # causes warned about once

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
            params, stack = set(d.params), [d.body]
            while stack:
                node = stack.pop()
                if node.kind == "var":
                    self._check_var(node, params)
                elif node.kind == "call":
                    self._check_call(node, params)
                stack.extend(node.kids)

    def _check_var(self, node: Node, params) -> None:
        name = node.value
        d = self.definitions.get(name)
        if name in params or name in _PIXEL_VARS or (name in _CONSTS and (d is None or d.is_function)):
            return
        if d is None or d.is_function:
            what = "a function used as a variable" if d is not None or name in BUILTINS else "undefined variable"
            raise InputError(f"{self.path}, line {node.line}: {what} '{name}'")

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
                                 f"'{name}(1)' or '{name}(1,dx,dy)', not '{_clip(node.text(True))}'")
            return
        wanted = {"if": (3, 3), "atan2": (2, 2), "select": (2, 10 ** 6), "min": (1, 10 ** 6),
                  "max": (1, 10 ** 6)}.get(name, (1, 1) if name in _FUNCS1 else None)
        if wanted is None:
            raise InputError(f"{self.path}, line {node.line}: undefined function '{name}' "
                             f"(not in Radiance's .cal language as pcomb reads it)")
        if not wanted[0] <= n <= wanted[1]:
            raise InputError(f"{self.path}, line {node.line}: {name}() with {n} argument(s)")

    # -- evaluation ------------------------------------------------------------------
    def _evaluation(self, xres, yres, inputs, x, y, trace=False) -> caleval.Evaluation:
        if x is None:
            x = np.arange(xres, dtype=np.float64)[None, :]
            y = (yres - 1 - np.arange(yres, dtype=np.float64))[:, None]
        return caleval.Evaluation(self.definitions, self.path, x, y, xres, yres, inputs, self.warned, trace)

    def evaluate(self, names, *, xres: int, yres: int, inputs=None, x=None, y=None) -> Dict[str, np.ndarray]:
        """``{name: array}`` of the ``names`` over an ``xres x yres`` picture (rows top
        to bottom; pcomb's ``y`` counts from the bottom) or over given ``x``, ``y``
        arrays; ``inputs``: ``(R, G, B)`` arrays broadcastable to the picture (or None:
        a file that reads them is then an error). Undefined outputs ``ro go bo`` are
        ``lo`` or 0 as in pcomb."""
        return self._values(names, self._evaluation(xres, yres, inputs, x, y))

    def _values(self, names, ev: caleval.Evaluation) -> Dict[str, np.ndarray]:
        out = {}
        with np.errstate(all="ignore"):
            for name in names:
                if name in self.definitions:
                    out[name] = ev.named(name)
                elif name in ("ro", "go", "bo") and "lo" in self.definitions:
                    out[name] = ev.named("lo")
                elif name in ("ro", "go", "bo", "lo"):
                    out[name] = np.zeros(ev.shape)
                else:
                    raise InputError(f"{self.path}: defines no '{name}'")
        return out

    def why_not_finite(self, names, *, xres: int, yres: int, inputs=None, x=None, y=None) -> Optional[str]:
        """The first operation that made one of ``names`` not a finite number, described
        (``line 1: ((-8.0)^(1.0/3.0)) raises a negative number to a fractional power: not
        a number (NaN)``), or None."""
        ev = self._evaluation(xres, yres, inputs, x, y, trace=True)
        self._values(names, ev)
        return ev.cause


def call_function(prog: CalProgram, name: str, *values) -> np.ndarray:
    """A function the program defines (``rad(r)``), evaluated on arrays ``values``."""
    d = prog.definitions.get(name)
    if d is None or not d.is_function:
        raise InputError(f"{prog.path}: defines no function {name}()")
    if len(d.params) != len(values):
        raise InputError(f"{prog.path}, line {d.line}: {name}() takes {len(d.params)} argument(s)")
    values = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in values))
    ev = caleval.Evaluation(prog.definitions, prog.path, np.zeros(values[0].shape), np.zeros(values[0].shape),
                            1.0, 1.0, None, prog.warned)
    with np.errstate(all="ignore"):
        return np.array(ev.function_value(d, values), np.float64)


def parse(text: str, path: str = "<expression>") -> CalProgram:
    """The program of ``.cal`` text (:class:`InputError` naming ``path``, line, token)."""
    toks = _tokens(_strip_comments(text, path), path)
    prog = CalProgram(path)
    for d in _Parser(toks, path).statements():
        prog.definitions.pop(d.name, None)
        prog.definitions[d.name] = d
    prog.check_names()
    return prog


def decode(data: bytes, path: str) -> str:
    """The text of a ``.cal`` file's bytes: UTF-8 (a BOM dropped), else Latin-1 (Radiance
    reads bytes; comments may hold anything). NUL bytes mean it is not a text file."""
    if b"\0" in data:
        raise InputError(f"{path}: not a text .cal file (it holds NUL bytes)")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def parse_file(path) -> CalProgram:
    """The program of a ``.cal`` file."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_TEXT + 1)
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(data) > MAX_TEXT:
        raise InputError(f"{path}: a .cal file of more than {MAX_TEXT} bytes")
    return parse(decode(data, path), path)
