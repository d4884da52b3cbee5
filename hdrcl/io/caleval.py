"""The evaluator of parsed Radiance ``.cal`` programs (:mod:`hdrcl.io.calexpr`), over many
pixels at once and by Radiance's own rules (``calexpr.c``, ``caldefn.c``, ``calfunc.c``;
``rcalc`` and ``pcomb`` share them):

* **only what is taken is computed**: ``if(c, a, b)`` computes ``a`` on the pixels where
  ``c > 0`` and ``b`` on the others; ``select(n, a1, a2, ...)`` computes only the chosen
  argument; a function's arguments are computed when its body first reads them (and then
  kept, for the first six, as ``calfunc.c``'s ``ALISTSIZ``); a variable once per pixel,
  where it is first needed; ``a / b`` computes ``a`` only where ``b`` is not 0. Each branch
  is evaluated on the subset of pixels that takes it (an index array), so recursion such
  as ``fact(n) = if(n - 1.5, n * fact(n - 1), 1)`` ends pixel by pixel;
* **errors as Radiance's errno**: a division by 0 gives 0 and marks the pixel; an index out
  of ``select``'s range gives 0 and marks it ("select(): domain error"); every library
  function (``sin``, ``if``, ``select``, ``ri`` ...) and ``^`` whose arguments marked a
  pixel gives 0 there and leaves the mark for the library functions around it
  (``sin(x/0 + 1)`` is 0, ``f(x/0)`` with ``f(a) = a + 1`` is 1); each of them clears the
  marks when it starts, so ``max(x/0, sin(x))`` is ``sin(x)``, as rcalc gives it. One
  warning per cause and file line, not one per pixel as ``rcalc`` prints them;
* NumPy's NaN and infinities where Radiance's C library gives them (``(-8)^(1/3)`` is NaN,
  as ``rcalc`` prints ``-nan``); with ``trace`` the first operation that made a number
  not finite is described (:attr:`Evaluation.cause`) for the callers' error messages.

Recursion runs on an explicit stack (a trampoline over generators), so nesting depth is
limited by :data:`MAX_FRAMES` and :data:`MAX_CALLS`, not by Python's recursion limit.
"""
from __future__ import annotations

import logging
import math
from typing import Dict, Optional

import numpy as np

from hdrcl.errors import InputError

logger = logging.getLogger(__name__)

__all__ = ["Evaluation", "run", "Value", "LUMA", "FUNCS1", "INPUTS", "CONSTS", "PIXEL_VARS", "LIBRARY",
           "MAX_CALLS", "MAX_FRAMES"]

#: Radiance's ``li()`` weights (``bright()`` of its standard primaries, as pcomb prints them).
LUMA = (0.265, 0.670, 0.065)
FUNCS1 = {"sqrt": np.sqrt, "exp": np.exp, "log": np.log, "log10": np.log10, "sin": np.sin, "cos": np.cos,
          "tan": np.tan, "asin": np.arcsin, "acos": np.arccos, "atan": np.arctan, "floor": np.floor,
          "ceil": np.ceil, "abs": np.abs, "sq": np.square}
INPUTS = {"ri": 0, "gi": 1, "bi": 2, "li": None}
CONSTS = {"PI": math.pi, "WE": 179.0}
PIXEL_VARS = ("x", "y", "xres", "yres")
#: Functions with Radiance's ``libfunc`` error rule (a marked pixel gives 0 there).
LIBRARY = frozenset(FUNCS1) | {"if", "select", "atan2", "min", "max"} | frozenset(INPUTS)
MAX_CALLS = 20000  # user functions nested (rcalc warns at 10000 and runs out of stack near 50000)
MAX_FRAMES = 1_000_000  # expression nodes being evaluated at once (a 100000-term sum fits)
ALISTSIZ = 6  # calfunc.c: the first six arguments of a call are kept once computed


class Value:
    """A request already answered: the trampoline hands ``v`` straight back."""

    __slots__ = ("v",)

    def __init__(self, v):
        self.v = v


def run(gen, too_deep):
    """Drive ``gen`` (a generator that yields generators or :class:`Value`, and receives
    their results) on an explicit stack; ``too_deep()`` raises past :data:`MAX_FRAMES`."""
    if type(gen) is Value:
        return gen.v
    stack, value = [gen], None
    while True:
        try:
            req = stack[-1].send(value)
        except StopIteration as stop:
            stack.pop()
            value = stop.value
            if not stack:
                return value
            continue
        if type(req) is Value:
            value = req.v
            continue
        stack.append(req)
        value = None
        if len(stack) > MAX_FRAMES:
            too_deep()


def _sub(idx, mask):
    """The pixel indices of ``idx`` (None: all) where ``mask``."""
    return np.flatnonzero(mask) if idx is None else idx[mask]


class _Store:
    """Values per pixel as they were first computed: ``full`` (any shape that broadcasts to
    the picture's, when computed for every pixel at once) or ``vals``/``done`` by position."""

    __slots__ = ("full", "flat", "vals", "done")

    def __init__(self):
        self.full = self.flat = self.vals = self.done = None

    def missing(self, pos):
        """The positions of ``pos`` (None: all) not computed yet (None: all of them)."""
        if self.full is not None:
            return _NONE
        if self.done is None:
            return pos
        return np.flatnonzero(~self.done) if pos is None else pos[~self.done[pos]]

    def store(self, size: int, pos, v) -> None:
        if pos is None and self.done is None:
            self.full = v
            return
        if self.done is None:
            self.vals, self.done = np.zeros(size), np.zeros(size, bool)
        self.vals[pos], self.done[pos] = v, True

    def get(self, shape, pos):
        if self.full is not None:
            if pos is None or np.ndim(self.full) == 0:
                return self.full
            if self.flat is None:
                self.flat = np.broadcast_to(self.full, shape).ravel()
            return self.flat[pos]
        return self.vals.reshape(shape) if pos is None else self.vals[pos]


_NONE = np.empty(0, np.int64)


class _Arg:
    """A function argument, computed lazily in the caller's frame on the pixels asked
    (``idx``: the call's pixels; positions in the store are relative to them)."""

    __slots__ = ("node", "frame", "idx", "keep", "store", "given")

    def __init__(self, node, frame, idx, keep, given=None):
        self.node, self.frame, self.idx, self.keep, self.given = node, frame, idx, keep, given
        self.store = _Store()


class Evaluation:
    """One evaluation of a program's definitions over ``x``, ``y`` (broadcast together).

    ``definitions``: ``{name: Definition}``; ``warned``: a set shared by the program's
    evaluations so a cause is warned about once."""

    def __init__(self, definitions: Dict, path: str, x, y, xres: float, yres: float, inputs=None,
                 warned: Optional[set] = None, trace: bool = False):
        self.defs, self.path, self.xres, self.yres = definitions, path, float(xres), float(yres)
        self.shape = np.broadcast_shapes(np.shape(x), np.shape(y))
        self.n = int(np.prod(self.shape, dtype=np.int64))
        # x, y and the inputs keep their shapes for whole-picture work (x is one row, y one
        # column: a radius is computed on the broadcast, not per pixel); flattened on demand
        self.x, self.y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        self.inputs = None if inputs is None else tuple(np.asarray(c, np.float64) for c in inputs)
        self.flats: Dict[str, np.ndarray] = {}
        self.memo: Dict[str, _Store] = {}
        self.active: set = set()
        self.err: Optional[np.ndarray] = None  # Radiance's errno, per pixel
        self.events = 0
        self.calls = 0
        self.warned = set() if warned is None else warned
        self.trace, self.cause = trace, None

    # -- driving -------------------------------------------------------------------------
    def value(self, node, frame=None):
        """``node`` over every pixel, shaped like ``x`` and ``y`` broadcast together."""
        v = run(self.ev(node, None, frame), self._too_deep)
        return np.broadcast_to(np.asarray(v, np.float64), self.shape)

    def named(self, name: str):
        """The global variable ``name`` over every pixel (shaped as :meth:`value`)."""
        v = run(self.variable(name, None, 0), self._too_deep)
        return np.broadcast_to(np.asarray(v, np.float64), self.shape)

    def function_value(self, d, values):
        frame = {}
        for p, v in zip(d.params, values):
            full = np.broadcast_to(np.asarray(v, np.float64), self.shape)
            frame[p] = _Arg(None, None, None, True, given=(full, full.ravel()))
        return self.value(d.body, frame)

    def flat(self, key: str, value) -> np.ndarray:
        """``value`` broadcast to the picture and flattened (once per key)."""
        f = self.flats.get(key)
        if f is None:
            f = self.flats[key] = np.broadcast_to(value, self.shape).ravel()
        return f

    def shape_of(self, idx):
        return self.shape if idx is None else idx.shape

    def _too_deep(self):
        raise InputError(f"{self.path}: expressions nested more than {MAX_FRAMES} deep to evaluate")

    def _warn(self, node, key: str, message: str) -> None:
        if (node.line, key) not in self.warned:
            self.warned.add((node.line, key))
            logger.warning("%s, line %d: %s", self.path, node.line, message)

    # -- Radiance's errno ------------------------------------------------------------------
    def _mark(self, idx, mask) -> None:
        if self.err is None:
            self.err = np.zeros(self.n, bool)
        if idx is None:
            self.err |= np.broadcast_to(mask, self.shape).ravel()
        else:
            self.err[idx[np.broadcast_to(mask, idx.shape)]] = True
        self.events += 1

    def _clear(self, idx) -> int:
        """``libfunc``'s and ``epow``'s ``errno = 0`` on entry (the earlier marks are not
        restored after: rcalc gives ``max(x/0, sin(x))`` = sin(x)); the event count."""
        if self.err is not None:
            if idx is None:
                self.err[:] = False
            else:
                self.err[idx] = False
        return self.events

    def _finish(self, idx, events, value):
        """``libfunc``'s end: 0 where its arguments marked the pixel; the marks stay."""
        if self.events != events:
            inner = self.err.reshape(self.shape) if idx is None else self.err[idx]
            if inner.any():
                value = np.where(inner, 0.0, value)
        return value

    # -- nodes -----------------------------------------------------------------------------
    def ev(self, node, idx, frame):
        """A generator computing ``node`` on the pixels ``idx``, or a :class:`Value`."""
        k = node.kind
        if k == "num":
            if self.trace and node.kids and not math.isfinite(node.value):
                return self.ev(node.kids[0], idx, frame)  # a folded constant: which operation made it so
            return Value(node.value)
        if k == "var":
            name = node.value
            if frame is not None and name in frame:
                return self.arg(frame[name], idx)
            if name == "x":
                return Value(self.x if idx is None else self.flat("x", self.x)[idx])
            if name == "y":
                return Value(self.y if idx is None else self.flat("y", self.y)[idx])
            if name in ("xres", "yres"):
                return Value(self.xres if name == "xres" else self.yres)
            return self.variable(name, idx, node.line)
        if k == "alias":
            return self.ev(node.kids[0], idx, frame)
        if k == "neg":
            return self.negate(node, idx, frame)
        if k == "call":
            if node.value in LIBRARY and not self._user_function(node.value):
                return self.library(node, idx, frame)
            return self.call(node, idx, frame)
        if k == "^":
            return self.power(node, idx, frame)
        if k == "/":
            return self.divide(node, idx, frame)
        return self.binary(node, idx, frame)

    def _user_function(self, name) -> bool:
        d = self.defs.get(name)
        return d is not None and d.is_function

    def negate(self, node, idx, frame):
        v = yield self.ev(node.kids[0], idx, frame)
        return -np.asarray(v, np.float64)

    def binary(self, node, idx, frame):
        a = np.asarray((yield self.ev(node.kids[0], idx, frame)), np.float64)
        b = np.asarray((yield self.ev(node.kids[1], idx, frame)), np.float64)
        r = a + b if node.kind == "+" else a - b if node.kind == "-" else a * b
        if self.trace:
            self._explain(node, r, (a, b), "overflows")
        return r

    def divide(self, node, idx, frame):
        """``edivi``: the divisor first; the numerator only where it is not 0."""
        d = np.asarray((yield self.ev(node.kids[1], idx, frame)), np.float64)
        zero = d == 0.0
        if not np.any(zero):
            a = np.asarray((yield self.ev(node.kids[0], idx, frame)), np.float64)
            r = a / d
            if self.trace:
                self._explain(node, r, (a, d), "overflows")
            return r
        self._mark(idx, zero)
        zero = np.broadcast_to(zero, self.shape_of(idx))
        count = int(np.count_nonzero(zero))
        self._warn(node, "/", f"division by zero in {_short(node)} at {count} of {self.n} pixels: 0 "
                              f"there, and 0 for the library functions around it, as Radiance "
                              f"(rcalc prints 'Division by zero')")
        out = np.zeros(zero.shape)
        keep = _sub(idx, ~zero)
        if keep.size:
            a = yield self.ev(node.kids[0], keep, frame)
            out[~zero] = np.asarray(a, np.float64) / np.broadcast_to(d, zero.shape)[~zero]
        return out

    def power(self, node, idx, frame):
        """``epow``: 0 where its arguments marked the pixel ("Illegal power")."""
        events = self._clear(idx)
        a = np.asarray((yield self.ev(node.kids[0], idx, frame)), np.float64)
        b = np.asarray((yield self.ev(node.kids[1], idx, frame)), np.float64)
        r = np.power(a, b)
        if self.trace:
            self._explain(node, r, (a, b), _pow_cause(a, b))
        return self._finish(idx, events, r)

    def variable(self, name, idx, line):
        d = self.defs.get(name)
        if d is None or d.is_function:
            if name in CONSTS:
                return CONSTS[name]
            raise InputError(f"{self.path}, line {line}: undefined variable '{name}'")
        memo = self.memo.get(name)
        if memo is None:
            memo = self.memo[name] = _Store()
        need = memo.missing(idx)
        if need is None or need.size:
            if name in self.active:
                raise InputError(f"{self.path}, line {d.line}: '{name}' is defined by itself (recursion)")
            self.active.add(name)
            v = yield self.ev(d.body, need, None)
            self.active.discard(name)
            memo.store(self.n, need, v)
        return memo.get(self.shape, idx)

    def arg(self, a: _Arg, idx):
        """An argument on the pixels ``idx`` (a subset of the call's), computed once there."""
        if a.given is not None:
            return a.given[0] if idx is None else a.given[1][idx]
        if not a.keep:
            return (yield self.ev(a.node, idx, a.frame))
        pos = None if idx is None else (idx if a.idx is None else np.searchsorted(a.idx, idx))
        need = a.store.missing(pos)
        if need is None or need.size:
            v = yield self.ev(a.node, need if a.idx is None or need is None else a.idx[need], a.frame)
            a.store.store(self.n if a.idx is None else a.idx.size, need, v)
        return a.store.get(self.shape if a.idx is None else a.idx.shape, pos)

    def call(self, node, idx, frame):
        d = self.defs[node.value]
        inner = {p: _Arg(k, frame, idx, i < ALISTSIZ) for i, (p, k) in enumerate(zip(d.params, node.kids))}
        self.calls += 1
        if self.calls > MAX_CALLS:
            raise InputError(f"{self.path}, line {node.line}: {node.value}() calls itself more than {MAX_CALLS} "
                             f"deep (Radiance runs out of stack; a recursion whose if() never reaches its end?)")
        v = yield self.ev(d.body, idx, inner)
        self.calls -= 1
        return v

    def library(self, node, idx, frame):
        """A library function with ``libfunc``'s rules (arguments computed inside it)."""
        name, kids = node.value, node.kids
        events = self._clear(idx)
        if name == "if":
            c = np.asarray((yield self.ev(kids[0], idx, frame)), np.float64) > 0
            if np.ndim(c) == 0 or c.all() or not c.any():
                taken = kids[1] if bool(np.all(c)) else kids[2]
                r = yield self.ev(taken, idx, frame)
            else:
                c = np.broadcast_to(c, self.shape_of(idx))
                r = np.zeros(c.shape)
                r[c] = yield self.ev(kids[1], _sub(idx, c), frame)
                r[~c] = yield self.ev(kids[2], _sub(idx, ~c), frame)
        elif name == "select":
            r = yield self.select(node, idx, frame)
        elif name in INPUTS:
            r = yield self.read_input(node, idx, frame)
        else:
            vals = []
            for k in kids:
                vals.append(np.asarray((yield self.ev(k, idx, frame)), np.float64))
            if name in FUNCS1:
                r = FUNCS1[name](vals[0])
                if self.trace:
                    self._explain(node, r, vals, _func_cause(name, vals[0]))
            elif name == "atan2":
                r = np.arctan2(vals[0], vals[1])
            elif name == "min":
                r = np.minimum.reduce(np.broadcast_arrays(*vals)) if len(vals) > 1 else vals[0]
            else:
                r = np.maximum.reduce(np.broadcast_arrays(*vals)) if len(vals) > 1 else vals[0]
        return self._finish(idx, events, r)

    def select(self, node, idx, frame):
        """``l_select``: index ``floor(n + 0.5)``; 0 gives the count; outside 0..count the
        pixel is marked (EDOM) and gives 0; only the chosen argument is computed."""
        choices = node.kids[1:]
        n = np.floor(np.asarray((yield self.ev(node.kids[0], idx, frame)), np.float64) + 0.5)
        n = np.broadcast_to(n, self.shape_of(idx))
        out = np.where(n == 0, float(len(choices)), 0.0)
        for i, k in enumerate(choices, 1):
            m = n == i
            if m.all():
                out = np.array(np.broadcast_to((yield self.ev(k, idx, frame)), out.shape), np.float64)
            elif m.any():
                out[m] = yield self.ev(k, _sub(idx, m), frame)
        bad = ~((n >= 0) & (n <= len(choices)))
        if bad.any():
            self._mark(idx, bad)
            self._warn(node, "select", f"select() index out of 0..{len(choices)} at {int(bad.sum())} of {self.n} "
                                       f"pixels (e.g. {_fmt(n[bad][0])}): 0 there, and 0 for the library "
                                       f"functions around it, as Radiance (rcalc prints 'select(): domain "
                                       f"error'); check the index expression")
        return out

    def read_input(self, node, idx, frame):
        if self.inputs is None:
            raise InputError(f"{self.path}, line {node.line}: '{node.value}(1)' reads the picture, "
                             f"which this file's role does not allow")
        c = INPUTS[node.value]
        if len(node.kids) == 3:  # pcomb's ri(1, dx, dy): the nearest pixel at the offset, edges repeated
            dx = yield self.ev(node.kids[1], idx, frame)
            dy = yield self.ev(node.kids[2], idx, frame)
            chans = self._shifted(idx, dx, dy)
        elif idx is None:
            chans = self.inputs
        else:
            chans = tuple(self.flat("rgb"[i], ch)[idx] for i, ch in enumerate(self.inputs))
        if c is None:
            return LUMA[0] * chans[0] + LUMA[1] * chans[1] + LUMA[2] * chans[2]
        return chans[c]

    def _shifted(self, idx, dx, dy):
        dx, dy = (np.nan_to_num(np.asarray(v, np.float64), nan=0.0, posinf=0.0, neginf=0.0) for v in (dx, dy))
        h, w = int(self.yres), int(self.xres)
        full = [np.broadcast_to(ch, (h, w)) for ch in self.inputs]
        x = self.x if idx is None else self.flat("x", self.x)[idx]
        y = self.y if idx is None else self.flat("y", self.y)[idx]
        xx = np.clip(x + np.floor(dx + 0.5), 0, w - 1).astype(np.int64)
        yy = np.clip(y + np.floor(dy + 0.5), 0, h - 1).astype(np.int64)
        xx, yy = np.broadcast_arrays(xx, yy)
        return tuple(ch[h - 1 - yy, xx] for ch in full)

    # -- tracing -------------------------------------------------------------------------
    def _explain(self, node, result, inputs, cause: str) -> None:
        """Remember the first operation whose finite inputs gave a number that is not."""
        if self.cause is not None:
            return
        bad = ~np.isfinite(result)
        for a in inputs:
            bad = bad & np.isfinite(a)
        if np.any(bad):
            what = "not a number (NaN)" if np.any(np.isnan(result) & bad) else "infinite"
            self.cause = f"line {node.line}: {_short(node)} {cause}: {what}"


def _short(node, limit: int = 60) -> str:
    text = node.text(True)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _fmt(v) -> str:
    return f"{float(v):g}"


def _pow_cause(a, b) -> str:
    a, b = np.broadcast_arrays(a, b)
    if np.any((a < 0) & (np.floor(b) != b) & np.isfinite(b)):
        return "raises a negative number to a fractional power"
    if np.any((a == 0) & (b < 0)):
        return "raises 0 to a negative power"
    return "overflows"


def _func_cause(name: str, a) -> str:
    a = np.asarray(a)
    if name in ("sqrt", "log", "log10") and np.any(a < 0):
        return f"takes {name}() of a negative number"
    if name in ("log", "log10") and np.any(a == 0):
        return f"takes {name}() of 0"
    if name in ("asin", "acos"):
        return f"takes {name}() of a number outside -1..1"
    if name == "exp":
        return "overflows"
    return f"takes {name}() of infinity"
