"""The dropped rows' dependency C (J[red] = C J[act]) of a sparse Phi_q by one sparse LU of
the augmented system (mbsim/analyses/redundancy.py: dependency, _dependency_sparse), against
numpy's dense lstsq (SVD) of the same rows.

Both are backward-stable solutions of a consistent full-rank least-squares problem, so they
differ by a few u cond(J[act]) relative (u = 1.1e-16; cond 8e3 on the 40-loop four-bar):
the bound is 100 u cond, and at least 1e-12.  A set of "active" rows that depend on each
other falls back to the dense lstsq (its minimum-norm answer)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from mbsim import core
from mbsim.analyses import redundancy
from mbsim.analyses.assembly import assemble
from tests.integrators import models as M

U = np.finfo(float).eps / 2


def _dense_dependency(J, red, act):
    return np.linalg.lstsq(J[act].T, J[red].T, rcond=None)[0].T


def _fourbar(n_cranks, th):
    model = M.parallel_fourbar(n_cranks)
    q0, _ = M.parallel_fourbar_state(model, 20.0)
    q = M.parallel_fourbar_motion(model, th, 0.0, 0.0)[0] if th is not None else q0
    J = core.phi_q(model, None, q, 0.0, sparse=True)
    act = assemble(model, q).active_rows  # a run's rows (mbsim's pivoted QR: reproducible)
    red = np.setdiff1d(np.arange(J.shape[0]), act)
    return J, act, red


def test_sparse_dependency_equals_the_dense_lstsq_on_forty_loops():
    J, act, red = _fourbar(41, None)
    assert sp.issparse(J) and red.size > 100  # the four-bar's 159 dropped rows
    Jd = J.toarray()
    C = redundancy.dependency(J, red, act)
    C_ref = _dense_dependency(Jd, red, act)
    tol = max(100 * U * np.linalg.cond(Jd[act]), 1e-12)
    assert C.shape == (red.size, act.size)
    assert np.abs(C - C_ref).max() <= tol * np.abs(C_ref).max()
    # the dependency itself: J[red] = C J[act] to round-off of J's entries
    assert np.abs(C @ Jd[act] - Jd[red]).max() <= tol * np.abs(Jd).max()


@pytest.mark.parametrize("th", [1e-3, 1e-5, 1e-6])
def test_sparse_dependency_near_the_flat_position(th):
    # cranks th rad from the ground line: the active rows' condition grows as 1 / th (3e4 to
    # 3e7); with its refinement the sparse solve still agrees with the SVD to u cond
    J, act, red = _fourbar(4, th)
    Jd = J.toarray()
    C = redundancy.dependency(J, red, act)
    C_ref = _dense_dependency(Jd, red, act)
    tol = max(100 * U * np.linalg.cond(Jd[act]), 1e-12)
    assert np.abs(C - C_ref).max() <= tol * max(np.abs(C_ref).max(), 1.0)


@pytest.mark.parametrize("th", [None, 1e-3, 1e-6])
def test_dependent_active_rows_fall_back_to_the_dense_lstsq(th):
    # a dropped row among the active ones: they depend on each other, the least-squares
    # solution is not unique, and the answer is the SVD's minimum-norm one
    J, act, red = _fourbar(4, th)
    act_bad = np.sort(np.concatenate([act, red[:1]]))
    red_bad = red[1:]
    assert redundancy._dependency_sparse(J, red_bad, act_bad) is None
    C = redundancy.dependency(J, red_bad, act_bad)
    np.testing.assert_array_equal(C, _dense_dependency(J.toarray(), red_bad, act_bad))


def test_no_dropped_rows_give_an_empty_dependency():
    J, act, _ = _fourbar(41, None)
    assert redundancy.dependency(J, np.zeros(0, int), act).shape == (0, act.size)


def test_a_dense_jacobian_of_many_coordinates_takes_the_sparse_solve(monkeypatch):
    # set-up passes a dense Phi_q below DENSE_NQ (nq 301 here): from DEPENDENCY_SPARSE_NQ on
    # it is solved sparse all the same; the sparse J's stored zeros change the LU's order,
    # so the two agree to round-off
    J, act, red = _fourbar(41, None)
    assert J.shape[1] >= redundancy.DEPENDENCY_SPARSE_NQ
    calls = []
    sparse = redundancy._dependency_sparse
    monkeypatch.setattr(redundancy, "_dependency_sparse",
                        lambda *a: calls.append(1) or sparse(*a))
    np.testing.assert_allclose(redundancy.dependency(J.toarray(), red, act),
                               redundancy.dependency(J, red, act), rtol=0, atol=1e-12)
    assert len(calls) == 2

