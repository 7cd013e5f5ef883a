"""The constrained equations of motion as the integrators see them, with counters.

Equations of motion (Haug eq. 11.1.x, Euler-parameter form):

    M(q) qdd + Phi_q^T lam = Q(q, qd, t),    Phi_q qdd = gamma(q, qd, t)

solved by the Schur complement of a *modified* mass matrix.  The Euler-parameter block
M_p = 4 G^T J' G is singular along p; the normalisation row p^T p = 1 fixes p^T pdd =
gamma_norm / 2, so adding c p p^T pdd to both sides changes nothing:

    Mt_p = 4 G^T J' G + c p p^T,   Qt_p = Q_p + c p gamma_norm / 2.

With s = p^T p, [G; p^T] [G; p^T]^T = s I, hence the exact block inverse

    Mt_p^-1 = (G^T J'^-1 G / 4 + p p^T / c) / s^2,

and lam = (Phi_q Mt^-1 Phi_q^T)^-1 (Phi_q Mt^-1 Qt - gamma), qdd = Mt^-1 (Qt - Phi_q^T lam).
Only the m x m Schur matrix is factored (Cholesky, or sparse LU above ``SPARSE_NQ``
coordinates), never the (nq + m) KKT matrix.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from mbsim import equations as eq

SPARSE_NQ = 700  # about 100 bodies' worth of coordinates: sparse Schur factorisation above


class SolveError(Exception):
    """A factorisation that failed inside a step (the integrator turns it into a message)."""


class System:
    """One model's equations of motion with its active constraint rows and counters.

    model: compiled Model; rows: (m_a,) active (independent) constraint rows, default all;
    sparse: None chooses by size (nq >= SPARSE_NQ).
    """

    def __init__(self, model, rows=None, sparse=None):
        self.model = model
        nb = model.nb
        self.nb, self.nq = nb, model.nq
        self.rows = np.arange(model.m) if rows is None else np.asarray(rows, dtype=int)
        self.all_rows = self.rows.size == model.m
        self.m = self.rows.size
        self.sparse = (model.nq >= SPARSE_NQ) if sparse is None else bool(sparse)
        self.rheonomic = any(it.kind == "driver" or it.func is not None for it in model.items)
        # position of each body's normalisation row among the active rows (-1: not active)
        pos = {r: k for k, r in enumerate(self.rows)}
        self.norm_pos = np.full(nb, -1)
        for it in model.items:
            if it.kind == "normalization":
                self.norm_pos[it.bi] = pos.get(int(it.rows[0]), -1)
        self.inv_mass = 1.0 / model.mass  # (nb,)
        self.J_inv = np.linalg.inv(model.J_local)  # (nb, 3, 3)
        self.c_norm = 4.0 * np.trace(model.J_local, axis1=1, axis2=2) / 3.0  # (nb,) scale of c
        self.counters = {"function_evaluations": 0, "constraint_evaluations": 0,
                         "factorizations": 0, "newton_iterations": 0}

    # -- constraint terms on the active rows ------------------------------------------------
    def terms(self, q, t, qd=None, phi=True, jac=True, gamma=False, nu=False):
        """Phi, Phi_q (dense or csr), gamma, nu on the active rows (eq.Terms)."""
        self.counters["constraint_evaluations"] += 1
        T = eq.constraints(self.model, q, t, qd=qd, phi=phi, jac=jac, gamma=gamma, nu=nu,
                           sparse=self.sparse)
        if not self.all_rows:
            r = self.rows
            T.phi = None if T.phi is None else T.phi[r]
            T.jac = None if T.jac is None else T.jac[r]
            T.gamma = None if T.gamma is None else T.gamma[r]
            T.nu = None if T.nu is None else T.nu[r]
        if nu and T.nu is None:
            T.nu = np.zeros(self.m)
        return T

    def nu(self, q, t):
        if not self.rheonomic:
            return np.zeros(self.m)
        return self.terms(q, t, phi=False, jac=False, nu=True).nu

    # -- the modified mass matrix --------------------------------------------------------------
    def minv_blocks(self, p, G):
        """(nb, 7, 7) blocks of Mt^-1 (module docstring) for Euler parameters p (nb, 4)."""
        s = np.einsum("bi,bi->b", p, p)
        Gt = G.transpose(0, 2, 1)
        Mp = 0.25 * np.matmul(np.matmul(Gt, self.J_inv), G)
        Mp += p[:, :, None] * p[:, None, :] / self.c_norm[:, None, None]
        Mp /= (s * s)[:, None, None]
        B = np.zeros((self.nb, 7, 7))
        B[:, 0, 0] = B[:, 1, 1] = B[:, 2, 2] = self.inv_mass
        B[:, 3:, 3:] = Mp
        return B

    def _apply_blocks(self, B, x):
        return np.einsum("bij,bj->bi", B, x.reshape(self.nb, 7)).reshape(-1)

    def schur(self, J, B):
        """X = Phi_q Mt^-1 and a factorisation of S = X Phi_q^T; returns (X, solve)."""
        self.counters["factorizations"] += 1
        if self.sparse:
            Bm = sp.bsr_matrix((B, np.arange(self.nb), np.arange(self.nb + 1)),
                               shape=(self.nq, self.nq))
            X = (J @ Bm).tocsr()
            S = (X @ J.T).tocsc()
            try:
                lu = spla.splu(S, permc_spec="MMD_AT_PLUS_A")
            except RuntimeError as exc:
                raise SolveError(f"singular constraint Jacobian ({exc})") from exc
            return X, lu.solve
        X = np.einsum("rbi,bij->rbj", J.reshape(-1, self.nb, 7), B).reshape(J.shape)
        S = X @ J.T
        try:
            c = la.cho_factor(S, check_finite=False)
        except la.LinAlgError as exc:
            raise SolveError("singular constraint Jacobian (Phi_q M^-1 Phi_q^T not positive "
                             "definite)") from exc
        return X, lambda b: la.cho_solve(c, b, check_finite=False)

    # -- accelerations -------------------------------------------------------------------------
    def accelerations(self, q, qd, t, baumgarte=None, jac=None):
        """Solve the equations of motion at (q, qd, t); returns (qdd, lam, power).

        lam: (m_a,) multipliers of the active rows; power = Q.qd - lam.nu, the rate of
        work of applied and driving forces (the kinetic energy's rate, see module doc).
        baumgarte: (alpha, beta) replaces gamma by gamma - 2 alpha Phi_dot - beta^2 Phi
        (Baumgarte 1972).  jac: Phi_q at q when the caller has it (coordinate partitioning).
        """
        self.counters["function_evaluations"] += 1
        stab = baumgarte is not None
        T = self.terms(q, t, qd=qd, phi=stab, jac=jac is None, gamma=True,
                       nu=stab or self.rheonomic)
        J = T.jac if jac is None else jac
        g = T.gamma
        if stab:
            a, b = baumgarte
            g = g - 2 * a * (J @ qd - T.nu) - b * b * T.phi
        st = eq.State(self.model, q, qd)
        Q = eq.applied_forces(self.model, q, qd, t, st=st)[0]
        Qt = Q.copy()
        k = self.norm_pos >= 0
        if np.any(k):  # Qt_p = Q_p + c p gamma_norm / 2
            Qt.reshape(self.nb, 7)[k, 3:] += (self.c_norm[k] * 0.5 * g[self.norm_pos[k]])[:, None] * st.p[k]
        B = self.minv_blocks(st.p, st.G)
        try:
            X, solve = self.schur(J, B)
        except SolveError:
            raise
        lam = solve(X @ Qt - g)
        qdd = self._apply_blocks(B, Qt) - X.T @ lam
        power = float(Q @ qd)
        if self.rheonomic:
            power -= float(lam @ T.nu)
        return qdd, lam, power

    def full_lam(self, lam):
        """(m,) multipliers on all rows, zero on the redundant ones."""
        if self.all_rows:
            return lam
        out = np.zeros(self.model.m)
        out[self.rows] = lam
        return out

    # -- projections ---------------------------------------------------------------------------
    def project_positions(self, q, t, tol=1e-12, max_iter=10):
        """Mass-weighted Newton projection of q onto Phi(q, t) = 0 (dq = -Mt^-1 Phi_q^T S^-1 Phi).
        Returns (q, converged, iterations, max|Phi|)."""
        q = np.array(q, dtype=float)
        for it in range(max_iter + 1):
            T = self.terms(q, t)
            res = float(np.abs(T.phi).max(initial=0.0))
            if res <= tol:
                return q, True, it, res
            if it == max_iter:
                break
            self.counters["newton_iterations"] += 1
            p = q.reshape(self.nb, 7)[:, 3:]
            from mbsim.rotations import G as rot_G

            X, solve = self.schur(T.jac, self.minv_blocks(p, rot_G(p)))
            q = q - X.T @ solve(T.phi)
        return q, False, max_iter, res

    def project_velocities(self, q, qd, t):
        """Mass-weighted projection of qd onto Phi_q qd = nu."""
        T = self.terms(q, t, phi=False, jac=True, nu=True)
        p = q.reshape(self.nb, 7)[:, 3:]
        from mbsim.rotations import G as rot_G

        X, solve = self.schur(T.jac, self.minv_blocks(p, rot_G(p)))
        return qd - X.T @ solve(T.jac @ qd - T.nu)

    def violations(self, q, qd, t):
        """(max |Phi|, max |Phi_q qd - nu|) over all rows."""
        T = eq.constraints(self.model, q, t, nu=True, sparse=self.sparse)
        return float(np.abs(T.phi).max(initial=0.0)), float(np.abs(T.jac @ qd - T.nu).max(initial=0.0))

    def energy(self, q, qd):
        """(T, V): kinetic and potential energy (Haug eq. 11.x)."""
        return eq.kinetic_energy(self.model, q, qd), eq.potential_energy(self.model, q)
