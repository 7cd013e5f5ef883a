"""Assembly: convergence from estimates, redundant and conflicting constraints by name."""

import numpy as np
import pytest

from mbsim.analyses.assembly import assemble
from mbsim.analyses.kinematic import kinematic
from mbsim.errors import ConvergenceError, ModelError
from mbsim.expr import parse_expression
from mbsim.model import compile_model
from tests.helpers import body, driver, func, joint, pts, spec
from tests.reference import equations as eq

Z = ((0, 0, 0), (0, 0, 1), (1, 0, 0))  # P, Q (axis z), R


def planar_four_bar(with_driver=True):
    """Crank 1 m, coupler 3 m, rocker 2 m, ground 3 m, all revolutes about z: the classic
    redundant model (15 revolute equations + 6 ground + 4 norms on 28 coordinates leave
    rank 27: three equations repeat the planar conditions, and the DOF is 1, not 28-25-... )."""
    a = np.deg2rad(60.0)
    B = np.array([np.cos(a), np.sin(a), 0.0])
    D = np.array([3.0, 0.0, 0.0])
    # rocker end C at distance 3 from B and 2 from D (upper branch)
    d = np.linalg.norm(D - B)
    x = (d**2 + 9 - 4) / (2 * d)
    h = np.sqrt(9 - x**2)
    u = (D - B) / d
    C = B + x * u + h * np.array([-u[1], u[0], 0])
    bodies = [
        body("ground", ground=True),
        body("crank", 1, (0.1, 0.1, 0.1), B / 2),
        body("coupler", 1, (0.1, 0.1, 0.1), (B + C) / 2),
        body("rocker", 1, (0.1, 0.1, 0.1), (C + D) / 2),
    ]

    def rev(name, bi, bj, Pi, Pj):
        return joint(name, "revolute", bi, bj,
                     {bi: pts(Pi, np.add(Pi, (0, 0, 1)), np.add(Pi, (1, 0, 0))),
                      bj: pts(Pj, np.add(Pj, (0, 0, 1)), np.add(Pj, (1, 0, 0)))})

    joints = [
        rev("O", "ground", "crank", (0, 0, 0), -B / 2),
        rev("B", "crank", "coupler", B / 2, (B - C) / 2),
        rev("C", "coupler", "rocker", (C - B) / 2, (C - D) / 2),
        rev("D", "rocker", "ground", (D - C) / 2, D),
    ]
    drivers = []
    if with_driver:
        drivers = [driver("spin", "rotation", func("expression", expr=parse_expression("2*t")),
                          joint="O")]
    return spec(bodies, joints, drivers)


def test_redundant_constraints_are_named_and_removed():
    model = compile_model(planar_four_bar())
    asm = assemble(model)
    assert asm.residual < 1e-10
    assert asm.redundant_rows.size == 3 and asm.dof == 0
    assert any("redundant constraints removed" in w for w in asm.warnings)
    assert set(asm.redundant_items) <= {"O", "B", "C", "D"}
    # and the driven kinematics run on the independent rows
    res = kinematic(model, {"t_end": 0.5, "step": 0.05})
    assert res.complete, res.message
    assert np.abs(res.channel("bodies/crank/omega").data[:, 2] - 2.0).max() < 1e-9


def test_conflicting_constraints_are_an_error():
    """Two revolutes between the same bodies with crossed axes cannot both hold away from
    the estimate's alignment: reported by joint name, not as a raw Newton failure."""
    bodies = [body("ground", ground=True), body("a", 1, (1, 1, 1), (0, 0, 0))]
    joints = [
        joint("R1", "revolute", "ground", "a",
              {"ground": pts(*Z), "a": pts((0, 0, 0), (0, 0, 1), (1, 0, 0))}),
        joint("R2", "revolute", "ground", "a",
              {"ground": pts((0, 0, 0), (1, 0, 0), (0, 1, 0)),
               "a": pts((0, 0, 0), (0, 1, 0), (1, 0, 0))}),
    ]
    model = compile_model(spec(bodies, joints))
    with pytest.raises((ModelError, ConvergenceError)) as err:
        assemble(model)
    assert "R1" in str(err.value) or "R2" in str(err.value)


def test_failure_names_worst_constraints():
    """A distance that cannot be met (|P_j - P_i| = 5 with both points fixed 1 m apart)."""
    bodies = [body("ground", ground=True), body("a", 1, (1, 1, 1), (1, 0, 0))]
    joints = [
        joint("S", "spherical", "ground", "a", {"ground": pts((1, 0, 0)), "a": pts((0, 0, 0))}),
        joint("far", "distance", "ground", "a", {"ground": pts((0, 0, 0)), "a": pts((0, 0, 0))},
              distance=5.0),
    ]
    model = compile_model(spec(bodies, joints))
    with pytest.raises((ConvergenceError, ModelError)) as err:
        assemble(model)
    assert "far" in str(err.value)


def test_assembly_keeps_euler_parameters_unit():
    model = compile_model(planar_four_bar())
    q = model.q0.copy()
    q[10] = 1.3  # crank e0 far off: the estimate is renormalised, the solution has |p| = 1
    asm = assemble(model, q)
    p = asm.q.reshape(model.nb, 7)[:, 3:]
    assert np.allclose(np.linalg.norm(p, axis=1), 1.0, atol=1e-12)
    assert np.abs(eq.phi(model, asm.q)).max() < 1e-10
