"""Joint reactions from multipliers (Haug Sec. 11.6) against hand statics and Newton-Euler."""

import numpy as np
import pytest

from mbsim.analyses.inverse import inverse
from mbsim.analyses.reactions import reactions
from mbsim.model import compile_model
from mbsim.rotations import A as rot_A
from mbsim.rotations import G as rot_G
from tests.helpers import body, driver, func, joint, pts, spec
from tests.reference import equations as eq

# Horizontal beam: length 2 along x, mass 3, hinge (revolute, axis y) at the origin, its tip
# (2, 0, 0) held by a link to the ground point (0, 0, 1.5): link length 2.5, direction from the
# tip to the anchor u = (-0.8, 0, 0.6).  Gravity -z.
MB, GR = 3.0, 9.81
T_LINK = MB * GR * 1.0 / (2.0 * 0.6)  # moments about the hinge: T 0.6 x 2 = m g x 1
U = np.array([-0.8, 0.0, 0.6])


def beam_spec(held_by="driver"):
    bodies = [body("beam", MB, (0.01, 1.0, 1.0), (1, 0, 0)), body("ground", ground=True)]
    joints = [joint("hinge", "revolute", "ground", "beam",
                    {"ground": pts((0, 0, 0), (0, 1, 0), (1, 0, 0)),
                     "beam": pts((-1, 0, 0), (-1, 1, 0), (0, 0, 0))})]
    drivers = []
    link_pts = {"ground": pts((0, 0, 1.5)), "beam": pts((1, 0, 0))}
    if held_by == "driver":
        drivers = [driver("link", "distance", func("constant", value=2.5),
                          bodies=("ground", "beam"), points=link_pts)]
    else:
        joints.append(joint("link", "distance", "ground", "beam", link_pts, distance=2.5))
    return spec(bodies, joints, drivers, gravity=(0, 0, -GR))


@pytest.mark.parametrize("held_by", ["driver", "joint"])
def test_beam_on_hinge_and_link_matches_hand_statics(held_by):
    """Hand statics: link tension T = m g / 1.2 = 24.525 N; hinge force on the beam
    F_h = -(m g + T u) = (0.8 T, 0, m g - 0.6 T) = (19.62, 0, 14.715) N; no hinge torque.
    Both are exact numbers, so only round-off remains: 1e-10 relative."""
    model = compile_model(beam_spec(held_by))
    res = inverse(model, {"t_end": 0.02, "step": 0.01})
    assert res.complete, res.message
    Fh = np.array([0.8 * T_LINK, 0.0, MB * GR - 0.6 * T_LINK])
    tol = 1e-10 * MB * GR
    assert np.abs(res.channel("joints/hinge/force_j").data - Fh).max() < tol
    assert np.abs(res.channel("joints/hinge/force_i").data + Fh).max() < tol
    assert np.abs(res.channel("joints/hinge/torque_j").data).max() < tol
    # joint frames: hinge on ground f = y, g = x, h = -z; on the beam the same directions
    np.testing.assert_allclose(res.channel("joints/hinge/force_i_local").data[0],
                               [0.0, -Fh[0], Fh[2]], atol=tol)
    np.testing.assert_allclose(res.channel("joints/hinge/force_j_local").data[0],
                               [0.0, Fh[0], -Fh[2]], atol=tol)
    if held_by == "driver":
        # effort along P_j - P_i (anchor -> tip): the link pulls, so it reads -T
        np.testing.assert_allclose(res.channel("drivers/link/force").data, -T_LINK, rtol=1e-12)
    else:
        np.testing.assert_allclose(res.channel("joints/link/force_j").data[0], T_LINK * U,
                                   atol=tol)


def test_reactions_after_a_dynamic_step_satisfy_newton_euler():
    """A 3D pendulum (products of inertia, pivot off the centroid's plane) swinging at 2 rad/s:
    lam from the KKT solve (equations.accelerations), the revolute's load on the arm must
    equal m (rdd - g) and, about the pivot, J omegad + omega x J omega - (P - r) x F."""
    J = np.array([[0.3, 0.02, 0.01], [0.02, 0.1, 0.03], [0.01, 0.03, 0.3]])
    th, w = 0.7, 2.0
    p = np.array([np.cos(th / 2), np.sin(th / 2), 0.0, 0.0])
    s_P = np.array([0.1, 0.0, 0.5])  # pivot in arm coordinates
    A = rot_A(p)
    r = -A @ s_P  # the pivot stays at the origin
    arm = body("arm", 2.0, (1, 1, 1), r, p)
    arm.inertia = J  # the helper reads 3 numbers as a diagonal
    bodies = [arm, body("ground", ground=True)]
    joints = [joint("pivot", "revolute", "ground", "arm",
                    {"ground": pts((0, 0, 0), (1, 0, 0), (0, 1, 0)),
                     "arm": pts(s_P, s_P + [1, 0, 0], s_P + [0, 1, 0])})]
    model = compile_model(spec(bodies, joints, gravity=(0, 0, -9.81)))
    q = model.q0.copy()
    qd = np.zeros(model.nq)
    Om = np.array([w, 0.0, 0.0])
    qd[0:3] = np.cross(Om, r)
    qd[3:7] = 0.5 * rot_G(p).T @ (A.T @ Om)
    assert np.abs(eq.constraints(model, q, nu=True).jac @ qd).max() < 1e-14
    qdd, lam = eq.accelerations(model, q, qd)
    (rx,) = [x for x in reactions(model, q, lam) if x.item == "pivot" and x.side == "j"]
    F = 2.0 * (qdd[:3] - model.gravity)
    wl = A.T @ Om
    wdl = 2 * rot_G(p) @ qdd[3:7]
    n_c = A @ (J @ wdl + np.cross(wl, J @ wl))
    n_P = n_c - np.cross(A @ s_P, F)
    np.testing.assert_allclose(rx.force[0], F, atol=1e-12 * np.abs(F).max())
    np.testing.assert_allclose(rx.torque[0], n_P, atol=1e-12 * np.abs(F).max())
    assert np.linalg.norm(n_P) > 0.1  # torques perpendicular to the axis are exercised
    assert abs(rx.torque_local[0, 0]) < 1e-12  # none about the revolute axis f
