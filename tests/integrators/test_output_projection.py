"""The output samples' velocities projected on the Schur factor their positions' Newton
step made (mbsim/fast/step.c: project_sample) against their projection on a fresh factor
(the stepper's ``REUSE_FACTOR`` off, as before).

The positions take the same Newton iteration in both: equal bit for bit.  The velocities
are put on Phi_q qd = nu at that q in both: the fresh projection Mt-orthogonally in one
solve; the simplified iteration, whose corrections lie in the range of Mt^-1 Phi_q^T at the
interpolated q (one positions' correction dq away), on a point that differs from it by the
change of that range over dq times the velocities' correction: second order in the
interpolant's error.  So the velocities agree within the projections' own tolerance, 1e-3
of the step's error scale (proj_tol = 1e-3 atol for the positions: Index1; measured <= 3e-5),
and both runs' outputs meet the constraints: max |Phi| <= proj_tol, and Phi_q qd - nu at
round-off (16 eps of the terms' size, step.c's VEL_ROUNDOFF, with a factor 4 for the
residual's own evaluation here) or, where the fresh projection itself is not at round-off
(the four cranks' flat positions, change points, where the simplified iteration does not
contract and the projection factors afresh), as well as it.
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


def chain_state(n):
    model = M.chain(n)
    return model, model.q0.copy(), np.zeros(model.nq)


CASES = {  # (state, t_end)
    "governor": (lambda: deck_state("governor"), 0.6),
    "slider_crank": (lambda: problem_state("slider_crank"), 0.6),
    "four_cranks": (lambda: problem_state("parallel_fourbar"), 0.6),  # passes flat positions
    "chain_40": (lambda: chain_state(40), 0.1),  # CSR Jacobians, the ground held (CROSS)
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
def test_velocities_on_the_positions_factor_agree_with_a_fresh_factorization(case, method,
                                                                             monkeypatch):
    state, t_end = CASES[case]
    model, q, qd = state()
    a = solver(model, q, qd, method, True, monkeypatch, t_end)  # on the positions' factor
    b = solver(model, q, qd, method, False, monkeypatch, t_end)  # on a fresh factor
    samples = 0
    worst_qd = 0.0
    while a.t < t_end:
        assert a.step()[0] and b.step()[0]
        assert a.t == b.t and np.array_equal(a.y, b.y)  # the outputs never feed back
        times = a.t_old + FRACTIONS * (a.t - a.t_old)
        Qa, QDa, _ = a.dense_output_many(times)
        Qb, QDb, _ = b.dense_output_many(times)
        samples += times.size
        assert np.array_equal(Qa, Qb)  # the same Newton iteration
        for k, t in enumerate(times):
            sv = OPTIONS["atol"] + OPTIONS["rtol"] * np.abs(QDb[k])
            worst_qd = max(worst_qd, float(np.max(np.abs(QDa[k] - QDb[k]) / sv)))
            ph, v = a.system.residuals(Qa[k], QDa[k], t)
            assert np.abs(ph).max() <= a.proj_tol, (case, t)
            vb = velocity_bound(a.system, Qa[k], QDa[k], t)
            vb = np.maximum(vb, 2 * np.abs(b.system.residuals(Qb[k], QDb[k], t)[1]
                                           [b.system.rows]))
            bad = np.abs(v[a.system.rows]) > vb
            assert not bad.any(), (case, t, np.abs(v[a.system.rows])[bad], vb[bad])
    counts = a._compiled.output_projections
    print(f"{case} {method}: worst |dqd| {worst_qd:.3g} of the error scale, {counts}")
    assert worst_qd <= 1e-3
    assert counts["kept"] + counts["fresh"] == samples
    assert b._compiled.output_projections == {"kept": 0, "fresh": 0}
