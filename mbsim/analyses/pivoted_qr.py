"""QR with column pivoting in numpy alone (Businger and Golub 1965), for the rank test.

The rank test (:func:`mbsim.analyses.common.rank_and_redundant` with ``lapack=False``, what
`mbsim check`'s assembly calls; runs keep LAPACK's, see there) factors
Phi_q^T (nq, m) as Phi_q^T P = Q R and reports the constraint rows P[rank:] as redundant.
scipy.linalg.qr(pivoting=True) (LAPACK dgeqp3) costs about 0.4 s to import, more than the
whole `mbsim check` of a small deck, so this module does the same factorization with numpy:
Householder reflections, the column of largest remaining norm brought forward at each
step (the first of equals, as idamax), and the remaining column norms downdated as LAPACK's
dlaqp2 does (recomputed when cancellation has eaten half their digits).  The pivot order,
and with it the rows reported redundant, is then LAPACK's wherever one column's norm is
the largest.  Where several are equal in exact arithmetic (the rows of a symmetric
mechanism), the last bits of the computed norms decide, and the runs past singular
positions are sensitive to which of the equivalent rows are dropped (the parallel
four-bar's accuracy at rtol 1e-10, tests/integrators/test_singular_loops.py), so the
arithmetic follows LAPACK's and OpenBLAS's where numpy allows: norms summed in extended
precision (OpenBLAS's x86-64 dnrm2 kernel uses the x87 unit), dlapy2's hypotenuse, the
reflector scaled by a reciprocal (dscal), its application as dgemv then dger.  Fused
multiply-adds in OpenBLAS's kernels are not reproduced: the last bits still differ, and
ties may still go another way (tests/analyses/test_pivoted_qr.py checks that the pivots
differ from LAPACK's only at ties, and that the rows kept are independent).

Cost O(n m min(n, m)) flops with one Python-level step per column; meant for the dense
set-up below DENSE_NQ coordinates: 0.005 s for a 100 x 100 matrix, 0.08 s for 400 x 400
(LAPACK: 0.0004 and 0.006 s; measured with the test suite running on the 2 CPUs).
"""

from __future__ import annotations

import numpy as np

TOL3Z = float(np.sqrt(np.finfo(float).eps))
"""Relative size below which a downdated column norm is recomputed (LAPACK dlaqp2's tol3z)."""


def qr_pivoted_r(a):
    """Upper-trapezoidal R and pivots of a P = Q R by Householder QR with column pivoting.

    Parameters
    ----------
    a : (n, m) array_like, real.

    Returns
    -------
    R : (min(n, m), m) upper trapezoidal; |diag(R)| non-increasing.
    piv : (m,) int, the column permutation P as indices: column k of a P is a[:, piv[k]].

    The same contract as ``scipy.linalg.qr(a, mode="r", pivoting=True)`` up to the signs of
    the rows of R (Golub and Van Loan, Matrix Computations, 4th ed., Alg. 5.4.1).
    """
    A = np.array(a, dtype=float, order="F", copy=True)
    if not np.isfinite(A).all():  # as scipy's check_finite: the caller reports the overflow
        raise ValueError("array must not contain infs or NaNs")
    n, m = A.shape
    k = min(n, m)
    piv = np.arange(m)
    vn1 = _nrm2(A)  # (m,) downdated norms of the remaining columns
    vn2 = vn1.copy()  # (m,) the norms when last computed exactly
    for i in range(k):
        p = i + int(np.argmax(vn1[i:]))  # the first of equals, as LAPACK's idamax
        if p != i:
            A[:, [i, p]] = A[:, [p, i]]
            piv[[i, p]] = piv[[p, i]]
            vn1[p], vn2[p] = vn1[i], vn2[i]
        # Householder reflector H = I - tau v v^T with H x = beta e1 (LAPACK dlarfg)
        x = A[i:, i]
        alpha = x[0]
        xnorm = _nrm2(x[1:, None])[0] if x.size > 1 else 0.0
        if xnorm == 0.0:
            tau = 0.0  # already upper triangular in this column: H = I
        else:
            beta = -np.copysign(_lapy2(alpha, xnorm), alpha)
            tau = (beta - alpha) / beta
            v = x * (1.0 / (alpha - beta))  # dscal by the reciprocal, as dlarfg
            v[0] = 1.0
            A[i, i] = beta
            A[i + 1:, i] = 0.0
            if i + 1 < m:
                B = A[i:, i + 1:]
                B += np.outer(v, -tau * (v @ B))  # dlarf: w = B^T v, then dger
        if i + 1 < m:
            _downdate_norms(A, vn1, vn2, i)
    return np.triu(A[:k, :]), piv


def _lapy2(x, y):
    """sqrt(x^2 + y^2) without overflow, rounded as LAPACK's dlapy2."""
    w, z = max(abs(x), abs(y)), min(abs(x), abs(y))
    return w if z == 0.0 else w * np.sqrt(1.0 + (z / w) ** 2)


def _nrm2(a):
    """Column norms of a summed in extended precision (x87 long double, as OpenBLAS's
    x86-64 dnrm2 kernel), rounded once to double."""
    x = a.astype(np.longdouble)
    return np.sqrt((x * x).sum(axis=0)).astype(float)


def _downdate_norms(A, vn1, vn2, i):
    """Norms of the columns i+1.. of A below row i, downdated by the row i just finished
    (LAPACK dlaqp2): vn1 <- vn1 sqrt(1 - (a_ij / vn1)^2), recomputed from A when the
    downdate has lost too much relative to the last exact norm vn2."""
    j = np.arange(i + 1, A.shape[1])
    live = vn1[j] != 0.0
    j = j[live]
    if j.size == 0:
        return
    temp = np.maximum(1.0 - (np.abs(A[i, j]) / vn1[j]) ** 2, 0.0)
    temp2 = temp * (vn1[j] / vn2[j]) ** 2
    again = temp2 <= TOL3Z
    if i + 1 < A.shape[0]:
        exact = _nrm2(A[i + 1:, j[again]])
    else:
        exact = np.zeros(int(again.sum()))
    vn1[j[again]] = exact
    vn2[j[again]] = exact
    vn1[j[~again]] *= np.sqrt(temp[~again])
