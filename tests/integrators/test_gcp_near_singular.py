"""Coordinate partitioning near a change point (gcp.py, module doc: tangent coordinates)
against the exact 1-DOF reduction of the four-crank parallel linkage
(tests/integrators/references.py: parallel_fourbar), at states close to the flat position
theta = 0, where Phi_q is within 1e-3..1e-5 of singular."""

import numpy as np
import pytest

from mbsim.analyses.common import rank_and_redundant
from mbsim.analyses.diagnosis import jacobian as _jac
from mbsim.analyses.trajectory import make_system
from mbsim.integrators import INTEGRATORS
from mbsim.integrators.gcp import Partition
from tests.integrators import models as M

P = M.FOURBAR
N = 4
MASS = N * (M.fourbar_crank_inertia()[2] + P["m_crank"] * P["L"] ** 2 / 4) + P["M"] * P["L"] ** 2
GRAV = P["g"] * (N * P["m_crank"] * P["L"] / 2 + P["M"] * P["L"])


def exact_state(model, th, thd):
    """q, qd, qdd of the linkage at crank angle th, rate thd (theta'' from the reduction)."""
    return M.parallel_fourbar_motion(model, th, thd, -GRAV * np.cos(th) / MASS)


# not named setup: pytest 7 calls a module-level setup(module) as a nose fixture
def prepared(theta_ref):
    """The four-bar's System on its independent rows and a gcp-rk45 integrator whose partition
    is the tangent one at theta_ref."""
    pb = M.reference_problem("parallel_fourbar")
    model = pb.model
    _, red = rank_and_redundant(model, _jac(model, pb.q0, 0.0))
    system = make_system(model, np.setdiff1d(np.arange(model.m), red))
    integ = INTEGRATORS["gcp-rk45"](system, 0.0, pb.q0.copy(), pb.qd0.copy(), 1.0,
                                    {"rtol": 1e-10, "atol": 1e-12})
    q, _, _ = exact_state(model, theta_ref, 20.0)
    J = system.terms(q, 0.0, phi=False).jac
    tangent = integ._tangent_partition(q, J, J, integ.part.iv, integ.part.iu)
    return model, system, integ, tangent


def stage(integ, part, q, qd, seed):
    """q, qd, qdd and the power of a stage (the integrator's right-hand side in ``part``) at
    (v, vd) of the exact state, Newton started 1e-9 off it."""
    integ._pred = q + 1e-9 * np.random.default_rng(seed).standard_normal(q.size)
    f = integ._rhs(0.0, np.concatenate([part.v(q), part.v(qd), [0.0]]), part)
    _, _, qq, qqd, qdd, _ = integ._last
    return qq, qqd, qdd, float(f[-1])


def test_tangent_coordinates_exact_away_from_singular():
    """At theta = 0.5 rad with the tangent partition of theta = 0.3 rad (rotated tangent),
    Newton, the velocity equations and the reduced equations reproduce the exact state and
    accelerations (to 1e-11 of |qdd|, measured 2e-14), and the power Q.qd is the rate of the
    reduction's kinetic energy."""
    model, _, integ, part = prepared(0.3)
    thd = 20.0
    q, qd, qdd_exact = exact_state(model, 0.5, thd)
    qq, qqd, qdd, power = stage(integ, part, q, qd, 0)
    assert np.abs(qq - q).max() < 1e-13
    assert np.abs(qqd - qd).max() < 1e-12 * thd
    assert np.abs(qdd - qdd_exact).max() <= 1e-11 * np.abs(qdd_exact).max()
    assert power == pytest.approx(MASS * thd * (-GRAV * np.cos(0.5) / MASS), rel=1e-10)


@pytest.mark.parametrize("delta", [1e-3, 1e-4])
def test_tangent_coordinates_near_flat_position(delta):
    """delta rad from the flat position (the partition 1e-2 rad before): the tangent
    coordinate's acceleration v'' keeps to 1e-6 of |v''| over 4 Newton starts (measured
    4e-11 and 4e-9), where the coordinate partition's v'' (a crank's Euler parameter, Schur
    complement) is off by more than 1e-6 (measured 1e-5 and 3e-2 relative: round-off in u
    amplified along the soft directions, and at 1e-4 the pivot floor)."""
    model, system, integ, part = prepared(-1e-2 + delta)
    q, qd, qdd_exact = exact_state(model, delta, 20.0)
    coords = Partition(integ.part.iv, integ.part.iu, 1.0)
    for p, ok in ((part, True), (coords, False)):
        a_exact = p.v(qdd_exact)
        worst = max(np.abs(p.v(stage(integ, p, q, qd, seed)[2]) - a_exact).max()
                    for seed in range(4))
        assert (worst <= 1e-6 * np.abs(a_exact).max()) == ok, (p.C is not None, worst)


def test_pivot_ratio_tracks_the_flat_position():
    """The trigger: the change-point measure falls in proportion to the angle from the flat
    position, as both families estimate it: the coordinate partition's Phi_u pivot ratio
    (gcp; 0.2 delta measured) and the square root of the Schur pivot ratio (index-1); below
    the policy's switch within 5e-3 rad, and a gcp partition there is the tangent one."""
    from mbsim.integrators import changepoints as cp

    model, system, integ, _ = prepared(0.5)
    ratios, schur = [], []
    for delta in (1e-1, 1e-2, 1e-3):
        q, qd, _ = exact_state(model, delta, 20.0)
        J = system.terms(q, 0.0, phi=False).jac
        ratios.append(integ._pivot_ratio(integ._factor(J, integ.part.iu)))
        system.accelerations(q, qd, 0.0)
        schur.append(cp.measure_from_schur(system.pivot_ratio))
    for s in (ratios, schur):
        assert s[1] == pytest.approx(s[0] / 10, rel=0.05), s
        assert s[2] == pytest.approx(s[0] / 100, rel=0.05), s
    assert ratios[2] < integ.policy.tangent < ratios[0]
    assert integ._partition(0.0, q).C is not None
