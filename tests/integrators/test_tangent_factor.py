"""The tangent completion's matrix A = [Phi_q; C] (mbsim/integrators/changepoints.py:
factor, stacked): built from the CSR arrays, it is sp.vstack's matrix entry for entry, so
the LU and every completion are unchanged to the bit."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from mbsim.integrators import changepoints as cp

rng = np.random.default_rng(40)


def _random_csr(m, n, density):
    J = sp.random(m, n, density=density, format="csr", random_state=rng)
    J.data[:] = rng.normal(size=J.nnz)
    return J


def test_stacked_equals_vstack_entry_for_entry():
    for m, n, k in ((300, 301, 1), (40, 42, 2), (5, 9, 4)):
        J = _random_csr(m, n, 0.05)
        C = np.zeros((k, n))
        C[rng.integers(k, size=2 * k), rng.integers(n, size=2 * k)] = rng.normal(size=2 * k)
        A = cp.stacked(J, C)
        ref = sp.vstack([J, sp.csr_matrix(C)], format="csr")
        assert A.format == "csr" and A.shape == (m + k, n)
        np.testing.assert_array_equal(A.toarray(), ref.toarray())
        np.testing.assert_array_equal(A.tocsc().indptr, ref.tocsc().indptr)


def test_stacked_takes_a_non_csr_jacobian():
    J = _random_csr(6, 8, 0.3).tocsc()
    C = rng.normal(size=(2, 8))
    np.testing.assert_array_equal(cp.stacked(J, C).toarray(), np.vstack([J.toarray(), C]))
