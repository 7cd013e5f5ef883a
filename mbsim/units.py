"""Quantities with units (``'55 mph'``, ``'500 psi'``, ``'9.81 m/s^2'``) converted to SI.

A unit is a scale factor to SI and an exponent vector over the base dimensions
(kg, m, s, rad). Unit expressions multiply (``*``, ``·``, ``.`` or a space), divide (``/``,
left to right: ``N*s/m`` is (N s)/m) and raise to integer powers (``^``, ``**``, ``²``, ``³``),
with parentheses: ``kg/(m*s^2)``. A space right after a divisor is ambiguous (``kg/m s^2``)
and rejected; write ``kg/(m s^2)`` or ``kg/m/s^2``.

Angles are a dimension of their own, so that ``'30 deg'`` is an angle, ``'600 rpm'`` an angular
velocity (rpm = 2 pi/60 rad/s) and a torque (N m) differs from a rotational stiffness
(N m/rad). ``Hz`` is 1/s, a *frequency*: ``'10 Hz'`` where an angular velocity is expected is an
error, never a silent factor 2 pi (write ``'600 rpm'`` or ``'62.8 rad/s'``). ``g`` is the gram
(not standard gravity); ``lb`` is the pound mass and ``lbf`` the pound force. Conversion
factors are the exact definitions (NIST SP 811): in = 0.0254 m, ft = 0.3048 m,
mph = 0.44704 m/s, lb = 0.45359237 kg, lbf = 4.4482216152605 N, psi = 6894.757293168 Pa.
"""

from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass

from mbsim.errors import ExpressionError

BASE = ("kg", "m", "s", "rad")


@dataclass(frozen=True)
class Unit:
    """``scale`` SI units of dimension ``dims`` (exponents of kg, m, s, rad)."""

    scale: float
    dims: tuple[int, int, int, int]
    doc: str = ""

    def __mul__(self, other: Unit) -> Unit:
        return Unit(self.scale * other.scale, _add(self.dims, other.dims, 1))

    def __truediv__(self, other: Unit) -> Unit:
        return Unit(self.scale / other.scale, _add(self.dims, other.dims, -1))

    def __pow__(self, k: int) -> Unit:
        return Unit(self.scale**k, tuple(k * d for d in self.dims))


def _add(a: tuple, b: tuple, sign: int) -> tuple[int, int, int, int]:
    return tuple(x + sign * y for x, y in zip(a, b, strict=True))


def _u(scale: float, doc: str, kg: int = 0, m: int = 0, s: int = 0, rad: int = 0) -> Unit:
    return Unit(scale, (kg, m, s, rad), doc)


NEWTON, PASCAL = _u(1.0, "newton", kg=1, m=1, s=-2), _u(1.0, "pascal", kg=1, m=-1, s=-2)
LBF = _u(4.4482216152605, "pound force", kg=1, m=1, s=-2)

UNITS: dict[str, Unit] = {
    "m": _u(1.0, "metre", m=1),
    "g": _u(1e-3, "gram", kg=1),
    "s": _u(1.0, "second", s=1),
    "rad": _u(1.0, "radian", rad=1),
    "deg": _u(math.pi / 180, "degree", rad=1),
    "°": _u(math.pi / 180, "degree", rad=1),
    "rev": _u(2 * math.pi, "revolution", rad=1),
    "rpm": _u(2 * math.pi / 60, "revolution per minute (2 pi/60 rad/s)", s=-1, rad=1),
    "Hz": _u(1.0, "hertz = 1/s (a frequency, not 2 pi rad/s)", s=-1),
    "min": _u(60.0, "minute", s=1),
    "h": _u(3600.0, "hour", s=1),
    "N": NEWTON,
    "Nm": _u(1.0, "newton metre", kg=1, m=2, s=-2),
    "Pa": PASCAL,
    "bar": _u(1e5, "bar", kg=1, m=-1, s=-2),
    "J": _u(1.0, "joule", kg=1, m=2, s=-2),
    "W": _u(1.0, "watt", kg=1, m=2, s=-3),
    "in": _u(0.0254, "inch", m=1),
    "ft": _u(0.3048, "foot", m=1),
    "mi": _u(1609.344, "mile", m=1),
    "mph": _u(0.44704, "mile per hour", m=1, s=-1),
    "lb": _u(0.45359237, "pound mass", kg=1),
    "lbf": LBF,
    "kip": _u(4448.2216152605, "kilopound force", kg=1, m=1, s=-2),
    "psi": _u(6894.757293168, "pound force per square inch", kg=1, m=-1, s=-2),
    "ksi": _u(6894757.293168, "thousand psi", kg=1, m=-1, s=-2),
    "slug": _u(14.593902937206364, "slug = lbf s^2/ft", kg=1),
}
_PREFIXES = {"n": 1e-9, "u": 1e-6, "µ": 1e-6, "m": 1e-3, "c": 1e-2, "h": 1e2, "k": 1e3, "M": 1e6,
             "G": 1e9}  # fmt: skip
# which prefixes each unit takes: only the ones engineers write, so that typos stay errors
for _base, _prefixes in {"m": "nuµmck", "g": "umk", "s": "nuµm", "N": "mkM", "Nm": "kM",
                         "Pa": "hkMG", "bar": "m", "J": "kM", "W": "kM", "Hz": "kM",
                         "rad": "m"}.items():  # fmt: skip
    for _p in _prefixes:
        _unit = UNITS[_base]
        UNITS[_p + _base] = Unit(_PREFIXES[_p] * _unit.scale, _unit.dims, f"{_p}{_unit.doc}")

DIMENSIONLESS: tuple[int, int, int, int] = (0, 0, 0, 0)
# named dimensions (exponents of kg, m, s, rad); the first name of a vector is the one reported
DIMENSIONS: dict[str, tuple[int, int, int, int]] = {
    "dimensionless": DIMENSIONLESS, "mass": (1, 0, 0, 0), "length": (0, 1, 0, 0),
    "time": (0, 0, 1, 0), "angle": (0, 0, 0, 1), "area": (0, 2, 0, 0), "volume": (0, 3, 0, 0),
    "velocity": (0, 1, -1, 0), "acceleration": (0, 1, -2, 0), "frequency": (0, 0, -1, 0),
    "angular velocity": (0, 0, -1, 1), "angular acceleration": (0, 0, -2, 1),
    "force": (1, 1, -2, 0), "torque": (1, 2, -2, 0), "energy": (1, 2, -2, 0),
    "power": (1, 2, -3, 0), "pressure": (1, -1, -2, 0), "stiffness": (1, 0, -2, 0),
    "damping": (1, 0, -1, 0), "rotational stiffness": (1, 2, -2, -1),
    "rotational damping": (1, 2, -1, -1), "inertia": (1, 2, 0, 0), "density": (1, -3, 0, 0),
    "momentum": (1, 1, -1, 0),
}  # fmt: skip
_NAMES = {}
for _name, _dims in DIMENSIONS.items():
    _NAMES.setdefault(_dims, _name)


def dimension_name(dims: tuple[int, ...]) -> str:
    """``'velocity'`` for (0, 1, -1, 0); unnamed vectors as ``'kg m^-1 s^-3'``."""
    if tuple(dims) in _NAMES:
        return _NAMES[tuple(dims)]
    return " ".join(b if d == 1 else f"{b}^{d}" for b, d in zip(BASE, dims, strict=True) if d)


_NUMBER = re.compile(r"\s*([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)")
_TOKEN = re.compile(r"\s+|[A-Za-zµμ°]+|\d+|\*\*|[*/^()·.²³+-]|.")
_SUPERSCRIPT = {"²": 2, "³": 3}
_KEYWORDS = {"if", "else", "and", "or", "not", "for", "lambda", "is"}  # 'in' is the inch
_UNIT_SHAPE = re.compile(r"\s*[A-Za-zµμ°(][A-Za-zµμ°\d\s*/^()·.²³+-]*")


class _UnitParser:
    """Recursive descent over the unit part; ``offset`` places it in ``text`` for columns."""

    def __init__(self, unit: str, text: str, offset: int):
        self.text = text
        toks = [(m.group(), offset + m.start()) for m in _TOKEN.finditer(unit.replace("μ", "µ"))]
        self.toks = [t for t in toks if not t[0].isspace()] + [("", len(text))]
        self.spaced = {pos + len(tok) for (tok, pos) in toks if tok.isspace()}  # after a space
        self.i = 0

    def error(self, msg: str, pos: int) -> ExpressionError:
        return ExpressionError(msg, self.text, pos + 1)

    def peek(self) -> str:
        return self.toks[self.i][0]

    def take(self) -> tuple[str, int]:
        self.i += 1
        return self.toks[self.i - 1]

    def parse(self) -> Unit:
        unit = self.product()
        if self.peek():
            raise self.error(f"unexpected '{self.peek()}' in unit", self.toks[self.i][1])
        return unit

    def product(self) -> Unit:
        unit = self.power()
        while self.peek() not in ("", ")"):
            tok, pos = self.toks[self.i]
            if tok in ("*", "·", "."):
                self.take()
                unit = unit * self.power()
            elif tok == "/":
                self.take()
                unit = unit / self.power()
                nxt, npos = self.toks[self.i]
                if nxt and (nxt.isalpha() or nxt in "(°") and npos in self.spaced:
                    hint = "write a/(b c) or a/b/c"
                    raise self.error(f"ambiguous space after a divisor; {hint}", npos)
            elif tok.isalpha() or tok in "(°":
                unit = unit * self.power()  # a space multiplies: 'N m'
            else:
                raise self.error(f"unexpected '{tok}' in unit", pos)
        return unit

    def power(self) -> Unit:
        tok, pos = self.take()
        if tok == "(":
            unit = self.product()
            if self.take()[0] != ")":
                raise self.error("unbalanced '(' in unit", pos)
        elif tok == "1":
            unit = Unit(1.0, DIMENSIONLESS)  # as in '1/s'
        elif tok.isalpha() or tok == "°":
            unit = lookup_unit(tok, self.text, pos + 1)
        else:
            raise self.error(f"expected a unit name, found '{tok or 'end of text'}'", pos)
        if self.peek() in _SUPERSCRIPT:
            return unit ** _SUPERSCRIPT[self.take()[0]]
        if self.peek() in ("^", "**"):
            self.take()
            sign = -1 if self.peek() == "-" else 1
            if self.peek() in "+-" and self.peek():
                self.take()
            exp, epos = self.take()
            if not exp.isdigit() or (self.peek() == "." and self.toks[self.i + 1][0].isdigit()):
                raise self.error(f"expected an integer exponent, found '{exp or 'end'}'", epos)
            unit = unit ** (sign * int(exp))
        return unit


def lookup_unit(name: str, text: str = "", column: int | None = None) -> Unit:
    """The :data:`UNITS` entry ``name``; an unknown name is an error with a suggestion."""
    if name in UNITS:
        return UNITS[name]
    same_case = [u for u in UNITS if u.lower() == name.lower()]
    close = same_case or difflib.get_close_matches(name, UNITS, n=1)
    hint = f"; did you mean '{close[0]}'?" if close else ""
    raise ExpressionError(f"unknown unit '{name}'{hint}", text, column)


def parse_unit(unit: str, text: str | None = None, offset: int = 0) -> Unit:
    """The :class:`Unit` of a unit expression such as ``'N*s/m'`` or ``'kg m^-1 s^-2'``."""
    return _UnitParser(unit, unit if text is None else text, offset).parse()


def _split(text: str) -> tuple[float, Unit | None]:
    if not isinstance(text, str):
        raise ExpressionError(f"expected a quantity such as '55 mph', got {type(text).__name__}")
    m = _NUMBER.match(text)
    if not m:
        raise ExpressionError("expected a number followed by a unit, e.g. '55 mph'", text, 1)
    value = float(m.group(1))
    if not math.isfinite(value):
        raise ExpressionError("number out of range", text, 1)
    rest = text[m.end() :]
    return value, (parse_unit(rest, text, m.end()) if rest.strip() else None)


def parse_quantity(text: str) -> tuple[float, str]:
    """Value in SI and dimension of a number with a unit.

    Parameters
    ----------
    text : str
        A plain number (no formula) and a unit: ``'55 mph'``, ``'-9.81 m/s^2'``, ``'1.5kN'``.
        A number alone is dimensionless.

    Returns
    -------
    value : float
        The quantity in SI units (kg, m, s, rad and their products).
    dimension : str
        A name from :data:`DIMENSIONS` (``'velocity'``, ``'pressure'``...) or, for unnamed
        dimensions, the canonical form ``'kg m^-1 s^-3'``.

    Raises
    ------
    ExpressionError
        Not a number, an unknown unit (with a did-you-mean suggestion) or a malformed unit.
    """
    value, unit = _split(text)
    if unit is None:
        return value, "dimensionless"
    return value * unit.scale, dimension_name(unit.dims)


def looks_like_quantity(text: object) -> bool:
    """True for a number followed by something shaped like a unit (``'55 mph'``, ``'30 deg'``),
    false for formulas (``'k*2'``, ``'2*pi'``) and for a number alone. Unknown units still look
    like quantities, so that :func:`parse_quantity` can name them."""
    m = _NUMBER.match(text) if isinstance(text, str) else None  # greedy: '2e-3*t' is 2e-3 *t
    if not m or not _UNIT_SHAPE.fullmatch(text, m.end()):
        return False
    return not any(w in _KEYWORDS for w in re.findall(r"[A-Za-z]+", text))


def to_si(text: str | float, expect: str | None = None) -> float:
    """The SI value of a quantity, checking its dimension.

    Parameters
    ----------
    text : str or float
        ``'12 in'``; a number without a unit (or a float) is taken as already SI.
    expect : str, optional
        A dimension name (``'length'``, ``'angular velocity'``, see :data:`DIMENSIONS`) or a
        unit expression of that dimension (``'m'``, ``'N*m/rad'``).

    Raises
    ------
    ExpressionError
        As :func:`parse_quantity`, or a dimension other than ``expect``:
        ``expected a length, got '5 s' (time)``.
    """
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        return float(text)
    value, unit = _split(text)
    if unit is None:
        return value
    if expect is not None:
        want = DIMENSIONS.get(expect) or _expected(expect)
        if unit.dims != want:
            name = expect if expect in DIMENSIONS else dimension_name(want)
            what = f"{'an' if name[0] in 'aeio' else 'a'} {name}" if name in DIMENSIONS else name
            got = dimension_name(unit.dims)
            raise ExpressionError(f"expected {what}, got '{text.strip()}' ({got})")
    return value * unit.scale


def _expected(expect: str) -> tuple[int, int, int, int]:
    try:
        return parse_unit(expect).dims
    except ExpressionError:
        raise ValueError(f"unknown dimension {expect!r}; use one of {list(DIMENSIONS)}") from None
