"""The numpy reference of the equations (tests only): Phi, Phi_q, nu, gamma, M, Q, KKT solve.

Production evaluates the same equations in C through :mod:`mbsim.core`; the tests compare
the two to round-off (tests/test_kernels.py).

q = [r_1, p_1, ..., r_nb, p_nb] (7 per body); rows in the order of ``model.items``.
Phi(q, t) = phi(q) - c(t);  Phi_q qd = nu = c'(t);  Phi_q qdd = gamma (Haug Ch. 9).
Equations of motion (Haug Ch. 11, Euler-parameter form):

    [ M     Phi_q^T ] [qdd]   [Q]          M = diag(m I, 4 G^T J' G)
    [ Phi_q   0     ] [lam] = [gamma]      Q = [F, 2 G^T (n' - w'~ J' w')]

where the normalisation row p^T p = 1 in Phi removes the null direction p of 4 G^T J' G.
"""

from __future__ import annotations

import numpy as np

from mbsim.core import State, Terms, require_finite  # (an input guard, not physics)
from tests.reference.basic import KERNELS


def constraints(model, q, t=0.0, qd=None, phi=True, jac=True, gamma=False, nu=False,
                sparse=False) -> Terms:
    """Evaluate Phi, Phi_q, nu and gamma at (q, qd, t); only the parts asked for."""
    st = State(model, q, qd)
    m, nq = model.m, model.nq
    out = Terms()
    out.phi = np.zeros(m) if phi else None
    out.gamma = np.zeros(m) if gamma else None
    out.nu = np.zeros(m) if nu else None
    if jac:
        if sparse:
            rr, cc, vv = [], [], []
        else:
            J = np.zeros((m, nq))
    for blk in model.blocks:
        fn = KERNELS[blk.kernel][0]
        if blk.kernel == "angle":
            res = fn(st, blk, jac=jac, gamma=gamma, t=t)
        else:
            res = fn(st, blk, jac=jac, gamma=gamma)
        rows = blk.rows.reshape(-1)
        if phi:
            val = res["phi"]
            if blk.kernel != "angle":
                val = val - blk.c_const
                if blk.funcs:
                    val = val.copy()
                    for n, f, sq in blk.funcs:
                        v = f(t)
                        val[n, 0] -= v * v if sq else v
            out.phi[rows] = val.reshape(-1)
        if jac:
            if sparse:
                rr.append(blk.scatter["ri"])
                cc.append(blk.scatter["ci"])
                vv.append(res["ji"].reshape(-1))
                if res.get("jj") is not None:
                    rr.append(blk.scatter["rj"])
                    cc.append(blk.scatter["cj"])
                    vv.append(res["jj"].reshape(-1))
            else:
                J[blk.scatter["ri"], blk.scatter["ci"]] = res["ji"].reshape(-1)
                if res.get("jj") is not None:
                    J[blk.scatter["rj"], blk.scatter["cj"]] = res["jj"].reshape(-1)
        if (gamma or nu) and blk.funcs:
            for n, f, sq in blk.funcs:
                r = blk.rows[n, 0]
                v, d1, d2 = f(t), f.d1(t), f.d2(t)
                if sq:  # target f^2: (f^2)' = 2 f f', (f^2)'' = 2 (f'^2 + f f'')
                    d1, d2 = 2 * v * d1, 2 * (d1 * d1 + v * d2)
                if nu:
                    out.nu[r] = d1
                if gamma:
                    res["gamma"][n, 0] += d2
        if gamma:
            out.gamma[rows] = res["gamma"].reshape(-1)
    if jac:
        if sparse:
            import scipy.sparse as sp  # here: scipy costs ~0.4 s to import (mbsim check: none)

            out.jac = sp.csr_matrix((np.concatenate(vv), (np.concatenate(rr), np.concatenate(cc))),
                                    shape=(m, nq))
        else:
            out.jac = J
    return out


def phi(model, q, t=0.0):
    return constraints(model, q, t, jac=False).phi


def phi_q(model, q, t=0.0, sparse=False):
    return constraints(model, q, t, phi=False, sparse=sparse).jac


def nu(model, q, t=0.0):
    return constraints(model, q, t, phi=False, jac=False, nu=True).nu


def gamma(model, q, qd, t=0.0):
    return constraints(model, q, t, qd=qd, phi=False, jac=False, gamma=True).gamma


def mass_matrix(model, q, sparse=False):
    """M = diag(m_b I3, 4 G_b^T J'_b G_b) (Haug Ch. 11); (nq, nq)."""
    st = State(model, q)
    Mp = 4 * np.einsum("bki,bkl,blj->bij", st.G, model.J_local, st.G)
    blocks = np.zeros((model.nb, 7, 7))
    blocks[:, 0, 0] = blocks[:, 1, 1] = blocks[:, 2, 2] = model.mass
    blocks[:, 3:, 3:] = Mp
    if sparse:
        import scipy.sparse as sp

        return sp.block_diag(list(blocks), format="csr")
    M = np.zeros((model.nq, model.nq))
    for b in range(model.nb):
        M[7 * b:7 * b + 7, 7 * b:7 * b + 7] = blocks[b]
    return M


def applied_forces(model, q, qd, t=0.0, st=None):
    """Q (nq,): gravity, force elements and the gyroscopic term -2 G^T w'~ J' w'.

    Returns (Q, F, n_local) with F (nb, 3) global forces and n_local (nb, 3) body torques
    (without the gyroscopic term) so that callers can report them.
    """
    st = st or State(model, q, qd)
    F = model.mass[:, None] * model.gravity[None, :]
    n_local = np.zeros((model.nb, 3))
    for el in model.forces:
        el.apply(st, t, F, n_local)
    w = st.omega_local
    gyro = np.cross(w, np.einsum("bij,bj->bi", model.J_local, w))
    Qp = 2 * np.einsum("bji,bj->bi", st.G, n_local - gyro)
    Q = np.concatenate([F, Qp], axis=1).reshape(-1)
    return Q, F, n_local


def potential_energy(model, q) -> float:
    st = State(model, q)
    V = -float(np.sum(model.mass * (st.r @ model.gravity)))
    return V + sum(el.potential(st) for el in model.forces)


def kinetic_energy(model, q, qd) -> float:
    st = State(model, q, qd)
    w = st.omega_local
    rot = np.einsum("bi,bij,bj->", w, model.J_local, w)
    return float(0.5 * np.sum(model.mass * np.sum(st.rd ** 2, 1)) + 0.5 * rot)


def accelerations(model, q, qd, t=0.0, Q=None, rows=None):
    """Solve the KKT system for (qdd, lam) (Haug Ch. 11). Dense LU; see the integrators
    for the sparse path.  ``rows``: the constraint rows to use (e.g. an assembly's
    ``active_rows``, without redundant ones); lam is returned for all rows, 0 for the others."""
    T = constraints(model, q, t, qd=qd, phi=False, gamma=True)
    if Q is None:
        Q = applied_forces(model, q, qd, t)[0]
    M = mass_matrix(model, q)
    J, g = T.jac, T.gamma
    if rows is not None:
        J, g = J[rows], g[rows]
    n, m = model.nq, J.shape[0]
    K = np.zeros((n + m, n + m))
    K[:n, :n] = M
    K[:n, n:] = J.T
    K[n:, :n] = J
    rhs = np.concatenate([Q, g])
    if not (np.isfinite(K).all() and np.isfinite(rhs).all()):
        require_finite(model, t, M=M, Q=Q, J=J, gamma=g)
    import scipy.linalg as la

    sol = la.solve(K, rhs)
    lam = sol[n:]
    if rows is not None:
        lam = np.zeros(model.m)
        lam[rows] = sol[n:]
    return sol[:n], lam
