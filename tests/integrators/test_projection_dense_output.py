"""The projection integrators' outputs through singular positions (issue 11).

The outputs between steps come from the RK interpolant, projected onto the constraints.  At
the four parallel cranks' flat positions (tests/integrators/test_singular_loops.py) an
extra DOP853 stage evaluated near the flat position gave, at rtol 1e-7, outputs 2.6e-4 m off
(2570 x rtol) with exact step ends; the dense output now checks the projection's nonlinear
part and integrates to the output where it exceeds the tolerance (index1.py,
Index1._dense_output_impl).  Asserted over a ladder of tolerances between the singular-loop
test's own (1e-6, 1e-8, 1e-10): the run completes, its position error against the exact
reduction is <= 10 rtol + 1e-9 m (the issue's bound) and its error estimate is within a
factor 10 of that error.  On a smooth deck no output is integrated to (the check costs
nothing there).
"""

import pytest

from mbsim.analyses.dynamic import dynamic
from mbsim.api import load_model
from mbsim.options import run_options
from tests.integrators.test_singular_loops import run

LADDER = (1e-3, 1e-4, 1e-5, 1e-7, 1e-9)
# Measured on this problem: DP5(4)'s global error grows like tol^(5/4)-ish at loose
# tolerances (2e-2 m at 1e-3, 1.03e-3 m at 1e-4, steady phase drift over 18-24 steps, not
# at the flat positions): tolerance proportionality, not the singular positions.
KNOWN = {("projection", 1e-3): "global error 20 x rtol (phase drift over 18 steps)",
         ("projection", 1e-4): "global error 10.3 x rtol (phase drift over 24 steps)"}


def cases():
    out = []
    for name in ("projection-dop853", "projection"):
        for rtol in LADDER:
            marks = []
            if (name, rtol) in KNOWN:
                marks.append(pytest.mark.xfail(reason=KNOWN[name, rtol], strict=True))
            out.append(pytest.param(name, rtol, id=f"{name}-{rtol:g}", marks=marks))
    return out


@pytest.mark.parametrize("name,rtol", cases())
def test_ladder_through_flat_positions(name, rtol):
    res, err = run(name, rtol)
    assert res.complete, res.message
    bound = 10 * rtol + 1e-9
    assert err <= bound, f"{name} rtol {rtol:g}: position error {err:.3g} m > {bound:.3g} m"
    est = res.summary["error_estimate"]["position"]
    assert 0.1 <= est / err <= 10, f"{name} rtol {rtol:g}: estimate {est:.3g}, true {err:.3g}"


def test_outputs_inside_the_step_over_the_flat_position():
    """rtol 1e-7 (the case of the issue's note): one 27 ms step crosses the first flat
    position; the outputs inside it (t = 0.08, 0.09, 0.10 s) are within 10 rtol of the
    reduction (an interpolant whose extra stages met the flat position left 2.6e-4 m there),
    and so is every other output."""
    from tests.integrators import models as M
    from tests.integrators import references as R

    res, _ = run("projection-dop853", 1e-7)
    pb = M.reference_problem("parallel_fourbar")
    err = R.position_error(res, pb.reference(res.t))
    inside = (res.t > 0.075) & (res.t < 0.105)
    assert inside.sum() == 3
    assert err.max() <= 1e-6, f"{err.max():.3g} m"


@pytest.mark.parametrize("deck,scene", [("models/governor.yaml", None),
                                        ("models/slider_crank.yaml", "free")])
def test_smooth_decks_interpolate(deck, scene):
    """Away from singular positions the projection of an interpolated state converges in one
    Newton step (or its later steps are far below the tolerance): no output is integrated
    to, so the default's CPU is unchanged."""
    spec, model = load_model(deck, scene=scene)
    res = dynamic(model, run_options("dynamic", spec, {"integrator": "projection-dop853",
                                                       "error_estimate": False}))
    assert res.complete, res.message
    assert res.counters["output_steps"] == 0
