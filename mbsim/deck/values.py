"""Reading values out of the Node tree: numbers, vectors, names, functions of time, points.

Everything goes through a :class:`Reader`, which knows the deck file, the parameters
evaluated so far and the warnings collected, and raises :class:`DeckError` with the file,
key path and line of the offending value and a message that says what was expected and
what was received.
"""

from __future__ import annotations

import difflib
import math
import re
import warnings
from typing import Any

import numpy as np

from mbsim import units
from mbsim.deck import limits
from mbsim.deck.schema import DIMENSIONS, FUNCTION_FORMS, HARMONIC_KEYS, INTERPOLATIONS
from mbsim.deck.spec import FunctionSpec, PointSet
from mbsim.deck.tree import Node
from mbsim.errors import QUOTE_LIMIT, DeckError, ExpressionError, MbsimError, Where, quote
from mbsim.expr import FUNCTIONS, RESERVED, Expression, parse_expression

NAME_RE = re.compile(r"[A-Za-z_][A-Za-z_0-9]*")

# Joint point geometry (per body): errors and the warning threshold.
ZERO_LENGTH = 1e-9  # m: |Q - P| or |R - P| below this is an error
PARALLEL = 1e-6  # rad: P->R this close to parallel with P->Q is an error ...
NEARLY_PARALLEL = 1e-2  # rad: ... and so is this close ("nearly parallel")
# rad off perpendicular: warn (below 1 deg the axes are orthogonalised silently)
SKEW_WARNING = math.radians(1.0)


def describe(node: Node | None, limit: int = 80) -> str:
    """A short, one-line rendering of what the deck gave: [0.0, 1.0], 'abc', a mapping."""
    if node is None:
        return "nothing"
    if node.kind == "map":  # at most `limit` characters are built (a 10^5-item list is cut)
        text = "a mapping {" + _joined(node.value, limit, str) + "}"
    elif node.kind == "seq":
        text = "[" + _joined(node.value, limit, lambda v: describe(v, limit)) + "]"
    elif node.value is None:
        text = "nothing (null)"
    elif isinstance(node.value, bool):
        text = node.text
    elif isinstance(node.value, (int, float)):
        text = repr(float(node.value))
    elif not isinstance(node.value, str):  # a YAML timestamp: `2001-12-14` unquoted
        text = f"a date {node.text or node.value} (YAML reads an unquoted date as a date)"
        return text if len(text) <= 2 * limit else text[: 2 * limit - 4] + " ..."
    else:
        text = quote(node.value, limit)
    return text if len(text) <= limit else text[: limit - 4] + " ...]"


def _joined(items, limit: int, fmt) -> str:
    parts, n = [], 0
    for item in items:
        parts.append(fmt(item))
        n += len(parts[-1]) + 2
        if n > limit:
            break
    return ", ".join(parts)


def suggest(word: str, options) -> str:
    """'; did you mean 'mass'?' or '' (difflib)."""
    if len(str(word)) > QUOTE_LIMIT:  # difflib is quadratic; a long word is no typo
        return ""
    close = difflib.get_close_matches(str(word), [str(o) for o in options], n=1)
    return f"; did you mean {close[0]!r}?" if close else ""


class Reader:
    """Reads typed values from nodes; ``where`` arguments are the node's own Where."""

    def __init__(self, file: str):
        self.file = file
        self.params: dict[str, float] = {}
        self.warnings: list[str] = []
        self._dims: dict[str, Any] = {}

    # -- errors, warnings, structure ---------------------------------------------------
    def error(self, where: Where, message: str, node: Node | None = None) -> DeckError:
        if node is not None and node.origin:
            message += f" (value from {node.origin})"
        return DeckError(" ".join(message.split()), where)

    def warn(self, where: Where, message: str) -> None:
        self.warnings.append(f"{where}: {message}")

    def items(self, node: Node, where: Where) -> list[tuple[str, Node, Where]]:
        """(key, child, child's Where) of a mapping node (error if not a mapping)."""
        if node.kind != "map":
            raise self.error(where, f"expected a mapping, got {describe(node)}", node)
        out = []
        for key, child in node.value.items():
            line = node.key_lines.get(key)
            out.append(
                (
                    key,
                    child,
                    Where(
                        self.file, _join(where.path, key), line if line is not None else child.line
                    ),
                )
            )
        return out

    def fields(self, node: Node, where: Where, allowed, required=(), what: str = "") -> dict:
        """Check a mapping's keys; returns {key: (child, Where)}."""
        got = {}
        for key, child, w in self.items(node, where):
            if key not in allowed:
                hint = suggest(key, allowed) or f"; expected one of: {', '.join(allowed)}"
                where_ = f" in {what}" if what else ""
                raise self.error(w, f"unknown key {quote(key)}{where_}{hint}")
            got[key] = (child, w)
        for key in required:
            if key not in got:
                raise self.error(
                    where, f"missing required key {key!r}{' for ' + what if what else ''}"
                )
        return got

    def name(self, node: Node, where: Where, known=None, what: str = "name") -> str:
        """A name (of a body, joint, ...); with ``known``, it must be one of them."""
        name = node.name()
        if name is None:
            raise self.error(where, f"expected a {what}, got {describe(node)}", node)
        if known is not None and name not in known:
            listed = ", ".join(known) or "none"
            hint = suggest(name, known) or f" (known: {_cut(listed)})"
            raise self.error(where, f"unknown {what} {quote(name)}{hint}", node)
        return name

    def choice(self, node: Node, where: Where, options, what: str = "value") -> str:
        name = node.name()
        if name not in options:
            raise self.error(
                where,
                f"expected {what} {' | '.join(options)}, got {describe(node)}"
                f"{suggest(name, options) if name else ''}",
                node,
            )
        return name

    # -- numbers -----------------------------------------------------------------------
    def number(self, node: Node, where: Where, dim: str | None = None) -> float:
        """A scalar: number, parameter name, formula of parameters, or quantity with a unit."""
        return self.number_info(node, where, dim)[0]

    def number_info(self, node: Node, where: Where, dim: str | None) -> tuple[float, bool]:
        """(SI value, whether it was written with a unit)."""
        value = node.value if node.kind == "scalar" else None
        if value is None or isinstance(value, bool) or not isinstance(value, (int, float, str)):
            raise self.error(where, f"expected {_a(dim)}, got {describe(node)}", node)
        if isinstance(value, (int, float)):
            return self._finite(float(value), node, where), False
        text = value.strip()
        try:
            return self._finite(float(text), node, where), False
        except ValueError:
            pass
        if text in self.params:
            return self.params[text], False
        if units.looks_like_quantity(text):
            return self._quantity(text, node, where, dim), True
        expr = self.formula(text, node, where, set())
        return self._finite(_constant(expr), node, where, text), False

    def _finite(self, x: float, node: Node, where: Where, text: str | None = None) -> float:
        if not math.isfinite(x):
            got = f"{quote(text)} = {x}" if text else describe(node)
            raise self.error(where, f"expected a finite number, got {got}", node)
        return x

    def _quantity(self, text: str, node: Node, where: Where, dim: str | None) -> float:
        try:
            value, got_dim = units.parse_quantity(text)
        except (MbsimError, ValueError, KeyError) as exc:
            hint = ""
            if set(NAME_RE.findall(text)) & (set(self.params) | {"t"}):  # '360 deg * t'
                fixed = re.sub(r"(?<=[\d.])\s*(deg|°)(?![A-Za-z_])", "*deg", text)
                fixed = re.sub(r"\s*\*\s*", "*", fixed)
                hint = (f"; a formula takes no units except the constant deg (pi/180): write "
                        f"{quote(fixed)}" if "*deg" in fixed else "; a formula takes no units "
                        "(the constant deg = pi/180 aside): give the others to a parameter, "
                        "e.g. L: '12 in'")  # fmt: skip
            why = _message(exc) if not hint else "a quantity is a number and a unit"
            raise self.error(where, f"bad quantity {quote(text)}: {why}{hint}", node) from None
        if dim is not None and got_dim != self._dim(dim):
            unit, words = DIMENSIONS[dim]
            got = f"{quote(text)} ({got_dim})"
            raise self.error(where, f"expected {_an(words)} (SI unit {unit}), got {got}", node)
        return self._finite(float(value), node, where, text)

    def _dim(self, dim: str):
        """The dimension of a DIMENSIONS entry, as mbsim.units represents dimensions."""
        if dim not in self._dims:
            self._dims[dim] = units.parse_quantity(f"1 {DIMENSIONS[dim][0]}")[1]
        return self._dims[dim]

    def formula(self, text: str, node: Node, where: Where, extra: set[str] | None):
        """Parse ``text`` and bind the parameters; it may use the parameters and the names
        ``extra`` (None: any name).  The cost is that of the formula's own names, not of
        the number of parameters (a deck of 10^4 chained parameters is read in linear time)."""
        try:
            expr = parse_expression(text)
            if extra is not None and any(n not in self.params and n not in extra
                                         for n in expr.names):
                parse_expression(text, allowed=sorted({*self.params, *extra}))  # the error
        except ExpressionError as exc:
            allowed = None if extra is None else {*self.params, *extra}
            raise self.error(where, self._formula_problem(text, exc, allowed), node) from None
        bound = {k: self.params[k] for k in expr.names if k in self.params}
        return expr.bind(bound) if bound else expr

    def _formula_problem(self, text: str, exc: ExpressionError, allowed) -> str:
        if allowed is not None:
            try:
                names = parse_expression(text).names
            except ExpressionError:
                names = set()
            unknown = sorted(set(names) - set(allowed))
            if unknown:
                bare = NAME_RE.fullmatch(text.strip())
                what = "parameter" if bare else "name"
                known = ", ".join(sorted(allowed)) or "no parameters"
                # a misspelt constant or function ('pie', 'sine') is as likely as a parameter
                hint = suggest(unknown[0], sorted(allowed) + sorted(RESERVED) + sorted(FUNCTIONS))
                hint = hint or f" (known: {_cut(known)}; constants {', '.join(RESERVED)})"
                in_text = "" if bare else f" in {quote(text)}"
                return f"unknown {what} {quote(unknown[0])}{in_text}{hint}"
        return f"bad formula: {_message(exc)}"

    def vector(self, node: Node, where: Where, n: int = 3, dim: str | None = None) -> np.ndarray:
        """Exactly ``n`` numbers."""
        if node.kind != "seq" or len(node.value) != n:
            raise self.error(where, f"expected {n} numbers, got {describe(node)}", node)
        return np.array(self.numbers(node.value, where, dim))

    def numbers(self, nodes: list[Node], where: Where, dim: str | None = None) -> list[float]:
        """:meth:`number` of each item of the list at ``where``; plain finite numbers (most of a
        deck's) read directly, without the Where each item's message would need."""
        out = []
        for i, v in enumerate(nodes):
            x = v.value
            if v.kind == "scalar" and type(x) in (float, int) and abs(x) < 1e308:  # (not NaN)
                out.append(float(x))
            else:
                out.append(self.number(v, _item(where, i, v), dim))
        return out

    def setting(self, node: Node, where: Where, dim: str | None):
        """An analysis setting: numbers, quantities and formulas of parameters -> float (ints
        only where ``dim`` is known); other strings, ints and bools stay as given."""
        if node.kind == "map":
            return {k: self.setting(c, w, None) for k, c, w in self.items(node, where)}
        if node.kind == "seq":
            return [self.setting(c, _item(where, i, c), None) for i, c in enumerate(node.value)]
        value = node.value
        if isinstance(value, bool) or value is None:
            return value
        if not isinstance(value, (int, float, str)):  # a date
            raise self.error(where, f"expected a number, a name or true/false, got "
                             f"{describe(node)}", node)
        if isinstance(value, float) or isinstance(value, int) and dim is not None:
            return self.number(node, where, dim)
        if isinstance(value, str) and self._numeric_text(value.strip()):
            return self.number(node, where, dim)
        return value

    def _numeric_text(self, text: str) -> bool:
        if units.looks_like_quantity(text) or text in self.params:
            return True
        try:
            expr = parse_expression(text)
        except ExpressionError:  # not a formula: a plain string setting ('dop853')
            return False
        return all(n in self.params for n in expr.names)

    def item(self, where: Where, i: int, node: Node) -> Where:
        """The Where of item ``i`` of the list at ``where``."""
        return _item(where, i, node)

    # -- functions of time ---------------------------------------------------------------
    def function(self, node: Node, where: Where, dim: str | None) -> FunctionSpec:
        """A function of time: number, formula in t, or {expression|polynomial|table|harmonic}."""
        if node.kind == "scalar" and node.value is not None and not isinstance(node.value, bool):
            return self._scalar_function(node, where, dim, {"t"})
        if node.kind != "map":
            raise self.error(
                where,
                "expected a function of time (a number, a formula in t, or "
                f"{{{' | '.join(FUNCTION_FORMS)}: ...}}), got {describe(node)}",
                node,
            )
        forms = [k for k in node.value if k in FUNCTION_FORMS]
        if len(forms) != 1:
            got = ", ".join(node.value) or "nothing"
            raise self.error(
                where,
                f"expected exactly one of {', '.join(FUNCTION_FORMS)}, "
                f"got {got}{suggest(next(iter(node.value), ''), FUNCTION_FORMS)}",
            )
        form = forms[0]
        allowed = (form, "interpolation") if form == "table" else (form,)
        got = self.fields(node, where, allowed, what="a function")
        child, w = got[form]
        if form == "expression":
            return self._scalar_function(child, w, dim, {"t"})
        if form == "polynomial":
            if child.kind != "seq" or not child.value:
                raise self.error(w, f"expected a list of coefficients, got {describe(child)}")
            if len(child.value) > limits.POLYNOMIAL_TERMS.value:
                raise self.error(w, limits.POLYNOMIAL_TERMS.exceeded(len(child.value)))
            coeffs = [self.number(v, _item(w, i, v)) for i, v in enumerate(child.value)]
            return FunctionSpec("polynomial", {"coefficients": coeffs}, w)
        if form == "harmonic":
            h = self.fields(child, w, HARMONIC_KEYS, ("amplitude", "frequency"), "harmonic")
            dims = {
                "amplitude": dim,
                "frequency": "angular_velocity",
                "phase": "angle",
                "offset": dim,
            }
            data = {k: self.number(*h[k], dims[k]) if k in h else 0.0 for k in HARMONIC_KEYS}
            return FunctionSpec("harmonic", data, w)
        return self._table(child, w, got, where, dim)

    def _table(self, child: Node, w: Where, got: dict, where: Where, dim) -> FunctionSpec:
        tab = self.fields(child, w, ("t", "value"), ("t", "value"), "a table")
        cols = {}
        for key, kdim in (("t", "time"), ("value", dim)):
            col, cw = tab[key]
            if col.kind != "seq":
                raise self.error(cw, f"expected a list of numbers, got {describe(col)}", col)
            if len(col.value) > limits.TABLE_POINTS.value:
                raise self.error(cw, limits.TABLE_POINTS.exceeded(len(col.value)))
            plain = [v.value for v in col.value]  # numbers as YAML read them: no conversion
            if all(type(x) in (int, float) for x in plain) and np.isfinite(
                    arr := np.array(plain, dtype=float)).all():  # fmt: skip
                cols[key] = arr
                continue
            cols[key] = np.array(
                [self.number(v, _item(cw, i, v), kdim) for i, v in enumerate(col.value)]
            )
        t, value = cols["t"], cols["value"]
        if len(t) < 2 or len(t) != len(value):
            raise self.error(
                w,
                f"a table needs at least 2 points and as many values as times, "
                f"got {len(t)} times and {len(value)} values",
            )
        bad = np.nonzero(np.diff(t) <= 0)[0]
        if bad.size:
            k = int(bad[0]) + 1
            raise self.error(
                tab["t"][1],
                f"times must be strictly increasing, got "
                f"t[{k - 1}] = {t[k - 1]:g}, t[{k}] = {t[k]:g}",
            )
        interp = "cubic"
        if "interpolation" in got:
            interp = self.choice(*got["interpolation"], INTERPOLATIONS, "interpolation")
        return FunctionSpec("table", {"t": t, "value": value, "interpolation": interp}, where)

    def _scalar_function(self, node: Node, where: Where, dim, variables: set[str]):
        """A number or a string formula: constant if it does not use ``variables``."""
        text = node.value.strip() if isinstance(node.value, str) else None
        if text is None or text in self.params or _is_float(text):
            return FunctionSpec("constant", {"value": self.number(node, where, dim)}, where)
        if units.looks_like_quantity(text):
            return FunctionSpec("constant", {"value": self.number(node, where, dim)}, where)
        expr = self.formula(text, node, where, variables)
        if not set(expr.names) & variables:
            value = self._finite(_constant(expr), node, where, text)
            return FunctionSpec("constant", {"value": value}, where)
        return FunctionSpec("expression", {"expr": expr}, where)

    def law(self, node: Node, where: Where, dim, names) -> FunctionSpec | Expression:
        """A force law: a function of time (FunctionSpec), or a formula that also uses other
        ``names`` (None: any name), kept as a bound Expression for the force model."""
        if node.kind != "scalar" or not isinstance(node.value, str):
            return self.function(node, where, dim)
        text = node.value.strip()
        if text in self.params or _is_float(text) or units.looks_like_quantity(text):
            return self.function(node, where, dim)
        expr = self.formula(text, node, where, None if names is None else {"t", *names})
        if not expr.names:  # folded to a constant once parameters are bound (e.g. 0 psi)
            return FunctionSpec("constant", {"value": self._finite(_constant(expr), node, where,
                                                                  text)}, where)
        if set(expr.names) <= {"t"}:
            return FunctionSpec("expression", {"expr": expr}, where)
        return expr

    # -- points ---------------------------------------------------------------------------
    def body_names(self, node: Node, where: Where, bodies, n: int) -> tuple[str, ...]:
        """``n`` distinct known body names (a single name is accepted for n = 1)."""
        items = node.value if node.kind == "seq" else [node] if n == 1 else None
        if items is None or len(items) != n:
            want = "1 body name" if n == 1 else f"{n} body names [i, j]"
            raise self.error(where, f"expected {want}, got {describe(node)}", node)
        seq = node.kind == "seq"
        names = tuple(self.name(v, _item(where, i, v) if seq else where, bodies, "body")
                      for i, v in enumerate(items))  # fmt: skip
        if len(set(names)) != n:
            raise self.error(where, f"expected two different bodies, got {describe(node)}", node)
        return names

    def points(self, node: Node, where: Where, needs: dict[str, str]) -> dict[str, PointSet]:
        """One entry per body of the item (``needs``: body -> points it must give), no other."""
        got = {k: (c, w) for k, c, w in self.items(node, where)}
        for key, (_, w) in got.items():
            if key not in needs:
                listed = ", ".join(needs)
                raise self.error(w, f"{quote(key)} is not a body of this item (bodies: {listed})"
                                 f"{suggest(key, needs)}")  # fmt: skip
        for body in needs:
            if body not in got:
                raise self.error(where, f"missing the points of body {body!r}")
        return {b: self.pointset(*got[b], needs[b]) for b in needs}

    def pointset(self, node: Node, where: Where, needs: str) -> PointSet:
        """{P, Q, R} or a flat list of 3/6/9 numbers; ``needs`` (e.g. 'PQ') must be given."""
        pts: dict[str, np.ndarray] = {}
        wheres: dict[str, Where] = {}
        if node.kind == "seq":
            n = len(node.value)
            if n not in (3, 6, 9):
                raise self.error(
                    where,
                    f"expected 3, 6 or 9 numbers (P, P Q or P Q R), got {describe(node)}",
                    node,
                )
            for k in range(n // 3):
                key = "PQR"[k]
                wheres[key] = Where(self.file, _join(where.path, key), where.line)
                pts[key] = np.array(self.numbers(node.value[3 * k : 3 * k + 3], wheres[key],
                                                 "length"))
        elif node.kind == "map":
            for key, (child, w) in self.fields(
                node, where, ("P", "Q", "R"), ("P",), "points"
            ).items():
                pts[key], wheres[key] = self.vector(child, w, 3, "length"), w
        else:
            raise self.error(
                where,
                f"expected {{P: [x, y, z], ...}} or 3, 6 or 9 numbers, got {describe(node)}",
                node,
            )
        missing = [k for k in needs if k not in pts]
        if missing:
            raise self.error(
                where, f"needs points {', '.join(needs)}; {', '.join(missing)} missing", node
            )
        if "R" in pts and "Q" not in pts:
            raise self.error(wheres["R"], "R given without Q (P→R is measured against P→Q)")
        self._check_axes(pts, wheres)
        return PointSet(pts["P"], pts.get("Q"), pts.get("R"), where)

    def _check_axes(self, pts: dict[str, np.ndarray], wheres: dict[str, Where]) -> None:
        if "Q" not in pts:
            return
        f = pts["Q"] - pts["P"]
        nf = math.sqrt(f.dot(f))  # (np.linalg.norm's sqrt(f . f), without its dispatch)
        if nf < ZERO_LENGTH:
            raise self.error(wheres["Q"], "zero-length axis P→Q (Q coincides with P)")
        if "R" not in pts:
            return
        g = pts["R"] - pts["P"]
        ng = math.sqrt(g.dot(g))
        if ng < ZERO_LENGTH:
            raise self.error(wheres["R"], "zero-length direction P→R (R coincides with P)")
        cos = np.dot(f, g) / (nf * ng)
        angle = math.acos(min(1.0, max(-1.0, cos)))
        off = min(angle, math.pi - angle)  # distance from parallel
        if off <= PARALLEL:
            raise self.error(
                wheres["R"], "P→R is parallel to P→Q; R must fix a direction across the axis"
            )
        if off <= NEARLY_PARALLEL:
            raise self.error(
                wheres["R"],
                f"P→R is nearly parallel to P→Q "
                f"({math.degrees(off):.3g}° from parallel); R must fix a direction "
                "across the axis",
            )
        if abs(angle - math.pi / 2) > SKEW_WARNING:
            self.warn(
                wheres["R"],
                f"P→R is {math.degrees(angle):.2f}° from P→Q; orthogonalised against it",
            )


def _constant(expr: Expression) -> float:
    """A constant formula's value; overflow and invalid operations give inf/nan for
    :meth:`Reader._finite` to report, without numpy's RuntimeWarning lines on the terminal."""
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return float(expr({}))


def _cut(text: str, limit: int = 2 * QUOTE_LIMIT) -> str:
    return text if len(text) <= limit else text[:limit] + ", ..."


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _item(where: Where, i: int, node: Node) -> Where:
    return Where(where.file, f"{where.path}[{i}]", node.line if node.line else where.line)


def _a(dim: str | None) -> str:
    return "a number" if dim is None else f"a number ({DIMENSIONS[dim][1]})"


def _an(words: str) -> str:
    return f"{'an' if words[0] in 'aeiou' else 'a'} {words}"


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _message(exc: Exception) -> str:
    return " ".join(str(getattr(exc, "message", None) or exc).split())
