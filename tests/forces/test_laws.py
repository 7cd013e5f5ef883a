"""Expression laws with named measures: the governor's engine torque C (dl - 0.15), a load
step in t, a one-way piston pressure force where(v < 0, ...), and the name checks."""

import numpy as np
import pytest

from mbsim.deck.spec import FunctionSpec
from mbsim.errors import DeckError
from mbsim.expr import parse_expression
from mbsim.model import compile_model
from tests.forces.builders import force, measure
from tests.helpers import body, spec
from tests.reference import equations as eq

DL = measure(
    "dl",
    "displacement",
    ("spindle", "collar"),
    {"spindle": [0, 0, 0], "collar": [0, 0, 0]},
    axis=[0, 0, 1],
)


def _governor(collar_z, law, **extra):
    bodies = [
        body("spindle", 200, (25, 25, 0.5)),
        body("collar", 1, (0.01, 0.01, 0.02), r=(0, 0, collar_z)),
    ]
    f = force(
        "engine",
        "torque",
        ("spindle",),
        law=law,
        direction=[0, 0, 1],
        frame="local",
        measures={"dl": DL},
        **extra,
    )
    return compile_model(spec(bodies, forces=[f]))


@pytest.mark.parametrize("z", [0.15, 0.2, 0.1])
def test_governor_engine_torque(z):
    """T_s = C (dl - 0.15) about the spindle axis, C = 100 N m/m bound as a parameter."""
    law = parse_expression("C*(dl - 0.15)").bind({"C": 100.0})
    model = _governor(z, law)
    _, _, n_local = eq.applied_forces(model, model.q0, np.zeros(model.nq))
    np.testing.assert_allclose(n_local[0], [0, 0, 100 * (z - 0.15)], atol=1e-12)
    np.testing.assert_allclose(n_local[1], 0)


def test_load_step_in_time():
    """T_e = where(t > 0.5, -50, 0): a formula in t only."""
    model = _governor(0.2, parse_expression("where(t > 0.5, -50, 0)"))
    for t, expected in ((0.0, 0.0), (0.5, 0.0), (0.51, -50.0), (3.0, -50.0)):
        _, _, n_local = eq.applied_forces(model, model.q0, np.zeros(model.nq), t)
        assert n_local[0, 2] == expected


def test_time_function_law():
    law = FunctionSpec(
        "harmonic", {"amplitude": 2.0, "frequency": 3.0, "phase": 0.0, "offset": 1.0}
    )
    model = _governor(0.2, law)
    _, _, n_local = eq.applied_forces(model, model.q0, np.zeros(model.nq), 0.4)
    assert n_local[0, 2] == pytest.approx(2 * np.sin(1.2) + 1)


def test_one_way_piston_force():
    """Pressure force K/(x - xA) - Fmin on the piston, only while it moves toward A (v < 0)."""
    v = measure("v", "velocity", ("piston",), axis=[1, 0, 0])
    x = measure("x", "coordinate", ("piston",), axis=[1, 0, 0])
    law = parse_expression("where(v < 0, K/(x - xA) - Fmin, 0)").bind(
        {"K": 20.0, "xA": -0.1, "Fmin": 5.0}
    )
    f = force(
        "gas",
        "force",
        ("piston",),
        {"piston": [0, 0, 0]},
        law=law,
        direction=[1, 0, 0],
        measures={"v": v, "x": x},
    )
    model = compile_model(spec([body("piston", r=(0.1, 0, 0))], forces=[f]))
    qd = np.zeros(7)
    for speed, expected in ((-0.5, 20 / 0.2 - 5), (0.5, 0.0), (0.0, 0.0)):
        qd[0] = speed
        _, F, _ = eq.applied_forces(model, model.q0, qd)
        np.testing.assert_allclose(F[0], [expected, 0, 0])


def test_tsda_law_uses_its_own_variables():
    """law: a cubic spring in l with a damper in ldot; actuator from a measure."""
    bodies = [body("a", r=(0, 0, 0)), body("b", r=(2, 0, 0))]
    f = force(
        "S",
        "tsda",
        ("a", "b"),
        {"a": [0, 0, 0], "b": [0, 0, 0]},
        L0=1.0,
        law="3*(l - 1)**3 + 2*ldot",
        actuator="x_b",
        measures={"x_b": measure("x_b", "coordinate", ("b",), axis=[1, 0, 0])},
    )
    model = compile_model(spec(bodies, forces=[f]))
    qd = np.zeros(14)
    qd[7] = 0.5
    _, F, _ = eq.applied_forces(model, model.q0, qd)
    tension = 3 * 1 + 2 * 0.5 - 2.0
    np.testing.assert_allclose(F, [[tension, 0, 0], [-tension, 0, 0]])
    assert model.forces[0].potential(eq.State(model, model.q0)) == 0.0


def test_unknown_name_is_a_deck_error_with_a_suggestion():
    with pytest.raises(DeckError, match="unknown name 'dll'.*did you mean 'dl'"):
        _governor(0.2, parse_expression("100*(dll - 0.15)"))
    with pytest.raises(DeckError, match="taken by the tsda"):
        bodies = [body("a"), body("b", r=(1, 0, 0))]
        f = force("S", "tsda", ("a", "b"), L0=1.0, law="l", measures={"l": measure("l", "time")})
        compile_model(spec(bodies, forces=[f]))
    with pytest.raises(DeckError, match="unknown measure type"):
        bad = force(
            "F",
            "torque",
            ("a",),
            law="m",
            direction=[0, 0, 1],
            measures={"m": measure("m", "speed")},
        )
        compile_model(spec([body("a")], forces=[bad]))
