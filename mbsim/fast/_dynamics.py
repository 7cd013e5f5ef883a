"""Compiled equations of motion: applied forces, the modified mass matrix, the Schur solve.

The same equations as :mod:`mbsim.equations` and :mod:`mbsim.integrators.system` (Haug 1989,
eq. 11.1.x, Euler-parameter form), in numba.  Tables built once by
:class:`mbsim.fast.dynamics.FastDynamics`:

- ``bt`` (nb, NB) float64 per body: mass (col 0), J' (1-9, row-major), J'^-1 (10-18,
  zero when J' is singular), c = 4 tr(J') / 3 (19), weight m g (20-22), 1 / m (23);
- ``ei`` (ne, 3) int64 / ``ef`` (ne, 9) float64 per compiled force element: kind
  (``EL_*``), bodies b1, b2 and data (TSDA: s_i', s_j', k, c, L0; force: vector, s'; torque:
  vector); other elements are applied in Python and arrive as ``Fx``, ``nx`` (nb, 3);
- ``sidx`` (4, m_a) int64: active rows (in the caller's order), the fill-reducing order of
  the Schur matrix (``order[k]``: the active row at position k, reverse Cuthill-McKee),
  the envelope's first column ``fc`` and offset ``off`` per position;
- ``inc`` (ninc, 3) int64: the incidences (active row u, column offset of the body in the
  row's compact Jacobian (0: body i, 7: body j), body), grouped by body;
- ``pairs`` (np, 3) int64: one line per (incidence g_u, incidence g_v) of the same body
  with pos(u) >= pos(v): envelope index of S[u, v], g_u, g_v.

The Schur matrix S = Phi_q Mt^-1 Phi_q^T is assembled into the envelope (profile) of its
symmetric permutation and factored by an envelope Cholesky: the fill stays inside the
envelope (George and Liu 1981, Ch. 4), so a chain costs O(m b^2) with b its bandwidth.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mbsim.fast._kernels import eval_constraints

EL_TSDA, EL_FORCE, EL_FORCE_LOCAL, EL_TORQUE, EL_TORQUE_LOCAL = range(5)
FAST = {"reassoc", "contract", "nsz"}  # reorder sums (vectorise), fused multiply-add; no nnan
NB = 24
STATUS_OK, STATUS_NOT_PD = 0, 1


@njit(cache=True)
def rotation(q, o, A, b):
    """A[b] = A(p), p = q[o:o+4]: homogeneous form of :func:`mbsim.rotations.A` (Haug eq.
    6.3.20).  (Indices instead of slices: a slice costs a reference count in numba.)"""
    e0, e1, e2, e3 = q[o], q[o + 1], q[o + 2], q[o + 3]
    d = e0 * e0 - e1 * e1 - e2 * e2 - e3 * e3
    A[b, 0, 0] = d + 2 * e1 * e1
    A[b, 1, 1] = d + 2 * e2 * e2
    A[b, 2, 2] = d + 2 * e3 * e3
    A[b, 0, 1] = 2 * (e1 * e2 - e0 * e3)
    A[b, 1, 0] = 2 * (e1 * e2 + e0 * e3)
    A[b, 0, 2] = 2 * (e1 * e3 + e0 * e2)
    A[b, 2, 0] = 2 * (e1 * e3 - e0 * e2)
    A[b, 1, 2] = 2 * (e2 * e3 - e0 * e1)
    A[b, 2, 1] = 2 * (e2 * e3 + e0 * e1)


@njit(cache=True)
def gmat(q, o, G):
    """G = G(p) = [-e, -e~ + e0 I] (3, 4), p = q[o:o+4]; omega_local = 2 G pd (Haug eq.
    6.3.18)."""
    e0, e1, e2, e3 = q[o], q[o + 1], q[o + 2], q[o + 3]
    G[0, 0], G[0, 1], G[0, 2], G[0, 3] = -e1, e0, e3, -e2
    G[1, 0], G[1, 1], G[1, 2], G[1, 3] = -e2, -e3, e0, e1
    G[2, 0], G[2, 1], G[2, 2], G[2, 3] = -e3, e2, -e1, e0


@njit(cache=True)
def _rot(A, b, x, xk, c, out, ok, trans):
    """out[ok] = A[b] x[xk, c:c+3] (trans: A[b]^T x)."""
    for i in range(3):
        s = 0.0
        for j in range(3):
            s += (A[b, j, i] if trans else A[b, i, j]) * x[xk, c + j]
        out[ok, i] = s


@njit(cache=True)
def _cross(x, xk, c, y, yk, out, ok, sign):
    """out[ok] += sign * (x[xk, c:c+3] x y[yk])."""
    a0, a1, a2 = x[xk, c], x[xk, c + 1], x[xk, c + 2]
    b0, b1, b2 = y[yk, 0], y[yk, 1], y[yk, 2]
    out[ok, 0] += sign * (a1 * b2 - a2 * b1)
    out[ok, 1] += sign * (a2 * b0 - a0 * b2)
    out[ok, 2] += sign * (a0 * b1 - a1 * b0)


@njit(cache=True)
def applied_forces(q, qd, bt, ei, ef, Fx, nx, Q):
    """Q (nq,) = [F, 2 G^T (n' - w'~ J' w')] per body (Haug eq. 11.1.x): gravity, the compiled
    elements (module doc), the Python elements' Fx, nx and the gyroscopic term."""
    nb = bt.shape[0]
    A = np.empty((nb, 3, 3))
    G = np.empty((3, 4))
    F = np.empty((nb, 3))
    n = np.empty((nb, 3))
    w = np.empty((nb, 3))
    W = np.zeros((6, 3))  # scratch vectors
    for b in range(nb):
        o = 7 * b + 3
        rotation(q, o, A, b)
        gmat(q, o, G)
        for i in range(3):
            F[b, i] = bt[b, 20 + i] + Fx[b, i]
            n[b, i] = nx[b, i]
            s = 0.0
            for m in range(4):
                s += G[i, m] * qd[o + m]
            w[b, i] = 2.0 * s
    for k in range(ei.shape[0]):
        kind, b1, b2 = ei[k, 0], ei[k, 1], ei[k, 2]
        if kind == EL_TSDA:  # f = k (l - L0) + c ldot, tension along u = d / l (Sec. 11.3)
            _rot(A, b2, ef, k, 3, W, 0, False)  # A_j s_j
            _rot(A, b1, ef, k, 0, W, 1, False)  # A_i s_i
            ln = 0.0
            for i in range(3):
                W[2, i] = q[7 * b2 + i] + W[0, i] - q[7 * b1 + i] - W[1, i]
                ln += W[2, i] * W[2, i]
            ln = math.sqrt(ln)
            for i in range(3):  # coincident points: no direction, no force
                W[2, i] = W[2, i] / ln if ln > 0 else 0.0
            # ldot = u . ((rd_j + A_j (w_j' x s_j')) - (rd_i + A_i (w_i' x s_i')))
            W[3, :] = 0.0
            W[4, :] = 0.0
            _cross(ef, k, 3, w, b2, W, 3, -1.0)
            _cross(ef, k, 0, w, b1, W, 4, -1.0)
            _rot(A, b2, W, 3, 0, W, 0, False)
            _rot(A, b1, W, 4, 0, W, 1, False)
            ldot = 0.0
            for i in range(3):
                ldot += W[2, i] * (qd[7 * b2 + i] + W[0, i] - qd[7 * b1 + i] - W[1, i])
            f = ef[k, 6] * (ln - ef[k, 8]) + ef[k, 7] * ldot
            for i in range(3):
                W[2, i] *= f  # f u: on P_i towards P_j, the opposite on P_j
                F[b1, i] += W[2, i]
                F[b2, i] -= W[2, i]
            _rot(A, b1, W, 2, 0, W, 3, True)
            _cross(ef, k, 0, W, 3, n, b1, 1.0)
            _rot(A, b2, W, 2, 0, W, 3, True)
            _cross(ef, k, 3, W, 3, n, b2, -1.0)
        elif kind == EL_FORCE_LOCAL:  # follower force: body-fixed direction, at s'
            _rot(A, b1, ef, k, 0, W, 0, False)
            for i in range(3):
                F[b1, i] += W[0, i]
                W[1, i] = ef[k, i]
            _cross(ef, k, 3, W, 1, n, b1, 1.0)
        elif kind == EL_FORCE:  # global vector at s'
            for i in range(3):
                F[b1, i] += ef[k, i]
            _rot(A, b1, ef, k, 0, W, 0, True)
            _cross(ef, k, 3, W, 0, n, b1, 1.0)
        else:  # torque on b1, the opposite on b2 (-1: none); local: frame of the first body
            if kind == EL_TORQUE_LOCAL:
                _rot(A, b2 if b2 >= 0 else b1, ef, k, 0, W, 5, False)
            else:
                for i in range(3):
                    W[5, i] = ef[k, i]
            _rot(A, b1, W, 5, 0, W, 0, True)
            for i in range(3):
                n[b1, i] += W[0, i]
            if b2 >= 0:
                _rot(A, b2, W, 5, 0, W, 0, True)
                for i in range(3):
                    n[b2, i] -= W[0, i]
    for b in range(nb):  # gyroscopic term and Q_p = 2 G^T (n' - w' x J' w')
        gmat(q, 7 * b + 3, G)
        for i in range(3):
            s = 0.0
            for j in range(3):
                s += bt[b, 1 + 3 * i + j] * w[b, j]
            W[0, i] = s
        _cross(w, b, 0, W, 0, n, b, -1.0)
        for i in range(3):
            Q[7 * b + i] = F[b, i]
        for m in range(4):
            s = 0.0
            for i in range(3):
                s += G[i, m] * n[b, i]
            Q[7 * b + 3 + m] = 2.0 * s


@njit(cache=True)
def mass_blocks(q, bt, Mb):
    """Mb (nb, 7, 7) = diag(m I, 4 G^T J' G) (Haug eq. 11.1.x)."""
    G = np.empty((3, 4))
    for b in range(bt.shape[0]):
        gmat(q, 7 * b + 3, G)
        Mb[b, :, :] = 0.0
        for i in range(3):
            Mb[b, i, i] = bt[b, 0]
        for a in range(4):
            for c in range(4):
                s = 0.0
                for i in range(3):
                    for j in range(3):
                        s += G[i, a] * bt[b, 1 + 3 * i + j] * G[j, c]
                Mb[b, 3 + a, 3 + c] = 4.0 * s


@njit(cache=True)
def minv_blocks(q, bt, unit, Mi):
    """Mi (nb, 4, 4): Euler-parameter block of Mt^-1 = (G^T J'^-1 G / 4 + p p^T / c) / s^2,
    s = p^T p (mbsim.integrators.system module doc); the translational block is I / m.
    unit: the identity metric instead (min-norm projections of models with singular J')."""
    G = np.empty((3, 4))
    H = np.empty((3, 4))
    for b in range(bt.shape[0]):
        o = 7 * b + 3
        if unit:
            Mi[b, :, :] = 0.0
            for a in range(4):
                Mi[b, a, a] = 1.0
            continue
        gmat(q, o, G)
        for i in range(3):  # H = J'^-1 G
            for e in range(4):
                t = 0.0
                for j in range(3):
                    t += bt[b, 10 + 3 * i + j] * G[j, e]
                H[i, e] = t
        s = 0.0
        for a in range(4):
            s += q[o + a] * q[o + a]
        s2 = 1.0 / (s * s)
        c = 1.0 / bt[b, 19]
        for a in range(4):
            for e in range(4):
                t = G[0, a] * H[0, e] + G[1, a] * H[1, e] + G[2, a] * H[2, e]
                Mi[b, a, e] = (0.25 * t + q[o + a] * q[o + e] * c) * s2


@njit(cache=True)
def _apply_minv(Mi, bt, unit, b, x, xk, xc, y, yk, yc):
    """y[yk, yc:yc+7] = (Mt^-1 block of body b) x[xk, xc:xc+7]."""
    for i in range(3):
        y[yk, yc + i] = x[xk, xc + i] if unit else x[xk, xc + i] * bt[b, 23]
    for a in range(4):
        s = 0.0
        for e in range(4):
            s += Mi[b, a, e] * x[xk, xc + 3 + e]
        y[yk, yc + 3 + a] = s


@njit(cache=True, fastmath=FAST)
def schur_factor(Jc, bt, Mi, unit, sidx, inc, pairs, XG, JG, env):
    """Factor the Schur matrix S = Phi_q Mt^-1 Phi_q^T of the active rows.

    Per incidence g = (row u, column offset, body b) of ``inc``: JG[g] = the row's 7 entries
    for b and XG[g] = Mt_b^-1 JG[g] (zero-padded to 8 for SIMD); S[u, v] = sum over shared
    bodies XG[g_u] . JG[g_v] (``pairs``), assembled in the envelope ``env`` and overwritten
    by its Cholesky factor L (diagonal stored as 1 / L_ii: multiplications, not divisions, on
    the dependency chains).  Returns False when S is not positive definite."""
    for g in range(inc.shape[0]):
        r = sidx[0, inc[g, 0]]
        o = inc[g, 1]
        for c in range(7):
            JG[g, c] = Jc[r, o + c]
        JG[g, 7] = 0.0
        XG[g, 7] = 0.0
        _apply_minv(Mi, bt, unit, inc[g, 2], JG, g, 0, XG, g, 0)
    env[:] = 0.0
    for k in range(pairs.shape[0]):
        g1 = pairs[k, 1]
        g2 = pairs[k, 2]
        s = 0.0
        for c in range(8):
            s += XG[g1, c] * JG[g2, c]
        env[pairs[k, 0]] += s
    n = sidx.shape[1]
    for i in range(n):  # envelope Cholesky, row by row (bordering)
        fi = sidx[2, i]
        oi = sidx[3, i] - fi
        for j in range(fi, i):
            fj = sidx[2, j]
            oj = sidx[3, j] - fj
            s = env[oi + j]
            for k in range(max(fi, fj), j):
                s -= env[oi + k] * env[oj + k]
            env[oi + j] = s * env[oj + j]
        s = env[oi + i]
        for k in range(fi, i):
            s -= env[oi + k] * env[oi + k]
        if not s > 0.0:
            return False
        env[oi + i] = 1.0 / math.sqrt(s)  # the diagonal is kept inverted
    return True


@njit(cache=True, fastmath=FAST)
def schur_solve(sidx, env, rhs, lam):
    """lam = S^-1 rhs (both in the active rows' order) with the factor of :func:`schur_factor`."""
    n = sidx.shape[1]
    z = np.empty(n)
    for i in range(n):  # L z = P rhs
        oi = sidx[3, i] - sidx[2, i]
        s = rhs[sidx[1, i]]
        for k in range(sidx[2, i], i):
            s -= env[oi + k] * z[k]
        z[i] = s * env[oi + i]
    for i in range(n - 1, -1, -1):  # L^T x = z, column by column
        oi = sidx[3, i] - sidx[2, i]
        z[i] *= env[oi + i]
        for k in range(sidx[2, i], i):
            z[k] -= env[oi + k] * z[i]
    for i in range(n):
        lam[sidx[1, i]] = z[i]


@njit(cache=True)
def _env_size(sidx):
    n = sidx.shape[1]
    return sidx[3, n - 1] + n - sidx[2, n - 1] if n > 0 else 0


@njit(cache=True)
def _rhs(
    q, qd, tv, ci, cf, rb, sidx, bt, nrm, ei, ef, Fx, nx, par, Jg, phi, Jc, gamma, nu, g, Q, Qt
):
    """Constraint terms, g = gamma (Baumgarte-stabilised when par[2]) on the active rows,
    Q and Qt = Q + c p gamma_norm / 2 (mbsim.integrators.system module doc)."""
    act = sidx[0]
    stab = par[2] != 0.0
    have_jac = Jg.shape[0] > 0
    eval_constraints(q, qd, tv, ci, cf, not have_jac, True, phi, Jc, gamma, nu)
    if have_jac:
        Jc[:, :] = Jg
    for u in range(act.size):
        r = act[u]
        g[u] = gamma[r]
        if stab:  # gamma - 2 alpha (Phi_q qd - nu) - beta^2 Phi (Baumgarte 1972)
            jv = 0.0
            for c in range(7):
                jv += Jc[r, c] * qd[7 * rb[r, 0] + c]
            if rb[r, 1] >= 0:
                for c in range(7):
                    jv += Jc[r, 7 + c] * qd[7 * rb[r, 1] + c]
            g[u] -= 2.0 * par[0] * (jv - nu[r]) + par[1] * par[1] * phi[r]
    applied_forces(q, qd, bt, ei, ef, Fx, nx, Q)
    Qt[:] = Q
    for b in range(bt.shape[0]):
        if nrm[b] >= 0:
            h = 0.5 * bt[b, 19] * g[nrm[b]]
            for m in range(4):
                Qt[7 * b + 3 + m] += h * q[7 * b + 3 + m]


@njit(cache=True)
def accelerations_schur(
    q, qd, tv, ci, cf, rb, sidx, inc, pairs, bt, nrm, ei, ef, Fx, nx, par, Jg, qdd, lam
):
    """(qdd, lam) by the Schur complement of Mt (mbsim.integrators.system):
    lam = S^-1 (Phi_q Mt^-1 Qt - g), qdd = Mt^-1 (Qt - Phi_q^T lam); returns
    (status, power), power = Q.qd - lam.nu."""
    m = rb.shape[0]
    ma = sidx.shape[1]
    nq = q.size
    nb = bt.shape[0]
    phi = np.empty(m)
    Jc = np.empty((m, 14))
    gamma = np.empty(m)
    nu = np.empty(m)
    g = np.empty(ma)
    Q = np.empty(nq)
    Qt = np.empty(nq)
    _rhs(
        q, qd, tv, ci, cf, rb, sidx, bt, nrm, ei, ef, Fx, nx, par, Jg, phi, Jc, gamma, nu, g, Q, Qt
    )
    Mi = np.empty((nb, 4, 4))
    minv_blocks(q, bt, False, Mi)
    XG = np.empty((inc.shape[0], 8))
    JG = np.empty((inc.shape[0], 8))
    env = np.empty(_env_size(sidx))
    if not schur_factor(Jc, bt, Mi, False, sidx, inc, pairs, XG, JG, env):
        return STATUS_NOT_PD, 0.0
    rhs = np.empty(ma)
    for u in range(ma):
        rhs[u] = -g[u]
    for k in range(inc.shape[0]):  # + Phi_q Mt^-1 Qt
        o = 7 * inc[k, 2]
        s = 0.0
        for c in range(7):
            s += XG[k, c] * Qt[o + c]
        rhs[inc[k, 0]] += s
    schur_solve(sidx, env, rhs, lam)
    for b in range(nb):  # qdd = Mt^-1 Qt - (Phi_q Mt^-1)^T lam
        o = 7 * b
        for i in range(3):
            qdd[o + i] = Qt[o + i] * bt[b, 23]
        for a in range(4):
            s = 0.0
            for e in range(4):
                s += Mi[b, a, e] * Qt[o + 3 + e]
            qdd[o + 3 + a] = s
    for k in range(inc.shape[0]):
        o = 7 * inc[k, 2]
        h = lam[inc[k, 0]]
        for c in range(7):
            qdd[o + c] -= XG[k, c] * h
    power = 0.0
    for i in range(nq):
        power += Q[i] * qd[i]
    for u in range(ma):
        power -= lam[u] * nu[sidx[0, u]]
    return STATUS_OK, power


@njit(cache=True)
def accelerations_kkt(q, qd, tv, ci, cf, rb, sidx, bt, nrm, ei, ef, Fx, nx, par, Jg, qdd, lam):
    """(qdd, lam) from the full KKT matrix [M, Phi_q^T; Phi_q, 0] by dense LU (Haug eq.
    11.1.x), for models where some J' is singular; returns (status, power)."""
    m = rb.shape[0]
    ma = sidx.shape[1]
    nq = q.size
    nb = bt.shape[0]
    phi = np.empty(m)
    Jc = np.empty((m, 14))
    gamma = np.empty(m)
    nu = np.empty(m)
    g = np.empty(ma)
    Q = np.empty(nq)
    Qt = np.empty(nq)
    _rhs(
        q, qd, tv, ci, cf, rb, sidx, bt, nrm, ei, ef, Fx, nx, par, Jg, phi, Jc, gamma, nu, g, Q, Qt
    )
    Mb = np.empty((nb, 7, 7))
    mass_blocks(q, bt, Mb)
    n = nq + ma
    K = np.zeros((n, n))
    rhs = np.empty(n)
    for b in range(nb):
        for i in range(7):
            for j in range(7):
                K[7 * b + i, 7 * b + j] = Mb[b, i, j]
    act = sidx[0]
    for u in range(ma):
        r = act[u]
        for s in range(2):
            b = rb[r, s]
            if b < 0:
                continue
            for c in range(7):
                K[nq + u, 7 * b + c] += Jc[r, 7 * s + c]
                K[7 * b + c, nq + u] += Jc[r, 7 * s + c]
    rhs[:nq] = Q
    rhs[nq:] = g
    sol = np.linalg.solve(K, rhs)
    qdd[:] = sol[:nq]
    lam[:] = sol[nq:]
    power = 0.0
    for i in range(nq):
        power += Q[i] * qd[i]
    for u in range(ma):
        power -= lam[u] * nu[act[u]]
    return STATUS_OK, power


@njit(cache=True)
def schur_project(q, Jc, bt, unit, sidx, inc, pairs, rhs, dq):
    """dq (nq,) = Mt^-1 Phi_q^T S^-1 rhs: the weighted least-norm correction with Phi_q dq =
    rhs on the active rows (unit: identity metric).  Returns False when S is not p.d."""
    ma = sidx.shape[1]
    Mi = np.empty((bt.shape[0], 4, 4))
    minv_blocks(q, bt, unit, Mi)
    XG = np.empty((inc.shape[0], 8))
    JG = np.empty((inc.shape[0], 8))
    env = np.empty(_env_size(sidx))
    if not schur_factor(Jc, bt, Mi, unit, sidx, inc, pairs, XG, JG, env):
        return False
    lam = np.empty(ma)
    schur_solve(sidx, env, rhs, lam)
    dq[:] = 0.0
    for k in range(inc.shape[0]):
        o = 7 * inc[k, 2]
        h = lam[inc[k, 0]]
        for c in range(7):
            dq[o + c] += XG[k, c] * h
    return True
