"""Scalar functions of time for drivers and time-varying loads, with exact first and second
derivatives (drivers need f, f' and f'' for Phi, nu and gamma; Haug Ch. 9)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from mbsim.deck.spec import FunctionSpec


class TimeFunction:
    """f(t) with derivatives: ``f(t)``, ``f.d1(t)``, ``f.d2(t)``. Subclasses set the three
    callables."""

    kind = "base"

    def __init__(self, f: Callable, d1: Callable, d2: Callable, text: str = ""):
        self._f, self._d1, self._d2 = f, d1, d2
        self.text = text

    def __call__(self, t):
        return self._f(t)

    def d1(self, t):
        return self._d1(t)

    def d2(self, t):
        return self._d2(t)

    def __repr__(self) -> str:
        return f"<{self.kind} {self.text}>"


def constant(value: float) -> TimeFunction:
    v = float(value)
    tf = TimeFunction(lambda t: v + 0.0 * np.asarray(t), lambda t: 0.0 * np.asarray(t),
                      lambda t: 0.0 * np.asarray(t), f"{v:g}")
    tf.kind = "constant"
    tf.value = v
    return tf


def polynomial(coefficients) -> TimeFunction:
    c = np.polynomial.Polynomial(np.asarray(coefficients, dtype=float))
    dc, ddc = c.deriv(1), c.deriv(2)
    tf = TimeFunction(c, dc, ddc, "polynomial " + str(list(np.asarray(coefficients, float))))
    tf.kind = "polynomial"
    return tf


def harmonic(amplitude=1.0, frequency=1.0, phase=0.0, offset=0.0) -> TimeFunction:
    a, w, ph, c = map(float, (amplitude, frequency, phase, offset))
    tf = TimeFunction(
        lambda t: a * np.sin(w * np.asarray(t) + ph) + c,
        lambda t: a * w * np.cos(w * np.asarray(t) + ph),
        lambda t: -a * w * w * np.sin(w * np.asarray(t) + ph),
        f"{a:g} sin({w:g} t + {ph:g}) + {c:g}",
    )
    tf.kind = "harmonic"
    return tf


def table(t, value, interpolation: str = "cubic") -> TimeFunction:
    """Tabulated f(t): 'cubic' (not-a-knot spline), 'pchip' (monotone) or 'linear'.

    Outside the table the end values are held (cubic/pchip extrapolate otherwise, which can
    run away); the derivatives there are zero.
    """
    t = np.asarray(t, dtype=float)
    v = np.asarray(value, dtype=float)
    if interpolation == "linear":
        spl = None

        def f(x):
            return np.interp(x, t, v)

        def d1(x):
            x = np.asarray(x, dtype=float)
            k = np.clip(np.searchsorted(t, x, side="right") - 1, 0, len(t) - 2)
            slope = (v[k + 1] - v[k]) / (t[k + 1] - t[k])
            return np.where((x < t[0]) | (x > t[-1]), 0.0, slope)

        def d2(x):
            return 0.0 * np.asarray(x, dtype=float)
    else:
        # imported here: scipy.interpolate costs ~0.2 s CPU to import, and only tables need it
        from scipy.interpolate import CubicSpline, PchipInterpolator

        spl = CubicSpline(t, v) if interpolation == "cubic" else PchipInterpolator(t, v)
        s1, s2 = spl.derivative(1), spl.derivative(2)

        def f(x):
            return spl(np.clip(x, t[0], t[-1]))

        def d1(x):
            x = np.asarray(x, dtype=float)
            return np.where((x < t[0]) | (x > t[-1]), 0.0, s1(np.clip(x, t[0], t[-1])))

        def d2(x):
            x = np.asarray(x, dtype=float)
            return np.where((x < t[0]) | (x > t[-1]), 0.0, s2(np.clip(x, t[0], t[-1])))

    tf = TimeFunction(f, d1, d2, f"table ({len(t)} points, {interpolation})")
    tf.kind = "table"
    return tf


def expression(expr) -> TimeFunction:
    """An Expression in the variable ``t`` (parameters already bound); derivatives are symbolic."""
    e1 = expr.diff("t")
    e2 = e1.diff("t")

    def wrap(e):
        if e.is_constant():
            c = float(e({}))
            return lambda t: c + 0.0 * np.asarray(t)
        return lambda t: e({"t": t})

    tf = TimeFunction(wrap(expr), wrap(e1), wrap(e2), str(expr))
    tf.kind = "expression"
    return tf


def from_spec(spec: FunctionSpec | float) -> TimeFunction:
    """Build the TimeFunction a deck's FunctionSpec describes."""
    if isinstance(spec, (int, float)):
        return constant(spec)
    d = spec.data
    if spec.kind == "constant":
        return constant(d["value"])
    if spec.kind == "polynomial":
        return polynomial(d["coefficients"])
    if spec.kind == "harmonic":
        return harmonic(d.get("amplitude", 1.0), d.get("frequency", 1.0), d.get("phase", 0.0),
                        d.get("offset", 0.0))
    if spec.kind == "table":
        return table(d["t"], d["value"], d.get("interpolation", "cubic"))
    if spec.kind == "expression":
        return expression(d["expr"])
    raise ValueError(f"unknown function kind {spec.kind!r}")
