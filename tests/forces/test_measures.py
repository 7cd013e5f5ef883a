"""Measures by hand on a simple configuration, and velocity measures against central
differences of position measures along a smooth motion (step 1e-5: truncation ~ 1e-10,
round-off ~ 1e-16/1e-5 = 1e-11, bound 1e-7)."""

import numpy as np
import pytest

from mbsim.forces.measures import MEASURES
from mbsim.model import compile_model
from mbsim.rotations import from_axis_angle, omega_to_pd
from tests.forces.builders import measure
from tests.helpers import body, pts, spec
from tests.reference import equations as eq

FRAMES = {"g": pts([0, 0, 0], [0, 0, 1], [1, 0, 0]), "b": pts([0, 0, 0], [0, 0, 1], [1, 0, 0])}


def _model(p=(1, 0, 0, 0), r=(1, 0, 0)):
    return compile_model(spec([body("g", ground=True), body("b", 2.0, (1, 2, 3), r, p)]))


def _value(model, ms, q, qd, t=0.0):
    m = MEASURES[ms.type].from_spec(ms, {n: k for k, n in enumerate(model.body_names)})
    return m.value(eq.State(model, q, qd), t)


@pytest.fixture
def config():
    """Body b at r = (1, 0, 0), turned 90 deg about z (x' -> y, y' -> -x), moving with
    rd = (0, 0, 1) and omega = (0, 0, 2) (global)."""
    p = from_axis_angle([0, 0, 1], np.pi / 2)
    model = _model(p)
    q = model.q0
    qd = np.zeros(model.nq)
    qd[7:10] = [0, 0, 1]
    qd[10:14] = omega_to_pd(p, np.array([0, 0, 2.0]))
    return model, q, qd


HAND = [
    # s' = (1, 0, 0) on b is at (1, 1, 0): distance to the origin sqrt 2
    (measure("m", "distance", ("g", "b"), {"g": [0, 0, 0], "b": [1, 0, 0]}), np.sqrt(2)),
    # along the ground's y: 1
    (
        measure("m", "displacement", ("g", "b"), {"g": [0, 0, 0], "b": [1, 0, 0]}, axis=[0, 1, 0]),
        1.0,
    ),
    (
        measure("m", "displacement", ("b", "g"), {"b": [0, 0, 0], "g": [0, 0, 0]}, axis=[0, 1, 0]),
        1.0,
    ),  # u_b = A (0, 1, 0) = (-1, 0, 0); d = 0 - (1, 0, 0): u . d = 1
    # v_P = rd + w x (A s') = (0, 0, 1) + (0, 0, 2) x (0, 1, 0) = (-2, 0, 1)
    (measure("m", "velocity", ("b",), {"b": [1, 0, 0]}, axis=[1, 0, 0]), -2.0),
    (measure("m", "velocity", ("b",), {"b": [1, 0, 0]}, axis=[0, 0, 1]), 1.0),
    (measure("m", "velocity", ("b",), {"b": [1, 0, 0]}, axis=[0, 1, 0], frame="local"), 2.0),
    (measure("m", "angle", ("g", "b"), FRAMES, joint="REV"), np.pi / 2),
    (measure("m", "angle", ("g", "b"), FRAMES, joint="REV", theta0=3.0), np.pi / 2),
    (measure("m", "angle", ("g", "b"), FRAMES, joint="REV", theta0=-3.0), np.pi / 2 - 2 * np.pi),
    (measure("m", "angular_velocity", ("b",), axis=[0, 0, 1]), 2.0),
    (measure("m", "angular_velocity", ("b",), axis=[0, 0, 1], frame="local"), 2.0),
    (measure("m", "angular_velocity", ("b",), axis=[1, 0, 0], frame="local"), 0.0),
    (measure("m", "coordinate", ("b",), {"b": [1, 0, 0]}, axis=[0, 1, 0]), 1.0),
    (measure("m", "coordinate", ("b",), {"b": [1, 0, 0]}, axis=[1, 0, 0]), 1.0),
    (measure("m", "time"), 0.25),
]


@pytest.mark.parametrize(
    "ms, expected", HAND, ids=[f"{m.type}-{k}" for k, (m, _) in enumerate(HAND)]
)
def test_measure_by_hand(config, ms, expected):
    model, q, qd = config
    assert _value(model, ms, q, qd, t=0.25) == pytest.approx(expected, abs=1e-12)


def test_every_measure_type_has_a_hand_case():
    assert {m.type for m, _ in HAND} == set(MEASURES)


def _motion(model, s):
    """q(s) of body b: a smooth translation and a rotation about a turning axis."""
    q = model.q0.copy()
    q[7:10] = [1 + 0.3 * s, 0.2 * np.sin(2 * s), 0.1 * s * s]
    p = np.array([1.0, 0.2 * s, -0.4 * s * s, 0.7 * s + 0.1])
    q[10:14] = p / np.linalg.norm(p)
    return q


def _qd(model, s, h=1e-6):
    return (_motion(model, s + h) - _motion(model, s - h)) / (2 * h)


RATE_PAIRS = [
    # (position measure, its rate)
    (
        measure("x", "coordinate", ("b",), {"b": [0.3, -0.2, 0.5]}, axis=[0.2, 0.5, -1]),
        measure("v", "velocity", ("b",), {"b": [0.3, -0.2, 0.5]}, axis=[0.2, 0.5, -1]),
    ),
    (
        measure(
            "x",
            "displacement",
            ("g", "b"),
            {"g": [0.1, 0, 0], "b": [0.3, -0.2, 0.5]},
            axis=[0, 1, 1],
        ),
        measure("v", "velocity", ("b",), {"b": [0.3, -0.2, 0.5]}, axis=[0, 1, 1]),
    ),
]


@pytest.mark.parametrize("pos, rate", RATE_PAIRS, ids=["coordinate", "displacement"])
def test_velocity_is_the_derivative(pos, rate):
    model = _model()
    h = 1e-5
    for s in (0.0, 0.4, 1.1):
        qd = _qd(model, s)
        fd = (
            _value(model, pos, _motion(model, s + h), qd)
            - _value(model, pos, _motion(model, s - h), qd)
        ) / (2 * h)
        assert abs(_value(model, rate, _motion(model, s), qd) - fd) < 1e-7


def test_angular_velocity_is_the_rate_of_the_angle():
    """A rotation phi(s) = 0.3 + 2 s + s^2 about the joint axis z: angle' = omega_z = phi'."""
    model = _model()
    ang = measure("th", "angle", ("g", "b"), FRAMES, joint="REV", theta0=1.0)
    om = measure("w", "angular_velocity", ("b",), axis=[0, 0, 1])
    om_local = measure("w", "angular_velocity", ("b",), axis=[0, 0, 1], frame="local")

    def q_of(s):
        q = model.q0.copy()
        q[10:14] = from_axis_angle([0, 0, 1], 0.3 + 2 * s + s * s)
        return q

    h = 1e-5
    for s in (0.0, 0.2, 0.5):
        qd = (q_of(s + h) - q_of(s - h)) / (2 * h)
        fd = (_value(model, ang, q_of(s + h), qd) - _value(model, ang, q_of(s - h), qd)) / (2 * h)
        assert _value(model, ang, q_of(s), qd) == pytest.approx(0.3 + 2 * s + s * s)
        assert abs(_value(model, om, q_of(s), qd) - fd) < 1e-7
        assert abs(_value(model, om_local, q_of(s), qd) - (2 + 2 * s)) < 1e-7
