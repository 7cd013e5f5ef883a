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
Only the m x m Schur matrix is factored, never the (nq + m) KKT matrix.  With the fused
constraint evaluation (fused.py: every kernel but the rotational driver's) the Schur matrix
is assembled body by body and factored banded or dense (kkt.py); otherwise it is formed from
Phi_q of :func:`mbsim.equations.constraints`, dense or (above ``SPARSE_NQ`` coordinates)
CSR with SuperLU.  Coordinate partitioning needs Phi_q itself: CSR above ``SPARSE_NQ``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from mbsim import equations as eq
from mbsim.integrators.fused import FusedConstraints
from mbsim.integrators.kkt import BlockSchur, SolveError

__all__ = ["SolveError", "System"]

_G_IDX = np.array([[1, 0, 3, 2], [2, 3, 0, 1], [3, 2, 1, 0]])
_G_SIGN = np.array([[-1.0, 1, 1, -1], [-1, -1, 1, 1], [-1, 1, -1, 1]])


def G_matrices(p):
    """G(p) (nb, 3, 4) = [-e, -e~ + e0 I] (Haug eq. 6.3.18) for p (nb, 4): one gather, one
    product."""
    return p[:, _G_IDX] * _G_SIGN


def mass_blocks(model, q):
    """(nb, 7, 7) diagonal blocks of M = diag(m I, 4 G^T J' G) (Haug eq. 11.1.x)."""
    G = G_matrices(q.reshape(model.nb, 7)[:, 3:])
    B = np.zeros((model.nb, 7, 7))
    B[:, 0, 0] = B[:, 1, 1] = B[:, 2, 2] = model.mass
    B[:, 3:, 3:] = 4 * np.matmul(np.matmul(G.transpose(0, 2, 1), model.J_local), G)
    return B


SPARSE_NQ = 250  # sparse Phi_q (CSR) from about 35 bodies on (measured crossover, spherical chain)


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
        fused = FusedConstraints(model, self.sparse)
        self.fused = fused if fused.ok else None
        # body-block Schur complement (kkt.py) where the fused evaluator applies
        self.bs = BlockSchur(*fused.pieces(), self.rows, nb, model.m) if fused.ok else None
        self.gravity_F = model.mass[:, None] * model.gravity[None, :]  # (nb, 3)

    # -- constraint terms on the active rows ------------------------------------------------
    def terms(self, q, t, qd=None, phi=True, jac=True, gamma=False, nu=False):
        """Phi, Phi_q (dense or csr), gamma, nu on the active rows (eq.Terms)."""
        self.counters["constraint_evaluations"] += 1
        if self.fused is not None:
            T = eq.Terms()
            T.phi, T.jac, T.gamma, T.nu = self.fused(q, t, qd, jac=jac, gamma=gamma, nu=nu)
        else:
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

    # -- applied forces ---------------------------------------------------------------------------
    def G(self, p):
        return G_matrices(p)

    def generalized_forces(self, q, qd, t=0.0):
        """Q (nq,) at (q, qd, t) (the interface of mbsim.fast's FastDynamics)."""
        return self.applied_forces(eq.State(self.model, q, qd), t)

    def applied_forces(self, st, t):
        """Q (nq,) as :func:`mbsim.equations.applied_forces` (gravity, force elements and
        the gyroscopic term -2 G^T w'~ J' w'), with G computed once and shared through st."""
        st._G = self.G(st.p)
        F = self.gravity_F.copy()
        n_local = np.zeros((self.nb, 3))
        for el in self.model.forces:
            el.apply(st, t, F, n_local)
        w = 2 * np.matmul(st._G, st.pd[:, :, None])[:, :, 0]  # omega' = 2 G pd
        st._om = w
        Jw = np.matmul(self.model.J_local, w[:, :, None])[:, :, 0]
        gyro = w[:, [1, 2, 0]] * Jw[:, [2, 0, 1]] - w[:, [2, 0, 1]] * Jw[:, [1, 2, 0]]
        Q = np.empty((self.nb, 7))
        Q[:, :3] = F
        Q[:, 3:] = 2 * np.matmul((n_local - gyro)[:, None, :], st._G)[:, 0]
        return Q.reshape(-1)

    # -- the modified mass matrix --------------------------------------------------------------
    def minv_blocks(self, p, G):
        """(nb, 7, 7) blocks of Mt^-1 (module docstring) for Euler parameters p (nb, 4)."""
        s = (p * p).sum(1)
        Mp = 0.25 * np.matmul(np.matmul(G.transpose(0, 2, 1), self.J_inv), G)
        Mp += p[:, :, None] * p[:, None, :] / self.c_norm[:, None, None]
        Mp /= (s * s)[:, None, None]
        B = np.zeros((self.nb, 7, 7))
        B[:, 0, 0] = B[:, 1, 1] = B[:, 2, 2] = self.inv_mass
        B[:, 3:, 3:] = Mp
        return B

    def _apply_blocks(self, B, x):
        return np.matmul(B, x.reshape(self.nb, 7, 1)).reshape(-1)

    def schur(self, J, B, rhs):
        """X = Phi_q Mt^-1 and the solution x of S x = rhs, S = X Phi_q^T (SPD, m x m);
        rhs: an array or a function of X.  Returns (X, x).  Dense: one LAPACK solve;
        sparse: SuperLU."""
        if not callable(rhs):
            rhs = (lambda b: lambda X: b)(rhs)
        self.counters["factorizations"] += 1
        if self.sparse:
            Bm = sp.bsr_matrix((B, np.arange(self.nb), np.arange(self.nb + 1)),
                               shape=(self.nq, self.nq))
            X = (J @ Bm).tocsr()
            S = (X @ J.T).tocsc()
            try:
                return X, spla.splu(S, permc_spec="MMD_AT_PLUS_A").solve(rhs(X))
            except RuntimeError as exc:
                raise SolveError(f"singular constraint Jacobian ({exc})") from exc
        X = np.matmul(J.reshape(-1, self.nb, 1, 7), B).reshape(J.shape)
        S = X @ J.T
        try:
            return X, np.linalg.solve(S, rhs(X))
        except np.linalg.LinAlgError as exc:
            raise SolveError("singular constraint Jacobian (Phi_q M^-1 Phi_q^T)") from exc

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
        nu_needed = stab or self.rheonomic
        st = eq.State(self.model, q, qd)
        Q = self.applied_forces(st, t)
        if self.bs is not None:
            return self._accelerations_blocks(q, qd, t, baumgarte, st, Q)
        T = self.terms(q, t, qd=qd, phi=stab, jac=jac is None, gamma=True, nu=nu_needed)
        J = T.jac if jac is None else jac
        g = T.gamma
        if stab:
            a, b = baumgarte
            g = g - 2 * a * (J @ qd - T.nu) - b * b * T.phi
        Qt = self._modified_forces(Q, g, st.p)
        B = self.minv_blocks(st.p, st.G)
        X, lam = self.schur(J, B, lambda X: X @ Qt - g)
        qdd = self._apply_blocks(B, Qt) - X.T @ lam
        power = float(Q @ qd)
        if self.rheonomic:
            power -= float(lam @ T.nu)
        return qdd, lam, power

    def _modified_forces(self, Q, g, p):
        """Qt = Q with Q_p + c p gamma_norm / 2 (module doc)."""
        Qt = Q.copy()
        k = self.norm_pos >= 0
        if np.any(k):
            c = self.c_norm[k] * 0.5 * g[self.norm_pos[k]]
            Qt.reshape(self.nb, 7)[k, 3:] += c[:, None] * p[k]
        return Qt

    def _active(self, x):
        return x if self.all_rows or x is None else x[self.rows]

    def _accelerations_blocks(self, q, qd, t, baumgarte, st, Q):
        """accelerations() through the fused evaluator and the body-block Schur complement."""
        self.counters["constraint_evaluations"] += 1
        self.counters["factorizations"] += 1
        stab = baumgarte is not None
        phi, vals, g, nu = self.fused(q, t, qd, jac="values", gamma=True,
                                      nu=stab or self.rheonomic)
        g, phi, nu = self._active(g), self._active(phi), self._active(nu)
        bs = self.bs
        Jb = bs.blocks(vals)
        if stab:
            a, b = baumgarte
            g = g - 2 * a * (bs.jac_times(Jb, qd) - nu) - b * b * phi
        Qt = self._modified_forces(Q, g, st.p)
        B = self.minv_blocks(st.p, st.G)
        y = np.matmul(B, Qt.reshape(self.nb, 7, 1))
        lam = bs.solve(Jb, B, bs.jac_times(Jb, y.reshape(-1)) - g)
        qdd = (y - np.matmul(B, bs.jac_t_times(Jb, lam)[:, :, None])).reshape(-1)
        power = float(Q @ qd)
        if self.rheonomic:
            power -= float(lam @ nu)
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
        if self.bs is not None:
            return self._project_positions_blocks(q, t, tol, max_iter)
        for it in range(max_iter + 1):
            T = self.terms(q, t)
            res = float(np.abs(T.phi).max(initial=0.0))
            if res <= tol:
                return q, True, it, res
            if it == max_iter:
                break
            self.counters["newton_iterations"] += 1
            p = q.reshape(self.nb, 7)[:, 3:]
            X, x = self.schur(T.jac, self.minv_blocks(p, self.G(p)), T.phi)
            q = q - X.T @ x
        return q, False, max_iter, res

    def _project_positions_blocks(self, q, t, tol, max_iter):
        bs = self.bs
        for it in range(max_iter + 1):
            self.counters["constraint_evaluations"] += 1
            phi, vals, _, _ = self.fused(q, t, jac="values")
            phi = self._active(phi)
            res = float(np.abs(phi).max(initial=0.0))
            if res <= tol:
                return q, True, it, res
            if it == max_iter:
                break
            self.counters["newton_iterations"] += 1
            self.counters["factorizations"] += 1
            p = q.reshape(self.nb, 7)[:, 3:]
            B = self.minv_blocks(p, self.G(p))
            Jb = bs.blocks(vals)
            x = bs.solve(Jb, B, phi)
            q = q - np.matmul(B, bs.jac_t_times(Jb, x)[:, :, None]).reshape(-1)
        return q, False, max_iter, res

    def project_velocities(self, q, qd, t):
        """Mass-weighted projection of qd onto Phi_q qd = nu."""
        if self.bs is not None:
            bs = self.bs
            self.counters["constraint_evaluations"] += 1
            self.counters["factorizations"] += 1
            _, vals, _, nu = self.fused(q, t, jac="values", nu=True)
            p = q.reshape(self.nb, 7)[:, 3:]
            B = self.minv_blocks(p, self.G(p))
            Jb = bs.blocks(vals)
            x = bs.solve(Jb, B, bs.jac_times(Jb, qd) - self._active(nu))
            return qd - np.matmul(B, bs.jac_t_times(Jb, x)[:, :, None]).reshape(-1)
        T = self.terms(q, t, phi=False, jac=True, nu=True)
        p = q.reshape(self.nb, 7)[:, 3:]
        X, x = self.schur(T.jac, self.minv_blocks(p, self.G(p)), T.jac @ qd - T.nu)
        return qd - X.T @ x

    def violations(self, q, qd, t):
        """(max |Phi|, max |Phi_q qd - nu|) over all rows."""
        if self.fused is not None:
            phi, J, _, nu = self.fused(q, t, nu=True)
        else:
            T = eq.constraints(self.model, q, t, nu=True, sparse=self.sparse)
            phi, J, nu = T.phi, T.jac, T.nu
        return float(np.abs(phi).max(initial=0.0)), float(np.abs(J @ qd - nu).max(initial=0.0))

    def energy(self, q, qd):
        """(T, V): kinetic and potential energy (Haug eq. 11.x)."""
        return eq.kinetic_energy(self.model, q, qd), eq.potential_energy(self.model, q)
