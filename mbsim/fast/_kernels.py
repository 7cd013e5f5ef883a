"""Compiled constraint kernels: every row of every kernel in one loop (numba).

The same equations as :mod:`mbsim.constraints.basic` (Haug 1989, Ch. 9), written per
constraint with scalars instead of batched numpy, so that one compiled call evaluates a
whole model.  The model is flattened once (:class:`mbsim.fast.constraints.FastConstraints`)
into two tables with one line per basic constraint (k = 0 .. nc-1):

- ``ci`` (nc, NI) int64: kernel code, body i, body j (-1: one body), first global row,
  flag (dot2: 1 when a is on body j; absolute: axis 0/1/2), time-target index (-1: none);
- ``cf`` (nc, NF) float64: three body-fixed vectors (columns 0-8, the kernel's arguments
  in the order listed in ``VECTORS``) and up to six constant targets (columns 9-14).

Results go into caller-owned buffers: ``phi``, ``gamma``, ``nu`` (m,) and the compact
Jacobian ``Jc`` (m, 14): columns 0-6 d Phi_r / d[r_i, p_i], 7-13 d Phi_r / d[r_j, p_j].
The dense (m_a, nq) and CSR Jacobians are filled from ``Jc`` by :func:`fill_dense` and
:func:`fill_csr`.  Time targets arrive as ``tv`` (nf, 3): the target c(t) (squared where
the driver says so), c'(t) and c''(t), evaluated in Python before the call.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

KERNEL_CODE = {
    "dot1": 0,
    "dot2": 1,
    "spherical": 2,
    "distance": 3,
    "angle": 4,
    "absolute": 5,
    "ground": 6,
    "normalization": 7,
}
"""kernel name -> code in ``ci[:, 0]``."""
DOT1, DOT2, SPHERICAL, DISTANCE, ANGLE, ABSOLUTE, GROUND, NORMALIZATION = range(8)
NE = np.array([1, 1, 3, 1, 1, 1, 6, 1], dtype=np.int64)  # equations per constraint, by code
VECTORS = {
    "dot1": ("ai", "aj"),
    "dot2": ("a", "si", "sj"),
    "spherical": ("si", "sj"),
    "distance": ("si", "sj"),
    "angle": ("gi", "hi", "gj"),
    "absolute": ("s",),
    "ground": (),
    "normalization": (),
}
"""kernel name -> the Block.vecs keys stored in cf[:, 0:3], cf[:, 3:6], cf[:, 6:9]."""
I_KERNEL, I_BI, I_BJ, I_ROW, I_FLAG, I_FUNC = range(6)
NI = 6
F_CONST = 9
NF = 15


@njit(cache=True)
def _vec(q, qd, b, cf, k, c, gam, B, V, s):
    """Body-fixed vector a' = cf[k, c:c+3] on body b, into slot s:

    - B[s] = B(p, a') = d(A(p) a')/dp (3, 4) (Haug eq. 9.3.14, the homogeneous form of
      :func:`mbsim.rotations.B`): column e0 is 2 (e0 a' + e x a'), the e block
      2 ((e.a') I + e a'^T - a' e^T - e0 a'~);
    - V[s, 0] = A a' = B p / 2 and, when gam, V[s, 1] = B pd (its rate) and
      V[s, 2] = B(pd, a') pd (the gamma term), B being linear in p.

    Scalars and indices, no slices: a numba slice costs a reference count, and locals stay
    in registers (twice as fast as going through the B array)."""
    o = 7 * b + 3
    e0, e1, e2, e3 = q[o], q[o + 1], q[o + 2], q[o + 3]
    a0, a1, a2 = cf[k, c], cf[k, c + 1], cf[k, c + 2]
    ea = 2.0 * (e1 * a0 + e2 * a1 + e3 * a2)
    b00 = 2.0 * (e0 * a0 + e2 * a2 - e3 * a1)
    b10 = 2.0 * (e0 * a1 + e3 * a0 - e1 * a2)
    b20 = 2.0 * (e0 * a2 + e1 * a1 - e2 * a0)
    b02 = 2.0 * (e1 * a1 - a0 * e2 + e0 * a2)
    b03 = 2.0 * (e1 * a2 - a0 * e3 - e0 * a1)
    b11 = 2.0 * (e2 * a0 - a1 * e1 - e0 * a2)
    b13 = 2.0 * (e2 * a2 - a1 * e3 + e0 * a0)
    b21 = 2.0 * (e3 * a0 - a2 * e1 + e0 * a1)
    b22 = 2.0 * (e3 * a1 - a2 * e2 - e0 * a0)
    B[s, 0, 0], B[s, 0, 1], B[s, 0, 2], B[s, 0, 3] = b00, ea, b02, b03
    B[s, 1, 0], B[s, 1, 1], B[s, 1, 2], B[s, 1, 3] = b10, b11, ea, b13
    B[s, 2, 0], B[s, 2, 1], B[s, 2, 2], B[s, 2, 3] = b20, b21, b22, ea
    V[s, 0, 0] = 0.5 * (b00 * e0 + ea * e1 + b02 * e2 + b03 * e3)
    V[s, 0, 1] = 0.5 * (b10 * e0 + b11 * e1 + ea * e2 + b13 * e3)
    V[s, 0, 2] = 0.5 * (b20 * e0 + b21 * e1 + b22 * e2 + ea * e3)
    if gam:
        d0, d1, d2, d3 = qd[o], qd[o + 1], qd[o + 2], qd[o + 3]
        V[s, 1, 0] = b00 * d0 + ea * d1 + b02 * d2 + b03 * d3
        V[s, 1, 1] = b10 * d0 + b11 * d1 + ea * d2 + b13 * d3
        V[s, 1, 2] = b20 * d0 + b21 * d1 + b22 * d2 + ea * d3
        ea = 2.0 * (d1 * a0 + d2 * a1 + d3 * a2)  # B(pd, a') pd
        b00 = 2.0 * (d0 * a0 + d2 * a2 - d3 * a1)
        b10 = 2.0 * (d0 * a1 + d3 * a0 - d1 * a2)
        b20 = 2.0 * (d0 * a2 + d1 * a1 - d2 * a0)
        b02 = 2.0 * (d1 * a1 - a0 * d2 + d0 * a2)
        b03 = 2.0 * (d1 * a2 - a0 * d3 - d0 * a1)
        b11 = 2.0 * (d2 * a0 - a1 * d1 - d0 * a2)
        b13 = 2.0 * (d2 * a2 - a1 * d3 + d0 * a0)
        b21 = 2.0 * (d3 * a0 - a2 * d1 + d0 * a1)
        b22 = 2.0 * (d3 * a1 - a2 * d2 - d0 * a0)
        V[s, 2, 0] = b00 * d0 + ea * d1 + b02 * d2 + b03 * d3
        V[s, 2, 1] = b10 * d0 + b11 * d1 + ea * d2 + b13 * d3
        V[s, 2, 2] = b20 * d0 + b21 * d1 + b22 * d2 + ea * d3


@njit(cache=True)
def _dot(V, s, a, z, b):
    """V[s, a] . V[z, b]."""
    return V[s, a, 0] * V[z, b, 0] + V[s, a, 1] * V[z, b, 1] + V[s, a, 2] * V[z, b, 2]


@njit(cache=True)
def eval_constraints(q, qd, tv, ci, cf, jac, gam, phi, Jc, gamma, nu):
    """Phi (with targets), compact Phi_q, gamma (with c'') and nu = c' of all rows.

    q, qd: (nq,); tv: (nf, 3); ci, cf: the model tables (module doc); jac, gam: what to
    compute besides phi and nu (gam needs qd).  Outputs (m,) phi, gamma, nu, (m, 14) Jc.
    Vector slots: 0 the direction (dot1: a_i, a_j in 0, 1; angle: g_i, h_i, g_j in 0-2),
    1 and 2 the points s_i, s_j."""
    B = np.empty((3, 3, 4))  # B(p, a') per slot
    V = np.zeros((3, 3, 3))  # per slot: val, vel, bdot
    d = np.empty(3)
    dd = np.zeros(3)
    nu[:] = 0.0
    if jac:
        Jc[:, :] = 0.0
    for k in range(ci.shape[0]):
        kind = ci[k, 0]
        bi = ci[k, 1]
        bj = ci[k, 2]
        r = ci[k, 3]
        flag = ci[k, 4]
        fn = ci[k, 5]
        if kind == DOT1:  # Phi = a_i . a_j (Haug eq. 9.2.3)
            _vec(q, qd, bi, cf, k, 0, gam, B, V, 0)
            _vec(q, qd, bj, cf, k, 3, gam, B, V, 1)
            phi[r] = _dot(V, 0, 0, 1, 0)
            if jac:
                for m in range(4):
                    si = 0.0
                    sj = 0.0
                    for i in range(3):
                        si += V[1, 0, i] * B[0, i, m]
                        sj += V[0, 0, i] * B[1, i, m]
                    Jc[r, 3 + m] = si
                    Jc[r, 10 + m] = sj
            if gam:
                gamma[r] = -(_dot(V, 0, 0, 1, 2) + _dot(V, 1, 0, 0, 2) + 2.0 * _dot(V, 0, 1, 1, 1))
        elif kind == DOT2 or kind == SPHERICAL or kind == DISTANCE:
            c0 = 3 if kind == DOT2 else 0  # dot2 keeps a in columns 0-2, s_i, s_j after it
            _vec(q, qd, bi, cf, k, c0, gam, B, V, 1)
            _vec(q, qd, bj, cf, k, c0 + 3, gam, B, V, 2)
            for i in range(3):  # d = r_j + A_j s_j - r_i - A_i s_i (Haug eq. 9.2.x)
                d[i] = q[7 * bj + i] + V[2, 0, i] - q[7 * bi + i] - V[1, 0, i]
                if gam:
                    dd[i] = qd[7 * bj + i] + V[2, 1, i] - qd[7 * bi + i] - V[1, 1, i]
            if kind == DOT2:  # Phi = a . d_ij, a on body i or j (Haug eq. 9.2.6)
                _vec(q, qd, bj if flag else bi, cf, k, 0, gam, B, V, 0)
                phi[r] = V[0, 0, 0] * d[0] + V[0, 0, 1] * d[1] + V[0, 0, 2] * d[2]
                if jac:
                    for i in range(3):
                        Jc[r, i] = -V[0, 0, i]
                        Jc[r, 7 + i] = V[0, 0, i]
                    ca = 10 if flag else 3
                    for m in range(4):
                        si = 0.0
                        sj = 0.0
                        da = 0.0
                        for i in range(3):
                            si += V[0, 0, i] * B[1, i, m]
                            sj += V[0, 0, i] * B[2, i, m]
                            da += d[i] * B[0, i, m]
                        Jc[r, 3 + m] = -si
                        Jc[r, 10 + m] = sj
                        Jc[r, ca + m] += da
                if gam:
                    g = 0.0
                    for i in range(3):
                        g += (
                            V[0, 0, i] * (V[2, 2, i] - V[1, 2, i])
                            + d[i] * V[0, 2, i]
                            + 2.0 * V[0, 1, i] * dd[i]
                        )
                    gamma[r] = -g
            elif kind == SPHERICAL:  # Phi = d_ij (3 equations, Haug eq. 9.4.1)
                for i in range(3):
                    phi[r + i] = d[i]
                    if jac:
                        Jc[r + i, i] = -1.0
                        Jc[r + i, 7 + i] = 1.0
                        for m in range(4):
                            Jc[r + i, 3 + m] = -B[1, i, m]
                            Jc[r + i, 10 + m] = B[2, i, m]
                    if gam:
                        gamma[r + i] = V[1, 2, i] - V[2, 2, i]
            else:  # DISTANCE: Phi = d . d, target C^2 (Haug eq. 9.2.9)
                phi[r] = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
                if jac:
                    for i in range(3):
                        Jc[r, i] = -2.0 * d[i]
                        Jc[r, 7 + i] = 2.0 * d[i]
                    for m in range(4):
                        si = 0.0
                        sj = 0.0
                        for i in range(3):
                            si += d[i] * B[1, i, m]
                            sj += d[i] * B[2, i, m]
                        Jc[r, 3 + m] = -2.0 * si
                        Jc[r, 10 + m] = 2.0 * sj
                if gam:
                    g = 0.0
                    for i in range(3):
                        g += d[i] * (V[2, 2, i] - V[1, 2, i]) + dd[i] * dd[i]
                    gamma[r] = -2.0 * g
        elif kind == ANGLE:  # theta from g_i to g_j about f_i minus f(t), wrapped (Sec. 9.5)
            _vec(q, qd, bi, cf, k, 0, gam, B, V, 0)  # g_i
            _vec(q, qd, bi, cf, k, 3, gam, B, V, 1)  # h_i
            _vec(q, qd, bj, cf, k, 6, gam, B, V, 2)  # g_j
            c = _dot(V, 0, 0, 2, 0)
            s = _dot(V, 1, 0, 2, 0)
            f = tv[fn, 0] if fn >= 0 else cf[k, F_CONST]
            cfn = math.cos(f)
            sfn = math.sin(f)
            phi[r] = math.atan2(s * cfn - c * sfn, c * cfn + s * sfn)
            rho = c * c + s * s
            if jac:
                for m in range(4):
                    dci = 0.0
                    dsi = 0.0
                    dcj = 0.0
                    dsj = 0.0
                    for i in range(3):
                        dci += V[2, 0, i] * B[0, i, m]
                        dsi += V[2, 0, i] * B[1, i, m]
                        dcj += V[0, 0, i] * B[2, i, m]
                        dsj += V[1, 0, i] * B[2, i, m]
                    Jc[r, 3 + m] = (c * dsi - s * dci) / rho
                    Jc[r, 10 + m] = (c * dsj - s * dcj) / rho
            if gam:
                gc = -(_dot(V, 0, 0, 2, 2) + _dot(V, 2, 0, 0, 2) + 2.0 * _dot(V, 0, 1, 2, 1))
                gs = -(_dot(V, 1, 0, 2, 2) + _dot(V, 2, 0, 1, 2) + 2.0 * _dot(V, 1, 1, 2, 1))
                cd = _dot(V, 0, 1, 2, 0) + _dot(V, 0, 0, 2, 1)
                sd = _dot(V, 1, 1, 2, 0) + _dot(V, 1, 0, 2, 1)
                thd = (c * sd - s * cd) / rho
                rhod = 2.0 * (c * cd + s * sd)
                gamma[r] = (c * gs - s * gc) / rho + thd * rhod / rho
        elif kind == ABSOLUTE:  # Phi = (r + A s')[axis] (Haug Sec. 9.5)
            _vec(q, qd, bi, cf, k, 0, gam, B, V, 0)
            phi[r] = q[7 * bi + flag] + V[0, 0, flag]
            if jac:
                Jc[r, flag] = 1.0
                for m in range(4):
                    Jc[r, 3 + m] = B[0, flag, m]
            if gam:
                gamma[r] = -V[0, 2, flag]
        elif kind == GROUND:  # r = r0, (e1, e2, e3) = e0' (6 equations)
            for i in range(3):
                phi[r + i] = q[7 * bi + i]
                phi[r + 3 + i] = q[7 * bi + 4 + i]
                if jac:
                    Jc[r + i, i] = 1.0
                    Jc[r + 3 + i, 4 + i] = 1.0
            if gam:
                for i in range(6):
                    gamma[r + i] = 0.0
        else:  # NORMALIZATION: p^T p - 1 (Haug eq. 6.3.2)
            o = 7 * bi + 3
            s = 0.0
            for m in range(4):
                s += q[o + m] * q[o + m]
                if jac:
                    Jc[r, 3 + m] = 2.0 * q[o + m]
            phi[r] = s
            if gam:
                s = 0.0
                for m in range(4):
                    s += qd[o + m] * qd[o + m]
                gamma[r] = -2.0 * s
        if kind != ANGLE:  # Phi = phi(q) - c: constant targets, then the time target
            for e in range(NE[kind]):
                phi[r + e] -= cf[k, F_CONST + e]
            if fn >= 0:
                phi[r] -= tv[fn, 0]
        if fn >= 0:  # nu = c', gamma += c''
            nu[r] = tv[fn, 1]
            if gam:
                gamma[r] += tv[fn, 2]


@njit(cache=True)
def fill_dense(Jc, rb, rows, J):
    """J[k, 7 b + c] = Jc[rows[k], ...]: the dense (m_a, nq) Jacobian of the rows ``rows``
    (rb: (m, 2) bodies of each row).  Writes the pattern only: J must be zero elsewhere."""
    for k in range(rows.size):
        r = rows[k]
        c0 = 7 * rb[r, 0]
        for c in range(7):
            J[k, c0 + c] = Jc[r, c]
        if rb[r, 1] >= 0:
            c1 = 7 * rb[r, 1]
            if c1 == c0:  # both ends on one body: the derivative is the sum
                for c in range(7):
                    J[k, c1 + c] += Jc[r, 7 + c]
            else:
                for c in range(7):
                    J[k, c1 + c] = Jc[r, 7 + c]


@njit(cache=True)
def fill_csr(Jc, rows, dpos, data):
    """data[dpos[k, c]] += Jc[rows[k], c]: the CSR values in the fixed pattern (dpos: (m_a,
    14) position of each compact entry in ``data``, -1 for the absent body j)."""
    data[:] = 0.0
    for k in range(rows.size):
        r = rows[k]
        for c in range(14):
            if dpos[k, c] >= 0:
                data[dpos[k, c]] += Jc[r, c]


@njit(cache=True)
def gather_dense(J, rb, rows, Jc):
    """The inverse of :func:`fill_dense`: compact rows from a dense (m_a, nq) Jacobian."""
    for k in range(rows.size):
        r = rows[k]
        c0 = 7 * rb[r, 0]
        for c in range(7):
            Jc[r, c] = J[k, c0 + c]
        if rb[r, 1] >= 0:
            c1 = 7 * rb[r, 1]
            for c in range(7):
                Jc[r, 7 + c] = 0.0 if c1 == c0 else J[k, c1 + c]


@njit(cache=True)
def select(src, rows, out):
    """out[k] = src[rows[k]]."""
    for k in range(rows.size):
        out[k] = src[rows[k]]


@njit(cache=True)
def jac_times(Jc, rb, x, out):
    """out (m,) = Phi_q x from the compact Jacobian (all rows)."""
    for r in range(rb.shape[0]):
        s = 0.0
        for c in range(7):
            s += Jc[r, c] * x[7 * rb[r, 0] + c]
        if rb[r, 1] >= 0:
            for c in range(7):
                s += Jc[r, 7 + c] * x[7 * rb[r, 1] + c]
        out[r] = s
