"""The coarse error estimate (mbsim.analyses.estimate.coarse_estimate): the run's method on
the run's own mesh coarsened by two, difference / (2^p - 1), against the independent
references of tests/integrators/references.py.

The default integrator (projection-dop853, p = 8) is checked on all five reference problems
at rtol 1e-5 and 1e-9 by tests/integrators/test_error_estimate.py (est / true there:
0.59-1.95); here Dormand-Prince 5(4) with projection (p = 5) at rtol 1e-8 on the three
problems that move and meet no singular position (est / true 0.82-1.61 measured), and what
the companion costs in steps.  A run that met a singular position (the four parallel
cranks, where the coarse estimate was 35x the true error at rtol 1e-7, and 34x under
OpenBLAS Prescott with the Python step, which passes the point between outputs without a
tangent stage) gets the companion at rtol / 5 instead; there the estimate is kept at least
the passage's round-off floor (estimate.roundoff_floor), and a companion that stops at the
passage where the run did not is replaced by another method at the run's tolerance.
Generalized-alpha (p = 2) on the pendulum and the slider-crank at rtol 1e-3 and 1e-6, and
on the four cranks, whose redundant rows keep the companion at rtol / 5.  A known
overestimate outside these tests: the pendulum at rtol 1e-5 with projection (19x).
"""

import math

import numpy as np
import pytest

from mbsim.analyses import estimate as est_mod
from mbsim.analyses import trajectory
from mbsim.analyses.dynamic import dynamic
from mbsim.errors import UsageError
from mbsim.integrators.changepoints import EPS
from tests.integrators import models as M
from tests.integrators import references as R

FLOOR = 1e-12  # m and rad: below this a true error is round-off (test_error_estimate.FLOOR)
MOVING = ("heavy_top", "pendulum", "slider_crank")  # moving, no singular position
CRANKS_SIZE = 1.0  # m: the four parallel cranks' size (|r| of a centroid, the motion's span)
PASSAGE_FLOOR = np.sqrt(EPS) * CRANKS_SIZE
"""m: the largest round-off floor of a passage of the cranks' flat position: the two
branches of Phi = 0 meet there, and a residual of eps x size fixes them only to sqrt(eps) x
size (estimate.roundoff_floor).  An error below it is noise; an estimate is compared with
the larger of the two."""


def run(pb, **opts):
    res = dynamic(pb.model, dict({"t_end": pb.t_end, "step": pb.step, "q0": pb.q0,
                                  "qd0": pb.qd0}, **opts))
    assert res.complete, res.message
    return res


@pytest.mark.parametrize("name", MOVING)
def test_coarse_estimate_of_dormand_prince_within_factor_10(name):
    """0.1 <= estimate / true error <= 10 in position (and orientation where a body
    rotates): neither an underestimate nor an overestimate by more than 10x."""
    pb = M.reference_problem(name)
    res = run(pb, integrator="projection", rtol=1e-8, atol=1e-10)
    est = res.summary["error_estimate"]
    assert "coarsened by 2" in est["method"]
    ref = pb.reference(res.t)
    pos = R.position_error(res, ref).max()
    assert pos > FLOOR
    assert 0.1 <= est["position"] / pos <= 10, (est["position"], pos)
    if pb.rotating:
        ori = R.orientation_error(res, ref).max()
        assert 0.1 <= est["orientation"] / ori <= 10, (est["orientation"], ori)


def test_coarse_companion_takes_half_the_steps():
    """The companion steps onto every other step end of the run: ceil(n / 2) steps for a
    run of n accepted steps, no rejected ones; the per-output channels cover every output."""
    pb = M.reference_problem("slider_crank")
    res = run(pb, rtol=1e-7, atol=1e-9)
    est, n = res.summary["error_estimate"], res.counters["steps"]
    assert est["steps"] == math.ceil(n / 2)
    assert res.channel("error/position").data.shape == res.t.shape
    assert res.channel("error/position").data.max() == pytest.approx(est["position"])


def test_tighter_companion_on_request():
    """estimate_method 'tighter': the companion at rtol / estimate_ratio, as before the
    coarse one; another value is a usage error naming the setting."""
    pb = M.reference_problem("pendulum")
    res = run(pb, rtol=1e-7, atol=1e-9, estimate_method="tighter")
    assert "at rtol/5" in res.summary["error_estimate"]["method"]
    with pytest.raises(UsageError, match="analysis setting estimate_method"):
        run(pb, estimate_method="finer")


@pytest.mark.parametrize("compiled", [True, False], ids=["c-step", "python-step"])
@pytest.mark.parametrize("integrator", ["projection-dop853", "projection"])
def test_a_run_past_a_singular_position_is_estimated_within_10x(compiled, integrator):
    """The four parallel cranks at rtol 1e-7 pass flat positions, whether or not a step
    meets them with a tangent stage (the Python step passes them between outputs without
    one): the change-point measure at the outputs shows the passage, and the estimate is the
    companion at rtol/5's, since the coarse one was 35x the truth there (34x under OpenBLAS
    Prescott).  The estimate is within [err / 10, 10 max(err, PASSAGE_FLOOR)]."""
    pb = M.reference_problem("parallel_fourbar")
    res = run(pb, integrator=integrator, rtol=1e-7, atol=1e-9, compiled_step=compiled)
    est = res.summary["error_estimate"]
    assert "at rtol/5" in est["method"] and "round-off floor" in est["method"]
    pos = R.position_error(res, pb.reference(res.t)).max()
    assert pos / 10 <= est["position"] <= 10 * max(pos, PASSAGE_FLOOR), (est["position"], pos)


def test_the_measure_at_the_outputs_sees_a_crossing_between_them():
    """outputs_measure's vertex: s linear in the distance to the point, sampled on both
    sides of it (|x - 0.3| at x = 0, 0.2, 0.4, 0.6): the local minimum's vertex is the
    point (0); a minimum that is not a crossing (a smooth turn, s symmetric about it)
    keeps its value."""
    s = np.abs(np.array([0.0, 0.2, 0.4, 0.6]) - 0.3)
    assert est_mod.vertices(s).min() == pytest.approx(0.0, abs=1e-15)
    turn = 0.1 + (np.array([0.0, 0.2, 0.4]) - 0.2) ** 2
    assert est_mod.vertices(turn)[1] == pytest.approx(0.1)


def test_the_round_off_floor_is_bounded_by_sqrt_eps():
    """roundoff_floor: eps x size / s in position, eps / s in orientation, s at least
    sqrt(eps) (the branches meeting at the point), so at most sqrt(eps) x size."""
    far = est_mod.roundoff_floor((1e-2, 2.0, None, None))
    assert far["position"] == pytest.approx(EPS * 2.0 / 1e-2)
    assert far["orientation"] == pytest.approx(EPS / 1e-2)
    at = est_mod.roundoff_floor((0.0, 2.0, None, None))
    assert at["position"] == pytest.approx(np.sqrt(EPS) * 2.0)


def _slow_crossing(monkeypatch, stops):
    """The cranks' slow crossing (models/parallel_fourbar.yaml, w0 10.51 rad/s) at rtol
    1e-10 with projection-dop853, every companion run for which ``stops(name, rtol)`` holds
    stopping at its first step as an integrator does (h_min); (result, true error)."""
    from tests.integrators.test_changepoints import _run

    step = trajectory.Stepper.step
    runs = []

    def stopping(self):
        if not runs:  # the first Stepper to step is the run itself
            runs.append(self)
        if (self is not runs[0] and not isinstance(self, est_mod.CoarseStepper)
                and stops(self.cls.name, float(self.opt["rtol"]))):
            return False, f"t = {self.solver.t:.6g} s: step size fell below h_min (test)"
        return step(self)

    monkeypatch.setattr(trajectory.Stepper, "step", stopping)
    return _run(integrator="projection-dop853", rtol=1e-10, max_steps=2000)


def test_a_companion_stopping_at_a_passage_is_replaced_at_the_runs_tolerance(monkeypatch):
    """The run passed a change point and its method's companion (rtol/5) stops where it
    did not, as it did under OpenBLAS Prescott: another method at the run's own tolerance
    gives the estimate (the run's method at rtol/2 is not tried: it crawled there too),
    within [err / 10, 10 max(err, PASSAGE_FLOOR)]."""
    res, err = _slow_crossing(
        monkeypatch, lambda name, rtol: name == "projection-dop853" and rtol < 1e-10)
    assert res.complete, res.message
    est = res.summary["error_estimate"]
    assert "with gcp-dop853 at rtol 1e-10" in est["method"], est
    assert "stopped" in est["method"] and "round-off floor" in est["method"]
    assert err / 10 <= est["position"] <= 10 * max(err, PASSAGE_FLOOR), (est["position"], err)


def test_every_companion_stopping_at_a_passage_gives_no_estimate_with_the_reason(monkeypatch):
    """When the retries with the other methods stop too, there is no estimate (None in the
    summary) and the reason says that the retries failed."""
    res, _ = _slow_crossing(monkeypatch, lambda name, rtol: True)
    est = res.summary["error_estimate"]
    assert est["position"] is None
    assert "no other companion" in est["reason"] and "not given" in est["reason"]


def test_a_companion_that_restarts_where_the_run_did_not_is_replaced(monkeypatch):
    """The run's method's companion fails once where the run did not and goes on after
    choosing its rows again (Stepper.restart, faked here: it keeps its rows): its estimate
    would measure its own failure, so another method at the run's tolerance gives it, as
    for a companion that stops, and the summary says why."""
    step, restart = trajectory.Stepper.step, trajectory.Stepper.restart
    failed = []

    def failing_once(self):
        if (not failed and not isinstance(self, est_mod.CoarseStepper)
                and self.cls.name == "projection-dop853" and float(self.opt["rtol"]) < 1e-10):
            failed.append(self)
            return False, f"t = {self.solver.t:.6g} s: step size fell below h_min (test)"
        return step(self)

    def restarting(self, message):
        if self in failed:
            self.changes.append({"t": float(self.solver.t), "rank": 0, "redundant": [],
                                 "after": message})
            return True
        return restart(self, message)

    monkeypatch.setattr(trajectory.Stepper, "restart", restarting)
    from tests.integrators.test_changepoints import _run

    monkeypatch.setattr(trajectory.Stepper, "step", failing_once)
    res, err = _run(integrator="projection-dop853", rtol=1e-10, max_steps=2000)
    assert res.complete, res.message
    assert failed, "the companion at rtol/5 was not run"
    est = res.summary["error_estimate"]
    assert "with gcp-dop853 at rtol 1e-10" in est["method"], est
    assert "restarted" in est["method"] and "choosing its rows again" in est["method"]
    assert err / 10 <= est["position"] <= 10 * max(err, PASSAGE_FLOOR), (est["position"], err)


def test_restart_beyond_counts_only_the_companions_extra_restarts():
    """Restarts the run made too do not disqualify its companion; the first extra one is
    named with its time and the failure that caused it."""
    def traj(*times):
        run = type("Run", (), {})()
        run.changes = [{"t": t, "after": f"failure at {t}"} for t in times]
        out = trajectory.Trajectory()
        out.run = run
        return out

    assert est_mod.restart_beyond(traj(0.2), traj(0.2)) is None
    assert est_mod.restart_beyond(traj(), traj()) is None
    said = est_mod.restart_beyond(traj(0.2, 0.5), traj(0.2))
    assert "t = 0.5 s" in said and "failure at 0.5" in said


@pytest.mark.parametrize("name", ("pendulum", "slider_crank"))
@pytest.mark.parametrize("rtol", [1e-3, 1e-6], ids=["loose", "tight"])
def test_coarse_estimate_of_generalized_alpha_within_factor_10(name, rtol):
    """Generalized-alpha (p = 2 in positions and velocities on a given mesh, Arnold & Bruls
    2007) gets the coarse companion: 0.1 <= estimate / true <= 10 in position and
    orientation (measured 0.44-1.0 at rtol 1e-3 and 1e-6 on these two: the loose end is in
    the asymptotic regime only roughly, hence the low side)."""
    pb = M.reference_problem(name)
    res = run(pb, integrator="genalpha", rtol=rtol, atol=rtol * 1e-2)
    est = res.summary["error_estimate"]
    assert "coarsened by 2" in est["method"] and "p = 2" in est["method"]
    ref = pb.reference(res.t)
    pos = R.position_error(res, ref).max()
    assert pos > FLOOR
    assert 0.1 <= est["position"] / pos <= 10, (est["position"], pos)
    if pb.rotating:
        ori = R.orientation_error(res, ref).max()
        assert 0.1 <= est["orientation"] / ori <= 10, (est["orientation"], ori)


def test_generalized_alpha_with_redundant_constraints_gets_the_tighter_companion():
    """The four parallel cranks have redundant rows and pass flat positions, which
    generalized-alpha does not detect: at rtol 1e-3 the coarse companion left the branch
    there (est / true 24), so the companion at rtol/5 is used (measured 0.91), within 10x."""
    pb = M.reference_problem("parallel_fourbar")
    res = run(pb, integrator="genalpha", rtol=1e-3, atol=1e-5)
    est = res.summary["error_estimate"]
    assert "at rtol/5" in est["method"]
    pos = R.position_error(res, pb.reference(res.t)).max()
    assert 0.1 <= est["position"] / pos <= 10, (est["position"], pos)


@pytest.mark.parametrize("integrator", ["projection-dop853", "genalpha"])
def test_companion_samples_in_bulk_equal_its_interpolant(integrator):
    """interpolant_many (one C call for an RK step, a column of times for the Hermite
    interpolant of generalized-alpha) against the interpolant sampled one time at a time,
    after a step of the default (C) and of the index-3 integrator: the same arithmetic, so
    equal to round-off (1e-12 of the state's scale, about 5e3 machine epsilons)."""
    import numpy as np

    from mbsim.analyses.estimate import interpolant, interpolant_many
    from mbsim.analyses.trajectory import Stepper, integrator_class

    pb = M.reference_problem("slider_crank")
    cls = integrator_class(integrator)
    opt = {"rtol": 1e-6, "atol": 1e-8, "h0": None, "max_steps": 100}
    run = Stepper(pb.model, cls, opt, 0.0, pb.q0.copy(), pb.qd0.copy(), pb.t_end,
                  np.arange(pb.model.m))
    for _ in range(3):
        ok, msg = run.step()
        assert ok, msg
    s = run.solver
    times = np.linspace(s.t_old, s.t, 7)[1:-1]
    Q, QD = interpolant_many(s, times)
    dense = interpolant(s)
    for k, t in enumerate(times):
        q, qd = dense(t)[:2]
        scale = max(1.0, float(np.abs(q).max()), float(np.abs(qd).max()))
        assert np.abs(Q[k] - q).max() <= 1e-12 * scale
        assert np.abs(QD[k] - qd).max() <= 1e-12 * scale


def test_coarse_companion_leaves_the_runs_counters_as_they_were():
    """The coarse companion integrates on the run's own equations of motion (no second
    set-up); the run's counters (function evaluations, factorisations, ...) are the run's
    alone, as without an estimate."""
    pb = M.reference_problem("slider_crank")
    on = run(pb, rtol=1e-7, atol=1e-9)
    off = run(pb, rtol=1e-7, atol=1e-9, error_estimate=False)
    assert "coarsened by 2" in on.summary["error_estimate"]["method"]
    assert on.counters == off.counters
