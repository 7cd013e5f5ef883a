"""The Schur complement S = Phi_q Mt^-1 Phi_q^T assembled body by body.

Every Jacobian row touches one or two bodies; its (row, body) piece is a 7-vector (the
fused evaluator's value buffer, :meth:`FusedConstraints.pieces`).  Gathering the pieces of
each body into Jb (nb, r, 7) (r: the most rows touching one body, padded with zeros) gives,
with the block inverse B (nb, 7, 7) of the modified mass matrix,

    S = sum_b Jb_b B_b Jb_b^T          (one batched product, scattered into S),
    Phi_q x = rows of Jb_b x_b,        Phi_q^T y = Jb_b^T y_b,

so no (m x nq) matrix is ever formed or multiplied.  S keeps a fixed pattern; ordered once
by reverse Cuthill-McKee it is banded for chains and trees (bandwidth w), and is factored by
banded Cholesky (LAPACK pbtrf, O(m w^2)) when w < m / 4, else densely.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee


class SolveError(Exception):
    """A factorisation that failed inside a step (the integrator turns it into a message)."""


class BlockSchur:
    """Compiled body-block layout of the active rows (module doc).

    rows, bodies: (P,) pieces; active: (m_a,) active global rows; nb bodies."""

    def __init__(self, rows, bodies, active, nb, m_total):
        pos = np.full(m_total, -1)
        pos[active] = np.arange(active.size)
        keep = pos[rows] >= 0
        self.keep = np.flatnonzero(keep)  # pieces on active rows
        r, b = pos[rows[keep]], bodies[keep]
        self.m, self.nb = active.size, nb
        slot = np.zeros(r.size, dtype=int)
        count = np.zeros(nb, dtype=int)
        for p in range(r.size):  # slot of each piece within its body
            slot[p] = count[b[p]]
            count[b[p]] += 1
        self.R = int(count.max(initial=1))
        self.gather = b * self.R + slot  # piece -> flat (nb * R) position
        row_of = np.full(nb * self.R, self.m)  # padding -> a dummy row m
        row_of[self.gather] = r
        self.row_of = row_of  # (nb * R,) row of each padded slot
        # pairs (i, j) of rows sharing a body
        ri = row_of.reshape(nb, self.R, 1).repeat(self.R, 2).reshape(-1)
        rj = row_of.reshape(nb, 1, self.R).repeat(self.R, 1).reshape(-1)
        valid = (ri < self.m) & (rj < self.m)
        pattern = sp.csr_matrix((np.ones(valid.sum()), (ri[valid], rj[valid])),
                                shape=(self.m, self.m))
        perm = reverse_cuthill_mckee(pattern, symmetric_mode=True) if self.m else np.zeros(0, int)
        inv = np.empty_like(perm)
        inv[perm] = np.arange(perm.size)
        pi, pj = inv[np.minimum(ri, self.m - 1)], inv[np.minimum(rj, self.m - 1)]
        w = int(np.abs(pi - pj)[valid].max(initial=0))
        self.banded = self.m > 40 and w < self.m / 4
        self.perm, self.inv, self.w = perm, inv, w
        lower = valid & (pi >= pj)
        if self.banded:  # lower banded storage ab[i - j, j] (of the permuted S)
            self.s_index = np.where(lower, (pi - pj) * self.m + pj, (w + 1) * self.m)
            self.s_size = (w + 1) * self.m
        else:
            self.s_index = np.where(valid, pi * self.m + pj, self.m * self.m)
            self.s_size = self.m * self.m

    # -- products with Phi_q ----------------------------------------------------------------
    def blocks(self, vals):
        """Jb (nb, R, 7) from the fused value buffer (all pieces)."""
        Jb = np.zeros((self.nb * self.R, 7))
        Jb[self.gather] = vals.reshape(-1, 7)[self.keep]
        return Jb.reshape(self.nb, self.R, 7)

    def jac_times(self, Jb, x):
        """Phi_q x (m_a,) for x (nq,)."""
        y = np.matmul(Jb, x.reshape(self.nb, 7, 1)).reshape(-1)
        return np.bincount(self.row_of, y, minlength=self.m + 1)[: self.m]

    def jac_t_times(self, Jb, lam):
        """Phi_q^T lam (nb, 7) for lam (m_a,)."""
        lp = np.append(lam, 0.0)[self.row_of].reshape(self.nb, 1, self.R)
        return np.matmul(lp, Jb)[:, 0, :]

    # -- S and its solution -------------------------------------------------------------------
    def solve(self, Jb, B, rhs):
        """x with S x = rhs, S = Phi_q Mt^-1 Phi_q^T (B: (nb, 7, 7) blocks of Mt^-1)."""
        Sb = np.matmul(np.matmul(Jb, B), Jb.transpose(0, 2, 1))
        data = np.bincount(self.s_index, Sb.reshape(-1), minlength=self.s_size + 1)
        data = data[: self.s_size]
        try:
            if self.banded:
                ab = data.reshape(self.w + 1, self.m)
                x = la.solveh_banded(ab, rhs[self.perm], lower=True, check_finite=False)
            else:
                S = data.reshape(self.m, self.m)
                x = np.linalg.solve(S, rhs[self.perm])
        except (la.LinAlgError, np.linalg.LinAlgError, ValueError) as exc:
            raise SolveError("singular constraint Jacobian (Phi_q M^-1 Phi_q^T not "
                             "positive definite)") from exc
        return x[self.inv]
