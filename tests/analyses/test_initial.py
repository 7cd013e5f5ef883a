"""Initial conditions: velocities from the given data and the constraints, minimum kinetic
energy for what is left free, a warning for conflicting data, consistent qdd and lam.

Reference: spatial slider-crank with the crank turning at omega = (-2 pi, 0, 0) rad/s:
slider xdot = -0.25133 m/s, rod rdot = (-0.12566, 0.25133, 0) m/s; with omega = (6, 0, 0),
rod omega = (1.92, -0.96, 0.48) rad/s (shared/reference/geometry.md, Sec. 1.2).
"""

import numpy as np
import pytest

from mbsim.analyses.initial import initial_state
from mbsim.model import compile_model
from mbsim.rotations import E as rot_E
from tests.analyses.test_kinematic_slider_crank import closed_form
from tests.helpers import body, joint, pts, slider_crank_spec, spec
from tests.reference import equations as eq

W = -2 * np.pi


def _slider_crank(**given):
    s = slider_crank_spec(0.3)
    s.drivers = {}
    s.bodies["crank"].omega = np.array([W, 0.0, 0.0])
    for name, (key, value) in given.items():
        setattr(s.bodies[name], key, np.asarray(value, float))
    return compile_model(s)


def _omega(model, q, qd, b):
    Q, V = q.reshape(model.nb, 7), qd.reshape(model.nb, 7)
    return 2 * rot_E(Q[b, 3:]) @ V[b, 3:]


def _crank_time(model, q):
    """The t of closed_form whose crank angle pi/2 + W t is the assembled one (the deck's
    crank orientation is rounded to 5 digits and, undriven, stays where assembly puts it)."""
    y_arm = eq.State(model, q).A[model.body_index("crank")][:, 1]
    return (np.arctan2(y_arm[2], y_arm[1]) - np.pi / 2) / W


def _check_consistent(model, q, qd, qdd, lam, t=0.0):
    T = eq.constraints(model, q, t, qd=qd, nu=True, gamma=True)
    assert np.abs(T.phi).max() < 1e-10
    assert np.abs(T.jac @ qd - T.nu).max() < 1e-10
    assert np.abs(T.jac @ qdd - T.gamma).max() < 1e-8 * max(1, np.abs(T.gamma).max())
    M = eq.mass_matrix(model, q)
    Q = eq.applied_forces(model, q, qd, t)[0]
    assert np.abs(M @ qdd + T.jac.T @ lam - Q).max() < 1e-8 * max(1, np.abs(Q).max())


def test_slider_crank_velocities_from_the_crank_speed():
    model = _slider_crank()
    q, qd, qdd, lam, info = initial_state(model)
    V = qd.reshape(model.nb, 7)
    sl, rod, crank = (model.body_index(n) for n in ("slider", "rod", "crank"))
    _, xd, _ = closed_form(_crank_time(model, q), 0.3)
    assert V[sl, 0] == pytest.approx(xd, abs=1e-10)  # exact closed form, -0.25133
    assert V[sl, 0] == pytest.approx(-0.25133, abs=1e-5)  # reference, 5 digits
    np.testing.assert_allclose(V[rod, :3], [-0.12566, 0.25133, 0], atol=1e-5)
    # reference (1.92, -0.96, 0.48) is for the IFToMM crank speed +6 rad/s; linear in it
    np.testing.assert_allclose(
        _omega(model, q, qd, rod), np.array([1.92, -0.96, 0.48]) * W / 6, atol=1e-5
    )
    np.testing.assert_allclose(_omega(model, q, qd, crank), [W, 0, 0], atol=1e-12)
    assert info["warnings"] == [] and info["free_velocity_dof"] == 0 and info["given"] == 3
    _check_consistent(model, q, qd, qdd, lam)


def test_consistent_extra_data_is_no_conflict():
    """The exact slider speed given as well: overdetermined but consistent."""
    q = initial_state(_slider_crank())[0]
    _, xd, _ = closed_form(_crank_time(_slider_crank(), q), 0.3)
    model = _slider_crank(slider=("rdot", [xd, 0, 0]))
    q, _qd, *_, info = initial_state(model)
    assert info["warnings"] == [] and info["given"] == 6


def test_conflicting_data_is_a_warning_naming_the_bodies():
    """A sideways slider speed is impossible in its translational joint; a slider xdot of
    -0.4 contradicts the crank speed: least squares, then a warning with the changes."""
    model = _slider_crank(slider=("rdot", [-0.4, 0.1, 0]))
    q, qd, qdd, lam, info = initial_state(model)
    (msg,) = info["warnings"]
    assert "slider rdot" in msg and "crank omega" in msg
    ch = info["changed"]
    assert ch["slider"]["rdot"][1] == pytest.approx(-0.1)  # the impossible part goes
    V = qd.reshape(model.nb, 7)[model.body_index("slider")]
    assert ch["slider"]["rdot"][0] == pytest.approx(V[0] + 0.4)
    assert -0.4 < V[0] < -0.25133  # a compromise between the two data
    _check_consistent(model, q, qd, qdd, lam)


def test_free_body_with_nothing_given_is_at_rest():
    model = compile_model(
        spec([body("a", 2.0, (1, 2, 3), (1, 2, 3), (0.9, 0.1, -0.2, 0.3))], gravity=(0, 0, -9.81))
    )
    _q, qd, qdd, _lam, info = initial_state(model)
    np.testing.assert_array_equal(qd, 0)
    np.testing.assert_allclose(qdd[:3], [0, 0, -9.81])
    assert info["free_velocity_dof"] == 6 and info["warnings"] == []


def test_free_body_keeps_its_given_velocity():
    model = compile_model(
        spec(
            [
                body(
                    "a",
                    2.0,
                    (1, 2, 3),
                    p=(0.9, 0.1, -0.2, 0.3),
                    rdot=(1, 2, 3),
                    omega_local=(0.5, -1, 2),
                )
            ]
        )
    )
    q, qd, *_, info = initial_state(model)
    np.testing.assert_allclose(qd[:3], [1, 2, 3])
    from mbsim.rotations import G as rot_G

    np.testing.assert_allclose(2 * rot_G(q[3:]) @ qd[3:], [0.5, -1, 2], atol=1e-12)
    assert info["free_velocity_dof"] == 0


def test_redundant_joint_rows_are_dropped():
    """A pendulum held by two identical revolutes: same motion as with one, redundant rows
    carry no multiplier."""
    P = {"g": pts((0, 0, 0), (1, 0, 0), (0, 1, 0)), "a": pts((0, 0, 0.5), (1, 0, 0.5))}
    bodies = [
        body("g", ground=True),
        body("a", 1.0, (0.1, 0.1, 0.01), (0, 0.3, -0.4), omega=(3.0, 0, 0)),
    ]
    one = compile_model(spec(bodies, [joint("R1", "revolute", "g", "a", P)], gravity=(0, 0, -9.81)))
    two = compile_model(
        spec(
            bodies,
            [joint("R1", "revolute", "g", "a", P), joint("R2", "revolute", "g", "a", P)],
            gravity=(0, 0, -9.81),
        )
    )
    _q1, qd1, qdd1, _lam1, _ = initial_state(one)
    _q2, qd2, qdd2, lam2, info = initial_state(two)
    assert any("redundant" in w for w in info["warnings"])
    np.testing.assert_allclose(qd2, qd1, atol=1e-10)
    np.testing.assert_allclose(qdd2, qdd1, atol=1e-8)
    red = info["assembly"].redundant_rows
    assert red.size == 5 and np.all(lam2[red] == 0)
