"""All the compiled (numba) code of :mod:`mbsim.fast`: constraint kernels and dynamics.

One module on purpose: numba's on-disk cache (``cache=True``) is checked per source file,
and a compiled function keeps its own inlined copy of what it calls; a caller in another
file would go on running a stale copy of an edited kernel.  Here an edit recompiles all.

Constraint kernels
------------------
The same equations as :mod:`mbsim.constraints.basic` (Haug 1989, Ch. 9), written per
constraint with scalars instead of batched numpy, so that one compiled call evaluates a
whole model.  The model is flattened once (:class:`mbsim.fast.constraints.FastConstraints`)
into two tables with one line per basic constraint (k = 0 .. nc-1):

- ``ci`` (nc, NI) int64: kernel code, body i, body j (-1: one body), first global row,
  flag (dot2: 1 when a is on body j; absolute: axis 0/1/2), time-target index (-1: none),
  the body of each of the three vector slots (-1: slot unused);
- ``cf`` (nc, NF) float64: the three body-fixed vectors (columns 0-8, the kernel's
  arguments in the slots listed in ``VECTORS``) and up to six constant targets (9-14).

Results go into caller-owned buffers: ``phi``, ``gamma``, ``nu`` (m,) and the compact
Jacobian ``Jc`` (m, 14): columns 0-6 d Phi_r / d[r_i, p_i], 7-13 d Phi_r / d[r_j, p_j].
The dense (m_a, nq) and CSR Jacobians are filled from ``Jc`` by :func:`fill_dense` and
:func:`fill_csr`.  Time targets arrive as ``tv`` (nf, 3): the target c(t) (squared where
the driver says so), c'(t) and c''(t), evaluated in Python before the call.

Equations of motion
-------------------
The same equations as :mod:`mbsim.equations` and :mod:`mbsim.integrators.system` (Haug 1989,
eq. 11.1.x, Euler-parameter form).  Tables built once by
:class:`mbsim.fast.dynamics.FastDynamics`:

- ``bt`` (nb, NB) float64 per body: mass (col 0), J' (1-9, row-major), J'^-1 (10-18,
  zero when J' is singular), c = 4 tr(J') / 3 (19), weight m g (20-22), 1 / m (23);
- ``ei`` (ne, 3) int64 / ``ef`` (ne, 9) float64 per compiled force element: kind
  (``EL_*``), bodies b1, b2 and data (TSDA: s_i', s_j', k, c, L0; force: vector, s'; torque:
  vector); other elements are applied in Python and arrive as ``loads`` (2, nb, 3):
  their forces F and body-frame torques n';
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

KERNELS = ("dot1", "dot2", "spherical", "distance", "angle", "absolute", "ground", "normalization")
KERNEL_CODE = {name: code for code, name in enumerate(KERNELS)}
"""kernel name -> code in ``ci[:, 0]``."""
DOT1, DOT2, SPHERICAL, DISTANCE, ANGLE, ABSOLUTE, GROUND, NORMALIZATION = range(8)
NE = np.array([1, 1, 3, 1, 1, 1, 6, 1], dtype=np.int64)  # equations per constraint, by code
VECTORS = {
    "dot1": (("ai", "i"), ("aj", "j")),
    "dot2": (("a", "i"), ("si", "i"), ("sj", "j")),  # a on body j when the flag says so
    "spherical": (None, ("si", "i"), ("sj", "j")),
    "distance": (None, ("si", "i"), ("sj", "j")),
    "angle": (("gi", "i"), ("hi", "i"), ("gj", "j")),
    "absolute": (("s", "i"),),
    "ground": (),
    "normalization": (),
}
"""kernel name -> per vector slot 0, 1, 2 (cf[:, 0:3], 3:6, 6:9): (Block.vecs key, body)."""
I_KERNEL, I_BI, I_BJ, I_ROW, I_FLAG, I_FUNC, I_SLOT = 0, 1, 2, 3, 4, 5, 6
NI = 9
F_CONST = 9
NF = 15
EL_TSDA, EL_FORCE, EL_FORCE_LOCAL, EL_TORQUE, EL_TORQUE_LOCAL = range(5)
FAST = {"reassoc", "contract", "nsz"}  # reorder sums (vectorise), fused multiply-add; no nnan
NB = 24
STATUS_OK, STATUS_NOT_PD = 0, 1


# -- constraint kernels ---------------------------------------------------------------------
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
    Vector slots (``VECTORS``): dot1 a_i, a_j; dot2 a, s_i, s_j; spherical and distance
    -, s_i, s_j; angle g_i, h_i, g_j; absolute s."""
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
        for v in range(3):  # the kernel's body-fixed vectors, one call site (compile time)
            if ci[k, I_SLOT + v] >= 0:
                _vec(q, qd, ci[k, I_SLOT + v], cf, k, 3 * v, gam, B, V, v)
        if kind == DOT1:  # Phi = a_i . a_j (Haug eq. 9.2.3)
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
            for i in range(3):  # d = r_j + A_j s_j - r_i - A_i s_i (Haug eq. 9.2.x)
                d[i] = q[7 * bj + i] + V[2, 0, i] - q[7 * bi + i] - V[1, 0, i]
                if gam:
                    dd[i] = qd[7 * bj + i] + V[2, 1, i] - qd[7 * bi + i] - V[1, 1, i]
            if kind == DOT2:  # Phi = a . d_ij, a on body i or j (Haug eq. 9.2.6)
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
def gather(rows, rb, phi_all, nu_all, gamma_all, Jc, gam, mode, phi, nu, gamma, J, dpos, data):
    """The results on ``rows`` from those of all rows, in one call: phi, nu (and gamma when
    gam) (m_a,), the Jacobian dense into J (mode 1, :func:`fill_dense`) or as CSR values
    into data (mode 2, :func:`fill_csr`); mode 0: no Jacobian."""
    for k in range(rows.size):
        phi[k] = phi_all[rows[k]]
        nu[k] = nu_all[rows[k]]
        if gam:
            gamma[k] = gamma_all[rows[k]]
    if mode == 1:
        fill_dense(Jc, rb, rows, J)
    elif mode == 2:
        fill_csr(Jc, rows, dpos, data)


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


# -- equations of motion --------------------------------------------------------------------
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
def applied_forces(q, qd, bt, ei, ef, loads, Q):
    """Q (nq,) = [F, 2 G^T (n' - w'~ J' w')] per body (Haug eq. 11.1.x): gravity, the compiled
    elements (module doc), the Python elements' loads and the gyroscopic term."""
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
            F[b, i] = bt[b, 20 + i] + loads[0, b, i]
            n[b, i] = loads[1, b, i]
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
def _rhs(q, qd, rb, sidx, bt, nrm, ei, ef, loads, par, phi, Jc, nu, gamma, g, Q, Qt):
    """g = gamma on the active rows (Baumgarte-stabilised when par[2]), Q and
    Qt = Q + c p gamma_norm / 2 (mbsim.integrators.system module doc)."""
    stab = par[2] != 0.0
    for u in range(sidx.shape[1]):
        r = sidx[0, u]
        g[u] = gamma[r]
        if stab:  # gamma - 2 alpha (Phi_q qd - nu) - beta^2 Phi (Baumgarte 1972)
            jv = 0.0
            for c in range(7):
                jv += Jc[r, c] * qd[7 * rb[r, 0] + c]
            if rb[r, 1] >= 0:
                for c in range(7):
                    jv += Jc[r, 7 + c] * qd[7 * rb[r, 1] + c]
            g[u] -= 2.0 * par[0] * (jv - nu[r]) + par[1] * par[1] * phi[r]
    applied_forces(q, qd, bt, ei, ef, loads, Q)
    Qt[:] = Q
    for b in range(bt.shape[0]):
        if nrm[b] >= 0:
            h = 0.5 * bt[b, 19] * g[nrm[b]]
            for m in range(4):
                Qt[7 * b + 3 + m] += h * q[7 * b + 3 + m]


@njit(cache=True)
def _solve_schur(q, bt, sidx, inc, pairs, Jc, Qt, g, qdd, lam):
    """lam = S^-1 (Phi_q Mt^-1 Qt - g), qdd = Mt^-1 (Qt - Phi_q^T lam) (mbsim.integrators.
    system module doc); False when S is not positive definite."""
    ma = sidx.shape[1]
    nb = bt.shape[0]
    Mi = np.empty((nb, 4, 4))
    minv_blocks(q, bt, False, Mi)
    XG = np.empty((inc.shape[0], 8))
    JG = np.empty((inc.shape[0], 8))
    env = np.empty(_env_size(sidx))
    if not schur_factor(Jc, bt, Mi, False, sidx, inc, pairs, XG, JG, env):
        return False
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
    return True


@njit(cache=True)
def _solve_kkt(q, rb, sidx, bt, Jc, Q, g, qdd, lam):
    """[M, Phi_q^T; Phi_q, 0] [qdd; lam] = [Q; g] by dense LU (Haug eq. 11.1.x); for models
    where some J' is singular.  Raises LinAlgError when the matrix is singular."""
    ma = sidx.shape[1]
    nq = q.size
    nb = bt.shape[0]
    Mb = np.empty((nb, 7, 7))
    mass_blocks(q, bt, Mb)
    n = nq + ma
    K = np.zeros((n, n))
    rhs = np.empty(n)
    for b in range(nb):
        for i in range(7):
            for j in range(7):
                K[7 * b + i, 7 * b + j] = Mb[b, i, j]
    for u in range(ma):
        r = sidx[0, u]
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


@njit(cache=True)
def accelerations(
    q, qd, tv, ci, cf, rb, sidx, inc, pairs, bt, nrm, ei, ef, loads, par, kkt, Jg, qdd, lam
):
    """(qdd, lam) of the equations of motion at (q, qd): the constraint terms
    (:func:`eval_constraints`; Jg (m, 14): the compact Phi_q given by the caller, or (0, 14)),
    the applied forces, then the Schur complement of Mt, or the dense KKT matrix when ``kkt``.
    par: Baumgarte (alpha, beta, on).  Returns (status, power), power = Q.qd - lam.nu."""
    m = rb.shape[0]
    ma = sidx.shape[1]
    nq = q.size
    phi = np.empty(m)
    Jc = np.empty((m, 14))
    gamma = np.empty(m)
    nu = np.empty(m)
    have_jac = Jg.shape[0] > 0
    eval_constraints(q, qd, tv, ci, cf, not have_jac, True, phi, Jc, gamma, nu)
    if have_jac:
        Jc[:, :] = Jg
    g = np.empty(ma)
    Q = np.empty(nq)
    Qt = np.empty(nq)
    _rhs(q, qd, rb, sidx, bt, nrm, ei, ef, loads, par, phi, Jc, nu, gamma, g, Q, Qt)
    if kkt:
        _solve_kkt(q, rb, sidx, bt, Jc, Q, g, qdd, lam)
    elif not _solve_schur(q, bt, sidx, inc, pairs, Jc, Qt, g, qdd, lam):
        return STATUS_NOT_PD, 0.0
    power = 0.0
    for i in range(nq):
        power += Q[i] * qd[i]
    for u in range(ma):
        power -= lam[u] * nu[sidx[0, u]]
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
