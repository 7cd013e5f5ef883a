"""Tangent coordinates near a change point of a mechanism (shared by gcp and index-1).

Where Phi_q (the active rows) approaches a rank loss, as at the flat position of a
parallelogram linkage, the Schur complement Phi_q M^-1 Phi_q^T has an eigenvalue ~ sigma^2
and its pivot floor (mbsim/fast/kernels.c) changes the result.  Tangent coordinates
v = C q, C = (N^T M N)^-1 N^T M, N an orthonormal basis of the null space of Phi_q at a
reference point (the M-orthogonal projection onto its tangent space: Mani, Haug & Atkinson
1985; Potra & Yen 1991), complete Phi_q to the square matrix A = [Phi_q; C], and the
accelerations come from the reduced equations (T^T M T) v'' = T^T (Q - M p), T = A^-1 [0; I],
p = A^-1 [gamma; 0] (Haug Sec. 11.4 with T in place of [I; -Phi_u^-1 Phi_v]), which solve
only A.  The module doc of :mod:`mbsim.integrators.gcp` has the measurements.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from mbsim.integrators.rk import StageFailure


def mass_times(system, q, X):
    """M(q) X, M block diagonal (System.mass_blocks)."""
    Mb = system.mass_blocks(q)
    nb = Mb.shape[0]
    return np.einsum("bij,bjk->bik", Mb, X.reshape(nb, 7, -1)).reshape(X.shape)


def tangent_map(system, q, Jd):
    """C (k, nq) of the tangent coordinates at q (Jd: dense Phi_q there, (m, nq), full row
    rank); None where the mass matrix is singular on the tangent space (a massless motion:
    no M-orthogonal projection)."""
    m, n = Jd.shape
    Qf, _ = la.qr(Jd.T, check_finite=False)
    N = Qf[:, m:n]
    MN = mass_times(system, q, N)
    try:
        cf = la.cho_factor(N.T @ MN, check_finite=False)
    except la.LinAlgError:
        return None
    return la.cho_solve(cf, MN.T, check_finite=False)  # C N = I


def factor(system, J, C):
    """LU of A = [Phi_q; C] (nq x nq)."""
    system.counters["factorizations"] += 1
    if system.sparse:
        try:
            return spla.splu(sp.vstack([J, sp.csr_matrix(C)]).tocsc())
        except RuntimeError as exc:
            raise StageFailure(f"singular [Phi_q; C] ({exc})") from exc
    return la.lu_factor(np.vstack([J, C]), check_finite=False)


def solve(system, fac, b, trans=False):
    """A^-1 b (A^-T b) with a factor of :func:`factor` (or any LU of the same kind)."""
    if system.sparse:
        return fac.solve(b, trans="T" if trans else "N")
    return la.lu_solve(fac, b, trans=1 if trans else 0, check_finite=False)


def basis(system, fac, k):
    """T = A^-1 [0; I] (nq x k): the tangent space with C T = I."""
    n = system.nq
    E = np.zeros((n, k))
    E[n - k:] = np.eye(k)
    return solve(system, fac, E)


def complete(system, t, q, v, vd, C, tol, max_iter):
    """(q, qd, fac, T): q on Phi(q, t) = 0 with C q = v by Newton on [Phi(q, t); C q - v] = 0
    from q, qd from A qd = [nu; vd], fac the LU of A = [Phi_q; C] at the last iterate, T its
    constraint terms.  qd is None when Newton neither stopped moving (max |dx| <= tol) nor
    left |Phi| <= tol within max_iter iterations (the caller says why)."""
    s = system
    x = np.array(q, dtype=float)
    for _ in range(max_iter):
        T = s.terms(x, t, jac=True, nu=s.rheonomic)
        fac = factor(s, T.jac, C)
        dx = solve(s, fac, np.concatenate([T.phi, C @ x - v]))
        x -= dx
        s.counters["newton_iterations"] += 1
        if np.abs(dx).max(initial=0.0) <= tol:
            break  # Phi_q of this iterate is within tol of Phi_q(x): keep it
    else:
        # the corrections may stagnate at round-off while the constraints themselves hold
        if np.abs(T.phi).max(initial=0.0) > tol:
            return x, None, fac, T
    nu = T.nu if s.rheonomic else np.zeros(s.m)
    return x, solve(s, fac, np.concatenate([nu, vd])), fac, T


def accelerations(system, t, q, qd, fac, k):
    """(qdd, power) from the reduced equations (module doc): (T^T M T) v'' = T^T (Q - M p), the
    constraint forces dropping out (T^T Phi_q^T = 0); power = Q.qd - lam.nu with lam from
    A^T [lam; mu] = Q - M qdd (mu = 0)."""
    s = system
    G = s.terms(q, t, qd=qd, phi=False, jac=False, gamma=True, nu=s.rheonomic)
    Tb = basis(s, fac, k)
    p = solve(s, fac, np.concatenate([G.gamma, np.zeros(k)]))
    Q = s.generalized_forces(q, qd, t)
    MTp = mass_times(s, q, np.column_stack([Tb, p]))
    try:
        a = la.solve(Tb.T @ MTp[:, :k], Tb.T @ (Q - MTp[:, k]), assume_a="sym",
                     check_finite=False)
    except la.LinAlgError as exc:
        raise StageFailure(f"t = {t:.6g} s: singular reduced mass matrix ({exc})") from exc
    s.counters["factorizations"] += 1
    qdd = Tb @ a + p
    power = float(Q @ qd)
    if s.rheonomic:
        r = Q - mass_times(s, q, qdd[:, None])[:, 0]
        lam = solve(s, fac, r, trans=True)[: s.m]
        power -= float(lam @ G.nu)
    return qdd, power
