"""The change-point policy (mbsim/integrators/changepoints.py, Policy and Approach): each
threshold against the derivation its docstring gives, the policy's direction in rtol, the two
numbers it takes from elsewhere against their sources, no change-point threshold outside the
module, and the approach's bookkeeping on a measure s(t) known in closed form."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
import pytest

from mbsim.integrators import base
from mbsim.integrators import changepoints as cp
from mbsim.integrators.rk import ClassicRK4, Dop853, DormandPrince54

ROOT = Path(__file__).resolve().parents[2]
EPS = np.finfo(float).eps
RTOLS = (1e-4, 1e-6, 1e-8, 1e-10, 1e-12)
# the error exponents -1/k of the adaptive pairs: DOP853 (k = 8), Dormand-Prince 5(4) (k = 5)
EXPONENTS = (-1.0 / (Dop853.error_order + 1), -1.0 / (DormandPrince54.error_order + 1))
REL = 1e-12  # relative tolerance of a closed-form law evaluated in floating point


def policy(family, rtol, exponent=EXPONENTS[0], fixed=False, n=28):
    return cp.Policy.for_run(family, rtol, rtol / 100, fixed, exponent=exponent, n=n)


@pytest.mark.parametrize("exponent", EXPONENTS)
@pytest.mark.parametrize("rtol", RTOLS)
def test_switch_is_where_the_family_round_off_reaches_rtol(rtol, exponent):
    """gcp: three solves leave eps s^-3, equal to rtol at the switch; index-1: the measured
    law max(floor, (eps / rtol)^(2/3)), the floor the kernels' Schur pivot floor (sqrt of it
    in s); the derived lower limit index1_law (eps s^-2 moving a step's qd by one tolerance
    at steps ~ rtol^(1/k)) is that limit's, not the switch's (Policy doc)."""
    k = -1.0 / exponent
    g, i = policy("gcp", rtol, exponent), policy("index-1", rtol, exponent)
    assert EPS * g.tangent ** -3 == pytest.approx(rtol, rel=REL)
    floor = np.sqrt(cp.SCHUR_PIVOT_FLOOR)
    assert i.tangent == pytest.approx(max(floor, (EPS / rtol) ** (2 / 3)), rel=REL)
    low = cp.Policy.index1_law(rtol, k)
    if low > floor:
        assert EPS * low ** -2 * rtol ** (1 / k - 1) == pytest.approx(1.0, rel=REL)
    else:
        assert EPS * floor ** -2 * rtol ** (1 / k - 1) <= 1.0


@pytest.mark.parametrize("exponent", EXPONENTS)
@pytest.mark.parametrize("rtol", RTOLS)
def test_round_off_thresholds_follow_their_derivations(rtol, exponent):
    """noise_s: eps s^-3 = 1 (round-off as large as the accelerations); noise_err: the error
    norm at which the controller's next step equals this one (SAFETY err^(-1/k) = 1); cut:
    a step cut by it has the truncation error eps / rtol of a step that had norm 1
    (cut^k = eps / rtol); branch_jump: sqrt(tangent / rtol), as many tolerances from the
    prediction's error (1) as from the other branch (tangent / rtol)."""
    k = -1.0 / exponent
    for family in ("gcp", "index-1"):
        p = policy(family, rtol, exponent)
        assert EPS * p.noise_s ** -3 == pytest.approx(1.0, rel=REL)
        assert base.SAFETY * p.noise_err ** (-1.0 / k) == pytest.approx(1.0, rel=REL)
        assert p.cut ** k == pytest.approx(EPS / rtol, rel=REL)
        if p.tangent <= rtol:  # the branches within a tolerance: no check
            assert p.branch_jump == np.inf
            continue
        assert p.branch_jump / 1.0 == pytest.approx((p.tangent / rtol) / p.branch_jump,
                                                    rel=REL)
        assert 1.0 < p.branch_jump < p.tangent / rtol


def test_a_start_below_the_switch_takes_the_region_below_it():
    """index-1 with fixed steps (switch 6.1e-4, above the kernels' floor) on a model whose
    measure at the start, s0, is below it: the switch moves to sqrt(floor s0) (below s0,
    above the floor), with branch_jump recomputed; a start at or below the floor takes no
    tangent coordinates; a start above the switch keeps the policy."""
    floor = np.sqrt(cp.SCHUR_PIVOT_FLOOR)
    p = policy("index-1", 1e-12, exponent=0.0, fixed=True)
    s0 = 0.5 * p.tangent
    q = p.at_start(s0, 1e-12)
    assert q.tangent == pytest.approx(np.sqrt(floor * s0), rel=REL)
    assert floor < q.tangent < s0
    assert q.branch_jump == pytest.approx(np.sqrt(q.tangent / 1e-12), rel=REL)
    assert p.at_start(0.5 * floor, 1e-12).tangent == 0.0
    assert p.at_start(2 * p.tangent, 1e-12) == p


def test_newton_and_rank_thresholds_follow_eps():
    """newton_iter: twice the quadratic-convergence count from one correct digit to the
    digits of a double; rank_lost: n eps (the factor's backward error)."""
    p = policy("gcp", 1e-8, n=41)
    digits = -np.log10(EPS)
    assert 2 ** (p.newton_iter // 2) >= digits > 2 ** (p.newton_iter // 2 - 1)
    assert p.rank_lost == pytest.approx(41 * EPS, rel=REL)


@pytest.mark.parametrize("family", ["gcp", "index-1"])
@pytest.mark.parametrize("rtol", RTOLS)
def test_newton_tolerances_follow_atol(family, rtol):
    """newton_tol: a hundredth of atol (Hairer & Wanner IV.8's kappa), at least the measured
    floor 1e-12 m (fixed steps: the floor alone); kept_residual: 1e2 newton_tol, one atol;
    the index-1 projection keeps a stalled projection within one atol in [1e-11, 1e-7] for
    its default tolerance 1e-3 atol in [1e-14, 1e-10]."""
    fixed = cp.Policy.for_run(family, rtol, 1.0, True, exponent=EXPONENTS[0], n=28)
    assert fixed.newton_tol == cp.NEWTON_FLOOR == 1e-12
    for atol in (1e-2 * rtol, rtol):
        p = cp.Policy.for_run(family, rtol, atol, False, exponent=EXPONENTS[0], n=28)
        assert p.newton_tol == pytest.approx(max(1e-2 * atol, 1e-12), rel=REL)
        assert p.kept_residual == pytest.approx(1e2 * p.newton_tol, rel=REL)
        proj_tol = min(1e-10, max(1e-14, 1e-3 * atol))
        assert cp.Policy.projection_kept(proj_tol) == pytest.approx(
            min(1e-7, max(1e-11, atol)), rel=REL)


@pytest.mark.parametrize("family", ["gcp", "index-1"])
def test_policy_is_monotone_in_rtol(family):
    """A tighter tolerance never shrinks the tangent region, the cut or the branch-jump
    threshold, and leaves the rtol-free thresholds alone."""
    for exponent in EXPONENTS:
        ps = [policy(family, r, exponent) for r in RTOLS]  # loosest first
        for a, b in zip(ps, ps[1:]):
            assert b.tangent >= a.tangent
            assert b.cut >= a.cut
            assert b.branch_jump >= a.branch_jump or a.branch_jump == np.inf
            assert (b.noise_s, b.noise_err, b.newton_iter) == (a.noise_s, a.noise_err,
                                                               a.newton_iter)
            assert b.newton_tol <= a.newton_tol
        assert all(0.0 < p.cut < 1.0 and 0.0 < p.noise_err < 1.0 for p in ps)


@pytest.mark.parametrize("family", ["gcp", "index-1"])
def test_fixed_steps_take_the_policy_of_a_run_that_asks_no_accuracy(family):
    """No error test: the switch where the tangent coordinates' own round-off meets the
    default rtol, whatever rtol says; no cut, no probe, the Newton stop at its floor;
    ``tangent_steps: false`` (index-1) and off() take no tangent coordinates."""
    for rtol in RTOLS:
        p = policy(family, rtol, exponent=0.0, fixed=True)
        assert p.tangent == cp.Policy.law(cp.DEFAULT_RTOL)
        assert (p.cut, p.noise_err) == (1.0, 1.0)
        assert p.newton_tol == cp.NEWTON_FLOOR
    p = cp.Policy.for_run(family, 1e-6, 1e-8, False, tangent=False, exponent=-0.2, n=28)
    assert p.tangent == 0.0
    assert policy(family, 1e-8).off().tangent == 0.0


def test_numbers_taken_from_elsewhere_agree_with_their_sources():
    """SCHUR_PIVOT_FLOOR is kernels.c's PIVOT_FLOOR, DEFAULT_RTOL the dynamic analysis's."""
    from mbsim.analyses.dynamic import DEFAULTS

    src = (ROOT / "mbsim" / "fast" / "kernels.c").read_text()
    m = re.search(r"#define PIVOT_FLOOR ([0-9.eE+-]+)", src)
    assert m and float(m.group(1)) == cp.SCHUR_PIVOT_FLOOR
    assert DEFAULTS["rtol"] == cp.DEFAULT_RTOL


# The float literals the integrators may hold, none of them a change-point threshold: the
# projection's default tolerance (index-1), Baumgarte's rates, the coordinate partition's
# re-partition ratio and the Taylor predictor's 1/2 (gcp).
ALLOWED_FLOATS = {
    "index1.py": {0.001, 1e-10, 1e-14, 10.0},
    "gcp.py": {0.5, 1.2},
}
IDENTITIES = {0.0, 1.0, 2.0}  # (zero, one; sqrt 2 of two draws' spread, index1._stage_noise)
OLD_NAMES = ("SINGULAR_PIVOT", "STRADDLE_NEAR", "TANGENT_PIVOT", "TANGENT_FLOOR", "NOISE_ERR",
             "NOISE_RATIO", "NOISE_STEP", "BRANCH_JUMP", "CUT", "S_FIXED", "S_NOISE",
             "S_INDEX1_CAP", "NEAR_INDEX1", "NEAR_GCP", "APPROACH_CUT")


@pytest.mark.parametrize("name", sorted(ALLOWED_FLOATS))
def test_no_change_point_threshold_outside_the_policy(name):
    """index1.py and gcp.py hold no threshold of their own: every float literal there is one
    of the documented non-policy numbers above, no module-level constant names a
    change-point threshold, and the only change-point numbers they read are the Policy's."""
    tree = ast.parse((ROOT / "mbsim" / "integrators" / name).read_text())
    floats = {n.value for n in ast.walk(tree)
              if isinstance(n, ast.Constant) and isinstance(n.value, float)}
    extra = floats - ALLOWED_FLOATS[name] - IDENTITIES
    assert not extra, sorted(extra)
    assigned = {t.id for n in tree.body if isinstance(n, ast.Assign)
                for t in n.targets if isinstance(t, ast.Name)}
    assert not assigned & set(OLD_NAMES)
    read = {n.attr for n in ast.walk(tree)
            if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name)
            and n.value.id == "cp" and n.attr.isupper()}
    assert not read, sorted(read)


# -- the approach, on s(t) = RATE (T_POINT - t): the measure falls linearly to the point ---
RATE, T_POINT = 0.35, 1.0  # 1/s, s (the four cranks cross at s' ~ 0.35 x their rad/s)


def feed(approach, times):
    """Accepted states at ``times`` (steps between them), s from the closed form."""
    for t0, t1 in zip(times, times[1:]):
        approach.accepted(t1, t1 - t0, RATE * (T_POINT - t1))


def test_approach_begins_two_steps_before_the_switch():
    """After a step of h with s falling at RATE, a state belongs to the approach once s <
    tangent + 2 h RATE; the s where it began holds until s rises past it."""
    pol = policy("gcp", 1e-8)
    a = cp.Approach(cp.stage_times(Dop853), None, pol)
    h = 1e-2
    s_begin = pol.tangent + 2 * h * RATE
    t_begin = T_POINT - s_begin / RATE  # the approach begins at the first state past this
    times = list(np.arange(0.0, t_begin + 1.5 * h, h))
    feed(a, times)
    assert a.near(h) == pytest.approx(RATE * (T_POINT - times[-1]), rel=1e-9)
    assert len(a.points) == 1 and a.h_far == pytest.approx(h)
    a.accepted(T_POINT + 0.5, 0.5, a.near(h) * 2)  # the motion turned away
    assert a.points == () and a.near(0.5) < RATE * 0.5 * 2 * 2 + pol.tangent


@pytest.mark.parametrize("tableau", [Dop853, DormandPrince54])
def test_step_across_clears_the_point_once_round_off_cuts_the_steps(tableau):
    """Two states of the approach and a proposed step cut below ``cut`` x the last step
    before it: the step tried crosses the extrapolated point with its stages clear of it
    (its nearest stage farther from it than those of the largest and the smallest step
    that cross it); an uncut
    step is left alone."""
    pol = policy("index-1", 1e-10, exponent=-1.0 / (tableau.error_order + 1))
    a = cp.Approach(cp.stage_times(tableau), None, pol)
    h = 1e-3
    times = list(T_POINT - 0.6 * h - h * np.arange(20)[::-1])  # the last 0.6 h before it
    feed(a, times)
    assert len(a.points) == 2
    assert a.step(h) is None  # not cut: the controller's step as it is
    d = T_POINT - times[-1]
    h_try = a.step(0.5 * pol.cut * h)
    assert h_try is not None and d < h_try <= h * (1 + REL)
    c = cp.stage_times(tableau)
    clear = np.abs(c * h_try - d).min()
    assert clear > 0.0
    for other in (h, d * (1 + 1e-6)):  # the largest step allowed, the smallest that crosses
        assert clear >= np.abs(c * other - d).min()
    assert a.accepted(times[-1] + h_try, h_try, RATE * abs(T_POINT - times[-1] - h_try))


def test_fixed_step_moves_only_where_the_motion_dwells_next_to_the_point():
    """A fixed step is moved across the point (into [h/2, 3h/2]) only where s changes by
    less than the switch over the widest gap between stage times (s'(t) = -rate): a dwell,
    not a passage."""
    pol = policy("index-1", 1e-6, exponent=0.0, fixed=True)
    c = cp.stage_times(ClassicRK4)  # 0, 1/2, 1: widest gap h/2
    h = 1e-3
    for rate, moved in ((0.5 * pol.tangent / (0.5 * h), True), (4 * pol.tangent / h, False)):
        a = cp.Approach(c, h, pol)
        t_last = T_POINT - 0.6 * h
        for t in (t_last - 3 * h, t_last - 2 * h, t_last - h, t_last):
            a.accepted(t, h, rate * (T_POINT - t))
        assert len(a.points) == 2
        got = a.step(h)
        assert (got is not None) == moved
        if moved:
            assert 0.5 * h <= got <= 1.5 * h


# -- the index-1 switch against the two paths' accelerations on the four cranks ---------------
def four_cranks_state(theta, thetad=10.0, theta_ref=0.06):
    """(system, q, qd, qdd, C): the four cranks' equations of motion on their independent
    rows and the exact state at crank angle theta (rad) from the flat position, turning at
    thetad (rad/s); C the tangent map taken theta_ref rad from the point.  Exact: the four
    cranks' effective inertia is constant (the cranks turn about fixed pivots, the coupler
    translates on a circle of radius L), so theta'' = -g cos(theta) (4 m_c L / 2 + M L) /
    I_eff, I_eff = 4 (J_c + m_c L^2 / 4) + M L^2."""
    from mbsim.analyses.common import rank_and_redundant
    from mbsim.analyses.diagnosis import jacobian
    from mbsim.analyses.trajectory import make_system
    from tests.integrators import models as M

    pb = M.reference_problem("parallel_fourbar")
    model = pb.model
    _, red = rank_and_redundant(model, jacobian(model, pb.q0, 0.0))
    system = make_system(model, np.setdiff1d(np.arange(model.m), red))
    P = M.FOURBAR
    L, mc, Mc, g = P["L"], P["m_crank"], P["M"], P["g"]
    i_eff = 4 * (M.fourbar_crank_inertia(L, mc)[2] + mc * L * L / 4) + Mc * L * L
    thetadd = -g * np.cos(theta) * (4 * mc * L / 2 + Mc * L) / i_eff
    q, qd, qdd = M.parallel_fourbar_motion(model, theta, thetad, thetadd)
    qr = M.parallel_fourbar_motion(model, theta_ref, thetad, 0.0)[0]
    C = cp.tangent_map(system, qr, system.terms(qr, 0.0, phi=False).jac)
    return system, q, qd, qdd, C


def four_cranks_accelerations(theta, thetad=10.0, ulps=4, seed=1, theta_ref=0.06):
    """(s, Schur error, tangent error) at crank angle theta (rad) from the flat position: the
    errors of qdd from the state q perturbed by ``ulps`` ulps (random signs) against the exact
    accelerations (:func:`four_cranks_state`), relative to max |qdd|; the tangent
    coordinates' C taken theta_ref rad from the point (benchmarks/index1_switch.py prints
    these for a range of theta)."""
    system, q, qd, qdd, C = four_cranks_state(theta, thetad, theta_ref)
    rng = np.random.default_rng(seed)
    qp = q + ulps * EPS * np.maximum(1.0, np.abs(q)) * rng.choice([-1.0, 1.0], q.size)
    a_schur = system.accelerations(qp, qd, 0.0)[0]
    s = cp.measure_from_schur(system.pivot_ratio)
    x, qdp, fac, _ = cp.complete(system, 0.0, qp, C @ q, C @ qd, C, 1e-14, 8)
    a_tangent = cp.accelerations(system, 0.0, x, qdp, fac, C.shape[0])[0]
    scale = np.abs(qdd).max()
    return (s, np.abs(a_schur - qdd).max() / scale, np.abs(a_tangent - qdd).max() / scale)


@pytest.mark.parametrize("theta", [3e-3, 1e-2, 3e-2])
def test_round_off_of_the_two_paths_above_the_pivot_floor(theta):
    """Above the kernels' pivot floor the Schur path's accelerations are within 10 eps s^-2
    of the exact ones and the tangent coordinates' within 10 eps s^-3 (measured 0.2-1.9 and
    0.04-0.6 x those laws): the laws the index-1 switch compares (Policy doc, ``tangent``)."""
    s, e_schur, e_tangent = four_cranks_accelerations(theta)
    assert s > np.sqrt(cp.SCHUR_PIVOT_FLOOR)
    assert e_schur <= 10 * EPS * s ** -2
    assert e_tangent <= 10 * EPS * s ** -3


def test_below_the_pivot_floor_only_the_tangent_coordinates_solve_the_equations():
    """Below sqrt(SCHUR_PIVOT_FLOOR) the kernels raise the Schur pivot: the accelerations are
    off by a sizeable fraction of max |qdd| (measured 0.4-0.9), the tangent coordinates'
    within 10 eps s^-3 (measured 2e-3 at s = 4e-5)."""
    s, e_schur, e_tangent = four_cranks_accelerations(1e-4)
    assert s < np.sqrt(cp.SCHUR_PIVOT_FLOOR)
    assert e_schur > 0.1
    assert e_tangent <= 10 * EPS * s ** -3 < 0.1


@pytest.mark.parametrize("theta", [1e-2, 1e-3, 1e-4])
def test_completion_ends_within_its_round_off_ball_whatever_the_newton_tolerance(theta):
    """Next to the point the completion's q is decided only to the round-off of a correction
    through A, eps max|q| / s (the computed residual cannot tell those points apart), and
    v'' = C qdd there is off by up to ~eps s^-2 relative, whatever the Newton tolerance:
    from 16 starts 1e-10 m around the exact q (a prediction's distance) at newton_tol 1e-12,
    2.2e-12 and 1e-14, measured |q - q*| <= 0.4 ball widths and v'' within 0.004-0.16 eps
    s^-2 at theta = 3e-2 ... 1e-4 rad under the default and Prescott kernels (Policy doc,
    ``newton_tol``; benchmarks/newton_floor.py --ball).  Bounds: one ball width, and
    eps s^-2."""
    system, q, qd, qdd, C = four_cranks_state(theta)
    s = cp.measure_from_lu(cp.factor(system, system.terms(q, 0.0, phi=False).jac, C), False)
    ball = EPS * np.abs(q).max() / s
    vdd = np.abs(C @ qdd).max()
    rng = np.random.default_rng(1)
    for tol in (1e-12, EPS / np.sqrt(cp.SCHUR_PIVOT_FLOOR), 1e-14):
        for _ in range(16):
            q0 = q + 1e-10 * rng.standard_normal(q.size)
            x, xd, fac, _ = cp.complete(system, 0.0, q0, C @ q, C @ qd, C, tol, 8)
            assert xd is not None
            a = cp.accelerations(system, 0.0, x, xd, fac, C.shape[0])[0]
            assert np.abs(x - q).max() <= ball
            assert np.abs(C @ (a - qdd)).max() <= EPS * s**-2 * vdd
