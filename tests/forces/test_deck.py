"""Force elements from deck text: every type and measure type through the loader (the syntax
docs/deck.md quotes), and deck errors that name the field."""

import numpy as np
import pytest

from mbsim.deck import load_deck_text
from mbsim.errors import DeckError
from mbsim.model import compile_model
from tests.reference import equations as eq

DECK = """
title: governor-style forces
parameters: {C: 100, K: 20, xA: -0.1, Fmin: 5}
bodies:
  ground: {ground: true}
  spindle: {mass: 200, inertia: [25, 25, 0.5]}
  collar: {mass: 1, inertia: [0.01, 0.01, 0.02], r: [0, 0, 0.2]}
  piston: {mass: 1, inertia: [1, 1, 1], r: [0.1, 0, 0], rdot: [-0.5, 0, 0]}
joints:
  SPIN:
    type: revolute
    bodies: [ground, spindle]
    points:
      ground: {P: [0, 0, 0], Q: [0, 0, 1], R: [1, 0, 0]}
      spindle: {P: [0, 0, 0], Q: [0, 0, 1], R: [1, 0, 0]}
forces:
  spring:
    type: tsda
    bodies: [spindle, collar]
    points: {spindle: [0, 0, 0], collar: [0, 0, 0]}
    k: 1000
    c: 30
    L0: 0.15
    actuator: '10*where(t > 1, 1, 0)'
  twist:
    type: rsda
    joint: SPIN
    k: 2.5
    theta0: '10 deg'
  engine:
    type: torque
    body: spindle
    law: 'C*(dl - 0.15)'
    direction: [0, 0, 1]
    frame: local
    measures:
      dl: {type: displacement, bodies: [spindle, collar],
           points: {spindle: [0, 0, 0], collar: [0, 0, 0]}, axis: z}
  load:
    type: torque
    bodies: [ground, spindle]
    law: [0, 0, 'where(t > 0.5, -50, 0)']
  gas:
    type: force
    body: piston
    law: 'where(v < 0, K/(x - xA) - Fmin, 0)'
    direction: [1, 0, 0]
    measures:
      v: {type: velocity, body: piston, axis: x}
      x: {type: coordinate, body: piston, axis: x}
      w: {type: angular_velocity, body: spindle, axis: [0, 0, 1], frame: local}
      th: {type: angle, joint: SPIN}
      d: {type: distance, bodies: [spindle, collar], points: {spindle: [0,0,0], collar: [0,0,0]}}
      tt: {type: time}
"""


def test_every_type_from_deck_text():
    model = compile_model(load_deck_text(DECK))
    assert [f.type for f in model.forces] == ["tsda", "rsda", "torque", "torque", "force"]
    q, qd = model.q0, np.zeros(model.nq)
    qd[7 * model.body_index("piston")] = -0.5
    _, F, n_local = eq.applied_forces(model, q, qd, 0.7)
    sp, co, pi = (model.body_index(n) for n in ("spindle", "collar", "piston"))
    # spring: l = 0.2, tension 1000 * 0.05 = 50 N pulls the collar down, the spindle up
    np.testing.assert_allclose(F[co], [0, 0, -50])
    np.testing.assert_allclose(F[sp], [0, 0, 50])
    # spindle torque about z: engine 100 * 0.05, load -50 (t > 0.5), twist -2.5 (0 - 10 deg)
    assert n_local[sp, 2] == pytest.approx(5 - 50 + 2.5 * np.radians(10))
    # gas: v < 0, K / (x - xA) - Fmin = 20 / 0.2 - 5
    np.testing.assert_allclose(F[pi], [95, 0, 0])
    _, F, _ = eq.applied_forces(model, q, qd, 1.5)  # the actuator pushes apart from t = 1
    np.testing.assert_allclose(F[co], [0, 0, -40])


@pytest.mark.parametrize(
    "edit, match",
    [
        (
            ("law: 'C*(dl - 0.15)'", "law: 'C*(dll - 0.15)'"),
            "unknown name 'dll'.*did you mean 'dl'",
        ),
        (("type: displacement", "type: displacment"), "measure type"),
        (("{type: time}", "{type: angle, joint: NOPE}"), "unknown joint 'NOPE'"),
        (("axis: z}", "axis: w}"), "axis"),
    ],
)
def test_deck_errors_name_the_field(edit, match):
    with pytest.raises(DeckError, match=match):
        compile_model(load_deck_text(DECK.replace(*edit)))
