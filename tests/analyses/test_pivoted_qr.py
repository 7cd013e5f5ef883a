"""The numpy QR with column pivoting (mbsim.analyses.pivoted_qr) against LAPACK's dgeqp3
(scipy.linalg.qr(pivoting=True)): the same pivot rule (largest remaining column norm, the
first of equals), hence the same rank and the same rows reported redundant, on every deck
and on matrices built to test the rule.

Where several columns have norms equal in exact arithmetic (the rows of a symmetric
mechanism), the last bits of the computed norms decide, in LAPACK as here, and the pivots
may differ.  The tests then check that the first differing pivot is such a tie: both
columns' remaining norms, recomputed from scratch after the common leading pivots, equal to
1e-12 of the largest (round-off of norms of order one is 1e-15; a genuine choice between
constraint rows differs by far more), and that the rows each keeps are independent.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as la

from mbsim import core
from mbsim.analyses.assembly import assemble
from mbsim.analyses.common import DENSE_NQ, _geqp3_pivots, rank_and_redundant
from mbsim.analyses.pivoted_qr import qr_pivoted_r
from mbsim.api import load_model
from mbsim.options import deck_context

ROOT = Path(__file__).resolve().parents[2]
DECKS = sorted((ROOT / "models").glob("*.yaml")) + \
    sorted((ROOT / "tests" / "analyses" / "data").glob("*.yaml"))
TOL = 1e-9  # rank_and_redundant's default: pivots below 1e-9 of the largest are rank loss
TIE = 1e-12  # relative: remaining norms this close are equal in exact arithmetic


def remaining_norms(a, lead):
    """Norms of a's columns after projecting out the columns ``lead`` (exact, by SVD)."""
    if len(lead) == 0:
        return np.linalg.norm(a, axis=0)
    U, s, _ = np.linalg.svd(a[:, lead], full_matrices=False)
    U = U[:, s > TOL * s[0]]
    return np.linalg.norm(a - U @ (U.T @ a), axis=0)


def assert_lapacks_pivots_up_to_ties(a, rank):
    """The first ``rank`` pivots of a's numpy QR are LAPACK's, except where a tie decided."""
    _, piv = qr_pivoted_r(a)
    _, piv_ref = la.qr(a, mode="r", pivoting=True)
    k = next((i for i in range(rank) if piv[i] != piv_ref[i]), None)
    if k is None:
        return False
    n = remaining_norms(a, piv[:k])
    assert abs(n[piv[k]] - n[piv_ref[k]]) <= TIE * n.max(), (k, n[piv[k]], n[piv_ref[k]])
    return True


@pytest.mark.parametrize("deck", DECKS, ids=lambda p: p.name)
def test_the_rows_reported_redundant_are_lapacks_on_every_deck(deck):
    """At the deck's estimates and at the assembled position: LAPACK's rank; LAPACK's
    redundant rows, or rows differing only where a tie decided; |diag R| equal to LAPACK's
    to 1e-12 of the largest where the pivots are the same; the rows kept independent."""
    spec, model = load_model(deck)
    assert model.nq < DENSE_NQ  # the decks are small: the dense path is the one tested
    hold = deck_context(spec, shapes=False).hold  # the deck's analysis.assembly.hold
    for q in (model.q0, assemble(model, hold=hold).q):
        J = core.phi_q(model, None, q, 0.0, sparse=False)
        rank, red = rank_and_redundant(model, J, lapack=False)
        R_ref, piv_ref = la.qr(J.T, mode="r", pivoting=True)
        d_ref = np.abs(np.diag(R_ref))
        assert rank == int(np.sum(d_ref > TOL * d_ref[0]))
        tied = assert_lapacks_pivots_up_to_ties(J.T, rank)
        if not tied:
            assert list(red) == sorted(piv_ref[rank:])
            d = np.abs(np.diag(qr_pivoted_r(J.T)[0]))
            np.testing.assert_allclose(d[:rank], d_ref[:rank], rtol=0, atol=1e-12 * d_ref[0])
        s = np.linalg.svd(np.delete(J, red, axis=0), compute_uv=False)
        assert s[-1] > TOL * s[0]


def test_pivots_and_r_are_lapacks_on_matrices_without_ties():
    """Random tall, wide and rank-deficient matrices: LAPACK's pivots, and R's leading
    rank x rank block to 1e-12 of the largest entry (columns past the rank are ordered by
    round-off)."""
    rng = np.random.default_rng(24)
    low_rank = rng.standard_normal((40, 20)) @ rng.standard_normal((20, 35))
    for a in (rng.standard_normal((30, 12)), rng.standard_normal((12, 30)), low_rank,
              np.hstack([low_rank, 3 * low_rank[:, :5]])):
        R, piv = qr_pivoted_r(a)
        R_ref, piv_ref = la.qr(a, mode="r", pivoting=True)
        rank = int(np.sum(np.abs(np.diag(R_ref)) > TOL * abs(R_ref[0, 0])))
        assert list(piv[:rank]) == list(piv_ref[:rank])
        assert int(np.sum(np.abs(np.diag(R)) > TOL * abs(R[0, 0]))) == rank
        np.testing.assert_allclose(np.abs(R[:rank, :rank]), np.abs(R_ref[:rank, :rank]),
                                   rtol=0, atol=1e-12 * abs(R_ref[0, 0]))
        # a P = Q R with Q orthogonal: R's columns have the norms of a's
        np.testing.assert_allclose(np.linalg.norm(R, axis=0),
                                   np.linalg.norm(a[:, piv], axis=0), rtol=1e-13)


def test_the_first_of_exactly_equal_columns_is_taken():
    """Bitwise-equal norms: the first column, as LAPACK's idamax."""
    assert list(qr_pivoted_r(np.eye(6))[1]) == list(range(6))
    assert qr_pivoted_r(np.ones((5, 5)))[1][0] == 0
    a = np.zeros((4, 3))
    a[0, 1] = a[1, 2] = 2.0
    assert list(qr_pivoted_r(a)[1]) == [1, 2, 0]


@pytest.mark.parametrize("deck", DECKS, ids=lambda p: p.name)
def test_the_runs_rank_check_is_scipys_qr_to_the_bit_on_every_deck(deck):
    """rank_and_redundant(lapack=True) calls LAPACK's dgeqp3 directly
    (common._geqp3_pivots): the routine and workspace size scipy.linalg.qr uses, so |diag R|
    and the pivots equal scipy's bit for bit (a run's rows must not depend on the shortcut),
    and the rank and redundant rows are those of scipy's R at the test's tolerance."""
    spec, model = load_model(deck)
    hold = deck_context(spec, shapes=False).hold
    for q in (model.q0, assemble(model, hold=hold).q):
        J = core.phi_q(model, None, q, 0.0, sparse=False)
        d, piv = _geqp3_pivots(J.T)
        R_ref, piv_ref = la.qr(J.T, mode="r", pivoting=True)
        d_ref = np.abs(np.diag(R_ref))
        assert np.array_equal(d, d_ref) and np.array_equal(piv, piv_ref)
        rank, red = rank_and_redundant(model, J)
        assert rank == int(np.sum(d_ref > TOL * d_ref[0]))
        assert list(red) == sorted(piv_ref[rank:])


def test_the_runs_rank_check_rejects_what_scipy_rejects():
    """A Jacobian with NaN is a ValueError, as in scipy.linalg.qr (check_finite)."""
    with pytest.raises(ValueError):
        _geqp3_pivots(np.array([[1.0, np.nan], [0.0, 1.0]]))
