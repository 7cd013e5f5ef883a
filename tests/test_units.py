"""Tests of mbsim.units: every unit engineers write in decks against hand-computed SI values
(exact definitions from NIST SP 811), dimension checks and the error messages."""

from __future__ import annotations

import math

import pytest

from mbsim.errors import ExpressionError
from mbsim.units import (
    DIMENSIONS,
    UNITS,
    dimension_name,
    looks_like_quantity,
    parse_quantity,
    parse_unit,
    to_si,
)

PI = math.pi

# (text, SI value computed by hand, dimension)
QUANTITIES = [
    ("55 mph", 24.5872, "velocity"),  # 55 * 0.44704
    ("500 psi", 3447378.646584, "pressure"),  # 500 * 6894.757293168
    ("30 deg", PI / 6, "angle"),
    ("600 rpm", 62.83185307179586, "angular velocity"),  # 600 * 2 pi / 60 = 20 pi
    ("12 in", 0.3048, "length"),  # 12 * 0.0254 = 1 ft
    ("1.5 kN", 1500.0, "force"),
    ("9.81 m/s^2", 9.81, "acceleration"),
    ("9.81 m/s**2", 9.81, "acceleration"),
    ("3 N*m", 3.0, "torque"),
    ("2 N m", 2.0, "torque"),
    ("2 Nm", 2.0, "torque"),
    ("10 mm", 0.01, "length"),
    ("1 lbf", 4.4482216152605, "force"),
    ("1 lb", 0.45359237, "mass"),
    ("2 bar", 2e5, "pressure"),
    ("1 kPa", 1e3, "pressure"),
    ("1 MPa", 1e6, "pressure"),
    ("1 g", 1e-3, "mass"),
    ("1 km/h", 1 / 3.6, "velocity"),
    ("1 ft", 0.3048, "length"),
    ("1 rad", 1.0, "angle"),
    ("1 rad/s", 1.0, "angular velocity"),
    ("1 deg/s", PI / 180, "angular velocity"),
    ("1 Hz", 1.0, "frequency"),  # 1/s, NOT 2 pi rad/s
    ("1 s", 1.0, "time"),
    ("1 ms", 1e-3, "time"),
    ("1 min", 60.0, "time"),
    ("1 h", 3600.0, "time"),
    ("1 kg", 1.0, "mass"),
    ("1 kg*m^2", 1.0, "inertia"),
    ("1 N/m", 1.0, "stiffness"),
    ("1 N*s/m", 1.0, "damping"),
    ("1 lbf/in", 175.12683524647636, "stiffness"),  # 4.4482216152605 / 0.0254
    ("1 N*m/rad", 1.0, "rotational stiffness"),
    ("1 N*m*s/rad", 1.0, "rotational damping"),
    ("1 lbf*in", 0.1129848290276167, "torque"),  # 4.4482216152605 * 0.0254
    ("1 psi", 4.4482216152605 / 0.0254**2, "pressure"),  # lbf/in^2; psi's 13 digits: 5e-14
    ("1 ft/s^2", 0.3048, "acceleration"),
    ("1 kg/(m*s^2)", 1.0, "pressure"),
    ("1 kg/m/s^2", 1.0, "pressure"),
    ("1 kg m^-1 s^-2", 1.0, "pressure"),
    ("2 m²", 2.0, "area"),
    ("1 cm^3", 1e-6, "volume"),
    ("1 N·m", 1.0, "torque"),
    ("1 N.m", 1.0, "torque"),
    ("30°", PI / 6, "angle"),
    ("3 µm", 3e-6, "length"),
    ("3 μm", 3e-6, "length"),  # Greek mu, as typed on some keyboards
    ("1 1/s", 1.0, "frequency"),
    ("1.5kN", 1500.0, "force"),
    ("-9.81 m/s^2", -9.81, "acceleration"),
    ("+2.5e3 mm", 2.5, "length"),
    (".5 h", 1800.0, "time"),
    ("  7 GPa  ", 7e9, "pressure"),
    ("1 W", 1.0, "power"),
    ("1 kg/m^3", 1.0, "density"),
    ("1 W/m^2", 1.0, "kg s^-3"),  # no name: canonical form
    ("5", 5.0, "dimensionless"),
]


@pytest.mark.parametrize("text, value, dim", QUANTITIES, ids=[q[0] for q in QUANTITIES])
def test_units_convert_to_si(text, value, dim):
    got, got_dim = parse_quantity(text)
    assert got == pytest.approx(value, rel=1e-13)  # a few products of exact factors: ~1e-16
    assert got_dim == dim
    if dim in DIMENSIONS:
        assert to_si(text, expect=dim) == got


def test_exact_definitions():
    assert parse_quantity("1 mph")[0] == 0.44704
    assert parse_quantity("1 psi")[0] == 6894.757293168
    assert parse_quantity("1 in")[0] == 0.0254
    assert parse_quantity("1 lbf")[0] == 4.4482216152605
    assert parse_quantity("1 lb")[0] == 0.45359237
    assert parse_quantity("1 ft")[0] == 0.3048
    assert parse_quantity("600 rpm")[0] == pytest.approx(20 * PI, rel=1e-15)


def test_expect_accepts_names_and_unit_expressions():
    assert to_si("12 in", "length") == pytest.approx(0.3048)
    assert to_si("12 in", "m") == pytest.approx(0.3048)
    assert to_si("1 lbf/in", "N/m") == pytest.approx(175.12683524647636)
    assert to_si("1 J", "energy") == 1.0 and to_si("1 N*m", "torque") == 1.0
    # a bare number (or a float) is already SI, whatever is expected
    assert to_si("4", "length") == 4.0 and to_si(2.5, "pressure") == 2.5 and to_si(3) == 3.0
    with pytest.raises(ValueError, match="unknown dimension"):
        to_si("1 m", expect="lenght")


MISMATCHES = [
    ("5 s", "length", "expected a length, got '5 s' (time)"),
    ("10 Hz", "angular velocity", "expected an angular velocity, got '10 Hz' (frequency)"),
    ("600 rpm", "frequency", "expected a frequency, got '600 rpm' (angular velocity)"),
    ("100 N*m", "rotational stiffness",
     "expected a rotational stiffness, got '100 N*m' (torque)"),
    ("2 m", "N/m", "expected a stiffness, got '2 m' (length)"),
    ("1 W/m^2", "pressure", "expected a pressure, got '1 W/m^2' (kg s^-3)"),
    ("1 kg", "kg s^-3", "expected kg s^-3, got '1 kg' (mass)"),
    ("1 lb", "force", "expected a force, got '1 lb' (mass)"),
]  # fmt: skip


@pytest.mark.parametrize("text, expect, message", MISMATCHES)
def test_dimension_mismatch_is_an_error(text, expect, message):
    with pytest.raises(ExpressionError) as info:
        to_si(text, expect)
    assert str(info.value) == message


BAD = [
    ("55 mhp", "unknown unit 'mhp'; did you mean 'mph'?", 4),
    ("1 KN", "unknown unit 'KN'; did you mean 'kN'?", 3),
    ("1 mpa", "unknown unit 'mpa'; did you mean 'MPa'?", 3),
    ("3 furlongs", "unknown unit 'furlongs'", 3),
    ("1 kg/m s^2", "ambiguous space after a divisor", 8),
    ("1 m^x", "expected an integer exponent, found 'x'", 5),
    ("1 m^", "expected an integer exponent, found 'end'", 5),
    ("1 m^1.5", "expected an integer exponent, found '1'", 5),
    ("1 (m", "unbalanced '('", 3),
    ("1 m)", "unexpected ')'", 4),
    ("1 N/", "expected a unit name, found 'end of text'", 5),
    ("1 N-m", "unexpected '-'", 4),
    ("2*pi rad", "expected a unit name, found '*'", 2),
    ("mph", "expected a number followed by a unit", 1),
    ("k*2", "expected a number followed by a unit", 1),
    ("1e999 m", "number out of range", 1),
    ("1 m#", "unexpected '#'", 4),
]


@pytest.mark.parametrize("text, message, column", BAD, ids=[b[0] for b in BAD])
def test_bad_quantities_name_the_problem(text, message, column):
    with pytest.raises(ExpressionError) as info:
        parse_quantity(text)
    assert message in str(info.value)
    assert info.value.column == column and info.value.text == text


def test_non_text_is_rejected():
    with pytest.raises(ExpressionError, match="expected a quantity"):
        parse_quantity(5)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "text, expected",
    [("55 mph", True), ("30 deg", True), ("30°", True), ("1.5kN", True), ("-9.81 m/s^2", True),
     ("12 in", True), ("2e-3 m", True), ("3 furlongs", True),  # unknown unit: still a quantity
     ("k*2", False), ("2*pi", False), ("2e-3*t", False), ("1/s", False), ("5", False),
     ("1 - t", False), ("3 if t > 1 else 0", False), ("3 if flag else 0", False),
     ("sin(t)", False), ("", False), (5.0, False), (None, False)],
)  # fmt: skip
def test_looks_like_quantity(text, expected):
    assert looks_like_quantity(text) is expected


def test_registry_and_unit_algebra():
    assert UNITS["kN"].scale == 1e3 and UNITS["kN"].dims == UNITS["N"].dims
    assert all(u.doc for u in UNITS.values())
    assert parse_unit("N*s/m") == parse_unit("kg/s")
    assert parse_unit("(m/s)^2").dims == (0, 2, -2, 0)
    assert dimension_name((0, 1, -1, 0)) == "velocity" and dimension_name((2, 0, 1, -1)) == (
        "kg^2 s rad^-1"
    )
