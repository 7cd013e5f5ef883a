"""Baumgarte's drift bound (mbsim/integrators/index1.py: Baumgarte) through singular positions.

The four parallel cranks of issue 11 (tests/integrators/models.py: parallel_fourbar) pass
their flat positions at t = 0.083 and 0.297 s in the first 0.5 s.  The equations of motion
see 41 independent rows of the 52; their solution set crosses another branch there (the
coupler rotating), which the 11 redundant rows forbid.  The monitors measure the violation on
all 52 rows, so they show whether the run stayed on the mechanism's own motion.
"""


from mbsim.analyses.dynamic import dynamic
from tests.integrators import models as M
from tests.integrators import references as R

RTOL = 1e-10  # a tight tolerance: fine steps resolve the turn onto the other branch


def run(drift_bound):
    pb = M.reference_problem("parallel_fourbar")
    res = dynamic(pb.model, {"t_end": 0.5, "step": pb.step, "q0": pb.q0, "qd0": pb.qd0,
                             "integrator": "baumgarte", "rtol": RTOL, "atol": 1e-2 * RTOL,
                             "drift_bound": drift_bound, "error_estimate": False})
    return pb, res


def test_drift_bound_keeps_every_row_through_flat_positions():
    """With the bound, the violation of all 52 rows (the 11 redundant ones included, which
    the equations never see) stays within 10 rtol: 10 x the tolerance on positions of
    size ~1 m (measured 1e-11 m), on velocities 10 rtol x the tip speed L thetad = 4 m/s
    (measured 3e-10 m/s); the position error against the exact reduction is within the
    bound of issue 11, 10 rtol + 1e-9 m."""
    pb, res = run(True)
    assert res.complete, res.message
    speed = 0.2 * 20.0  # m/s, crank tip: L thetad0 (the speed at the bottom, the largest)
    assert res.channel("monitors/position_violation").data.max() <= 10 * RTOL
    assert res.channel("monitors/velocity_violation").data.max() <= 10 * RTOL * speed
    assert R.position_error(res, pb.reference(res.t)).max() <= 10 * RTOL + 1e-9
    assert res.counters["drift_projections"] > 0  # the passages did need it


def test_without_the_bound_the_run_leaves_the_mechanism_and_says_so():
    """The same run without the bound (Baumgarte 1972 alone) drifts at the flat position of
    t = 0.297 s (the rows open to 1e-5, 1e5 times the tolerance) and follows the drifted
    constraint set onto the other branch (the motion 7 mm off at 0.32 s).  That is never a
    silent result: the run ends at the first output past the drift limit (1000 x the
    tolerance) or where the redundant rows stop holding, naming it, and the outputs before
    it are the mechanism's motion (within 1e-8 m of the exact reduction: the first passage
    at 0.083 s costs 2.6e-9 m without the bound)."""
    pb, res = run(False)
    assert not res.complete
    # either check may see it first: the drift over 1000 x the tolerance, or the redundant
    # rows no longer holding where the independent ones do (both: left the mechanism)
    assert "constraint drift" in res.message or "no longer hold" in res.message, res.message
    assert 0.28 < res.t[-1] < 0.31  # the output of t = 0.30 s is past the limit
    assert res.channel("monitors/position_violation").data.max() <= 1e3 * (RTOL + 1e-2 * RTOL)
    assert R.position_error(res, pb.reference(res.t)).max() <= 1e-8
