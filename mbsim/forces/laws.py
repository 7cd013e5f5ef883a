"""Scalar force laws: a function of time, or a formula in t, the element's own variables
(e.g. a TSDA's ``l`` and ``ldot``) and its named measures (:mod:`mbsim.forces.measures`).

The deck gives a law as a number, a FunctionSpec (any function-of-time form) or a bound
Expression (parameters already substituted by the loader); code may also pass a formula
string.  :func:`compile_law` checks the names once, so that evaluation is a plain call:
``law(st, t, own)`` with ``own`` the element's variables ({'l': ..., 'ldot': ...}).
"""

from __future__ import annotations

import difflib

from mbsim import functions
from mbsim.deck.spec import FunctionSpec
from mbsim.errors import DeckError, ExpressionError, Where
from mbsim.expr import Expression, parse_expression


class Law:
    """f(st, t, own) -> float.  ``kind``: 'constant' | 'time' | 'expression'; ``text`` for
    messages; ``measures``: the (name, Measure) pairs the formula uses."""

    __slots__ = ("_expr", "_tf", "kind", "measures", "own", "text", "value")

    def __init__(self, kind, text, value=0.0, tf=None, expr=None, measures=(), own=()):
        self.kind, self.text, self.value = kind, text, float(value)
        self._tf, self._expr = tf, expr
        self.measures, self.own = tuple(measures), tuple(own)

    def __call__(self, st, t: float, own: dict | None = None) -> float:
        if self.kind == "constant":
            return self.value
        if self.kind == "time":
            return float(self._tf(t))
        env = {"t": float(t)}
        if own:
            env.update(own)
        for name, m in self.measures:
            env[name] = m.value(st, t)
        return float(self._expr(env))

    @property
    def is_constant(self) -> bool:
        return self.kind == "constant"

    def __repr__(self) -> str:
        return f"<law {self.text}>"


def compile_law(value, where: Where, measures: dict, own: tuple[str, ...] = ()) -> Law:
    """Compile a deck law; names other than t, ``own`` and ``measures`` are a DeckError at
    ``where`` with a suggestion."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return Law("constant", f"{float(value):g}", value=value)
    if isinstance(value, FunctionSpec):
        tf = functions.from_spec(value)
        if tf.kind == "constant":
            return Law("constant", tf.text, value=tf.value)
        return Law("time", tf.text, tf=tf)
    allowed = {"t", *own, *measures}
    if isinstance(value, str):
        try:
            value = parse_expression(value)
        except ExpressionError as exc:
            raise DeckError(f"bad formula: {exc}", where) from None
    if not isinstance(value, Expression):
        raise DeckError(
            f"expected a law (number, function of t or formula), got {type(value).__name__}", where
        )
    unknown = sorted(value.names - allowed)
    if unknown:
        close = difflib.get_close_matches(unknown[0], sorted(allowed), n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        known = ", ".join(sorted(allowed))
        raise DeckError(
            f"unknown name {unknown[0]!r} in the law {str(value)!r}{hint} "
            f"(a law may use: {known}; declare others under 'measures')",
            where,
        )
    if value.is_constant():
        return Law("constant", str(value), value=float(value({})))
    used = tuple((n, measures[n]) for n in sorted(value.names) if n in measures)
    return Law(
        "expression",
        str(value),
        expr=value,
        measures=used,
        own=tuple(n for n in own if n in value.names),
    )


def compile_optional(
    data: dict, key: str, where: Where, measures: dict, own: tuple[str, ...] = ()
) -> Law | None:
    """The law ``data[key]`` (None when absent)."""
    if data.get(key) is None:
        return None
    return compile_law(data[key], where.child(key), measures, own)
