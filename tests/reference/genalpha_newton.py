"""The Newton iteration of generalized-alpha and HHT in numpy: the reference that
mbsim/fast/implicit.c is checked against (tests/integrators/test_genalpha_compiled.py), and
nothing else uses.

The same equations and stopping tests as mb_ga_newton and mb_ga_tangent (the method in
mbsim/integrators/genalpha.py's module doc), written from the System's Python methods
(terms, generalized_forces, mass_blocks) and scipy's dense and sparse LU; each function takes
the integrator for its state, options and system.
"""

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from mbsim.integrators.base import ROUNDOFF_ULPS, rms_norm
from mbsim.integrators.genalpha import KKT_REG


def residual(ga, q, qd, qdd, lam, t):
    """(r, T, Q, Mb): r = M(q) qdd + Phi_q(q)^T lam - Q(q, qd, t) on the active rows."""
    s = ga.system
    T = s.terms(q, t, jac=True, nu=s.rheonomic)
    Q = s.generalized_forces(q, qd, t)
    Mb = s.mass_blocks(q)
    r = np.einsum("bij,bj->bi", Mb, qdd.reshape(-1, 7)).reshape(-1) + T.jac.T @ lam - Q
    return r, T, Q, Mb


def tangent(ga, q, qd, qdd, lam, t):
    """(K, C) = (dr/dq, dr/dqd) by forward differences, ground columns zero."""
    n = q.size
    r0 = residual(ga, q, qd, qdd, lam, t)[0]
    K, C = np.zeros((n, n)), np.zeros((n, n))
    for j in range(n):
        if ga.system.model.is_ground[j // 7]:
            continue
        d = 1.5e-8 * max(1.0, abs(q[j]))
        x = q.copy()
        x[j] += d
        K[:, j] = (residual(ga, x, qd, qdd, lam, t)[0] - r0) / d
        d = 1.5e-8 * max(1.0, abs(qd[j]))
        x = qd.copy()
        x[j] += d
        C[:, j] = (residual(ga, q, x, qdd, lam, t)[0] - r0) / d
    return K, C


def iteration_matrix(ga, Mb, J, bp, gp, KC):
    """solve(b) on the factor of [M + gp/bp C + K/bp, Phi_q^T; Phi_q, -eps I]."""
    s = ga.system
    n, m = s.nq, s.m
    if sp.issparse(J):
        jn = float(J.multiply(J).sum(axis=1).max()) if m else 0.0
    else:
        jn = float((J * J).sum(axis=1).max()) if m else 0.0
    eps = KKT_REG * jn / max(float(np.abs(Mb).max()), 1e-300)
    b, i, j = np.meshgrid(np.arange(s.nb), np.arange(7), np.arange(7), indexing="ij")
    bi, bj = (7 * b + i).reshape(-1), (7 * b + j).reshape(-1)
    if s.sparse:
        A = sp.csr_matrix((Mb.reshape(-1), (bi, bj)), shape=(n, n))
        if KC is not None:
            A = A + sp.csr_matrix(gp / bp * KC[1] + KC[0] / bp)
        S = sp.bmat([[A, J.T], [J, -eps * sp.identity(m)]], format="csc")
        return spla.splu(S).solve
    S = np.zeros((n + m, n + m))
    S[bi, bj] = Mb.reshape(-1)
    if KC is not None:
        S[:n, :n] += gp / bp * KC[1] + KC[0] / bp
    S[:n, n:] = J.T
    S[n:, :n] = J
    S[n:, n:] = -eps * np.eye(m)
    lu = la.lu_factor(S, check_finite=False)
    return lambda rhs: la.lu_solve(lu, rhs, check_finite=False)


def newton(ga, h, a, KC=None):
    """(q, qd, qdd, lam, a1, power, iterations) of the step h from the integrator's state
    with the acceleration-like variable a, or None where Newton fails."""
    s = ga.system
    am, af, gam, beta = ga.coef
    t1 = ga.t + h
    n = s.nq
    qdd = ga.qdd.copy()
    lam = ga.lam.copy()
    a1 = (af * ga.qdd - am * a + (1 - af) * qdd) / (1 - am)
    q = ga.q + h * ga.qd + h * h * ((0.5 - beta) * a + beta * a1)
    qd = ga.qd + h * ((1 - gam) * a + gam * a1)
    bp = (1 - am) / (beta * h * h * (1 - af))
    gp = gam / (beta * h)
    prev = np.inf
    qs = ROUNDOFF_ULPS * np.finfo(float).eps * max(1.0, np.abs(q).max(initial=0.0))
    r_floor = None
    iterations = 0
    for it in range(ga.max_newton):
        r, T, Q, Mb = residual(ga, q, qd, qdd, lam, t1)
        if r_floor is None:
            r_floor = qs * bp * ga._mscale
        elif np.abs(T.phi).max(initial=0.0) <= qs and np.all(np.abs(r) <= r_floor):
            break
        try:
            solve = iteration_matrix(ga, Mb, T.jac, bp, gp, KC)
            dx = solve(np.concatenate([-r / bp, -T.phi]))
        except (la.LinAlgError, RuntimeError, ValueError):
            return None
        if not np.all(np.isfinite(dx)):
            return None
        dq = dx[:n]
        q += dq
        qd += gp * dq
        qdd += bp * dq
        lam += bp * dx[n:]
        iterations += 1
        err = rms_norm(dq, ga.atol + ga.rtol * np.abs(q))
        if err <= ga.newton_tol:
            break
        if ga.newton_contraction and prev < np.inf and err < prev and (
                err * err / (prev - err) <= ga.newton_tol):
            break
        if np.abs(dq).max(initial=0.0) <= 64 * np.finfo(float).eps * max(1.0, np.abs(q).max()):
            break
        if it >= 2 and err > 0.9 * prev:
            return None
        prev = err
    else:
        return None
    power = float(Q @ qd) - (float(lam @ T.nu) if s.rheonomic else 0.0)
    a1 = (af * ga.qdd - am * a + (1 - af) * qdd) / (1 - am)
    return q, qd, qdd, lam, a1, power, iterations
