"""Bodies held by their own rows left out of the Schur matrix (mbsim/fast/dynamics.py:
held_bodies, schur_structure; kernels.c: held_coupling, fixed_body_multipliers).

The 40-loop parallel four-bar (tests/integrators/models.py: parallel_fourbar(41), nq = 301,
the sparse path) is the model that takes the cut structure: its ground carries 41 pivots.
Against the numpy reference (tests/reference/equations.py, dense KKT solve) and a dense
mass-weighted least-norm correction, with the bound of tests/test_kernels.py (10 u cond of
the matrix factored, at least 1e-10 relative):

- q off the constraints by 1e-6 and qd random, the ground included: a held body that moves
  (qdd_ground from its own rows, gamma of its normalisation row not zero) exercises the
  coupling of the other rows to it; qdd and lam on every active row, the ground's own rows'
  multipliers (reactions of the 41 pivots) included;
- the projection's correction Mt^-1 Phi_q^T S^-1 rhs for a random rhs: the held body's own
  rows fix its part (they are square on its 7 coordinates), so the least-norm correction
  of the cut structure is the full one;
- a model where the cut does not halve the envelope (a 16-link chain) keeps RCM's structure;
  with the cut forced (HELD_GAIN 0: the ground's spherical joint out of S) the chain's
  accelerations still match the reference, and the plain structure's to round-off.
"""

from __future__ import annotations

import numpy as np

from mbsim import fast
from mbsim.fast.dynamics import CROSS
from tests.integrators import models as M
from tests.reference import equations as eq
from tests.test_kernels import _close, _independent_rows, _modified_mass, _solve_tolerance

rng = np.random.default_rng(2411)


def _fourbar41():
    model = M.parallel_fourbar(41)
    q0, _ = M.parallel_fourbar_state(model, 20.0)
    q = q0 + 1e-6 * rng.normal(size=model.nq)
    qd = 0.1 * rng.normal(size=model.nq)
    # the rows independent on the linkage (at q0, as a run chooses them): at q they stay
    # well conditioned (chosen at q, the redundant rows' 1e-6 residue would count as rank)
    return model, q, qd, _independent_rows(model, q0)


def test_forty_loops_take_the_held_structure_and_match_the_reference():
    model, q, qd, rows = _fourbar41()
    system = fast.System(model, rows)
    assert system.sparse and np.any(system.inc[:, 1] >= CROSS)  # the cut structure
    qdd_ref, lam_ref = eq.accelerations(model, q, qd, 0.3, rows=rows)
    tol = _solve_tolerance(model, q, 0.3, rows, system)
    for _ in range(2):  # a second call: nothing stale reused
        qdd, lam, _power = system.accelerations(q, qd, 0.3)
        _close(qdd, qdd_ref, tol)
        _close(system.full_lam(lam), lam_ref, tol)


def test_held_structure_projection_is_the_least_norm_correction():
    model, q, _, rows = _fourbar41()
    system = fast.System(model, rows)
    rhs = rng.normal(size=rows.size)
    system.fc.compact(q, 0.0, jac=True)  # Phi_q at q, as project_positions leaves it
    dq = system._correction(rhs).copy()
    J = eq.constraints(model, q, 0.0).jac[rows]
    Mi = np.linalg.inv(_modified_mass(model, q))
    ref = Mi @ J.T @ np.linalg.solve(J @ Mi @ J.T, rhs)
    _close(dq, ref, _solve_tolerance(model, q, 0.0, rows, system))


def test_a_chain_keeps_its_structure():
    model = M.chain(40)  # nq = 287: the sparse path; one link on the ground
    system = fast.System(model)
    assert system.sparse and not np.any(system.inc[:, 1] >= CROSS)


def test_a_chain_with_the_cut_forced_matches_the_reference(monkeypatch):
    """The chain's ground (6 ground rows, its normalisation, the first spherical joint's 3
    entries) cut out of S although it does not pay (HELD_GAIN 0), at a state where the
    ground moves (qd random on every body): qdd and lam against the dense KKT reference, and
    against the plain structure, with test_kernels.py's bound."""
    from mbsim.fast import dynamics

    plain_model, cut_model = M.chain(40), M.chain(40)  # two models: two table caches
    plain = fast.System(plain_model)
    monkeypatch.setattr(dynamics, "HELD_GAIN", 0.0)
    cut = fast.System(cut_model)
    assert cut.sparse and np.count_nonzero(cut.inc[:, 1] >= CROSS) == 3
    assert not np.any(plain.inc[:, 1] >= CROSS)
    q = cut_model.q0 + 1e-6 * rng.normal(size=cut_model.nq)
    qd = 0.1 * rng.normal(size=cut_model.nq)
    qdd_ref, lam_ref = eq.accelerations(cut_model, q, qd, 0.1)
    tol = _solve_tolerance(cut_model, q, 0.1, None, cut)
    qdd, lam, _ = cut.accelerations(q, qd, 0.1)
    _close(qdd, qdd_ref, tol)
    _close(cut.full_lam(lam), lam_ref, tol)
    qdd_p, lam_p, _ = plain.accelerations(q, qd, 0.1)
    _close(qdd, qdd_p, tol)
    _close(lam, lam_p, tol)
