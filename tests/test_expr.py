"""Tests of mbsim.expr: evaluation against numpy, derivatives against finite differences,
printing round trips, and the whitelist (every forbidden construct is an ExpressionError)."""

from __future__ import annotations

import ast
import builtins
import copy
import math
import pickle

import numpy as np
import pytest

from mbsim.errors import ExpressionError, MbsimError
from mbsim.expr import FUNCTIONS, Expression, evaluate, parse_expression

RNG = np.random.default_rng(20240611)

# ---- evaluation ----------------------------------------------------------------------------------

FORMULAS = [
    ("pi/2 - 2*pi*t", lambda x, y, t: np.pi / 2 - 2 * np.pi * t),
    ("x**2 - 3*y + 1e-3/t", lambda x, y, t: x**2 - 3 * y + 1e-3 / t),
    ("-x**2", lambda x, y, t: -(x**2)),
    ("2**-t", lambda x, y, t: 2.0**-t),
    ("x**y**2", lambda x, y, t: x ** (y**2)),
    ("sin(x)*cos(y) + tan(t)", lambda x, y, t: np.sin(x) * np.cos(y) + np.tan(t)),
    ("exp(-t)*log(1 + x**2) + log10(t) + sqrt(t)",
     lambda x, y, t: np.exp(-t) * np.log(1 + x**2) + np.log10(t) + np.sqrt(t)),
    ("atan2(y, x) + hypot(x, y) + atan(x)",
     lambda x, y, t: np.arctan2(y, x) + np.hypot(x, y) + np.arctan(x)),
    ("asin(t) + acos(t/2)", lambda x, y, t: np.arcsin(t) + np.arccos(t / 2)),
    ("sinh(x) - cosh(y) + tanh(t)", lambda x, y, t: np.sinh(x) - np.cosh(y) + np.tanh(t)),
    ("abs(x) + sign(y) + floor(3*x) + ceil(3*y)",
     lambda x, y, t: np.abs(x) + np.sign(y) + np.floor(3 * x) + np.ceil(3 * y)),
    ("min(x, y, t) + max(x, y)",
     lambda x, y, t: np.minimum(np.minimum(x, y), t) + np.maximum(x, y)),
    ("clip(x, -0.5, 0.5)", lambda x, y, t: np.clip(x, -0.5, 0.5)),
    ("where(y < 0, 10*x, -x)", lambda x, y, t: np.where(y < 0, 10 * x, -x)),
    ("3*x if y >= 0 else t", lambda x, y, t: np.where(y >= 0, 3 * x, t)),
    ("(x > y)*2 + (x != y) - (t == t)", lambda x, y, t: (x > y) * 2.0 + (x != y) - 1.0),
    ("heaviside(x) + rad2deg(y) + deg2rad(t) + 30*deg",
     lambda x, y, t: np.heaviside(x, 1.0) + np.degrees(y) + np.radians(t) + np.pi / 6),
    ("e**t - exp(t)", lambda x, y, t: 0 * t),
]  # fmt: skip


@pytest.mark.parametrize("text, ref", FORMULAS, ids=[f[0] for f in FORMULAS])
def test_evaluation_matches_numpy_for_scalars_and_arrays(text, ref):
    x, y = RNG.uniform(-2, 2, 50), RNG.uniform(-2, 2, 50)
    t = RNG.uniform(0.1, 0.9, 50)
    if text == "x**y**2":
        x = np.abs(x) + 0.1  # real powers need a positive base
    e = parse_expression(text)
    got = e(x=x, y=y, t=t)
    np.testing.assert_allclose(got, ref(x, y, t), rtol=1e-13, atol=1e-13)
    for i in range(3):  # the scalar path (math, not numpy) must agree and give a Python float
        value = e({"x": float(x[i]), "y": float(y[i]), "t": float(t[i])})
        assert type(value) is float
        assert value == pytest.approx(ref(x[i], y[i], t[i]), rel=1e-13, abs=1e-13)


def test_scalar_and_array_inputs():
    e = parse_expression("pi/2 - 2*pi*t")
    assert e(t=0.25) == 0.0 and type(e(t=1)) is float  # ints and numpy scalars become floats
    assert type(e({"t": np.float32(0.5)})) is float
    t = np.linspace(0, 1, 7)
    np.testing.assert_allclose(e(t=t), np.pi / 2 - 2 * np.pi * t)
    np.testing.assert_allclose(e(t=[0.0, 0.25]), [np.pi / 2, 0.0])
    assert parse_expression("2*pi").is_constant() and parse_expression("2*pi")() == 2 * np.pi
    assert evaluate("a*b", {"a": 2.0}, b=3.0) == 6.0
    assert evaluate(4) == 4.0 and parse_expression(2.5).is_constant()


def test_names_exclude_constants_and_functions():
    e = parse_expression("where(v < 0, K/(y - yA) - Fmin, 0) + sin(pi*e*t)")
    assert e.names == frozenset({"v", "K", "y", "yA", "Fmin", "t"})
    assert e.text == "where(v < 0, K/(y - yA) - Fmin, 0) + sin(pi*e*t)"


def test_step_and_heaviside_values():
    # ADAMS STEP(x, x0, h0, x1, h1): h0 + (h1 - h0) s^2 (3 - 2 s), s = (x - x0)/(x1 - x0)
    e = parse_expression("step(x, 1, -2, 3, 4)")
    assert e(x=0.0) == -2.0 and e(x=1.0) == -2.0 and e(x=3.0) == 4.0 and e(x=9.0) == 4.0
    assert e(x=2.0) == pytest.approx(1.0)  # midpoint: (h0 + h1)/2
    assert e(x=1.5) == pytest.approx(-2 + 6 * 0.25**2 * (3 - 0.5))
    xs = np.array([0.0, 1.5, 2.0, 5.0])
    np.testing.assert_allclose(e(x=xs), [e(x=float(v)) for v in xs])
    h = parse_expression("heaviside(x)")
    assert (h(x=-1e-300), h(x=0.0), h(x=2.0)) == (0.0, 1.0, 1.0)
    np.testing.assert_array_equal(h(x=np.array([-1.0, 0.0, 1.0])), [0.0, 1.0, 1.0])


def test_singular_points_follow_numpy():
    with pytest.warns(RuntimeWarning):
        assert parse_expression("1/x")(x=0.0) == math.inf
    with pytest.warns(RuntimeWarning):
        assert math.isnan(parse_expression("x**0.5")(x=-4.0))  # nan, not a complex number
    with pytest.warns(RuntimeWarning):
        assert parse_expression("10**x")(x=1e6) == math.inf
    # a scalar where() evaluates only the branch it takes: no warning, no nan
    assert parse_expression("where(x > 0, 1/x, 0)")(x=0.0) == 0.0


# ---- derivatives -----------------------------------------------------------------------------
# Central differences with h = 1e-6: truncation error h^2 |f'''|/6 ~ 2e-13 |f'''| and round-off
# eps |f| / h ~ 2e-10 |f|; the sample domains keep |f|, |f'''| below ~1e2, so a relative
# tolerance of 1e-7 (scaled by max(1, |f|, |f'|)) has three orders of margin and still catches
# any wrong rule (those give O(1) errors).
H, RTOL = 1e-6, 1e-7


def _uniform(*bounds):
    return lambda: [RNG.uniform(lo, hi) for lo, hi in bounds]


def _away(sample, kinks):  # resample until every kink is at least 0.01 away
    def draw():
        while True:
            args = sample()
            if all(abs(k) > 0.01 for k in kinks(*args)):
                return args

    return draw


SAMPLERS = {
    "asin": _uniform((-0.9, 0.9)), "acos": _uniform((-0.9, 0.9)), "tan": _uniform((-1.2, 1.2)),
    "log": _uniform((0.2, 3)), "log10": _uniform((0.2, 3)), "sqrt": _uniform((0.2, 3)),
    "atan2": _uniform((-2, 2), (0.3, 2)), "hypot": _uniform((-2, 2), (0.3, 2)),
    "abs": _away(_uniform((-2, 2)), lambda x: [x]),
    "sign": _away(_uniform((-2, 2)), lambda x: [x]),
    "heaviside": _away(_uniform((-2, 2)), lambda x: [x]),
    "floor": _away(_uniform((-3, 3)), lambda x: [x - round(x)]),
    "ceil": _away(_uniform((-3, 3)), lambda x: [x - round(x)]),
    "min": _away(_uniform(*[(-2, 2)] * 3), lambda a, b, c: [a - b, a - c, b - c]),
    "max": _away(_uniform(*[(-2, 2)] * 3), lambda a, b, c: [a - b, a - c, b - c]),
    "clip": _away(_uniform((-2, 2), (-1, -0.3), (0.3, 1)), lambda x, lo, hi: [x - lo, x - hi]),
    "where": lambda: [RNG.choice([-1.0, 1.0]) * RNG.uniform(0.5, 1), *RNG.uniform(-2, 2, 2)],
    "step": _away(_uniform((-1.5, 1.5), (-1, -0.3), (-2, 2), (0.3, 1), (-2, 2)),
                  lambda x, x0, h0, x1, h1: [x - x0, x - x1]),
}  # fmt: skip
NARGS = {name: 3 if f.nargs[1] is None else f.nargs[0] for name, f in FUNCTIONS.items()}
CASES = [(name, i) for name, n in NARGS.items() for i in range(n)]


def _check_derivative(e: Expression, var: str, env: dict) -> None:
    d = e.diff(var)
    hi, lo = dict(env), dict(env)
    hi[var] += H
    lo[var] -= H
    fd = (e(hi) - e(lo)) / (2 * H)
    scale = max(1.0, abs(e(env)), abs(fd))
    assert abs(d(env) - fd) <= RTOL * scale, f"d/d{var} {e} = {d} at {env}: {d(env)} vs FD {fd}"


@pytest.mark.parametrize("name, i", CASES, ids=[f"{n}-arg{i}" for n, i in CASES])
def test_function_derivative_matches_finite_difference(name, i):
    n = NARGS[name]
    names = [f"a{k}" for k in range(n)]
    e = parse_expression(f"{name}({', '.join(names)})")
    sample = SAMPLERS.get(name, _uniform(*[(-2, 2)] * n))
    for _ in range(5):
        env = dict(zip(names, map(float, sample()), strict=True))
        _check_derivative(e, names[i], env)  # first derivative
        _check_derivative(e.diff(names[i]), names[i], env)  # second, via the first's rules


OPERATOR_CASES = ["x + y", "x - y", "x*y", "x/y", "-x", "x**3", "x**y", "y**x", "2**x",
                  "e**(x*y)", "x**-2", "(x < y)*x", "x*y/(1 + x**2)**0.5", "sin(x*y)**2",
                  "step(x, y - 3, y, y + 3, x*y)", "clip(x, y - 3, y*x)", "min(x**2, y, 5)",
                  "atan2(x*y, y**2 + 1)", "hypot(x, x*y)", "where(x > 0, exp(x*y), y - x)"]


@pytest.mark.parametrize("text", OPERATOR_CASES)
def test_operator_and_composite_derivatives(text):
    e = parse_expression(text)
    for _ in range(5):
        env = {"x": RNG.uniform(0.5, 2), "y": RNG.uniform(0.5, 2)}
        for var in ("x", "y"):
            _check_derivative(e, var, env)
            _check_derivative(e.diff(var), var, env)


def test_exact_derivatives_and_simplification():
    e = parse_expression("pi/2 - 2*pi*t")
    assert str(e.diff("t")) == repr(-2 * math.pi) and str(e.diff("t").diff("t")) == "0"
    assert str(parse_expression("x*y").diff("z")) == "0"
    assert str(parse_expression("1*x + 0").diff("x")) == "1"
    assert str(parse_expression("x**3").diff("x")) == "3*x**2"
    assert str(parse_expression("sin(2*t)").diff("t")) == "cos(2*t)*2"
    assert str(parse_expression("e**t").diff("t")) == "e**t"
    s = parse_expression("sin(2*t)*exp(-t)")
    t = np.linspace(0, 3, 11)  # (sin 2t e^-t)'' = (-3 sin 2t - 4 cos 2t) e^-t
    ref = (-3 * np.sin(2 * t) - 4 * np.cos(2 * t)) * np.exp(-t)
    np.testing.assert_allclose(s.diff("t").diff("t")(t=t), ref, rtol=1e-12, atol=1e-12)
    step = parse_expression("step(t, 0, 0, 2, 1)")  # s = t/2: U' = 6 s (1 - s)/2
    assert step.diff("t")(t=1.0) == pytest.approx(0.75) and step.diff("t")(t=2.5) == 0.0
    assert step.diff("t").diff("t")(t=0.5) == pytest.approx(1.5 * (1 - 2 * 0.25))
    d = parse_expression("abs(x)").diff("x")
    assert (d(x=-3.0), d(x=2.0)) == (-1.0, 1.0)
    with pytest.raises(ExpressionError, match="differentiate"):
        parse_expression("x").diff("2x")


# ---- bind, printing -----------------------------------------------------------------------------


def test_bind_substitutes_and_folds():
    e = parse_expression("C*(y0 - y) + 0*k")
    b = e.bind({"C": 2, "y0": 1.5, "unused": 7.0})
    assert b.names == frozenset({"y"}) and str(b) == "2*(1.5 - y)"  # 0*k simplified away
    assert b(y=1.0, k=3.0) == 1.0
    c = parse_expression("2*pi*f*A").bind({"f": 0.5, "A": 3})
    assert c.is_constant() and str(c) == repr(3 * math.pi) and c() == 3 * math.pi
    assert parse_expression("x").bind({}) == parse_expression("x")
    for bad, match in [
        ({"pi": 3.0}, "reserved"),
        ({"e": 1.0}, "reserved"),
        ({"C": "abc"}, "finite number"),
        ({"C": math.inf}, "finite number"),
    ]:
        with pytest.raises(ExpressionError, match=match):
            e.bind(bad)


ROUND_TRIP = ["pi/2 - 2*pi*t", "-x**2", "(-x)**2", "(x**2)**3", "x**2**3", "x**-2", "a - (b - c)",
              "a/(b*c)", "a - -2", "-(a*b)", "(a < b)*3", "(a < b) == (c > d)", "-pi", "1e-20*x",
              "where(v < 0, K/(y - yA) - Fmin, 0)", "3 if t > 1 else -1", "1.5e300*x", "+x",
              "min(a, b, c) + max(a, b)", "step(t, 0, 0, 1, 2)", "atan2(y, x)", "2*-x"]  # fmt: skip


@pytest.mark.parametrize("text", ROUND_TRIP)
def test_str_round_trips_through_the_parser(text):
    e = parse_expression(text)
    for x in (e, e.diff("t"), e.diff("x"), e.diff("a"), e.diff("x").diff("x")):
        again = parse_expression(str(x))
        assert again == x, f"{x} -> {again}"
        assert str(again) == str(x)


# ---- the whitelist -------------------------------------------------------------------------

FORBIDDEN = [
    ("__import__('os')", "unknown function '__import__'"),
    ("().__class__", "attribute access '.__class__'"),
    ("().__class__.__bases__[0]", "not allowed"),
    ("open('x')", "unknown function 'open'"),
    ("[1,2]", "a list is not allowed"),
    ("(1, 2)", "a tuple is not allowed"),
    ("{1: 2}", "a dict is not allowed"),
    ("'a'", "'a' is not allowed"),
    ("b'a'", "is not allowed"),
    ("f'{x}'", "f-string"),
    ("lambda: 1", "lambda is not allowed"),
    ("(lambda: 0)()", "only functions named directly"),
    ("x.y", "attribute access '.y'"),
    ("x[0]", "subscript"),
    ("f(x=1)", "unknown function 'f'"),
    ("sin(x=1)", "keyword arguments are not allowed"),
    ("sin(*x)", "'*' unpacking"),
    ("2^3", "write powers as '**'"),
    ("x % 2", "operator '%'"),
    ("x // 2", "operator '//'"),
    ("x @ y", "operator '@'"),
    ("quux(1)", "unknown function 'quux'; allowed: abs"),
    ("sinn(x)", "did you mean 'sin'"),
    ("x and y", "'and'/'or'"),
    ("not x", "'not'"),
    ("~x", "'~'"),
    ("a < b < c", "chained comparisons"),
    ("x is None", "only the comparisons"),
    ("x in y", "only the comparisons"),
    ("[x for x in y]", "comprehension"),
    ("(y := 1)", "':='"),
    ("True", "True is not allowed"),
    ("None", "None is not allowed"),
    ("1j", "1j is not allowed"),
    ("sin", "'sin' is a function"),
    ("sin(1, 2)", "sin() takes 1 argument, got 2"),
    ("step(1, 2)", "takes 5 arguments"),
    ("min(1)", "takes at least 2 arguments"),
    ("1e999", "number out of range"),
    ("1" + "0" * 400, "number out of range"),
    ("x if y", "invalid formula"),
    ("import os", "invalid formula"),
    ("1; 2", "invalid formula"),
    ("x = 1", "invalid formula"),
    ("", "empty formula"),
    ("   ", "empty formula"),
    ("x\0", "invalid formula"),
    ("x" + "+x" * 6000, "longer than 10000"),
    ("-" * 150 + "x", "nested deeper than 100"),
    ("sin(" * 120 + "x" + ")" * 120, "nested deeper than 100"),
    ("(" * 300 + "x" + ")" * 300, "invalid formula"),  # Python's own parenthesis limit
]


@pytest.mark.parametrize("text, message", FORBIDDEN, ids=[repr(f[0][:30]) for f in FORBIDDEN])
def test_forbidden_constructs_raise_expression_error(text, message):
    with pytest.raises(ExpressionError) as info:
        parse_expression(text)
    assert message in str(info.value)
    assert isinstance(info.value, MbsimError) and info.value.exit_code == 2


def test_errors_give_the_column():
    cases = [("2^3", 2), ("1 + x.y", 5), ("a + open(1)", 5), ("x + [1]", 5), ("é + sin(x=1)", 9)]
    for text, col in cases:
        with pytest.raises(ExpressionError) as info:
            parse_expression(text)
        assert info.value.column == col, text
        assert info.value.text == text and f"(column {col})" in str(info.value)


def test_other_inputs_are_rejected():
    for bad in ([1, 2], None, b"x", True, math.nan):
        with pytest.raises(ExpressionError):
            parse_expression(bad)


def test_unknown_names_with_suggestions():
    with pytest.raises(ExpressionError, match=r"unknown name 'kk'; did you mean 'k'\?") as info:
        parse_expression("a + b + kk", allowed={"a", "b", "k"})
    assert info.value.column == 9
    assert parse_expression("a*k", allowed=["a", "k", "t"]).names == {"a", "k"}
    with pytest.raises(ExpressionError, match=r"unknown name 'zz' \(column 1\)"):
        parse_expression("zz", allowed=[])
    e = parse_expression("k*x")
    with pytest.raises(ExpressionError, match="unknown name 'k'; did you mean 'kk'"):
        e(x=1.0, kk=2.0)
    with pytest.raises(ExpressionError, match="must be a number"):
        e(x=1.0, k="two")


def test_formulas_never_reach_eval_or_exec(monkeypatch):
    real_compile = builtins.compile

    def boom(*args, **kwargs):
        raise AssertionError("eval/exec called")

    def ast_only(source, filename, mode, flags=0, *args, **kwargs):
        # ast.parse is compile(..., PyCF_ONLY_AST): a tree, never code objects
        assert flags & ast.PyCF_ONLY_AST, "formula compiled to code"
        return real_compile(source, filename, mode, flags, *args, **kwargs)

    monkeypatch.setattr(builtins, "eval", boom)
    monkeypatch.setattr(builtins, "exec", boom)
    monkeypatch.setattr(builtins, "compile", ast_only)
    e = parse_expression("sqrt(x) + where(x > 1, 2, 3)*unique_name_1234 + step(x, 0, 0, 1, 1)")
    assert e(x=4.0, unique_name_1234=1.0) == 5.0
    assert math.isfinite(e.diff("x").diff("x")(x=0.5, unique_name_1234=2.0))


def test_expressions_pickle_and_hash():
    e = parse_expression("C*(y0 - y) + step(t, 0, 0, 1, 1)", allowed=["C", "y0", "y", "t"])
    again = pickle.loads(pickle.dumps(e.diff("t")))
    assert again == e.diff("t") and hash(again) == hash(e.diff("t"))
    assert again(t=0.5) == e.diff("t")(t=0.5) and again.text == e.diff("t").text
    assert copy.deepcopy(e).names == e.names and repr(e).startswith("Expression(")


def test_functions_registry_is_documented():
    for name, f in FUNCTIONS.items():
        assert f.name == name and f.signature.startswith(f"{name}(") and f.doc
        lo, hi = f.nargs
        assert hi is None or hi >= lo >= 1


def test_long_sums_and_products_are_regrouped_with_the_same_value():
    """A sum or product of more terms than the depth limit is read as nested groups
    (mbsim.expr._regroup): the value is the left-to-right one up to round-off, and str()
    parses back to the same tree."""
    import random

    from mbsim.expr import MAX_DEPTH, parse_expression

    rng = random.Random(1)
    vals = [rng.uniform(0.5, 2.0) for _ in range(3 * MAX_DEPTH)]
    ops = [rng.choice("+-*/") for _ in vals[1:]]
    text = repr(vals[0]) + "".join(f" {o} x*{v!r}" for o, v in zip(ops, vals[1:]))
    ref = eval(text, {"x": 1.5})  # noqa: S307 - the test's own numbers
    expr = parse_expression(text)
    assert abs(expr(x=1.5) - ref) <= 1e-12 * abs(ref)
    assert parse_expression(str(expr)) == expr
    assert parse_expression(" - ".join(["x"] * 2000))(x=1.0) == -1998.0
