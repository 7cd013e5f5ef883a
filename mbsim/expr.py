"""Safe formulas from decks: parse, evaluate, differentiate symbolically.

A deck formula such as ``'where(v < 0, K/(y - yA) - Fmin, 0)'`` is read with
``ast.parse(mode='eval')`` and converted to a small immutable tree of :class:`Num`,
:class:`Name` and :class:`Apply` nodes. Only numbers, names, ``+ - * / **``, one comparison
(``< <= > >= == !=``, value 1.0 or 0.0), ``a if c else b`` (read as ``where``) and calls of
:data:`FUNCTIONS` by plain name get through; anything else is an
:class:`~mbsim.errors.ExpressionError` naming what was found and its column. The text never
reaches ``eval``/``exec``; ``pi`` and ``e`` are reserved constants.

Evaluation compiles the constant-folded tree once into nested closures; inputs may be floats or
numpy arrays (broadcasting; scalar inputs give a Python float, a constant formula a float even
for array inputs). Singular points follow numpy: ``1/0`` is ``inf`` with numpy's RuntimeWarning,
not an exception. ``diff`` builds the exact derivative (chain rule; piecewise functions are
differentiated branch by branch, their kinks ignored), simplified by constant folding and
neutral elements, and ``str()`` of any expression parses back to the same tree.
"""

from __future__ import annotations

import ast
import difflib
import functools
import math
import operator
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mbsim.errors import ExpressionError

MAX_LENGTH = 10_000  # characters; deck formulas are one-liners, longer text is abuse or a mistake
MAX_DEPTH = 100  # nesting of the parsed tree; also bounds recursion in diff, str and compile
RESERVED = {"pi": math.pi, "e": math.e, "deg": math.pi / 180}
"""Constants of every formula. ``deg`` is one degree in radians, so that ``30*deg`` is an angle
of 30 degrees in SI (rad) and ``360*deg*t`` a turn per second; ``deg2rad``/``rad2deg`` convert
a value that is already in degrees/radians."""


@dataclass(frozen=True, slots=True)
class Num:
    """A number; ``label`` (``'pi'``, ``'e'``) only keeps str() readable and is not compared."""

    value: float
    label: str | None = field(default=None, compare=False)


@dataclass(frozen=True, slots=True)
class Name:
    """A free variable."""

    id: str


@dataclass(frozen=True, slots=True)
class Apply:
    """``op(*args)``; op is an operator (``'+'``, ``'neg'``, ``'<'``...) or a FUNCTIONS key."""

    op: str
    args: tuple


Node = Num | Name | Apply
ZERO, ONE = Num(0.0), Num(1.0)


@dataclass(frozen=True)
class Function:
    """A whitelisted function: ``signature`` (``'atan2(y, x)'``; ``...`` marks any number of
    arguments), vectorised ``impl`` and the partial derivatives in each argument as formulas in
    the signature's names (the chain rule sums them times the arguments' derivatives)."""

    signature: str
    impl: Callable[..., Any]
    partials: tuple[str, ...]
    doc: str
    name: str = field(init=False)
    params: tuple[str, ...] = field(init=False)
    nargs: tuple[int, int | None] = field(init=False)  # (least, most); most None: any number

    def __post_init__(self) -> None:
        name, params = self.signature[:-1].split("(")
        params = tuple(params.split(", "))
        nargs = (len(params) - 1, None) if params[-1] == "..." else (len(params), len(params))
        for key, value in (("name", name), ("params", params), ("nargs", nargs)):
            object.__setattr__(self, key, value)  # derived once; the dataclass stays frozen


# ---- numerics: math on Python floats (several times faster than numpy scalars), else numpy ----


def _vec(math_fn: Callable, np_fn: Callable) -> Callable:
    def impl(*args):
        if all(type(a) is float for a in args):
            try:
                return math_fn(*args)
            except (ValueError, OverflowError):
                pass  # outside math's domain: numpy's nan/inf (and warning), as for arrays
        return np_fn(*args)

    return impl


def _step(x, x0, h0, x1, h1):
    if type(x) is float and type(x0) is float and type(x1) is float:
        if x <= x0:
            return h0
        if x >= x1:
            return h1
        s = (x - x0) / (x1 - x0)  # x0 < x < x1 here: no division by zero
        return h0 + (h1 - h0) * s * s * (3.0 - 2.0 * s)
    with np.errstate(divide="ignore", invalid="ignore"):  # x1 == x0 only off the chosen branch
        s = (x - x0) / np.subtract(x1, x0)
        mid = h0 + (h1 - h0) * s * s * (3.0 - 2.0 * s)
    return np.where(x <= x0, h0, np.where(x >= x1, h1, mid))


def _truth(r):
    return r.astype(float) if isinstance(r, np.ndarray) else float(r)


def _div(x, y):
    try:
        return x / y
    except ZeroDivisionError:
        return np.float64(x) / y  # inf/nan with numpy's warning, as for arrays


def _pow(x, y):
    try:
        r = x**y
    except (ZeroDivisionError, OverflowError):
        return np.float64(x) ** y
    return np.float64(x) ** y if type(r) is complex else r  # negative base: nan, not complex


# symbol: (impl, precedence for printing, partial derivatives in the operands a, b)
_OPS: dict[str, tuple[Callable, int, tuple[str, ...]]] = {
    "+": (operator.add, 2, ("1", "1")), "-": (operator.sub, 2, ("1", "-1")),
    "*": (operator.mul, 3, ("b", "a")), "/": (_div, 3, ("1/b", "-a/b**2")),
    "neg": (operator.neg, 4, ("-1",)), "**": (_pow, 5, ("b*a**(b - 1)", "a**b*log(a)")),
    "<": (lambda a, b: _truth(a < b), 1, ()), "<=": (lambda a, b: _truth(a <= b), 1, ()),
    ">": (lambda a, b: _truth(a > b), 1, ()), ">=": (lambda a, b: _truth(a >= b), 1, ()),
    "==": (lambda a, b: _truth(a == b), 1, ()), "!=": (lambda a, b: _truth(a != b), 1, ()),
}  # fmt: skip


def _impl(op: str) -> Callable:
    return FUNCTIONS[op].impl if op in FUNCTIONS else _OPS[op][0]


# ---- smart constructors: fold constants, drop neutral elements ---------------------------------


def _isnum(n: Node, v: float) -> bool:
    return isinstance(n, Num) and n.value == v


_SIMPLIFY: dict[str, Callable] = {
    "+": lambda a, b: b if _isnum(a, 0) else a if _isnum(b, 0) else None,
    "-": lambda a, b: (a if _isnum(b, 0) else _make("neg", b) if _isnum(a, 0)
                      else ZERO if a == b else None),
    "*": lambda a, b: (ZERO if _isnum(a, 0) or _isnum(b, 0) else b if _isnum(a, 1)
                      else a if _isnum(b, 1) else _make("neg", b) if _isnum(a, -1)
                      else _make("neg", a) if _isnum(b, -1) else None),
    "/": lambda a, b: (ZERO if _isnum(a, 0) else a if _isnum(b, 1)
                      else _make("neg", a) if _isnum(b, -1) else None),
    "**": lambda a, b: ONE if _isnum(b, 0) else a if _isnum(b, 1) else None,
    "neg": lambda a: a.args[0] if isinstance(a, Apply) and a.op == "neg" else None,
    "where": lambda c, a, b: (a if a == b or (isinstance(c, Num) and c.value != 0)
                              else b if isinstance(c, Num) else None),
}  # fmt: skip


def _make(op: str, *args: Node) -> Node:
    """``op(*args)``, constant-folded (when the value is finite) and simplified."""
    if all(isinstance(a, Num) for a in args):
        impl = _impl(op)
        # functions fold with Python floats (math: the same libm on every numpy version;
        # numpy 1.24's log(e) is 1 - 1 ulp), operators with numpy's (1/0 is inf, no raise)
        cast = float if op in FUNCTIONS else np.float64
        with np.errstate(all="ignore"):
            v = float(impl(*(cast(a.value) for a in args)))
        if math.isfinite(v):  # 1/0 or log(-1) stay as written: a formula, not 'inf'
            return Num(v)
    rule = _SIMPLIFY.get(op)
    r = rule(*args) if rule else None
    return Apply(op, tuple(args)) if r is None else r


def _rebuild(n: Node, values: Mapping[str, Node]) -> Node:
    """``n`` with names replaced by ``values``, constant-folded and simplified."""
    if isinstance(n, Name):
        return values.get(n.id, n)
    if isinstance(n, Apply):
        return _make(n.op, *(_rebuild(a, values) for a in n.args))
    return n


def _free_names(n: Node) -> set[str]:
    if isinstance(n, Apply):
        return set().union(*(_free_names(a) for a in n.args))
    return {n.id} if isinstance(n, Name) else set()


# ---- derivatives -------------------------------------------------------------------------------


@functools.cache
def _partials(op: str) -> tuple[tuple[str, ...], tuple[Node, ...]]:
    """(parameter names, parsed partial derivatives) of an operator or function."""
    if op in FUNCTIONS:
        return FUNCTIONS[op].params, tuple(_parse(p)._node for p in FUNCTIONS[op].partials)
    partials = tuple(_parse(p)._node for p in _OPS[op][2])
    return ("a", "b")[: len(partials)], partials


def _d(n: Node, var: str) -> Node:
    """d n / d var, exact; piecewise functions are differentiated branch by branch."""
    if isinstance(n, Num):
        return ZERO
    if isinstance(n, Name):
        return ONE if n.id == var else ZERO
    if n.op == "where":
        return _make("where", n.args[0], _d(n.args[1], var), _d(n.args[2], var))
    if n.op in ("min", "max"):  # min(a, rest...) = where(a <= min(rest...), a, min(rest...))
        a, rest = n.args[0], n.args[1] if len(n.args) == 2 else Apply(n.op, n.args[1:])
        cmp = Apply("<=" if n.op == "min" else ">=", (a, rest))
        return _d(Apply("where", (cmp, a, rest)), var)
    params, partials = _partials(n.op)
    if not partials:
        return ZERO  # comparisons are piecewise constant
    total = ZERO  # chain rule: sum over arguments of (df/d arg) (d arg/d var)
    for arg, partial in zip(n.args, partials, strict=True):
        d_arg = _d(arg, var)
        if not _isnum(d_arg, 0):
            df = _rebuild(partial, dict(zip(params, n.args, strict=True)))
            total = _make("+", total, _make("*", df, d_arg))
    return total


_SQ1 = "sqrt(1 - u**2)"
_STEP_IN = "where(x <= x0, 0, where(x >= x1, 0, 6*(h1 - h0)*{}/(x1 - x0)**{}))"  # 0 outside
FUNCTIONS: dict[str, Function] = {f.name: f for f in (Function(*row) for row in [
    ("sin(u)", _vec(math.sin, np.sin), ("cos(u)",), "sine"),
    ("cos(u)", _vec(math.cos, np.cos), ("-sin(u)",), "cosine"),
    ("tan(u)", _vec(math.tan, np.tan), ("1/cos(u)**2",), "tangent"),
    ("asin(u)", _vec(math.asin, np.arcsin), (f"1/{_SQ1}",), "arc sine"),
    ("acos(u)", _vec(math.acos, np.arccos), (f"-1/{_SQ1}",), "arc cosine"),
    ("atan(u)", _vec(math.atan, np.arctan), ("1/(1 + u**2)",), "arc tangent"),
    ("atan2(y, x)", _vec(math.atan2, np.arctan2), ("x/(x**2 + y**2)", "-y/(x**2 + y**2)"),
     "angle of the point (x, y)"),
    ("sinh(u)", _vec(math.sinh, np.sinh), ("cosh(u)",), "hyperbolic sine"),
    ("cosh(u)", _vec(math.cosh, np.cosh), ("sinh(u)",), "hyperbolic cosine"),
    ("tanh(u)", _vec(math.tanh, np.tanh), ("1 - tanh(u)**2",), "hyperbolic tangent"),
    ("exp(u)", _vec(math.exp, np.exp), ("exp(u)",), "e**u"),
    ("log(u)", _vec(math.log, np.log), ("1/u",), "natural logarithm"),
    ("log10(u)", _vec(math.log10, np.log10), (f"1/(u*{math.log(10.0)!r})",), "base-10 logarithm"),
    ("sqrt(u)", _vec(math.sqrt, np.sqrt), ("1/(2*sqrt(u))",), "square root"),
    ("abs(u)", abs, ("sign(u)",), "absolute value"),
    ("sign(u)", np.sign, ("0",), "-1, 0 or 1"),
    ("min(a, b, ...)", lambda *a: functools.reduce(np.minimum, a), (), "smallest argument"),
    ("max(a, b, ...)", lambda *a: functools.reduce(np.maximum, a), (), "largest argument"),
    ("hypot(a, b)", _vec(math.hypot, np.hypot), ("a/hypot(a, b)", "b/hypot(a, b)"),
     "sqrt(a**2 + b**2)"),
    ("floor(u)", _vec(lambda x: float(math.floor(x)), np.floor), ("0",), "round down"),
    ("ceil(u)", _vec(lambda x: float(math.ceil(x)), np.ceil), ("0",), "round up"),
    ("clip(x, lo, hi)", lambda x, lo, hi: np.minimum(np.maximum(x, lo), hi),
     ("where(x < lo, 0, where(x > hi, 0, 1))", "where(x < lo, 1, 0)",
      "where(x < lo, 0, where(x > hi, 1, 0))"), "x limited to [lo, hi]"),
    ("where(cond, a, b)", lambda c, a, b: np.where(np.not_equal(c, 0), a, b), (),
     "a where cond is nonzero, else b"),
    ("step(x, x0, h0, x1, h1)", _step,
     (_STEP_IN.format("(x - x0)*(x1 - x)", 3), _STEP_IN.format("-(x - x0)*(x1 - x)**2", 4),
      "1 - step(x, x0, 0, x1, 1)", _STEP_IN.format("-(x - x0)**2*(x1 - x)", 4),
      "step(x, x0, 0, x1, 1)"),
     "ADAMS cubic step: h0 for x <= x0, h1 for x >= x1, smooth s**2 (3 - 2 s) between"),
    ("heaviside(u)", lambda x: np.heaviside(x, 1.0), ("0",), "0 for u < 0, 1 for u >= 0"),
    ("rad2deg(u)", _vec(math.degrees, np.degrees), ("180/pi",), "angle u (rad) in degrees"),
    ("deg2rad(u)", _vec(math.radians, np.radians), ("pi/180",), "angle u (degrees) in rad"),
])}  # fmt: skip

# ---- compilation to closures, printing ---------------------------------------------------------


def _compile(n: Node) -> Callable[[dict], Any]:
    if isinstance(n, Num):
        v = n.value
        return lambda env: v
    if isinstance(n, Name):
        return operator.itemgetter(n.id)
    fs = [_compile(a) for a in n.args]
    if n.op == "where":
        fc, fa, fb = fs

        def where(env):
            c = fc(env)
            if isinstance(c, np.ndarray):
                return np.where(c != 0, fa(env), fb(env))
            return fa(env) if c else fb(env)  # scalar: only the branch taken is evaluated

        return where
    impl = _impl(n.op)
    if len(fs) == 1:
        (a,) = fs
        return lambda env: impl(a(env))
    if len(fs) == 2:
        a, b = fs
        return lambda env: impl(a(env), b(env))
    return lambda env: impl(*[f(env) for f in fs])


def _fmt(n: Node) -> tuple[str, int]:
    """(text, precedence; 6 = atom), parenthesised so that parsing gives the same tree."""
    if isinstance(n, Num):
        if n.label:
            return n.label, 6
        text = str(int(n.value)) if n.value.is_integer() and abs(n.value) < 1e15 else repr(n.value)
        return text, 4 if text.startswith("-") else 6
    if isinstance(n, Name):
        return n.id, 6
    if n.op in FUNCTIONS:
        return f"{n.op}({', '.join(_fmt(a)[0] for a in n.args)})", 6
    p = _OPS[n.op][1]
    if n.op == "neg":
        s, q = _fmt(n.args[0])
        return "-" + (f"({s})" if q < p else s), p
    (ls, lp), (rs, rp) = _fmt(n.args[0]), _fmt(n.args[1])
    ls = f"({ls})" if (lp <= p if n.op == "**" or p == 1 else lp < p) else ls
    rs = f"({rs})" if (rp < p if n.op == "**" else rp <= p) else rs
    sep = "" if p >= 3 else " "
    return f"{ls}{sep}{n.op}{sep}{rs}", p


# ---- the public class --------------------------------------------------------------------------


class Expression:
    """A parsed, immutable formula; call it with values for its free names.

    Attributes
    ----------
    text : str
        The source text (for derived expressions: their printed form).
    names : frozenset of str
        Free variable names (not ``pi``, ``e`` or function names).
    """

    __slots__ = ("_columns", "_fn", "_names", "_node", "names", "text")

    def __init__(self, node: Node, text: str | None = None, columns: Mapping | None = None):
        self._node = node
        self.text = _fmt(node)[0] if text is None else text
        self.names = frozenset(_free_names(node))
        self._names = tuple(sorted(self.names))
        self._columns = dict(columns or {})  # name -> column of first use, for error messages
        self._fn = _compile(_rebuild(node, {}))

    def __call__(self, env: Mapping[str, Any] | None = None, /, **kw: Any) -> float | np.ndarray:
        """Value at ``env`` and/or keywords (numbers or arrays); scalar inputs give a float."""
        if kw:
            env = {**env, **kw} if env else kw
        elif env is None:
            env = {}
        vals = {}
        for name in self._names:
            try:
                v = env[name]
            except KeyError:
                hint = _suggest(name, env.keys())
                raise ExpressionError(f"unknown name '{name}'{hint}", self.text) from None
            vals[name] = v if type(v) is float else _coerce(name, v, self.text)
        r = self._fn(vals)
        return r if type(r) is float or (isinstance(r, np.ndarray) and r.ndim) else float(r)

    def diff(self, var: str) -> Expression:
        """Exact derivative with respect to ``var``, simplified; ``e.diff('t').diff('t')``."""
        if not isinstance(var, str) or not var.isidentifier():
            raise ExpressionError(f"cannot differentiate with respect to {var!r}", self.text)
        return Expression(_rebuild(_d(self._node, var), {}))

    def bind(self, values: Mapping[str, float]) -> Expression:
        """Substitute numbers for names (parameters) and constant-fold; other names stay free."""
        subst = {}
        for k, v in values.items():
            if k in RESERVED:
                msg = f"'{k}' is a reserved constant and cannot be bound"
                raise ExpressionError(msg, self.text)
            if k in self.names:
                try:
                    subst[k] = Num(float(v))
                except (TypeError, ValueError):
                    subst[k] = Num(math.nan)
                if not math.isfinite(subst[k].value):
                    msg = f"value for '{k}' must be a finite number, got {v!r}"
                    raise ExpressionError(msg, self.text)
        return Expression(_rebuild(self._node, subst)) if subst else self

    def is_constant(self) -> bool:
        """True when the formula has no free names."""
        return not self.names

    def __str__(self) -> str:
        return _fmt(self._node)[0]

    def __repr__(self) -> str:
        return f"Expression({str(self)!r})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Expression) and self._node == other._node

    def __hash__(self) -> int:
        return hash(self._node)

    def __reduce__(self) -> tuple:
        # the compiled closures do not pickle; the tree does (models sent to worker processes)
        return (Expression, (self._node, self.text, self._columns))


def _coerce(name: str, v: Any, text: str) -> float | np.ndarray:
    if isinstance(v, (int, float, np.integer, np.floating)):
        return float(v)
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        msg = f"value for '{name}' must be a number or an array of numbers, got {type(v).__name__}"
        raise ExpressionError(msg, text) from None
    return float(a) if a.ndim == 0 else a


def _suggest(name: str, candidates: Iterable[str]) -> str:
    close = difflib.get_close_matches(name, [str(c) for c in candidates], n=1)
    return f"; did you mean '{close[0]}'?" if close else ""


# ---- parsing -----------------------------------------------------------------------------------

_BINOPS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**"}
_CMPOPS = {ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">", ast.GtE: ">=", ast.Eq: "==", ast.NotEq: "!="}
_BAD_OPS = {ast.BitXor: "^", ast.FloorDiv: "//", ast.Mod: "%", ast.MatMult: "@", ast.LShift: "<<",
            ast.RShift: ">>", ast.BitOr: "|", ast.BitAnd: "&"}  # fmt: skip
_KINDS = {"List": "a list", "Tuple": "a tuple", "Dict": "a dict", "Set": "a set",
          "Lambda": "lambda", "ListComp": "a comprehension", "SetComp": "a comprehension",
          "DictComp": "a comprehension", "GeneratorExp": "a generator expression",
          "NamedExpr": "':=' assignment", "JoinedStr": "an f-string", "Starred": "'*' unpacking",
          "Subscript": "a subscript ('x[...]')", "Slice": "a slice",
          "BoolOp": "'and'/'or' (multiply conditions, (a < b)*(c < d), or use where)"}  # fmt: skip


_UNIT_CALLS = {
    "deg": "'deg' is the constant pi/180 (one degree in radians), not a function: write "
           "30*deg for 30 degrees, or deg2rad(x) / rad2deg(x) to convert a value",
    "rad": "'rad' is not a function: angles in formulas are in radians already; write "
           "deg2rad(x) for x in degrees (or x*deg), rad2deg(x) to get degrees",
}  # fmt: skip


class _Converter:
    """Python ast -> Node, whitelisting as it goes; ``src`` is the text wrapped in parentheses."""

    def __init__(self, text: str, src: str):
        self.text, self.src = text, src.encode()
        self.columns: dict[str, int] = {}

    def col(self, offset: int) -> int:
        # ast offsets are UTF-8 bytes into src; its leading '(' makes them 1-based characters
        return len(self.src[:offset].decode(errors="ignore"))

    def error(self, msg: str, n: ast.AST) -> ExpressionError:
        return ExpressionError(msg, self.text, self.col(n.col_offset))

    def convert(self, n: ast.AST, depth: int = 0) -> Node:
        if depth > MAX_DEPTH:
            raise _TooDeep  # _parse regroups long sums and products, or reports the limit
        sub = functools.partial(self.convert, depth=depth + 1)
        if isinstance(n, ast.Constant):
            if isinstance(n.value, bool) or not isinstance(n.value, (int, float)):
                raise self.error(f"{n.value!r} is not allowed: only numbers and names", n)
            v = float(n.value) if isinstance(n.value, float) or abs(n.value) < 10**308 else math.inf
            if not math.isfinite(v):
                raise self.error("number out of range", n)
            return Num(v)
        if isinstance(n, ast.Name):
            if n.id in RESERVED:
                return Num(RESERVED[n.id], n.id)
            if n.id in FUNCTIONS:
                raise self.error(f"'{n.id}' is a function; call it as {n.id}(...)", n)
            self.columns.setdefault(n.id, self.col(n.col_offset))
            return Name(n.id)
        if isinstance(n, ast.UnaryOp) and isinstance(n.op, (ast.USub, ast.UAdd)):
            u = sub(n.operand)
            if isinstance(n.op, ast.UAdd):
                return u
            return Num(-u.value) if isinstance(u, Num) and not u.label else Apply("neg", (u,))
        if isinstance(n, ast.UnaryOp):
            what = "'not'" if isinstance(n.op, ast.Not) else "'~'"
            raise self.error(f"{what} is not supported; use a comparison or where(...)", n)
        if isinstance(n, ast.BinOp) and type(n.op) in _BINOPS:
            return Apply(_BINOPS[type(n.op)], (sub(n.left), sub(n.right)))
        if isinstance(n, ast.BinOp):
            sym = _BAD_OPS.get(type(n.op), type(n.op).__name__)
            col = self.col(max(self.src.find(sym.encode(), n.left.end_col_offset or 0), 0))
            hint = "; write powers as '**', e.g. 2**3" if sym == "^" else ""
            raise ExpressionError(f"operator '{sym}' is not allowed{hint}", self.text, col)
        if isinstance(n, ast.Compare):
            if len(n.ops) > 1:
                msg = "chained comparisons (a < b < c) are not supported; write (a < b)*(b < c)"
                raise self.error(msg, n)
            if type(n.ops[0]) not in _CMPOPS:
                raise self.error("only the comparisons < <= > >= == != are allowed", n)
            return Apply(_CMPOPS[type(n.ops[0])], (sub(n.left), sub(n.comparators[0])))
        if isinstance(n, ast.IfExp):
            return Apply("where", (sub(n.test), sub(n.body), sub(n.orelse)))
        if isinstance(n, ast.Call):
            return self.call(n, sub)
        if isinstance(n, ast.Attribute):
            raise self.error(f"attribute access '.{n.attr}' is not allowed", n)
        kind = _KINDS.get(type(n).__name__, type(n).__name__)
        raise self.error(f"{kind} is not allowed in a formula", n)

    def call(self, n: ast.Call, sub: Callable[[ast.AST], Node]) -> Node:
        if not isinstance(n.func, ast.Name):
            raise self.error("only functions named directly can be called, e.g. sin(x)", n)
        name, fn = n.func.id, FUNCTIONS.get(n.func.id)
        if name in _UNIT_CALLS:  # 'deg(30)': the old helper read radians; say what is right
            raise self.error(_UNIT_CALLS[name], n)
        if fn is None:
            hint = _suggest(name, FUNCTIONS) or f"; allowed: {', '.join(sorted(FUNCTIONS))}"
            raise self.error(f"unknown function '{name}'{hint}", n)
        if n.keywords:
            kw = n.keywords[0]
            raise self.error(f"keyword arguments are not allowed ({kw.arg or '**'}=...)", kw)
        for a in n.args:
            if isinstance(a, ast.Starred):
                raise self.error("'*' unpacking is not allowed", a)
        lo, hi = fn.nargs
        if len(n.args) < lo or (hi is not None and len(n.args) > hi):
            want = f"{lo} argument" + "s" * (lo > 1) if lo == hi else f"at least {lo} arguments"
            raise self.error(f"{name}() takes {want}, got {len(n.args)}", n)
        return Apply(name, tuple(sub(a) for a in n.args))


class _TooDeep(Exception):
    """The tree as Python parses it is deeper than MAX_DEPTH (or than ast can build)."""


@functools.lru_cache(maxsize=1024)
def _parse(text: str) -> Expression:
    if len(text) > MAX_LENGTH:
        raise ExpressionError(f"formula longer than {MAX_LENGTH} characters", text[:40] + "...")
    if not text.strip():
        raise ExpressionError("empty formula", text)
    # Parentheses let leading spaces and YAML line breaks through; only the tree is ever used.
    src = "(" + text.replace("\r", " ").replace("\n", " ") + ")"
    try:
        return _parse_src(text, src)
    except _TooDeep:
        pass
    # Python reads a + b + c ... as ((a + b) + c) ...: a sum or product of many terms is a
    # deep tree.  Regrouped into nested groups of at most FLAT_GROUP terms it is shallow
    # (5000 terms: 4 levels of groups); the value differs from the left-to-right sum by
    # round-off only.  What is still too deep is nesting the formula writes itself.
    flat = _regroup(src)
    if flat is not None and flat != src:
        try:
            return _parse_src(text, flat)
        except _TooDeep:
            pass
    raise ExpressionError(f"formula nested deeper than {MAX_DEPTH} levels (parentheses, "
                          "function calls, powers or conditions inside one another)", text)


def _parse_src(text: str, src: str) -> Expression:
    try:
        tree = ast.parse(src, mode="eval")
    except SyntaxError as exc:
        col = min(max((exc.offset or 1) - 1, 1), len(text) + 1)
        raise ExpressionError(f"invalid formula: {exc.msg}", text, col) from None
    except RecursionError:
        raise _TooDeep from None
    except (MemoryError, ValueError) as exc:
        raise ExpressionError(f"invalid formula: {exc}", text) from None
    conv = _Converter(text, src)
    return Expression(conv.convert(tree.body), text, conv.columns)


FLAT_GROUP = 16  # terms per group when a long sum or product is regrouped (_regroup)
_CHAIN_OPS = {"+", "-", "*", "/", "**"}
_SEPARATORS = {"if", "else", "and", "or", "not", "in", "is", "lambda"}
_OPEN, _CLOSE = {"(": ")", "[": "]", "{": "}"}, {")", "]", "}"}


def _regroup(src: str) -> str | None:
    """``src`` with every sum (``+ -``) or product (``* /``) of more than FLAT_GROUP terms
    written as nested parenthesised groups of at most FLAT_GROUP terms: ``a - b - c + d``
    -> ``(a - b) - (c - d)``, ``a / b / c * d`` -> ``(a / b) / (c / d)`` (the operators of a
    group after a ``-`` or ``/`` are flipped, so the value is the same up to round-off).

    Works on Python's tokens, bracket group by bracket group, without recursion (a stack);
    None when the text does not tokenize (the parser then reports the syntax error).
    """
    import io
    import tokenize

    try:
        toks = [t.string for t in tokenize.generate_tokens(io.StringIO(src).readline)
                if t.type not in (tokenize.NEWLINE, tokenize.NL, tokenize.ENDMARKER,
                                  tokenize.COMMENT, tokenize.INDENT, tokenize.DEDENT)]
    except (tokenize.TokenError, SyntaxError, IndentationError):
        return None
    stack: list[list[str]] = [[]]  # the items of each open bracket group
    for tok in toks:
        if tok in _OPEN:
            stack.append([tok])
        elif tok in _CLOSE and len(stack) > 1:
            group = stack.pop()
            stack[-1].append(group[0] + " ".join(_flatten_span(group[1:])) + tok)
        else:
            stack[-1].append(tok)
    if len(stack) != 1:
        return None
    return " ".join(_flatten_span(stack[0]))


def _flatten_span(items: list[str]) -> list[str]:
    """One bracket group's items (inner groups already one item each), chains regrouped."""
    out: list[str] = []
    segment: list[str] = []
    for item in items:
        if item in _SEPARATORS or item == "," or (
                not item[:1].isalnum() and item[:1] not in "._([{" and item not in _CHAIN_OPS):
            out += _flatten_segment(segment) + [item]  # a comparison, a comma, `if`...
            segment = []
        else:
            segment.append(item)
    return out + _flatten_segment(segment)


def _operand_end(item: str | None) -> bool:
    return item is not None and item not in _CHAIN_OPS


def _flatten_segment(seg: list[str]) -> list[str]:
    """A run of operands and ``+ - * / **``: sums, then each term's products, regrouped."""
    if not seg:
        return []
    terms = _split(seg, ("+", "-"))
    for k, (op, term) in enumerate(terms):
        factors = _split(term, ("*", "/"))
        terms[k] = (op, [_grouped(factors, {"*": "/", "/": "*"})])
    return [_grouped(terms, {"+": "-", "-": "+"})]


def _split(seg: list[str], ops: tuple[str, str]) -> list[tuple[str | None, list[str]]]:
    """[(operator before, items)]: ``seg`` cut at its binary ``ops``."""
    parts: list[tuple[str | None, list[str]]] = [(None, [])]
    prev = None
    for item in seg:
        if item in ops and _operand_end(prev):
            parts.append((item, []))
        else:
            parts[-1][1].append(item)
        prev = item
    return parts


def _grouped(parts: list[tuple[str | None, list[str]]], flip: dict[str, str]) -> str:
    terms = [(op, " ".join(items)) for op, items in parts]
    while len(terms) > FLAT_GROUP:
        chunks = [terms[i:i + FLAT_GROUP] for i in range(0, len(terms), FLAT_GROUP)]
        terms = []
        for chunk in chunks:
            op0, first = chunk[0]
            inverse = op0 is not None and op0 == list(flip)[1]  # after '-' or '/'
            rest = "".join(f" {flip[op] if inverse else op} {t}" for op, t in chunk[1:])
            terms.append((op0, f"({first}{rest})"))
    text = terms[0][1]
    return text + "".join(f" {op} {t}" for op, t in terms[1:])


def parse_expression(text: str | float, allowed: Iterable[str] | None = None) -> Expression:
    """Parse a deck formula (or wrap a number) into an :class:`Expression`.

    Parameters
    ----------
    text : str or number
        The formula, e.g. ``'C*(y0 - y)'``; parsed once per distinct text (cached).
    allowed : iterable of str, optional
        The names the formula may use; any other free name is an error with a suggestion.

    Raises
    ------
    ExpressionError
        Syntax errors, constructs outside the whitelist, unknown names (with their column).
    """
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        if not math.isfinite(text):
            raise ExpressionError(f"number out of range: {text!r}")
        return Expression(Num(float(text)))
    if not isinstance(text, str):
        raise ExpressionError(f"expected a formula or a number, got {type(text).__name__}")
    expr = _parse(text)
    if allowed is not None:
        allowed = set(allowed)
        for name in sorted(expr.names - allowed, key=lambda k: expr._columns.get(k, 0)):
            msg = f"unknown name '{name}'{_suggest(name, allowed)}"
            raise ExpressionError(msg, text, expr._columns.get(name))
    return expr


def evaluate(text: str | float, env: Mapping[str, Any] | None = None, **kw: Any) -> float:
    """Parse (cached) and evaluate in one call: ``evaluate('2*pi*f', f=3.0)``."""
    return parse_expression(text)(env, **kw)
