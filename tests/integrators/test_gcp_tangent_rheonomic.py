"""Tangent coordinates of coordinate partitioning (mbsim/integrators/gcp.py, module doc) on a
*rheonomic* model: ``_tangent_accelerations`` (the reduced equations (T^T M T) v'' =
T^T (Q - M p) and, for a driven model, power = Q.qd - lam.nu with lam from the transposed
solve) and ``_complete`` (A qd = [nu; vd]) against the exact reduction and against
System.accelerations (the C kernels' Schur solve), then through whole runs.

The model: the four-crank parallel linkage of tests/integrators/models.py (parallel_fourbar,
the FOURBAR data) whose pivots sit on a base body, not on the ground; a translation driver
shakes the base along d = (1, 1, 0)/sqrt(2) (joint ``slide``, translational ground-base;
driver ``shake``: s(t) = A sin(W t)).  Phi_q qd = nu has nu = s'(t) on the driver's row, so
the rheonomic terms are non-zero.  One degree of freedom (the crank angle theta relative to
the base), 11 redundant rows (as the ground-mounted linkage), singular positions at
theta = 0, pi.  Exact reduction: the base acceleration a = s'' d acts as a force -m a on every
body, so

    MASS theta'' = S (a_x sin(theta) - (g + a_y) cos(theta)),
    MASS = N (I_crank + m_crank L^2 / 4) + M L^2,   S = N m_crank L / 2 + M L,

and the rate of the kinetic energy (what the integrators call power, Q.qd - lam.nu) is
sum_b m_b rd_b . rdd_b + N I_crank theta' theta'' (the base and the coupler translate).
The control (``shaken=False``): the base welded to the ground (joint ``fixed``, no driver),
a scleronomic model with the same geometry.
"""

import functools

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from mbsim.analyses.common import rank_and_redundant
from mbsim.analyses.diagnosis import jacobian as _jac
from mbsim.analyses.dynamic import dynamic
from mbsim.analyses.trajectory import make_system
from mbsim.expr import parse_expression
from mbsim.integrators import INTEGRATORS, gcp
from mbsim.model import compile_model
from tests.helpers import body, driver, func, joint, pts, spec
from tests.integrators import models as M

P = M.FOURBAR
N = 4
L, G = P["L"], P["g"]
I_CRANK = M.fourbar_crank_inertia()[2]
MASS = N * (I_CRANK + P["m_crank"] * L ** 2 / 4) + P["M"] * L ** 2
S = N * P["m_crank"] * L / 2 + P["M"] * L
AMP, W = 0.03, 15.0  # m, rad/s: base acceleration up to 6.75 m/s^2 (0.7 g), speed 0.45 m/s
D = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)  # the shaking direction (both terms of theta'')
THETA0, THETAD0 = -np.pi / 2, 20.0  # as the reference problem: 5 flat passages in 1 s


@functools.lru_cache(maxsize=None)
def shaken_fourbar(shaken=True):
    """parallel_fourbar(4) with its pivots G<i> on the body ``base`` (module doc); the base
    slides on the ground along D, driven by s(t) = AMP sin(W t), or (shaken=False) is welded
    to the ground."""
    frame = pts((0, 0, 0), tuple(D), (0, 0, 1))
    parts, loops = M.parallel_fourbar_parts(N, THETA0, mount="base")
    bodies = [body("ground", ground=True), body("base", 5.0, (0.1, 0.2, 0.3))] + parts
    joints = [joint("slide", "translational" if shaken else "fixed", "ground", "base",
                    {"ground": frame, "base": frame})] + loops
    drivers = ([driver("shake", "translation",
                       func("expression", expr=parse_expression(f"{AMP}*sin({W}*t)")),
                       joint="slide")] if shaken else [])
    return compile_model(spec(bodies, joints, drivers, gravity=(0, -G, 0)))


def base_motion(t, shaken=True):
    """(s, s', s'') of the base along D."""
    if not shaken:
        return 0.0, 0.0, 0.0
    return AMP * np.sin(W * t), AMP * W * np.cos(W * t), -AMP * W * W * np.sin(W * t)


def theta_acc(t, th, shaken=True):
    """theta'' of the exact reduction (module doc)."""
    a = base_motion(t, shaken)[2] * D
    return S * (a[0] * np.sin(th) - (G + a[1]) * np.cos(th)) / MASS


def exact_state(model, t, th, thd, shaken=True):
    """q, qd, qdd of the mechanism at time t, crank angle th (relative to the base) and rate
    thd: the base at s(t) D, crank<i> turned by th about z with its pivot at the base point
    (x_i, 0, 0), the coupler translating on a circle of radius L about the base."""
    return M.parallel_fourbar_motion(model, th, thd, theta_acc(t, th, shaken),
                                     base_motion(t, shaken), D)


def exact_power(model, qd, qdd, thd, thdd):
    """dT/dt of the exact motion (module doc)."""
    trans = sum(model.mass[b] * qd[7 * b:7 * b + 3] @ qdd[7 * b:7 * b + 3]
                for b in range(model.nb))
    return float(trans + N * I_CRANK * thd * thdd)


def setup(shaken=True, sparse=False, compiled=False):
    """The model, its System on the independent rows (chosen at the initial state, as the
    dynamic analysis does) and a gcp-dop853 integrator started there: with its stages in
    Python (``_complete``, ``_tangent_accelerations``: the equations under test here), or
    in C (``compiled``: mbsim/fast/partition.c, through ``_rhs``)."""
    model = shaken_fourbar(shaken)
    q0, qd0, _ = exact_state(model, 0.0, THETA0, THETAD0, shaken)
    _, red = rank_and_redundant(model, _jac(model, q0, 0.0))
    assert red.size == 11
    system = make_system(model, np.setdiff1d(np.arange(model.m), red), sparse=sparse)
    integ = INTEGRATORS["gcp-dop853"](system, 0.0, q0, qd0, 1.0,
                                      {"rtol": 1e-10, "atol": 1e-12, "compiled_step": compiled})
    return model, system, integ


def compiled_stage(integ, t, q, qd, part, seed):
    """(q, qd, qdd, power) of the compiled stage in ``part`` at (v, vd) of (q, qd), Newton
    started 1e-9 off q."""
    integ._pred = q + 1e-9 * np.random.default_rng(seed).standard_normal(q.size)
    f = integ._rhs(t, np.concatenate([part.v(q), part.v(qd), [0.0]]), part)
    return (*integ._last[2:5], float(f[-1]))


def tangent_partition(integ, q, t):
    """The tangent partition at q (gcp's own construction: _tangent_partition)."""
    J = integ.system.terms(q, t, phi=False).jac
    part = integ._tangent_partition(q, J, J.toarray() if integ.system.sparse else J,
                                    integ.part.iv, integ.part.iu)
    assert part is not None and part.C.shape == (1, q.size)
    return part


def dense(J):
    return J.toarray() if hasattr(J, "toarray") else J


# (t, theta, theta'): away from the flat positions (|sin theta| >= 0.6); s'(t) = 0.45 cos(15 t)
# m/s is 0.38, -0.036, -0.43, -0.095 m/s there (the driver's nu, asserted non-zero below)
STATES = [(0.037, 0.5, 20.0), (0.11, 1.2, -7.0), (0.23, 2.5, 13.0), (0.3, -2.0, 5.0)]
TOL = 1e-9


@pytest.mark.parametrize("sparse", [False, True], ids=["dense", "sparse"])
@pytest.mark.parametrize("shaken", [True, False], ids=["rheonomic", "scleronomic"])
def test_tangent_accelerations_regular_states(shaken, sparse):
    """At regular states (the coordinate partition's Phi_u pivot ratio above the run's
    switch, changepoints.Policy.tangent),
    with the tangent partition of the state itself and of a state 0.3 rad away (a rotated
    tangent: the reduced equations are exact for any C with [Phi_q; C] regular), and after
    ``_complete`` rebuilt (q, qd) from v = C q, vd = C qd (Newton started 1e-9 off):

    - qdd from _tangent_accelerations == System.accelerations == the exact reduction, and
      power == System's power == dT/dt of the reduction, each to 1e-9 relative;
    - Phi_q qdd = gamma to 1e-12 of |Phi_q| |qdd| + |gamma|; q, qd from _complete within
      1e-12 m, 1e-11 m/s of the exact state;
    - rheonomic: nu != 0 (|nu| >= 0.03 m/s) and the term lam.nu is >= 2 % of the power (so a
      missing, mis-signed or mis-solved lam fails the 1e-9); scleronomic: power == Q.qd.

    Tolerance: cond([Phi_q; C]) <= 100 and cond(Phi_q) <= 100 (asserted) at these states, so
    round-off in either solve is ~ cond^2 eps ~ 1e-12 relative for the Schur complement (whose
    condition is that of Phi_q squared); measured 1e-13 (System) and 2e-15 (tangent) against
    the exact qdd, 3e-14 for the power.  1e-9 leaves 1e4 of margin for other BLAS builds and
    is still 1e7 below any formula error (the lam.nu term alone is 2 % and more)."""
    model, system, integ = setup(shaken, sparse)
    assert system.rheonomic == shaken
    for t, th, thd in STATES:
        q, qd, qdd_ex = exact_state(model, t, th, thd, shaken)
        power_ex = exact_power(model, qd, qdd_ex, thd, theta_acc(t, th, shaken))
        Tm = system.terms(q, t, qd=qd, gamma=True, nu=True)
        J = dense(Tm.jac)
        assert np.abs(Tm.phi).max() < 1e-14 and np.abs(J @ qd - Tm.nu).max() < 1e-13
        if shaken:
            assert np.abs(Tm.nu).max() >= 0.03
        else:
            assert not np.any(Tm.nu)
        # a regular configuration: gcp would not switch to tangent coordinates here
        assert integ._pivot_ratio(integ._factor(Tm.jac, integ.part.iu)) > integ.policy.tangent
        assert np.linalg.cond(J) < 100
        qdd_sys, _, power_sys = system.accelerations(q, qd, t)
        Q = system.generalized_forces(q, qd, t)
        for th_part in (th, th + 0.3):
            part = tangent_partition(integ, exact_state(model, t, th_part, thd, shaken)[0], t)
            assert np.linalg.cond(np.vstack([J, part.C])) < 100
            rng = np.random.default_rng(int(1e3 * th_part) % 2 ** 31)
            integ._pred = q + 1e-9 * rng.standard_normal(q.size)
            qq, qqd, fac = integ._complete(t, part.v(q), part.v(qd), part)
            assert np.abs(qq - q).max() < 1e-12
            assert np.abs(qqd - qd).max() < 1e-11
            for fac_ in (fac, integ._factor_tangent(Tm.jac, part.C)):  # _complete's / exact q
                qdd, power = integ._tangent_accelerations(t, qq, qqd, fac_, part)
                scale = np.abs(qdd_ex).max()
                assert np.abs(qdd - qdd_ex).max() <= TOL * scale, (t, th_part)
                assert np.abs(qdd - qdd_sys).max() <= TOL * scale, (t, th_part)
                gam = np.abs(J).max() * np.abs(qdd).max() + np.abs(Tm.gamma).max()
                assert np.abs(J @ qdd - Tm.gamma).max() <= 1e-12 * gam
                assert power == pytest.approx(power_ex, rel=TOL, abs=0)
                assert power == pytest.approx(power_sys, rel=TOL, abs=0)
        if shaken:  # the lam.nu term: 3 % (t = 0.11 s, nu = -0.036 m/s) to 260 % of the power
            assert abs(float(Q @ qd) - power_ex) >= 0.02 * abs(power_ex)
        else:
            assert float(Q @ qd) == pytest.approx(power_ex, rel=TOL, abs=0)


@pytest.mark.parametrize("delta,power_tol", [(1e-3, 1e-6), (1e-4, 1e-3)])
def test_tangent_accelerations_near_flat_position(delta, power_tol):
    """delta rad past the flat position theta = pi (Phi_u's pivot ratio below
    the run's switch, changepoints.Policy.tangent); the tangent partition taken 1e-2
    rad before it, as gcp picks it on the way
    in) at t = 0.4 s, where the base moves (nu = s' = 0.43 m/s) and accelerates (s'' = 1.9
    m/s^2):

    - at the exact state: qdd to 1e-9 of |qdd| and the power to 1e-9 relative of the exact
      reduction (measured 5e-13 / 2e-15 at 1e-3 rad, 2e-12 / 3e-14 at 1e-4 rad: cond([Phi_q;
      C]) is 2.5e4 and 2.5e5, as Phi_q's, ~ 2 / delta; the Schur complement of
      System.accelerations squares that and meets its pivot floor, 8e-2 / 4e-4 off at 1e-4
      rad, not asserted);
    - from (v, vd) through ``_complete`` (Newton started 1e-9 off, 4 starts): v'' = C qdd to
      1e-6 of |v''| (the bound of test_gcp_near_singular.py; measured 4e-11, 8e-9) and the
      power to ``power_tol`` (measured 1.7e-8 at 1e-3 rad, 1.5e-5 at 1e-4 rad: the completed
      qd carries round-off along the soft directions, 4e-9 and 4e-7 m/s, which the full qdd
      and the multipliers (|lam| ~ 2e4) amplify and lam.nu passes on; the scleronomic model's
      Q.qd only 1.5e-9).  Either bound is 500x and more below the lam.nu share (51 % here,
      asserted >= 5 %), so a missing or wrong lam.nu still fails."""
    model, system, integ = setup()
    t, th, thd = 0.4, np.pi + delta, 20.0
    q, qd, qdd_ex = exact_state(model, t, th, thd)
    power_ex = exact_power(model, qd, qdd_ex, thd, theta_acc(t, th))
    Tm = system.terms(q, t, qd=qd, gamma=True, nu=True)
    assert np.abs(Tm.nu).max() >= 0.4
    assert integ._pivot_ratio(integ._factor(Tm.jac, integ.part.iu)) < integ.policy.tangent
    part = tangent_partition(integ, exact_state(model, t, np.pi - 1e-2, thd)[0], t)
    qdd, power = integ._tangent_accelerations(t, q, qd, integ._factor_tangent(Tm.jac, part.C),
                                              part)
    assert np.abs(qdd - qdd_ex).max() <= TOL * np.abs(qdd_ex).max()
    assert power == pytest.approx(power_ex, rel=TOL, abs=0)
    a_ex = part.v(qdd_ex)
    worst_v = worst_power = 0.0
    for seed in range(4):
        integ._pred = q + 1e-9 * np.random.default_rng(seed).standard_normal(q.size)
        qq, qqd, fac = integ._complete(t, part.v(q), part.v(qd), part)
        qdd, power = integ._tangent_accelerations(t, qq, qqd, fac, part)
        worst_v = max(worst_v, np.abs(part.v(qdd) - a_ex).max() / np.abs(a_ex).max())
        worst_power = max(worst_power, abs(power - power_ex) / abs(power_ex))
    assert worst_v <= 1e-6 and worst_power <= power_tol, (worst_v, worst_power)
    Q = system.generalized_forces(q, qd, t)
    assert abs(float(Q @ qd) - power_ex) >= 0.05 * abs(power_ex)


@pytest.mark.parametrize("shaken", [True, False], ids=["rheonomic", "scleronomic"])
def test_compiled_tangent_stage_regular_states(shaken):
    """The tangent stage in C (partition.c: tangent_stage) at the regular states above, from
    (v, vd) with Newton started 1e-9 off: q, qd as ``_complete``'s bounds, qdd and the power
    within TOL of the exact reduction (the same bounds as the Python stage's)."""
    model, system, integ = setup(shaken, compiled=True)
    assert integ._compiled is not None
    for t, th, thd in STATES:
        q, qd, qdd_ex = exact_state(model, t, th, thd, shaken)
        power_ex = exact_power(model, qd, qdd_ex, thd, theta_acc(t, th, shaken))
        part = tangent_partition(integ, exact_state(model, t, th - 0.3, thd, shaken)[0], t)
        qq, qqd, qdd, power = compiled_stage(integ, t, q, qd, part, 0)
        assert np.abs(qq - q).max() < 1e-12
        assert np.abs(qqd - qd).max() < 1e-11
        assert np.abs(qdd - qdd_ex).max() <= TOL * np.abs(qdd_ex).max(), (t, th)
        assert power == pytest.approx(power_ex, rel=TOL, abs=0)


@pytest.mark.parametrize("delta,power_tol", [(1e-3, 1e-6), (1e-4, 1e-3)])
def test_compiled_tangent_stage_near_flat_position(delta, power_tol):
    """The tangent stage in C delta rad past the flat position, as the Python stage above
    (4 Newton starts): v'' = C qdd within 1e-6 of |v''| and the power within power_tol of
    the exact reduction's, whose lam.nu share (51 %) a missing or wrong term would miss."""
    model, system, integ = setup(compiled=True)
    t, th, thd = 0.4, np.pi + delta, 20.0
    q, qd, qdd_ex = exact_state(model, t, th, thd)
    power_ex = exact_power(model, qd, qdd_ex, thd, theta_acc(t, th))
    part = tangent_partition(integ, exact_state(model, t, np.pi - 1e-2, thd)[0], t)
    a_ex = part.v(qdd_ex)
    worst_v = worst_power = 0.0
    for seed in range(4):
        _, _, qdd, power = compiled_stage(integ, t, q, qd, part, seed)
        worst_v = max(worst_v, np.abs(part.v(qdd) - a_ex).max() / np.abs(a_ex).max())
        worst_power = max(worst_power, abs(power - power_ex) / abs(power_ex))
    assert worst_v <= 1e-6 and worst_power <= power_tol, (worst_v, worst_power)


MAX_STEPS = 500  # measured 39-68 steps: a broken branch fails here instead of creeping on


def reduction(times):
    """theta, theta' of the exact reduction at the output times (scipy DOP853 at rtol 1e-13,
    as tests/integrators/references.py: ~1e-12 relative)."""
    sol = solve_ivp(lambda t, y: [y[1], theta_acc(t, y[0])], (times[0], times[-1]),
                    [THETA0, THETAD0], t_eval=times, method="DOP853", rtol=1e-13, atol=1e-15)
    assert sol.success, sol.message
    return sol.y


@pytest.mark.parametrize("compiled", [True, False], ids=["C", "Python"])
@pytest.mark.parametrize("rtol", [1e-8, 1e-9, 1e-10])
def test_run_through_flat_positions(rtol, compiled, monkeypatch):
    """gcp-dop853 over 1 s from the bottom at 20 rad/s on the shaken linkage (5 flat
    passages), its stages in C or in Python: the run completes, the tangent branch runs (a
    spy on the tangent stages, _tangent_accelerations, or on the compiled trials in tangent
    coordinates, whose stages are not seen one by one: a step across a flat position counts
    as a stage there; stages near theta = 0 mod pi, i.e. |sin theta| < 0.1, with |nu| >=
    0.01 m/s, the driver moving; where a step's end lands depends on round-off, OpenBLAS
    Prescott put none within 0.1), and

    - position error against the exact reduction <= 10 rtol + 1e-9 m (the bound of
      test_singular_loops.py; measured 2.5e-9, 5.5e-10, 3.2e-11 m at rtol 1e-8, 1e-9, 1e-10;
      at 1e-10 it was 3.1e-9 m, at one output, before the gcp switch grew with the
      tolerance: an extra dense-output stage of DOP853 fell in coordinates at a Phi_u pivot
      ratio of 5.6e-5);
    - energy - work_nonconservative constant to 100 rtol x max(energy) (the work is the
      integral of the stages' power, the driver's lam.nu included; measured 3.8e-7, 3.2e-8,
      1.4e-8 J with max(energy) = 23 J, i.e. 1.6, 1.4 and 6 rtol x 23 J; w is integrated by
      the same RK method but not error-controlled, hence the factor).  In the tangent stages
      lam.nu is a large share of the power (the driver does 10.6 J of work in 1 s): without
      it the balance is 1.7 J off, with lam from the untransposed solve 125 J.
    """
    model = shaken_fourbar()
    q0, qd0, _ = exact_state(model, 0.0, THETA0, THETAD0)
    seen = []
    cls = gcp.GeneralizedCoordinatePartitioning
    original = cls._tangent_accelerations

    from mbsim.fast.partition import CompiledStage

    trial = CompiledStage.trial

    b = 7 * model.body_index("crank0")

    def sin_theta(q):
        return np.sin(2 * np.arctan2(q[b + 6], q[b + 3]))

    def spy_trial(self, t, h, y, f, start, qd0, control):
        """A compiled trial in tangent coordinates: its stages are not seen one by one, so
        a step that passes a flat position (sin theta changes sign over it) counts as a
        stage there (sin 0), else the step's end is recorded."""
        st = trial(self, t, h, y, f, start, qd0, control)
        if self.C is not None and st == 0:
            q = self.buffer("q")
            s0, s1 = sin_theta(start), sin_theta(q)
            seen.append((t + h, 0.0 if s0 * s1 <= 0 else s1,
                         np.abs(system_nu(q, t + h)).max()))
        return st

    def spy(self, t, q, qd, fac, part):
        out = original(self, t, q, qd, fac, part)
        seen.append((t, sin_theta(q), np.abs(system_nu(q, t)).max()))
        return out

    system_nu = None
    monkeypatch.setattr(cls, "_tangent_accelerations", spy)
    monkeypatch.setattr(CompiledStage, "trial", spy_trial)
    init = cls.__init__

    def keep_system(self, system, *a, **k):
        nonlocal system_nu
        system_nu = system.nu
        init(self, system, *a, **k)

    monkeypatch.setattr(cls, "__init__", keep_system)
    res = dynamic(model, {"t_end": 1.0, "step": 0.01, "q0": q0, "qd0": qd0,
                          "integrator": "gcp-dop853", "rtol": rtol, "atol": 1e-2 * rtol,
                          "error_estimate": False, "max_steps": MAX_STEPS,
                          "compiled_step": compiled})
    assert res.complete, res.message
    assert res.t[-1] == pytest.approx(1.0)
    th, thd = reduction(res.t)
    assert np.count_nonzero(np.diff(np.floor(th / np.pi))) == 5
    near = [(t, nu) for t, s, nu in seen if abs(s) < 0.1]
    assert near and max(nu for _, nu in near) >= 0.01, seen[:5]
    assert res.counters["repartitions"] >= 2  # into tangent coordinates and out again
    assert res.counters["tangent_partitions"] >= 1  # the counter sees what the spy saw
    err = 0.0
    for k, t in enumerate(res.t):
        qe = exact_state(model, t, th[k], thd[k])[0]
        for b, name in enumerate(model.body_names):
            r = res.channel(f"bodies/{name}/r").data[k]
            err = max(err, float(np.linalg.norm(r - qe[7 * b:7 * b + 3])))
    assert err <= 10 * rtol + 1e-9, f"position error {err:.3g} m"
    energy = res.channel("monitors/energy").data
    work = res.channel("monitors/work_nonconservative").data
    assert np.abs(work).max() > 5.0  # the driver's work (10.6 J): the balance is not trivial
    drift = float(np.abs((energy - work) - (energy[0] - work[0])).max())
    bound = 100 * rtol * float(np.abs(energy).max())
    assert drift <= bound, f"energy - work drifts {drift:.3g} J > {bound:.3g} J"
