"""The projection of the output samples on factors already made (mbsim/fast/step.c:
project_sample) against the projection on fresh factors at every sample (the stepper's
``REUSE_FACTOR`` off, as before).

Both put the same interpolated sample on the same constraint manifold: the positions to
max |Phi| <= proj_tol, the velocities onto Phi_q qd = nu at the projected q (the
Mt-orthogonal projection, the same point to round-off at the same q).  The positions differ
by the tangential part of the two iterations' corrections, of the size of the correction
(the interpolant's error, within the error test's scale atol + rtol |q| of the step) times
the simplified iteration's contraction (<= 1/2 by its guard); the velocities by the
projection's change with q over that difference.  So each output of the two runs agrees
within the step's error scale (atol + rtol |y| componentwise), and both meet the constraints
to the projection tolerance (positions) and to round-off (velocities: 16 eps of the terms'
size, step.c's VEL_ROUNDOFF, with a factor 4 for the residual's own evaluation here), or,
where the fresh projection itself is not at round-off (the four cranks' flat positions, a
change point, where the simplified iteration gives up and factors afresh), as well as it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mbsim.analyses.trajectory import Stepper
from mbsim.analyses.trajectory import initial_conditions as _initial
from mbsim.deck import load_deck
from mbsim.fast import stepper
from mbsim.integrators import INTEGRATORS
from mbsim.model import compile_model
from mbsim.options import deck_context
from tests.integrators import models as M

ROOT = Path(__file__).resolve().parents[2]
EPS = np.finfo(float).eps
OPTIONS = {"rtol": 1e-6, "atol": 1e-8}  # the decks' default tolerances
FRACTIONS = np.array([0.1, 0.35, 0.6, 0.85])  # output samples inside each step


def deck_state(name):
    model = compile_model(load_deck(ROOT / "models" / f"{name}.yaml"))
    spec = load_deck(ROOT / "models" / f"{name}.yaml")
    q, qd, _ = _initial(model, 0.0, {"tol": 1e-10}, deck_context(spec, shapes=False).hold)
    return model, q, qd


def problem_state(name):
    pb = M.reference_problem(name)
    return pb.model, pb.q0, pb.qd0


CASES = {
    "governor": lambda: deck_state("governor"),
    "slider_crank": lambda: problem_state("slider_crank"),
    "four_cranks": lambda: problem_state("parallel_fourbar"),  # passes flat positions
}


def solver(model, q, qd, method, reuse, monkeypatch, t_end):
    monkeypatch.setattr(stepper, "REUSE_FACTOR", reuse)
    st = Stepper(model, INTEGRATORS[method], dict(OPTIONS), 0.0, q.copy(), qd.copy(), t_end,
                 None)
    assert st.solver._compiled is not None
    return st.solver


def velocity_bound(system, q, qd, t):
    """16 eps (sum |Phi_q| max |qd| + |nu|) per active row, times 4 (module doc)."""
    tm = system.terms(q, t, jac=True, phi=False, nu=True)
    J = tm.jac.toarray() if hasattr(tm.jac, "toarray") else np.asarray(tm.jac)
    return 64 * EPS * (np.abs(J).sum(axis=1) * np.abs(qd).max() + np.abs(tm.nu))


@pytest.mark.parametrize("method", ["projection-dop853", "projection"])
@pytest.mark.parametrize("case", list(CASES))
def test_outputs_on_kept_factors_agree_with_fresh_factorizations(case, method, monkeypatch):
    model, q, qd = CASES[case]()
    t_end = 0.6
    a = solver(model, q, qd, method, True, monkeypatch, t_end)  # factors already made
    b = solver(model, q, qd, method, False, monkeypatch, t_end)  # fresh at every sample
    samples = 0
    worst_q = worst_qd = 0.0
    while a.t < t_end:
        assert a.step()[0] and b.step()[0]
        assert a.t == b.t and np.array_equal(a.y, b.y)  # the outputs never feed back
        times = a.t_old + FRACTIONS * (a.t - a.t_old)
        Qa, QDa, _ = a.dense_output_many(times)
        Qb, QDb, _ = b.dense_output_many(times)
        samples += times.size
        for k, t in enumerate(times):
            sq = OPTIONS["atol"] + OPTIONS["rtol"] * np.abs(Qb[k])
            sv = OPTIONS["atol"] + OPTIONS["rtol"] * np.abs(QDb[k])
            worst_q = max(worst_q, float(np.max(np.abs(Qa[k] - Qb[k]) / sq)))
            worst_qd = max(worst_qd, float(np.max(np.abs(QDa[k] - QDb[k]) / sv)))
            ph, v = a.system.residuals(Qa[k], QDa[k], t)
            assert np.abs(ph).max() <= a.proj_tol, (case, t)
            # at round-off, or no worse than the fresh projection's: at the four cranks' flat
            # positions S's raised pivot (kernels.c: PIVOT_FLOOR) leaves the fresh one at
            # ~1e-11, and the simplified iteration does not contract there (its fallback)
            vb = velocity_bound(a.system, Qa[k], QDa[k], t)
            vb = np.maximum(vb, 2 * np.abs(b.system.residuals(Qb[k], QDb[k], t)[1]
                                           [b.system.rows]))
            bad = np.abs(v[a.system.rows]) > vb
            assert not bad.any(), (case, t, np.abs(v[a.system.rows])[bad], vb[bad])
    print(f"{case} {method}: worst |dq| {worst_q:.3g}, |dqd| {worst_qd:.3g} of the error scale")
    assert worst_q <= 1.0 and worst_qd <= 1.0, (worst_q, worst_qd)
    counts = a._compiled.output_projections
    assert counts["kept"] + counts["fresh"] == 2 * samples  # q and qd of every sample
    assert b._compiled.output_projections == {"kept": 0, "fresh": 0}
    if case == "slider_crank":  # the light crank (J'_yy = 1e-5 kg m^2) turns ~0.1 rad per
        # step: on the end's factor the positions' residual grows ~100 x (step.c), far past
        # the guard's 1/2, so every sample's positions are projected on fresh factors
        assert counts["fresh"] >= samples
